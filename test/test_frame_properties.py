"""Property-based tests (Hypothesis) of the binary frame parser."""

from accel_calib_ros.dataio.mpu9250_frame import encode_frame, FRAME_SIZE, FrameParser, RawFrame
from hypothesis import given, HealthCheck, settings, strategies as st

PROFILE = settings(max_examples=150, deadline=None,
                   suppress_health_check=[HealthCheck.too_slow])

int16 = st.integers(-32768, 32767)
temp = st.integers(-5000, 15000)                            # -0 .. 66 °C on an MPU-9250


@st.composite
def streams(draw, min_frames=3, max_frames=40):
    """Draw a contiguous stream of frames with consecutive seq and t_us (wraps included)."""
    n = draw(st.integers(min_frames, max_frames))
    seq0 = draw(st.integers(0, 255))
    t0 = draw(st.integers(0, 2 ** 32 - 1))
    period = draw(st.sampled_from([1000, 2000, 5000, 10000]))
    t = draw(st.integers(-200, 200))
    frames = []
    for k in range(n):
        axes = draw(st.lists(int16, min_size=6, max_size=6))
        t = max(-5000, min(15000, t + draw(st.integers(-40, 40))))
        frames.append(RawFrame((seq0 + k) & 0xFF, (t0 + k * period) & 0xFFFFFFFF,
                               tuple(axes[:3]) + (t,) + tuple(axes[3:])))
    return frames


def feed_in_chunks(parser, data, cuts):
    out = []
    start = 0
    for cut in sorted({c % (len(data) + 1) for c in cuts}) + [len(data)]:
        out += parser.feed(data[start:cut])
        start = cut
    return out + parser.flush()


@PROFILE
@given(st.binary(max_size=600), st.lists(st.integers(0, 10 ** 6), max_size=8))
def test_arbitrary_bytes_never_raise(data, cuts):
    parser = FrameParser()
    out = feed_in_chunks(parser, data, cuts)
    c = parser.counters()
    assert c['bytes_in'] == len(data)
    assert len(out) == c['frames'] <= len(data) // FRAME_SIZE
    assert c['bytes_skipped'] >= 0 and c['lost_frames'] >= 0


@PROFILE
@given(streams(), st.lists(st.integers(0, 10 ** 6), max_size=10))
def test_round_trip_any_chunking(frames, cuts):
    data = b''.join(encode_frame(*f) for f in frames)
    parser = FrameParser()
    assert feed_in_chunks(parser, data, cuts) == frames
    assert (parser.crc_errors, parser.lost_frames, parser.rejected, parser.bytes_skipped) == \
        (0, 0, 0, 0)


@PROFILE
@given(streams(), st.data())
def test_garbage_between_frames_loses_nothing(frames, data):
    """Bytes without a sync byte between frames: every frame comes out, in order."""
    pieces = []
    for f in frames:
        pieces.append(data.draw(st.binary(max_size=30).map(lambda b: b.replace(b'\xa5', b'\x00'))))
        pieces.append(encode_frame(*f))
    parser = FrameParser()
    assert parser.feed(b''.join(pieces)) + parser.flush() == frames
    assert parser.lost_frames == 0


@PROFILE
@given(streams(min_frames=4), st.data())
def test_one_corrupted_byte_costs_one_frame_and_no_garbage(frames, data):
    """CRC-8 catches every single-byte error: only the hit frame is missing, and counted."""
    raw = bytearray(b''.join(encode_frame(*f) for f in frames))
    where = data.draw(st.integers(0, len(raw) - 1))
    raw[where] ^= data.draw(st.integers(1, 255))
    hit = where // FRAME_SIZE
    parser = FrameParser()
    out = parser.feed(bytes(raw)) + parser.flush()
    assert out == frames[:hit] + frames[hit + 1:]
    assert parser.lost_frames == (1 if 0 < hit < len(frames) - 1 else 0)


@PROFILE
@given(streams(min_frames=6), st.data())
def test_dropped_frames_counted_from_seq_and_t_us(frames, data):
    drop = data.draw(st.sets(st.integers(1, len(frames) - 2), max_size=len(frames) // 3))
    kept = [f for k, f in enumerate(frames) if k not in drop]
    parser = FrameParser()
    out = parser.feed(b''.join(encode_frame(*f) for f in kept)) + parser.flush()
    assert out == kept
    assert parser.lost_frames == len(drop)
