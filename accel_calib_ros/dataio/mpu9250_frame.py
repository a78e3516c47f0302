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


class FrameParser:
    """
    Incremental parser of the binary frame stream; never raises on bad bytes.

    Feed it whatever the port returned; it keeps a cut-off frame for the next call.
    Candidates start at every sync word; a candidate whose CRC fails is counted and
    the scan resumes one byte after its sync, so a valid frame that follows garbage
    or a corrupted frame (or one that hides behind a false sync in data) is kept.

    Counters: ``frames`` (good frames), ``crc_errors`` (candidates whose CRC failed),
    ``bytes_skipped`` (bytes not part of a good frame), ``lost_frames`` (from gaps in
    ``seq``, modulo 256), ``bytes_in``.
    """

    def __init__(self):
        self._buf = bytearray()
        self._synced = False
        self.last_seq = None
        self.frames = 0
        self.crc_errors = 0
        self.bytes_skipped = 0
        self.lost_frames = 0
        self.bytes_in = 0

    def reset(self):
        """Forget the partial frame and the sequence (after a reconnect); keep counters."""
        self._buf.clear()
        self._synced = False
        self.last_seq = None

    def counters(self):
        """Return the counters as a dict."""
        return {'frames': self.frames, 'crc_errors': self.crc_errors,
                'bytes_skipped': self.bytes_skipped, 'lost_frames': self.lost_frames,
                'bytes_in': self.bytes_in}

    def feed(self, data):
        """
        Parse more bytes.

        :param data: bytes-like object, any length (may be empty).
        :return: list of RawFrame, in stream order.
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
        synced = self._synced
        last = self.last_seq
        skipped = crc_errors = lost = 0
        while True:
            if synced and buf[pos:pos + 2] == SYNC:
                i = pos
            else:
                i = find(SYNC, pos)
                if i < 0:
                    # Keep a trailing 0xA5: it may be the first half of the next sync.
                    keep = 1 if n > pos and buf[n - 1] == 0xA5 else 0
                    skipped += n - pos - keep
                    pos = n - keep
                    break
                if i > pos:
                    skipped += i - pos
                    pos = i
                    synced = False
            end = i + FRAME_SIZE
            if end > n:
                break
            crc = 0
            for k in range(i + 2, end):
                crc = table[crc ^ buf[k]]
            if crc:                          # the CRC byte itself included: 0 when intact
                crc_errors += 1
                skipped += 1
                pos = i + 1
                synced = False
                continue
            if not synced:
                i, end = self._prefer_overlapping(buf, i, n)
                skipped += i - pos
            seq, t_us = head(buf, i + 2)
            out.append(RawFrame(seq, t_us, block(buf, i + 7)))
            if last is not None:
                gap = (seq - last - 1) & 0xFF
                if gap != 0xFF:              # 0xFF: a repeated seq, not 255 lost frames
                    lost += gap
            last = seq
            pos = end
            synced = True
        del buf[:pos]
        self._synced = synced
        self.last_seq = last
        self.frames += len(out)
        self.crc_errors += crc_errors
        self.bytes_skipped += skipped
        self.lost_frames += lost
        return out

    @staticmethod
    def _prefer_overlapping(buf, i, n):
        """
        Pick between a resync candidate and a valid candidate overlapping it.

        A CRC-8 passes by chance once in 256 false syncs; when another valid candidate
        starts inside this one, keep the one that is followed by a sync word.
        """
        end = i + FRAME_SIZE
        if buf[end:end + 2] == SYNC:
            return i, end
        j = buf.find(SYNC, i + 1, end)
        while j >= 0:
            j_end = j + FRAME_SIZE
            if j_end + 2 <= n and buf[j_end:j_end + 2] == SYNC and crc8(buf[j + 2:j_end]) == 0:
                return j, j_end
            j = buf.find(SYNC, j + 1, end)
        return i, end


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
    :raises ValueError: unsupported range, with the allowed values.
    """

    def __init__(self, accel_range_g=2, gyro_range_dps=250):
        self.accel_scale = accel_scale(accel_range_g)
        self.gyro_scale = gyro_scale(gyro_range_dps)

    def to_si(self, counts):
        """
        Convert seven counts to SI.

        :param counts: (ax, ay, az, temp, gx, gy, gz) counts.
        :return: ((ax, ay, az) m/s², temperature °C, (gx, gy, gz) rad/s).
        """
        a = self.accel_scale
        g = self.gyro_scale
        ax, ay, az, t, gx, gy, gz = counts
        return ((ax * a, ay * a, az * a), t / TEMP_LSB_PER_C + TEMP_OFFSET_C,
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
                (clip((temp - TEMP_OFFSET_C) * TEMP_LSB_PER_C),) +
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
        out[:, 3] = (np.broadcast_to(np.asarray(temp, float), (n,)) - TEMP_OFFSET_C) \
            * TEMP_LSB_PER_C
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
