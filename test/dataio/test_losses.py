"""
Every lost sample counted: across resets, long gaps and v1 re-locks.

Regressions measured on main: a 2.5 s UART stall (seq and t_us kept counting, 501 frames
never sent) and a 2 s unplug left ``lost_frames`` unchanged (a gap over 2 s counted 0, and
``reset()`` on reopen cleared the baseline); a version-1 re-lock after a 1030 ms gap counted
5 (the seq gap modulo 256, 6, read as 6 samples at a slower rate).
"""

from accel_calib_ros.dataio.wire import encode, FrameParser, RawFrame
import pytest


def stream(first, n, version=2, period_us=1000, t0=7_000, seq0=0, index0=None):
    """Return n frames of a stream from sample number ``first`` (seq, t_us by the index)."""
    out = []
    for k in range(first, first + n):
        j = k if index0 is None else k - index0
        seq = (seq0 + j) & (0xFFFF if version == 2 else 0xFF)
        counts = (k % 30000, k // 30000, 16384, 1335, 0, 0, 0)    # the index in ax, ay
        out.append(RawFrame(seq, (t0 + j * period_us) & 0xFFFFFFFF, counts, None, version))
    return out


def feed(parser, frames, host_s=None, chunk=20):
    """Feed frames in reads of ``chunk``; the host time is the last sample's (1 kHz)."""
    out = []
    for k in range(0, len(frames), chunk):
        part = frames[k:k + chunk]
        host = None if host_s is None else host_s(part[-1])
        out += parser.feed(b''.join(encode(f) for f in part), host)
    return out


def at(frame):
    """Host time of a sample at 1 kHz (its index, carried in ax and ay)."""
    return 1000.0 + (frame.counts[0] + 30000 * frame.counts[1]) * 1e-3


@pytest.mark.parametrize('version', [2, 1])
def test_a_long_stall_is_counted_with_host_times(version):
    """2.5 s not sent (seq and t_us go on): all 2500 missing samples counted."""
    parser = FrameParser()
    frames = stream(0, 3000, version) + stream(5500, 3000, version)
    out = feed(parser, frames, at) + parser.flush()
    assert out == frames
    assert parser.lost_frames == 2500 and parser.gaps_uncounted == 0


def test_a_long_gap_without_host_times_is_not_guessed():
    parser = FrameParser()
    frames = stream(0, 3000) + stream(5500, 3000)
    assert feed(parser, frames) + parser.flush() == frames
    assert parser.lost_frames == 0 and parser.gaps_uncounted == 1


def test_a_device_restart_is_not_counted_as_a_loss():
    """The board restarts 3 s later: seq and t_us from 0 again; host times say 3 s."""
    parser = FrameParser()
    before = stream(0, 3000, t0=900_000_000)
    after = stream(6000, 3000, t0=1_500_000, index0=6000)
    out = feed(parser, before + after, at) + parser.flush()
    assert out == before + after
    assert parser.lost_frames == 0 and parser.gaps_uncounted == 1


@pytest.mark.parametrize('version', [2, 1])
def test_losses_are_counted_across_a_reset(version):
    """A reopen or a reader failure resets the parser: the gap around it still counts."""
    parser = FrameParser()
    first = feed(parser, stream(0, 1000, version), at) + parser.flush()
    parser.reset()
    second = feed(parser, stream(1400, 1000, version), at) + parser.flush()
    assert len(first) + len(second) == 2000
    assert parser.lost_frames == 400


def test_v1_relock_is_checked_against_the_measured_period():
    """A 1030 ms gap of version-1 frames: 1029 lost, not 5 (1030 mod 256 = 6)."""
    frames = stream(0, 1000, 1) + stream(2029, 1000, 1)
    plain = FrameParser()
    assert feed(plain, frames, at) + plain.flush() == frames
    assert plain.lost_frames == 1029
    after_reset = FrameParser()
    feed(after_reset, frames[:1000], at)
    after_reset.flush()
    after_reset.reset()
    feed(after_reset, frames[1000:], at)
    after_reset.flush()
    assert after_reset.lost_frames == 1029
    garbled = FrameParser()                     # re-locked through damage in the gap
    junk = bytes(range(256)) * 4
    garbled.feed(b''.join(encode(f) for f in frames[:1000]), 2.0)
    garbled.feed(junk, 2.5)
    garbled.feed(b''.join(encode(f) for f in frames[1000:]), 3.1)
    garbled.flush()
    assert garbled.lost_frames == 1029


def test_v1_gaps_too_long_for_its_seq_are_not_guessed():
    """Version 1 at 1 kHz: 3000 s of gap is ±300 periods of doubt: two seq values fit."""
    parser = FrameParser()
    frames = stream(0, 1000, 1) + stream(3_001_000, 1000, 1)
    assert feed(parser, frames, at) + parser.flush() == frames
    assert parser.lost_frames == 0 and parser.gaps_uncounted == 1
    v2 = FrameParser()                          # version 2's 16-bit seq tells it
    frames = stream(0, 1000) + stream(2_001_000, 1000)
    assert feed(v2, frames, at) + v2.flush() == frames
    assert v2.lost_frames == 2_000_000 and v2.gaps_uncounted == 0
