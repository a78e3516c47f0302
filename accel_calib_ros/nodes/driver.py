"""
ROS 2 node ``mpu9250_driver``: MPU9250 serial frames to ``sensor_msgs/Imu``.

Reads the binary frame of the interface spec (or the ASCII line format) from a serial
port in a background thread and publishes ``imu/data_raw`` (sensor_msgs/Imu,
REP-145: orientation not reported, identity quaternion with
``orientation_covariance[0] = -1``) and ``imu/temperature`` (sensor_msgs/Temperature,
at ``temperature_rate_hz``, stamped like the sample it comes from), both reliable with
depth 100. A lost port is logged once per outage and reopened with exponential
back-off; ``/diagnostics`` reports the link at 1 Hz: frame rate, CRC errors, rejected
candidates, lost samples (``seq`` gaps, cross-checked with ``t_us``) and the sensor.

The firmware (``firmware/``, docs/firmware.md) sends an info frame at start-up and on
request ('?'): chip (WHO_AM_I), ranges, rate and baud. With ``ranges_from_device`` the
driver takes the ranges from it and, with ``chip: auto``, the temperature formula
(MPU-6050: counts/340 + 36.53 °C; MPU-6500/9250/9255: counts/333.87 + 21 °C). A chip
the firmware does not know is reported as an error. Once the sample rate is known the
driver warns when the baud rate cannot carry it (22-byte frames, 10 bits per byte).

Stamps (``timestamp``): ``device`` maps the microcontroller µs clock onto host time
(:class:`~accel_calib_ros.dataio.mpu9250_frame.ClockMapper`: the transport jitter does not
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
from sensor_msgs.msg import Imu, Temperature
import serial

from .common import declare_parameters, Param, ParameterProblem, run
from ..dataio.mpu9250_frame import (ACCEL_LSB_PER_G, AsciiLineParser, ClockMapper, Converter,
                                    FRAME_SIZE, FrameParser, GYRO_LSB_PER_DPS,
                                    temp_counts_range, TEMP_FORMULAS)

NODE_NAME = 'mpu9250_driver'
QUEUE_DEPTH = 100
READ_TIMEOUT_S = 0.05
FORMATS = ('binary', 'ascii')
TIMESTAMPS = ('device', 'host')
CHIP_CHOICES = ('auto', 'mpu9250', 'mpu9255', 'mpu6500', 'mpu6050')
INFO_REQUEST = b'?'
INFO_WAIT_S = 1.5
READER_ERROR_LOG_S = 10.0
"""At most one log line per this many seconds about reader failures."""
BITS_PER_BYTE = 10

PARAMS = [
    Param('port', '/dev/ttyUSB0', 'serial device path (a change reopens the port)',
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
    Param('timestamp', 'device', 'stamps from the device clock mapped to host time (device) '
          'or from the receive time (host)', choices=TIMESTAMPS, read_only=True),
    Param('temperature_rate_hz', 10.0, 'imu/temperature publish rate, Hz (0 = every sample)',
          low=0.0, high=10000.0),
    Param('reconnect_min_s', 0.2, 'first reconnect delay, s', low=0.01, high=60.0),
    Param('reconnect_max_s', 5.0, 'longest reconnect delay, s', low=0.01, high=600.0),
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
        self.diag_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self.connected = False
        self.reconnects = 0
        self.published = 0
        self._last_error = ''
        self.reader_errors = 0
        self._last_reader_error = ''
        self._reader_error_logged = -math.inf
        self._diag_prev = (time.monotonic(), 0, 0, 0, 0)
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
        rate = p['temperature_rate_hz']
        self._temp_period_s = 1.0 / rate if rate > 0 else 0.0
        self.frame_id = p['frame_id']
        self.reconnect_min_s = p['reconnect_min_s']
        self.reconnect_max_s = p['reconnect_max_s']
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
        if self._baud_warned or not isinstance(parser, FrameParser) \
                or parser.period_us is None or parser.frames < 50:
            return
        rate = 1e6 / parser.period_us
        baud = self.baud
        if self.device_info is not None:
            baud = min(baud, self.device_info.baud)
        capacity = baud / (BITS_PER_BYTE * FRAME_SIZE)
        self._baud_warned = True
        if rate > capacity:
            self.get_logger().warning(
                f'{baud} baud carries at most {capacity:.0f} frames/s of {FRAME_SIZE} bytes '
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
                now = time.monotonic()
                if now - self._reader_error_logged >= READER_ERROR_LOG_S:
                    self._reader_error_logged = now
                    self.get_logger().error(
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
        ever_connected = False
        while not self._stop.is_set():
            if self._reopen.is_set():
                self._reopen.clear()
                self._drop_port()
                self.get_logger().info(f'reopening {self.port} at {self.baud} baud')
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
                self._connected_at = time.monotonic()
                self._info_requests = 0
                self.connected = True
                delay = self.reconnect_min_s
                if ever_connected:
                    self.reconnects += 1
                    self.get_logger().info(f'reconnected to {self.port}')
                else:
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
        now = time.monotonic()
        c = self.counters()
        t0, frames0, errors0, lost0, failures0 = self._diag_prev
        self._diag_prev = (now, c['frames'], c['crc_errors'], c['lost_frames'],
                           self.reader_errors)
        rate = (c['frames'] - frames0) / max(now - t0, 1e-3)
        new_errors = c['crc_errors'] - errors0
        new_lost = c['lost_frames'] - lost0
        status = DiagnosticStatus()
        status.name = f'{self.get_name()}: serial'
        status.hardware_id = self.port
        if not self.connected:
            status.level = DiagnosticStatus.ERROR
            status.message = f'not connected: {self._last_error}'
        elif self.device_info is not None and self.device_info.status != 0:
            status.level = DiagnosticStatus.ERROR
            status.message = f'firmware: {self.device_info.status_text}'
        elif rate <= 0:
            status.level = DiagnosticStatus.WARN
            status.message = 'connected, no frames'
        elif self.reader_errors > failures0:
            status.level = DiagnosticStatus.ERROR
            status.message = (f'serial reader failed and was restarted: '
                              f'{self._last_reader_error}')
        elif isinstance(self.parser, FrameParser) and self.parser.strict:
            status.level = DiagnosticStatus.ERROR
            status.message = (f'link badly corrupted (quality {self.parser.quality:.2f}): only '
                              'frames confirmed by both neighbours are published')
        elif new_errors or new_lost:
            status.level = DiagnosticStatus.WARN
            status.message = f'{new_errors} CRC errors, {new_lost} lost frames in the last period'
            if new_lost and c['frames'] > frames0:
                share = new_lost / (new_lost + c['frames'] - frames0)
                status.message += f' ({100.0 * share:.1f} % of the samples)'
        else:
            status.level = DiagnosticStatus.OK
            status.message = 'streaming'
        values = {'frame_rate_hz': f'{rate:.1f}', 'frames': c['frames'],
                  'crc_errors': c['crc_errors'], 'lost_frames': c['lost_frames'],
                  'bytes_skipped': c['bytes_skipped'], 'connected': self.connected,
                  'rejected': c['rejected'], 'reconnects': self.reconnects,
                  'reader_errors': self.reader_errors,
                  'format': self.format, 'timestamp': self.timestamp, 'baud': self.baud,
                  'accel_range_g': self.accel_range_g, 'gyro_range_dps': self.gyro_range_dps,
                  'temperature_formula': self.converter.temp_formula}
        parser = self.parser
        if isinstance(parser, FrameParser):
            values['link_quality'] = f'{parser.quality:.3f}'
        if isinstance(parser, FrameParser) and parser.period_us:
            values['device_rate_hz'] = f'{1e6 / parser.period_us:.1f}'
        info = self.device_info
        if info is not None:
            values.update({'chip': info.chip, 'who_am_i': f'0x{info.who_am_i:02x}',
                           'firmware_status': info.status_text,
                           'firmware_rate_hz': info.rate_hz, 'firmware_baud': info.baud})
        if self.timestamp == 'device':
            values['clock_drift_ppm'] = f'{self.clock_mapper.drift_ppm:.1f}'
        status.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        array = DiagnosticArray()
        array.header.stamp = self.get_clock().now().to_msg()
        array.status = [status]
        self.diag_pub.publish(array)

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
