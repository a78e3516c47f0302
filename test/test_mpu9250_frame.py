"""The MPU9250 wire format: CRC, frames, resynchronisation, ASCII, units, clock mapping."""

import math
import random
import struct

from accel_calib_ros.dataio.mpu9250_frame import (accel_scale, AsciiLineParser, ClockMapper,
                                                  Converter, crc8, encode_ascii_line,
                                                  encode_frame, FRAME_SIZE, FrameParser,
                                                  gyro_scale, RawFrame, SPIKE_COUNTS, temp_c)
import numpy as np
import pytest

G0 = 9.80665


def bitwise_crc8(data):
    """Textbook bit-by-bit CRC-8/poly 0x07, independent of the table."""
    crc = 0
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = ((crc << 1) ^ 0x07) if crc & 0x80 else (crc << 1)
            crc &= 0xFF
    return crc


def random_frames(n, rng, seq0=0, t0=4_294_000_000, period_us=5000):
    """Uniformly random axes (the hardest case for a plausibility check), 15..35 °C."""
    counts = rng.integers(-32768, 32768, (n, 7))
    counts[:, 3] = np.clip(1335 + np.cumsum(rng.integers(-20, 21, n)), -2000, 4700)
    counts = counts.tolist()
    return [RawFrame((seq0 + k) & 0xFF, (t0 + k * period_us) & 0xFFFFFFFF, tuple(c))
            for k, c in enumerate(counts)]


def encode_all(frames):
    return b''.join(encode_frame(*f) for f in frames)


def test_crc_known_vector():
    assert crc8(b'123456789') == 0xF4
    assert bitwise_crc8(b'123456789') == 0xF4
    data = bytes(range(19))
    assert crc8(data) == bitwise_crc8(data)
    assert crc8(b'') == 0


def test_encode_layout():
    frame = encode_frame(0x12, 0x01020304, (1, -2, 16384, -32768, 32767, 0, -1))
    assert len(frame) == FRAME_SIZE == 22
    assert frame[:2] == b'\xa5\x5a'
    assert frame[2] == 0x12
    assert frame[3:7] == bytes([4, 3, 2, 1])                   # t_us little-endian
    assert frame[7:9] == b'\x00\x01'                            # ax big-endian
    assert frame[9:11] == b'\xff\xfe'
    assert struct.unpack('>7h', frame[7:21]) == (1, -2, 16384, -32768, 32767, 0, -1)
    assert frame[21] == bitwise_crc8(frame[2:21])
    with pytest.raises(struct.error):
        encode_frame(0, 0, (40000, 0, 0, 0, 0, 0, 0))


def test_round_trip_with_wraps():
    frames = random_frames(600, np.random.default_rng(1), seq0=200)
    parser = FrameParser()
    assert parser.feed(encode_all(frames)) + parser.flush() == frames
    assert (parser.frames, parser.crc_errors, parser.lost_frames, parser.bytes_skipped) == \
        (600, 0, 0, 0)


def test_garbage_between_frames():
    rng = np.random.default_rng(2)
    frames = random_frames(200, rng)
    pieces = [b'\xa5\xa5\x5a\x00garbage\xa5']
    for f in frames:
        pieces.append(encode_frame(*f))
        pieces.append(rng.integers(0, 256, int(rng.integers(0, 30)), dtype=np.uint8).tobytes())
        pieces.append(b'\xa5\x5a' + bytes(5))           # a false sync cut short
    parser = FrameParser()
    out = parser.feed(b''.join(pieces)) + parser.flush()
    assert out == frames
    assert parser.lost_frames == 0
    assert parser.bytes_skipped > 0


def test_split_feeds_at_every_boundary():
    frames = random_frames(4, np.random.default_rng(3))
    data = b'\x00\xa5' + encode_all(frames) + b'\x5a\x11'
    for cut in range(len(data) + 1):
        parser = FrameParser()
        out = parser.feed(data[:cut]) + parser.feed(data[cut:]) + parser.flush()
        assert out == frames, cut
    parser = FrameParser()
    out = []
    for k in range(len(data)):
        out += parser.feed(data[k:k + 1])
    assert out + parser.flush() == frames
    assert parser.crc_errors == 0


def test_corruption_loses_no_intact_frame():
    """Two % of the bytes flipped over 20k frames: every untouched frame comes out."""
    rng = np.random.default_rng(4)
    frames = random_frames(20000, rng)
    clean = np.frombuffer(encode_all(frames), np.uint8)
    hit = np.flatnonzero(rng.random(len(clean)) < 0.02)
    data = clean.copy()
    data[hit] ^= rng.integers(1, 256, len(hit)).astype(np.uint8)
    damaged = set((hit // FRAME_SIZE).tolist())
    intact = [f for k, f in enumerate(frames) if k not in damaged]
    assert len(damaged) > 5000
    parser = FrameParser()
    out = []
    raw = data.tobytes()
    for k in range(0, len(raw), 997):              # odd chunk size: frames split too
        out += parser.feed(raw[k:k + 997])
    got = set(out + parser.flush())
    lost = [f for f in intact if f not in got]
    assert lost == []
    assert parser.crc_errors > 0
    bogus = len(got - set(frames))                  # corrupted frames whose CRC-8 passed
    assert bogus < len(damaged) / 100
    assert parser.lost_frames >= len(damaged) - bogus - 5


def test_sequence_gaps_counted_with_wrap():
    frames = random_frames(300, np.random.default_rng(5), seq0=250)
    keep = [f for k, f in enumerate(frames) if k not in (3, 4, 5, 100, 299 - 1)]
    parser = FrameParser()
    assert len(parser.feed(encode_all(keep)) + parser.flush()) == len(keep)
    assert parser.lost_frames == 5
    parser.reset()                               # after a reconnect: no gap across it
    parser.feed(encode_frame(77, 0, (0,) * 7))
    assert parser.lost_frames == 5


def test_ascii_lines_good_and_bad():
    parser = AsciiLineParser()
    text = (b'1,2,3,4,5,6,7\r\n'
            + encode_ascii_line((-1, -2, 16384, 100, 0, 0, -32768), t_us=4294967295)
            + b'\n   \n'
            + b'hello\n1,2,3\n1,2,3,4,5,6,7,8,9\n1,2,x,4,5,6,7\n40000,0,0,0,0,0,0\n'
            + b'\xff\xfe,1\n9, 8; 7 6,5,4,3\n1,2')
    out = []
    for k in range(0, len(text), 5):
        out += parser.feed(text[k:k + 5])
    assert out == [RawFrame(None, None, (1, 2, 3, 4, 5, 6, 7)),
                   RawFrame(None, 4294967295, (-1, -2, 16384, 100, 0, 0, -32768)),
                   RawFrame(None, None, (9, 8, 7, 6, 5, 4, 3))]
    assert parser.bad_lines == 6
    assert parser.feed(b',3,4,5,6,7\n') == [RawFrame(None, None, (1, 2, 3, 4, 5, 6, 7))]
    parser.feed(b'x' * 1000)                      # binary noise without newlines
    assert parser.bad_lines == 7 and len(parser._buf) == 0


@pytest.mark.parametrize('range_g, lsb', [(2, 16384), (4, 8192), (8, 4096), (16, 2048)])
def test_accel_conversion(range_g, lsb):
    conv = Converter(accel_range_g=range_g)
    assert accel_scale(range_g) == pytest.approx(G0 / lsb)
    (ax, ay, az), _, _ = conv.to_si((lsb, -lsb, lsb // 2, 0, 0, 0, 0))
    assert (ax, ay, az) == pytest.approx((G0, -G0, G0 / 2))
    assert conv.to_counts((G0, -G0, 100 * G0), 21.0, (0, 0, 0))[:3] == (lsb, -lsb, 32767)


@pytest.mark.parametrize('range_dps, lsb', [(250, 131), (500, 65.5), (1000, 32.8),
                                            (2000, 16.4)])
def test_gyro_conversion(range_dps, lsb):
    conv = Converter(gyro_range_dps=range_dps)
    assert gyro_scale(range_dps) == pytest.approx(math.radians(1) / lsb)
    _, _, (gx, gy, gz) = conv.to_si((0, 0, 0, 0, 1000, -1000, 0))
    assert gx == pytest.approx(math.radians(1000 / lsb)) and gy == -gx and gz == 0
    counts = conv.to_counts((0, 0, 0), 21.0, (math.radians(100), 0, -1e6))
    assert counts[4] == round(100 * lsb) and counts[6] == -32768


def test_temperature_and_array_conversion():
    assert temp_c(0) == 21.0
    assert temp_c(3338.7) == pytest.approx(31.0)
    conv = Converter(4, 500)
    counts = conv.to_counts((1.0, 2.0, 3.0), 35.5, (0.1, 0.2, 0.3))
    assert counts[3] == round(14.5 * 333.87)
    array = conv.to_counts_array([[1.0, 2.0, 3.0]], [35.5], [[0.1, 0.2, 0.3]])
    assert tuple(array[0].tolist()) == counts
    back = conv.to_si(counts)
    assert back[0] == pytest.approx((1.0, 2.0, 3.0), abs=conv.accel_scale)
    assert back[1] == pytest.approx(35.5, abs=0.01)


@pytest.mark.parametrize('kwargs, words', [({'accel_range_g': 3}, ['accelerometer', '2, 4']),
                                           ({'gyro_range_dps': 300}, ['gyroscope', '250']),
                                           ({'accel_range_g': 'big'}, ['accelerometer'])])
def test_unsupported_range(kwargs, words):
    with pytest.raises(ValueError) as err:
        Converter(**kwargs)
    for word in words:
        assert word in str(err.value)


def simulate_link(seconds, rate, drift_ppm, rng, jitter_s=0.004, t0_us=4_294_000_000):
    """Device sample times and host receive times with transport jitter and drift."""
    n = int(seconds * rate)
    dev_s = np.arange(n) / rate                        # true device clock
    true_host = 1.7e9 + 12.345 + dev_s * (1.0 + drift_ppm * 1e-6)
    delay = 0.001 + rng.exponential(jitter_s / 2, n) + rng.uniform(0, jitter_s, n)
    # USB-serial delivers in bursts: a sample waits for the next sample of its burst.
    burst_end = np.maximum.accumulate(true_host + delay)
    host = burst_end
    t_us = (t0_us + np.round(dev_s * 1e6).astype(np.int64)) & 0xFFFFFFFF
    return t_us, host, true_host


def test_clock_mapper_removes_jitter_and_tracks_drift():
    rng = np.random.default_rng(6)
    rate = 200.0
    t_us, host, true_host = simulate_link(120.0, rate, 50.0, rng)
    mapper = ClockMapper()
    stamps = np.array([mapper.update(int(t), float(h)) for t, h in zip(t_us, host)])
    assert mapper.resets == 0                         # the wrap is not a reset
    jitter = np.std(np.diff(host))
    assert jitter > 1e-3
    spacing_error = np.diff(stamps) - np.diff(true_host)
    assert np.std(spacing_error) < jitter / 50
    assert np.max(np.abs(spacing_error[int(5 * rate):])) < 2e-5
    error = stamps - true_host                        # constant part = minimum delay
    settled = error[int(40 * rate):]
    assert np.ptp(settled) < 5e-4                     # 50 ppm would be 4 ms over 80 s
    assert 0.0008 < np.median(settled) < 0.0015
    assert mapper.drift_ppm == pytest.approx(50.0, abs=15.0)


def test_clock_mapper_resets_on_device_reset():
    rng = np.random.default_rng(7)
    t_us, host, true_host = simulate_link(10.0, 100.0, 0.0, rng)
    mapper = ClockMapper()
    for t, h in zip(t_us, host):
        mapper.update(int(t), float(h))
    # The microcontroller reboots: its clock restarts at 0 one second later.
    later = host[-1] + 1.0
    stamp = mapper.update(0, later)
    assert mapper.resets == 1
    assert stamp == pytest.approx(later)
    assert mapper.update(10_000, later + 0.0105) == pytest.approx(later + 0.01, abs=1e-3)
    # A forward jump far beyond the host time elapsed is a reset too.
    mapper.update(10_000 + 3_000_000_000 // 2, later + 0.02)
    assert mapper.resets == 2


def sensor_frames(n, seq0=0, t0=1000, period=1000, temp=1335):
    return [RawFrame((seq0 + k) & 0xFF, (t0 + k * period) & 0xFFFFFFFF,
                     (10 * k, -5, 16384, temp, 3, -3, 0)) for k in range(n)]


def test_crc_valid_frame_that_does_not_continue_the_stream_is_rejected():
    """A CRC-valid candidate with a seq/t_us that do not fit (false sync, damage) is dropped."""
    frames = sensor_frames(10)
    fakes = [RawFrame(7, 123456, (1, 2, 3, 1335, 4, 5, 6)),           # t_us off
             RawFrame(200, frames[5].t_us + 500, (1, 2, 3, 1335, 4, 5, 6)),  # seq off
             RawFrame(frames[4].seq + 1, frames[4].t_us + 1000, (0, 0, 0, 30000, 0, 0, 0))]
    data = b''.join(encode_frame(*f) for f in frames[:5]) + \
        b''.join(encode_frame(*f) for f in fakes) + \
        b''.join(encode_frame(*f) for f in frames[5:])
    parser = FrameParser()
    assert parser.feed(data) + parser.flush() == frames
    assert parser.rejected == 3 and parser.lost_frames == 0


def test_relock_after_device_restart_and_long_gap():
    before = sensor_frames(5, seq0=100, t0=50_000_000)
    after = sensor_frames(5, seq0=0, t0=200)                            # clock restarted
    later = sensor_frames(5, seq0=77, t0=900_000_000)                   # 850 s later
    parser = FrameParser()
    out = parser.feed(b''.join(encode_frame(*f) for f in before + after + later))
    assert out + parser.flush() == before + after + later
    assert parser.lost_frames == 0


def test_temperature_plausibility():
    frames = sensor_frames(6)
    hot = frames[3]._replace(counts=frames[3].counts[:3] + (32000,) + frames[3].counts[4:])
    jump = frames[4]._replace(counts=frames[4].counts[:3] + (1335 + 3000,)
                              + frames[4].counts[4:])                   # +9 °C in 1 ms
    parser = FrameParser()
    out = parser.feed(b''.join(encode_frame(*f) for f in frames[:3] + [hot, jump] + frames[5:]))
    assert out + parser.flush() == frames[:3] + frames[5:]
    assert parser.lost_frames == 2 and parser.rejected == 2
    # An MPU-6050 at 25 °C reads -3920 counts: plausible for the default (any chip) range.
    cold = sensor_frames(3, temp=-3920)
    parser = FrameParser()
    assert parser.feed(b''.join(encode_frame(*f) for f in cold)) == cold


def test_optional_spike_check():
    """With spike_counts, a one-sample spike between agreeing neighbours is not published."""
    frames = sensor_frames(8)
    spiked = list(frames)
    spiked[4] = frames[4]._replace(counts=(frames[4].counts[0] + 8192,) + frames[4].counts[1:])
    data = b''.join(encode_frame(*f) for f in spiked)
    parser = FrameParser(spike_counts=SPIKE_COUNTS)
    out = parser.feed(data)
    assert out == frames[:4] + frames[5:7]                               # newest held back
    assert parser.flush() == [frames[7]]
    assert parser.rejected == 1 and parser.lost_frames == 1
    step = [f._replace(counts=(f.counts[0] + (8192 if k >= 4 else 0),) + f.counts[1:])
            for k, f in enumerate(frames)]                               # a real step: kept
    parser = FrameParser(spike_counts=SPIKE_COUNTS)
    assert parser.feed(b''.join(encode_frame(*f) for f in step)) + parser.flush() == step
    assert FrameParser().feed(data) + [] == spiked                      # default: no check


def test_mpu6050_temperature_formula():
    conv = Converter(temp_formula='mpu6050')
    assert conv.to_si((0, 0, 0, 340, 0, 0, 0))[1] == pytest.approx(37.53)
    assert conv.to_counts((0, 0, 0), 36.53, (0, 0, 0))[3] == 0
    with pytest.raises(ValueError):
        Converter(temp_formula='bmi160')


def test_badly_damaged_link_publishes_no_garbage():
    """At 20 % byte corruption CRC-8 collisions abound: only sandwiched frames go out."""
    rng = np.random.default_rng(12)
    frames = random_frames(60000, rng, period_us=1000)
    clean = np.frombuffer(encode_all(frames), np.uint8)
    hit = np.flatnonzero(rng.random(len(clean)) < 0.2)
    data = clean.copy()
    data[hit] ^= rng.integers(1, 256, len(hit)).astype(np.uint8)
    parser = FrameParser()
    raw = data.tobytes()
    out = []
    for k in range(0, len(raw), 4096):
        out += parser.feed(raw[k:k + 4096])
    out += parser.flush()
    assert parser.strict and parser.quality < 0.1
    sent = set(frames)
    assert all(f in sent for f in out)
    lenient = FrameParser(strict_below=None)        # without: collisions get through
    bad = [f for f in lenient.feed(raw) + lenient.flush() if f not in sent]
    assert len(bad) > 5
    clean_parser = FrameParser()
    clean_parser.feed(encode_all(frames[:2000]))
    assert not clean_parser.strict and clean_parser.quality > 0.9


def test_link_recovering_from_strict_mode_does_not_raise():
    """Regression: a frame held on a bad link was released as a tuple (AttributeError)."""
    rng = random.Random(1)
    parser = FrameParser()
    parser.feed(rng.randbytes(20000))                 # link quality falls: strict mode
    assert parser.strict
    out = []
    for start in range(0, 400, 10):                   # clean frames: quality recovers
        out += parser.feed(b''.join(encode_frame(k & 0xFF, 1000 * k, (0, 0, 16384, 0, 1, 2, 3))
                                    for k in range(start, start + 10)))
    assert not parser.strict
    stamps = [f.t_us for f in out]
    assert stamps == sorted(set(stamps)) and len(out) >= 390
    assert all(f.seq == (f.t_us // 1000) & 0xFF for f in out)     # only frames that were sent
