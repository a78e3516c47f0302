"""
Fit and accept (``session.accept``): the one decision of the node, ``fit`` and ``guide``.

Plain unit tests of what needed a calibration node (and rclpy) before: the residual
against the windows' noise, the physics, the temperature tables, the refusal naming the
pose that is missing, and the gyroscope and magnetometer fitted only beside an accepted
accelerometer.
"""

from accel_calib_ros.core.collector import ImuCollector
from accel_calib_ros.session.accept import (CollectedImu, FIT, fit_and_accept, NODE, Settings,
                                            thermal_wanted)
from accel_calib_ros.session.gap import model_gap
from accel_calib_ros.session.windows import Observations, Window, WindowSet
from accel_calib_ros.sim.motion import random_directions, simulate_window_means
from accel_calib_ros.sim.sensor import mpu9250_like
import numpy as np
import pytest


def windows_of(means, temps=None, count=300, scatter=0.03, gyro=None):
    """Return a WindowSet of window means held one after the other (1.4 s each)."""
    n = len(means)
    temps = np.full(n, 25.0) if temps is None else temps
    return WindowSet.from_windows([
        Window(mean=np.asarray(m, float), scatter=np.full(3, scatter), count=count,
               t_start=k - 0.7, t_stop=k + 0.7, temp=float(t),
               gyro_mean=None if gyro is None else gyro[k])
        for k, (m, t) in enumerate(zip(means, temps))])


def session(n=20, seed=5, effects=(), temps=None, **kw):
    rng = np.random.default_rng(seed)
    sensor = mpu9250_like(rng, rate_hz=200.0, effects=effects)
    u = random_directions(n, np.random.default_rng(seed + 1))
    means = simulate_window_means(sensor, u, 300, rng, temp=temps, **kw)
    return sensor, means


def test_a_good_session_is_accepted_and_the_message_says_what_was_fitted():
    _, means = session(20)
    windows = windows_of(means, scatter=0.02)
    outcome = fit_and_accept(windows.observations(5.0, 200.0), Settings(words=NODE))
    assert outcome.accepted and outcome.refusal is None, outcome.refusal
    assert 0 < outcome.predicted_accuracy <= 0.02 and outcome.observations == 20
    message = outcome.message()
    assert message.startswith('ml calibration from 20 windows') and 'thermal bands 0' in message
    assert outcome.sensors()['accelerometer'] == {'status': 'calibrated', 'reason': None}


def test_moving_poses_are_refused_by_the_residual_with_the_doors_words():
    rng = np.random.default_rng(9)
    _, means = session(20)
    moved = windows_of(means + rng.normal(0, 0.2, means.shape))
    outcome = fit_and_accept(moved.observations(5.0, 200.0), Settings(words=NODE))
    assert not outcome.accepted and 'residual' in outcome.refusal
    assert 'model-gap check follows on ~/status' in outcome.refusal
    assert outcome.calibration is not None                 # the fit is there, refused
    assert outcome.message().startswith('refused: gravity-norm residual')
    # No check without the noise of the windows (samples, not windows).
    refusal = fit_and_accept(Observations(moved.mean), Settings(max_predicted_error=10.0)).refusal
    assert refusal is None or 'residual' not in refusal


def test_readings_in_g_are_not_physical():
    u = random_directions(20, np.random.default_rng(6))
    windows = windows_of(0.6 * 9.80665 * u + 5.0, scatter=0.01)
    outcome = fit_and_accept(windows.observations(5.0, 200.0), Settings(words=NODE))
    assert not outcome.accepted and 'not physical' in outcome.refusal
    warned = fit_and_accept(windows.observations(5.0, 200.0),
                            Settings(refuse_unphysical=False, max_predicted_error=10.0,
                                     max_residual_ratio=None, words=FIT))
    assert warned.accepted and any('m/s²' in w for w in warned.warnings)


def test_temperature_tables_when_two_bands_are_filled_and_the_hint_without():
    temps = np.r_[np.full(20, 22.0), np.full(20, 37.0)]
    sensor, means = session(40, seed=7, effects=('temperature_bias',), temps=temps)
    windows = windows_of(means, temps)
    assert thermal_wanted('auto', temps, 10.0) and not thermal_wanted('auto', temps[:25], 10.0)
    outcome = fit_and_accept(windows.observations(5.0, 200.0),
                             Settings(thermal='auto', words=NODE))
    assert outcome.accepted and outcome.thermal, outcome.refusal
    assert 'thermal bands 2' in outcome.message()
    fresh = 9.80665 * random_directions(200, np.random.default_rng(9))
    for temp in (22.0, 37.0):
        t = np.full(200, temp)
        err = outcome.calibration.correct(sensor.distort(fresh, t), t) - fresh
        assert np.abs(err).max() < 0.05
    off = fit_and_accept(windows.observations(5.0, 200.0), Settings(thermal='off', words=NODE))
    assert not off.accepted and 'thermal:=auto' in off.refusal
    with pytest.raises(Exception, match='no temperature was received'):
        fit_and_accept(windows_of(means, np.full(40, np.nan)).observations(),
                       Settings(thermal='on', words=NODE))


def test_a_tilt_only_session_is_refused_naming_the_pose_it_lacks():
    tilt = np.radians(np.r_[0.0, np.full(6, 12.0), np.full(8, 24.0)])
    azimuth = np.r_[0.0, np.arange(6) * np.pi / 3, np.arange(8) * np.pi / 4]
    dirs = np.c_[np.sin(tilt) * np.cos(azimuth), np.sin(tilt) * np.sin(azimuth), np.cos(tilt)]
    rng = np.random.default_rng(5)
    means = simulate_window_means(mpu9250_like(rng, rate_hz=200.0), dirs, 300, rng)
    outcome = fit_and_accept(windows_of(means, scatter=0.02).observations(5.0, 200.0),
                             Settings(words=NODE))
    assert not outcome.accepted
    assert 'predicted accuracy' in outcome.refusal and 'z axis down' in outcome.refusal
    assert 'max_predicted_error' in outcome.refusal and outcome.predicted_accuracy > 0.02


def test_too_few_windows_and_none_are_refusals_not_errors():
    _, means = session(3)
    outcome = fit_and_accept(windows_of(means).observations(), Settings(words=NODE))
    assert not outcome.accepted and outcome.calibration is None
    assert 'orientations' in outcome.refusal or 'observations' in outcome.refusal
    empty = fit_and_accept(WindowSet.from_windows([]).observations(), Settings(words=NODE))
    assert empty.refusal.startswith('no static windows collected yet')


def test_the_other_sensors_are_fitted_only_beside_an_accepted_accelerometer():
    collector = ImuCollector(1000, 100)
    collector.add_samples(np.column_stack([np.arange(10.0), np.tile([0, 0, 9.8], (10, 1)),
                                           np.zeros((10, 3)), np.full(10, 25.0)]))
    _, means = session(3)
    refused = fit_and_accept(windows_of(means).observations(), Settings(words=NODE),
                             CollectedImu(collector, windows_of(means)))
    assert refused.gyro.status == 'not fitted' and refused.magnetometer.status == 'absent'
    assert refused.json_keys()['gyro_T'] is None


def test_window_sets_weigh_pool_and_turn_into_static_windows():
    w = windows_of(np.tile([0.0, 0.0, 9.8], (3, 1)), count=2000, scatter=0.02,
                   gyro=[np.zeros(3), None, np.ones(3)])
    np.testing.assert_allclose(w.weights(5.0, 100.0), 500.0)
    np.testing.assert_allclose(w.weights(5.0, None), 500.0)        # 100 Hz assumed
    np.testing.assert_allclose(w.noise(), 0.02)
    assert np.isnan(w.gyro_mean[1]).all() and w.windows()[1].gyro_mean is None
    static = w.to_static_windows()
    np.testing.assert_allclose(static.t_mid, [0.0, 1.0, 2.0])
    assert WindowSet.from_windows([]).noise() is None


def test_the_model_gap_check_names_what_the_model_misses():
    rng = np.random.default_rng(11)
    sensor = mpu9250_like(rng, rate_hz=200.0)
    sensor.T = np.diag(np.diag(sensor.T))
    sensor.T[0, 1], sensor.T[1, 2] = 0.02, -0.015          # 1.1° and 0.9° off square
    u = random_directions(30, np.random.default_rng(12))
    means = simulate_window_means(sensor, u, 300, rng)
    gap = model_gap(windows_of(means, scatter=sensor.noise_std[0]), 'gn', 9.80665, 200.0)
    assert 'nonorthogonality' in gap['missing_effects'] and 'gn model' in gap['note']
    assert model_gap(WindowSet.from_windows([]), 'ml', 9.80665) is None


def test_every_door_refuses_the_residual_in_its_own_words():
    rng = np.random.default_rng(9)
    _, means = session(20)
    moved = windows_of(means + rng.normal(0, 0.2, means.shape)).observations(5.0, 200.0)
    node, cli = (fit_and_accept(moved, Settings(words=w)).refusal for w in (NODE, FIT))
    assert 'max_residual_ratio' in node and 'model-gap check follows on ~/status' in node
    assert '--max-residual-ratio' in cli and 'accel-calib diagnose DATA' in cli
    assert fit_and_accept(moved, Settings(max_residual_ratio=None, max_predicted_error=1.0,
                                          words=FIT)).refusal is None


def test_the_session_records_are_plain_and_fresh():
    from accel_calib_ros.session.accept import Outcome
    a, b = Outcome(), Outcome(refusal='x')
    assert a.warnings == [] and a.warnings is not b.warnings        # a fresh list each
    assert b.replace(refusal=None).refusal is None and b.refusal == 'x'
    w = Window(np.zeros(3), np.ones(3), 5, 1.0, 2.0)
    assert w.count == 5 and w.t_mid == 1.5 and np.isnan(w.temp) and 'count=5' in repr(w)
    with pytest.raises(TypeError):
        Settings(metod='ml')
    with pytest.raises(TypeError):
        Observations(np.zeros((1, 3)), readings=np.zeros((1, 3)))
    with pytest.raises(AttributeError):
        a.refusl = 'typo'                                # __slots__: a typo is an error
