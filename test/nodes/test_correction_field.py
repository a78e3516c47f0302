"""
The correction node in the field: its monitor, its frames, one node.

In-process on real rclpy over DDS (the node under test in the test's own context), plus
one subprocess started the way launch_ros starts it (remaps and a params file).
"""

import json
import math
import time

from accel_calib_ros.dataio.calibration_file import save_calibration
from accel_calib_ros.nodes.correction_monitor import ESTIMATE_PARAM, PARAMS
from diagnostic_msgs.msg import DiagnosticStatus
import numpy as np
import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from ros_helpers import start_node, stop_node
from sensor_msgs.msg import Imu, MagneticField
from std_msgs.msg import Bool, String
from std_srvs.srv import Trigger
from test_correction_node import make_calibration, Rig, rig_factory  # noqa: F401

pytestmark = pytest.mark.ros
G = 9.80665


def still_messages(rng, n, t0, rate=100.0, bias=(0.0, 0.0, 0.0), frame='imu_link',
                   gravity=(0.0, 0.0, G)):
    """Imu messages of a sensor at rest (noise 3 mg, 0.1 deg/s), stamped ``rate`` Hz apart."""
    out = []
    for i in range(n):
        m = Imu()
        t = t0 + i / rate
        m.header.stamp.sec, m.header.stamp.nanosec = int(t), int((t % 1.0) * 1e9)
        m.header.frame_id = frame
        m.orientation_covariance = [-1.0] + [0.0] * 8
        a = np.asarray(gravity) + rng.normal(0, 0.03, 3)
        w = np.asarray(bias) + rng.normal(0, math.radians(0.1), 3)
        m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z = map(float, a)
        m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z = map(float, w)
        out.append(m)
    return out


def latched_health(rig, level):
    """Subscribe late to the latched health topic; return its JSON once it says ``level``."""
    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
    got = []
    rig.peer.create_subscription(String, '/accel_correction/health', got.append, latched)
    rig.spin_until(lambda: got and json.loads(got[-1].data)['level'] == level)
    return json.loads(got[-1].data)


def stream(rig, messages, rate=100.0):
    """Publish at real time (a best-effort queue is never outrun); wait for the output."""
    start = len(rig.received)
    t0 = time.monotonic()
    for k, m in enumerate(messages):
        rig.imu_pub.publish(m)
        while time.monotonic() < t0 + (k + 1) / rate:
            rig.executor.spin_once(timeout_sec=0.002)
    rig.spin_until(lambda: len(rig.received) - start >= len(messages) * 0.95)
    return rig.received[start:]


def identity_calibration():
    cal = make_calibration(40)
    cal.T = np.eye(3)
    cal.bias = np.zeros(3)
    cal.gyro_bias = np.zeros(3)
    cal.noise_std = np.full(3, 0.03)
    return cal


def test_gyro_bias_at_rest_in_the_node(tmp_path, rig_factory):  # noqa: F811
    path = tmp_path / 'calibration.yaml'
    save_calibration(identity_calibration(), path)
    rig = rig_factory(path)
    bias = (0.004, -0.003, 0.002)                  # rad/s: a power-up change
    rng = np.random.default_rng(1)
    got = stream(rig, still_messages(rng, 450, 100.0, bias=bias))
    late = np.array([[m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z]
                     for m in got[-50:]]).mean(axis=0)
    assert np.abs(late).max() < math.radians(0.05), late          # the bias is gone
    estimate = rig.node.monitor.bias
    np.testing.assert_allclose(estimate, bias, atol=math.radians(0.03))
    statuses = {s.name: s for s in rig.last_diagnostics()}
    gyro = statuses['accel_correction: gyro bias at rest']
    assert gyro.level == DiagnosticStatus.OK and 'change from the file' in gyro.message
    rig.spin_until(lambda: rig.node.get_parameter(ESTIMATE_PARAM).value[0] != 0.0)
    np.testing.assert_allclose(rig.node.get_parameter(ESTIMATE_PARAM).value, estimate)
    # The reset service: back to the file's bias.
    client = rig.peer.create_client(Trigger, '/accel_correction/reset_gyro_bias')
    rig.spin_until(client.service_is_ready)
    future = client.call_async(Trigger.Request())
    rig.spin_until(future.done)
    assert future.result().success and 'reset' in future.result().message
    assert rig.node.monitor.bias == (0.0, 0.0, 0.0)


def test_health_is_latched_and_says_recalibrate(tmp_path, rig_factory):  # noqa: F811
    path = tmp_path / 'calibration.yaml'
    save_calibration(identity_calibration(), path)
    rig = rig_factory(path)
    rng = np.random.default_rng(2)
    stream(rig, still_messages(rng, 400, 100.0, gravity=(0.0, 0.0, G + 0.1)))   # 10 mg off
    stream(rig, [m for m in still_messages(rng, 30, 104.0)
                 if not m.linear_acceleration.__setattr__('x', 5.0)])          # then a move
    # A rest 10 s later confirms the first one was a rest (not a lift's plateau).
    stream(rig, still_messages(rng, 150, 112.0, gravity=(0.0, 0.0, G + 0.1)))
    rig.spin_until(lambda: rig.node.monitor.monitor.health.periods >= 1)
    body = latched_health(rig, 'recalibrate')
    assert body['recalibrate'] and body['message'].startswith('recalibrate')
    assert body['disagreement_mg'] == pytest.approx(10.2, abs=1.0)
    statuses = {s.name: s for s in rig.last_diagnostics()}
    health = statuses['accel_correction: calibration health']
    assert health.level == DiagnosticStatus.WARN and 'recalibrate' in health.message


def test_a_stationary_signal_saying_moving_stops_the_update(tmp_path, rig_factory):  # noqa
    path = tmp_path / 'calibration.yaml'
    save_calibration(identity_calibration(), path)
    rig = rig_factory(path)
    (ok,) = rig.node.set_parameters([Parameter('stationary_topic', value='robot_still')])
    assert ok.successful, ok.reason
    pub = rig.peer.create_publisher(Bool, 'robot_still', 10)
    rig.spin_until(lambda: pub.get_subscription_count() > 0)
    rng = np.random.default_rng(3)
    messages = still_messages(rng, 300, 100.0, bias=(0.004, 0.004, 0.004))
    start = len(rig.received)
    t0 = time.monotonic()
    for k, m in enumerate(messages):
        if k % 10 == 0:
            pub.publish(Bool(data=False))
        rig.imu_pub.publish(m)
        while time.monotonic() < t0 + (k + 1) / 100.0:
            rig.executor.spin_once(timeout_sec=0.002)
    rig.spin_until(lambda: len(rig.received) - start >= 280)
    assert rig.node.monitor.bias == (0.0, 0.0, 0.0)
    statuses = {s.name: s for s in rig.last_diagnostics()}
    values = {v.key: v.value for v in statuses['accel_correction: gyro bias at rest'].values}
    assert values['stationary_input'] == 'robot_still: moving'


@pytest.mark.parametrize('spec', PARAMS, ids=lambda p: p.name)
def test_careless_values_of_every_monitor_parameter_are_refused(
        tmp_path, rig_factory, spec):  # noqa: F811
    rig = rig_factory(tmp_path / 'missing.yaml')
    bad = {'bool': [1, 'yes', 0.5], 'double': [float('nan'), float('inf'), -1e9, 'fast', True],
           'string': [3, True]}[spec.kind]
    if spec.kind == 'string' and spec.choices:
        bad = bad + ['std_msgs/String']
    for value in bad:
        (r,) = rig.node.set_parameters([Parameter(spec.name, value=value)])
        assert not r.successful and r.reason, (spec.name, value)
        assert rig.node.params[spec.name] == spec.default


def test_the_estimate_parameter_is_read_only(tmp_path, rig_factory):  # noqa: F811
    rig = rig_factory(tmp_path / 'missing.yaml')
    (r,) = rig.node.set_parameters([Parameter(ESTIMATE_PARAM, value=[1.0, 2.0, 3.0])])
    assert not r.successful and 'read-only' in r.reason


# -- frames that tell the truth ----------------------------------------------------------------
def test_a_level_trim_gives_the_levelled_frame(tmp_path, rig_factory):  # noqa: F811
    path = tmp_path / 'calibration.yaml'
    cal = identity_calibration()
    cal.level_roll_pitch_rad = (0.02, -0.01)
    save_calibration(cal, path)
    rig = rig_factory(path)
    mags = []
    rig.peer.create_subscription(MagneticField, 'imu/mag_corrected', mags.append, 10)
    rng = np.random.default_rng(4)
    got = stream(rig, still_messages(rng, 20, 100.0, frame='imu_link'))
    assert {m.header.frame_id for m in got} == {'imu_link_level'}
    (ok,) = rig.node.set_parameters([Parameter('level_frame_id', value='base_imu_level')])
    assert ok.successful, ok.reason
    got = stream(rig, still_messages(rng, 20, 101.0, frame='imu_link'))
    assert {m.header.frame_id for m in got} == {'base_imu_level'}


def test_without_a_trim_the_raw_frame_passes(tmp_path, rig_factory):  # noqa: F811
    path = tmp_path / 'calibration.yaml'
    save_calibration(identity_calibration(), path)
    rig = rig_factory(path)
    got = stream(rig, still_messages(np.random.default_rng(5), 20, 100.0, frame='imu_link'))
    assert {m.header.frame_id for m in got} == {'imu_link'}


# -- one node per process -----------------------------------------------------------------------
def test_remapped_node_name_names_exactly_one_node(tmp_path):
    path = tmp_path / 'calibration.yaml'
    save_calibration(identity_calibration(), path)
    params = tmp_path / 'params.yaml'
    params.write_text(f'/**:\n  ros__parameters:\n    calibration_file: {path}\n')
    proc = start_node('accel_calib_ros.nodes.correction', None, '-r', '__ns:=/robot1',
                      '-r', '__node:=accel_correction', '--params-file', str(params))
    context = rclpy.Context()
    rclpy.init(context=context)
    probe = rclpy.create_node('graph_probe', context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(probe)
    try:
        deadline = time.monotonic() + 20.0
        names = []
        while time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.1)
            names = [n for n in probe.get_node_names_and_namespaces()
                     if n[0] != 'graph_probe']
            if ('accel_correction', '/robot1') in names:
                time.sleep(1.0)               # a second node would have shown up by now
                executor.spin_once(timeout_sec=0.1)
                names = [n for n in probe.get_node_names_and_namespaces()
                         if n[0] != 'graph_probe']
                break
        assert names.count(('accel_correction', '/robot1')) == 1, names
        assert len(names) == 1, names
    finally:
        executor.shutdown()
        probe.destroy_node()
        rclpy.try_shutdown(context=context)
        code, log = stop_node(proc)
    assert 'already registered' not in log, log
    assert code in (0, -2), log


def test_config_file_holds_every_parameter_with_its_default():
    import os
    import yaml
    from accel_calib_ros.nodes.correction import PARAMS as NODE_PARAMS
    path = os.path.join(os.path.dirname(__file__), '..', '..', 'config', 'correction.yaml')
    with open(path, encoding='utf-8') as f:
        values = yaml.safe_load(f)['/**']['ros__parameters']
    for spec in NODE_PARAMS:
        assert spec.name in values, spec.name
        assert spec.check(values[spec.name]) == spec.default, spec.name


def test_a_frame_id_tf2_would_refuse_is_refused(tmp_path, rig_factory):  # noqa: F811
    rig = rig_factory(tmp_path / 'missing.yaml')
    for value in ('/imu_level', 'imu level', 'imu\nlevel', 5):
        (r,) = rig.node.set_parameters([Parameter('level_frame_id', value=value)])
        assert not r.successful and ('level_frame_id' in r.reason or 'type' in r.reason), value
    assert rig.node.params['level_frame_id'] == ''


# -- never silently off, a frozen sensor, a clock that steps --------------------------------
def _statuses(rig):
    return {s.name: s for s in rig.last_diagnostics()}


def test_a_frozen_sensor_is_an_error_in_diagnostics_and_on_health(tmp_path, rig_factory):  # noqa
    path = tmp_path / 'calibration.yaml'
    save_calibration(identity_calibration(), path)
    rig = rig_factory(path)
    rng = np.random.default_rng(7)
    messages = still_messages(rng, 250, 100.0)
    frozen = messages[100]
    for m in messages[100:]:                         # the driver repeats one reading
        m.linear_acceleration = frozen.linear_acceleration
        m.angular_velocity = frozen.angular_velocity
    stream(rig, messages)
    rig.spin_until(lambda: rig.node.monitor.monitor.fault is not None)
    statuses = _statuses(rig)
    for part in ('gyro bias at rest', 'calibration health'):
        status = statuses[f'accel_correction: {part}']
        assert status.level == DiagnosticStatus.ERROR and 'frozen' in status.message
    body = latched_health(rig, 'error')
    assert body['healthy'] is False and body['sensor_fault']['kind'] == 'frozen'


def test_no_still_period_for_the_stated_time_is_a_warning(tmp_path, rig_factory):  # noqa: F811
    path = tmp_path / 'calibration.yaml'
    save_calibration(identity_calibration(), path)
    rig = rig_factory(path)
    (ok,) = rig.node.set_parameters([Parameter('still_timeout_s', value=1.0)])
    assert ok.successful, ok.reason
    rng = np.random.default_rng(8)
    moving = still_messages(rng, 250, 100.0)
    for m in moving:                                 # shaken: never still
        m.linear_acceleration.x = float(rng.normal(0.0, 2.0))
    stream(rig, moving)
    statuses = _statuses(rig)
    for part in ('gyro bias at rest', 'calibration health'):
        status = statuses[f'accel_correction: {part}']
        assert status.level == DiagnosticStatus.WARN, status.message
        assert 'no still period for' in status.message and 'accelerating' in status.message


def test_a_clock_that_steps_back_restarts_the_monitor(tmp_path, rig_factory):  # noqa: F811
    path = tmp_path / 'calibration.yaml'
    save_calibration(identity_calibration(), path)
    rig = rig_factory(path)
    rng = np.random.default_rng(9)
    bias = (0.004, -0.003, 0.002)
    stream(rig, still_messages(rng, 200, 100.0, bias=bias))
    stream(rig, still_messages(rng, 300, 40.0, bias=bias))      # a re-plug: 60 s back
    mon = rig.node.monitor.monitor
    assert mon.cutter.steps >= 1 and mon.cutter.backwards >= 1
    assert mon.gyro.updates >= 1                                # still working after it
    values = {v.key: v.value for v in
              _statuses(rig)['accel_correction: gyro bias at rest'].values}
    assert int(values['clock_steps']) >= 1


def test_only_the_monitor_parameters_reach_the_monitor(tmp_path, rig_factory,  # noqa: F811
                                                       monkeypatch):
    rig = rig_factory(tmp_path / 'missing.yaml')
    calls = []
    monkeypatch.setattr(rig.node.monitor, 'apply', calls.append)
    (ok,) = rig.node.set_parameters([Parameter('level_duration_s', value=3.0)])
    assert ok.successful and calls == []
    (ok,) = rig.node.set_parameters([Parameter('health_false_alarm', value=1e-5)])
    assert ok.successful and calls == [{'health_false_alarm': 1e-5}]


def test_a_stream_that_stops_is_a_warning_too(tmp_path, rig_factory):  # noqa: F811
    path = tmp_path / 'calibration.yaml'
    save_calibration(identity_calibration(), path)
    rig = rig_factory(path)
    (ok,) = rig.node.set_parameters([Parameter('still_timeout_s', value=1.0)])
    assert ok.successful, ok.reason
    rig.spin(1.2)
    status = _statuses(rig)['accel_correction: calibration health']
    assert status.level == DiagnosticStatus.WARN and 'no imu/data_raw for' in status.message


def test_unstamped_messages_are_said_not_left_silently_unchecked(tmp_path, rig_factory):  # noqa
    """Regression: zero stamps gave the monitor a clock that never moved: no block, no word."""
    path = tmp_path / 'calibration.yaml'
    save_calibration(identity_calibration(), path)
    rig = rig_factory(path)
    rng = np.random.default_rng(10)
    messages = still_messages(rng, 250, 100.0)
    for m in messages:
        m.header.stamp.sec = m.header.stamp.nanosec = 0
    stream(rig, messages)
    statuses = _statuses(rig)
    for part in ('gyro bias at rest', 'calibration health'):
        status = statuses[f'accel_correction: {part}']
        assert status.level == DiagnosticStatus.WARN, status.message
        assert 'stamps have not advanced' in status.message
    stream(rig, still_messages(rng, 150, 100.0))                # stamped again: checked
    assert rig.node.monitor.monitor.blocks > 0
    assert 'stamps have not advanced' not in \
        _statuses(rig)['accel_correction: gyro bias at rest'].message
