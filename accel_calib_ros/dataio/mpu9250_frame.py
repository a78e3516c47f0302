"""
MPU9250 serial wire format: frames, parsers, unit conversions and clock mapping.

ROS-free and hardware-free, so it can be tested and benchmarked on its own. The binary
frame (interface spec section 1) is 22 bytes::

    0xA5 0x5A | seq u8 | t_us u32 LE | ax ay az temp gx gy gz (7 x i16 BE) | crc8

CRC-8 with polynomial 0x07, init 0, no reflection and no final xor, over bytes 2..20.
"""

import math
import re
import struct
from typing import NamedTuple, Optional, Tuple

G0 = 9.80665
"""Standard gravity, m/s² (the unit of the accelerometer's full-scale range)."""
SYNC = b'\xa5\x5a'
FRAME_SIZE = 22
ACCEL_LSB_PER_G = {2: 16384.0, 4: 8192.0, 8: 4096.0, 16: 2048.0}
"""Accelerometer sensitivity per full-scale range (±g), counts per g."""
GYRO_LSB_PER_DPS = {250: 131.0, 500: 65.5, 1000: 32.8, 2000: 16.4}
"""Gyroscope sensitivity per full-scale range (±°/s), counts per °/s."""
TEMP_LSB_PER_C = 333.87
TEMP_OFFSET_C = 21.0
TEMP_FORMULAS = {'mpu6500': (333.87, 21.0), 'mpu6050': (340.0, 36.53)}
"""Temperature count per °C and offset: MPU-6500/9250/9255 and MPU-6050 families."""
INT16_MIN, INT16_MAX = -32768, 32767

_HEAD = struct.Struct('<BI')
_BLOCK = struct.Struct('>7h')
_ASCII_SPLIT = re.compile(r'[,;\s]+')


def _make_table():
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = ((crc << 1) ^ 0x07) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table.append(crc)
    return tuple(table)


CRC8_TABLE = _make_table()


def crc8(data):
    """
    CRC-8 (polynomial 0x07, init 0, no reflection, no final xor) of ``data``.

    :param data: bytes-like object.
    :return: int in 0..255.
    """
    table = CRC8_TABLE
    crc = 0
    for byte in data:
        crc = table[crc ^ byte]
    return crc


class RawFrame(NamedTuple):
    """
    One sample as it came off the wire, in raw counts.

    :param seq: frame counter 0..255 (None for ASCII lines).
    :param t_us: device clock in µs, uint32 (None when the source does not send it).
    :param counts: seven ints (ax, ay, az, temp, gx, gy, gz).
    """

    seq: Optional[int]
    t_us: Optional[int]
    counts: Tuple[int, ...]


def encode_frame(seq, t_us, counts):
    """
    Encode one binary frame.

    :param seq: frame counter (taken modulo 256).
    :param t_us: device clock in µs (taken modulo 2**32).
    :param counts: seven int16 counts (ax, ay, az, temp, gx, gy, gz).
    :return: 22 bytes.
    :raises struct.error: a count is outside int16.
    """
    body = _HEAD.pack(int(seq) & 0xFF, int(t_us) & 0xFFFFFFFF) + \
        _BLOCK.pack(*(int(c) for c in counts))
    return SYNC + body + bytes((crc8(body),))


class InfoFrame(NamedTuple):
    """
    The firmware's info frame (docs/firmware.md): what the board found and configured.

    :param status: 0 streaming, 1 unknown chip, 2 no sensor answer, 3 configuration failed.
    :param who_am_i: the sensor's WHO_AM_I register (0 when nothing answered).
    :param accel_range_g: accelerometer full scale, ±g.
    :param gyro_range_dps: gyroscope full scale, ±°/s.
    :param rate_hz: configured sample rate, Hz.
    :param dlpf_cfg: CONFIG.DLPF_CFG.
    :param baud: UART baud rate the firmware was built for.
    :param fw_version: (major, minor).
    """

    status: int
    who_am_i: int
    accel_range_g: int
    gyro_range_dps: int
    rate_hz: int
    dlpf_cfg: int
    baud: int
    fw_version: Tuple[int, int]

    @property
    def chip(self):
        """Chip name from WHO_AM_I ('unknown (0x..)' otherwise)."""
        return CHIPS.get(self.who_am_i, f'unknown (0x{self.who_am_i:02x})')

    @property
    def status_text(self):
        """Return the status in words."""
        return INFO_STATUS.get(self.status, f'status {self.status}')


INFO_SYNC = b'\xa5\x49'
INFO_MAGIC = b'ACFW'
INFO_VERSION = 1
INFO_STATUS = {0: 'streaming', 1: 'unknown chip (WHO_AM_I not recognised): not streaming',
               2: 'no sensor answers at I2C address 0x68: not streaming',
               3: 'sensor did not accept its configuration: not streaming'}
CHIPS = {0x71: 'MPU-9250', 0x73: 'MPU-9255', 0x70: 'MPU-6500', 0x68: 'MPU-6050'}
"""WHO_AM_I values of the supported chips."""
_INFO = struct.Struct('<BBBBHHBIBB4s')

TEMP_PLAUSIBLE_C = (-45.0, 95.0)
"""Temperatures a working sensor can report (operating range -40..85 °C plus margin)."""
TEMP_STEP_C = 4.0
"""Largest plausible temperature change between two samples close in time, °C."""
SPIKE_COUNTS = 2048
"""Suggested spike threshold (counts) for signals band-limited by the sensor's DLPF."""
STRICT_BELOW = 0.2
"""Link quality (share of the bytes in accepted frames) under which a frame needs both
neighbours: on a link this damaged, CRC-8 collisions would otherwise be published."""
QUALITY_WINDOW_FRAMES = 200
MAX_GAP_S = 2.0
"""Longest gap (device seconds) bridged by the sequence check; longer needs re-locking."""


def encode_info(info):
    """
    Encode an info frame (22 bytes) from an :class:`InfoFrame`.

    :param info: InfoFrame.
    :return: bytes.
    """
    body = _INFO.pack(INFO_VERSION, info.status, info.who_am_i, info.accel_range_g,
                      info.gyro_range_dps, info.rate_hz, info.dlpf_cfg, info.baud,
                      info.fw_version[0], info.fw_version[1], INFO_MAGIC)
    return INFO_SYNC + body + bytes((crc8(body),))


def decode_info(frame):
    """
    Decode a 22-byte info frame.

    :param frame: bytes starting with the info sync.
    :return: InfoFrame, or None when it is not a valid info frame.
    """
    if len(frame) < FRAME_SIZE or frame[:2] != INFO_SYNC or crc8(frame[2:FRAME_SIZE]) != 0:
        return None
    (version, status, who, accel, gyro, rate, dlpf, baud, major, minor,
     magic) = _INFO.unpack_from(frame, 2)
    if version != INFO_VERSION or magic != INFO_MAGIC:
        return None
    return InfoFrame(status, who, accel, gyro, rate, dlpf, baud, (major, minor))


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
    Incremental parser of the binary frame stream; never raises on bad bytes.

    Feed it whatever the port returned; it keeps a cut-off frame for the next call. A
    candidate (sync word, CRC-8 valid) is published only when it is also plausible:

    - its temperature lies in the physical range (``temp_range``);
    - it continues the stream: ``seq`` and ``t_us`` agree with the last accepted frame
      (``t_us`` gap = n sample periods with n = ``seq`` gap modulo 256, to 0.2 %), the
      temperature moved less than :data:`TEMP_STEP_C`;
    - after a resynchronisation (start, reconnect, device restart or a long gap) a
      frame is confirmed by a later candidate that continues it in the same way;
    - optionally (``spike_counts``, off by default because it assumes a band-limited
      signal) it is not a one-sample spike larger than ``spike_counts`` on an axis
      between two adjacent neighbours that agree with each other on all six axes; the
      newest frame is then held until the next one arrives (or :meth:`flush` is called).

    - on a badly damaged link (``quality``, the share of the recent bytes that belonged to
      accepted frames, below ``strict_below``: about 10 % of the bytes corrupted) a frame
      is published only when both of its neighbours in the byte stream are accepted
      frames that continue it: a CRC-8 collision then needs two more valid frames around
      it. On a good link (2 % of the bytes corrupted: quality ≈ 0.64) this is off and no
      intact frame is lost.

    The scan resumes one byte after a candidate that was not accepted, so a valid frame
    hidden behind a false sync is kept. Info frames (sync ``0xA5 0x49``, CRC and magic)
    are collected in ``infos``.

    Counters: ``frames`` (published), ``crc_errors`` (candidates whose CRC failed),
    ``rejected`` (CRC-valid candidates that were implausible or never confirmed),
    ``bytes_skipped`` (bytes not part of a published or info frame), ``lost_frames``
    (samples missing between published frames, from ``seq`` and ``t_us``),
    ``info_frames``, ``bytes_in``.

    :param temp_range: (low, high) plausible temperature counts (default: any chip).
    :param spike_counts: spike threshold in counts, e.g. :data:`SPIKE_COUNTS` (None: no
        spike check).
    :param strict_below: quality under which frames need both neighbours (None: never).
    """

    PENDING = 6

    def __init__(self, temp_range=None, spike_counts=None, strict_below=STRICT_BELOW):
        self._buf = bytearray()
        self.temp_range = temp_range or temp_counts_range()
        self.spike_counts = spike_counts
        self.strict_below = strict_below
        self.quality = 1.0
        self.infos = []
        self.frames = 0
        self.crc_errors = 0
        self.rejected = 0
        self.lost_frames = 0
        self.info_frames = 0
        self.bytes_in = 0
        self._consumed = 0
        self.period_us = None
        self.reset()

    @property
    def last_seq(self):
        """``seq`` of the last accepted frame (None before the first)."""
        return None if self._ref is None else self._ref.seq

    def reset(self):
        """Forget the partial frame and the sequence (after a reconnect); keep counters."""
        self._consumed += len(self._buf)
        self._buf.clear()
        self._ref = None
        self._older = []
        self._pending = []
        self._held = None
        self._last_out = None
        self._last_end = None

    @property
    def strict(self):
        """Whether frames currently need both neighbours (badly damaged link)."""
        return self.strict_below is not None and self.quality < self.strict_below

    @property
    def bytes_skipped(self):
        """Bytes consumed that were not part of a published, held or info frame."""
        return max(self._consumed - FRAME_SIZE * (self.frames + self.info_frames
                                                  + (self._held is not None)), 0)

    def counters(self):
        """Return the counters as a dict."""
        return {'frames': self.frames, 'crc_errors': self.crc_errors,
                'rejected': self.rejected, 'bytes_skipped': self.bytes_skipped,
                'lost_frames': self.lost_frames, 'info_frames': self.info_frames,
                'bytes_in': self.bytes_in}

    def take_infos(self):
        """Return and forget the info frames received since the last call."""
        infos, self.infos = self.infos, []
        return infos

    # -- plausibility ------------------------------------------------------------------

    def _gap(self, a, b, period):
        """
        Return the samples from frame ``a`` to ``b`` (>= 1); 0 when ``b`` does not continue ``a``.

        :param period: sample period in µs, or None (then only a short gap is accepted).
        """
        dseq = (b.seq - a.seq) & 0xFF
        dt = (b.t_us - a.t_us) & 0xFFFFFFFF
        if dt == 0 or dt > MAX_GAP_S * 1e6:
            return 0
        if period is None:
            if not 1 <= dseq <= 16 or not 50.0 <= dt / dseq <= 1e6:
                return 0
            n = dseq
        else:
            n = int(dt / period + 0.5)
            if n < 1 or (n & 0xFF) != dseq or abs(dt - n * period) > 20.0 + 0.002 * dt:
                return 0
        lsb = 340.0
        if abs(b.counts[3] - a.counts[3]) > (TEMP_STEP_C + dt * 1e-6) * lsb:
            return 0
        return n

    def _accept(self, frame, n, out, start):
        """Frame continues the stream n samples after the reference: hold it, emit the held."""
        adjacent = n == 1 and self._last_end == start
        self._last_end = start + FRAME_SIZE
        self._accepted += 1
        if self._ref is not None and n:
            dt = (frame.t_us - self._ref.t_us) & 0xFFFFFFFF
            observed = dt / n
            if self.period_us is None:
                self.period_us = observed
            elif n <= 4 and abs(observed - self.period_us) < 0.005 * self.period_us:
                self.period_us += 0.02 * (observed - self.period_us)   # outliers ignored
        if self._ref is not None:
            self._older = (self._older + [self._ref])[-2:]
        self._ref = frame
        self.rejected += len(self._pending)     # candidates that never continued the stream
        self._pending = []
        held = self._held
        if self.spike_counts is None and not self.strict:
            self._held = None
            if held is not None:                 # held while the link was bad
                self._release(held[0], frame, out, False)
            self._release(frame, None, out, True)
            return
        self._held = (frame, adjacent)
        if held is not None:
            self._release(held[0], frame, out, held[1] and adjacent)

    def _release(self, frame, following, out, sandwiched):
        if self.strict and not sandwiched:
            self.rejected += 1
            return
        prev = self._last_out
        if self.spike_counts is not None and prev is not None and following is not None \
                and self._is_spike(prev, frame, following):
            self.rejected += 1
            return
        if prev is not None:
            n = self._gap(prev, frame, self.period_us)
            if n == 0:                           # re-locked: gap unknown
                n = 1
            self.lost_frames += n - 1
        self._last_out = frame
        out.append(frame)

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

    def flush(self):
        """
        Release the held newest frame (call when the stream pauses, e.g. on a read timeout).

        :return: list of RawFrame (0 or 1).
        """
        out = []
        held, self._held = self._held, None
        if held is not None:
            self._release(held[0], None, out, False)
            self.frames += len(out)
        return out

    # -- scanning ----------------------------------------------------------------------

    def feed(self, data):
        """
        Parse more bytes.

        :param data: bytes-like object, any length (may be empty).
        :return: list of RawFrame, in stream order (the newest frame is held back).
        """
        buf = self._buf
        buf += data
        self.bytes_in += len(data)
        n = len(buf)
        out = []
        pos = 0
        table = CRC8_TABLE
        head = _HEAD.unpack_from
        block = _BLOCK.unpack_from
        find = buf.find
        lo, hi = self.temp_range
        crc_errors = 0
        self._accepted = 0
        base = self._consumed
        while True:
            i = find(0xA5, pos)
            if i < 0 or i + 1 >= n:
                pos = n if i < 0 else i          # keep a trailing 0xA5
                break
            kind = buf[i + 1]
            if kind != 0x5A and kind != 0x49:
                pos = i + 1
                continue
            end = i + FRAME_SIZE
            if end > n:
                pos = i
                break
            crc = 0
            for k in range(i + 2, end):
                crc = table[crc ^ buf[k]]
            if crc:                              # the CRC byte itself included: 0 when intact
                crc_errors += 1
                pos = i + 1
                continue
            if kind == 0x49:
                info = decode_info(bytes(buf[i:end]))
                if info is None:
                    pos = i + 1
                    continue
                self.infos.append(info)
                self.info_frames += 1
                pos = end
                continue
            seq, t_us = head(buf, i + 2)
            frame = RawFrame(seq, t_us, block(buf, i + 7))
            if not lo <= frame.counts[3] <= hi:
                self.rejected += 1
                pos = i + 1
                continue
            ref = self._ref
            gap = self._gap(ref, frame, self.period_us) if ref is not None else 0
            if not gap and ref is not None:
                # The newest reference may itself be a CRC-8 collision whose t_us was hit
                # within tolerance: a frame that continues an older reference is good.
                for older in reversed(self._older):
                    gap = self._gap(older, frame, self.period_us)
                    if gap and (frame.t_us - ref.t_us) & 0x80000000 == 0:
                        self._ref = older
                        break
                    gap = 0
            if gap:
                self._accept(frame, gap, out, base + i)
                pos = end
                continue
            confirmed = None
            for cand in reversed(self._pending):
                if self._gap(cand, frame, None):
                    confirmed = cand
                    break
            if confirmed is not None:            # re-lock on two frames that agree
                chain = [confirmed]              # with the earlier ones that lead up to it
                for cand in reversed(self._pending[:self._pending.index(confirmed)]):
                    if self._gap(cand, chain[0], None):
                        chain.insert(0, cand)
                self.rejected += len(self._pending) - len(chain)
                self._pending = []
                self._ref = None
                self._older = []
                self.period_us = None
                for k, cand in enumerate(chain):
                    self._accept(cand, self._gap(chain[k - 1], cand, None) if k else 0, out, -1)
                self._accept(frame, self._gap(confirmed, frame, None), out, base + i)
                pos = end
                continue
            self._pending.append(frame)
            if len(self._pending) > self.PENDING:
                del self._pending[0]
                self.rejected += 1
            pos = i + 1
        del buf[:pos]
        self._consumed += pos
        if pos:
            weight = pos / (pos + FRAME_SIZE * QUALITY_WINDOW_FRAMES)
            self.quality += weight * (min(FRAME_SIZE * self._accepted / pos, 1.0) - self.quality)
        self.frames += len(out)
        self.crc_errors += crc_errors
        return out


class AsciiLineParser:
    """
    Parser of the hobby-firmware text format; never raises on bad lines.

    One sample per line: ``ax,ay,az,temp,gx,gy,gz`` raw counts, optionally led by
    ``t_us`` (8 fields). Commas, semicolons or whitespace separate the fields; blank
    lines are ignored; anything else is counted in ``bad_lines``.
    """

    MAX_LINE = 256

    def __init__(self):
        self._buf = bytearray()
        self.frames = 0
        self.bad_lines = 0
        self.bytes_in = 0
        self.bytes_skipped = 0

    def reset(self):
        """Forget the partial line (after a reconnect); keep counters."""
        self._buf.clear()

    def counters(self):
        """Return the counters as a dict."""
        return {'frames': self.frames, 'bad_lines': self.bad_lines,
                'bytes_skipped': self.bytes_skipped, 'bytes_in': self.bytes_in}

    def feed(self, data):
        """
        Parse more bytes.

        :param data: bytes-like object.
        :return: list of RawFrame with ``seq`` None (and ``t_us`` None for 7 fields).
        """
        buf = self._buf
        buf += data
        self.bytes_in += len(data)
        out = []
        start = 0
        while True:
            nl = buf.find(b'\n', start)
            if nl < 0:
                break
            frame = self.parse_line(bytes(buf[start:nl]))
            if frame is not None:
                out.append(frame)
            start = nl + 1
        del buf[:start]
        if len(buf) > self.MAX_LINE:     # no newline for too long: not this format
            self.bad_lines += 1
            self.bytes_skipped += len(buf)
            buf.clear()
        self.frames += len(out)
        return out

    def parse_line(self, line):
        """Parse one line (bytes, without newline); count and return None when bad."""
        text = line.strip(b' \t\r\x00')
        if not text:
            return None
        try:
            fields = [int(f) for f in _ASCII_SPLIT.split(text.decode('ascii')) if f]
        except (UnicodeDecodeError, ValueError):
            fields = None
        if fields is None or len(fields) not in (7, 8) or \
                any(not INT16_MIN <= c <= INT16_MAX for c in fields[-7:]) or \
                (len(fields) == 8 and not 0 <= fields[0] <= 0xFFFFFFFF):
            self.bad_lines += 1
            self.bytes_skipped += len(line) + 1
            return None
        if len(fields) == 8:
            return RawFrame(None, fields[0], tuple(fields[1:]))
        return RawFrame(None, None, tuple(fields))


def encode_ascii_line(counts, t_us=None):
    """Encode one text line (bytes, with newline), led by ``t_us`` when given."""
    fields = ([] if t_us is None else [int(t_us) & 0xFFFFFFFF]) + [int(c) for c in counts]
    return (','.join(str(f) for f in fields) + '\n').encode('ascii')


# -- conversions -------------------------------------------------------------------------

def _range_key(name, value, table, unit):
    try:
        number = float(value)
    except (TypeError, ValueError):
        number = math.nan
    for key in table:
        if number == key:
            return key
    allowed = ', '.join(str(k) for k in table)
    raise ValueError(f'unsupported {name} {value!r}: use one of {allowed} ({unit})')


def accel_scale(range_g):
    """
    Return m/s² per count for an accelerometer full-scale range.

    :param range_g: ±2, 4, 8 or 16 g.
    :raises ValueError: unsupported range.
    """
    return G0 / ACCEL_LSB_PER_G[_range_key('accelerometer range', range_g, ACCEL_LSB_PER_G,
                                           '±g')]


def gyro_scale(range_dps):
    """
    Return rad/s per count for a gyroscope full-scale range.

    :param range_dps: ±250, 500, 1000 or 2000 °/s.
    :raises ValueError: unsupported range.
    """
    key = _range_key('gyroscope range', range_dps, GYRO_LSB_PER_DPS, '±°/s')
    return math.radians(1.0) / GYRO_LSB_PER_DPS[key]


def temp_c(count):
    """Temperature in °C of a raw count."""
    return count / TEMP_LSB_PER_C + TEMP_OFFSET_C


class Converter:
    """
    Raw counts to SI units (REP-103) and back, for given full-scale ranges.

    :param accel_range_g: ±2, 4, 8 or 16.
    :param gyro_range_dps: ±250, 500, 1000 or 2000.
    :param temp_formula: ``mpu6500`` (MPU-6500/9250/9255: counts/333.87 + 21 °C) or
        ``mpu6050`` (counts/340 + 36.53 °C).
    :raises ValueError: unsupported range or formula, with the allowed values.
    """

    def __init__(self, accel_range_g=2, gyro_range_dps=250, temp_formula='mpu6500'):
        self.accel_scale = accel_scale(accel_range_g)
        self.gyro_scale = gyro_scale(gyro_range_dps)
        if temp_formula not in TEMP_FORMULAS:
            raise ValueError(f'unsupported temperature formula {temp_formula!r}: use one of '
                             f'{", ".join(TEMP_FORMULAS)}')
        self.temp_formula = temp_formula
        self.temp_lsb_per_c, self.temp_offset_c = TEMP_FORMULAS[temp_formula]

    def to_si(self, counts):
        """
        Convert seven counts to SI.

        :param counts: (ax, ay, az, temp, gx, gy, gz) counts.
        :return: ((ax, ay, az) m/s², temperature °C, (gx, gy, gz) rad/s).
        """
        a = self.accel_scale
        g = self.gyro_scale
        ax, ay, az, t, gx, gy, gz = counts
        return ((ax * a, ay * a, az * a), t / self.temp_lsb_per_c + self.temp_offset_c,
                (gx * g, gy * g, gz * g))

    def to_counts(self, accel, temp, gyro):
        """
        Convert SI readings to seven counts, rounded and clipped to int16 (the device side).

        :param accel: (3,) m/s².
        :param temp: °C.
        :param gyro: (3,) rad/s.
        :return: tuple of seven ints.
        """
        def clip(value):
            return max(INT16_MIN, min(INT16_MAX, int(round(value))))
        return (tuple(clip(v / self.accel_scale) for v in accel) +
                (clip((temp - self.temp_offset_c) * self.temp_lsb_per_c),) +
                tuple(clip(v / self.gyro_scale) for v in gyro))

    def to_counts_array(self, accel, temp, gyro):
        """
        Vectorised :meth:`to_counts`.

        :param accel: (N, 3) m/s².
        :param temp: (N,) °C.
        :param gyro: (N, 3) rad/s.
        :return: (N, 7) int16 array.
        """
        import numpy as np
        accel = np.asarray(accel, float).reshape(-1, 3)
        n = len(accel)
        out = np.empty((n, 7))
        out[:, :3] = accel / self.accel_scale
        out[:, 3] = (np.broadcast_to(np.asarray(temp, float), (n,)) - self.temp_offset_c) \
            * self.temp_lsb_per_c
        out[:, 4:] = np.asarray(gyro, float).reshape(-1, 3) / self.gyro_scale
        return np.clip(np.round(out), INT16_MIN, INT16_MAX).astype(np.int16)


# -- device clock ------------------------------------------------------------------------

class ClockMapper:
    """
    Map the microcontroller's µs clock onto host time, without the transport jitter.

    The host receives sample k at ``host_k = offset + (1 + drift) * dev_k + delay_k``
    with ``delay_k >= d_min``: the lower envelope of ``host - dev`` is the clock
    offset (plus the constant minimum delay). The device clock is unwrapped (uint32
    µs); ``host - dev`` is reduced to its minimum over blocks of ``block_s`` seconds and
    a straight line is fitted through the last ``blocks`` minima (offset and drift).
    Stamps are ``dev + line(dev)``: the device's own sample spacing, placed on the host
    clock. A device clock that steps backwards, or forward by more than host time
    can explain (``jump_s``), restarts the mapping (``resets`` counts these). After a
    refit the stamps slew to the new line at no more than ``max_slew`` (s/s) instead of
    stepping, unless it moved by more than ``step_s``.

    :param block_s: length of one minimum block, device seconds.
    :param blocks: number of blocks in the fit (window = blocks x block_s).
    :param jump_s: tolerated excess of device time over host time between samples.
    :param max_slew: largest rate of change of the applied offset, s per s.
    :param step_s: a larger change of the fitted offset is applied at once.
    """

    def __init__(self, block_s=2.0, blocks=15, jump_s=0.5, max_slew=1e-3, step_s=0.005):
        self.block_s = float(block_s)
        self.max_slew = float(max_slew)
        self.step_s = float(step_s)
        self.blocks = int(blocks)
        self.jump_s = float(jump_s)
        self.resets = 0
        self.reset()
        self.resets = 0

    def reset(self):
        """Forget the mapping (after a reconnect or a device reset)."""
        self.resets += 1
        self._last_raw = None
        self._last_host = None
        self._dev = 0.0             # unwrapped device time since the first sample, s
        self._host0 = None          # host time of the first sample (keeps floats small)
        self._points = []           # (dev, min offset) of finished blocks
        self._block_start = None
        self._block_min = None
        self._a = 0.0               # offset at dev = 0
        self._b = 0.0               # drift, s/s
        self._applied = 0.0         # offset used for the last stamp
        self._applied_dev = 0.0

    @property
    def drift_ppm(self):
        """Return the estimated device clock rate error, parts per million."""
        return self._b * 1e6

    def update(self, t_us, host_s):
        """
        Map one sample.

        :param t_us: device clock, µs, uint32 (wraps at 2**32).
        :param host_s: host receive time of the sample, s.
        :return: stamp on the host clock, s.
        """
        if self._last_raw is not None:
            delta = ((t_us - self._last_raw) & 0xFFFFFFFF) * 1e-6
            if delta > 2147.483648 or delta > (host_s - self._last_host) + self.jump_s:
                self.reset()
            else:
                self._dev += delta
        if self._last_raw is None:
            self._host0 = host_s
            self._dev = 0.0
        self._last_raw = t_us
        self._last_host = host_s
        dev = self._dev
        offset = (host_s - self._host0) - dev
        if self._block_start is None:
            self._block_start = dev
            self._block_min = (dev, offset)
        elif offset < self._block_min[1]:
            self._block_min = (dev, offset)
        if dev - self._block_start >= self.block_s:
            self._points.append(self._block_min)
            del self._points[:-self.blocks]
            self._block_start = dev
            self._block_min = (dev, offset)
            self._fit()
        elif not self._points:
            self._a = self._block_min[1]
        target = self._a + self._b * dev
        if not self._points or abs(target - self._applied) > self.step_s:
            self._applied = target
        else:                        # slew to a refitted line: no step in the stamps
            limit = self.max_slew * (dev - self._applied_dev)
            self._applied += max(-limit, min(limit, target - self._applied))
        self._applied_dev = dev
        return self._host0 + dev + self._applied

    def _fit(self):
        pts = self._points
        if len(pts) < 3:
            self._a = min(p[1] for p in pts)
            self._b = 0.0
            return
        n = len(pts)
        mx = sum(p[0] for p in pts) / n
        my = sum(p[1] for p in pts) / n
        sxx = sum((p[0] - mx) ** 2 for p in pts)
        sxy = sum((p[0] - mx) * (p[1] - my) for p in pts)
        b = sxy / sxx if sxx > 0 else 0.0
        # Under every block minimum (lower envelope): stamps do not run ahead of receipt.
        self._a = min(p[1] - b * p[0] for p in pts)
        self._b = b
