"""
ROS 2 node ``mpu9250_driver``: MPU9250 serial frames to ``sensor_msgs/Imu``.

Reads the binary frames of the interface spec, versions 1 and 2 told apart frame by frame
(or the ASCII line format), from a serial port in a background thread and publishes
``imu/data_raw`` (sensor_msgs/Imu, REP-145: orientation not reported, identity quaternion
with ``orientation_covariance[0] = -1``) and ``imu/temperature`` (sensor_msgs/Temperature,
at ``temperature_rate_hz``, stamped like the sample it comes from), both reliable with
depth 100, and, for frames that carry the AK8963 block (frame version 2, an MPU-9250 behind
firmware 2.x), ``imu/mag`` (sensor_msgs/MagneticField, tesla, in the accelerometer's frame:
x = y_mag, y = x_mag, z = −z_mag; 0.15 µT per count times the factory adjustment
(ASA − 128)/256 + 1 from the info frame; overflow samples (ST2 HOFL) are dropped and
counted; covariance from ``magnetic_field_stddev``, all zeros = unknown). Until the info
frame gives the ASA values, magnetometer samples are held back (at most 10 s after the port
opens; then they are published unadjusted and diagnostics say so). ``/diagnostics`` reports
the link at 1 Hz: frame version, frame rate, CRC
errors, rejected candidates, lost samples (``seq`` gaps, cross-checked with ``t_us``),
timing jitter, the sensor and the firmware's recoveries.

Supervision: the reader thread never dies: any exception is caught, counted
(``reader_errors``), logged at most every 10 s, and the reader starts over. A lost port is
logged once per outage and reopened with exponential back-off. The watchdog: no valid
frame for ``watchdog_s`` (0.5 s) makes ``/diagnostics`` ERROR and the port is reopened
(then again after 2 s, 4 s, ... up to ``reconnect_max_s``, and never within 2 s of opening
it: an Arduino restarts when its port is opened); diagnostics say OK only while frames
flow.

The firmware (``firmware/``, docs/firmware.md) sends an info frame at start-up and on
request ('?'): chip (WHO_AM_I), ranges, rate and baud. With ``ranges_from_device`` the
driver takes the ranges from it and, with ``chip: auto``, the temperature formula
(MPU-6050: counts/340 + 36.53 °C; MPU-6500/9250/9255: counts/333.87 + 21 °C). A chip
the firmware does not know is reported as an error. Once the sample rate is known the
driver warns when the baud rate cannot carry it (22-byte frames, 10 bits per byte).

Stamps (``timestamp``): ``device`` maps the microcontroller µs clock onto host time
(:class:`~accel_calib_ros.dataio.wire.clock.ClockMapper`: the transport jitter does not
reach the stamps); ``host`` uses the receive time, spread back over a batch by the
device clock.
"""

import math
import threading
import time

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu, MagneticField, Temperature
import serial

from .common import declare_parameters, Param, ParameterProblem, run, Throttled
from ..dataio.wire import (ACCEL_LSB_PER_G, AsciiLineParser, ClockMapper, Converter,
                           FRAME_V1_SIZE, FRAME_V2_SIZE, FrameParser, GYRO_LSB_PER_DPS,
                           MAG_AK8963, MagConverter, temp_counts_range, TEMP_FORMULAS)

NODE_NAME = 'mpu9250_driver'
QUEUE_DEPTH = 100
READ_TIMEOUT_S = 0.05
FORMATS = ('binary', 'ascii')
TIMESTAMPS = ('device', 'host')
CHIP_CHOICES = ('auto', 'mpu9250', 'mpu9255', 'mpu6500', 'mpu6050')
INFO_REQUEST = b'?'
INFO_WAIT_S = 1.5
READER_ERROR_LOG_S = 10.0
"""At most one log line per this many seconds about reader failures (and watchdog reopens)."""
OPEN_GRACE_S = 2.0
"""The watchdog does not reopen a port within this many seconds of opening it (an Arduino
Uno resets when its port is opened: bootloader and sensor start-up take about 1.5 s)."""
BITS_PER_BYTE = 10
MAG_ASA_WAIT_S = 10.0
"""Magnetometer samples wait this long after opening the port for the info frame's ASA."""
JITTER_WARN_US = 100.0
"""Device clock jitter above which the driver says once that the stamps carry it."""

PARAMS = [
    Param('port', '/dev/ttyACM0', 'serial device path (a change reopens the port)',
          empty_ok=False),
    Param('baud', 1_000_000, 'serial baud rate; the firmware default is 1000000 (a change '
          'reopens the port)', low=300, high=12_000_000),
    Param('frame_id', 'imu_link', 'frame_id of the messages', empty_ok=False),
    Param('accel_range_g', 2, 'accelerometer full scale, ±g (the info frame overrides it '
          'when ranges_from_device)', choices=tuple(ACCEL_LSB_PER_G)),
    Param('gyro_range_dps', 250, 'gyroscope full scale, ±°/s (the info frame overrides it '
          'when ranges_from_device)', choices=tuple(GYRO_LSB_PER_DPS)),
    Param('ranges_from_device', True, 'take ranges and chip from the firmware info frame'),
    Param('chip', 'auto', 'sensor for the temperature formula: auto (from the info frame, '
          'else MPU-9250), mpu9250, mpu9255, mpu6500 or mpu6050', choices=CHIP_CHOICES),
    Param('format', 'binary', 'wire format: binary or ascii', choices=FORMATS,
          read_only=True),
    Param('linear_acceleration_stddev', 0.03,
          'accelerometer noise, m/s² (diagonal covariance; 0 = unknown)', low=0.0),
    Param('angular_velocity_stddev', 0.002,
          'gyroscope noise, rad/s (diagonal covariance; 0 = unknown)', low=0.0),
    Param('magnetic_field_stddev', 0.0,
          'magnetometer noise, T (diagonal covariance of imu/mag; 0 = unknown)', low=0.0),
    Param('timestamp', 'device', 'stamps from the device clock mapped to host time (device) '
          'or from the receive time (host)', choices=TIMESTAMPS, read_only=True),
    Param('temperature_rate_hz', 10.0, 'imu/temperature publish rate, Hz (0 = every sample)',
          low=0.0, high=10000.0),
    Param('reconnect_min_s', 0.2, 'first reconnect delay, s', low=0.01, high=60.0),
    Param('reconnect_max_s', 5.0, 'longest reconnect delay, s', low=0.01, high=600.0),
    Param('watchdog_s', 0.5, 'no valid frame for this long: diagnostics ERROR and the port '
          'is reopened, s', low=0.05, high=60.0),
]


def _stamp(seconds):
    sec = math.floor(seconds)
    nanosec = min(int(round((seconds - sec) * 1e9)), 999_999_999)
    return Time(sec=int(sec), nanosec=nanosec)


class Mpu9250Driver(Node):
    """
    The driver node; see the module docstring.

    :param kwargs: passed to :class:`rclpy.node.Node` (``context``,
        ``parameter_overrides``, ...).
    :raises ParameterProblem: a parameter is invalid (nothing is started then).
    """

    def __init__(self, **kwargs):
        super().__init__(NODE_NAME, **kwargs)
        self.params = declare_parameters(self, PARAMS, self._on_change)
        p = self.params
        if p['reconnect_max_s'] < p['reconnect_min_s']:
            raise ParameterProblem("parameter 'reconnect_max_s' must be >= reconnect_min_s, "
                                   f"got {p['reconnect_max_s']:g} < {p['reconnect_min_s']:g}")
        self.port = p['port']
        self.baud = p['baud']
        self.frame_id = p['frame_id']
        self.format = p['format']
        self.timestamp = p['timestamp']
        self.reconnect_min_s = p['reconnect_min_s']
        self.reconnect_max_s = p['reconnect_max_s']
        self.device_info = None
        self.mag_published = 0
        self.mag_overflows = 0
        self.mag_held = 0
        self._mag_unadjusted_warned = False
        self._temp_period_s = 0.0
        self._last_temp_stamp = None
        self._apply_settings()
        self.parser = FrameParser(temp_range=self._temp_range()) \
            if self.format == 'binary' else AsciiLineParser()
        self.clock_mapper = ClockMapper()
        self._reopen = threading.Event()
        self._prev_stamp = None
        self._baud_warned = False
        self._info_requests = 0
        self._connected_at = None
        qos = QoSProfile(depth=QUEUE_DEPTH, history=HistoryPolicy.KEEP_LAST,
                         reliability=ReliabilityPolicy.RELIABLE)
        self.imu_pub = self.create_publisher(Imu, 'imu/data_raw', qos)
        self.temp_pub = self.create_publisher(Temperature, 'imu/temperature', qos)
        self.mag_pub = self.create_publisher(MagneticField, 'imu/mag', qos)
        self.diag_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self.connected = False
        self.reconnects = 0
        self.published = 0
        self._last_error = ''
        self.reader_errors = 0
        self._log_throttled = Throttled(self.get_logger(), READER_ERROR_LOG_S)
        self._last_reader_error = ''
        self.watchdog_s = p['watchdog_s']
        self.watchdog_reopens = 0
        self._watchdog_wait = self.watchdog_s
        self._opened_at = None          # monotonic time the port was (re)opened
        self._first_open_at = None
        self._last_frame_at = None      # monotonic time of the last valid frame
        self._jitter_warned = False
        self._diag_prev = (time.monotonic(), 0, 0, 0, 0, 0)
        self._stop = threading.Event()
        self._serial = None
        self._thread = threading.Thread(target=self._run, name='mpu9250_serial', daemon=True)
        self.create_timer(1.0, self._publish_diagnostics)
        self._thread.start()
        self.get_logger().info(
            f'reading {self.format} frames from {self.port} at {self.baud} baud, '
            f'±{self.accel_range_g} g, ±{self.gyro_range_dps} °/s, {self.timestamp} '
            'timestamps')

    # -- parameters ----------------------------------------------------------------------

    def _chip_formula(self):
        chip = self.params['chip']
        if chip == 'auto':
            info = self.device_info
            chip = 'mpu6050' if info is not None and info.who_am_i == 0x68 else 'mpu9250'
        return 'mpu6050' if chip == 'mpu6050' else 'mpu6500'

    def _temp_range(self):
        if self.params['chip'] == 'auto' and self.device_info is None:
            return temp_counts_range()
        return temp_counts_range(*TEMP_FORMULAS[self._chip_formula()])

    def _apply_settings(self):
        """Build converter and covariances from the parameters and the device info."""
        p = self.params
        accel, gyro = p['accel_range_g'], p['gyro_range_dps']
        info = self.device_info
        if p['ranges_from_device'] and info is not None and info.status == 0 \
                and info.accel_range_g in ACCEL_LSB_PER_G \
                and info.gyro_range_dps in GYRO_LSB_PER_DPS:
            accel, gyro = info.accel_range_g, info.gyro_range_dps
        self.accel_range_g, self.gyro_range_dps = accel, gyro
        self.converter = Converter(accel, gyro, self._chip_formula())
        accel_cov = [0.0] * 9
        gyro_cov = [0.0] * 9
        for k in (0, 4, 8):
            accel_cov[k] = p['linear_acceleration_stddev'] ** 2
            gyro_cov[k] = p['angular_velocity_stddev'] ** 2
        self.accel_cov, self.gyro_cov = accel_cov, gyro_cov
        mag_cov = [0.0] * 9
        for k in (0, 4, 8):
            mag_cov[k] = p['magnetic_field_stddev'] ** 2
        self.mag_cov = mag_cov
        asa = info.asa if info is not None and info.mag_status == MAG_AK8963 else None
        self.mag_converter = MagConverter(asa) if asa is not None else None
        rate = p['temperature_rate_hz']
        self._temp_period_s = 1.0 / rate if rate > 0 else 0.0
        self.frame_id = p['frame_id']
        self.reconnect_min_s = p['reconnect_min_s']
        self.reconnect_max_s = p['reconnect_max_s']
        self.watchdog_s = p['watchdog_s']
        parser = getattr(self, 'parser', None)
        if isinstance(parser, FrameParser):
            parser.temp_range = self._temp_range()

    def _on_change(self, changes):
        p = self.params
        if p['reconnect_max_s'] < p['reconnect_min_s']:
            raise ParameterProblem('reconnect_max_s must be >= reconnect_min_s')
        self._apply_settings()
        if 'port' in changes or 'baud' in changes:
            self.port, self.baud = p['port'], p['baud']
            self._baud_warned = False
            self._reopen.set()

    # -- device information --------------------------------------------------------------

    def _handle_info(self, info):
        old = self.device_info
        self.device_info = info
        if old is not None and old == info:
            return
        log = self.get_logger()
        if old is not None and info.recoveries > old.recoveries and \
                info[:8] == old[:8] and info.frame_version == old.frame_version:
            self._log_throttled(                # the firmware re-initialised the sensor
                'recovery', 'warning',
                f'the firmware recovered the sensor ({info.recovery_text}); '
                f'{info.recoveries} recoveries, {info.i2c_errors} failed I2C transfers since it '
                'started (firmware_recoveries in /diagnostics)')
            return
        text = (f'firmware {info.fw_version[0]}.{info.fw_version[1]}: {info.chip} '
                f'(WHO_AM_I 0x{info.who_am_i:02x}), ±{info.accel_range_g} g, '
                f'±{info.gyro_range_dps} °/s, {info.rate_hz} Hz, built for {info.baud} baud')
        if info.status != 0:
            log.error(f'{text}: {info.status_text}')
        else:
            log.info(text)
            if self.params['ranges_from_device'] and (
                    info.accel_range_g != self.params['accel_range_g']
                    or info.gyro_range_dps != self.params['gyro_range_dps']):
                log.info(f'using the ranges of the firmware (±{info.accel_range_g} g, '
                         f'±{info.gyro_range_dps} °/s), not the parameters')
        if info.baud != self.baud:
            log.warning(f'the firmware sends at {info.baud} baud but the port is opened at '
                        f'{self.baud}: set parameter baud to {info.baud}')
        self._apply_settings()

    def _check_capacity(self):
        """Warn once when the baud rate cannot carry the observed sample rate."""
        parser = self.parser
        if not isinstance(parser, FrameParser) or parser.period_us is None \
                or parser.frames < 50:
            return
        jitter = parser.jitter_us
        if not self._jitter_warned and jitter is not None and jitter > JITTER_WARN_US:
            self._jitter_warned = True
            self.get_logger().warning(
                f'the device stamps its samples with {jitter:.0f} µs of jitter (a firmware '
                'that stamps at read time?): frames are kept, and device timestamps carry '
                'the jitter (timing_jitter_us in /diagnostics)')
        if self._baud_warned:
            return
        rate = 1e6 / parser.period_us
        baud = self.baud
        if self.device_info is not None:
            baud = min(baud, self.device_info.baud)
        size = FRAME_V2_SIZE if parser.version == 2 else FRAME_V1_SIZE
        capacity = baud / (BITS_PER_BYTE * size)
        self._baud_warned = True
        if rate > capacity:
            self.get_logger().warning(
                f'{baud} baud carries at most {capacity:.0f} frames/s of {size} bytes '
                f'but the device samples at {rate:.0f} Hz: about '
                f'{100.0 * (1.0 - capacity / rate):.0f} % of the samples will be lost '
                '(lost_frames in /diagnostics); use 1000000 baud (firmware default)')

    # -- serial thread -------------------------------------------------------------------

    def _open(self):
        ser = serial.Serial(self.port, self.baud, timeout=READ_TIMEOUT_S)
        try:
            ser.reset_input_buffer()         # stale bytes from before we were listening
        except (OSError, serial.SerialException):
            pass
        return ser

    def _run(self):
        """Supervise the reader: an exception is logged (throttled), counted and restarts it."""
        while not self._stop.is_set():
            try:
                self._read_loop()
            except Exception as err:    # noqa: B902 - nothing may stop the reader for good
                self.reader_errors += 1
                self._last_reader_error = f'{type(err).__name__}: {err}'
                self._log_throttled(
                    'reader', 'error',
                    f'serial reader failed ({self._last_reader_error}); restarting it '
                    f'(reader_errors {self.reader_errors} in /diagnostics)')
                self.parser.reset()     # the partial frame and the sequence are suspect
                self.clock_mapper.reset()
                self._prev_stamp = None
                self._stop.wait(READ_TIMEOUT_S)
        self._drop_port()

    def _read_loop(self):
        delay = self.reconnect_min_s
        outage_logged = False
        ever_connected = self._opened_at is not None
        while not self._stop.is_set():
            if self._reopen.is_set():
                self._reopen.clear()
                self._drop_port()
                self.get_logger().info(f'reopening {self.port} at {self.baud} baud')
            elif self._serial is not None and self._watchdog_due():
                self._drop_port()
                self.watchdog_reopens += 1
                self._log_throttled(
                    'watchdog', 'warning',
                    f'no valid frame for {time.monotonic() - self._silent_since():.1f} s: '
                    f'reopening {self.port} (watchdog; {self.watchdog_reopens} so far)')
                self._watchdog_wait = min(self._watchdog_wait * 2.0,
                                          max(self.reconnect_max_s, self.watchdog_s))
                ever_connected = False      # a reopen, not a reconnection after an outage
            if self._serial is None:
                try:
                    self._serial = self._open()
                except (OSError, serial.SerialException, ValueError) as err:
                    self._last_error = str(err)
                    if not outage_logged:
                        self.get_logger().warning(
                            f'cannot open {self.port}: {err}; retrying with back-off up to '
                            f'{self.reconnect_max_s:g} s')
                        outage_logged = True
                    self._stop.wait(delay)
                    delay = min(delay * 2.0, self.reconnect_max_s)
                    continue
                self.parser.reset()
                self.clock_mapper.reset()
                self._prev_stamp = None
                first_open = self._opened_at is None
                self._connected_at = self._opened_at = time.monotonic()
                if first_open:
                    self._first_open_at = self._opened_at
                self._info_requests = 0
                self.connected = True
                delay = self.reconnect_min_s
                if ever_connected:
                    self.reconnects += 1
                    self.get_logger().info(f'reconnected to {self.port}')
                elif first_open:
                    self.get_logger().info(f'connected to {self.port}')
                ever_connected = True
                outage_logged = False
            try:
                ser = self._serial
                waiting = ser.in_waiting
                data = ser.read(waiting if waiting else 1)
            except (OSError, serial.SerialException) as err:
                self._drop_port()
                self._last_error = str(err)
                if not self._stop.is_set():
                    self.get_logger().warning(
                        f'lost {self.port}: {err}; reconnecting with back-off')
                    outage_logged = True
                continue
            if data:
                self._handle(data, self.get_clock().now().nanoseconds * 1e-9)
            elif isinstance(self.parser, FrameParser):
                self._publish(self.parser.flush(), self.get_clock().now().nanoseconds * 1e-9)
            self._maybe_request_info()

    def _silent_since(self):
        """Return the monotonic time since which no valid frame came (None: no port)."""
        if self._opened_at is None:
            return None
        if self._last_frame_at is None:
            return self._opened_at
        return max(self._last_frame_at, self._opened_at)

    def _watchdog_due(self):
        """Whether the watchdog should reopen the port now."""
        since = self._silent_since()
        if since is None:
            return False
        now = time.monotonic()
        info = self.device_info
        if info is not None and info.status != 0:
            return False                # the link works; the firmware says why it is idle
        return now - since >= self._watchdog_wait and now - self._opened_at >= OPEN_GRACE_S

    def _maybe_request_info(self):
        """Ask the firmware for its info frame when none came soon after connecting."""
        if self.format != 'binary' or self.device_info is not None or \
                self._serial is None or self._info_requests >= 3:
            return
        if time.monotonic() - self._connected_at < INFO_WAIT_S * (1 + 2 * self._info_requests):
            return
        self._info_requests += 1
        try:
            self._serial.write(INFO_REQUEST)
        except (OSError, serial.SerialException):
            pass

    def _drop_port(self):
        ser, self._serial = self._serial, None
        self.connected = False
        if ser is not None:
            try:
                ser.close()
            except Exception:           # noqa: B902 - closing a dead port may fail any way
                pass

    def _handle(self, data, host_s):
        frames = self.parser.feed(data)
        if isinstance(self.parser, FrameParser):
            for info in self.parser.take_infos():
                self._handle_info(info)
            self._check_capacity()
        self._publish(frames, host_s)

    def _publish(self, frames, host_s):
        if not frames:
            return
        self._last_frame_at = time.monotonic()
        self._watchdog_wait = self.watchdog_s
        stamps = self._stamps(frames, host_s)
        to_si = self.converter.to_si
        temp_period = self._temp_period_s
        for frame, stamp_s in zip(frames, stamps):
            (ax, ay, az), temp, (gx, gy, gz) = to_si(frame.counts)
            stamp = _stamp(stamp_s)
            imu = Imu()
            imu.header.stamp = stamp
            imu.header.frame_id = self.frame_id
            imu.orientation.w = 1.0              # REP-145: identity, covariance[0] = -1
            imu.orientation_covariance[0] = -1.0
            imu.angular_velocity.x = gx
            imu.angular_velocity.y = gy
            imu.angular_velocity.z = gz
            imu.angular_velocity_covariance = self.gyro_cov
            imu.linear_acceleration.x = ax
            imu.linear_acceleration.y = ay
            imu.linear_acceleration.z = az
            imu.linear_acceleration_covariance = self.accel_cov
            # Decimate by the device clock when there is one (bursts share host stamps).
            clock = stamp_s if frame.t_us is None else frame.t_us * 1e-6
            last = self._last_temp_stamp
            elapsed = None if last is None else (clock - last) % 4294.967296 \
                if frame.t_us is not None else clock - last
            send_temp = temp_period <= 0.0 or elapsed is None or elapsed < 0 or \
                elapsed >= temp_period * 0.999
            try:
                self.imu_pub.publish(imu)
                if send_temp:
                    msg = Temperature()
                    msg.header.stamp = stamp
                    msg.header.frame_id = self.frame_id
                    msg.temperature = temp
                    msg.variance = 0.0
                    self.temp_pub.publish(msg)
                    self._last_temp_stamp = clock
            except Exception:           # noqa: B902 - context shut down under us: stop
                self._stop.set()
                return
            self.published += 1
            if frame.mag is not None:
                self._publish_mag(frame.mag, stamp)

    def _publish_mag(self, block, stamp):
        """Publish one AK8963 sample (held until the ASA is known, dropped on overflow)."""
        conv = self.mag_converter
        if conv is None:
            info = self.device_info
            if info is not None and info.mag_status == MAG_AK8963:
                conv = self.mag_converter = MagConverter(info.asa)
            elif self._opened_at is not None and \
                    time.monotonic() - self._opened_at < MAG_ASA_WAIT_S and \
                    (info is None or info.info_version < 2):
                self.mag_held += 1              # the info frame with the ASA may come
                return
            else:
                conv = MagConverter()           # no ASA from this device: unadjusted
                if not self._mag_unadjusted_warned:
                    self._mag_unadjusted_warned = True
                    self.get_logger().warning(
                        'magnetometer samples without the AK8963 sensitivity adjustment (no '
                        'info frame with ASA values): imu/mag is unadjusted, up to ±50 % off')
        field = conv.to_tesla(block)
        if field is None:
            self.mag_overflows += 1             # ST2 HOFL: not a valid measurement
            return
        msg = MagneticField()
        msg.header.stamp = stamp
        msg.header.frame_id = self.frame_id
        msg.magnetic_field.x, msg.magnetic_field.y, msg.magnetic_field.z = field
        msg.magnetic_field_covariance = self.mag_cov
        try:
            self.mag_pub.publish(msg)
        except Exception:               # noqa: B902 - context shut down under us: stop
            self._stop.set()
            return
        self.mag_published += 1

    def _stamps(self, frames, host_s):
        if frames[-1].t_us is None:
            return [host_s] * len(frames)
        if self.timestamp == 'device':
            mapper = self.clock_mapper
            out = []
            prev = self._prev_stamp
            for f in frames:
                if f.t_us is None:
                    stamp = host_s
                    prev = None
                else:
                    stamp = mapper.update(f.t_us, host_s)
                    if prev is not None and stamp <= prev + 1e-6:
                        # A start-up burst maps many samples onto one receive time (the
                        # mapping is causal): keep the stamps strictly increasing.
                        stamp = prev + 1e-6
                    prev = stamp
                out.append(stamp)
            self._prev_stamp = prev
            return out
        last = frames[-1].t_us
        return [host_s - (((last - f.t_us) & 0xFFFFFFFF) * 1e-6 if f.t_us is not None else 0.0)
                for f in frames]

    # -- diagnostics ---------------------------------------------------------------------

    def counters(self):
        """Return the link counters as a dict (frames, crc_errors, lost_frames, ...)."""
        c = self.parser.counters()
        c.setdefault('crc_errors', c.get('bad_lines', 0))
        c.setdefault('lost_frames', 0)
        c.setdefault('rejected', 0)
        return c

    def _publish_diagnostics(self):
        self.diag_pub.publish(self.diagnostics())

    def diagnostics(self):
        """
        Return the link status for ``/diagnostics`` (one period since the last call).

        Levels: ERROR when not connected, when the firmware does not stream, when no valid
        frame came for ``watchdog_s``, when the reader failed in the period or the link is
        badly corrupted; WARN while waiting for the first frame after opening the port and
        when frames were lost, CRC errors seen or the firmware recovered the sensor in the
        period; OK only while frames flow cleanly.

        :return: DiagnosticArray with one DiagnosticStatus.
        """
        now = time.monotonic()
        c = self.counters()
        info = self.device_info
        recoveries = info.recoveries if info is not None else 0
        t0, frames0, errors0, lost0, failures0, recoveries0 = self._diag_prev
        self._diag_prev = (now, c['frames'], c['crc_errors'], c['lost_frames'],
                           self.reader_errors, recoveries)
        rate = (c['frames'] - frames0) / max(now - t0, 1e-3)
        new_errors = c['crc_errors'] - errors0
        new_lost = c['lost_frames'] - lost0
        # Since the last valid frame (or the first opening): a watchdog reopen does not
        # make the silence any shorter.
        since = self._last_frame_at if self._last_frame_at is not None else self._first_open_at
        silence = now - since if since is not None else math.inf
        status = DiagnosticStatus()
        status.name = f'{self.get_name()}: serial'
        status.hardware_id = self.port
        if not self.connected:
            status.level = DiagnosticStatus.ERROR
            status.message = f'not connected: {self._last_error}'
        elif info is not None and info.status != 0:
            status.level = DiagnosticStatus.ERROR
            status.message = f'firmware: {info.status_text}'
        elif silence >= self.watchdog_s and (self._last_frame_at is not None
                                             or silence >= OPEN_GRACE_S):
            status.level = DiagnosticStatus.ERROR
            status.message = f'no valid frame for {silence:.1f} s'
            if self.watchdog_reopens:
                status.message += f' (port reopened {self.watchdog_reopens} times)'
        elif rate <= 0 or silence >= self.watchdog_s:
            status.level = DiagnosticStatus.WARN
            status.message = 'connected, waiting for the first frame' \
                if self._last_frame_at is None else f'no valid frame for {silence:.1f} s'
        elif self.reader_errors > failures0:
            status.level = DiagnosticStatus.ERROR
            status.message = (f'serial reader failed and was restarted: '
                              f'{self._last_reader_error}')
        elif isinstance(self.parser, FrameParser) and self.parser.strict:
            status.level = DiagnosticStatus.ERROR
            status.message = (f'link badly corrupted (quality {self.parser.quality:.2f}): only '
                              'frames confirmed by both neighbours are published')
        elif recoveries > recoveries0:
            status.level = DiagnosticStatus.WARN
            status.message = (f'the firmware recovered the sensor {recoveries - recoveries0} '
                              f'times in the last period ({info.recovery_text}); '
                              f'{new_lost} samples lost')
        elif new_errors or new_lost:
            status.level = DiagnosticStatus.WARN
            status.message = f'{new_errors} CRC errors, {new_lost} lost frames in the last period'
            if new_lost and c['frames'] > frames0:
                share = new_lost / (new_lost + c['frames'] - frames0)
                status.message += f' ({100.0 * share:.1f} % of the samples)'
        else:
            status.level = DiagnosticStatus.OK
            status.message = 'streaming'
        parser = self.parser
        binary = isinstance(parser, FrameParser)
        version = parser.version if binary else None
        values = {'frame_rate_hz': f'{rate:.1f}', 'frames': c['frames'],
                  'frame_version': version if version else ('ascii' if not binary else 'none'),
                  'crc_errors': c['crc_errors'], 'lost_frames': c['lost_frames'],
                  'bytes_skipped': c['bytes_skipped'], 'connected': self.connected,
                  'rejected': c['rejected'], 'reconnects': self.reconnects,
                  'reader_errors': self.reader_errors,
                  'watchdog_reopens': self.watchdog_reopens,
                  'last_frame_age_s': f'{silence:.2f}' if math.isfinite(silence) else 'none',
                  'format': self.format, 'timestamp': self.timestamp, 'baud': self.baud,
                  'accel_range_g': self.accel_range_g, 'gyro_range_dps': self.gyro_range_dps,
                  'temperature_formula': self.converter.temp_formula}
        if binary:
            values['link_quality'] = f'{parser.quality:.3f}'
            values['frames_v1'] = c['frames_v1']
            values['frames_v2'] = c['frames_v2']
            values['timing_jitter_frames'] = c['timing_jitter']
            jitter = parser.jitter_us
            values['timing_jitter_us'] = 'unknown' if jitter is None else f'{jitter:.0f}'
            values['parser_errors'] = c['internal_errors']
            if parser.period_us:
                values['device_rate_hz'] = f'{1e6 / parser.period_us:.1f}'
        if info is not None:
            values.update({'chip': info.chip, 'who_am_i': f'0x{info.who_am_i:02x}',
                           'firmware_status': info.status_text,
                           'firmware_version': f'{info.fw_version[0]}.{info.fw_version[1]}',
                           'firmware_rate_hz': info.rate_hz, 'firmware_baud': info.baud})
            if info.info_version >= 2:
                values.update({'firmware_frame_version': info.frame_version,
                               'firmware_recoveries': info.recoveries,
                               'firmware_i2c_errors': info.i2c_errors,
                               'firmware_last_recovery': info.recovery_text})
        values.update(self._mag_diagnostics(c))
        if self.timestamp == 'device':
            values['clock_drift_ppm'] = f'{self.clock_mapper.drift_ppm:.1f}'
        status.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        array = DiagnosticArray()
        array.header.stamp = self.get_clock().now().to_msg()
        array.status = [status]
        return array

    def _mag_diagnostics(self, counters):
        """Return the magnetometer's diagnostic values."""
        info = self.device_info
        conv = self.mag_converter
        if info is not None and info.info_version >= 2:
            text = info.mag_text
            if info.mag_status != MAG_AK8963:
                text += f' ({info.chip}): no imu/mag'
        elif counters.get('mag_frames'):
            text = 'AK8963 block in the frames, no info frame from the firmware'
        else:
            text = 'not reported (no info frame of version 2): no imu/mag'
        return {'magnetometer': text, 'mag_frames': counters.get('mag_frames', 0),
                'mag_published': self.mag_published, 'mag_overflows': self.mag_overflows,
                'mag_held_for_asa': self.mag_held,
                'mag_asa': ' '.join(str(a) for a in conv.asa) if conv is not None
                else 'unknown'}

    def destroy_node(self):
        """Stop the serial thread, close the port, then destroy the node."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)
        return super().destroy_node()


def build_node(context=None, parameter_overrides=None):
    """
    Build the driver node (for running it in-process, e.g. in a demo or a test).

    :param context: rclpy Context (default: the global one, already initialised).
    :param parameter_overrides: list of rclpy.parameter.Parameter.
    :return: Mpu9250Driver (its serial thread is already running).
    :raises ParameterProblem: a parameter is invalid.
    """
    return Mpu9250Driver(context=context, parameter_overrides=parameter_overrides or [])


def main(args=None):
    """Run the node until Ctrl-C; exit status 2 on a bad parameter."""
    run(Mpu9250Driver, NODE_NAME, args)


if __name__ == '__main__':
    main()
