"""Magnetometer soft/hard iron, alignment to the accelerometer, field and dip (§10)."""

from accel_calib_ros.core.accelerometer.fit import calibrate
from accel_calib_ros.core.errors import CalibrationError, InputError
from accel_calib_ros.core.magnetometer.fit import (_linear_start, canonical, correct_field,
                                                   fit_alignment, fit_magnetometer,
                                                   sphere_coverage)
from accel_calib_ros.core.samples import Samples
from accel_calib_ros.core.windows import detect_static_windows
from accel_calib_ros.sim import motion as sim_motion
from accel_calib_ros.sim import sensor as simulate
import numpy as np
import pytest
from scipy.spatial.transform import Rotation


def session_with_mag(seed, poses=24, directions=None, rate_hz=100.0, misalignment_deg=2.0,
                     earth=None, tremor_deg=0.3):
    """Simulate a hand-held session of an MPU-9250-like sensor with an AK8963."""
    rng = np.random.default_rng(seed)
    sensor = simulate.mpu9250_like(rng, rate_hz=rate_hz)
    sensor.magnetometer = simulate.ak8963_like(np.random.default_rng(seed + 500),
                                               misalignment_deg=misalignment_deg)
    if directions is None:
        directions = sim_motion.random_poses(poses, rng)
    return sim_motion.simulate_session(sensor, directions, rng, rate_hz=rate_hz,
                                       earth_field=earth or simulate.EarthField(48.0, 60.0),
                                       tremor_deg=tremor_deg)


def truth_of(session, field_known=False):
    """(T, R, field_uT) of the simulated magnetometer in the fit's convention."""
    mag = session.sensor.magnetometer
    return canonical(mag.T, mag.R, session.earth_field.field_uT, field_known)


def sphere_error(fit, session, n=20000):
    """RMS error (µT) of the fit's corrected field over field directions on the sphere."""
    T, R, field_uT = truth_of(session)
    u = sim_motion.random_directions(n, np.random.default_rng(1))
    raw = (field_uT * u) @ (T @ R).T + session.sensor.magnetometer.hard_iron
    err = fit.correct(raw) - field_uT * u
    return float(np.sqrt(np.mean(np.sum(err ** 2, axis=1))))


def test_sphere_coverage_measures_the_fraction_visited():
    rng = np.random.default_rng(0)
    u = sim_motion.random_directions(100000, rng)
    assert sphere_coverage(u) == 1.0
    assert 0.5 <= sphere_coverage(u[u[:, 2] > 0]) < 0.7   # cells touched at its edge count
    angle = np.linspace(0, 2 * np.pi, 1000)
    circle = np.column_stack([np.cos(angle), np.sin(angle), np.zeros_like(angle)])
    assert sphere_coverage(circle) < 0.4                    # a curve crosses cells...
    assert sphere_coverage(circle, cells=400) < 0.15        # ...fewer, the finer they are
    assert sphere_coverage(np.tile([0.0, 0.0, 2.0], (10, 1)), cells=50) == 1 / 50
    assert sphere_coverage(np.zeros((0, 3))) == 0.0
    assert sphere_coverage(np.full((3, 3), np.nan)) == 0.0
    assert sphere_coverage(u[:20], min_samples=2) <= sphere_coverage(u[:20])


def test_canonical_form_is_upper_triangular_and_equivalent():
    rng = np.random.default_rng(3)
    mag = simulate.ak8963_like(rng, misalignment_deg=10.0)
    T, R, field_uT = canonical(mag.T, mag.R, 48.0)
    assert np.allclose(np.tril(T, -1), 0) and np.all(np.diag(T) > 0)
    assert np.linalg.det(T) == pytest.approx(1.0)
    assert np.allclose(R @ R.T, np.eye(3)) and np.linalg.det(R) == pytest.approx(1.0)
    f = sim_motion.random_directions(5, rng)
    assert np.allclose((T @ R @ (field_uT * f).T), mag.T @ mag.R @ (48.0 * f).T)
    T_known, _, same = canonical(mag.T, mag.R, 48.0, field_known=True)
    assert same == 48.0 and np.allclose(T_known @ R, mag.T @ mag.R)
    with pytest.raises(InputError, match='reflection'):
        canonical(np.diag([1.0, 1.0, -1.0]), np.eye(3), 48.0)


def test_recovers_soft_hard_iron_alignment_and_dip_with_honest_accuracy():
    ratios, worst = [], 0.0
    for seed in range(6):
        session = session_with_mag(seed)
        windows = detect_static_windows(session.samples)
        accel = calibrate(windows.mean, weights=windows.count, noise_std=windows.noise_std)
        fit = fit_magnetometer(session.samples, windows, accel=accel)
        assert fit.converged and fit.alignment_fitted, fit.message
        for value in (fit.T, fit.hard_iron_uT, fit.R, fit.field_uT, fit.dip_deg,
                      fit.predicted_accuracy, fit.coverage, fit.residual_rms_uT,
                      fit.covariance, fit.dip_std_deg):
            assert np.all(np.isfinite(value))
        T, R, field_uT = truth_of(session)
        mag = session.sensor.magnetometer
        # Errors against the truth, in standard errors of the reported covariance.
        theta = Rotation.from_matrix(fit.R @ R.T).as_rotvec()
        error = np.concatenate([(fit.T * fit.field_uT - T * field_uT)[np.triu_indices(3)],
                                fit.hard_iron_uT - mag.hard_iron, theta])
        std = np.sqrt(np.diag(fit.covariance))
        worst = max(worst, float(np.max(np.abs(error) / std)),
                    abs(fit.dip_deg - session.earth_field.dip_deg) / fit.dip_std_deg)
        # The errors were there: tens of µT of hard iron, % of soft iron, ~1° of R.
        assert np.linalg.norm(mag.hard_iron) > 10 and np.abs(T - np.eye(3)).max() > 0.01
        assert fit.field_uT == pytest.approx(field_uT, rel=1e-3)
        assert fit.residual_rms_uT == pytest.approx(0.4, rel=0.1)     # the sensor noise
        assert fit.coverage >= 0.25
        ratios.append(sphere_error(fit, session) / fit.predicted_accuracy)
        assert fit.predicted_accuracy < 0.2
    assert worst < 4.5
    rms = float(np.sqrt(np.mean(np.square(ratios))))
    assert 0.5 < rms < 2.0, ratios


def test_corrected_field_keeps_a_constant_angle_to_gravity():
    session = session_with_mag(11, misalignment_deg=8.0, earth=simulate.EarthField(52.0, -30.0))
    sensor = session.sensor
    fit = fit_magnetometer(session.samples, accel=(sensor.T, sensor.bias))
    assert fit.dip_deg == pytest.approx(-30.0, abs=0.1)
    ok = session.samples.mag_rows
    field = correct_field(session.samples.mag[ok], fit.T, fit.hard_iron_uT, fit.R)
    assert np.allclose(field, fit.correct(session.samples.mag[ok]))
    up = session.true_accel[ok] / np.linalg.norm(session.true_accel[ok], axis=1)[:, None]
    still = session.pose[ok] >= 0
    dip = np.degrees(np.arcsin(-np.sum(up * field, axis=1) / np.linalg.norm(field, axis=1)))
    assert np.sqrt(np.mean((dip[still] + 30.0) ** 2)) < 1.0
    raw_dip = session.samples.mag[ok][still] - session.sensor.magnetometer.hard_iron
    raw_dip = np.degrees(np.arcsin(-np.sum(up[still] * raw_dip, axis=1)
                                   / np.linalg.norm(raw_dip, axis=1)))
    assert np.std(raw_dip) > 3 * np.std(dip[still])        # the alignment mattered


def test_known_field_fixes_the_scale_and_slow_magnetometer_rows_are_skipped():
    session = session_with_mag(12, rate_hz=200.0)
    rows = session.samples.mag_rows
    assert 0.45 < rows.mean() < 0.55                      # 100 Hz beside 200 Hz
    sensor = session.sensor
    fit = fit_magnetometer(session.samples, accel=(sensor.T, sensor.bias), field_uT=48.0)
    assert fit.samples_used == rows.sum()
    assert fit.field_uT == 48.0
    T, _, _ = truth_of(session, field_known=True)
    assert np.allclose(fit.T, T, atol=3e-3)
    assert abs(np.linalg.det(fit.T) - 1) > 1e-3 or abs(np.linalg.det(T) - 1) < 1e-3


def test_predicted_accuracy_matches_a_monte_carlo_of_the_covariance():
    session = session_with_mag(13)
    sensor = session.sensor
    fit = fit_magnetometer(session.samples, accel=(sensor.T, sensor.bias))
    rng = np.random.default_rng(2)
    n = 20000
    dp = rng.multivariate_normal(np.zeros(12), fit.covariance, n)
    u = sim_motion.random_directions(n, rng)
    T1 = fit.T * fit.field_uT
    raw = u @ (T1 @ fit.R).T + fit.hard_iron_uT
    err = np.empty((n, 3))
    upper = np.triu_indices(3)
    for k in range(n):
        T = T1.copy()
        T[upper] += dp[k, :6]
        R = Rotation.from_rotvec(dp[k, 9:]).as_matrix() @ fit.R
        scale = np.linalg.det(T) ** (1 / 3)
        err[k] = correct_field(raw[k], T / scale, fit.hard_iron_uT + dp[k, 6:9], R)[0] \
            - fit.field_uT * u[k]
    monte_carlo = np.sqrt(np.mean(np.sum(err ** 2, axis=1)))
    assert fit.predicted_accuracy == pytest.approx(monte_carlo, rel=0.05)


def test_insufficient_coverage_is_refused_with_the_fraction_seen():
    rng = np.random.default_rng(14)
    tilt = np.radians(rng.uniform(0, 60, 16))
    heading = rng.uniform(0, 2 * np.pi, 16)
    axis = np.column_stack([np.sin(heading), -np.cos(heading), np.zeros(16)])
    session = session_with_mag(14, directions=Rotation.from_rotvec(tilt[:, None] * axis))
    sensor = session.sensor
    with pytest.raises(CalibrationError, match=r'saw \d+% of the sphere'):
        fit_magnetometer(session.samples, accel=(sensor.T, sensor.bias))
    relaxed = fit_magnetometer(session.samples, accel=(sensor.T, sensor.bias), min_coverage=0)
    assert relaxed.coverage < 0.25
    other = session_with_mag(15)
    full = fit_magnetometer(other.samples, accel=(other.sensor.T, other.sensor.bias))
    assert relaxed.predicted_accuracy > 3 * full.predicted_accuracy
    # A robot yawing on the floor: the field stays on one cone, a flat ellipse.
    heading = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    session = session_with_mag(16, directions=Rotation.from_rotvec(heading[:, None]
                                                                   * [0.0, 0.0, 1.0]))
    with pytest.raises(CalibrationError, match=r'do not determine .* \d+% of the sphere'):
        fit_magnetometer(session.samples)
    # A band of ±20° about a great circle: an ellipsoid can be fitted, and the path
    # crosses many cells, but the directions stay near one plane.
    rng = np.random.default_rng(16)
    azimuth = rng.uniform(0, 2 * np.pi, 5000)
    elevation = np.radians(rng.uniform(-20, 20, 5000))
    u = np.column_stack([np.cos(elevation) * np.cos(azimuth),
                         np.cos(elevation) * np.sin(azimuth), np.sin(elevation)])
    mag = 48.0 * u + [20.0, -10.0, 5.0] + 0.1 * rng.standard_normal((5000, 3))
    band = Samples(np.arange(5000) / 100.0, np.tile([0.0, 0.0, 9.8], (5000, 1)), mag=mag)
    assert sphere_coverage(u) >= 0.25
    with pytest.raises(CalibrationError, match='stay near one cone'):
        fit_magnetometer(band)


def test_too_few_static_windows_keep_R_at_identity():
    session = session_with_mag(17)
    windows = detect_static_windows(session.samples)
    fit = fit_magnetometer(session.samples, windows.select(np.arange(4)))
    assert not fit.alignment_fitted and not fit.converged
    assert np.array_equal(fit.R, np.eye(3))
    assert 'R kept at identity' in fit.message and '4 static windows' in fit.message
    assert np.isfinite(fit.dip_deg) and fit.field_uT > 0


def test_degenerate_inputs_give_clear_errors():
    session = session_with_mag(18, poses=10, tremor_deg=0.0)
    s = session.samples
    with pytest.raises(InputError, match='no magnetometer'):
        fit_magnetometer(Samples(s.t, s.accel, s.temp, s.gyro))
    with pytest.raises(InputError, match='field_uT'):
        fit_magnetometer(s, field_uT=-48.0)
    mag = np.full_like(s.mag, np.nan)
    mag[:5] = s.mag[:5]
    with pytest.raises(CalibrationError, match='5 magnetometer samples'):
        fit_magnetometer(Samples(s.t, s.accel, s.temp, s.gyro, mag))
    with pytest.raises(InputError, match='outside'):
        fit_magnetometer(s.subset(slice(0, 2000)), detect_static_windows(s))
    with pytest.raises(CalibrationError, match='no static window'):
        fit_magnetometer(s, detect_static_windows(s).select(np.zeros(0, int)))
    partial = s.mag.copy()
    partial[7, 1] = np.nan
    with pytest.raises(InputError, match='magnetometer rows'):
        Samples(s.t, s.accel, mag=partial).validate()
    Samples(s.t, s.accel, mag=mag).validate()          # rows without a sample are fine
    assert Samples(s.t, s.accel, mag=mag).subset(slice(0, 8)).mag_rows.sum() == 5


def test_alignment_is_found_from_any_misalignment():
    attitude = Rotation.random(20, random_state=1)           # body to world, one per window
    dip = np.radians(60.0)
    up = attitude.inv().apply([0.0, 0.0, 1.0])
    field = attitude.inv().apply([np.cos(dip), 0.0, -np.sin(dip)])
    noise = np.random.default_rng(0).standard_normal((20, 3)) * 1e-3
    for angle in (5.0, 60.0, 170.0):
        R = Rotation.from_rotvec(np.radians(angle) * np.array([1.0, 2.0, 3.0])
                                 / np.sqrt(14.0)).as_matrix()
        v = field @ R.T + noise
        v /= np.linalg.norm(v, axis=1, keepdims=True)
        for R_fit, dip_fit in (_linear_start(up, v), fit_alignment(up, v)[:2]):
            assert Rotation.from_matrix(R_fit @ R.T).magnitude() < 3e-3
            assert dip_fit == pytest.approx(dip, abs=3e-3)
