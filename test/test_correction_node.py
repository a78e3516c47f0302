"""
The accel_correction node, in-process with real rclpy over DDS.

The node runs in the test's own process (a fresh context per test, its own domain id),
so its output can be compared with :meth:`Calibration.correct` to 1e-9 and every
published message can be accounted for.
"""

import os
import random
import subprocess
import sys
import time

from accel_calib_ros.core.calibration import Calibration
from accel_calib_ros.core.thermal import ThermalBand, ThermalTable
from accel_calib_ros.dataio.atomic import atomic_write_text
from accel_calib_ros.dataio.calibration_file import (calibration_to_yaml, load_calibration,
                                                     save_calibration)
from accel_calib_ros.nodes.correction import CorrectionNode, UNCALIBRATED_STD
import numpy as np
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu, Temperature

RELIABLE = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)


def make_calibration(seed, thermal=False):
    """Build a plausible calibration (optionally with two temperature bands)."""
    rng = np.random.default_rng(seed)
    T = np.diag(1.0 + rng.uniform(-0.03, 0.03, 3))
    T[np.triu_indices(3, 1)] = rng.uniform(-0.02, 0.02, 3)
    cov = np.diag(rng.uniform(1e-8, 1e-6, 9))
    table = None
    if thermal:
        bands = [ThermalBand(20.0, 30.0, 25.0, rng.uniform(-1e-3, 1e-3, 3),
                             rng.uniform(-1e-3, 1e-3, 3), rng.uniform(-0.05, 0.05, 3), 20),
                 ThermalBand(30.0, 40.0, 34.0, rng.uniform(-1e-3, 1e-3, 3),
                             rng.uniform(-1e-3, 1e-3, 3), rng.uniform(-0.05, 0.05, 3), 20)]
        table = ThermalTable(10.0, bands)
    return Calibration(T=T, bias=rng.uniform(-0.5, 0.5, 3), covariance=cov,
                       noise_std=np.full(3, 0.03), thermal=table, method='ml')


class Rig:
    """The node under test plus a raw publisher and a corrected subscriber."""

    def __init__(self, calibration_file):
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=random.randint(100, 200))
        self.node = CorrectionNode(
            context=self.context,
            parameter_overrides=[Parameter('calibration_file', value=str(calibration_file)),
                                 Parameter('reload_period_s', value=0.05)])
        self.peer = rclpy.create_node('peer', context=self.context)
        self.imu_pub = self.peer.create_publisher(Imu, 'imu/data_raw', RELIABLE)
        self.temp_pub = self.peer.create_publisher(Temperature, 'imu/temperature', RELIABLE)
        self.received = []
        self.peer.create_subscription(Imu, 'imu/corrected', self.received.append, RELIABLE)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.executor.add_node(self.peer)
        self.spin_until(lambda: self.imu_pub.get_subscription_count() > 0
                        and self.peer.count_publishers('imu/corrected') > 0
                        and self.temp_pub.get_subscription_count() > 0)
        self.spin(0.3)          # let the reverse direction (corrected -> peer) match too

    def spin(self, seconds):
        """Process callbacks for ``seconds``."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.01)

    def spin_until(self, condition, timeout=10.0):
        """Process callbacks until ``condition()`` holds; fail after ``timeout`` s."""
        end = time.monotonic() + timeout
        while not condition():
            assert time.monotonic() < end, 'timed out'
            self.executor.spin_once(timeout_sec=0.01)

    def set_temperature(self, value):
        """Publish a temperature and wait until the node has it."""
        self.temp_pub.publish(Temperature(temperature=value, variance=0.0))
        self.spin_until(lambda: self.node.temperature == value)

    def close(self):
        """Tear everything down."""
        self.executor.shutdown()
        self.node.destroy_node()
        self.peer.destroy_node()
        rclpy.try_shutdown(context=self.context)


def raw_message(rng, i):
    """Build an Imu message with every field filled with something recognisable."""
    m = Imu()
    m.header.stamp.sec = 1000 + i
    m.header.stamp.nanosec = 123456 + i
    m.header.frame_id = 'imu_link'
    m.orientation.x, m.orientation.y, m.orientation.z, m.orientation.w = 0.1, 0.2, 0.3, 0.9
    m.orientation_covariance = [-1.0] + [0.0] * 8
    m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z = \
        (float(v) for v in rng.normal(0, 0.1, 3))
    m.angular_velocity_covariance = [float(v) for v in np.arange(9) * 1e-4]
    g = rng.normal(0, 1, 3)
    g = 9.80665 * g / np.linalg.norm(g) + rng.normal(0, 0.3, 3)
    m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z = \
        (float(v) for v in g)
    m.linear_acceleration_covariance = [0.5] * 9
    return m


def accel(m):
    """linear_acceleration as an array."""
    a = m.linear_acceleration
    return np.array([a.x, a.y, a.z])


def assert_passthrough(sent, got):
    """Everything except the acceleration and its covariance is unchanged."""
    assert got.header.stamp.sec == sent.header.stamp.sec
    assert got.header.stamp.nanosec == sent.header.stamp.nanosec
    assert got.header.frame_id == sent.header.frame_id
    assert (got.orientation.x, got.orientation.y, got.orientation.z, got.orientation.w) == \
        (sent.orientation.x, sent.orientation.y, sent.orientation.z, sent.orientation.w)
    assert list(got.orientation_covariance) == list(sent.orientation_covariance)
    assert (got.angular_velocity.x, got.angular_velocity.y, got.angular_velocity.z) == \
        (sent.angular_velocity.x, sent.angular_velocity.y, sent.angular_velocity.z)
    assert list(got.angular_velocity_covariance) == list(sent.angular_velocity_covariance)


@pytest.fixture
def rig_factory():
    rigs = []

    def make(path):
        rigs.append(Rig(path))
        return rigs[-1]
    yield make
    for rig in rigs:
        rig.close()


def send(rig, messages, batch=20):
    """Publish messages (spinning in between) and wait until all came back corrected."""
    start = len(rig.received)
    for k, m in enumerate(messages):
        rig.imu_pub.publish(m)
        if k % batch == batch - 1:
            rig.executor.spin_once(timeout_sec=0.0)
    rig.spin_until(lambda: len(rig.received) - start >= len(messages))
    return rig.received[start:]


@pytest.mark.parametrize('thermal', [False, True])
def test_corrects_like_core_and_passes_the_rest(tmp_path, rig_factory, thermal):
    path = tmp_path / 'calibration.yaml'
    save_calibration(make_calibration(1, thermal), path)
    cal = load_calibration(path)
    rig = rig_factory(path)
    rng = np.random.default_rng(2)
    for temp in (27.5, 36.0):
        rig.set_temperature(temp)
        sent = [raw_message(rng, i) for i in range(50)]
        got = send(rig, sent)
        assert len(got) == len(sent)
        expected = cal.correct(np.array([accel(m) for m in sent]), np.full(len(sent), temp))
        assert np.max(np.abs(np.array([accel(m) for m in got]) - expected)) < 1e-9
        cov = cal.acceleration_covariance().reshape(9)
        for s, g in zip(sent, got):
            assert_passthrough(s, g)
            np.testing.assert_allclose(g.linear_acceleration_covariance, cov, rtol=1e-12)
    if thermal:     # the drift tables really were applied
        assert np.max(np.abs(expected - cal.correct(np.array([accel(m) for m in sent])))) \
            > 1e-3


def test_without_calibration_passes_through_with_large_covariance(tmp_path, rig_factory):
    rig = rig_factory(tmp_path / 'missing.yaml')
    rng = np.random.default_rng(3)
    sent = [raw_message(rng, i) for i in range(30)]
    got = send(rig, sent)
    for s, g in zip(sent, got):
        assert_passthrough(s, g)
        assert np.array_equal(accel(g), accel(s))
        np.testing.assert_array_equal(
            np.asarray(g.linear_acceleration_covariance).reshape(3, 3),
            np.eye(3) * UNCALIBRATED_STD ** 2)


def test_hot_reload_without_dropping_and_bad_files_are_ignored(tmp_path, rig_factory):
    path = tmp_path / 'calibration.yaml'
    cal_a = make_calibration(10)
    save_calibration(cal_a, path)
    rig = rig_factory(path)
    rng = np.random.default_rng(4)
    cal_b = make_calibration(11)
    published, sent = 0, []
    switched_at = None
    t0 = time.monotonic()
    rate = 400.0
    # Stream at 400 Hz; replace the file after 0.5 s; it must take effect within 1 s.
    while time.monotonic() - t0 < 2.0:
        due = int((time.monotonic() - t0) * rate)
        while published < due:
            m = raw_message(rng, published)
            rig.imu_pub.publish(m)
            sent.append(m)
            published += 1
        if switched_at is None and time.monotonic() - t0 > 0.5:
            save_calibration(cal_b, path)
            switched_at = published
        rig.executor.spin_once(timeout_sec=0.001)
    rig.spin_until(lambda: len(rig.received) >= published)
    assert len(rig.received) == published, 'messages were dropped'
    got = np.array([accel(m) for m in rig.received])
    raw = np.array([accel(m) for m in sent])
    is_a = np.all(np.abs(got - cal_a.correct(raw)) < 1e-9, axis=1)
    is_b = np.all(np.abs(got - cal_b.correct(raw)) < 1e-9, axis=1)
    assert np.all(is_a | is_b)
    # One clean switch: A until some message, B from there on. Messages published just
    # before the new file may still have been queued when it was loaded, so the switch
    # can come a little before ``switched_at``, never long after it.
    first_b = int(np.argmax(is_b))
    assert is_b[first_b] and np.all(is_b[first_b:]) and np.all(is_a[:first_b])
    assert first_b > switched_at - 0.2 * rate
    assert (first_b - switched_at) / rate < 1.0
    assert [m.header.stamp.sec for m in rig.received] == [m.header.stamp.sec for m in sent]

    # A corrupt file and a half-written one are both ignored: B stays in use.
    for bad in ('format: something else\n', calibration_to_yaml(cal_a)[:200]):
        atomic_write_text(path, bad)
        rig.spin(0.3)
        m = raw_message(rng, 0)
        (out,) = send(rig, [m])
        np.testing.assert_allclose(accel(out), cal_b.correct(accel(m))[0], atol=1e-9)
    # A good file afterwards is picked up again.
    save_calibration(cal_a, path)
    rig.spin(0.3)
    m = raw_message(rng, 0)
    (out,) = send(rig, [m])
    np.testing.assert_allclose(accel(out), cal_a.correct(accel(m))[0], atol=1e-9)
    assert os.path.exists(path)


def test_bad_parameter_exits_with_status_2():
    proc = subprocess.run(
        [sys.executable, '-m', 'accel_calib_ros.nodes.correction', '--ros-args', '-p',
         'reload_period_s:=-1.0'], capture_output=True, text=True, timeout=30)
    assert proc.returncode == 2, proc.stderr
    assert "parameter 'reload_period_s'" in proc.stderr
    assert 'Traceback' not in proc.stderr
