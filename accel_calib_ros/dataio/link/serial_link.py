"""
The serial link: open, back-off, watchdog, info request, supervision; ROS-free.

A :class:`SerialLink` owns the port, the frame parser and the clock mapping. Its reader
thread (:meth:`SerialLink.run`) repeats :meth:`SerialLink.step` (one read, or one wait
for the next attempt to open the port) and survives any exception in it: the exception
is counted (``reader_errors``), logged at most every 10 s, and the reader starts over.
Samples go to ``on_samples(frames, stamps)``, info frames to ``on_info(info)``, both
called from the reader thread. The port is opened by ``open_port(path, baud, timeout)``
and time comes from ``clock`` (``monotonic()``, ``host()``, ``sleep(seconds, event)``):
the tests give a fake port and a fake clock and step the link by hand.
"""

import threading
import time

import serial

from ..wire import AsciiLineParser, FrameParser
from ..wire.clock import Stamper

READ_TIMEOUT_S = 0.05
"""A read returns after this long without a byte."""
INFO_REQUEST = b'?'
INFO_WAIT_S = 1.5
LOG_PERIOD_S = 10.0
"""At most one log line per this many seconds about reader failures (and watchdog reopens)."""
OPEN_GRACE_S = 2.0
"""The watchdog does not reopen a port within this many seconds of opening it (an Arduino
Uno resets when its port is opened: bootloader and sensor start-up take about 1.5 s)."""
HOLD_MAX_S = 1.5
"""Frames are never held back longer than this (waiting for the clock mapping to settle)."""
PORT_ERRORS = (OSError, serial.SerialException, ValueError)


def open_serial(path, baud, timeout):
    """
    Open a serial port with pyserial and drop what was received before.

    :return: the open ``serial.Serial``.
    :raises serial.SerialException, OSError, ValueError: it cannot be opened.
    """
    port = serial.Serial(path, baud, timeout=timeout)
    try:
        port.reset_input_buffer()       # stale bytes from before we were listening
    except (OSError, serial.SerialException):
        pass
    return port


class SystemClock:
    """The real clocks: monotonic time for the link's timing, wall time for stamps."""

    def monotonic(self):
        """Return monotonic seconds."""
        return time.monotonic()

    def host(self):
        """Return the host time stamps are made of, seconds."""
        return time.time()

    def sleep(self, seconds, event):
        """Wait ``seconds`` or until ``event`` is set."""
        event.wait(seconds)


class _Quiet:
    def __getattr__(self, name):
        return lambda *args, **kwargs: None


class SerialLink:
    """
    A supervised serial reader of the MPU9250 frames (or the ASCII lines).

    :param port: device path.
    :param baud: baud rate.
    :param fmt: ``binary`` (frames of interface.md §1 and §1b) or ``ascii``.
    :param timestamp: ``device`` (the device clock mapped onto host time) or ``host``.
    :param open_port: ``open_port(path, baud, timeout)`` -> an object with ``in_waiting``,
        ``read(n)``, ``write(data)``, ``close()`` (default :func:`open_serial`).
    :param clock: object with ``monotonic()``, ``host()`` and ``sleep(seconds, event)``
        (default :class:`SystemClock`).
    :param logger: object with ``info``, ``warning`` and ``error`` methods (default: none).
    :param on_samples: ``on_samples(frames, stamps)``: RawFrames and their host stamps, s.
    :param on_info: ``on_info(info)``: an InfoFrame from the firmware.
    :param reconnect_min_s: first delay before opening the port again, s.
    :param reconnect_max_s: longest such delay, s.
    :param watchdog_s: no valid frame for this long reopens the port, s.
    :param temp_range: plausible temperature counts for the parser (binary).
    """

    def __init__(self, port, baud, fmt='binary', timestamp='device', open_port=None,
                 clock=None, logger=None, on_samples=None, on_info=None,
                 reconnect_min_s=0.2, reconnect_max_s=5.0, watchdog_s=0.5, temp_range=None):
        self.port = port
        self.baud = baud
        self.format = fmt
        self.timestamp = timestamp
        self.open_port = open_port or open_serial
        self.clock = clock or SystemClock()
        self.log = logger or _Quiet()
        self.on_samples = on_samples or (lambda frames, stamps: None)
        self.on_info = on_info or (lambda info: None)
        self.reconnect_min_s = reconnect_min_s
        self.reconnect_max_s = reconnect_max_s
        self.watchdog_s = watchdog_s
        self.parser = FrameParser(temp_range=temp_range) if fmt == 'binary' \
            else AsciiLineParser()
        self.binary = fmt == 'binary'
        self.stamper = Stamper(timestamp)
        self._queue = []                # (frame, stamp token, arrival): not yet delivered
        self.info = None                # the firmware's last info frame
        self.connected = False
        self.reconnects = 0
        self.reader_errors = 0
        self.watchdog_reopens = 0
        self.last_error = ''
        self.last_reader_error = ''
        self.opened_at = None           # monotonic time the port was (re)opened
        self.first_open_at = None
        self.last_frame_at = None       # monotonic time of the last valid frame
        self._port = None
        self._info_requests = 0
        self._watchdog_wait = watchdog_s
        self._delay = reconnect_min_s
        self._next_open = -float('inf')
        self._outage_logged = False
        self._ever_connected = False
        self._logged = {}
        self._reopen = threading.Event()
        self._stop = threading.Event()
        self._thread = None

    # -- control -------------------------------------------------------------------------

    def start(self):
        """Start the reader thread."""
        self._thread = threading.Thread(target=self.run, name='serial_link', daemon=True)
        self._thread.start()

    def stop(self, timeout=2.0):
        """Stop the reader (and wait for it up to ``timeout`` s); the port is closed."""
        self._stop.set()
        if self._thread is not None and self._thread.is_alive() and \
                self._thread is not threading.current_thread():
            self._thread.join(timeout=timeout)

    @property
    def stopped(self):
        """Whether :meth:`stop` was called."""
        return self._stop.is_set()

    def reopen(self, port=None, baud=None):
        """Reopen the port (at a new path or baud rate) from the reader thread."""
        if port is not None:
            self.port = port
        if baud is not None:
            self.baud = baud
        self._reopen.set()

    def _throttled(self, kind, level, text):
        now = self.clock.monotonic()
        if now - self._logged.get(kind, -float('inf')) >= LOG_PERIOD_S:
            self._logged[kind] = now
            getattr(self.log, level)(text)

    # -- the reader ----------------------------------------------------------------------

    def run(self):
        """Read until :meth:`stop` (the reader thread's body); the port is closed at the end."""
        while not self._stop.is_set():
            self.step()
        self._drop_port()

    def step(self):
        """
        Do one thing and never raise: reopen, or wait to open, or open, or read once.

        Supervision: an exception is logged (throttled), counted in ``reader_errors``, the
        parser and the clock mapping start afresh, and the next step goes on.
        """
        try:
            self._step()
        except Exception as err:        # noqa: B902 - nothing may stop the reader for good
            self.reader_errors += 1
            self.last_reader_error = f'{type(err).__name__}: {err}'
            self._throttled(
                'reader', 'error',
                f'serial reader failed ({self.last_reader_error}); restarting it '
                f'(reader_errors {self.reader_errors} in /diagnostics)')
            self.parser.reset()         # the partial frame and the sequence are suspect
            self.clock.sleep(READ_TIMEOUT_S, self._stop)

    def _step(self):
        if self._reopen.is_set():
            self._reopen.clear()
            self._drop_port()
            self.log.info(f'reopening {self.port} at {self.baud} baud')
        elif self._port is not None and self._watchdog_due():
            self._drop_port()
            self.watchdog_reopens += 1
            self._throttled(
                'watchdog', 'warning',
                f'no valid frame for {self.clock.monotonic() - self._silent_since():.1f} s: '
                f'reopening {self.port} (watchdog; {self.watchdog_reopens} so far)')
            self._watchdog_wait = min(self._watchdog_wait * 2.0,
                                      max(self.reconnect_max_s, self.watchdog_s))
            self._ever_connected = False    # a reopen, not a reconnection after an outage
        if self._port is None and not self._open():
            return
        try:
            ser = self._port
            waiting = ser.in_waiting
            data = ser.read(waiting if waiting else 1)
        except (OSError, serial.SerialException) as err:
            self._drop_port()
            self.last_error = str(err)
            if not self._stop.is_set():
                self.log.warning(f'lost {self.port}: {err}; reconnecting with back-off')
                self._outage_logged = True
            return
        host = self.clock.host()
        if data:
            self._handle(self.parser.feed(data), host)
        else:                           # a pause: the held newest frame, and what waited
            self._deliver(self.parser.flush() if self.binary else [], host)
        self._maybe_request_info()

    def _open(self):
        """Open the port when its back-off delay has passed; return whether it is open."""
        now = self.clock.monotonic()
        if now < self._next_open:
            self.clock.sleep(self._next_open - now, self._stop)
            return False
        try:
            self._port = self.open_port(self.port, self.baud, READ_TIMEOUT_S)
        except PORT_ERRORS as err:
            self.last_error = str(err)
            if not self._outage_logged:
                self.log.warning(f'cannot open {self.port}: {err}; retrying with back-off up '
                                 f'to {self.reconnect_max_s:g} s')
                self._outage_logged = True
            self._next_open = now + self._delay
            self._delay = min(self._delay * 2.0, self.reconnect_max_s)
            return False
        self.parser.reset()
        first_open = self.opened_at is None
        self.opened_at = self.clock.monotonic()
        if first_open:
            self.first_open_at = self.opened_at
        self._info_requests = 0
        self.connected = True
        self._delay = self.reconnect_min_s
        self._next_open = -float('inf')
        if self._ever_connected:
            self.reconnects += 1
            self.log.info(f'reconnected to {self.port}')
        elif first_open:
            self.log.info(f'connected to {self.port}')
        self._ever_connected = True
        self._outage_logged = False
        return True

    def _drop_port(self):
        port, self._port = self._port, None
        self.connected = False
        if port is not None:
            try:
                port.close()
            except Exception:           # noqa: B902 - closing a dead port may fail any way
                pass

    def _silent_since(self):
        """Return the monotonic time since which no valid frame came (None: no port)."""
        if self.opened_at is None:
            return None
        if self.last_frame_at is None:
            return self.opened_at
        return max(self.last_frame_at, self.opened_at)

    def _watchdog_due(self):
        """Whether the watchdog should reopen the port now."""
        since = self._silent_since()
        if since is None:
            return False
        now = self.clock.monotonic()
        info = self.info
        if info is not None and info.status != 0:
            return False                # the link works; the firmware says why it is idle
        return now - since >= self._watchdog_wait and now - self.opened_at >= OPEN_GRACE_S

    def _maybe_request_info(self):
        """Ask the firmware for its info frame when none came soon after connecting."""
        if not self.binary or self.info is not None or self._port is None or \
                self._info_requests >= 3:
            return
        if self.clock.monotonic() - self.opened_at < INFO_WAIT_S * (1 + 2 * self._info_requests):
            return
        self._info_requests += 1
        try:
            self._port.write(INFO_REQUEST)
        except (OSError, serial.SerialException):
            pass

    # -- frames --------------------------------------------------------------------------

    @property
    def clock_mapper(self):
        """The device clock mapping (:class:`~accel_calib_ros.dataio.wire.clock.ClockMapper`)."""
        return self.stamper.mapper

    def _handle(self, frames, host):
        if self.binary:
            for info in self.parser.take_infos():
                self.info = info
                self.on_info(info)
        self._deliver(frames, host)

    def _deliver(self, frames, host):
        """Queue a read's frames with their stamp tokens; hand on what need not wait."""
        if frames:
            now = self.clock.monotonic()
            self.last_frame_at = now
            self._watchdog_wait = self.watchdog_s
            tokens = self.stamper.observe(frames, host)
            self._queue.extend((f, t, now) for f, t in zip(frames, tokens))
        if self._queue and (self.stamper.ready or
                            self.clock.monotonic() - self._queue[0][2] >= HOLD_MAX_S):
            # Stamped now, not on arrival: a burst that waited in the OS buffer before the
            # mapping settled is placed by the device clock, not at its arrival.
            queue, self._queue = self._queue, []
            self.on_samples([f for f, _, _ in queue],
                            self.stamper.stamps([t for _, t, _ in queue]))

    # -- state for the diagnostics -------------------------------------------------------

    def snapshot(self):
        """
        Return the link's state at this moment as a dict (for :func:`~.health.assess`).

        Keys: ``time`` (monotonic), ``counters`` (the parser's, with ``crc_errors``,
        ``lost_frames`` and ``rejected`` always present), ``connected``, ``last_error``,
        ``reconnects``, ``reader_errors``, ``last_reader_error``, ``watchdog_reopens``,
        ``last_frame_at``, ``first_open_at``, ``opened_at``, ``stopped``, ``binary``, ``format``,
        ``timestamp``, ``baud``, ``port``, ``info``, and for the binary format ``version``,
        ``quality``, ``strict``, ``jitter_us``, ``period_us``; ``drift_ppm`` with device
        timestamps.
        """
        parser = self.parser
        c = parser.counters()
        c.setdefault('crc_errors', c.get('bad_lines', 0))
        c.setdefault('lost_frames', 0)
        c.setdefault('rejected', 0)
        snap = {'time': self.clock.monotonic(), 'counters': c, 'connected': self.connected,
                'last_error': self.last_error, 'reconnects': self.reconnects,
                'reader_errors': self.reader_errors,
                'last_reader_error': self.last_reader_error,
                'watchdog_reopens': self.watchdog_reopens,
                'last_frame_at': self.last_frame_at, 'first_open_at': self.first_open_at,
                'opened_at': self.opened_at, 'stopped': self._stop.is_set(),
                'binary': self.binary, 'format': self.format,
                'timestamp': self.timestamp, 'baud': self.baud, 'port': self.port,
                'info': self.info}
        if self.binary:
            snap.update({'version': parser.version, 'quality': parser.quality,
                         'strict': parser.strict, 'jitter_us': parser.jitter_us,
                         'period_us': parser.period_us})
        if self.timestamp == 'device':
            snap['drift_ppm'] = self.clock_mapper.drift_ppm
        snap['stamps_clamped'] = self.stamper.clamped
        return snap
