"""
On a real robot, round two: several robots on one host, a clock that jumps, the level frame.

Processes over real rclpy/DDS where the case is about processes (two launched stacks in
one ROS_HOME, the driver on a re-plug); the rest in-process on real rclpy, the node's
callbacks driven by the test. SIGINT during ``~/calibrate`` is the last phase of the
whole-chain test (test_calibration_node.py), which has the windows for it.
"""

import math
import os
import subprocess
import time

from accel_calib_ros.core.accelerometer.fit import Calibration
from accel_calib_ros.dataio.calibration_file import load_calibration, save_calibration
from accel_calib_ros.nodes.calibration import CalibrationNode
from accel_calib_ros.nodes.correction import CorrectionNode
from accel_calib_ros.nodes.driver import Mpu9250Driver
from accel_calib_ros.nodes.level_frame import level_pose, LevelFrame
from accel_calib_ros.nodes.parameters import ParameterProblem
from diagnostic_msgs.msg import DiagnosticArray
import launch_tools
import numpy as np
import pytest
import rclpy
from rclpy.parameter import Parameter
from ros_helpers import Collector, read_log, stop_node
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import Imu
from std_srvs.srv import Trigger
from test_launch_file import bin_path, LAUNCH, ROOT
from test_node_files import _feed_good_session, _imu

pytestmark = pytest.mark.ros


def statuses(collector):
    """Return the newest /diagnostics status of each name: {name: (level, message, values)}."""
    out = {}
    for array in collector.messages['/diagnostics']:
        for s in array.status:
            out[s.name] = (s.level, s.message, dict({kv.key: kv.value for kv in s.values},
                                                    hardware_id=s.hardware_id))
    return out


# -- two stacks in one ROS_HOME, launched with the defaults ------------------------------------
def test_two_stacks_in_one_ros_home_keep_their_own_calibration(monkeypatch, tmp_path, procs):
    """/robot1 and /robot2 (this one as for a bag: no driver, sim time) on one host."""
    from rosgraph_msgs.msg import Clock
    home = tmp_path / 'ros_home'
    robot1 = home / 'accel_calib_ros' / 'robot1' / 'imu_link' / 'calibration.yaml'
    robot2 = home / 'accel_calib_ros' / 'robot2' / 'imu_link' / 'calibration.yaml'
    cal = Calibration(T=np.diag([1.01, 0.99, 1.02]), bias=[0.1, -0.2, 0.3])
    cal.sensor_id = 'robot1/imu_link'
    save_calibration(cal, robot1)
    robot2.parent.mkdir(parents=True)
    robot2.write_bytes(robot1.read_bytes())         # /robot1's file where /robot2 looks
    actions = launch_tools.load_description(LAUNCH, ROOT, monkeypatch)
    env = dict(os.environ, ROS_HOME=str(home))
    started = []
    for given in ({'namespace': 'robot1', 'driver': 'false'},
                  {'namespace': 'robot2', 'driver': 'false', 'use_sim_time': 'true'}):
        for p in launch_tools.command_lines(actions, given, str(tmp_path), bin_path):
            log = open(tmp_path / f'{given["namespace"]}_{p["name"]}.log', 'w')
            proc = subprocess.Popen(p['cmd'], stdout=log, stderr=subprocess.STDOUT,
                                    stdin=subprocess.DEVNULL, env=env)
            proc.log_path = log.name
            log.close()
            procs.procs.append(proc)
            started.append(proc)
    names = {f'robot{k}/{n}: {part}' for k in (1, 2)
             for n, part in (('accel_calibration', 'collection'),
                             ('accel_correction', 'calibration'))}
    with Collector({'/diagnostics': DiagnosticArray}) as collector:
        clock = collector.node.create_publisher(Clock, '/clock', 10)

        def tick():                              # /robot2 runs on /clock
            clock.publish(Clock(clock=collector.node.get_clock().now().to_msg()))
        collector.node.create_timer(0.1, tick)
        seen = collector.spin_until(lambda: names <= set(statuses(collector)), 40.0)
        graph = collector.node.get_node_names_and_namespaces()
    logs = '\n'.join(read_log(p) for p in started)
    assert seen, (sorted(statuses(collector)), logs[-3000:])
    assert not [n for n in graph if n[0] == 'mpu9250_driver'], graph      # driver:=false
    got = statuses(collector)
    level, message, values = got['robot1/accel_correction: calibration']
    assert level == b'\x00' and values['calibration_file'] == str(robot1), message
    assert values['sensor_id'] == values['hardware_id'] == 'robot1/imu_link'
    level, message, values = got['robot2/accel_correction: calibration']
    assert level == b'\x02', message                 # another sensor's: refused, ERROR
    assert "made for sensor 'robot1/imu_link'" in message and 'uncalibrated' in message
    assert values['calibration_file'] == str(robot2)
    for k, path in ((1, robot1), (2, robot2)):
        _, _, values = got[f'robot{k}/accel_calibration: collection']
        assert values['calibration_file'] == str(path)
        assert values['hardware_id'] == values['sensor_id'] == f'robot{k}/imu_link'
    assert 'Traceback' not in logs
    assert all(p.poll() is None for p in started), logs[-3000:]
    codes = [stop_node(p)[0] for p in started]
    assert codes == [0] * len(started), codes


@pytest.fixture
def home(tmp_path, monkeypatch):
    """Give the test a ROS_HOME of its own; return its accel_calib_ros folder."""
    monkeypatch.setenv('ROS_HOME', str(tmp_path / 'ros_home'))
    return tmp_path / 'ros_home' / 'accel_calib_ros'


@pytest.fixture
def context():
    """Yield an rclpy Context for nodes built in-process (destroyed with it)."""
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    made = []
    ctx.made = made
    yield ctx
    for node in made:
        node.destroy_node()
    rclpy.try_shutdown(context=ctx)


def build(context, cls, namespace='/', **params):
    """Build a node of ``cls`` under ``namespace`` in ``context``."""
    node = cls(context=context, namespace=namespace,
               parameter_overrides=[Parameter(k, value=v) for k, v in params.items()])
    context.made.append(node)
    return node


def test_the_calibration_records_its_sensor_and_lives_in_its_folder(home, context):
    node = build(context, CalibrationNode, '/robot1')
    assert node.sensor == 'robot1/imu_link'
    assert node.path == str(home / 'robot1' / 'imu_link' / 'calibration.yaml')
    _feed_good_session(node)
    response = node.calibrate_and_wait()
    assert response.success, response.message
    assert load_calibration(node.path).sensor_id == 'robot1/imu_link'
    from accel_calib_ros.dataio.history import History
    with History(home / 'robot1' / 'imu_link' / 'history.sqlite', readonly=True) as h:
        (session,) = h.sessions()
        assert session['sensor_id'] == 'robot1/imu_link'
    # Another frame on the same robot is another sensor, with files of its own.
    other = build(context, CalibrationNode, '/robot1', frame_id='tail_imu')
    assert other.path == str(home / 'robot1' / 'tail_imu' / 'calibration.yaml')
    # ~/reset forgets the coverage with the windows.
    assert node.progress()['coverage']['distinct_directions'] > 0
    node.on_reset(Trigger.Request(), Trigger.Response())
    assert node.progress()['coverage'] == {'min_eigenvalue_x3': 0.0, 'distinct_directions': 0}


def test_a_file_of_another_sensor_is_refused_unless_on_purpose(home, context, tmp_path):
    path = tmp_path / 'calibration.yaml'
    cal = Calibration(T=np.diag([1.01, 0.99, 1.02]), bias=[0.1, -0.2, 0.3])
    cal.sensor_id = 'robot1/imu_link'
    save_calibration(cal, path)
    node = build(context, CorrectionNode, '/robot2', calibration_file=str(path))
    assert node.corrector.cal is None
    status = node.diagnostics().status[0]
    assert status.level == b'\x02' and status.name == 'robot2/accel_correction: calibration'
    assert "made for sensor 'robot1/imu_link', this node corrects 'robot2/imu_link'" \
        in status.message
    (r,) = node.set_parameters([Parameter('accept_other_sensor', value=True)])
    assert r.successful and node.corrector.cal is not None          # applied on purpose
    (r,) = node.set_parameters([Parameter('accept_other_sensor', value=False)])
    assert r.successful and node.corrector.cal is None              # and taken back
    same = build(context, CorrectionNode, '/robot1', calibration_file=str(path))
    assert same.corrector.cal is not None and not same._file_problem


def test_a_missing_calibration_file_set_at_runtime_is_refused(home, context, tmp_path):
    path = tmp_path / 'calibration.yaml'
    save_calibration(Calibration(T=np.eye(3), bias=[0.0, 0.0, 0.1]), path)
    node = build(context, CorrectionNode, calibration_file=str(path))
    missing = tmp_path / 'typo.yaml'
    (r,) = node.set_parameters([Parameter('calibration_file', value=str(missing))])
    assert not r.successful and r.reason == (f'calibration_file {missing}: no such file '
                                             f'(the node keeps {path})')
    assert node.path == str(path) and node.corrector.cal is not None
    assert node.get_parameter('calibration_file').value == str(path)


def test_the_driver_refuses_a_frame_id_tf2_refuses(context):
    with pytest.raises(ParameterProblem, match="no leading '/'.*'imu_link'"):
        build(context, Mpu9250Driver, frame_id='/imu_link', port='/nonexistent/tty')


# -- a device clock that jumps --------------------------------------------------------------------
def test_a_re_plug_onto_a_board_600_s_ahead_restarts_the_stamps(procs, tmp_path):
    link = str(tmp_path / 'imu0')
    args = ['--link', link, '--poses', 'faces', '--count', '1', '--hold', '60', '--rate', 200]
    t0_us = 1_000_000_000
    first, _ = procs.device(args + ['--t0-us', t0_us])
    started = time.time()
    driver = procs.node('accel_calib_ros.nodes.driver',
                        {'port': link, 'reconnect_min_s': 0.1, 'reconnect_max_s': 0.4})
    received = []                                   # (receive time, stamp)
    with Collector({'imu/data_raw': Imu, '/diagnostics': DiagnosticArray}) as collector:
        collector.node.create_subscription(
            Imu, 'imu/data_raw', lambda m: received.append(
                (time.time(), m.header.stamp.sec + m.header.stamp.nanosec * 1e-9)), 100)
        assert collector.spin_until(lambda: len(received) >= 200, 20), read_log(driver)
        stop_node(first)
        replugged = time.time()
        ahead = int(t0_us + (replugged - started + 600.0) * 1e6) % 2 ** 32
        procs.device(args + ['--t0-us', ahead])
        assert collector.spin_until(
            lambda: sum(t > replugged + 0.5 for t, _ in received) >= 400, 20), \
            read_log(driver)
        stepped = [s for s in (statuses(collector).get('mpu9250_driver: serial'),)
                   if s is not None]
        warned = [(s.level, s.message) for a in collector.messages['/diagnostics']
                  for s in a.status if 'device clock stepped' in s.message]
    arrival, stamps = np.array(received).T
    assert np.all(np.diff(stamps) > 0)                          # never backwards
    assert np.max(stamps - arrival) < 0.5                       # never ahead of arrival
    after = arrival > replugged + 2.0
    assert np.max(np.abs(stamps[after] - arrival[after])) < 0.1     # on the new clock
    assert warned and warned[0][0] == b'\x01', warned
    step = float(warned[0][1].split('stepped ')[1].split(' s')[0])
    assert step == pytest.approx(600.0, abs=5.0)
    assert stepped and int(stepped[0][2]['clock_resets']) == 1
    code, log = stop_node(driver)
    assert code == 0 and 'Traceback' not in log, log


def test_the_calibration_node_restarts_on_a_step_back_and_calibrates(home, context):
    """A bag that loops: the stamps go back 600 s in the middle of the session."""
    from accel_calib_ros.sim.motion import random_directions, simulate_session
    from accel_calib_ros.sim.sensor import mpu9250_like, with_gyro_errors
    rng = np.random.default_rng(21)
    sensor = with_gyro_errors(mpu9250_like(rng, rate_hz=200.0), np.random.default_rng(22))
    s = simulate_session(sensor, random_directions(16, rng), rng, hold_s=1.6, move_s=0.6,
                         rate_hz=200.0, lead_s=1.6).samples
    node = build(context, CalibrationNode)
    half = len(s.t) // 2
    t = np.where(np.arange(len(s.t)) < half, 1000.0 + s.t, 400.0 + s.t)
    for k in range(len(s.t)):
        node.on_imu(_imu(t[k], s.accel[k], s.gyro[k]))
        if k % 400 == 0:
            node.process_pending()
    node.process_pending()
    assert node.intake.time.steps == 1
    assert len(node.windows) + len(node.detector.peek()) >= 15      # windows on both sides
    response = node.calibrate_and_wait()
    assert response.success, response.message
    assert 'finite and increasing' not in response.message
    gyro = node.progress()['last_calibration']['sensors']['gyroscope']
    assert gyro['status'] == 'calibrated', gyro


# -- the level frame's transform ----------------------------------------------------------------
class FakeTFMessage:
    """Stands in for tf2_msgs/TFMessage where tf2_msgs is not installed."""

    def __init__(self, transforms):
        self.transforms = transforms


class FakePublisher:
    """Records what would go on /tf_static."""

    def __init__(self):
        self.sent = []

    def publish(self, msg):
        self.sent.append(msg)


def rest(node, roll, pitch, n=300):
    """Feed ``n`` samples of the robot resting with the sensor tilted (roll, pitch)."""
    g = 9.80665 * np.array([-math.sin(pitch), math.sin(roll) * math.cos(pitch),
                            math.cos(roll) * math.cos(pitch)])
    rng = np.random.default_rng(5)
    for k in range(n):
        node.on_imu(_imu(100.0 + k / 100.0, g + rng.normal(0, 0.01, 3), [0.0, 0.0, 0.0]))
    node._rate_hz = 100.0


def test_the_level_frame_transform_is_published_or_its_command_given(context, tmp_path):
    path = tmp_path / 'calibration.yaml'
    save_calibration(Calibration(T=np.eye(3), bias=[0.0, 0.0, 0.0]), path)
    node = build(context, CorrectionNode, calibration_file=str(path))
    if node.level_frame.publishes:                  # a ROS install: tf2_msgs is there
        pytest.skip('tf2_msgs installed: see the published case below')
    rest(node, math.radians(2.0), math.radians(-1.5))
    response = node.on_level(Trigger.Request(), Trigger.Response())
    assert response.success, response.message
    command = response.message.split('run: ')[1]
    assert command.startswith('ros2 run tf2_ros static_transform_publisher --x 0 --y 0 '
                              '--z 0 --roll ')
    assert command.endswith('--frame-id imu_link --child-frame-id imu_link_level')
    values = command.split()
    rpy = [float(values[values.index(f'--{k}') + 1]) for k in ('roll', 'pitch', 'yaw')]
    L = load_calibration(path).level_rotation()
    pose = Rotation.from_euler('ZYX', rpy[::-1]).as_matrix()   # tf2's setRPY
    np.testing.assert_allclose(pose @ L, np.eye(3), atol=1e-8)   # the level frame in raw
    status = node.diagnostics().status[0]
    assert command in status.message and status.level == b'\x01'
    # The published path, with an injected message type and publisher.
    sink = FakePublisher()
    node.level_frame = LevelFrame(node, message_type=FakeTFMessage, publisher=sink)
    node._update_level_frame()
    (msg,) = sink.sent
    (t,) = msg.transforms
    assert (t.header.frame_id, t.child_frame_id) == ('imu_link', 'imu_link_level')
    q = t.transform.rotation
    np.testing.assert_allclose(Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix(),
                               level_pose(L), atol=1e-9)
    assert node.level_frame.words() == 'imu_link -> imu_link_level published on /tf_static'
    node._update_level_frame()                      # unchanged: not sent again
    assert len(sink.sent) == 1


def test_a_failed_level_save_changes_nothing(context, tmp_path, monkeypatch):
    path = tmp_path / 'calibration.yaml'
    save_calibration(Calibration(T=np.eye(3), bias=[0.0, 0.0, 0.0]), path)
    before = path.read_bytes()
    node = build(context, CorrectionNode, calibration_file=str(path))
    rest(node, math.radians(2.0), math.radians(-1.5))

    def full(*args, **kwargs):
        raise OSError(28, 'No space left on device')
    monkeypatch.setattr('accel_calib_ros.session.persist.save', full)
    response = node.on_level(Trigger.Request(), Trigger.Response())
    assert not response.success and 'not saved' in response.message
    assert 'No space left' in response.message
    assert path.read_bytes() == before
    assert node.corrector.cal.level_roll_pitch_rad is None and not node.corrector.trimmed
    assert node.level_frame.words() == ''
