"""
A fake clock, a fake device and its fake port, for the serial link without hardware.

:class:`FakeClock` is the link's clock (``monotonic``, ``host``, ``sleep``): time moves only
when the link waits or reads. :class:`FakeDevice` is a board that samples at ``rate_hz``
with its own µs clock (``ppm`` fast), sends frame version 2 (or 1) and an info frame at
plug-in, once a second and on request; it can stall its UART (samples made, never sent),
be unplugged (the port disappears; it keeps sampling) and restart (seq and t_us from 0).
Bytes it sends while nobody has the port open stay in the "OS buffer", as a pty or a
serial driver keeps them, unless the opener flushes. ``device.opener`` is the link's
``open_port``.
"""

import math

from accel_calib_ros.dataio.wire import (encode_frame, encode_frame_v2, encode_info,
                                         encode_info_v2, InfoFrame, MAG_ABSENT)


FRAME_SYNCS = (b'\xa5\x5a', b'\xa5\x5b')


class FakeClock:
    """Monotonic and host time that move only when someone waits or reads."""

    def __init__(self, t=1000.0, host_offset=1.7e9):
        self.t = float(t)
        self.host_offset = host_offset

    def monotonic(self):
        return self.t

    def host(self):
        return self.t + self.host_offset

    def sleep(self, seconds, event):
        if not event.is_set():
            self.t += max(seconds, 0.0)


class FakeDevice:
    """
    A board on a serial port, in fake time.

    :param clock: FakeClock.
    :param rate_hz: sample rate (true time).
    :param ppm: device clock error, parts per million (t_us runs fast by this much).
    :param version: data frame version, 1 or 2.
    :param info: InfoFrame sent (None: no info frames at all, as a hobby firmware).
    :param delay_s: transport delay from sample to the host's OS buffer, s.
    :param t0_us: device clock at the first sample.
    """

    def __init__(self, clock, rate_hz=500.0, ppm=0.0, version=2, info='default',
                 delay_s=0.0005, t0_us=4_294_000_000, streaming=True):
        self.clock = clock
        self.rate = rate_hz
        self.ppm = ppm
        self.version = version
        if info == 'default':
            info = InfoFrame(0, 0x71, 2, 250, int(rate_hz), 1, 1_000_000, (2, 0),
                             version, MAG_ABSENT, info_version=2)
        self.info = info
        self.streaming = streaming
        self.delay_s = delay_s
        self.t0_us = t0_us
        self.start = clock.t
        self.made = 0               # samples made (index of the next one)
        self.seq0 = 0
        self.index0 = 0             # sample index of the last restart
        self.sent = []              # (sample index, arrival time) of frames put on the wire
        self.never_sent = 0         # samples made but not sent (stall, unplugged)
        self.buffer = []            # (arrival time, bytes) waiting in the OS
        self.stalls = []            # (start, end) true times
        self.unplugs = []           # (start, end) true times
        self.restarts = []          # true times
        self.flushed = 0            # bytes dropped by an opener that flushes
        self.vanished = 0           # frames sent but lost with the tty at an unplug
        self.opens = 0
        self.requests = 0
        self.port = None
        self.flush_on_open = False
        self.counts = (0, 0, 16384, 1335, 1, 2, 3)
        self._info_due = self.start
        self._plugged = True

    # -- what happens in time ------------------------------------------------------------

    def _in(self, spans, t):
        return any(a <= t < b for a, b in spans)

    def advance(self):
        """Make every sample (and info frame) due by the clock's time."""
        now = self.clock.t
        while True:
            t = self.start + self.made / self.rate
            if t > now:
                break
            for when in self.restarts:
                if self.start + (self.made - 1) / self.rate < when <= t:
                    self.index0, self.seq0 = self.made, 0
                    self._info_due = t
            plugged = not self._in(self.unplugs, t)
            if not plugged and self._plugged:       # the device goes away, its tty too
                if self.port is not None:
                    self.port.dead = True
                self.vanished += sum(1 for _, d in self.buffer if d[:2] in FRAME_SYNCS)
                self.buffer = []
            self._plugged = plugged
            stalled = self._in(self.stalls, t)
            if plugged and not stalled and self.info is not None and t >= self._info_due:
                self._emit(t, self._info_bytes())
                self._info_due = t + 1.0
            k = self.made - self.index0
            self.made += 1
            if not self.streaming:
                continue
            if not plugged or stalled:
                self.never_sent += 1
                continue
            dev_us = self.t0_us + round(k * 1e6 / self.rate * (1 + self.ppm * 1e-6)) \
                if self.index0 == 0 else round(k * 1e6 / self.rate * (1 + self.ppm * 1e-6))
            seq = self.seq0 + k
            counts = (self.made - 1) % 30000, *self.counts[1:]
            data = encode_frame(seq & 0xFF, dev_us, counts) if self.version == 1 \
                else encode_frame_v2(seq & 0xFFFF, dev_us, counts)
            self.sent.append((self.made - 1, t + self.delay_s))
            self._emit(t, data)

    def _info_bytes(self):
        info = self.info
        return encode_info_v2(info) if info.info_version == 2 else encode_info(info)

    def _emit(self, t, data):
        self.buffer.append((t + self.delay_s, data))

    def answer_request(self):
        """Answer a request for the info frame at once, as the firmware does."""
        self.requests += 1
        t = self.clock.t
        if self.info is not None and not self._in(self.unplugs, t) and \
                not self._in(self.stalls, t):
            self._emit(self.clock.t, self._info_bytes())

    def plugged(self):
        return not self._in(self.unplugs, self.clock.t)

    def opener(self, path, baud, timeout):
        """Open the port (the link's ``open_port``): a FakePort while plugged in."""
        self.advance()
        if not self.plugged():
            raise OSError(2, f'could not open port {path}: No such file or directory')
        self.opens += 1
        if self.flush_on_open:
            due = [(t, d) for t, d in self.buffer if t <= self.clock.t]
            self.flushed += sum(len(d) for _, d in due)
            self.buffer = [(t, d) for t, d in self.buffer if t > self.clock.t]
        self.port = FakePort(self, timeout)
        return self.port


class FakePort:
    """The open port: reads what has arrived by the fake time (blocking up to timeout)."""

    def __init__(self, device, timeout):
        self.device = device
        self.timeout = timeout
        self.dead = False
        self.closed = False
        self.written = b''

    def _due(self):
        self.device.advance()
        now = self.device.clock.t
        return [(t, d) for t, d in self.device.buffer if t <= now]

    @property
    def in_waiting(self):
        if self.dead:
            raise OSError(5, 'Input/output error')
        return sum(len(d) for _, d in self._due())

    def read(self, n):
        if self.dead:
            raise OSError(5, 'Input/output error')
        dev = self.device
        if not self._due():                 # block until something arrives, or time out
            later = [t for t, _ in dev.buffer if t > dev.clock.t]
            nxt = min(later + [dev.start + dev.made / dev.rate + dev.delay_s])
            dev.clock.t = min(dev.clock.t + self.timeout, max(nxt, dev.clock.t + 1e-6))
            dev.advance()
            if self.dead:
                raise OSError(5, 'Input/output error')
        out = bytearray()
        keep = []
        for t, d in dev.buffer:
            if t <= dev.clock.t and len(out) < n:
                take = d[:n - len(out)]
                out += take
                if len(take) < len(d):
                    keep.append((t, d[len(take):]))
            else:
                keep.append((t, d))
        dev.buffer = keep
        return bytes(out)

    def write(self, data):
        if self.dead:
            raise OSError(5, 'Input/output error')
        self.written += data
        if b'?' in data:
            self.device.answer_request()
        return len(data)

    def reset_input_buffer(self):
        dev = self.device
        dev.advance()
        due = [(t, d) for t, d in dev.buffer if t <= dev.clock.t]
        dev.flushed += sum(len(d) for _, d in due)
        dev.buffer = [(t, d) for t, d in dev.buffer if t > dev.clock.t]

    def close(self):
        self.closed = True
        if self.device.port is self:
            self.device.port = None


def run_link(link, seconds, step_limit=10_000_000):
    """Step ``link`` until its fake clock has moved ``seconds``; return the steps taken."""
    clock = link.clock
    end = clock.t + seconds
    steps = 0
    while clock.t < end and steps < step_limit:
        before = clock.t
        link.step()
        steps += 1
        if clock.t == before:       # a step that did not wait: time still moves a little
            clock.t += 1e-6
    return steps


def nearly(a, b, tol):
    return math.isclose(a, b, abs_tol=tol)
