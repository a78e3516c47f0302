"""
The virtual device's end of the serial link: frames encoded and damaged, a pty plugged in.

:class:`Wire` turns sensor counts into the interface's frames (v1, v2 with the AK8963
block, or ASCII lines) on the device's clock, corrupts bytes at a given rate and counts
what it did; :class:`Pty` is one plug-in of the device (a raw pseudo-terminal, with an
optional symlink such as ``/tmp/ttyIMU``).
"""

import contextlib
import errno
import os
import tty

import numpy as np

from ..dataio.wire import (BY_KEY, DEFAULT_CHIP, encode_ascii_line, encode_frame,
                           encode_frame_v2, encode_info, encode_info_v2, InfoFrame, MAG_ABSENT,
                           MAG_AK8963, MagConverter)


class Wire:
    """
    Encodes samples into bytes, optionally corrupting them, and counts what it did.

    :param args: parsed options.
    :param rng: numpy Generator for the corruption and the start of the device clock.
    """

    def __init__(self, args, rng):
        self.ascii = args.ascii
        self.version = getattr(args, 'frame_version', 2)
        self.corrupt = args.corrupt
        self.rng = rng
        # The microcontroller's µs clock runs clock_ppm fast: it stamps the sensor's true
        # sample period as this many of its µs.
        self.clock_ppm = getattr(args, 'clock_ppm', 0.0)
        self.period_us = 1e6 / args.rate * (1 + self.clock_ppm * 1e-6)
        self.t0_us = args.t0_us if args.t0_us is not None else int(rng.integers(0, 2 ** 32))
        self.seq = 0
        self.frames = 0
        self.bytes_corrupted = 0
        self.frames_damaged = 0
        self.ranges = (args.accel_range, args.gyro_range)
        self.rate_hz = min(max(int(round(args.rate)), 1), 0xFFFF)
        self.chip = BY_KEY[getattr(args, 'chip', DEFAULT_CHIP.key)]
        magnetometer = self.chip.magnetometer or DEFAULT_CHIP.magnetometer
        self.mag_converter = MagConverter(magnetometer=magnetometer)
        self.last_sizes = []        # bytes of each frame of the last encode()

    def whole_frames(self, written):
        """Return how many frames of the last :meth:`encode` fit whole in ``written`` bytes."""
        total = 0
        for k, size in enumerate(self.last_sizes):
            total += size
            if total > written:
                return k
        return len(self.last_sizes)

    def info(self, has_mag):
        """
        Return the info frame a firmware would send (none in the ASCII format).

        A virtual chip (``--chip``: its WHO_AM_I) that streams; with a magnetometer, one
        whose factory adjustment is neutral (ASA 128), so the driver converts its blocks at
        once.
        """
        if self.ascii:
            return b''
        info = InfoFrame(0, self.chip.who_am_i, self.ranges[0], self.ranges[1], self.rate_hz, 1,
                         1_000_000, (2, 0), self.version, MAG_AK8963 if has_mag else MAG_ABSENT,
                         (128, 128, 128) if has_mag else (0, 0, 0))
        return encode_info_v2(info) if self.version == 2 else encode_info(info)

    def mag_blocks(self, mag_ut):
        """
        Return the AK8963 blocks of magnetometer samples for :meth:`encode` (None: none).

        :param mag_ut: (n, 3) µT in the accelerometer frame, NaN rows without a sample, or
            None.
        """
        if mag_ut is None or self.version != 2 or self.ascii:
            return None
        to_counts = self.mag_converter.to_counts
        return [None if not np.all(np.isfinite(row)) else to_counts(row * 1e-6)
                for row in np.asarray(mag_ut, float)]

    def skip(self, n):
        """Advance ``seq`` over ``n`` samples made but never sent (UART stalled, unplugged)."""
        self.seq = (self.seq + n) & (0xFFFF if self.version == 2 else 0xFF)

    def encode(self, counts, first_index, mag=None):
        """
        Encode samples number ``first_index``... as bytes (corrupted if asked).

        :param counts: (n, 7) int16 counts.
        :param mag: None, or n entries each None or (hx, hy, hz, st2): AK8963 counts in its
            own axes (e.g. from ``MagConverter.to_counts``), sent in version-2 frames.
        """
        pieces, sizes = [], []
        self.last_sizes = sizes
        for k, row in enumerate(counts.tolist()):
            t_us = (self.t0_us + int(round((first_index + k) * self.period_us))) & 0xFFFFFFFF
            if self.ascii:
                piece = encode_ascii_line(row, t_us)
            elif self.version == 2:
                piece = encode_frame_v2(self.seq, t_us, row, None if mag is None else mag[k])
            else:
                piece = encode_frame(self.seq, t_us, row)
            self.seq = (self.seq + 1) & (0xFFFF if self.version == 2 else 0xFF)
            pieces.append(piece)
            sizes.append(len(piece))
        self.frames += len(pieces)
        data = b''.join(pieces)
        if self.corrupt > 0 and data:
            buf = np.frombuffer(data, np.uint8).copy()
            hit = np.flatnonzero(self.rng.random(len(buf)) < self.corrupt)
            if len(hit):
                buf[hit] ^= self.rng.integers(1, 256, len(hit)).astype(np.uint8)
                self.bytes_corrupted += len(hit)
                ends = np.cumsum(sizes)
                self.frames_damaged += len(np.unique(np.searchsorted(ends, hit, side='right')))
                data = buf.tobytes()
        return data


class Pty:
    """
    One plug-in of the device: a pty pair in raw mode, plus the optional symlink.

    :param link: symlink path or None.
    """

    def __init__(self, link):
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        os.set_blocking(self.master, False)
        self.path = os.ttyname(self.slave)
        self.link = link
        if link:        # a new link under a fresh name (never an existing file), renamed
            from ..dataio.atomic import temp_name
            folder, name = os.path.split(os.path.abspath(link))
            for _ in range(100):
                tmp = os.path.join(folder, temp_name(folder, name, os.urandom(4).hex()))
                try:
                    os.symlink(self.path, tmp)
                    break
                except FileExistsError:
                    continue
            try:
                os.replace(tmp, link)
            except BaseException:
                with contextlib.suppress(OSError):
                    os.unlink(tmp)
                raise

    def requests(self):
        """Return the bytes the reader wrote to the device (``?`` asks for the info frame)."""
        try:
            return os.read(self.master, 4096)
        except (BlockingIOError, OSError):
            return b''

    def write(self, data):
        """Write what the pty takes; return the number of bytes dropped (buffer full)."""
        done = 0
        while done < len(data):
            try:
                n = os.write(self.master, data[done:])
            except BlockingIOError:
                break
            except OSError as err:
                if err.errno in (errno.EAGAIN, errno.EIO):
                    break
                raise
            if n <= 0:
                break
            done += n
        return len(data) - done

    def close(self):
        """Unplug: remove the link, close both ends."""
        if self.link:
            try:
                if os.path.islink(self.link) and os.readlink(self.link) == self.path:
                    os.unlink(self.link)
            except OSError:
                pass
        for fd in (self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass
