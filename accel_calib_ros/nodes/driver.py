"""
ROS 2 node ``mpu9250_driver``: MPU9250 serial frames to ``sensor_msgs/Imu``.

Reads the binary frame of the interface spec (or the ASCII line format) from a serial
port in a background thread and publishes ``imu/data_raw`` (sensor_msgs/Imu,
REP-145: orientation not reported, ``orientation_covariance[0] = -1``) and
``imu/temperature`` (sensor_msgs/Temperature) with the same stamp and frame_id, both
reliable with depth 100. A lost port is logged once per outage and reopened with
exponential back-off; ``/diagnostics`` reports the link at 1 Hz.

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

from .common import choice, declare, number, ParameterProblem, run, text
from ..dataio.mpu9250_frame import (ACCEL_LSB_PER_G, AsciiLineParser, ClockMapper, Converter,
                                    FrameParser, GYRO_LSB_PER_DPS)

NODE_NAME = 'mpu9250_driver'
QUEUE_DEPTH = 100
READ_TIMEOUT_S = 0.05
FORMATS = ('binary', 'ascii')
TIMESTAMPS = ('device', 'host')


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
        p = {}
        p['port'] = declare(self, 'port', '/dev/ttyUSB0', 'serial device path')
        p['baud'] = declare(self, 'baud', 115200, 'serial baud rate')
        p['frame_id'] = declare(self, 'frame_id', 'imu_link', 'frame_id of the messages')
        p['accel_range_g'] = declare(self, 'accel_range_g', 2,
                                     'accelerometer full scale, ±g: 2, 4, 8 or 16')
        p['gyro_range_dps'] = declare(self, 'gyro_range_dps', 250,
                                      'gyroscope full scale, ±°/s: 250, 500, 1000 or 2000')
        p['format'] = declare(self, 'format', 'binary', 'wire format: binary or ascii')
        p['linear_acceleration_stddev'] = declare(
            self, 'linear_acceleration_stddev', 0.03,
            'accelerometer noise, m/s² (diagonal covariance; 0 = unknown)')
        p['angular_velocity_stddev'] = declare(
            self, 'angular_velocity_stddev', 0.002,
            'gyroscope noise, rad/s (diagonal covariance; 0 = unknown)')
        p['timestamp'] = declare(self, 'timestamp', 'device',
                                 'stamps from the device clock mapped to host time '
                                 '(device) or from the receive time (host)')
        p['reconnect_min_s'] = declare(self, 'reconnect_min_s', 0.2,
                                       'first reconnect delay, s')
        p['reconnect_max_s'] = declare(self, 'reconnect_max_s', 5.0,
                                       'longest reconnect delay, s')
        self.port = text('port', p['port'])
        self.baud = p['baud']
        if isinstance(self.baud, bool) or not isinstance(self.baud, int) or self.baud <= 0:
            raise ParameterProblem("parameter 'baud' must be a positive integer, "
                                   f'got {self.baud!r}')
        self.frame_id = text('frame_id', p['frame_id'])
        accel_range = choice('accel_range_g', p['accel_range_g'], tuple(ACCEL_LSB_PER_G))
        gyro_range = choice('gyro_range_dps', p['gyro_range_dps'], tuple(GYRO_LSB_PER_DPS))
        self.format = choice('format', p['format'], FORMATS)
        self.timestamp = choice('timestamp', p['timestamp'], TIMESTAMPS)
        accel_std = number('linear_acceleration_stddev', p['linear_acceleration_stddev'], 0.0)
        gyro_std = number('angular_velocity_stddev', p['angular_velocity_stddev'], 0.0)
        self.reconnect_min_s = number('reconnect_min_s', p['reconnect_min_s'], 0.0,
                                      low_open=True)
        self.reconnect_max_s = number('reconnect_max_s', p['reconnect_max_s'],
                                      self.reconnect_min_s)
        self.converter = Converter(accel_range, gyro_range)
        self.accel_cov = [0.0] * 9
        self.gyro_cov = [0.0] * 9
        for k in (0, 4, 8):
            self.accel_cov[k] = accel_std ** 2
            self.gyro_cov[k] = gyro_std ** 2

        self.parser = FrameParser() if self.format == 'binary' else AsciiLineParser()
        self.clock_mapper = ClockMapper()
        qos = QoSProfile(depth=QUEUE_DEPTH, history=HistoryPolicy.KEEP_LAST,
                         reliability=ReliabilityPolicy.RELIABLE)
        self.imu_pub = self.create_publisher(Imu, 'imu/data_raw', qos)
        self.temp_pub = self.create_publisher(Temperature, 'imu/temperature', qos)
        self.diag_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self.connected = False
        self.reconnects = 0
        self.published = 0
        self._last_error = ''
        self._diag_prev = (time.monotonic(), 0, 0, 0)
        self._stop = threading.Event()
        self._serial = None
        self._thread = threading.Thread(target=self._run, name='mpu9250_serial', daemon=True)
        self.create_timer(1.0, self._publish_diagnostics)
        self._thread.start()
        self.get_logger().info(
            f'reading {self.format} frames from {self.port} at {self.baud} baud, '
            f'±{accel_range} g, ±{gyro_range} °/s, {self.timestamp} timestamps')

    # -- serial thread -------------------------------------------------------------------

    def _open(self):
        ser = serial.Serial(self.port, self.baud, timeout=READ_TIMEOUT_S)
        try:
            ser.reset_input_buffer()         # stale bytes from before we were listening
        except (OSError, serial.SerialException):
            pass
        return ser

    def _run(self):
        delay = self.reconnect_min_s
        outage_logged = False
        ever_connected = False
        while not self._stop.is_set():
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
        self._drop_port()

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
        if not frames:
            return
        stamps = self._stamps(frames, host_s)
        to_si = self.converter.to_si
        for frame, stamp_s in zip(frames, stamps):
            (ax, ay, az), temp, (gx, gy, gz) = to_si(frame.counts)
            stamp = _stamp(stamp_s)
            imu = Imu()
            imu.header.stamp = stamp
            imu.header.frame_id = self.frame_id
            imu.orientation.w = 0.0
            imu.orientation_covariance[0] = -1.0
            imu.angular_velocity.x = gx
            imu.angular_velocity.y = gy
            imu.angular_velocity.z = gz
            imu.angular_velocity_covariance = self.gyro_cov
            imu.linear_acceleration.x = ax
            imu.linear_acceleration.y = ay
            imu.linear_acceleration.z = az
            imu.linear_acceleration_covariance = self.accel_cov
            msg = Temperature()
            msg.header.stamp = stamp
            msg.header.frame_id = self.frame_id
            msg.temperature = temp
            msg.variance = 0.0
            try:
                self.imu_pub.publish(imu)
                self.temp_pub.publish(msg)
            except Exception:           # noqa: B902 - context shut down under us: stop
                self._stop.set()
                return
            self.published += 1

    def _stamps(self, frames, host_s):
        if frames[-1].t_us is None:
            return [host_s] * len(frames)
        if self.timestamp == 'device':
            mapper = self.clock_mapper
            return [mapper.update(f.t_us, host_s) if f.t_us is not None else host_s
                    for f in frames]
        last = frames[-1].t_us
        return [host_s - (((last - f.t_us) & 0xFFFFFFFF) * 1e-6 if f.t_us is not None else 0.0)
                for f in frames]

    # -- diagnostics ---------------------------------------------------------------------

    def counters(self):
        """Return the link counters as a dict (frames, crc_errors, lost_frames, ...)."""
        c = self.parser.counters()
        c.setdefault('crc_errors', c.get('bad_lines', 0))
        c.setdefault('lost_frames', 0)
        return c

    def _publish_diagnostics(self):
        now = time.monotonic()
        c = self.counters()
        t0, frames0, errors0, lost0 = self._diag_prev
        self._diag_prev = (now, c['frames'], c['crc_errors'], c['lost_frames'])
        rate = (c['frames'] - frames0) / max(now - t0, 1e-3)
        new_errors = c['crc_errors'] - errors0
        new_lost = c['lost_frames'] - lost0
        status = DiagnosticStatus()
        status.name = f'{self.get_name()}: serial'
        status.hardware_id = self.port
        if not self.connected:
            status.level = DiagnosticStatus.ERROR
            status.message = f'not connected: {self._last_error}'
        elif rate <= 0:
            status.level = DiagnosticStatus.WARN
            status.message = 'connected, no frames'
        elif new_errors or new_lost:
            status.level = DiagnosticStatus.WARN
            status.message = f'{new_errors} CRC errors, {new_lost} lost frames in the last period'
        else:
            status.level = DiagnosticStatus.OK
            status.message = 'streaming'
        values = {'frame_rate_hz': f'{rate:.1f}', 'frames': c['frames'],
                  'crc_errors': c['crc_errors'], 'lost_frames': c['lost_frames'],
                  'bytes_skipped': c['bytes_skipped'], 'connected': self.connected,
                  'reconnects': self.reconnects, 'format': self.format,
                  'timestamp': self.timestamp}
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
