"""
ROS 2 node ``mpu9250_driver``: MPU9250 serial frames to ``sensor_msgs/Imu``.

The serial link (port, back-off, watchdog, info request, parser, stamps) is
:class:`~accel_calib_ros.dataio.link.SerialLink`, ROS-free; this node keeps the
parameters, turns the link's frames into ``imu/data_raw``, ``imu/temperature`` and
``imu/mag`` and packs the link's health (:func:`~accel_calib_ros.dataio.link.assess`)
into ``/diagnostics`` once a second. What it publishes, when, and what the diagnostics
say: docs/driver.md.
"""

import math
import time

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu, MagneticField, Temperature

from .common import (declare_parameters, hardware_id, Param, ParameterProblem, run,
                     Throttled)
from ..dataio.link import assess, link_values, SerialLink, SystemClock
from ..dataio.link.serial_link import LOG_PERIOD_S
from ..dataio.wire import (ACCEL_LSB_PER_G, BY_KEY, chip_of, Converter, DEFAULT_CHIP,
                           FRAME_V1_SIZE, FRAME_V2_SIZE, GYRO_LSB_PER_DPS, MAG_AK8963,
                           MagConverter, temp_counts_range, TEMP_FORMULAS)

NODE_NAME = 'mpu9250_driver'
QUEUE_DEPTH = 100
FORMATS = ('binary', 'ascii')
TIMESTAMPS = ('device', 'host')
CHIP_CHOICES = ('auto',) + tuple(BY_KEY)
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
          f'else {DEFAULT_CHIP.name}) or ' + ', '.join(CHIP_CHOICES[1:]), choices=CHIP_CHOICES),
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


class _NodeClock(SystemClock):
    """The link's clocks: monotonic for its timing, the node's ROS clock for the stamps."""

    def __init__(self, node):
        self._ros = node.get_clock()

    def host(self):
        """Return ROS time, s."""
        return self._ros.now().nanoseconds * 1e-9


class Mpu9250Driver(Node):
    """
    The driver node; see the module docstring and docs/driver.md.

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
        self.format = p['format']
        self.timestamp = p['timestamp']
        self.device_info = None         # the info frame of this connection
        self._last_info = None          # the last one logged
        self.published = 0
        self.publish_errors = 0
        self.last_publish_error = ''
        self.mag_published = 0
        self.mag_overflows = 0
        self.mag_held = 0
        self._mag_unadjusted_warned = False
        self._temp_period_s = 0.0
        self._last_temp_stamp = None
        self._baud_warned = False
        self._jitter_warned = False
        self._log_throttled = Throttled(self.get_logger(), LOG_PERIOD_S)
        self.link = None
        self._apply_settings()
        qos = QoSProfile(depth=QUEUE_DEPTH, history=HistoryPolicy.KEEP_LAST,
                         reliability=ReliabilityPolicy.RELIABLE)
        self.imu_pub = self.create_publisher(Imu, 'imu/data_raw', qos)
        self.temp_pub = self.create_publisher(Temperature, 'imu/temperature', qos)
        self.mag_pub = self.create_publisher(MagneticField, 'imu/mag', qos)
        self.diag_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self.link = SerialLink(
            p['port'], p['baud'], self.format, self.timestamp, clock=_NodeClock(self),
            logger=self.get_logger(), on_samples=self._on_samples, on_info=self._handle_info,
            on_connect=self._on_connect, reconnect_min_s=p['reconnect_min_s'],
            reconnect_max_s=p['reconnect_max_s'], watchdog_s=p['watchdog_s'],
            temp_range=self._temp_range(), hold_for_info=self._hold_for_info())
        self._diag_prev = dict(self.link.snapshot(), published=0, publish_errors=0)
        self.create_timer(1.0, self._publish_diagnostics)
        self.link.start()
        self.get_logger().info(
            f'reading {self.format} frames from {p["port"]} at {p["baud"]} baud, '
            f'±{self.accel_range_g} g, ±{self.gyro_range_dps} °/s, {self.timestamp} '
            'timestamps')

    @property
    def parser(self):
        """Return the link's parser: frames (binary format) or text lines (ascii)."""
        return self.link.parser

    # -- parameters ----------------------------------------------------------------------

    def _chip_formula(self):
        chip = self.params['chip']
        if chip == 'auto':
            info = self.device_info
            known = chip_of(info.who_am_i) if info is not None else None
            chip = (known or DEFAULT_CHIP).key
        return BY_KEY[chip].temp.name

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
        self.accel_cov = self._diagonal(p['linear_acceleration_stddev'])
        self.gyro_cov = self._diagonal(p['angular_velocity_stddev'])
        self.mag_cov = self._diagonal(p['magnetic_field_stddev'])
        asa = info.asa if info is not None and info.mag_status == MAG_AK8963 else None
        self.mag_converter = MagConverter(asa) if asa is not None else None
        rate = p['temperature_rate_hz']
        self._temp_period_s = 1.0 / rate if rate > 0 else 0.0
        self.frame_id = p['frame_id']
        link = self.link
        if link is not None:
            link.reconnect_min_s = p['reconnect_min_s']
            link.reconnect_max_s = p['reconnect_max_s']
            link.watchdog_s = p['watchdog_s']
            link.hold_for_info = self._hold_for_info()
            if link.binary:
                link.parser.temp_range = self._temp_range()

    def _hold_for_info(self):
        """Whether frames wait for the info frame: it sets what they are converted with."""
        return self.params['ranges_from_device'] or self.params['chip'] == 'auto'

    @staticmethod
    def _diagonal(stddev):
        cov = [0.0] * 9
        for k in (0, 4, 8):
            cov[k] = stddev ** 2
        return cov

    def _on_change(self, changes):
        p = self.params
        if p['reconnect_max_s'] < p['reconnect_min_s']:
            raise ParameterProblem('reconnect_max_s must be >= reconnect_min_s')
        self._apply_settings()
        if 'port' in changes or 'baud' in changes:
            self._baud_warned = False
            self.link.reopen(p['port'], p['baud'])

    # -- device information --------------------------------------------------------------

    def _on_connect(self):
        """Forget the info frame: the port was (re)opened, the device may have changed."""
        self.device_info = None
        self._apply_settings()

    def _handle_info(self, info):
        """Take an info frame: the settings from it, and a log line when it says news."""
        if info != self.device_info:
            self.device_info = info
            self._apply_settings()
        old, self._last_info = self._last_info, info
        if old == info:
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
        if info.baud != self.params['baud']:
            log.warning(f'the firmware sends at {info.baud} baud but the port is opened at '
                        f'{self.params["baud"]}: set parameter baud to {info.baud}')

    def _check_capacity(self):
        """Warn once when the baud rate cannot carry the sample rate (reader thread)."""
        link = self.link
        parser = link.parser
        if not link.binary or parser.period_us is None or parser.frames < 50:
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
        baud = link.baud
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

    # -- messages ------------------------------------------------------------------------

    def _on_samples(self, frames, stamps):
        """Publish the link's samples (called from the link's reader thread)."""
        self._check_capacity()
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
            if self._publish(self.imu_pub, imu):
                self.published += 1
            elif self.link.stopped:
                return
            if send_temp:
                msg = Temperature()
                msg.header.stamp = stamp
                msg.header.frame_id = self.frame_id
                msg.temperature = temp
                msg.variance = 0.0
                if self._publish(self.temp_pub, msg):
                    self._last_temp_stamp = clock
            if frame.mag is not None:
                self._publish_mag(frame.mag, stamp)

    def _publish_mag(self, block, stamp):
        """Publish one AK8963 sample (held until the ASA is known, dropped on overflow)."""
        conv = self.mag_converter
        if conv is None:
            info = self.device_info
            opened_at = self.link.opened_at
            if info is not None and info.mag_status == MAG_AK8963:
                conv = self.mag_converter = MagConverter(info.asa)
            elif opened_at is not None and \
                    time.monotonic() - opened_at < MAG_ASA_WAIT_S and \
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
        if self._publish(self.mag_pub, msg):
            self.mag_published += 1

    def _publish(self, publisher, msg):
        """
        Publish one message; return whether it went out.

        A failure (Fast DDS's transient "cannot publish data", say) is counted
        (``publish_errors``), logged at most every 10 s and survived; only the end of the
        context stops the reader.
        """
        try:
            publisher.publish(msg)
            return True
        except Exception as err:        # noqa: B902 - one failed publish must not end it
            if not self.context.ok():
                self.link.stop(timeout=0)
                return False
            self.publish_errors += 1
            self.last_publish_error = f'{publisher.topic_name}: {type(err).__name__}: {err}'
            self._log_throttled(
                'publish', 'error',
                f'could not publish on {self.last_publish_error}; the message is dropped and '
                f'the driver goes on (publish_errors {self.publish_errors} in /diagnostics)')
            return False

    # -- diagnostics ---------------------------------------------------------------------

    @property
    def reader_errors(self):
        """Reader failures caught and survived so far."""
        return self.link.reader_errors

    @property
    def watchdog_reopens(self):
        """Port reopens by the watchdog so far."""
        return self.link.watchdog_reopens

    def _publish_diagnostics(self):
        try:
            self.diag_pub.publish(self.diagnostics())
        except Exception as err:        # noqa: B902 - the node never dies on its report
            if self.context.ok():
                self._log_throttled('diagnostics', 'error',
                                    f'diagnostics not published: {type(err).__name__}: {err}')

    def diagnostics(self):
        """
        Return the link status for ``/diagnostics`` (one period since the last call).

        The level and message come from :func:`~accel_calib_ros.dataio.link.assess`
        (docs/driver.md lists them); the values are the link's, the conversion's and the
        magnetometer's.

        :return: DiagnosticArray with one DiagnosticStatus.
        """
        snap = self.link.snapshot()
        snap['published'] = self.published
        snap['publish_errors'] = self.publish_errors
        snap['last_publish_error'] = self.last_publish_error
        prev, self._diag_prev = self._diag_prev, snap
        level, message = assess(snap, prev, self.params['watchdog_s'])
        status = DiagnosticStatus()
        status.name = f'{self.get_name()}: serial'
        status.hardware_id = hardware_id(self.frame_id)
        status.level = bytes((level,))
        status.message = message
        values = link_values(snap, prev)
        drift = values.pop('clock_drift_ppm', None)
        values.update({'accel_range_g': self.accel_range_g,
                       'gyro_range_dps': self.gyro_range_dps,
                       'temperature_formula': self.converter.temp_formula})
        values.update(self._mag_diagnostics(snap['counters']))
        if drift is not None:
            values['clock_drift_ppm'] = drift
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
        self.link.stop()
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
