"""
The driver node in-process on a pty: info frame, MPU-6050 formula, baud warning, params.

Frames are written by the test itself, so each case controls exactly what the "firmware"
says; the node runs in its own rclpy Context with an executor spun by the test.
"""

import os
import threading
import time
import tty

from accel_calib_ros.dataio.wire import (encode_frame, encode_frame_v2, encode_info,
                                         encode_info_v2, InfoFrame, MAG_AK8963)
from accel_calib_ros.nodes.driver import build_node
from diagnostic_msgs.msg import DiagnosticArray
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu, MagneticField, Temperature

pytestmark = pytest.mark.ros


class Rig:
    """A pty, the driver on its slave, and a subscriber node, in one Context."""

    def __init__(self, tmp_path, **params):
        self.master, slave = os.openpty()
        tty.setraw(slave)
        self.path = os.ttyname(slave)
        self._slave = slave
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        overrides = [Parameter('port', value=self.path), Parameter('reconnect_min_s', value=0.05)]
        overrides += [Parameter(k, value=v) for k, v in params.items()]
        self.node = build_node(self.context, overrides)
        self.logs = []
        self.sub = rclpy.create_node('info_sub', context=self.context)
        qos = QoSProfile(depth=5000, reliability=ReliabilityPolicy.RELIABLE)
        self.imu, self.temp, self.diag, self.mag = [], [], [], []
        self.sub.create_subscription(Imu, 'imu/data_raw', self.imu.append, qos)
        self.sub.create_subscription(MagneticField, 'imu/mag', self.mag.append, qos)
        self.sub.create_subscription(Temperature, 'imu/temperature', self.temp.append, qos)
        self.sub.create_subscription(DiagnosticArray, '/diagnostics', self.diag.append, 10)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.executor.add_node(self.sub)

    def write(self, data):
        os.write(self.master, data)

    def spin_until(self, predicate, timeout):
        deadline = time.monotonic() + timeout
        while not predicate():
            if time.monotonic() > deadline:
                return False
            self.executor.spin_once(timeout_sec=0.05)
        return True

    def status(self):
        for array in reversed(self.diag):
            for s in array.status:
                if s.name.endswith('serial'):
                    return s, {kv.key: kv.value for kv in s.values}
        return None, None

    def close(self):
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        self.sub.destroy_node()
        rclpy.try_shutdown(context=self.context)
        os.close(self.master)
        os.close(self._slave)


@pytest.fixture
def rigs(tmp_path):
    made = []

    def make(**params):
        rig = Rig(tmp_path, **params)
        made.append(rig)
        return rig
    yield make
    for rig in made:
        rig.close()


def frames(n, start=0, period_us=1000, temp=0, accel=(0, 0, 2048)):
    return b''.join(encode_frame(k & 0xFF, 5000 + k * period_us, accel + (temp, 1, 2, 3))
                    for k in range(start, start + n))


def test_info_frame_sets_chip_ranges_and_mpu6050_temperature(rigs):
    rig = rigs()
    time.sleep(0.3)                                   # the driver opens the pty
    rig.write(encode_info(InfoFrame(0, 0x68, 16, 2000, 1000, 1, 1_000_000, (1, 0))))
    rig.write(frames(50, temp=340))                   # 1 °C above 36.53 on an MPU-6050
    assert rig.spin_until(lambda: len(rig.imu) >= 49 and rig.temp, 10)
    msg = rig.imu[-1]
    assert msg.linear_acceleration.z == pytest.approx(2048 * 9.80665 / 2048)   # ±16 g
    assert msg.angular_velocity.x == pytest.approx(1 / 16.4 * 3.141592653589793 / 180)
    assert rig.temp[-1].temperature == pytest.approx(37.53)
    assert (msg.orientation.w, msg.orientation_covariance[0]) == (1.0, -1.0)
    assert rig.spin_until(lambda: rig.status()[1] and 'chip' in rig.status()[1], 5)
    status, values = rig.status()
    assert values['chip'] == 'MPU-6050' and values['temperature_formula'] == 'mpu6050'
    assert values['accel_range_g'] == '16' and values['lost_frames'] == '0'


def test_unknown_chip_is_an_error_in_diagnostics(rigs):
    rig = rigs()
    time.sleep(0.3)
    rig.write(encode_info(InfoFrame(1, 0x12, 2, 250, 1000, 1, 1_000_000, (1, 0))))

    def reported():
        status, values = rig.status()
        return status is not None and 'unknown chip' in status.message
    assert rig.spin_until(reported, 10)
    status, values = rig.status()
    assert status.level == b'\x02' and values['who_am_i'] == '0x12'
    assert rig.imu == []


def test_baud_too_low_for_the_rate_is_warned_and_gaps_counted(rigs):
    rig = rigs(baud=115200)
    time.sleep(0.3)
    kept = b''.join(frames(1, start=k) for k in range(0, 400) if k % 2 == 0)  # half lost
    rig.write(kept)
    assert rig.spin_until(lambda: len(rig.imu) >= 199, 10)
    assert rig.node._capacity_checked is not None
    assert rig.node.parser.lost_frames == 199
    assert rig.node.parser.period_us == pytest.approx(1000.0)


def test_temperature_rate_parameter_and_runtime_changes(rigs):
    rig = rigs(temperature_rate_hz=100.0)
    node = rig.node
    time.sleep(0.3)
    rig.write(frames(300))                            # 0.3 s of device time at 1 kHz
    assert rig.spin_until(lambda: len(rig.imu) >= 299, 10)
    assert 28 <= len(rig.temp) <= 31                  # 100 Hz of the 1 kHz samples
    d = node.describe_parameter('baud')
    assert d.integer_range[0].from_value == 300 and 'baud' in d.description
    assert node.describe_parameter('format').read_only
    for name, value in (('temperature_rate_hz', -1.0), ('format', 'ascii'),
                        ('accel_range_g', 3), ('reconnect_max_s', 0.01)):
        (result,) = node.set_parameters([Parameter(name, value=value)])
        assert not result.successful and result.reason, name
    (result,) = node.set_parameters([Parameter('temperature_rate_hz', value=0)])
    assert result.successful
    rig.temp.clear()
    rig.imu.clear()
    rig.write(frames(50, start=300))
    assert rig.spin_until(lambda: len(rig.imu) >= 50 and len(rig.temp) >= 50, 10)


def test_reader_survives_an_exception_and_reports_it(rigs):
    """Regression: an exception in the reader thread stopped the driver for good."""
    rig = rigs()
    node = rig.node
    real_feed = node.parser.feed
    calls = []

    def failing_feed(data, *args):
        calls.append(len(data))
        if len(calls) == 1:
            raise AttributeError("'tuple' object has no attribute 'seq'")
        return real_feed(data, *args)
    node.parser.feed = failing_feed
    time.sleep(0.3)
    rig.write(frames(10))
    assert rig.spin_until(lambda: node.reader_errors == 1, 5)
    rig.write(frames(200, start=10))
    assert rig.spin_until(lambda: len(rig.imu) >= 150, 10)      # the reader restarted
    assert rig.spin_until(lambda: rig.status()[1] is not None
                          and rig.status()[1]['reader_errors'] == '1', 5)


def test_info_v2_recoveries_and_frame_version_in_diagnostics(rigs):
    """Firmware 2.x: frame version 2 and its recovery counters reach /diagnostics."""
    rig = rigs(watchdog_s=10.0)     # the "device" pauses while the test waits for messages
    time.sleep(0.3)
    info = InfoFrame(0, 0x71, 4, 500, 1000, 1, 1_000_000, (2, 0), frame_version=2,
                     mag_status=0, info_version=2)
    rig.write(encode_info_v2(info))
    rig.write(b''.join(encode_frame_v2(k, 1000 * k, (0, 0, 8192, 1335, 0, 0, 0))
                       for k in range(200)))
    assert rig.spin_until(lambda: len(rig.imu) >= 199, 10)
    assert rig.imu[-1].linear_acceleration.z == pytest.approx(9.80665)       # ±4 g
    rig.write(encode_info_v2(info._replace(recoveries=2, i2c_errors=9, last_recovery=4)))

    def stream():                                           # 40 samples lost in the recovery
        for k in range(200, 2200, 10):
            rig.write(b''.join(encode_frame_v2(j + 40, 1000 * j + 40_000,
                                               (0, 0, 8192, 1335, 0, 0, 0))
                               for j in range(k, k + 10)))
            time.sleep(0.01)
    writer = threading.Thread(target=stream, daemon=True)
    writer.start()

    def reported():
        status, values = rig.status()
        return values is not None and 'recovered' in status.message
    assert rig.spin_until(reported, 5)
    writer.join(5)
    status, values = rig.status()
    assert values['frame_version'] == '2' and values['frames_v2'] == values['frames']
    assert values['firmware_last_recovery'] == 'I2C bus stuck (SDA held low)'
    assert values['firmware_i2c_errors'] == '9' and values['lost_frames'] == '40'
    assert status.level == b'\x01' and 'recovered the sensor 2 times' in status.message


def mag_frames(start, n, every=10, hofl_at=()):
    """Frame-v2 bytes at 1 kHz with an AK8963 block every ``every`` frames."""
    out = []
    for k in range(start, start + n):
        mag = None
        if k % every == 0:
            mag = (100 + k, -200, 300 - k, 0x10 | (0x08 if k in hofl_at else 0))
        out.append(encode_frame_v2(k, 1000 * k, (0, 0, 16384, 1335, 0, 0, 0), mag))
    return b''.join(out)


def test_magnetometer_published_in_tesla_in_the_accelerometer_frame(rigs):
    """imu/mag: ASA from the info frame, axes swapped to the accelerometer's, HOFL dropped."""
    rig = rigs(magnetic_field_stddev=0.4e-6, frame_id='imu')
    time.sleep(0.3)
    rig.write(mag_frames(0, 30))                       # before the info frame: held back
    assert rig.spin_until(lambda: len(rig.imu) >= 29, 10)
    assert rig.mag == [] and rig.node.mag_held >= 2
    asa = (176, 128, 64)                               # factors 1.1875, 1.0, 0.75
    rig.write(encode_info_v2(InfoFrame(0, 0x71, 2, 250, 1000, 1, 1_000_000, (2, 0), 2,
                                       MAG_AK8963, asa, info_version=2)))
    rig.write(mag_frames(30, 300, hofl_at=(100, 200)))
    assert rig.spin_until(lambda: len(rig.mag) >= 28, 10)
    rig.spin_until(lambda: False, 0.3)
    assert len(rig.mag) == 28 and rig.node.mag_overflows == 2     # 30 blocks, 2 overflows
    by_stamp = {(m.header.stamp.sec, m.header.stamp.nanosec): m for m in rig.imu}
    ks = [k for k in range(30, 330, 10) if k not in (100, 200)]
    for k, msg in zip(ks, rig.mag):
        assert (msg.header.stamp.sec, msg.header.stamp.nanosec) in by_stamp  # its sample's
        assert msg.header.frame_id == 'imu'
        hx, hy, hz = 100 + k, -200, 300 - k
        assert msg.magnetic_field.x == pytest.approx(hy * 0.15e-6 * 1.0)     # x = y_mag
        assert msg.magnetic_field.y == pytest.approx(hx * 0.15e-6 * 1.1875)  # y = x_mag
        assert msg.magnetic_field.z == pytest.approx(-hz * 0.15e-6 * 0.75)   # z = -z_mag
        assert msg.magnetic_field_covariance[0] == pytest.approx(0.16e-12)
        assert msg.magnetic_field_covariance[1] == 0.0

    def reported():
        values = rig.status()[1]
        return values is not None and values.get('mag_overflows') == '2'
    assert rig.spin_until(reported, 5)
    values = rig.status()[1]
    assert values['magnetometer'] == 'AK8963' and values['mag_asa'] == '176 128 64'
    assert values['mag_published'] == '28'


def test_no_magnetometer_on_an_mpu6500(rigs):
    rig = rigs()
    time.sleep(0.3)
    rig.write(encode_info_v2(InfoFrame(0, 0x70, 2, 250, 1000, 1, 1_000_000, (2, 0), 2, 0,
                                       info_version=2)))
    rig.write(b''.join(encode_frame_v2(k, 1000 * k, (0, 0, 16384, 1335, 0, 0, 0))
                       for k in range(100)))
    assert rig.spin_until(lambda: len(rig.imu) >= 99, 10)

    def reported():
        values = rig.status()[1]
        return values is not None and 'chip' in values
    assert rig.spin_until(reported, 5)
    values = rig.status()[1]
    assert values['magnetometer'] == 'absent (no AK8963 answers) (MPU-6500): no imu/mag'
    assert rig.mag == [] and values['mag_frames'] == '0'


def v2_frames(start, n, az, period_us=1000):
    return b''.join(encode_frame_v2(k, 1000 + period_us * k, (0, 0, az, 1335, 0, 0, 0))
                    for k in range(start, start + n))


def test_frames_before_the_info_frame_wait_for_its_ranges(rigs):
    """Regression: up to ~1 s of data was converted with the parameter ranges (4x off)."""
    rig = rigs()
    time.sleep(0.3)
    rig.write(v2_frames(0, 200, 4096))                 # 1 g at ±8 g
    rig.spin_until(lambda: False, 0.4)
    assert rig.imu == []                               # held: the ranges are not known yet
    rig.write(encode_info_v2(InfoFrame(0, 0x71, 8, 250, 1000, 1, 1_000_000, (2, 0), 2, 0,
                                       info_version=2)))
    rig.write(v2_frames(200, 200, 4096))
    assert rig.spin_until(lambda: len(rig.imu) >= 399, 10)
    assert {round(m.linear_acceleration.z, 3) for m in rig.imu} == {9.807}
    assert rig.node.link.info_timeouts == 0


def test_the_info_frame_is_forgotten_on_reopen(rigs):
    """Regression: device_info survived a reopen (another firmware behind the same port)."""
    rig = rigs()
    node = rig.node
    time.sleep(0.3)
    rig.write(encode_info_v2(InfoFrame(0, 0x71, 2, 250, 1000, 1, 1_000_000, (2, 0), 2, 0,
                                       info_version=2)))
    rig.write(v2_frames(0, 300, 16384))
    assert rig.spin_until(lambda: len(rig.imu) >= 299, 10)
    opens = node.link.reconnects + node.link.watchdog_reopens
    assert rig.spin_until(lambda: node.link.watchdog_reopens > opens, 10)     # silent
    assert node.device_info is None and node.accel_range_g == 2
    rig.write(encode_info_v2(InfoFrame(0, 0x71, 4, 250, 1000, 1, 1_000_000, (2, 0), 2, 0,
                                       info_version=2)))              # the new firmware
    rig.write(v2_frames(0, 300, 8192))
    assert rig.spin_until(lambda: len(rig.imu) >= 598, 10)
    assert {round(m.linear_acceleration.z, 3) for m in rig.imu[300:]} == {9.807}
    assert node.accel_range_g == 4
