"""
The field monitor's science (core.monitor) on the field simulator (sim.field_stream), ROS-free.

Short simulated days, a few seeds: the monitor's claims as properties; the rates over
many seeds are in bench/bench_monitor.py.
"""

import json
import math

from accel_calib_ros.core.monitor import (Block, corrected_arrays, FieldMonitor,
                                          MonitorSettings, Run)
from accel_calib_ros.core.monitor.stats import chi2_quantile, chi2_survival
from accel_calib_ros.sim import field_stream as F
import numpy as np
import pytest
from scipy import stats

DEG = math.pi / 180.0
MG = 9.80665e-3


def run_day(rig, segments, events, rng, settings=None, stationary=None, chunk_s=0.1,
            monitor=None):
    """Feed a simulated day through a monitor; return it and the estimate per chunk."""
    mon = monitor or FieldMonitor(rig.calibration, settings)
    trace = []
    for chunk in F.stream(rig, segments, events, rng, chunk_s=chunk_s):
        a, g, m = corrected_arrays(rig.calibration, chunk['accel'], chunk['gyro'],
                                   chunk['temp'], chunk['mag'])
        if stationary is not None:
            mon.set_stationary(chunk['t'][0], stationary(chunk['kind']))
        mon.feed(chunk['t'], a, g, chunk['temp'], m)
        trace.append((chunk['kind'], chunk['t'][-1], mon.gyro_bias.copy()))
    return mon, trace


def bias_left(rig, events):
    """Return the corrected rate at rest without noise: what the file leaves of the bias."""
    raw = rig.sensor.gyro_bias + events.gyro_change
    return corrected_arrays(rig.calibration, np.zeros((1, 3)), raw[None, :],
                            np.array([25.0]))[1][0]


# -- statistics ------------------------------------------------------------------------------
@pytest.mark.parametrize('k', [1, 2, 3, 5, 12])
@pytest.mark.parametrize('alpha', [1e-2, 1e-4, 1e-6])
def test_chi2_without_scipy_matches_scipy(k, alpha):
    assert chi2_quantile(alpha, k) == pytest.approx(stats.chi2.isf(alpha, k), rel=1e-8)
    for x in (0.5, 3.0, 20.0, 60.0):
        assert chi2_survival(x, k) == pytest.approx(stats.chi2.sf(x, k), rel=1e-9)


# -- blocks ----------------------------------------------------------------------------------
def test_run_sees_a_tilt_and_a_turn_and_nothing_at_rest():
    rng = np.random.default_rng(0)
    g = 9.80665
    for tilt, heading in ((0.0, 0.0), (0.01, 0.0), (0.0, 0.02)):
        run = None
        for k in range(50):
            t = 0.1 * k + 0.05
            angle = tilt * t
            a = g * np.array([math.sin(angle), 0.0, math.cos(angle)])
            h = heading * t          # the body turns left: the field turns right
            m = np.array([20 * math.cos(-h), 20 * math.sin(-h), -40.0])
            b = Block(100, t, 0.1, a + rng.standard_normal(3) * 1e-4, np.full(3, 1e-6),
                      np.zeros(3), np.full(3, 1e-6), 25.0, 10, m + rng.standard_normal(3) * 0.01,
                      np.full(3, 0.01))
            run = Run(b) if run is None else run.add(b) or run
        rate, sd = run.tilt_rate()
        assert rate == pytest.approx(tilt, abs=5 * sd + 1e-6)
        turn, sd = run.heading_rate()
        assert turn == pytest.approx(heading, abs=5 * sd + 1e-6)


def test_feed_in_pieces_equals_feed_at_once():
    rng = np.random.default_rng(1)
    rig = F.field_rig(rng)
    pose = F.random_pose(rng, 20)
    chunks = list(F.stream(rig, [F.still(pose, 8.0)], F.Events(), rng, chunk_s=8.0))
    c = chunks[0]
    a, g, m = corrected_arrays(rig.calibration, c['accel'], c['gyro'], c['temp'], c['mag'])
    whole, parts = FieldMonitor(rig.calibration), FieldMonitor(rig.calibration)
    whole.feed(c['t'], a, g, c['temp'], m)
    for lo in range(0, len(a), 37):
        sl = slice(lo, lo + 37)
        parts.feed(c['t'][sl], a[sl], g[sl], c['temp'][sl], m[sl])
    whole.finish()
    parts.finish()
    assert whole.blocks == parts.blocks
    np.testing.assert_allclose(whole.gyro_bias, parts.gyro_bias, atol=1e-12)
    assert whole.last_health.chi2 == pytest.approx(parts.last_health.chi2, rel=1e-9)


def test_non_finite_rows_are_skipped_and_nothing_non_finite_comes_out():
    rng = np.random.default_rng(2)
    rig = F.field_rig(rng)
    c = next(F.stream(rig, [F.still(F.random_pose(rng, 10), 6.0)], F.Events(), rng, 6.0))
    a, g, m = corrected_arrays(rig.calibration, c['accel'], c['gyro'], c['temp'], c['mag'])
    a[::7, 0] = np.nan
    g[::11, 2] = np.inf
    c['temp'][::5] = np.nan
    mon = FieldMonitor(rig.calibration)
    mon.feed(c['t'], a, g, c['temp'], m)
    mon.finish()
    assert np.all(np.isfinite(mon.gyro_bias))
    json.dumps(mon.last_health.to_dict(), allow_nan=False)
    json.dumps(mon.gyro_summary(), allow_nan=False)


# -- the gyro bias ---------------------------------------------------------------------------
@pytest.mark.parametrize('seed', [3, 4])
def test_power_up_change_is_gone_after_5_s_still_and_holds_while_moving(seed):
    rng = np.random.default_rng(seed)
    rig = F.field_rig(rng)
    ev = F.Events(gyro_change=0.5 * DEG * rng.choice([-1.0, 1.0], 3))
    p, q = F.random_pose(rng, 30), F.random_pose(rng, 30)
    segs = [F.move(q, p, 2.0), F.still(p, 5.0), F.move(p, q, 6.0), F.still(q, 3.0)]
    mon, trace = run_day(rig, segs, ev, rng)
    truth = bias_left(rig, ev)
    at_5s = [b for kind, t, b in trace if kind == 'still' and t <= 7.0][-1]
    assert np.abs(at_5s - truth).max() <= 0.02 * DEG
    moving = [b for kind, t, b in trace if kind == 'move' and t > 7.0]
    assert np.abs(np.array(moving) - moving[0]).max() <= 0.005 * DEG


def _turn_day(seed, magnetometer, stationary=None, settings=None):
    rng = np.random.default_rng(seed)
    rig = F.field_rig(rng, magnetometer=magnetometer)
    pose = F.random_pose(rng, 10)
    segs = [F.move(pose, pose, 2.0), F.still(pose, 10.0), F.turn(pose, 0.05, 60.0)]
    mon, trace = run_day(rig, segs, F.Events(), rng, settings, stationary)
    before = [b for kind, t, b in trace if kind == 'still'][-1]
    up = mon.health.clusters[-1]['u'] if mon.health.clusters else np.array([0, 0, 1.0])
    moved = max(abs(float(up @ (b - before))) for kind, t, b in trace if kind == 'turn')
    return mon, moved


def test_a_turn_about_gravity_is_not_absorbed_with_a_magnetometer():
    mon, moved = _turn_day(5, True)
    assert moved <= 0.1 * 0.05
    assert 'magnetometer sees a turn' in mon.gyro.vertical


def test_without_a_magnetometer_a_turn_faster_than_the_bound_is_not_absorbed_at_all():
    mon, moved = _turn_day(6, False)                    # 0.05 rad/s, the bound 0.2 deg/s
    assert moved <= 0.02 * DEG
    mon.finish()
    assert mon.gyro.held_rate == pytest.approx(0.05, rel=0.1)
    assert 'not absorbed' in mon.gyro.vertical


def test_without_a_magnetometer_a_turn_slower_than_the_bound_is_absorbed_at_most_its_rate():
    rng = np.random.default_rng(6)
    rig = F.field_rig(rng, magnetometer=False)
    pose = F.random_pose(rng, 10)
    rate = 0.15 * DEG                                   # below the 0.2 deg/s bound
    segs = [F.move(pose, pose, 2.0), F.still(pose, 10.0), F.turn(pose, rate, 60.0)]
    mon, trace = run_day(rig, segs, F.Events(), rng)
    before = [b for kind, t, b in trace if kind == 'still'][-1]
    up = pose.inv().apply([0.0, 0.0, 1.0])
    moved = max(abs(float(up @ (b - before))) for kind, t, b in trace if kind == 'turn')
    assert 0.5 * rate < moved <= rate + 0.02 * DEG      # absorbed, never beyond the turn
    assert 'looks like a bias' in mon.gyro.vertical


def test_a_stationary_signal_does_not_let_a_turntable_be_absorbed():
    rng = np.random.default_rng(21)
    rig = F.field_rig(rng, magnetometer=False)
    pose = F.random_pose(rng, 10)
    segs = [F.move(pose, pose, 2.0), F.still(pose, 10.0), F.turn(pose, 3.0 * DEG, 60.0)]
    mon, trace = run_day(rig, segs, F.Events(), rng, stationary=lambda kind: True)
    before = [b for kind, t, b in trace if kind == 'still'][-1]
    up = pose.inv().apply([0.0, 0.0, 1.0])
    moved = max(abs(float(up @ (b - before))) for kind, t, b in trace if kind == 'turn')
    assert moved <= 0.02 * DEG                          # 3 deg/s: beyond the 1 deg/s bound
    assert 'stationary signal' in mon.gyro.vertical and 'not absorbed' in mon.gyro.vertical


def test_a_stationary_signal_saying_moving_stops_every_update():
    mon, moved = _turn_day(7, False, stationary=lambda kind: kind == 'still')
    assert moved <= 1e-9


def test_reset_returns_to_the_file():
    rng = np.random.default_rng(8)
    rig = F.field_rig(rng)
    ev = F.Events(gyro_change=0.5 * DEG * np.ones(3))
    pose = F.random_pose(rng, 10)
    mon, _ = run_day(rig, [F.still(pose, 5.0), F.move(pose, pose, 2.0)], ev, rng)
    assert np.abs(mon.gyro_bias).max() > 0.3 * DEG
    mon.reset_gyro_bias()
    assert np.all(mon.gyro_bias == 0.0) and mon.gyro.updates == 0


def test_gyro_estimate_off_when_disabled():
    rng = np.random.default_rng(9)
    rig = F.field_rig(rng)
    ev = F.Events(gyro_change=0.5 * DEG * np.ones(3))
    mon, _ = run_day(rig, [F.still(F.random_pose(rng, 10), 5.0)], ev, rng,
                     MonitorSettings(gyro_bias_enabled=False))
    assert np.all(mon.gyro_bias == 0.0)


# -- calibration health ----------------------------------------------------------------------
def _cycle(rng, rig, events, periods=6, hold=6.0):
    poses = [F.random_pose(rng, 45) for _ in range(3)]
    segs = [F.move(poses[2], poses[0], 2.0)]
    for k in range(periods):
        segs += [F.still(poses[k % 3], hold), F.move(poses[k % 3], poses[(k + 1) % 3], 3.0)]
    mon, _ = run_day(rig, segs, events, rng, chunk_s=1.0)
    mon.finish()
    return mon


def test_a_fine_calibration_is_healthy():
    rng = np.random.default_rng(10)
    rig = F.field_rig(rng)
    mon = _cycle(rng, rig, F.Events())
    assert mon.health.periods >= 6
    assert mon.health.failures == 0
    r = mon.last_health
    assert r.level == 'ok' and r.healthy and r.orientations == 3
    assert 'consistent with gravity' in r.message


def test_a_5_mg_shift_is_flagged_within_3_periods_with_its_cause():
    rng = np.random.default_rng(11)
    rig = F.field_rig(rng)
    shift = 5 * MG * np.array([1.0, -1.0, 1.0])
    mon = _cycle(rng, rig, F.Events(knocks=[(0.0, shift)]), periods=3)
    first = mon.health.first_failure
    assert first is not None and first.periods <= 3
    assert first.message.startswith('recalibrate') and 'bias shift' in first.cause
    assert mon.last_health.to_dict()['recalibrate']


def test_temperature_outside_the_range_is_a_warning_with_the_size_it_explains():
    rng = np.random.default_rng(12)
    rig = F.field_rig(rng)
    hot = rig.calibration.temperature_range_c[1] + 10.0
    mon = _cycle(rng, rig, F.Events(temperature=hot), periods=3)
    r = mon.health.first_warning
    assert r is not None and mon.health.failures == 0
    assert r.level == 'warn' and r.healthy and not r.to_dict()['recalibrate']
    assert r.cause.startswith('temperature outside the calibrated range')
    assert r.temperature_outside_c == pytest.approx(10.0, abs=0.01)
    assert 'could explain up to' in r.warning


def test_opposite_orientations_tell_a_bias_shift_from_a_scale_change():
    from accel_calib_ros.core.monitor.health import CalibrationHealth, ErrorModel
    rng = np.random.default_rng(13)
    cal = F.field_rig(rng).calibration
    cal.level_roll_pitch_rad = None
    up = np.array([0.0, 0.0, 1.0])
    for kind, word in (('bias', 'a bias shift of about'), ('scale', 'a scale change (about')):
        h = CalibrationHealth(ErrorModel(cal))
        for sign in (1.0, -1.0):         # z up, then z down: |a| moves opposite ways for
            d = 8 * MG * (sign if kind == 'bias' else 1.0)   # a bias, the same for a scale
            h.clusters.append({'u': sign * up, 'd': d, 'se': 1e-5, 't': 0.0, 'temp': 25.0})
        r = h.check(25.0)
        assert r.level == 'recalibrate'
        assert r.cause.startswith(word)


def test_without_covariance_the_words_say_how_the_error_was_taken():
    rng = np.random.default_rng(14)
    rig = F.field_rig(rng)
    rig.calibration.covariance = None
    mon = _cycle(rng, rig, F.Events(), periods=2)
    assert any('no parameter covariance' in n for n in mon.last_health.notes)
    assert mon.last_health.level == 'ok'


def test_a_robot_that_never_rests_has_no_verdict():
    rng = np.random.default_rng(15)
    rig = F.field_rig(rng)
    p, q = F.random_pose(rng, 30), F.random_pose(rng, 30)
    mon, _ = run_day(rig, [F.move(p, q, 20.0)], F.Events(), rng)
    mon.finish()
    assert mon.last_health is None and mon.health.result.level == 'unknown'
    assert mon.gyro.updates == 0


def test_settings_change_in_place_keeps_the_estimate():
    rng = np.random.default_rng(16)
    rig = F.field_rig(rng)
    ev = F.Events(gyro_change=0.5 * DEG * np.ones(3))
    mon, _ = run_day(rig, [F.still(F.random_pose(rng, 10), 5.0)], ev, rng)
    before = mon.gyro_bias.copy()
    mon.apply_settings(mon.settings.replace(health_false_alarm=1e-6, gyro_bias_limit_deg_s=2.0,
                                            threshold_factor=4.0))
    np.testing.assert_array_equal(mon.gyro_bias, before)
    assert mon.health.false_alarm == 1e-6 and mon.detector.factor == 4.0
    assert mon.gyro.limit == pytest.approx(2.0 * DEG)


def test_without_a_heading_a_power_up_change_is_followed_a_slow_turn_from_rest_is_not():
    # The first rest after a start takes up to 1 deg/s about gravity for the power-up
    # change of the zero-rate output; a turn in place that sets off from rest (0.5 deg/s,
    # 15 deg) is held, and the drive after it keeps the estimate the rest gave.
    rng = np.random.default_rng(22)
    rig = F.field_rig(rng, magnetometer=False)
    pose = F.random_pose(rng, 5)
    up = pose.inv().apply([0.0, 0.0, 1.0])
    change = 0.5 * DEG * up                           # all of it along gravity
    ev = F.Events(gyro_change=change)
    segs = [F.move(pose, pose, 2.0), F.still(pose, 8.0), F.turn(pose, 0.5 * DEG, 30.0),
            F.move(pose, pose, 5.0), F.still(pose, 5.0)]
    mon, trace = run_day(rig, segs, ev, rng)
    left = bias_left(rig, ev)
    after_rest = [b for kind, t, b in trace if kind == 'still' and t <= 10.0][-1]
    assert abs(up @ (after_rest - left)) < 0.03 * DEG              # followed in the rest
    turning = [b for kind, t, b in trace if kind == 'turn']
    assert max(abs(up @ (b - after_rest)) for b in turning) < 0.02 * DEG   # not the turn
    mon.finish()
    assert mon.gyro.turning >= 1
