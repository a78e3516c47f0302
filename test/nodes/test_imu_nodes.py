"""
The whole IMU in the nodes, in-process on real rclpy.

The correction node, spun with a peer over DDS, corrects ``angular_velocity`` with the
gyroscope's T (and maps its covariance) and ``imu/mag`` into ``imu/mag_corrected``; the
calibration node, fed a simulated session message by message through its callbacks,
solves and reports all three sensors (and says which are absent).
"""

import functools
import json
import random
import time

from accel_calib_ros.core.calibration import Calibration, MagnetometerPart
from accel_calib_ros.dataio.calibration_file import load_calibration, save_calibration
from accel_calib_ros.nodes.calibration import CalibrationNode
from accel_calib_ros.nodes.correction import CorrectionNode
from accel_calib_ros.sim import motion as sim_motion
from accel_calib_ros.sim import sensor as sim
from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from ros_helpers import nodes_in_a_context
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import Imu, MagneticField
from std_srvs.srv import Trigger

pytestmark = pytest.mark.ros

RELIABLE = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)


def imu_calibration(magnetometer=True):
    """Return a calibration with a gyroscope T and (optionally) a magnetometer part."""
    R = Rotation.from_rotvec([0.02, -0.01, 0.03]).as_matrix()
    mag = MagnetometerPart(T=[[0.97, 0.01, -0.02], [0.0, 1.02, 0.015], [0.0, 0.0, 1.01]],
                           hard_iron_uT=[12.0, -25.0, 7.5], R=R, field_uT=48.0, dip_deg=61.0,
                           predicted_accuracy=0.05, noise_std_uT=0.4)
    return Calibration(T=np.diag([1.01, 0.99, 1.02]), bias=[0.1, -0.2, 0.3],
                       covariance=np.diag(np.full(9, 1e-7)), noise_std=np.full(3, 0.02),
                       gyro_bias=[0.01, -0.02, 0.03],
                       gyro_T=[[1.02, 0.01, -0.015], [0.012, 0.98, 0.004], [-0.02, 0.007, 1.01]],
                       gyro_predicted_accuracy=4e-3, magnetometer=mag if magnetometer else None)


class Rig:
    """The correction node, a peer publishing raw Imu and MagneticField, and its outputs."""

    def __init__(self, path):
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=random.randint(100, 200))
        self.node = CorrectionNode(context=self.context, parameter_overrides=[
            Parameter('calibration_file', value=str(path)),
            Parameter('reload_period_s', value=0.05)])
        self.peer = rclpy.create_node('imu_peer', context=self.context)
        self.imu_pub = self.peer.create_publisher(Imu, 'imu/data_raw', RELIABLE)
        self.mag_pub = self.peer.create_publisher(MagneticField, 'imu/mag', RELIABLE)
        self.imu, self.mag, self.diagnostics = [], [], []
        self.peer.create_subscription(Imu, 'imu/corrected', self.imu.append, RELIABLE)
        self.peer.create_subscription(MagneticField, 'imu/mag_corrected', self.mag.append,
                                      RELIABLE)
        self.peer.create_subscription(DiagnosticArray, '/diagnostics', self.diagnostics.append,
                                      10)
        self.executor = SingleThreadedExecutor(context=self.context)
        for node in (self.node, self.peer):
            self.executor.add_node(node)
        self.spin_until(lambda: self.imu_pub.get_subscription_count() > 0
                        and self.mag_pub.get_subscription_count() > 0
                        and self.peer.count_publishers('imu/mag_corrected') > 0
                        and self.peer.count_publishers('imu/corrected') > 0)
        self.spin(0.3)

    def spin(self, seconds):
        """Process callbacks for ``seconds``."""
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(timeout_sec=0.01)

    def spin_until(self, condition, timeout=10.0):
        """Process callbacks until ``condition()``; fail after ``timeout`` s."""
        end = time.monotonic() + timeout
        while not condition():
            assert time.monotonic() < end, 'timed out'
            self.executor.spin_once(timeout_sec=0.01)

    def close(self):
        """Tear down."""
        self.executor.shutdown()
        self.node.destroy_node()
        self.peer.destroy_node()
        rclpy.try_shutdown(context=self.context)


def imu_message(i, rate, cov):
    """Return a raw Imu message with angular rate ``rate`` (3,) and its covariance (9,)."""
    m = Imu()
    m.header.stamp.sec, m.header.frame_id = 100 + i, 'imu_link'
    m.orientation.w = 1.0
    m.orientation_covariance[0] = -1.0
    m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z = (float(v) for v in rate)
    m.angular_velocity_covariance = np.asarray(cov, float)
    m.linear_acceleration.z = 9.8
    return m


def mag_message(i, field_t, cov):
    """Return a raw MagneticField message, tesla, with covariance ``cov`` (9,) tesla²."""
    m = MagneticField()
    m.header.stamp.sec, m.header.frame_id = 100 + i, 'imu_link'
    m.magnetic_field.x, m.magnetic_field.y, m.magnetic_field.z = (float(v) for v in field_t)
    m.magnetic_field_covariance = np.asarray(cov, float)
    return m


@pytest.fixture
def rig(tmp_path):
    path = tmp_path / 'calibration.yaml'
    save_calibration(imu_calibration(), path)
    r = Rig(path)
    r.spin_until(lambda: r.node.corrector.cal is not None)
    yield r
    r.close()


def test_gyro_T_and_magnetometer_are_applied_with_their_covariances(rig):
    cal = load_calibration(rig.node.path)
    rng = np.random.default_rng(4)
    gyro_cov = np.diag([1e-4, 2e-4, 3e-4])
    rates = rng.normal(0, 1.0, (20, 3))
    for i, w in enumerate(rates):
        rig.imu_pub.publish(imu_message(i, w, gyro_cov.reshape(9)))
    rig.spin_until(lambda: len(rig.imu) == len(rates))
    A = np.linalg.inv(cal.gyro_T)
    for i, (w, msg) in enumerate(zip(rates, rig.imu)):
        out = msg.angular_velocity
        expected = A @ (w - cal.gyro_bias)
        np.testing.assert_allclose([out.x, out.y, out.z], expected, atol=1e-12)
        # the driver's noise mapped through T⁻¹, plus (accuracy |ω|)² / 3 per axis
        cov = A @ gyro_cov @ A.T + np.eye(3) * (4e-3 * np.linalg.norm(expected)) ** 2 / 3
        np.testing.assert_allclose(np.reshape(msg.angular_velocity_covariance, (3, 3)), cov,
                                   rtol=1e-9, atol=1e-15)
    # the magnetometer: tesla in and out, field = Rᵀ T⁻¹ (raw - hard iron)
    m = cal.magnetometer
    M = m.R.T @ np.linalg.inv(m.T)
    fields = rng.normal(0, 40.0, (10, 3))                      # µT
    known = np.diag([4e-13, 4e-13, 9e-13])                      # (0.6-0.9 µT)², tesla²
    for i, f in enumerate(fields):
        rig.mag_pub.publish(mag_message(i, f * 1e-6, np.zeros(9) if i % 2 else known.ravel()))
    rig.spin_until(lambda: len(rig.mag) == len(fields))
    cal_var = (0.05e-6) ** 2 / 3
    for i, (f, msg) in enumerate(zip(fields, rig.mag)):
        out = msg.magnetic_field
        np.testing.assert_allclose(np.array([out.x, out.y, out.z]) * 1e6,
                                   M @ (f - m.hard_iron_uT), atol=1e-9)
        assert msg.header.frame_id == 'imu_link' and msg.header.stamp.sec == 100 + i
        noise = (0.4e-6) ** 2 * M @ M.T if i % 2 else M @ known @ M.T   # unknown: the fit's
        np.testing.assert_allclose(np.reshape(msg.magnetic_field_covariance, (3, 3)),
                                   noise + np.eye(3) * cal_var, rtol=1e-9, atol=1e-24)
    # a non-finite field is dropped, never published; the node lives on
    rig.mag_pub.publish(mag_message(99, [float('nan'), 0.0, 0.0], np.zeros(9)))
    rig.mag_pub.publish(mag_message(100, [1e-5, 2e-5, 3e-5], np.zeros(9)))
    rig.spin_until(lambda: len(rig.mag) == len(fields) + 1)
    assert rig.mag[-1].header.stamp.sec == 200
    start = len(rig.diagnostics)
    rig.spin_until(lambda: len(rig.diagnostics) > start)
    status = rig.diagnostics[-1].status[0]      # the calibration; the monitor's follow
    assert 'gyro: bias, scale and misalignment' in status.message
    assert 'magnetometer: corrected on imu/mag_corrected' in status.message


def test_without_a_magnetometer_part_nothing_is_published_and_diagnostics_say_so(tmp_path):
    path = tmp_path / 'calibration.yaml'
    save_calibration(imu_calibration(magnetometer=False), path)
    rig = Rig(path)
    try:
        rig.spin_until(lambda: rig.node.corrector.cal is not None)
        for i in range(5):
            rig.mag_pub.publish(mag_message(i, [1e-5, 2e-5, 3e-5], np.zeros(9)))
        rig.spin_until(lambda: rig.node._mag_samples == 5)
        rig.spin(0.2)
        assert rig.mag == []
        start = len(rig.diagnostics)
        rig.spin_until(lambda: len(rig.diagnostics) > start)
        status = rig.diagnostics[-1].status[0]      # the calibration; the monitor's follow
        assert 'has no magnetometer part: not corrected' in status.message
        values = {kv.key: kv.value for kv in status.values}
        assert values['mag_samples'] == '5' and values['mag_corrected_published'] == '0'
    finally:
        rig.close()


# -- the calibration node, fed through its callbacks -----------------------------------------

@pytest.fixture
def calibration_node(tmp_path):
    """Make CalibrationNodes in their own context (never spun)."""
    with nodes_in_a_context(calibration_file=str(tmp_path / 'calibration.yaml'),
                            history=False) as build:
        yield functools.partial(build, CalibrationNode)


def _stamp(msg, t):
    msg.header.stamp.sec, msg.header.stamp.nanosec = int(t), int(round((t % 1) * 1e9)) % 10 ** 9


def feed(node, samples, t0=1000.0, magnetometer=True):
    """Hand a simulated session to the node message by message (Imu and MagneticField)."""
    for k, t in enumerate(t0 + samples.t):
        m = Imu()
        _stamp(m, t)
        m.orientation_covariance[0] = -1.0
        a, w = samples.accel[k], samples.gyro[k]
        m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z = map(float, a)
        m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z = map(float, w)
        node.on_imu(m)
        if magnetometer and samples.mag_rows[k]:
            f = MagneticField()
            _stamp(f, t)
            f.magnetic_field.x, f.magnetic_field.y, f.magnetic_field.z = \
                (float(v) * 1e-6 for v in samples.mag[k])
            node.on_mag(f)
    node.process_pending()


@pytest.fixture(scope='module')
def imu_session():
    """Simulate a hand-held session at 200 Hz with gyroscope errors and a magnetometer."""
    rng = np.random.default_rng(21)
    sensor = sim.with_gyro_errors(sim.mpu9250_like(rng, 200.0), np.random.default_rng(22))
    sensor.magnetometer = sim.ak8963_like(np.random.default_rng(23))
    return sim_motion.simulate_session(sensor, sim_motion.random_poses(16, rng), rng, hold_s=2.5,
                                       rate_hz=200.0, tremor_deg=0.2)


def test_calibration_node_solves_and_reports_all_three_sensors(calibration_node, tmp_path,
                                                               imu_session):
    node = calibration_node(max_mag_samples=3000)
    feed(node, imu_session.samples)
    assert len(node.imu.mag) <= 3000 and node.imu.stride > 1            # decimated, bounded
    response = node.calibrate_and_wait()
    assert response.success, response.message
    assert 'gyroscope: calibrated' in response.message
    assert 'magnetometer: calibrated' in response.message
    last = node.progress()['last_calibration']
    assert {k: v['status'] for k, v in last['sensors'].items()} == {
        'accelerometer': 'calibrated', 'gyroscope': 'calibrated', 'magnetometer': 'calibrated'}
    json.dumps(last, allow_nan=False)                                   # finite, JSON-ready
    cal = load_calibration(tmp_path / 'calibration.yaml')
    truth = imu_session.sensor
    # the RMS relative rate error left over all directions, against the predicted one
    left = np.linalg.solve(cal.gyro_T, truth.gyro_T) - np.eye(3)
    assert np.sqrt(np.sum(left ** 2) / 3) < 3 * last['gyro_predicted_accuracy'] < 0.005
    np.testing.assert_allclose(last['gyro_T'], cal.gyro_T)
    np.testing.assert_allclose(cal.gyro_bias, truth.gyro_bias, atol=3e-4)
    np.testing.assert_allclose(cal.magnetometer.hard_iron_uT, truth.magnetometer.hard_iron,
                               atol=0.3)
    assert cal.magnetometer.predicted_accuracy == last['mag_predicted_accuracy'] < 0.3
    status = node.progress()['imu']
    assert status['gyro_received'] and status['mag_samples'] == len(node.imu.mag)


def test_a_sensor_without_data_is_reported_never_fails_the_others(calibration_node, tmp_path,
                                                                  imu_session):
    node = calibration_node()
    feed(node, imu_session.samples, magnetometer=False)
    response = node.calibrate_and_wait()
    assert response.success, response.message
    last = node.progress()['last_calibration']
    assert last['sensors']['gyroscope']['status'] == 'calibrated'
    assert last['sensors']['magnetometer'] == {
        'status': 'absent', 'reason': 'no imu/mag received', 'predicted_accuracy': None,
        'max_predicted_error': None, 'unit': 'uT'}
    assert last['mag_T'] is None and last['gyro_T'] is not None
    assert load_calibration(tmp_path / 'calibration.yaml').magnetometer is None
    # a node that keeps no raw samples says so for the gyroscope
    other = calibration_node(max_gyro_samples=0, calibration_file=str(tmp_path / 'b.yaml'))
    feed(other, imu_session.samples)
    response = other.calibrate_and_wait()
    assert response.success, response.message
    sensors = other.progress()['last_calibration']['sensors']
    assert sensors['gyroscope']['status'] == 'not collected'
    assert sensors['magnetometer']['status'] == 'calibrated'
    # ~/reset forgets the IMU buffers too
    other.on_reset(Trigger.Request(), Trigger.Response())
    assert other.imu.mag_samples() is None


def test_an_accelerometer_only_session_keeps_the_files_other_parts(calibration_node, tmp_path,
                                                                   imu_session):
    """A new session without a magnetometer no longer drops the file's one."""
    path = tmp_path / 'calibration.yaml'
    save_calibration(imu_calibration(), path)
    before = load_calibration(path)
    node = calibration_node()
    feed(node, imu_session.samples, magnetometer=False)
    response = node.calibrate_and_wait()
    assert response.success, response.message
    assert 'magnetometer: absent' in response.message
    assert 'magnetometer: carried forward from the file it replaces' in response.message
    cal = load_calibration(path)
    np.testing.assert_allclose(cal.magnetometer.hard_iron_uT, before.magnetometer.hard_iron_uT)
    assert not np.allclose(cal.gyro_T, before.gyro_T)      # this session's own gyroscope
