"""
The mpu9250_driver node as a subprocess, on real rclpy over DDS.

The virtual MPU9250 (``accel_calib_ros.sim.device``) streams on a pty behind a symlink;
the driver reads it; an in-process Collector checks what reaches the graph.
"""

import math
import signal
import statistics
import time

from diagnostic_msgs.msg import DiagnosticArray
import pytest
from ros_helpers import Collector, serial_status, stop_node, wait_exit
from sensor_msgs.msg import Imu, Temperature

pytestmark = pytest.mark.ros

DRIVER = 'accel_calib_ros.nodes.driver'
IMU, TEMP, DIAG = 'imu/data_raw', 'imu/temperature', '/diagnostics'


@pytest.fixture
def collector():
    c = Collector({IMU: Imu, TEMP: Temperature, DIAG: DiagnosticArray})
    try:
        yield c
    finally:
        c.close()


def start_pair(procs, tmp_path, device_args=(), **params):
    link = str(tmp_path / 'imu0')
    device, _ = procs.device(['--link', link, '--poses', 'faces', '--count', '1',
                              '--hold', '60', '--seed', '3', '--temp', '31.5']
                             + list(device_args))
    params = {'port': link, 'reconnect_min_s': 0.1, 'reconnect_max_s': 0.4, **params}
    driver = procs.node(DRIVER, params)
    return device, driver


def stamp_s(msg):
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


def test_stream_reaches_the_graph(procs, collector, tmp_path):
    _, driver = start_pair(procs, tmp_path)
    assert collector.spin_until(lambda: collector.count(IMU) >= 400 and
                                collector.count(TEMP) >= 10, 20), driver.log_path
    imu = collector.messages[IMU][-100:]
    for msg in imu:
        assert msg.header.frame_id == 'imu_link'
        assert msg.orientation_covariance[0] == -1.0            # REP-145: unknown
        assert (msg.orientation.x, msg.orientation.y, msg.orientation.z,
                msg.orientation.w) == (0.0, 0.0, 0.0, 1.0)      # identity, not (0,0,0,0)
        assert msg.linear_acceleration_covariance[0] == pytest.approx(0.03 ** 2)
    mean = [sum(getattr(m.linear_acceleration, a) for m in imu) / len(imu) for a in 'xyz']
    assert math.sqrt(sum(v * v for v in mean)) == pytest.approx(9.81, abs=0.6)
    assert abs(mean[0]) > 9.0                      # the first face: +x up
    gyro = max(abs(m.angular_velocity.z) for m in imu)
    assert gyro < 0.05
    temps = collector.messages[TEMP][-10:]
    assert all(t.header.frame_id == 'imu_link' for t in temps)
    assert sum(t.temperature for t in temps) / len(temps) == pytest.approx(31.5, abs=0.1)
    # Temperature at its own rate (default 10 Hz), stamped like an IMU sample.
    temp_stamps = [stamp_s(t) for t in collector.messages[TEMP]]
    temp_spacing = statistics.median(b - a for a, b in zip(temp_stamps, temp_stamps[1:]))
    assert temp_spacing == pytest.approx(0.1, abs=0.006)
    stamps = [stamp_s(m) for m in imu]
    assert all(b > a for a, b in zip(stamps, stamps[1:]))
    # Median, not mean: a best-effort subscriber on a loaded machine may miss a few.
    spacing = statistics.median(b - a for a, b in zip(stamps, stamps[1:]))
    assert spacing == pytest.approx(1 / 200.0, rel=0.02)
    assert abs(time.time() - stamps[-1]) < 1.0
    imu_stamps = {stamp_s(m) for m in collector.messages[IMU]}
    assert sum(s in imu_stamps for s in temp_stamps) >= 0.9 * len(temp_stamps)
    assert collector.spin_until(lambda: serial_status(collector) is not None, 5)
    status = serial_status(collector)
    assert status['connected'] == 'True' and status['port'].endswith('imu0')
    assert status['hardware_id'] == 'imu_link'                # the sensor id
    assert driver.poll() is None
    code, log = stop_node(driver)
    assert code == 0, log
    assert 'Traceback' not in log


def test_corrupted_stream_and_diagnostics(procs, collector, tmp_path):
    _, driver = start_pair(procs, tmp_path, ['--corrupt', '0.02'], timestamp='host')
    assert collector.spin_until(lambda: collector.count(IMU) >= 200, 20), driver.log_path

    def errors_reported():
        status = serial_status(collector)
        return status is not None and int(status['crc_errors']) > 0 \
            and int(status['lost_frames']) > 0
    assert collector.spin_until(errors_reported, 10)
    status = serial_status(collector)
    assert float(status['frame_rate_hz']) > 80
    assert int(status['bytes_skipped']) > 0
    assert status['level'] in (b'\x00', b'\x01')
    imu = collector.messages[IMU]
    norms = [math.sqrt(m.linear_acceleration.x ** 2 + m.linear_acceleration.y ** 2 +
                       m.linear_acceleration.z ** 2) for m in imu]
    good = sum(abs(n - 9.81) < 1.0 for n in norms)
    assert good >= 0.97 * len(norms)                # CRC-8 lets ~1/256 bad frames pass
    assert driver.poll() is None


def test_unplug_replug_resumes_without_restart(procs, collector, tmp_path):
    device, driver = start_pair(procs, tmp_path, ['--unplug-s', '1.0'])
    assert collector.spin_until(lambda: collector.count(IMU) >= 50, 20), driver.log_path
    device.send_signal(signal.SIGUSR1)
    unplugged_at = time.time()
    collector.spin(1.5)
    collector.clear()
    assert collector.spin_until(lambda: sum(stamp_s(m) > unplugged_at + 1.0
                                            for m in collector.messages[IMU]) >= 100, 15)
    assert driver.poll() is None
    code, log = stop_node(driver)
    assert code == 0
    assert log.count('lost ') == 1, log             # logged once per outage
    assert log.count('reconnected') == 1, log
    assert 'Traceback' not in log


def test_bad_parameter_exits_2(procs):
    driver = procs.node(DRIVER, {'accel_range_g': 3, 'port': '/nonexistent/tty'})
    code = wait_exit(driver, 20)
    _, log = stop_node(driver)
    assert code == 2, log
    lines = [line for line in log.splitlines() if line.strip()]
    assert len(lines) == 1, log
    assert 'accel_range_g' in lines[0] and '2, 4, 8, 16' in lines[0]


def test_missing_port_retries_quietly(procs, tmp_path):
    driver = procs.node(DRIVER, {'port': str(tmp_path / 'absent'), 'reconnect_min_s': 0.05,
                                 'reconnect_max_s': 0.1})
    time.sleep(2.0)
    assert driver.poll() is None
    code, log = stop_node(driver)
    assert code == 0
    assert log.count('cannot open') == 1, log


def test_ascii_format_and_int_for_double(procs, collector, tmp_path):
    _, driver = start_pair(procs, tmp_path, ['--ascii'], format='ascii',
                           linear_acceleration_stddev=1, accel_range_g=2)
    assert collector.spin_until(lambda: collector.count(IMU) >= 100, 20), driver.log_path
    msg = collector.messages[IMU][-1]
    assert msg.linear_acceleration_covariance[0] == 1.0
    assert msg.linear_acceleration.x == pytest.approx(9.81, abs=0.6)
    code, log = stop_node(driver)
    assert code == 0, log
