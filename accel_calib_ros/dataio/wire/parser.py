"""
Incremental parser of the binary stream: data frames of versions 1 and 2, info frames.

ROS-free and hardware-free. :meth:`FrameParser.feed` takes whatever the port returned and
never raises: bad bytes are skipped and counted, and an unexpected error inside the parser
(a bug) is caught, counted in ``internal_errors`` and the parser starts afresh.
"""

import collections
import heapq
import math

from .chips import TEMP_FORMULAS
from .crc import crc16, CRC8_TABLE
from .frames import BLOCK, HEAD_V1, HEAD_V2, INT16_MAX, INT16_MIN, MAG, RawFrame
from .info import decode_info

TEMP_PLAUSIBLE_C = (-45.0, 95.0)
"""Temperatures a working sensor can report (operating range -40..85 °C plus margin)."""
TEMP_STEP_C = 4.0
"""Largest plausible temperature change between two samples close in time, °C."""
SPIKE_COUNTS = 2048
"""Suggested spike threshold (counts) for signals band-limited by the sensor's DLPF."""
STRICT_BELOW = 0.2
"""Link quality (share of the bytes in accepted frames) under which a version-1 frame needs
both neighbours: on a link this damaged, CRC-8 collisions would otherwise be published."""
QUALITY_WINDOW_FRAMES = 200
QUALITY_WINDOW_BYTES = 22 * QUALITY_WINDOW_FRAMES
MAX_GAP_S = 2.0
"""Longest gap (device seconds) bridged by the sequence check; longer needs re-locking."""
PERIOD_REL = 1e-4
"""Relative uncertainty of the measured sample period when a gap is counted in periods."""
LONG_GAP_TOL_S = 10.0
"""A gap over :data:`MAX_GAP_S` is counted only when its device time agrees with the host
time between the two frames' arrival within this (plus 2 %): a device restart does not."""
TIGHT_US = 20.0
TIGHT_REL = 1e-4
"""Timing tolerance of an interrupt-stamped firmware: 20 µs + 100 ppm of the interval (the
period is measured over the last 512 frames, so only the sensor clock's short-term wander
against the microcontroller's remains; a long gap on a bad link gets no wide window for a
damaged ``t_us`` to fall into)."""
JITTER_WINDOW = 64
"""Accepted frames over which the stream's own timing jitter is measured."""
JITTER_MIN_FRAMES = 8
PERIOD_WINDOW = 512
"""Frames over which the sample period is measured (a long base averages the jitter out)."""
OVERLAP = 4
"""Bytes at the end of an accepted frame searched for the next sync (dropped bytes)."""
PENDING = 6

_KINDS = {0x5A: (22, 1), 0x49: (22, 0), 0x4A: (34, 0)}   # second sync byte: size, version


def temp_counts_range(lsb_per_c=None, offset_c=None):
    """
    Plausible raw temperature counts for a chip's formula (both formulas when None).

    :return: (low, high) counts.
    """
    formulas = list(TEMP_FORMULAS.values()) if lsb_per_c is None else [(lsb_per_c, offset_c)]
    lo = min((TEMP_PLAUSIBLE_C[0] - off) * lsb for lsb, off in formulas)
    hi = max((TEMP_PLAUSIBLE_C[1] - off) * lsb for lsb, off in formulas)
    return max(int(lo), INT16_MIN), min(int(hi), INT16_MAX)


class FrameParser:
    """
    Incremental parser of the binary frame stream; never raises.

    Reads frame versions 1 (``0xA5 0x5A``, CRC-8) and 2 (``0xA5 0x5B``, CRC-16, optional
    AK8963 block) in any mix, and the info frames of both layouts (collected in ``infos``).
    A candidate (sync word, valid flags, valid check value) is published only when it is
    also plausible:

    - its temperature lies in the physical range (``temp_range``);
    - it continues the stream: ``seq`` and ``t_us`` agree with the last accepted frame of
      the same version (version 1: the ``t_us`` gap is n sample periods with n ≡ the
      ``seq`` gap modulo 256; version 2: n is the ``seq`` gap itself) and the temperature
      moved less than :data:`TEMP_STEP_C`;
    - after a resynchronisation (start, reconnect, device restart or a gap over
      :data:`MAX_GAP_S`) a frame is confirmed by a later candidate that continues it
      (within 16 samples for version 1, 4096 for version 2, at a rate of 1 Hz..20 kHz);
    - optionally (``spike_counts``, off by default because it assumes a band-limited
      signal) it is not a one-sample spike larger than ``spike_counts`` on an axis
      between two adjacent neighbours that agree with each other; the newest frame is then
      held until the next one arrives (or :meth:`flush` is called);
    - version 1 only, on a badly damaged link (``quality``, the share of the recent bytes
      that belonged to accepted frames, below ``strict_below``: about 10 % of the bytes
      corrupted): a frame is published only when both of its neighbours in the byte
      stream are accepted frames that continue it (a CRC-8 collision then needs two more
      valid frames around it). CRC-16 does not need this.

    Timing: the tolerance on ``t_us`` is the stream's own precision. An interrupt-stamped
    firmware (the normal case) keeps it at 20 µs + 100 ppm; a firmware that stamps at read
    time (host-side jitter) widens it to 1.5 times the jitter measured over the last 64
    frames (the second-largest deviation, so one odd frame does not widen it), up to 45 %
    (version 1, whose ``seq`` is ambiguous beyond) or 95 % (version 2) of a period. A frame
    whose check value passes and that continues ``seq`` is therefore not lost for jitter;
    frames whose ``t_us`` deviated beyond 20 µs + 100 ppm are counted in ``timing_jitter``.
    Until 8 deviations are known (after a re-lock) the window is 45 % of a period.

    Resynchronisation: after a failed candidate the scan resumes one byte after its sync,
    inside its own bytes; after an accepted frame it resumes :data:`OVERLAP` bytes before
    its end (a frame that lost bytes is followed by a sync inside its own length), so one
    damaged or shortened frame never costs the intact frame after it.

    Counters: ``frames`` (published; ``frames_v1``, ``frames_v2``, ``mag_frames``),
    ``crc_errors`` (candidates whose check value or flags failed), ``rejected`` (valid
    candidates that were implausible or never confirmed), ``bytes_skipped`` (bytes not
    part of a published, held or info frame), ``lost_frames`` (samples missing between
    published frames, from ``seq`` and ``t_us`` at the measured rate: across re-locks,
    resets and, with host times, gaps of any length), ``gaps_uncounted`` (gaps whose loss
    cannot be told: a device restart, a change of frame version or rate), ``info_frames``,
    ``bytes_in``, ``timing_jitter``, ``internal_errors`` (bugs caught; 0 unless something
    is wrong).

    :param temp_range: (low, high) plausible temperature counts (default: any chip).
    :param spike_counts: spike threshold in counts, e.g. :data:`SPIKE_COUNTS` (None: no
        spike check).
    :param strict_below: quality under which version-1 frames need both neighbours (None:
        never).
    """

    PENDING = PENDING

    def __init__(self, temp_range=None, spike_counts=None, strict_below=STRICT_BELOW):
        self._buf = bytearray()
        self.temp_range = temp_range or temp_counts_range()
        self.spike_counts = spike_counts
        self.strict_below = strict_below
        self.quality = 1.0
        self.infos = []
        self.frames = 0
        self.frames_v1 = 0
        self.frames_v2 = 0
        self.mag_frames = 0
        self.crc_errors = 0
        self.rejected = 0
        self.lost_frames = 0
        self.gaps_uncounted = 0
        self.info_frames = 0
        self.bytes_in = 0
        self.timing_jitter = 0
        self.internal_errors = 0
        self.last_internal_error = ''
        self.version = None
        self.period_us = None
        self._last_period = None
        self._host = None           # host time of the bytes being parsed (feed's host_s)
        self._last_out = None       # the last published frame: the baseline of the loss
        self._last_out_host = None  # and the host time it came in
        self._consumed = 0          # bytes deleted from the buffer: absolute position of buf[0]
        self._covered = 0           # bytes that belonged to published or info frames
        self._covers = collections.deque(maxlen=16)
        self._tail_end = 0
        self._accepted_bytes = 0
        self.reset()

    # -- state ---------------------------------------------------------------------------

    def reset(self):
        """
        Forget the partial frame and the sequence (its state is suspect); keep counters.

        The last published frame stays the baseline of the loss count: the samples missing
        between it and the next one published are counted, across the reset too.
        """
        self._consumed += len(self._buf)
        self._buf.clear()
        self._ref = None            # last accepted frame
        self._ref_at = (0, 0.0)     # its unwrapped (sample index, device µs)
        self._older = []            # the two references before it, with their positions
        self._pending = []          # (frame, start, end): valid candidates not yet confirmed
        self._held = None           # (frame, adjacent, start, end)
        self._last_end = None
        self._restart_timing()

    def _restart_timing(self):
        if self.period_us:
            self._last_period = self.period_us
        self.period_us = None
        self._hist = collections.deque(maxlen=PERIOD_WINDOW)
        self._devs = collections.deque(maxlen=JITTER_WINDOW)
        self._jitter = None

    @property
    def last_seq(self):
        """``seq`` of the last accepted frame (None before the first)."""
        return None if self._ref is None else self._ref.seq

    @property
    def strict(self):
        """Whether version-1 frames currently need both neighbours (badly damaged link)."""
        return self.strict_below is not None and self.quality < self.strict_below

    @property
    def jitter_us(self):
        """Return the timing jitter: second-largest recent |Δt − n·period|, µs (or None)."""
        return self._jitter

    @property
    def bytes_skipped(self):
        """Bytes consumed that were not part of a published, held or info frame."""
        held = 0 if self._held is None else self._held[3] - self._held[2]
        return max(self._consumed - self._covered - held, 0)

    def counters(self):
        """Return the counters as a dict."""
        return {'frames': self.frames, 'crc_errors': self.crc_errors,
                'rejected': self.rejected, 'bytes_skipped': self.bytes_skipped,
                'lost_frames': self.lost_frames, 'gaps_uncounted': self.gaps_uncounted,
                'info_frames': self.info_frames,
                'bytes_in': self.bytes_in, 'frames_v1': self.frames_v1,
                'frames_v2': self.frames_v2, 'mag_frames': self.mag_frames,
                'timing_jitter': self.timing_jitter, 'internal_errors': self.internal_errors}

    def take_infos(self):
        """Return and forget the info frames received since the last call."""
        infos, self.infos = self.infos, []
        return infos

    # -- plausibility --------------------------------------------------------------------

    def _tolerance(self, dt, period, version):
        """Largest accepted |Δt − n·period|, µs, for an interval of ``dt`` µs."""
        jitter = self._jitter
        extra = 0.45 * period if jitter is None else 1.5 * jitter
        return TIGHT_US + TIGHT_REL * dt + min(extra, (0.45 if version == 1 else 0.95) * period)

    def _gap(self, a, b, period):
        """
        Return the samples from frame ``a`` to ``b`` (>= 1); 0 when ``b`` does not continue ``a``.

        :param period: sample period in µs, or None (then only a short gap is accepted).
        """
        if a.version != b.version:
            return 0
        dt = (b.t_us - a.t_us) & 0xFFFFFFFF
        if dt == 0 or dt > MAX_GAP_S * 1e6:
            return 0
        dseq = (b.seq - a.seq) & (0xFF if b.version == 1 else 0xFFFF)
        if period is None:              # re-locking: a short gap at a plausible rate
            if not 1 <= dseq <= (16 if b.version == 1 else 4096) or \
                    not 50.0 <= dt / dseq <= 1e6:
                return 0
            n = dseq
        else:
            if b.version == 1:
                n = int(dt / period + 0.5)
                if n < 1 or (n & 0xFF) != dseq:
                    return 0
            else:
                n = dseq
                if n == 0:
                    return 0
            if abs(dt - n * period) > self._tolerance(dt, period, b.version):
                return 0
        if abs(b.counts[3] - a.counts[3]) > (TEMP_STEP_C + dt * 1e-6) * 340.0:
            return 0
        return n

    def _loss(self, prev, frame):
        """
        Return the samples missing between two published frames.

        The gap is counted in sample periods of the measured rate (the current one, or the
        one before a re-lock): the number n of periods in the ``t_us`` gap, within the
        period's uncertainty, that agrees with the ``seq`` gap modulo its width (256 for
        version 1, 65536 for version 2) counts n - 1 lost samples when it is the only such
        n. A gap over :data:`MAX_GAP_S` also needs the host times of both frames to agree
        with it (so a device restart is not counted). Anything else (no rate measured yet,
        another frame version, several or no such n) counts nothing and is counted in
        ``gaps_uncounted``.
        """
        period = self.period_us or self._last_period
        if period is None or prev.version != frame.version:
            self.gaps_uncounted += 1
            return 0
        n = self._gap(prev, frame, period)
        if n:
            return n - 1
        dt = (frame.t_us - prev.t_us) & 0xFFFFFFFF
        if dt > MAX_GAP_S * 1e6:
            host, host0 = self._host, self._last_out_host
            if host is None or host0 is None or \
                    abs(dt * 1e-6 - (host - host0)) > 0.02 * (host - host0) + LONG_GAP_TOL_S:
                self.gaps_uncounted += 1
                return 0
        width = 0x100 if frame.version == 1 else 0x10000
        x = dt / period
        spread = (0.45 if frame.version == 1 else 1.0) + x * PERIOD_REL
        dseq = (frame.seq - prev.seq) % width
        lo = max(math.ceil(x - spread), 1)
        first = lo + (dseq - lo) % width               # the smallest n >= lo, n = dseq mod
        if first > x + spread or first + width <= x + spread:
            self.gaps_uncounted += 1                   # none, or more than one
            return 0
        return first - 1

    def _advance(self, ref, frame, n):
        """Return the unwrapped position of an accepted frame; update period and jitter."""
        if ref is None or not n:
            self._hist.clear()
            self._hist.append((0, 0.0))
            return (0, 0.0)
        dt = (frame.t_us - ref.t_us) & 0xFFFFFFFF
        period = self.period_us
        if period is not None:
            dev = abs(dt - n * period)
            self._devs.append(dev)
            if dev > TIGHT_US + TIGHT_REL * dt:
                self.timing_jitter += 1
            if len(self._devs) >= JITTER_MIN_FRAMES:
                self._jitter = heapq.nlargest(2, self._devs)[-1]
        at = (self._ref_at[0] + n, self._ref_at[1] + dt)
        hist = self._hist
        hist.append(at)
        i0, t0 = hist[0]
        if at[0] > i0:
            self.period_us = (at[1] - t0) / (at[0] - i0)
        return at

    # -- accepting and releasing ---------------------------------------------------------

    def _accept(self, frame, n, out, start, end):
        """Take a frame that continues the stream n samples after the reference; release."""
        adjacent = n == 1 and self._last_end == start
        self._last_end = end
        self._tail_end = max(self._tail_end, end)
        self._accepted_bytes += end - start
        ref = self._ref
        at = self._advance(ref, frame, n)
        if ref is not None:
            self._older = (self._older + [(ref, self._ref_at)])[-2:]
        self._ref, self._ref_at = frame, at
        self.version = frame.version
        self.rejected += len(self._pending)     # candidates that never continued the stream
        self._pending = []
        item = (frame, adjacent, start, end)
        held = self._held
        if self.spike_counts is None and not (self.strict and frame.version == 1):
            self._held = None
            if held is not None:                 # held while the link was bad
                self._release(held, frame, out, False)
            self._release(item, None, out, True)
            return
        self._held = item
        if held is not None:
            self._release(held, frame, out, held[1] and adjacent)

    def _release(self, item, following, out, sandwiched):
        frame, _, start, end = item
        if self.strict and frame.version == 1 and not sandwiched:
            self.rejected += 1
            return
        prev = self._last_out
        if self.spike_counts is not None and prev is not None and following is not None \
                and self._is_spike(prev, frame, following):
            self.rejected += 1
            return
        if prev is not None:
            self.lost_frames += self._loss(prev, frame)
        self._last_out = frame
        self._last_out_host = self._host
        self._cover(start, end)
        out.append(frame)

    def _cover(self, start, end):
        # Frames may overlap (a shortened frame's next sync) and a confirmed candidate may
        # come after an info frame that followed it: count each byte once.
        new = end - start
        for s, e in self._covers:
            new -= max(0, min(e, end) - max(s, start))
        self._covered += max(new, 0)
        self._covers.append((start, end))

    def _is_spike(self, prev, frame, following):
        limit = self.spike_counts
        period = self.period_us
        if period is None:
            return False
        for a, b in ((prev, frame), (frame, following)):
            if not 1 <= ((b.t_us - a.t_us) & 0xFFFFFFFF) / period < 2.5:
                return False                     # neighbours not adjacent: no verdict
        axes = (0, 1, 2, 4, 5, 6)
        p, c, f = prev.counts, frame.counts, following.counts
        if any(abs(f[k] - p[k]) > limit // 2 for k in axes):
            return False                         # neighbours disagree: no verdict
        return any(abs(c[k] - (p[k] + f[k]) / 2) > limit for k in axes)

    def _count(self, out):
        self.frames += len(out)
        for frame in out:
            if frame.version == 2:
                self.frames_v2 += 1
                if frame.mag is not None:
                    self.mag_frames += 1
            else:
                self.frames_v1 += 1

    def _internal_error(self, err):
        self.internal_errors += 1
        self.last_internal_error = f'{type(err).__name__}: {err}'
        try:
            self.reset()
        except Exception:               # noqa: B902 - a reset must not raise either
            self._buf = bytearray()
            self._ref = None
            self._pending = []
            self._held = None

    def flush(self):
        """
        Release the held newest frame (call when the stream pauses, e.g. on a read timeout).

        :return: list of RawFrame (0 or 1).
        """
        try:
            out = []
            held, self._held = self._held, None
            if held is not None:
                self._release(held, None, out, False)
            self._count(out)
            return out
        except Exception as err:        # noqa: B902 - never raise on data
            self._internal_error(err)
            return []

    # -- scanning ------------------------------------------------------------------------

    def feed(self, data, host_s=None):
        """
        Parse more bytes; never raises.

        :param data: bytes-like object, any length (may be empty).
        :param host_s: host time the bytes came in, s (None: unknown); with it a gap over
            :data:`MAX_GAP_S` can be counted (its device time checked against host time).
        :return: list of RawFrame, in stream order (a held frame comes out later).
        """
        try:
            self._host = host_s
            return self._feed(data)
        except Exception as err:        # noqa: B902 - never raise on data
            self._internal_error(err)
            return []

    def _feed(self, data):
        buf = self._buf
        buf += data
        self.bytes_in += len(data)
        n = len(buf)
        out = []
        pos = 0
        table = CRC8_TABLE
        find = buf.find
        lo, hi = self.temp_range
        crc_errors = 0
        self._accepted_bytes = 0
        base = self._consumed
        while True:
            i = find(0xA5, pos)
            if i < 0 or i + 1 >= n:
                pos = n if i < 0 else i          # keep a trailing 0xA5
                break
            kind = buf[i + 1]
            tail = base + i < self._tail_end     # inside the last accepted frame's bytes
            if kind == 0x5B:
                if i + 2 >= n:
                    pos = i
                    break
                flags = buf[i + 2]
                if flags & 0xFE:                 # reserved flag bits: not a frame
                    crc_errors += not tail
                    pos = i + 1
                    continue
                size, version = (32 if flags & 1 else 25), 2
            elif kind in _KINDS:
                size, version = _KINDS[kind]
            else:
                pos = i + 1
                continue
            end = i + size
            if end > n:
                pos = i
                break
            if size == 22:
                crc = 0
                for k in range(i + 2, end):
                    crc = table[crc ^ buf[k]]
                valid = crc == 0                 # the CRC byte itself included
            else:
                valid = crc16(buf[i + 2:end - 2]) == buf[end - 2] | (buf[end - 1] << 8)
            if not valid:
                crc_errors += not tail
                pos = i + 1
                continue
            start, stop = base + i, base + end
            if version == 0:
                info = decode_info(bytes(buf[i:end]))
                if info is None:
                    pos = i + 1
                    continue
                self.infos.append(info)
                self.info_frames += 1
                self._cover(start, stop)
                pos = end
                continue
            if version == 1:
                seq, t_us = HEAD_V1.unpack_from(buf, i + 2)
                frame = RawFrame(seq, t_us, BLOCK.unpack_from(buf, i + 7))
            else:
                _, seq, t_us = HEAD_V2.unpack_from(buf, i + 2)
                frame = RawFrame(seq, t_us, BLOCK.unpack_from(buf, i + 9),
                                 MAG.unpack_from(buf, i + 23) if size == 32 else None, 2)
            if not lo <= frame.counts[3] <= hi:
                self.rejected += not tail
                pos = i + 1
                continue
            gap = self._continuation(frame)
            if gap:
                self._accept(frame, gap, out, start, stop)
                pos = max(end - OVERLAP, i + 1)
                continue
            if tail:                             # a coincidence inside an accepted frame
                pos = i + 1
                continue
            if self._confirm(frame, out, start, stop):
                pos = max(end - OVERLAP, i + 1)
                continue
            self._pending.append((frame, start, stop))
            if len(self._pending) > self.PENDING:
                del self._pending[0]
                self.rejected += 1
            pos = i + 1
        del buf[:pos]
        self._consumed += pos
        if pos:
            weight = pos / (pos + QUALITY_WINDOW_BYTES)
            self.quality += weight * (min(self._accepted_bytes / pos, 1.0) - self.quality)
        self._count(out)
        self.crc_errors += crc_errors
        return out

    def _continuation(self, frame):
        """Return the samples from the reference to ``frame`` (0: it does not continue)."""
        ref = self._ref
        if ref is None:
            return 0
        gap = self._gap(ref, frame, self.period_us)
        if gap:
            return gap
        # The newest reference may itself be a collision whose t_us was hit within
        # tolerance: a frame that continues an older reference is good.
        for older, at in reversed(self._older):
            gap = self._gap(older, frame, self.period_us)
            if gap and (frame.t_us - ref.t_us) & 0x80000000 == 0:
                self._ref, self._ref_at = older, at
                return gap
        return 0

    def _confirm(self, frame, out, start, end):
        """Re-lock on ``frame`` and a pending candidate it continues; return True if so."""
        confirmed = None
        for cand in reversed(self._pending):
            if self._gap(cand[0], frame, None):
                confirmed = cand
                break
        if confirmed is None:
            return False
        chain = [confirmed]                      # with the earlier ones that lead up to it
        for cand in reversed(self._pending[:self._pending.index(confirmed)]):
            if self._gap(cand[0], chain[0][0], None):
                chain.insert(0, cand)
        self.rejected += len(self._pending) - len(chain)
        self._pending = []
        self._ref = None
        self._older = []
        self._restart_timing()
        for k, (cand, cand_start, cand_end) in enumerate(chain):
            gap = self._gap(chain[k - 1][0], cand, None) if k else 0
            self._accept(cand, gap, out, cand_start, cand_end)
        self._accept(frame, self._gap(confirmed[0], frame, None), out, start, end)
        return True
