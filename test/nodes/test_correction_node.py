"""
The accel_correction node, in-process with real rclpy over DDS.

The node runs in the test's own process (a fresh context per test, its own domain id),
so its output can be compared with :meth:`Calibration.correct` to 1e-9 and every
published message can be accounted for.
"""

import os
import random
import re
import subprocess
import sys
import time

from accel_calib_ros.core.accelerometer.fit import Calibration
from accel_calib_ros.core.accelerometer.thermal import ThermalBand, ThermalTable
from accel_calib_ros.dataio.atomic import atomic_write_text
from accel_calib_ros.dataio.calibration_file import (calibration_to_yaml, load_calibration,
                                                     save_calibration)
from accel_calib_ros.nodes.correction import CorrectionNode, UNCALIBRATED_STD
from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu, Temperature
from std_srvs.srv import Trigger

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
        self.diagnostics = []
        self.peer.create_subscription(DiagnosticArray, '/diagnostics',
                                      self.diagnostics.append, 10)
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

    def last_diagnostics(self):
        """Wait for the next /diagnostics message of the node; return its statuses."""
        start = len(self.diagnostics)
        self.spin_until(lambda: len(self.diagnostics) > start)
        return self.diagnostics[-1].status

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
    # No gyro bias in the calibration: the zero-rate offset is still in, on the diagonal.
    extra = np.asarray(got.angular_velocity_covariance) - sent.angular_velocity_covariance
    assert np.all(extra.reshape(3, 3)[np.eye(3, dtype=bool)] > 0)
    assert np.all(extra.reshape(3, 3)[~np.eye(3, dtype=bool)] == 0)


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


def diagnostics_of(rig):
    """Return the node's /diagnostics status: (level byte, message, values dict)."""
    rig.node.publish_diagnostics()
    status = rig.last_diagnostics()[0]       # then the field monitor's two
    return status.level, status.message, {kv.key: kv.value for kv in status.values}


BAD_FILES = {
    'fit: hello': b'fit: hello\n',
    'deep nesting': b'a: ' + b'[' * 5000 + b']' * 5000 + b'\n',
    'non-UTF-8': b'version: 1\nmethod: \xff\xfe\n',
}


def bad_variants(cal):
    """Calibration texts with values that would make the output non-finite."""
    text = calibration_to_yaml(cal)
    out = dict(BAD_FILES)
    out['T = 1e-300'] = re.sub(r'T:\n- \[[^,]+,', 'T:\n- [1.0e-300,', text, count=1).encode()
    out['NaN gravity'] = re.sub(r'gravity_m_s2: \S+', 'gravity_m_s2: .nan', text,
                                count=1).encode()
    out['NaN thermal offset'] = re.sub(r'(offset\w*: \[)[^,\]]+', r'\1.nan', text,
                                       count=1).encode()
    assert all(v != text.encode() for v in out.values()), 'a variant did not change'
    return out


def test_bad_files_keep_the_last_good_calibration_and_say_so(tmp_path, rig_factory):
    path = tmp_path / 'calibration.yaml'
    path.write_bytes(BAD_FILES['fit: hello'])                  # bad from the start
    rig = rig_factory(path)
    rng = np.random.default_rng(5)
    m = raw_message(rng, 0)
    (out,) = send(rig, [m])
    assert np.array_equal(accel(out), accel(m))                # documented pass-through
    level, message, values = diagnostics_of(rig)
    assert level == b'\x01' and 'uncalibrated' in message and 'bad calibration' in message
    good = make_calibration(21, thermal=True)
    save_calibration(good, path)
    rig.spin_until(lambda: rig.node.corrector.cal is not None)
    for name, data in bad_variants(good).items():
        with open(path, 'wb') as f:
            f.write(data)
        rig.spin_until(lambda: rig.node._file_problem != '', timeout=5.0)
        rig.set_temperature(30.0 + len(name) % 5)
        m = raw_message(rng, 1)
        (out,) = send(rig, [m])
        expected = good.correct(accel(m), np.array([rig.node.temperature]))[0]
        np.testing.assert_allclose(accel(out), expected, atol=1e-9, err_msg=name)
        level, message, _ = diagnostics_of(rig)
        assert level == b'\x01' and 'keeping the last good calibration' in message, name
        save_calibration(good, path)
        rig.spin_until(lambda: rig.node._file_problem == '', timeout=5.0)
    assert diagnostics_of(rig)[0] == b'\x00'


def test_non_finite_input_is_dropped_and_counted(tmp_path, rig_factory):
    path = tmp_path / 'calibration.yaml'
    save_calibration(make_calibration(3), path)
    rig = rig_factory(path)
    rng = np.random.default_rng(6)
    bad = raw_message(rng, 0)
    bad.linear_acceleration.y = float('nan')
    bad2 = raw_message(rng, 1)
    bad2.angular_velocity.z = float('inf')
    good = raw_message(rng, 2)
    for m in (bad, bad2):
        rig.imu_pub.publish(m)
    (out,) = send(rig, [good])
    rig.spin(0.2)
    assert len(rig.received) == 1 and out.header.stamp.sec == good.header.stamp.sec
    assert rig.node._dropped == 2
    assert diagnostics_of(rig)[2]['dropped_non_finite'] == '2'
    # One hardware_id per sensor across the nodes: the sensor id (nodes/paths).
    assert {s.hardware_id for s in rig.last_diagnostics()} == {good.header.frame_id}


def test_gyro_bias_level_trim_and_temperature_warning(tmp_path, rig_factory):
    from accel_calib_ros.core.level import roll_pitch
    path = tmp_path / 'calibration.yaml'
    cal = make_calibration(7)
    cal.gyro_bias = np.array([0.01, -0.02, 0.005])
    cal.temperature_range_c = (20.0, 30.0)
    save_calibration(cal, path)
    rig = rig_factory(path)
    rng = np.random.default_rng(7)
    sent = [raw_message(rng, i) for i in range(20)]
    got = send(rig, sent)
    for s, g in zip(sent, got):
        w_in = np.array([s.angular_velocity.x, s.angular_velocity.y, s.angular_velocity.z])
        w_out = np.array([g.angular_velocity.x, g.angular_velocity.y, g.angular_velocity.z])
        np.testing.assert_allclose(w_out, w_in - cal.gyro_bias, atol=1e-12)
        # The bias is removed: what is left is the driver's noise covariance.
        assert list(g.angular_velocity_covariance) == list(s.angular_velocity_covariance)
    # Temperature: inside the range plus margin is fine, far outside warns.
    rig.set_temperature(31.0)
    assert diagnostics_of(rig)[0] == b'\x00'
    rig.set_temperature(45.0)
    level, message, _ = diagnostics_of(rig)
    assert level == b'\x01' and 'outside the calibrated range' in message

    # Level trim: the robot rests with the sensor tilted 3 deg about x and -2 about y.
    roll, pitch = np.radians(3.0), np.radians(-2.0)
    up = 9.80665 * np.array([np.sin(-pitch), np.sin(roll) * np.cos(pitch),
                             np.cos(roll) * np.cos(pitch)])
    resting = []
    for i in range(300):
        m = raw_message(rng, i)
        raw = cal.distort((up + rng.normal(0, 0.01, 3))[None, :])[0]
        m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z = \
            (float(v) for v in raw)
        resting.append(m)
    for k in range(0, len(resting), 50):
        send(rig, resting[k:k + 50])
    rig.node._rate_hz = 100.0
    response = rig.node.on_level(None, Trigger.Response())
    assert response.success, response.message
    stored = load_calibration(path).level_roll_pitch_rad
    np.testing.assert_allclose(stored, roll_pitch(up), atol=2e-3)
    np.testing.assert_allclose(stored, (roll, pitch), atol=2e-3)
    (out,) = send(rig, resting[-1:])
    a = accel(out)
    assert np.hypot(a[0], a[1]) < 0.05 and abs(a[2] - 9.80665) < 0.05   # now level
    # Moving: refused, the file keeps its trim.
    before = path.read_bytes()
    shaking = [raw_message(rng, i) for i in range(300)]
    for k in range(0, len(shaking), 50):
        send(rig, shaking[k:k + 50])
    response = rig.node.on_level(None, Trigger.Response())
    assert not response.success and 'moving' in response.message
    assert path.read_bytes() == before


def test_parameters_change_at_runtime_or_are_refused(tmp_path, rig_factory):
    from rcl_interfaces.srv import SetParameters
    path_a, path_b = tmp_path / 'a.yaml', tmp_path / 'b.yaml'
    cal_a, cal_b = make_calibration(30), make_calibration(31)
    save_calibration(cal_a, path_a)
    save_calibration(cal_b, path_b)
    rig = rig_factory(path_a)
    client = rig.peer.create_client(SetParameters, '/accel_correction/set_parameters')
    rig.spin_until(client.service_is_ready)

    def set_params(**values):
        req = SetParameters.Request(parameters=[
            Parameter(k, value=v).to_parameter_msg() for k, v in values.items()])
        future = client.call_async(req)
        rig.spin_until(future.done)
        return future.result().results

    (ok,) = set_params(calibration_file=str(path_b))
    assert ok.successful, ok.reason
    rng = np.random.default_rng(8)
    m = raw_message(rng, 0)
    (out,) = send(rig, [m])
    np.testing.assert_allclose(accel(out), cal_b.correct(accel(m))[0], atol=1e-9)
    for name, value, words in (('reload_period_s', -1.0, 'reload_period_s'),
                               ('reload_period_s', 'fast', 'type'),
                               ('temperature_margin_c', float('nan'), 'temperature_margin_c'),
                               ('diagnostics_period_s', 2.0, 'read-only')):
        (r,) = set_params(**{name: value})
        assert not r.successful and words in r.reason, (name, r.reason)
    assert rig.node.get_parameter('reload_period_s').value == 0.05
    (r,) = set_params(reload_period_s=2)                  # an integer for a double
    assert r.successful and rig.node.params['reload_period_s'] == 2.0


def test_correction_node_is_lean():
    code = ('import sys, accel_calib_ros.nodes.correction; '
            'print(",".join(m for m in ("scipy", "matplotlib") if m in sys.modules))')
    proc = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == ''


def _hysteresis_calibration():
    """Return a calibration with a one-pose thermal table and a heating/cooling term."""
    from accel_calib_ros.core.accelerometer.thermal_lag import Hysteresis
    cal = make_calibration(5)
    zeros = np.zeros(3)
    bands = [ThermalBand(20.0, 25.0, 22.0, zeros, zeros, np.array([0.01, -0.02, 0.05]), 30),
             ThermalBand(25.0, 30.0, 28.0, zeros, zeros, np.array([0.03, -0.01, 0.09]), 30)]
    cal.thermal = ThermalTable(5.0, bands, 'linear', 25.0, (21.0, 29.0),
                               Hysteresis(20.0, [0.0, 0.004, -0.03], 'temperature_rate'),
                               'still')
    cal.temperature_range_c = (21.0, 29.0)
    return cal


def test_the_hysteresis_follows_the_temperature_stream_over_a_reload(tmp_path, rig_factory):
    path = tmp_path / 'calibration.yaml'
    save_calibration(_hysteresis_calibration(), path)
    cal = load_calibration(path)
    rig = rig_factory(path)
    rng = np.random.default_rng(9)
    stamps = 1000.0 + np.arange(40) * 1.0
    temps = 22.0 + 0.1 * np.arange(40)                 # heating at 6 degC/min
    for k, (t, temp) in enumerate(zip(stamps, temps)):
        msg = Temperature(temperature=float(temp), variance=0.0)
        msg.header.stamp.sec, msg.header.stamp.nanosec = int(t), 0
        rig.temp_pub.publish(msg)
        rig.spin_until(lambda temp=temp: rig.node.temperature == temp)
        if k == 20:                                    # the same file again: a reload
            before = rig.node.corrector
            save_calibration(cal, path)
            rig.spin_until(lambda: rig.node.corrector is not before)
    sent = [raw_message(rng, i) for i in range(20)]
    got = send(rig, sent)
    stream = cal.lag_stream()
    gradient = stream.gradient(stamps, temps)[-1]
    assert gradient > 1.0                               # the term is there, and carried on
    expected = cal.correct(np.array([accel(m) for m in sent]), np.full(20, temps[-1])) \
        - np.linalg.solve(cal.T, gradient * cal.hysteresis.offset_per_c)
    assert np.max(np.abs(np.array([accel(m) for m in got]) - expected)) < 1e-9
    # A silence of the temperature longer than the lag's gap restarts it, and says so.
    msg = Temperature(temperature=26.0, variance=0.0)
    msg.header.stamp.sec = int(stamps[-1] + 100.0)
    rig.temp_pub.publish(msg)
    rig.spin_until(lambda: rig.node.temperature == 26.0)
    assert rig.node.corrector.lag.gradient == 0.0
    status = rig.last_diagnostics()[0]
    values = {kv.key: kv.value for kv in status.values}
    assert values['hysteresis_restarts'] == '1'
    assert 'restarted from zero' in status.message
    rig.set_temperature(35.0)
    status = rig.last_diagnostics()[0]
    assert 'outside the calibrated range' in status.message and 'extrapolation' in \
        status.message
