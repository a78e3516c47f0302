"""One still pose while the temperature sweeps: the lag, the bins and their checks, the fit."""

from accel_calib_ros.core.accelerometer.thermal_lag import (Hysteresis, lagged_temperature,
                                                            LagState, LagStream)
from accel_calib_ros.core.accelerometer.thermal_pose import fit_still
from accel_calib_ros.core.accelerometer.thermal_still import still_bins
from accel_calib_ros.core.calibration import Calibration
from accel_calib_ros.core.constants import G0
from accel_calib_ros.core.errors import CalibrationError
from accel_calib_ros.core.samples import Samples
from accel_calib_ros.sim.chamber import ChamberProgramme, simulate_still, thermal_unit
import numpy as np
import pytest

MG = G0 / 1000.0


def _brute_lag(time, temp, tau, substeps=200):
    """Return the lag by many small Euler steps on the linear interpolation (a check)."""
    out = [temp[0]]
    lag = temp[0]
    for k in range(1, len(temp)):
        for j in range(substeps):
            f = (j + 0.5) / substeps
            x = temp[k - 1] + f * (temp[k] - temp[k - 1])
            lag += (time[k] - time[k - 1]) / substeps * (x - lag) / tau
        out.append(lag)
    return np.array(out)


def test_the_lag_is_exact_for_a_linear_temperature_and_restarts_after_a_gap():
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.uniform(0.5, 1.5, 300))
    x = 20.0 + 10.0 * np.sin(t / 40.0)
    lag = lagged_temperature(t, x, 25.0, gap_s=1e9)
    assert np.max(np.abs(lag - _brute_lag(t, x, 25.0))) < 1e-3
    ramp_t = np.arange(0.0, 3000.0, 2.0)
    ramp = 0.05 * ramp_t                              # 3 °C/min
    gradient = ramp - lagged_temperature(ramp_t, ramp, 60.0)
    assert gradient[-1] == pytest.approx(60.0 * 0.05, rel=1e-9)   # tau x rate
    gap = t.copy()
    gap[150:] += 100.0
    split = lagged_temperature(gap, x, 25.0, gap_s=30.0)
    assert split[150] == x[150]                       # in equilibrium after the gap
    assert np.allclose(split[:150], lag[:150])


def test_stream_and_state_give_the_recording_s_lag_piece_by_piece():
    rng = np.random.default_rng(1)
    t = np.cumsum(rng.uniform(0.05, 0.15, 4000))
    t[2500:] += 60.0
    x = 30.0 + 5.0 * np.cos(t / 30.0)
    whole = x - lagged_temperature(t, x, 40.0)
    stream = LagStream(40.0)
    parts = np.concatenate([stream.gradient(t[a:a + 333], x[a:a + 333])
                            for a in range(0, len(t), 333)])
    state = LagState(40.0)
    steps = np.array([state.update(a, b) for a, b in zip(t, x)])
    assert np.max(np.abs(parts - whole)) < 1e-9
    assert np.max(np.abs(steps - whole)) < 1e-9
    assert stream.restarts == state.restarts == 1
    h = Hysteresis(40.0, [0.01, 0.0, -0.02])
    assert np.allclose(h.offset(t, x), np.outer(whole, [0.01, 0.0, -0.02]))


def test_the_file_s_gap_is_the_one_the_lag_restarts_after(tmp_path):
    """``thermal.hysteresis.gap_s`` was written but not read: an edit of it did nothing."""
    from accel_calib_ros.core.accelerometer.thermal import ThermalTable
    from accel_calib_ros.core.correction import Corrector
    from accel_calib_ros.dataio.calibration_file import load_calibration, save_calibration
    t = np.r_[np.arange(0.0, 200.0, 1.0), np.arange(245.0, 400.0, 1.0)]      # a 45 s pause
    x = 20.0 + 0.05 * t
    table = ThermalTable(5.0, [], 'linear', 25.0, (20.0, 45.0),
                         Hysteresis(60.0, [0.01, 0.0, 0.0], gap_s=60.0), 'still')
    save_calibration(Calibration(T=np.eye(3), bias=np.zeros(3), thermal=table,
                                 temperature_range_c=(20.0, 45.0)), tmp_path / 'c.yaml')
    cal = load_calibration(tmp_path / 'c.yaml')
    assert cal.hysteresis.gap_s == 60.0
    expected = x - lagged_temperature(t, x, 60.0, gap_s=60.0)      # the pause bridged
    assert np.allclose(cal.lag_stream().gradient(t, x), expected)
    corrector = Corrector(cal)
    assert np.allclose([corrector.lag.update(a, b) for a, b in zip(t, x)], expected)
    assert corrector.lag.restarts == 0


@pytest.fixture(scope='module')
def chamber():
    """Return a chamber cycle (cool, heat, cool) of one unit with 10 mg of hysteresis, 5 Hz."""
    rng = np.random.default_rng(7)
    programme = ChamberProgramme(rates_c_min=3.0, hold_s=600.0)
    sensor = thermal_unit(rng, hysteresis_mg=10.0)
    session = simulate_still(sensor, [0.0, 0.0, 1.0], rng, programme.duration_s, rate_hz=5.0,
                             temperature=programme)
    return session, sensor, programme


def _leg(session, programme, k):
    s = session.samples
    sel = programme.leg_of(s.t) == k
    return Samples(s.t[sel], s.accel[sel], s.temp[sel], s.gyro[sel])


def test_bins_hold_the_recording_and_a_knock_is_left_out(chamber):
    session, _, programme = chamber
    s = session.samples
    accel = s.accel.copy()
    hit = (s.t > 3000.0) & (s.t < 3004.0)
    accel[hit] += np.random.default_rng(2).standard_normal((hit.sum(), 3)) * 0.5
    rec = still_bins(Samples(s.t, accel, s.temp, s.gyro))
    assert rec.pose.max() == 0
    assert 1 <= len(rec.dropped) <= 2
    assert all('knock' in d['reason'] for d in rec.dropped)
    low, high = rec.temp_range_c
    assert low < -15.0 and high > 70.0


def test_a_move_starts_a_new_pose_and_many_moves_are_refused(chamber):
    session, _, _ = chamber
    s = session.samples
    tilted = s.accel.copy()
    later = s.t > 4000.0
    angle = np.radians(5.0)
    rot = np.array([[1, 0, 0], [0, np.cos(angle), -np.sin(angle)],
                    [0, np.sin(angle), np.cos(angle)]])
    tilted[later] = tilted[later] @ rot.T
    rec = still_bins(Samples(s.t, tilted, s.temp, s.gyro))
    assert rec.pose.max() == 1 and len(rec.moves) == 1
    assert abs(rec.moves[0] - 4000.0) < 20.0
    shaken = s.accel.copy()
    for k, start in enumerate(np.arange(500.0, 6500.0, 700.0)):
        sel = s.t > start
        a = np.radians(3.0 * (-1) ** k)
        r = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
        shaken[sel] = shaken[sel] @ r.T
    with pytest.raises(CalibrationError, match='moved'):
        still_bins(Samples(s.t, shaken, s.temp, s.gyro))


@pytest.mark.parametrize('case, words', [
    ('no temperature', 'no temperature column'),
    ('span', 'spans only'),
    ('jumps', 'jumps by'),
    ('noisy', 'scatters by'),
])
def test_a_recording_that_cannot_carry_a_thermal_fit_is_refused_with_what_to_record(
        chamber, case, words):
    session, _, _ = chamber
    s = session.samples
    temp = s.temp.copy()
    if case == 'no temperature':
        temp = None
    elif case == 'span':
        temp = 25.0 + 0.001 * (s.t - s.t[0]) / 60.0
    elif case == 'jumps':
        temp[len(temp) // 2:] += 5.0
    elif case == 'noisy':
        temp = temp + np.random.default_rng(3).standard_normal(len(temp)) * 2.0
    with pytest.raises(CalibrationError, match=words):
        still_bins(Samples(s.t, s.accel, temp, s.gyro))


def test_the_fit_follows_the_offsets_is_zero_at_the_reference_and_references_the_gyro(chamber):
    session, sensor, programme = chamber
    heating = _leg(session, programme, 1)
    rec = still_bins(heating)
    fit = fit_still(rec, 25.0, 5.0, Hysteresis(sensor.gradient_tau_s),
                    gyro_reference=np.array([0.01, -0.02, 0.03]))
    table = fit.table
    assert table.source == 'still' and table.extrapolation == 'linear'
    assert np.allclose(table.drift(np.zeros((1, 3)), [25.0]), 0.0, atol=1e-12)
    # The offsets against temperature as simulated (the die is the reported temperature).
    temps = np.linspace(-15.0, 70.0, 18)
    d = temps - sensor.temp_ref
    truth = (np.outer(d, sensor.bias_tempco) + np.outer(d ** 2, sensor.bias_tempco_quadratic)
             + np.outer(d ** 3, sensor.bias_tempco_cubic))
    fitted = table.drift(np.zeros((len(temps), 3)), temps)
    assert np.max(np.abs(fitted - truth)) < 0.5 * MG
    # The gyro bias: the reference at 25 °C plus the simulated drift with temperature.
    gyro = table.gyro_bias(temps)
    expected = np.array([0.01, -0.02, 0.03]) + np.outer(d, sensor.gyro_bias_tempco)
    assert np.max(np.abs(gyro - expected)) < np.radians(0.02)
    # The hysteresis term where the simulation put one, none where it did not.
    h = table.hysteresis
    assert h is not None
    truth_k = sensor.bias_gradient
    big = np.abs(truth_k) > 0.5 * np.max(np.abs(truth_k))
    assert np.allclose(h.offset_per_c[big], truth_k[big], rtol=0.25)
    assert np.all(h.offset_per_c[truth_k == 0] == 0.0)
    rows = fit.accuracy
    assert rows and all(r['predicted_accuracy_m_s2'] > 0 for r in rows)


def test_calibration_corrects_with_the_hysteresis_across_pieces(chamber):
    session, sensor, programme = chamber
    rec = still_bins(_leg(session, programme, 1))
    fit = fit_still(rec, 25.0, 5.0, Hysteresis(sensor.gradient_tau_s))
    cal = Calibration(T=sensor.T, bias=sensor.bias, thermal=fit.table)
    s = session.samples
    whole = cal.correct(s.accel, s.temp, s.t)
    stream = cal.lag_stream()
    parts = np.vstack([cal.correct(s.accel[a:a + 999], s.temp[a:a + 999], s.t[a:a + 999],
                                   stream) for a in range(0, len(s.t), 999)])
    assert np.max(np.abs(parts - whole)) < 1e-12
    cooling = programme.leg_of(s.t) == 2
    err = whole[cooling] - whole[programme.leg_of(s.t) == 1].mean(axis=0)
    plain = cal.correct(s.accel, s.temp)[cooling]
    plain_err = plain - cal.correct(s.accel, s.temp)[programme.leg_of(s.t) == 1].mean(axis=0)
    worst = np.argmax(np.abs(sensor.bias_gradient))
    rms = np.sqrt(np.mean(err[:, worst] ** 2))
    assert rms < 0.4 * np.sqrt(np.mean(plain_err[:, worst] ** 2))


def test_a_live_stream_binned_row_by_row_gives_the_recording_s_bins(chamber):
    from accel_calib_ros.core.accelerometer.thermal_still import StillBinner
    session, _, _ = chamber
    s = session.samples
    t = s.t.copy()
    t[len(t) // 2:] += 120.0                        # a pause: a new stretch
    rows = Samples(t, s.accel, s.temp, s.gyro)
    rec = still_bins(rows, bin_s=10.0)
    binner = StillBinner(bin_s=10.0)
    for row in zip(rows.t, rows.accel, rows.temp, rows.gyro):
        binner.add(*row)
    binner.add(t[-1] + 0.1, [np.nan, 0.0, 0.0], 20.0)        # counted, not binned
    live = binner.recording()
    np.testing.assert_array_equal(live.bins.mean, rec.bins.mean)
    np.testing.assert_array_equal(live.segment, rec.segment)
    np.testing.assert_array_equal(live.pose, rec.pose)
    assert live.skipped_rows == 1 and live.segment.max() == 1
