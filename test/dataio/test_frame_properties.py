"""Property-based tests (Hypothesis) of the binary frame parser, stateful included."""

import random

from accel_calib_ros.dataio.wire import encode, FRAME_SIZE, FrameParser, RawFrame
from hypothesis import given, HealthCheck, settings, strategies as st
from hypothesis.stateful import invariant, precondition, rule, RuleBasedStateMachine

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
    data = b''.join(encode(f) for f in frames)
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
        pieces.append(encode(f))
    parser = FrameParser()
    assert parser.feed(b''.join(pieces)) + parser.flush() == frames
    assert parser.lost_frames == 0


@PROFILE
@given(streams(min_frames=4), st.data())
def test_one_corrupted_byte_costs_one_frame_and_no_garbage(frames, data):
    """CRC-8 catches every single-byte error: only the hit frame is missing, and counted."""
    raw = bytearray(b''.join(encode(f) for f in frames))
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
    out = parser.feed(b''.join(encode(f) for f in kept)) + parser.flush()
    assert out == kept
    assert parser.lost_frames == len(drop)


class NoisyLink(RuleBasedStateMachine):
    """
    A device sending frames over a damaged link, and the parser reading it.

    Rules append clean frames to the wire, damage the bytes not yet read (bit flips, byte
    corruption, drops, insertions, bursts of random bytes, long runs of junk that swing
    the link quality), restart the device (new ``seq``/``t_us``, possibly the other frame
    version), reconnect (parser reset) and deliver the wire to the parser in random
    chunks. Invariants after every step: the parser never raised (``internal_errors``),
    every published frame is one that was sent, in the order sent, at most once (a
    version-1 frame whose CRC-8 collided in its data bytes, with sync, ``seq`` and ``t_us``
    intact, is the format's known floor and is tolerated; version-2 frames are damaged
    only where CRC-16 must catch it or by drops and insertions, and at most one CRC-16
    collision is tolerated), and the counters add up.
    """

    def __init__(self):
        super().__init__()
        self.parser = FrameParser()
        self.wire = bytearray()
        self.sent = {}                  # frame -> send index
        self.headers = {}               # (version, has mag, seq, t_us) -> send index
        self.published = []
        self.fed = 0
        self.version = 2
        self.seq = 0
        self.t_us = 4_294_000_000
        self.temp = 1335
        self.floor = {1: 0, 2: 0}

    def _frame(self, data, mag):
        axes = data.draw(st.lists(int16, min_size=6, max_size=6))
        self.temp = max(1300, min(1370, self.temp + data.draw(st.integers(-3, 3))))
        counts = tuple(axes[:3]) + (self.temp,) + tuple(axes[3:])
        if self.version == 1:
            frame = RawFrame(self.seq & 0xFF, self.t_us, counts)
        else:
            block = tuple(data.draw(st.lists(int16, min_size=3, max_size=3))) + (0x10,) \
                if mag else None
            frame = RawFrame(self.seq & 0xFFFF, self.t_us, counts, block, 2)
        self.seq += 1
        self.t_us = (self.t_us + 1000) & 0xFFFFFFFF
        index = len(self.sent)
        self.sent[frame] = index
        self.headers[(frame.version, frame.mag is not None, frame.seq, frame.t_us)] = index
        return frame

    def _feed(self, chunk):
        self.fed += len(chunk)
        self.published += self.parser.feed(bytes(chunk))

    @rule(n=st.integers(1, 12), mag=st.booleans(), data=st.data())
    def send(self, n, mag, data):
        for _ in range(n):
            self.wire += encode(self._frame(data, mag and data.draw(st.booleans())))

    @rule(data=st.data())
    def deliver(self, data):
        size = data.draw(st.integers(0, max(len(self.wire), 1)))
        chunk, self.wire = self.wire[:size], self.wire[size:]
        self._feed(chunk)

    @rule()
    def pause(self):
        """Flush the held frame, as the driver does when the port times out."""
        self.published += self.parser.flush()

    @precondition(lambda self: self.version == 2 and len(self.wire) >= 2)
    @rule(data=st.data())
    def flip_bits(self, data):
        """Flip up to 16 adjacent bits: a burst CRC-16 always detects."""
        at = data.draw(st.integers(0, len(self.wire) - 2))
        pattern = data.draw(st.integers(1, 0xFFFF))
        self.wire[at] ^= pattern >> 8
        self.wire[at + 1] ^= pattern & 0xFF

    @precondition(lambda self: self.version == 2 and self.wire)
    @rule(data=st.data())
    def corrupt_byte(self, data):
        at = data.draw(st.integers(0, len(self.wire) - 1))
        self.wire[at] ^= data.draw(st.integers(1, 255))

    @precondition(lambda self: self.version == 2 and self.wire)
    @rule(data=st.data())
    def drop_bytes(self, data):
        at = data.draw(st.integers(0, len(self.wire) - 1))
        del self.wire[at:at + data.draw(st.integers(1, 3))]

    @precondition(lambda self: self.version == 2)
    @rule(data=st.data())
    def insert_bytes(self, data):
        at = data.draw(st.integers(0, len(self.wire)))
        self.wire[at:at] = data.draw(st.binary(min_size=1, max_size=3))

    @precondition(lambda self: self.version == 2 and self.wire)
    @rule(data=st.data())
    def burst(self, data):
        """Replace 5..50 bytes with line noise."""
        at = data.draw(st.integers(0, len(self.wire) - 1))
        noise = data.draw(st.binary(min_size=5, max_size=50))
        self.wire[at:at + len(noise)] = noise

    @rule(data=st.data())
    def junk(self, data):
        """Send a long stretch of garbage (the link quality swings down)."""
        seed = data.draw(st.integers(0, 2 ** 32 - 1))
        size = data.draw(st.sampled_from([50, 600, 5000]))
        self.wire += random.Random(seed).randbytes(size)

    @rule(data=st.data(), version=st.sampled_from([1, 2]))
    def device_restart(self, data, version):
        """Restart the board: seq and its clock start anew (maybe another frame version)."""
        self._feed(self.wire)
        self.wire = bytearray()
        self.version = version
        self.seq = data.draw(st.integers(0, 0xFFFF))
        self.t_us = data.draw(st.integers(0, 2 ** 32 - 1))

    @rule()
    def reconnect(self):
        """Reopen the port: unread bytes are gone, the parser starts over."""
        self.wire = bytearray()
        self.published += self.parser.flush()
        self.parser.reset()

    @precondition(lambda self: self.version == 2)
    @rule(n=st.integers(2, 8), data=st.data())
    def clean_run_is_published(self, n, data):
        """Send a clean run of version-2 frames: after any damage it comes out whole."""
        self._feed(self.wire)
        self.wire = bytearray()
        run = [self._frame(data, data.draw(st.booleans())) for _ in range(n)]
        pieces = b''.join(encode(f) for f in run)
        cut = data.draw(st.integers(0, len(pieces)))
        self._feed(pieces[:cut])
        self._feed(pieces[cut:])
        self.published += self.parser.flush()
        got = set(self.published)
        assert all(f in got for f in run), (run, self.published[-n:])

    @invariant()
    def never_raises(self):
        assert self.parser.internal_errors == 0, self.parser.last_internal_error

    @invariant()
    def only_sent_frames_in_order_once(self):
        order = []
        for f in self.published:
            if f in self.sent:
                order.append(self.sent[f])
                continue
            key = (f.version, f.mag is not None, f.seq, f.t_us)
            assert key in self.headers, f'garbage published: {f}'
            order.append(self.headers[key])
        assert order == sorted(set(order)), 'out of order or twice'

    @invariant()
    def counters_consistent(self):
        p = self.parser
        c = p.counters()
        assert c['frames'] == len(self.published)
        assert c['frames_v1'] + c['frames_v2'] == c['frames']
        assert c['mag_frames'] == sum(f.mag is not None for f in self.published)
        assert c['bytes_in'] == self.fed
        assert 0 <= c['bytes_skipped'] <= c['bytes_in']
        assert min(c['crc_errors'], c['rejected'], c['lost_frames'], c['info_frames']) >= 0
        floor = {1: 0, 2: 0}
        for f in self.published:
            floor[f.version] += f not in self.sent
        assert floor[2] <= 1, 'more than one CRC-16 collision'
        assert 0.0 <= p.quality <= 1.0


NoisyLink.TestCase.settings = settings(max_examples=200, stateful_step_count=50, deadline=None,
                                       suppress_health_check=[HealthCheck.too_slow])
test_noisy_link = NoisyLink.TestCase
