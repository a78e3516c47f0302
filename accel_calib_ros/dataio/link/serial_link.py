"""
The serial link: open, back-off, watchdog, info request, supervision; ROS-free.

A :class:`SerialLink` owns the port, the frame parser and the stamps. Its reader thread
(:meth:`SerialLink.run`) repeats :meth:`SerialLink.step` (one read, or one wait for the
next attempt to open the port) and survives any exception in it: the exception is counted
(``reader_errors``), logged at most every 10 s, and the reader goes on. Samples go to
``on_samples(frames, stamps)``, info frames to ``on_info(info)``, a new connection to
``on_connect()``, all called from the reader thread. The port is opened by
``open_port(path, baud, timeout)`` and time comes from ``clock`` (``monotonic()``,
``host()``, ``sleep(seconds, event)``): the tests give a fake port and a fake clock and
step the link by hand. :meth:`SerialLink.snapshot` is taken under the reader's lock, so a
diagnostics thread never sees its state half-changed.

What a reopen keeps (after a watchdog timeout or an outage: the same port at the same
rate): the bytes the device sent while the port was closed (no flush: they are real
samples, stamped by their device clock, their gaps counted), the parser's partial frame and
loss baseline, the clock mapping. What it forgets: the firmware's info frame (the device
may have restarted or been swapped); it is asked for again at once, and frames wait for it
(at most :data:`HOLD_MAX_S`) so that they are never converted with ranges the device does
not use. The input is flushed only when what the OS holds is known not to belong to this
session: at the first open (bytes from before the driver started, possibly minutes old; an
Uno restarts on that open anyway), and when the port or the baud rate changes (another
device's bytes, or bytes received at the wrong rate: garbage).
"""

import threading
import time

import serial

from ..wire import AsciiLineParser, FrameParser
from ..wire.clock import Stamper

READ_TIMEOUT_S = 0.05
"""A read returns after this long without a byte."""
INFO_REQUEST = b'?'
INFO_WAIT_S = 1.0
"""The info frame is asked for on opening the port, then again after this long (3 times)."""
INFO_STALE_S = 2.5
"""A firmware that does not stream repeats its info frame every second: a "not streaming"
status older than this is no longer the device's state (the link went silent)."""
LOG_PERIOD_S = 10.0
"""At most one log line per this many seconds about reader failures (and watchdog reopens)."""
OPEN_GRACE_S = 2.0
"""The watchdog does not reopen a port within this many seconds of opening it (an Arduino
Uno resets when its port is opened: bootloader and sensor start-up take about 1.5 s)."""
HOLD_MAX_S = 1.5
"""Frames are never held back longer than this (for the info frame, or for the clock
mapping to settle)."""
PORT_ERRORS = (OSError, serial.SerialException, ValueError)


class _KeepingSerial(serial.Serial):
    """pyserial's Serial without the input flush its POSIX ``open()`` does."""

    _opening = False

    def open(self):                     # noqa: A003 - pyserial's own name
        """Open the port, keeping what the OS buffered for it."""
        self._opening = True
        try:
            super().open()
        finally:
            self._opening = False

    def _reset_input_buffer(self):
        if not self._opening:
            super()._reset_input_buffer()


def open_serial(path, baud, timeout):
    """
    Open a serial port with pyserial, keeping the bytes the OS holds for it.

    pyserial's own ``open()`` flushes them (``tcflush``); they are samples the device sent
    while the port was closed (a reopen, a replug), so they are kept.

    :return: the open ``serial.Serial``.
    :raises serial.SerialException, OSError, ValueError: it cannot be opened.
    """
    return _KeepingSerial(path, baud, timeout=timeout)


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
        ``read(n)``, ``write(data)``, ``reset_input_buffer()``, ``close()`` (default
        :func:`open_serial`).
    :param clock: object with ``monotonic()``, ``host()`` and ``sleep(seconds, event)``
        (default :class:`SystemClock`).
    :param logger: object with ``info``, ``warning`` and ``error`` methods (default: none).
    :param on_samples: ``on_samples(frames, stamps)``: RawFrames and their host stamps, s.
    :param on_info: ``on_info(info)``: an InfoFrame from the firmware.
    :param on_connect: ``on_connect()``: the port was (re)opened; the info is forgotten.
    :param reconnect_min_s: first delay before opening the port again, s.
    :param reconnect_max_s: longest such delay, s.
    :param watchdog_s: no valid frame for this long reopens the port, s.
    :param temp_range: plausible temperature counts for the parser (binary).
    :param hold_for_info: binary format: frames wait for the connection's info frame (the
        ranges they are converted with), at most :data:`HOLD_MAX_S`.
    """

    def __init__(self, port, baud, fmt='binary', timestamp='device', open_port=None,
                 clock=None, logger=None, on_samples=None, on_info=None, on_connect=None,
                 reconnect_min_s=0.2, reconnect_max_s=5.0, watchdog_s=0.5, temp_range=None,
                 hold_for_info=True):
        self.port = port
        self.baud = baud
        self.format = fmt
        self.timestamp = timestamp
        self.open_port = open_port or open_serial
        self.clock = clock or SystemClock()
        self.log = logger or _Quiet()
        self.on_samples = on_samples or (lambda frames, stamps: None)
        self.on_info = on_info or (lambda info: None)
        self.on_connect = on_connect or (lambda: None)
        self.reconnect_min_s = reconnect_min_s
        self.reconnect_max_s = reconnect_max_s
        self.watchdog_s = watchdog_s
        self.hold_for_info = hold_for_info
        self.binary = fmt == 'binary'
        self.parser = FrameParser(temp_range=temp_range) if self.binary else AsciiLineParser()
        self.stamper = Stamper(timestamp)
        self.info = None                # this connection's info frame (None: not yet)
        self.info_at = None             # monotonic time it came
        self.connected = False
        self.reconnects = 0
        self.reader_errors = 0
        self.watchdog_reopens = 0
        self.info_timeouts = 0          # connections whose frames waited for no info frame
        self.last_error = ''
        self.last_reader_error = ''
        self.opened_at = None           # monotonic time the port was (re)opened
        self.first_open_at = None
        self.last_frame_at = None       # monotonic time of the last valid frame
        self._port = None
        self._queue = []                # (frame, stamp token, arrival): not yet delivered
        self._expect_info = True        # False once a source proved it sends none
        self._flush_next = True         # the first open: what waited predates us
        self._info_requests = 0
        self._info_asked_at = None
        self._watchdog_wait = watchdog_s
        self._delay = reconnect_min_s
        self._next_open = -float('inf')
        self._outage_logged = False
        self._ever_connected = False
        self._logged = {}
        self._lock = threading.Lock()
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
        """Reopen the port from the reader thread (a new path or rate: its input flushed)."""
        if port is not None and port != self.port:
            self.port = port
            self._flush_next = True     # another device's bytes
        if baud is not None and baud != self.baud:
            self.baud = baud
            self._flush_next = True     # what came at the old rate is garbage
        self._reopen.set()

    def _throttled(self, kind, level, text):
        now = self.clock.monotonic()
        if now - self._logged.get(kind, -float('inf')) >= LOG_PERIOD_S:
            self._logged[kind] = now
            getattr(self.log, level)(text)

    @property
    def clock_mapper(self):
        """Return the device clock mapping (the ClockMapper of ``dataio/wire/clock.py``)."""
        return self.stamper.mapper

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
        parser forgets its partial frame (its state is suspect; the loss baseline stays),
        and the next step goes on.
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
            with self._lock:
                self.parser.reset()
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
        with self._lock:
            if data:
                frames = self.parser.feed(data, host) if self.binary else self.parser.feed(data)
                infos = self.parser.take_infos() if self.binary else []
            else:                       # a pause: the held newest frame, and what waited
                frames = self.parser.flush() if self.binary else []
                infos = []
            now = self.clock.monotonic()
            for info in infos:
                self.info, self.info_at = info, now
                self._expect_info = True
            ready = self._queue_frames(frames, host, now)
        for info in infos:
            self.on_info(info)
        if ready:
            self.on_samples(*ready)
        self._maybe_request_info()

    def _open(self):
        """Open the port when its back-off delay has passed; return whether it is open."""
        now = self.clock.monotonic()
        if now < self._next_open:
            self.clock.sleep(self._next_open - now, self._stop)
            return False
        try:
            port = self.open_port(self.port, self.baud, READ_TIMEOUT_S)
        except PORT_ERRORS as err:
            self.last_error = str(err)
            if not self._outage_logged:
                self.log.warning(f'cannot open {self.port}: {err}; retrying with back-off up '
                                 f'to {self.reconnect_max_s:g} s')
                self._outage_logged = True
            self._next_open = now + self._delay
            self._delay = min(self._delay * 2.0, self.reconnect_max_s)
            return False
        if self._flush_next:
            self._flush_next = False
            try:
                port.reset_input_buffer()
            except (OSError, serial.SerialException):
                pass
        first_open = self.opened_at is None
        with self._lock:
            self._port = port
            self.stamper.mapper.reopened()      # the device may be another (its clock too)
            self.opened_at = self.clock.monotonic()
            if first_open:
                self.first_open_at = self.opened_at
            self.info = self.info_at = None     # the device may have restarted or changed
            self.connected = True
        self._info_requests = 0
        self._info_asked_at = None
        self._delay = self.reconnect_min_s
        self._next_open = -float('inf')
        if self._ever_connected:
            self.reconnects += 1
            self.log.info(f'reconnected to {self.port}')
        elif first_open:
            self.log.info(f'connected to {self.port}')
        self._ever_connected = True
        self._outage_logged = False
        self.on_connect()
        self._maybe_request_info()
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

    def status_current(self, now=None):
        """Whether the firmware's "not streaming" status is the device's state now."""
        info = self.info
        now = self.clock.monotonic() if now is None else now
        return info is not None and info.status != 0 and now - self.info_at < INFO_STALE_S

    def _watchdog_due(self):
        """Whether the watchdog should reopen the port now."""
        since = self._silent_since()
        if since is None:
            return False
        now = self.clock.monotonic()
        if self.status_current(now):
            return False                # the link works; the firmware says why it is idle
        return now - since >= self._watchdog_wait and now - self.opened_at >= OPEN_GRACE_S

    def _maybe_request_info(self):
        """Ask for the info frame on opening, then every INFO_WAIT_S while none came."""
        if not self.binary or self.info is not None or self._port is None or \
                self._info_requests >= 3:
            return
        now = self.clock.monotonic()
        if self._info_asked_at is not None and now - self._info_asked_at < INFO_WAIT_S:
            return
        self._info_requests += 1
        self._info_asked_at = now
        try:
            self._port.write(INFO_REQUEST)
        except (OSError, serial.SerialException):
            pass

    # -- frames --------------------------------------------------------------------------

    def _waiting_for_info(self):
        return self.binary and self.hold_for_info and self._expect_info and self.info is None

    def _queue_frames(self, frames, host, now):
        """
        Queue a read's frames with their stamp tokens; return what may go out now.

        Frames wait while the connection's info frame has not come (the ranges) and while
        the clock mapping settles (so a burst that waited in the OS buffer is placed by its
        device clock, not at its arrival), never longer than :data:`HOLD_MAX_S`. Stamps
        are made when they go out. Called under the lock.

        :return: (frames, stamps) or None.
        """
        if frames:
            self.last_frame_at = now
            self._watchdog_wait = self.watchdog_s
            tokens = self.stamper.observe(frames, host)
            self._queue.extend((f, t, now) for f, t in zip(frames, tokens))
        if not self._queue:
            return None
        waited = now - self._queue[0][2]
        if waited < HOLD_MAX_S and (self._waiting_for_info() or not self.stamper.ready):
            return None
        if self._waiting_for_info():
            self._expect_info = False   # a source without info frames: do not wait again
            self.info_timeouts += 1
            self.log.warning(f'no info frame from the device {HOLD_MAX_S:g} s after its first '
                             'frame: converting with the parameters (ranges, chip) until one '
                             'comes')
        queue, self._queue = self._queue, []
        return ([f for f, _, _ in queue], self.stamper.stamps([t for _, t, _ in queue]))

    # -- state for the diagnostics -------------------------------------------------------

    def snapshot(self):
        """
        Return the link's state at this moment as a dict (for :func:`~.link_health.assess`).

        Taken under the reader's lock: every value is of the same moment. Keys: ``time``
        (monotonic), ``counters`` (the parser's, with ``crc_errors``, ``lost_frames``,
        ``gaps_uncounted`` and ``rejected`` always present), ``connected``, ``last_error``,
        ``reconnects``, ``reader_errors``, ``last_reader_error``, ``watchdog_reopens``,
        ``last_frame_at``, ``first_open_at``, ``opened_at``, ``stopped``, ``binary``,
        ``format``, ``timestamp``, ``baud``, ``port``, ``info`` (this connection's),
        ``info_age_s``, ``status_current``, ``frames_held``, ``info_timeouts``,
        ``stamps_clamped``, ``clock_resets``, ``clock_step_s`` (the step of the device
        clock that started the newest mapping, s, or None), and for the binary format ``version``,
        ``quality``, ``strict``, ``jitter_us``, ``period_us``; ``drift_ppm`` with device
        timestamps.
        """
        with self._lock:
            parser = self.parser
            now = self.clock.monotonic()
            c = parser.counters()
            c.setdefault('crc_errors', c.get('bad_lines', 0))
            c.setdefault('lost_frames', 0)
            c.setdefault('gaps_uncounted', 0)
            c.setdefault('rejected', 0)
            snap = {'time': now, 'counters': c, 'connected': self.connected,
                    'last_error': self.last_error, 'reconnects': self.reconnects,
                    'reader_errors': self.reader_errors,
                    'last_reader_error': self.last_reader_error,
                    'watchdog_reopens': self.watchdog_reopens,
                    'last_frame_at': self.last_frame_at, 'first_open_at': self.first_open_at,
                    'opened_at': self.opened_at, 'stopped': self._stop.is_set(),
                    'binary': self.binary, 'format': self.format,
                    'timestamp': self.timestamp, 'baud': self.baud, 'port': self.port,
                    'info': self.info,
                    'info_age_s': None if self.info_at is None else now - self.info_at,
                    'status_current': self.status_current(now),
                    'frames_held': len(self._queue), 'info_timeouts': self.info_timeouts,
                    'stamps_clamped': self.stamper.clamped,
                    'clock_resets': self.clock_mapper.resets,
                    'clock_step_s': self.clock_mapper.last_step_s}
            if self.binary:
                snap.update({'version': parser.version, 'quality': parser.quality,
                             'strict': parser.strict, 'jitter_us': parser.jitter_us,
                             'period_us': parser.period_us})
            if self.timestamp == 'device':
                snap['drift_ppm'] = self.clock_mapper.drift_ppm
            return snap
