"""Predicted accuracy, outlier windows, the gyro in the static test and the gyro bias (core)."""

from accel_calib_ros.core.accelerometer.fit import (calibrate, check_geometry, estimate_gyro_bias,
                                                    find_outlier_windows, missing_faces)
from accel_calib_ros.core.accelerometer.ml import cramer_rao_bound, fit_ml
from accel_calib_ros.core.accuracy import predicted_accuracy
from accel_calib_ros.core.errors import CalibrationError
from accel_calib_ros.core.samples import Samples
from accel_calib_ros.core.windows import detect_static_windows
from accel_calib_ros.sim.motion import random_directions, simulate_session, simulate_window_means
from accel_calib_ros.sim.sensor import mpu9250_like
import numpy as np
import pytest

G = 9.80665


def _true_error(cal, sensor, n=2000):
    u = random_directions(n, np.random.default_rng(99))
    corrected = cal.correct(sensor.distort(G * u))
    return float(np.sqrt(np.mean(np.sum((corrected - G * u) ** 2, axis=1))))


@pytest.mark.parametrize('method', ['ml', 'ellipsoid'])
def test_predicted_accuracy_matches_the_true_error_on_average(method):
    ratios = []
    for seed in range(40):
        rng = np.random.default_rng(seed)
        sensor = mpu9250_like(rng)
        sensor.noise_std = np.full(3, 0.3)            # large noise: parameter error dominates
        n = 12 + seed % 20
        counts = np.full(n, 100)
        y = simulate_window_means(sensor, random_directions(n, rng), counts, rng)
        cal = calibrate(y, G, method, counts, noise_std=sensor.noise_std)
        ratios.append((_true_error(cal, sensor) / cal.predicted_accuracy) ** 2)
    # E[true²] = predicted² when the covariance is right; a wrong noise level or a
    # missing factor would move this mean by far more than its sampling spread.
    assert 0.6 < np.mean(ratios) < 1.6, np.mean(ratios)


def test_predicted_accuracy_is_scale_free_and_right_on_raw_counts_and_low_noise():
    rng = np.random.default_rng(7)
    sensor = mpu9250_like(rng)
    sensor.noise_std = np.full(3, 1e-4)
    counts = np.full(20, 200)
    dirs = random_directions(20, rng)
    y = simulate_window_means(sensor, dirs, counts, rng)
    # Without the floor (what no averaging removes) the prediction follows the noise.
    cal = calibrate(y, G, 'ml', counts, noise_std=sensor.noise_std, sigma_floor=0.0)
    assert cal.predicted_accuracy < 1e-4
    per_g = 16384 / G                                   # ±2 g counts per m/s²
    for floor in (0.0, None):                           # the floor scales with T too
        cal = calibrate(y, G, 'ml', counts, noise_std=sensor.noise_std, sigma_floor=floor)
        cal_counts = calibrate(y * per_g, G, 'ml', counts, noise_std=sensor.noise_std * per_g,
                               sigma_floor=floor)
        assert cal_counts.predicted_accuracy == pytest.approx(cal.predicted_accuracy,
                                                              rel=1e-3)
        np.testing.assert_allclose(cal_counts.T / per_g, cal.T, rtol=1e-6)


def test_fisher_covariance_agrees_with_the_ml_cramer_rao_bound():
    rng = np.random.default_rng(3)
    sensor = mpu9250_like(rng)
    counts = np.full(30, 150)
    y = simulate_window_means(sensor, random_directions(30, rng), counts, rng)
    cal = calibrate(y, G, 'ml', counts, noise_std=sensor.noise_std)
    fit = fit_ml(y, counts, G)
    crb = cramer_rao_bound(fit.T, fit.bias, fit.directions, 1.0, counts / counts.mean(), G)
    ratio = np.diag(cal.covariance) / np.diag(crb)
    assert np.allclose(ratio, ratio[0], rtol=0.05)          # same shape, one noise level²
    per_window = np.mean(sensor.noise_std) / np.sqrt(150)
    assert per_window ** 2 <= ratio[0] < 4 * per_window ** 2
    assert predicted_accuracy(cal.T, cal.covariance, G) == pytest.approx(cal.predicted_accuracy)


def test_gn_covariance_charges_the_held_terms_and_what_they_alias():
    rng = np.random.default_rng(4)
    sensor = mpu9250_like(rng)
    sensor.T = np.diag(np.diag(sensor.T))
    counts = np.full(14, 150)
    y = simulate_window_means(sensor, random_directions(14, rng), counts, rng)
    cal = calibrate(y, G, 'gn', counts, noise_std=sensor.noise_std)
    held = [1, 2, 4]                                     # T_xy, T_xz, T_yz
    # The held terms get their posterior mean square (measured here by the ml fit of the
    # same windows), coupled to the fitted terms they alias into on these poses.
    np.testing.assert_allclose(np.diag(cal.covariance)[held] >= cal.cross_axis.mean_square
                               * (1 - 1e-9), True)
    assert cal.cross_axis.measured.all() and np.all(np.diag(cal.covariance) > 0)
    assert 0 < cal.predicted_accuracy < 0.02
    # The same poses on a sensor with cross-axis terms: gn is charged for holding them.
    skew = mpu9250_like(np.random.default_rng(4))
    y = simulate_window_means(skew, random_directions(14, rng), counts, rng)
    cal = calibrate(y, G, 'gn', counts, noise_std=skew.noise_std)
    assert cal.predicted_accuracy > 0.5 * _true_error(cal, skew) > 0.02


def test_one_pose_and_a_tilt_cap_fail_the_geometry_with_the_missing_faces():
    rng = np.random.default_rng(1)
    one = np.array([0.1, 0.2, 9.8]) + 0.05 * rng.standard_normal((3000, 3))
    for method in ('ml', 'gn', 'ellipsoid'):
        with pytest.raises(CalibrationError, match='z axis down'):
            check_geometry(one, method)
    assert missing_faces(one) == ['x axis up', 'x axis down', 'y axis up', 'y axis down',
                                  'z axis down']


def test_outlier_windows_are_found_and_clean_sessions_keep_every_window():
    for seed in range(6):
        rng = np.random.default_rng(seed)
        sensor = mpu9250_like(rng, effects=('temperature_bias',) if seed % 2 else ())
        n = 30
        counts = np.full(n, 200)
        temps = np.linspace(15, 40, n)
        y = simulate_window_means(sensor, random_directions(n, rng), counts, rng, temp=temps)
        keep, reasons = find_outlier_windows(y, counts, counts, sensor.noise_std, G, temps,
                                             thermal=bool(seed % 2), band_width_c=10.0)
        assert keep.all(), reasons                       # no false alarm
        bad = y.copy()
        bad[[4, 17]] += 0.3 * np.array([[1, -1, 0.5], [-0.5, 0.5, 1.0]])
        keep, reasons = find_outlier_windows(bad, counts, counts, sensor.noise_std, G, temps,
                                             thermal=bool(seed % 2), band_width_c=10.0)
        assert sorted(np.flatnonzero(~keep)) == [4, 17] and [k for k, _ in reasons] == [4, 17]
        assert 'residual' in reasons[0][1]


def _turning_session(seed=2, rate=100.0):
    rng = np.random.default_rng(seed)
    sensor = mpu9250_like(rng)
    s = simulate_session(sensor, random_directions(12, rng), rng, hold_s=3.0, rate_hz=rate)
    return sensor, s


def test_gyro_joins_the_static_test():
    sensor, s = _turning_session()
    plain = detect_static_windows(s.samples)
    assert len(plain) == 12 and not plain.dropped
    gyro = s.samples.gyro.copy()
    hold = np.flatnonzero((s.pose == 6) & (np.linalg.norm(gyro - sensor.gyro_bias, axis=1)
                                           < 0.02))
    gyro[hold] += [0.0, np.radians(6.0), 0.0]            # a slow turn the whole hold
    half = np.flatnonzero((s.pose == 9) & (np.linalg.norm(gyro - sensor.gyro_bias, axis=1)
                                           < 0.02))
    half = half[len(half) // 2:]
    gyro[half] += [np.radians(6.0), 0.0, 0.0]            # a turn in the second half only
    turned = Samples(s.samples.t, s.samples.accel, s.samples.temp, gyro)
    w = detect_static_windows(turned)
    assert len(w) == 11 and len(w.dropped) == 1 and 'rotating' in w.dropped[0]['reason']
    assert s.samples.t[hold[0]] - 0.5 <= w.dropped[0]['t_start'] <= s.samples.t[hold[-1]]
    cut = [k for k in range(len(w)) if plain.start[9] - 5 <= w.start[k] <= plain.stop[9]]
    assert len(cut) == 1 and w.stop[cut[0]] <= half[0]   # cut before the turn
    no_gyro = detect_static_windows(turned, max_rotation_rad_s=None)
    assert len(no_gyro) == 12


def test_gyro_bias_from_static_windows_and_per_band():
    sensor, s = _turning_session(seed=5)
    w = detect_static_windows(s.samples)
    bias = estimate_gyro_bias(w.gyro_mean, w.count)
    assert np.abs(bias - sensor.gyro_bias).max() < 3e-4
    assert estimate_gyro_bias(np.full((3, 3), np.nan)) is None
    rng = np.random.default_rng(8)
    n = 60
    temps = np.r_[np.full(30, 22.0), np.full(30, 34.0)]
    counts = np.full(n, 200)
    sensor = mpu9250_like(rng)
    y = simulate_window_means(sensor, random_directions(n, rng), counts, rng, temp=temps)
    gyro = np.where(temps[:, None] < 30, 0.01, 0.02) + 1e-4 * rng.standard_normal((n, 3))
    cal = calibrate(y, G, 'ml', counts, temps, thermal=True, noise_std=sensor.noise_std,
                    gyro_means=gyro)
    np.testing.assert_allclose(cal.gyro_bias, 0.015, atol=1e-3)
    out = cal.gyro_bias_at(np.array([22.0, 34.0]))
    np.testing.assert_allclose(out, [[0.01] * 3, [0.02] * 3], atol=1e-4)
    assert cal.temperature_range_c == (22.0, 34.0)
