"""
The ASCII line format for hobby firmware (interface.md §1, last paragraph).

One sample per line: ``ax,ay,az,temp,gx,gy,gz`` raw counts, optionally led by ``t_us``.
"""

import re

from .frames import INT16_MAX, INT16_MIN, RawFrame

_ASCII_SPLIT = re.compile(r'[,;\s]+')


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
