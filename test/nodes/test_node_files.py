"""The nodes' file parameters and ranges: logged and refused, never fatal."""

import os
import stat

from accel_calib_ros.dataio.history import History
from accel_calib_ros.nodes.calibration import CalibrationNode
from accel_calib_ros.nodes.parameters import ParameterProblem
from accel_calib_ros.sim.motion import random_directions, simulate_session
from accel_calib_ros.sim.sensor import mpu9250_like
import numpy as np
import pytest
from rclpy.parameter import Parameter
from ros_helpers import nodes_in_a_context
from sensor_msgs.msg import Imu
from std_srvs.srv import Trigger

pytestmark = pytest.mark.ros


@pytest.fixture
def make(tmp_path):
    """Build nodes of a class in their own context (never spun)."""
    with nodes_in_a_context() as build:
        yield build


def _imu(t, a, w):
    m = Imu()
    m.header.stamp.sec, m.header.stamp.nanosec = int(t), int(round((t % 1) * 1e9)) % 10 ** 9
    m.header.frame_id = 'imu_link'
    m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z = map(float, a)
    m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z = map(float, w)
    return m


def _feed_good_session(node):
    rng = np.random.default_rng(4)
    s = simulate_session(mpu9250_like(rng, rate_hz=200.0), random_directions(16, rng), rng,
                         hold_s=1.6, move_s=0.6, rate_hz=200.0, lead_s=1.6)
    for t, a, w in zip(1000.0 + s.samples.t, s.samples.accel, s.samples.gyro):
        node.on_imu(_imu(t, a, w))
    node.process_pending()


def test_a_calibration_file_that_is_a_fifo_is_refused_not_fatal(make, tmp_path):
    fifo = tmp_path / 'calibration.yaml'
    os.mkfifo(fifo)
    node = make(CalibrationNode, calibration_file=str(fifo))      # starts: logged, not fatal
    _feed_good_session(node)
    response = node.calibrate_and_wait()
    assert not response.success and 'FIFO' in response.message, response.message
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)
    assert not (tmp_path / 'history.sqlite').exists()              # refused: no session
    good = str(tmp_path / 'ok' / 'calibration.yaml')
    (r,) = node.set_parameters([Parameter('calibration_file', value=good)])
    assert r.successful, r.reason
    response = node.calibrate_and_wait()
    assert response.success, response.message
    with History(tmp_path / 'ok' / 'history.sqlite', readonly=True) as h:
        (session,) = h.sessions()
        assert session['sensor_id'] == 'imu_link' and session['calibrations'] == 1
        assert session['windows'] == 16


def test_file_parameters_refuse_devices_links_and_unknown_users(make, tmp_path):
    node = make(CalibrationNode, calibration_file=str(tmp_path / 'c.yaml'))
    os.mkfifo(tmp_path / 'fifo')
    (tmp_path / 'dir').mkdir()
    for name in ('calibration_file', 'history_file'):
        for value in (str(tmp_path / 'fifo'), str(tmp_path / 'dir'), '~nouser_16/c.yaml'):
            (r,) = node.set_parameters([Parameter(name, value=value)])
            assert not r.successful and r.reason, (name, value)
    assert node.path == str(tmp_path / 'c.yaml')
    assert not os.path.exists('~nouser_16')
    with pytest.raises(ParameterProblem, match='no user'):
        make(CalibrationNode, calibration_file='~nouser_16/c.yaml')
    with pytest.raises(ParameterProblem, match='no user'):
        make(CalibrationNode, history_file='~nouser_16/h.sqlite')


def test_a_damaged_history_is_logged_and_the_calibration_still_saved(make, tmp_path):
    db = tmp_path / 'history.sqlite'
    db.write_bytes(b'SQLite format 3\x00' + bytes(4096))
    before = db.read_bytes()
    node = make(CalibrationNode, calibration_file=str(tmp_path / 'calibration.yaml'))
    _feed_good_session(node)
    response = node.calibrate_and_wait()
    assert response.success, response.message
    assert (tmp_path / 'calibration.yaml').is_file() and db.read_bytes() == before


def test_sensor_id_is_normalised_and_checked(make, tmp_path):
    node = make(CalibrationNode, calibration_file=str(tmp_path / 'c.yaml'),
                sensor_id=' padded ')
    assert node.params['sensor_id'] == 'padded'
    for bad in ('a\u202eb', 'x\x1by', '\t'):
        (r,) = node.set_parameters([Parameter('sensor_id', value=bad)])
        assert not r.successful and 'sensor' in r.reason
    assert node.params['sensor_id'] == 'padded'
    with pytest.raises(ParameterProblem, match='sensor_id'):
        make(CalibrationNode, calibration_file=str(tmp_path / 'c.yaml'), sensor_id='a\x00b')


def test_periods_and_rates_have_sane_low_bounds(make, tmp_path):
    """``reload_period_s=1e-9`` pinned a core: every period and rate has a floor."""
    from accel_calib_ros.nodes import calibration, correction, driver
    specs = {p.name: p for module in (calibration, correction, driver) for p in module.PARAMS}
    for name, tiny in (('reload_period_s', 1e-9), ('reconnect_min_s', 1e-9),
                       ('reconnect_max_s', 1e-9), ('band_width_c', 1e-9),
                       ('max_weight_s', 1e-9), ('diagnostics_period_s', 1e-9),
                       ('level_duration_s', 1e-9)):
        with pytest.raises(ParameterProblem):
            specs[name].check(tiny)
    periods = [n for n in specs if n.endswith(('_s', '_hz')) or 'period' in n or 'rate' in n]
    for name in periods:
        spec = specs[name]
        assert spec.low is not None, name
        zero_means_default = spec.low == 0 and not spec.low_open
        if not zero_means_default:
            assert spec.low >= 1e-3, name
    node = make(CalibrationNode, calibration_file=str(tmp_path / 'c.yaml'))
    (r,) = node.set_parameters([Parameter('rate_hz', value=1e-9)])
    assert not r.successful
    (r,) = node.set_parameters([Parameter('rate_hz', value=200.0)])
    assert r.successful, r.reason
    with pytest.raises(ParameterProblem, match='rate_hz'):
        make(CalibrationNode, calibration_file=str(tmp_path / 'c.yaml'), rate_hz=0.01)
    from accel_calib_ros.nodes.correction import CorrectionNode
    corr = make(CorrectionNode, calibration_file=str(tmp_path / 'c.yaml'))
    (r,) = corr.set_parameters([Parameter('reload_period_s', value=1e-9)])
    assert not r.successful
    with pytest.raises(ParameterProblem):
        make(CorrectionNode, reload_period_s=1e-9)


def test_correction_level_into_a_fifo_is_refused(make, tmp_path):
    from accel_calib_ros.core.calibration import Calibration
    from accel_calib_ros.dataio.calibration_file import save_calibration
    from accel_calib_ros.nodes.correction import CorrectionNode
    good = tmp_path / 'cal.yaml'
    save_calibration(Calibration(T=np.eye(3), bias=np.zeros(3)), good)
    node = make(CorrectionNode, calibration_file=str(good))
    for k in range(400):
        node.on_imu(_imu(1000.0 + k * 0.005, [0.0, 0.0, 9.80665], [0.0, 0.0, 0.0]))
    os.remove(good)
    os.mkfifo(good)
    response = node.on_level(Trigger.Request(), Trigger.Response())
    assert not response.success and 'FIFO' in response.message, response.message
    assert stat.S_ISFIFO(os.lstat(good).st_mode)


def test_a_stationary_topic_rclpy_cannot_take_is_refused_with_the_reason(make, tmp_path):
    """It was accepted, then failed to apply (logged, rolled back) or was cut at a NUL."""
    from accel_calib_ros.nodes.correction import CorrectionNode
    node = make(CorrectionNode, calibration_file=str(tmp_path / 'c.yaml'))
    for bad in ('bad topic name', 'a\x00b', '1st'):
        (r,) = node.set_parameters([Parameter('stationary_topic', value=bad)])
        assert not r.successful and 'topic name' in r.reason, bad
    assert node.params['stationary_topic'] == ''
    (r,) = node.set_parameters([Parameter('stationary_topic', value='/robot1/stationary')])
    assert r.successful, r.reason
    with pytest.raises(ParameterProblem, match='stationary_topic'):
        make(CorrectionNode, calibration_file=str(tmp_path / 'c.yaml'), stationary_topic='a b')
