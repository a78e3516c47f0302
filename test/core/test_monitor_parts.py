"""
The field monitor's parts on hand-made blocks.

Cutting, the noise of means, the history's allowance, the publication of the gyro
estimate, the neighbours of a rest.
"""

import math

from accel_calib_ros.core.monitor import Block, BlockCutter, FieldMonitor, Run
from accel_calib_ros.core.monitor.inertial import Neighbours, period_words
from accel_calib_ros.core.monitor.mean_noise import MeanNoise
from accel_calib_ros.core.monitor.prior import DATASHEET_TEMPCO, MG, sensor_prior
from accel_calib_ros.sim import field_stream as F
import numpy as np
import pytest

G = 9.80665
DEG = math.pi / 180.0


def samples(rng, seconds, rate=100.0, t0=0.0, gravity=(0.0, 0.0, G), noise=0.03):
    t = t0 + np.arange(int(seconds * rate)) / rate
    a = np.asarray(gravity) + rng.normal(0.0, noise, (len(t), 3))
    g = rng.normal(0.0, 0.002, (len(t), 3))
    return t, a, g, np.full(len(t), 25.0)


# -- cutting -------------------------------------------------------------------------------
def test_a_gap_ends_a_block_and_is_a_step_not_one_long_block():
    rng = np.random.default_rng(0)
    cutter = BlockCutter(0.1)
    t, a, g, temp = samples(rng, 2.0)
    t2, a2, g2, temp2 = samples(rng, 2.0, t0=12.0)           # 10 s later
    events = cutter.cut(t, a, g, temp) + cutter.cut(t2, a2, g2, temp2) + cutter.finish()
    blocks = [v for kind, v in events if kind == 'block']
    assert max(b.duration for b in blocks) <= 0.1 + 1e-9
    assert [kind for kind, _ in events].count('step') == 1 and cutter.backwards == 0


def test_a_step_back_is_a_step_too_and_the_blocks_are_the_same_in_pieces():
    rng = np.random.default_rng(1)
    t, a, g, temp = samples(rng, 3.0)
    t = np.r_[t, t[:150]]                                     # the clock jumps back 3 s
    a, g, temp = np.vstack([a, a[:150]]), np.vstack([g, g[:150]]), np.r_[temp, temp[:150]]
    whole, parts = BlockCutter(0.1), BlockCutter(0.1)
    one = whole.cut(t, a, g, temp) + whole.finish()
    two = []
    for lo in range(0, len(t), 7):
        two += parts.cut(t[lo:lo + 7], a[lo:lo + 7], g[lo:lo + 7], temp[lo:lo + 7])
    two += parts.finish()
    assert whole.backwards == parts.backwards == 1
    assert [k for k, _ in one] == [k for k, _ in two]
    for (k1, v1), (_, v2) in zip(one, two):
        if k1 == 'block':
            assert v1.n == v2.n and np.allclose(v1.a_mean, v2.a_mean)


def test_a_clock_that_stands_still_does_not_make_one_block_forever():
    rng = np.random.default_rng(2)
    cutter = BlockCutter(0.1)
    t, a, g, temp = samples(rng, 1.0)
    cutter.cut(t, a, g, temp)
    still = np.full(2000, t[-1])                              # the stamps stop
    events = cutter.cut(still, a[:1].repeat(2000, 0), g[:1].repeat(2000, 0), temp[:1].repeat(2000))
    assert ('step', 'the sample clock does not advance') in events


def test_low_rates_get_longer_blocks_and_below_20_hz_the_monitor_refuses():
    rng = np.random.default_rng(3)
    for rate, step in ((200.0, 0.1), (50.0, 0.2), (25.0, 0.4)):
        cutter = BlockCutter(0.1)
        cutter.cut(*samples(rng, 2.0, rate))
        assert cutter.step_s == pytest.approx(step) and not cutter.too_slow
    rig = F.field_rig(np.random.default_rng(4), rate_hz=100.0)
    mon = FieldMonitor(rig.calibration)
    mon.feed(*samples(rng, 5.0, 10.0))
    assert 'needs at least 20 Hz' in mon.too_slow


# -- the noise of means ---------------------------------------------------------------------
def _runs(rng, count, slow=0.0):
    """Still periods of 30 s of 0.1 s blocks, white noise plus a slow random walk."""
    runs = []
    for _ in range(count):
        drift = np.cumsum(rng.normal(0.0, slow, 300))
        run = None
        for k in range(300):
            a = np.array([0.0, 0.0, G + drift[k]]) + rng.normal(0.0, 0.03 / math.sqrt(20), 3)
            b = Block(20, 0.1 * k, 0.1, a, np.full(3, 0.03 ** 2))
            run = Run(b) if run is None else run.add(b) or run
        runs.append(run)
    return runs


def test_white_noise_gives_a_ratio_near_one_and_slow_noise_more():
    rng = np.random.default_rng(5)
    white, slow = MeanNoise(), MeanNoise()
    assert white.ratio(300) == pytest.approx(3.5 ** 2)          # the prior before any data
    for run in _runs(rng, 20):
        white.add(run)
    for run in _runs(rng, 20, slow=0.002):
        slow.add(run)
    assert white.fit()[0] == pytest.approx(1.0, abs=0.1)
    assert white.ratio(300) < 2.5
    assert slow.ratio(300) > 5.0 * white.ratio(300)
    assert slow.summary()['batch_ratio']['32_blocks'] > slow.summary()['batch_ratio']['1_blocks']


# -- the allowance from the history ----------------------------------------------------------
def test_the_history_scatter_is_the_allowance_and_its_slope_the_tempco():
    rng = np.random.default_rng(6)
    calibrations = [{'bias': rng.normal(0.0, 2.0 * MG, 3), 'temperature_range_c': (t, t + 1.0)}
                    for t in (15.0, 20.0, 25.0, 30.0, 35.0, 40.0)]
    prior = sensor_prior(1.0 * MG, calibrations, 'imu7')
    assert 'history of imu7' in prior.allowance_source
    assert np.all(prior.allowance > 1.0 * MG) and np.all(prior.allowance < 6.0 * MG)
    assert 'history' in prior.tempco_source
    few = sensor_prior(1.0 * MG, calibrations[:2])
    np.testing.assert_allclose(few.allowance, 1.0 * MG)
    np.testing.assert_allclose(few.tempco, DATASHEET_TEMPCO)


# -- the gyro estimate is not published before the tilt test could see the tilt ---------------
def test_a_slowly_tilting_rest_publishes_nothing():
    rng = np.random.default_rng(7)
    rig = F.field_rig(rng)
    mon = FieldMonitor(rig.calibration)
    tilt = 0.05 * DEG                       # a slow tilt: the gyro sees it, so does gravity
    moved = 0.0
    for k in range(300):
        t = 0.1 * k + 0.05
        angle = tilt * t
        a = G * np.array([math.sin(angle), 0.0, math.cos(angle)]) + rng.normal(0, 0.003, 3)
        g = np.array([0.0, tilt, 0.0]) + rng.normal(0, 0.0005, 3)
        mon.add_block(Block(20, t, 0.1, a, np.full(3, 0.03 ** 2), g, np.full(3, 1e-6), 25.0))
        moved = max(moved, float(np.max(np.abs(mon.gyro_bias))))
    assert mon.gyro.rejected >= 1
    assert moved <= 0.02 * DEG


# -- inertial rest --------------------------------------------------------------------------
def _rest(a, seconds=3.0, t0=0.0):
    run = None
    for k in range(int(seconds * 10)):
        b = Block(20, t0 + 0.1 * k + 0.05, 0.1, np.asarray(a, float), np.full(3, 0.03 ** 2),
                  np.zeros(3), np.full(3, 1e-6))
        run = Run(b) if run is None else run.add(b) or run
    return run


def test_a_plateau_between_two_rests_that_agree_is_dropped_a_lasting_shift_is_kept():
    up = np.array([0.0, 0.0, G])
    lift = Neighbours()
    out = []
    for k, a in enumerate((up, up + [0, 0, 0.8], up)):     # rest, a lift's plateau, rest
        out += lift.arrive(a, 25.0, 20.0 * k)
        lift.close(_rest(a, t0=20.0 * k), {'d': float(np.linalg.norm(a) - G), 'a': a})
    assert [r[0] for r in out] == ['confirm', 'drop']
    knock = Neighbours()
    out = []
    for k, a in enumerate((up, up + [0, 0, 0.05], up + [0, 0, 0.05])):  # a 5 mg shift stays
        out += knock.arrive(a, 25.0, 20.0 * k)
        knock.close(_rest(a, t0=20.0 * k), {'d': float(np.linalg.norm(a) - G), 'a': a})
    assert [r[0] for r in out] == ['confirm', 'confirm']
    split = Neighbours()                  # one plateau in two halves confirms nothing
    out = []
    for t0, a in ((0.0, up), (20.0, up + [0, 0, 0.8]), (23.0, up + [0, 0, 0.8]), (26.0, up)):
        out += split.arrive(a, 25.0, t0)
        split.close(_rest(a, 1.5, t0=t0), {'d': float(np.linalg.norm(a) - G)})
    assert [r[0] for r in out] == ['confirm', 'drop', 'drop']


def test_a_tilt_without_rotation_is_a_vehicle_braking():
    up = np.array([0.0, 0.0, G])
    braking = up + np.array([1.5, 0.0, 0.0])                  # 8.7 deg, |a| +11 mg
    van = Neighbours()
    out = []
    for k, a in enumerate((up, braking, up)):
        out += van.arrive(a, 25.0, 20.0 * k)
        van.close(_rest(a, t0=20.0 * k), {'d': float(np.linalg.norm(a) - G), 'a': a})
    assert [r[0] for r in out] == ['confirm', 'drop']


def test_a_heaving_period_wanders():
    rng = np.random.default_rng(8)
    run = None
    for k in range(60):
        t = 0.1 * k
        a = np.array([0.0, 0.0, G + 0.3 * math.sin(2 * math.pi * 0.3 * t)])
        b = Block(20, t, 0.1, a + rng.normal(0, 0.007, 3), np.full(3, 0.03 ** 2))
        run = Run(b) if run is None else run.add(b) or run
    assert period_words(run)
    assert not period_words(_rest([0.0, 0.0, G]))


# -- frozen ---------------------------------------------------------------------------------
def test_a_sensor_stuck_on_two_codes_is_frozen_a_live_quantised_one_is_not():
    from accel_calib_ros.core.monitor.still import frozen_words
    rng = np.random.default_rng(9)
    lsb = G / 16384.0
    t = np.arange(20) / 200.0
    base = np.array([0.1, -0.2, G])
    stuck = base + lsb * rng.integers(0, 2, (20, 3))
    live = np.round((base + rng.normal(0.0, 0.03, (20, 3))) / lsb) * lsb
    gyro = rng.normal(0.0, 0.002, (20, 3))
    assert 'repeats its output' in frozen_words(Block.of(t, stuck, gyro))
    assert frozen_words(Block.of(t, live, gyro)) == ''
    assert frozen_words(Block.of(t, live, np.zeros((20, 3)))) == ''     # no gyro recorded
    assert 'gyro repeats' in frozen_words(Block.of(t, live, np.tile(gyro[0], (20, 1))))
