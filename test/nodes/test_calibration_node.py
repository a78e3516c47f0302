"""
The accel_calibration node as a subprocess, on real rclpy over DDS.

(a) the whole chain: virtual MPU9250 on a pty -> driver -> calibration node ->
``~/calibrate`` -> file -> correction node, checked against the simulated truth at
poses the calibration never saw, with the advice live on ``~/advice``; (b) a bad
parameter exits with status 2. The rest runs the node in-process, fed message by
message through its callback (deterministic: nothing is published faster than real
time into a best-effort queue): refusals leave the file byte-for-byte alone,
``~/reset``, runtime parameters, gyro bias, the model-gap check after the response,
bounded memory. What the node decides is ``session.accept``'s, tested without ROS in
test/session.
"""

import functools
import json
import os
import re
import signal
import subprocess
import sys
import time

from accel_calib_ros.core.accelerometer.fit import Calibration
from accel_calib_ros.dataio.calibration_file import load_calibration, save_calibration
from accel_calib_ros.nodes.calibration import CalibrationNode
from accel_calib_ros.session.windows import Window
from accel_calib_ros.sim.motion import simulate_session, simulate_window_means
from accel_calib_ros.sim.sensor import mpu9250_like
import numpy as np
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from ros_helpers import Collector, nodes_in_a_context, Processes, read_log, stop_node, wait_exit
from sensor_msgs.msg import Imu
from std_msgs.msg import String
from std_srvs.srv import Trigger
import yaml

pytestmark = pytest.mark.ros

CALIBRATION = 'accel_calib_ros.nodes.calibration'
CORRECTION = 'accel_calib_ros.nodes.correction'
DRIVER = 'accel_calib_ros.nodes.driver'

LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
RELIABLE = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)


class Client(Collector):
    """Collector plus the calibration node's status, its services and a raw publisher."""

    def __init__(self):
        super().__init__({'imu/data_raw': Imu, 'imu/corrected': Imu}, RELIABLE, 'test_peer')
        self.status, self.advice = {}, {}
        self.node.create_subscription(String, 'accel_calibration/status', self._on_status,
                                      LATCHED)
        self.node.create_subscription(String, 'accel_calibration/advice', self._on_advice,
                                      LATCHED)
        self.calibrate = self.node.create_client(Trigger, 'accel_calibration/calibrate')
        self.reset = self.node.create_client(Trigger, 'accel_calibration/reset')

    def _on_status(self, msg):
        self.status = json.loads(msg.data)

    def _on_advice(self, msg):
        self.advice = json.loads(msg.data)

    def wait(self, condition, timeout, what):
        """Process callbacks until ``condition()``; fail naming ``what`` after ``timeout``."""
        assert self.spin_until(condition, timeout), f'timed out waiting for {what}'

    def call(self, client, timeout=30.0):
        """Call a Trigger service and return its response."""
        self.wait(client.service_is_ready, 15.0, f'service {client.srv_name}')
        future = client.call_async(Trigger.Request())
        self.executor.spin_until_future_complete(future, timeout_sec=timeout)
        assert future.done(), f'{client.srv_name} did not answer within {timeout} s'
        return future.result()


@pytest.fixture
def procs(tmp_path):
    """Start nodes and devices; stop them all afterwards, nodes must exit with 0."""
    p = Processes(tmp_path)
    yield p
    nodes = [proc for proc in p.procs if proc.args[2].startswith('accel_calib_ros.nodes')]
    codes = {}
    for proc in reversed(p.procs):
        code, log = stop_node(proc)
        print(log)
        codes[proc.args[2]] = code
    assert all(codes[proc.args[2]] == 0 for proc in nodes), codes


@pytest.fixture
def client():
    c = Client()
    yield c
    c.close()


def test_bad_parameter_exits_with_status_2():
    for bad in ('method:=foo', 'gravity:=abc', 'max_windows:=3'):
        proc = subprocess.run(
            [sys.executable, '-m', CALIBRATION, '--ros-args', '-p',
             bad], capture_output=True, text=True, timeout=30)
        assert proc.returncode == 2, proc.stderr
        name = bad.split(':=')[0]
        assert f"parameter '{name}'" in proc.stderr
        assert 'Traceback' not in proc.stderr


def truth_calibration(path):
    """Read the simulated sensor's own T and bias from the device's --truth-out file."""
    with open(path, encoding='utf-8') as f:
        truth = yaml.safe_load(f)
    return Calibration(T=np.asarray(truth['T'], float),
                       bias=np.asarray(truth['bias_m_s2'], float))


CAL_POSES, FRESH_POSES, HOLD_S, MOVE_S = 14, 3, 2.0, 0.7


def test_full_chain_device_to_corrected(tmp_path, procs, client):
    link, truth_path = str(tmp_path / 'imu0'), str(tmp_path / 'truth.yaml')
    cal_path = tmp_path / 'calibration.yaml'
    # The nodes first, so that the device's first pose is not spent waiting for them.
    calibration = procs.node(CALIBRATION, {'calibration_file': str(cal_path)})
    procs.node(CORRECTION, {'calibration_file': str(cal_path)})
    client.wait(lambda: client.calibrate.service_is_ready(), 15.0, 'the calibration node')
    procs.device(['--link', link, '--poses', 'random', '--count', CAL_POSES + FRESH_POSES,
                  '--hold', HOLD_S, '--move', MOVE_S, '--rate', 200, '--seed', 11,
                  '--truth-out', truth_path, '--corrupt', 0.02])
    procs.node(DRIVER, {'port': link})
    truth = truth_calibration(truth_path)
    client.wait(lambda: client.status.get('windows', 0) >= CAL_POSES - 1,
                CAL_POSES * (HOLD_S + MOVE_S) + 30, 'calibration windows')
    response = client.call(client.calibrate)
    print(response.message)
    assert response.success, response.message
    assert str(cal_path) in response.message and 'predicted accuracy' in response.message
    cal = load_calibration(cal_path)
    assert cal.observations >= CAL_POSES - 1
    assert 0 < cal.predicted_accuracy <= 0.02
    # The advice, live on its latched topic (interface.md §5 keys).
    client.wait(lambda: client.advice.get('windows', 0) >= CAL_POSES - 1, 5.0, 'advice')
    assert {'windows', 'predicted_accuracy', 'target', 'enough', 'next_pose'} \
        <= set(client.advice)
    assert client.advice['target'] == 0.01

    # The parameters against the truth, over directions never held.
    rng = np.random.default_rng(0)
    fresh = rng.standard_normal((500, 3))
    fresh *= 9.80665 / np.linalg.norm(fresh, axis=1, keepdims=True)
    err = np.linalg.norm(cal.correct(truth.distort(fresh)) - fresh, axis=1)
    print(f'fit vs truth over 500 fresh directions: max {err.max():.4f} m/s2')
    assert err.max() < 0.05

    # The live stream while the device holds the poses the calibration never saw.
    client.spin(0.6)                    # the correction node reloads within 0.25 s
    client.clear()
    client.spin(FRESH_POSES * (HOLD_S + MOVE_S))

    def by_stamp(topic):
        return {(m.header.stamp.sec, m.header.stamp.nanosec):
                (m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z)
                for m in client.messages[topic]}
    raw, corrected = by_stamp('imu/data_raw'), by_stamp('imu/corrected')
    keys = sorted(set(raw) & set(corrected))
    assert len(keys) > 200, f'only {len(keys)} corrected samples arrived'
    raw = np.array([raw[k] for k in keys])
    corrected = np.array([corrected[k] for k in keys])
    live = np.linalg.norm(corrected - truth.correct(raw), axis=1)
    raw_err = np.linalg.norm(raw - truth.correct(raw), axis=1)
    print(f'live corrected vs truth over {len(keys)} samples: max {live.max():.4f}, '
          f'RMS {np.sqrt(np.mean(live ** 2)):.4f} m/s2 (raw RMS '
          f'{np.sqrt(np.mean(raw_err ** 2)):.4f})')
    assert live.max() < 0.05

    # SIGINT during ~/calibrate: the call is answered before the node exits (refused, or
    # its save completed), never a save after the signal without an answer; exit 0.
    before = cal_path.read_bytes()
    future = client.calibrate.call_async(Trigger.Request())
    client.wait(lambda: client.status.get('calibrating'), 10.0, 'the call to begin')
    calibration.send_signal(signal.SIGINT)
    client.wait(future.done, 15.0, 'the answer to ~/calibrate')
    code = wait_exit(calibration, 15.0)
    log = read_log(calibration)
    assert code == 0 and 'Traceback' not in log, log[-3000:]
    response = future.result()
    print(response.message)
    if response.success:
        assert load_calibration(cal_path).created != cal.created
    else:
        assert 'shutting down' in response.message and cal_path.read_bytes() == before


@pytest.fixture
def node_in_process(tmp_path):
    """Make CalibrationNodes in their own context (never spun): the decision logic."""
    with nodes_in_a_context(calibration_file=str(tmp_path / 'calibration.yaml')) as build:
        yield functools.partial(build, CalibrationNode)


CANDIDATE_FACES = np.vstack([np.eye(3), -np.eye(3)])


def inject_windows(node, means, temps, count=300, scatter=0.03):
    """Hand the node finished windows as its detector would."""
    for k, (mean, temp) in enumerate(zip(means, temps)):
        node.windows.append(Window(mean=np.asarray(mean, float), scatter=np.full(3, scatter),
                                   count=count, t_start=k - 0.7, t_stop=k + 0.7,
                                   temp=float(temp)))


def directions(n, seed):
    """Return ``n`` random unit vectors."""
    rng = np.random.default_rng(seed)
    d = rng.standard_normal((n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def test_config_files_match_the_declared_parameters():
    from accel_calib_ros.nodes.correction import CorrectionNode
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        for cls, name in ((CalibrationNode, 'calibration'), (CorrectionNode, 'correction')):
            path = os.path.join(root, 'config', f'{name}.yaml')
            with open(path, encoding='utf-8') as f:
                body = yaml.safe_load(f)['/**']
            node = cls(context=context, cli_args=['--ros-args', '-r', '__ns:=/robot1',
                                                  '--params-file', path])
            try:
                for key, value in body['ros__parameters'].items():
                    assert node.has_parameter(key), f'{name}.yaml: {key} is not a parameter'
                    assert node.get_parameter(key).value == value
                declared = set(node.list_parameters([], 0).names) - {
                    'use_sim_time', 'start_type_description_service'}
                assert declared == set(body['ros__parameters']), f'{name}.yaml is incomplete'
            finally:
                node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)
    with open(os.path.join(root, 'accel_calib_ros', 'nodes', 'driver.py'),
              encoding='utf-8') as f:
        source = f.read()
    with open(os.path.join(root, 'config', 'driver.yaml'), encoding='utf-8') as f:
        driver = yaml.safe_load(f)['/**']['ros__parameters']
    for key in driver:
        assert re.search(rf"(declare\(\s*self,\s*|Param\(\s*)'{key}'", source), \
            f'driver.yaml: {key} is not a driver parameter'


# -- in-process, fed through the subscription callback ------------------------------------

def imu_message(t, accel, gyro=None, frame_id='imu_link'):
    """Build a raw sensor_msgs/Imu as the driver publishes it."""
    m = Imu()
    m.header.stamp.sec, m.header.stamp.nanosec = int(t), int(round((t % 1) * 1e9)) % 10 ** 9
    m.header.frame_id = frame_id
    m.orientation.w = 1.0
    m.orientation_covariance[0] = -1.0
    m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z = \
        (float(v) for v in accel)
    if gyro is None:
        m.angular_velocity_covariance[0] = -1.0
    else:
        m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z = \
            (float(v) for v in gyro)
    return m


def feed(node, samples, t0=1000.0, gyro_bias=None):
    """Hand a simulated recording to the node message by message, then detect."""
    gyro = samples.gyro if gyro_bias is None else samples.gyro + gyro_bias
    for t, a, w in zip(t0 + samples.t, samples.accel, gyro):
        node.on_imu(imu_message(t, a, w))
    node.process_pending()


def collected(node):
    """Return the windows finished plus the one being held at the end of the stream."""
    return len(node.windows) + len(node.detector.peek())


def session(directions, seed, hold_s=2.0, rate_hz=200.0):
    """Simulate a session holding the given gravity directions."""
    rng = np.random.default_rng(seed)
    sensor = mpu9250_like(rng, rate_hz=rate_hz)
    return simulate_session(sensor, directions, rng, hold_s=hold_s, move_s=0.6,
                            rate_hz=rate_hz, lead_s=hold_s)


def test_refusals_leave_the_file_untouched_and_reset_clears(node_in_process, tmp_path):
    path = tmp_path / 'calibration.yaml'
    save_calibration(Calibration(T=np.diag([1.01, 0.99, 1.0]), bias=[0.1, -0.2, 0.3]), path)
    before = path.read_bytes()
    mtime = os.stat(path).st_mtime_ns
    node = node_in_process()
    feed(node, session(np.eye(3), seed=3).samples)
    assert collected(node) == 3
    response = node.calibrate_and_wait()
    assert not response.success
    assert 'refused' in response.message and 'orientations' in response.message
    assert path.read_bytes() == before and os.stat(path).st_mtime_ns == mtime
    status = node.progress()
    assert status['windows'] == 2 and status['last_calibration']['success'] is False
    assert node._advice['next_pose']['name']

    # A tilt-only session (every pose within 25 deg of +z): solvable, but the fit cannot
    # stand behind its z bias: refused on predicted accuracy, naming what is missing.
    tilt = np.radians(np.r_[0.0, np.full(6, 12.0), np.full(8, 24.0)])
    azimuth = np.r_[0.0, np.arange(6) * np.pi / 3, np.arange(8) * np.pi / 4]
    dirs = np.c_[np.sin(tilt) * np.cos(azimuth), np.sin(tilt) * np.sin(azimuth),
                 np.cos(tilt)]
    tilted = node_in_process()
    feed(tilted, session(dirs, seed=5, hold_s=1.6).samples)
    assert collected(tilted) == 15
    response = tilted.calibrate_and_wait()
    assert not response.success, response.message
    assert 'predicted accuracy' in response.message and 'z axis down' in response.message
    assert tilted.progress()['last_calibration']['predicted_accuracy'] > 0.02
    assert path.read_bytes() == before and os.stat(path).st_mtime_ns == mtime

    response = node.on_reset(Trigger.Request(), Trigger.Response())
    assert response.success and len(node.windows) == 0
    response = node.calibrate_and_wait()
    assert not response.success and 'no static windows' in response.message
    assert path.read_bytes() == before


def test_session_start_up_burst_and_gyro_bias(node_in_process, tmp_path):
    """A burst of stale samples first must not cost the session; gyro bias is stored."""
    s = session(directions(16, 3), seed=6, hold_s=1.6)
    node = node_in_process(calibration_file=str(tmp_path / 'new' / 'dir' / 'cal.yaml'))
    assert (tmp_path / 'new' / 'dir').is_dir()               # default directories made
    rng = np.random.default_rng(7)
    for k in range(300):                # 300 queued samples stamped 100 us apart
        node.on_imu(imu_message(999.97 + 1e-4 * k, s.samples.accel[0] + rng.normal(0, 0.03, 3),
                                rng.normal(0.0, 0.002, 3) + [0.012, -0.02, 0.007]))
    bias = np.array([0.012, -0.02, 0.007])
    feed(node, s.samples, gyro_bias=bias)
    assert collected(node) == 16                         # every hold
    assert abs(node.detector.rate_hz - 200.0) < 2.0
    response = node.calibrate_and_wait()
    assert response.success, response.message
    cal = load_calibration(tmp_path / 'new' / 'dir' / 'cal.yaml')
    simulated = getattr(s.sensor, 'gyro_bias', np.zeros(3))     # the simulator's own offset
    assert np.abs(cal.gyro_bias - bias - simulated).max() < 3e-4
    assert cal.sensor_id == 'imu_link' and cal.predicted_accuracy <= 0.02
    # The calibration and its windows are in the history next to the file.
    from accel_calib_ros.dataio.history import History
    with History(tmp_path / 'new' / 'dir' / 'history.sqlite') as history:
        (row,) = history.calibrations('imu_link')
        assert row['method'] == 'ml' and abs(row['predicted_accuracy']
                                             - cal.predicted_accuracy) < 1e-9
        assert len(history.windows('imu_link')['mean']) == 16


def test_parameters_change_at_runtime_or_are_refused(node_in_process, tmp_path):
    node = node_in_process()
    for name, value in (('method', 'gn'), ('max_predicted_error', 0.05),
                        ('target_accuracy', 0.002), ('max_windows', 20),
                        ('calibration_file', str(tmp_path / 'x' / 'c.yaml')),
                        ('window_s', 0.3)):
        (r,) = node.set_parameters([Parameter(name, value=value)])
        assert r.successful, (name, r.reason)
        assert node.params[name] == value
    assert node.windows.maxlen == 20 and node.path.endswith('c.yaml')
    assert (tmp_path / 'x').is_dir() and node.detector.window_s == 0.3
    for name, value in (('method', 'lm'), ('gravity', 12.0), ('max_windows', 3),
                        ('max_predicted_error', float('nan')), ('threshold_factor', 0.5),
                        ('thermal', 'maybe')):
        (r,) = node.set_parameters([Parameter(name, value=value)])
        assert not r.successful and r.reason, name
        assert node.get_parameter(name).value != value


def test_model_gap_check_after_the_response(node_in_process):
    rng = np.random.default_rng(11)
    sensor = mpu9250_like(rng, rate_hz=200.0)
    sensor.T = np.diag(np.diag(sensor.T))
    sensor.T[0, 1], sensor.T[1, 2] = 0.02, -0.015          # 1.1° and 0.9° off square
    u = directions(30, 12)
    noise = sensor.noise_std[0]
    means = simulate_window_means(sensor, u, 300, rng)
    node = node_in_process(method='gn', max_residual_ratio=1000.0, max_predicted_error=1.0)
    inject_windows(node, means, np.full(30, 25.0), scatter=noise)
    response = node.calibrate_and_wait()
    assert response.success, response.message
    assert 'Note' not in response.message and node._model_gap is None
    executor = SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    deadline = time.monotonic() + 10.0
    while node._model_gap is None and time.monotonic() < deadline:
        executor.spin_once(timeout_sec=0.05)
    executor.remove_node(node)
    gap = node.progress()['model_gap']
    assert 'nonorthogonality' in gap['missing_effects'] and 'gn model' in gap['note']


def test_memory_stays_bounded(node_in_process):
    node = node_in_process(max_windows=10)
    rng = np.random.default_rng(13)
    s = session(CANDIDATE_FACES, seed=14, hold_s=1.6)
    for k in range(4):                                     # 24 holds, 10 kept
        feed(node, s.samples, t0=1000.0 + 100.0 * k)
    assert len(node.windows) == 10
    # An hour-long hold at 200 Hz through the detector: its state stays bounded.
    det = node.detector
    det.finish()
    seen = []
    chunk = 2000
    for k in range(360):
        t = 5000.0 + (k * chunk + np.arange(chunk)) / 200.0
        seen += det.feed(t, [0.1, 0.2, 9.8] + rng.normal(0, 0.02, (chunk, 3)))
        assert det.retained_samples() <= det.cap + chunk + 2 * det.n + 256
    (window,) = det.finish()
    assert window['count'] > 0.99 * 360 * chunk and not seen
    assert node.intake.pending() == 0


def test_calibrate_thermal_learns_the_warm_up_on_top_of_the_file(node_in_process, tmp_path):
    from accel_calib_ros.sim.chamber import ChamberProgramme, simulate_still, thermal_unit
    from sensor_msgs.msg import Temperature
    rng = np.random.default_rng(12)
    warm_up = ChamberProgramme(set_points=(45.0,), rates_c_min=100.0, hold_s=1500.0,
                               start_c=20.0, board_tau_s=400.0, lead_s=60.0)
    sensor = thermal_unit(rng, offsets_mg=(10.0, 8.0, 30.0), span_c=(20.0, 45.0),
                          temp_ref=21.0)
    s = simulate_still(sensor, [0.0, 0.0, 1.0], rng, warm_up.duration_s, rate_hz=5.0,
                       temperature=warm_up).samples
    path = tmp_path / 'calibration.yaml'
    node = node_in_process()
    response = node.calibrate_thermal_and_wait()        # nothing yet, and no file
    assert not response.success and 'no thermal data collected yet' in response.message
    for t, a, temp in zip(1000.0 + s.t, s.accel, s.temp):
        node.intake.on_temperature(Temperature(temperature=float(temp)))
        node.on_imu(imu_message(t, a))
    node.process_pending()
    assert node.progress()['thermal']['enough']
    response = node.calibrate_thermal_and_wait()
    assert not response.success and 'no calibration in force' in response.message
    assert not path.exists()
    save_calibration(Calibration(T=sensor.T, bias=sensor.bias, temperature_range_c=(20.5, 21.5),
                                 sensor_id=node.sensor), path)
    before = path.read_bytes()
    node.params['thermal_min_span_c'] = 50.0            # more than the warm-up gives
    response = node.calibrate_thermal_and_wait()
    assert not response.success and 'spans only' in response.message
    assert path.read_bytes() == before
    node.params['thermal_min_span_c'] = 5.0
    response = node.calibrate_thermal_and_wait()
    assert response.success, response.message
    cal = load_calibration(path)
    assert cal.thermal is not None and cal.thermal.source == 'still'
    np.testing.assert_allclose(cal.T, sensor.T)
    temps = np.array([25.0, 35.0, 44.0])
    d = temps - sensor.temp_ref
    truth = (np.outer(d, sensor.bias_tempco) + np.outer(d ** 2, sensor.bias_tempco_quadratic)
             + np.outer(d ** 3, sensor.bias_tempco_cubic))
    fitted = cal.thermal.drift(np.zeros((3, 3)), temps)
    # Referenced to the file's own temperature (21 degC): the offsets' change from there.
    ref = cal.thermal.reference_c - sensor.temp_ref
    truth -= (sensor.bias_tempco * ref + sensor.bias_tempco_quadratic * ref ** 2
              + sensor.bias_tempco_cubic * ref ** 3)
    assert np.max(np.abs(fitted - truth)) < 1e-3 * 9.80665
    assert node.progress()['last_thermal']['success']
    node.on_reset(Trigger.Request(), Trigger.Response())
    assert node.progress()['thermal']['bins'] == 0
