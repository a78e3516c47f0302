"""Gyroscope scale and misalignment from the moves between static windows (interface.md §9)."""

from accel_calib_ros.core.accelerometer.fit import calibrate
from accel_calib_ros.core.errors import CalibrationError, InputError
from accel_calib_ros.core.gyroscope.fit import fit_gyro, predicted_accuracy
from accel_calib_ros.core.gyroscope.moves import clipped, integrate, Moves
from accel_calib_ros.core.samples import Samples
from accel_calib_ros.core.windows import detect_static_windows
from accel_calib_ros.sim import motion as sim_motion
from accel_calib_ros.sim import sensor as simulate
import numpy as np
import peer_data
import pytest
from scipy.spatial.transform import Rotation


def hand_held(seed, poses=24, tremor_deg=0.3, full_scale=None, move_s=1.5, directions=None):
    """Simulate a hand-held session of an MPU-9250-like sensor with gyro errors."""
    rng = np.random.default_rng(seed)
    sensor = simulate.with_gyro_errors(simulate.mpu9250_like(rng),
                                       np.random.default_rng(seed + 1000), full_scale)
    if directions is None:
        directions = sim_motion.random_poses(poses, rng)
    return sim_motion.simulate_session(sensor, directions, rng, move_s=move_s,
                                       tremor_deg=tremor_deg)


def relative_error(T_fit, T_true):
    """RMS relative rate error over the sphere of correcting with T_fit when T_true holds."""
    A = np.linalg.solve(T_fit, T_true) - np.eye(3)
    return float(np.sqrt(np.sum(A ** 2) / 3.0))


def test_simulated_rates_integrate_to_the_simulated_orientations():
    session = hand_held(3, poses=6)
    pose, t = session.pose, session.samples.t
    gravity = session.true_accel / np.linalg.norm(session.true_accel, axis=1, keepdims=True)
    for k in range(5):
        a = np.flatnonzero(pose == k)[-20]          # inside hold k (the hand trembles)
        b = np.flatnonzero(pose == k + 1)[10]       # inside hold k + 1
        C = integrate(session.true_rate[a:b + 1], t[a:b + 1])
        assert np.allclose(C.T @ gravity[a], gravity[b], atol=1e-10)
        assert np.degrees(np.arccos(np.clip(gravity[a] @ gravity[b], -1, 1))) > 1.0


def test_jacobian_matches_finite_differences():
    rng = np.random.default_rng(0)
    rates = [rng.standard_normal((n, 3)) * 2.0 for n in (50, 80, 30)]
    steps = [np.full(len(r), 0.01) for r in rates]
    g = rng.standard_normal((6, 3))
    g /= np.linalg.norm(g, axis=1, keepdims=True)
    moves = Moves(rates, steps, g[:3], g[3:])
    K = np.eye(3) + 0.05 * rng.standard_normal((3, 3))
    _, J, Jb, _ = moves.evaluate(K)
    h = 1e-6
    for i in range(9):
        d = np.zeros(9)
        d[i] = h
        numeric = (moves.evaluate(K + d.reshape(3, 3))[0]
                   - moves.evaluate(K - d.reshape(3, 3))[0]) / (2 * h)
        assert np.allclose(J[:, :, i], numeric, atol=1e-8)
    for i in range(3):
        d = np.zeros(3)
        d[i] = h
        up = Moves([r - d for r in rates], steps, g[:3], g[3:]).evaluate(K)[0]
        down = Moves([r + d for r in rates], steps, g[:3], g[3:]).evaluate(K)[0]
        assert np.allclose(Jb[:, :, i], (up - down) / (2 * h), atol=1e-8)


def test_recovers_T_on_hand_held_sessions_and_predicts_its_accuracy_honestly():
    ratios, worst = [], 0.0
    for seed in range(6):
        session = hand_held(seed)
        windows = detect_static_windows(session.samples)
        accel = calibrate(windows.mean, weights=windows.count, noise_std=windows.noise_std)
        fit = fit_gyro(session.samples, windows, accel=accel)
        truth = session.sensor.gyro_T
        assert fit.converged, fit.message
        assert fit.missing_axes == () and fit.moves_used == len(fit.moves) == len(windows) - 1
        for value in (fit.T, fit.bias, fit.covariance, fit.predicted_accuracy,
                      fit.residual_rms_deg, fit.excitation_deg):
            assert np.all(np.isfinite(value))
        # The gyro errors are there (±3 % scale) and are found to a few 0.01 %.
        assert relative_error(np.eye(3), truth) > 0.01
        std = np.sqrt(np.diag(fit.covariance)).reshape(3, 3)
        worst = max(worst, float(np.max(np.abs(fit.T - truth) / std)))
        ratios.append(relative_error(fit.T, truth) / fit.predicted_accuracy)
        assert fit.predicted_accuracy < 2e-3
        assert np.allclose(fit.bias, session.sensor.gyro_bias, atol=1e-3)
        assert fit.residual_rms_deg < 0.2
    assert worst < 4.5                                   # 54 entries, each within ~4 sigma
    rms = float(np.sqrt(np.mean(np.square(ratios))))
    assert 0.5 < rms < 2.0, ratios                       # the prediction is honest


def test_correct_inverts_the_model():
    session = hand_held(1, poses=16)
    fit = fit_gyro(session.samples, accel=(session.sensor.T, session.sensor.bias))
    w = np.random.default_rng(2).standard_normal((50, 3))
    raw = w @ fit.T.T + fit.bias
    assert np.allclose(fit.correct(raw), w)


def test_predicted_accuracy_is_the_sphere_average():
    rng = np.random.default_rng(5)
    T = np.eye(3) + 0.03 * rng.standard_normal((3, 3))
    L = 1e-3 * rng.standard_normal((9, 9))
    C = L @ L.T
    dT = rng.multivariate_normal(np.zeros(9), C, 100000).reshape(-1, 3, 3)
    u = sim_motion.random_directions(100000, rng)
    err = np.einsum('ij,njk,nk->ni', np.linalg.inv(T), dT, u)
    monte_carlo = np.sqrt(np.mean(np.sum(err ** 2, axis=1)))
    assert predicted_accuracy(T, C) == pytest.approx(monte_carlo, rel=0.02)
    assert predicted_accuracy(T, np.full((9, 9), np.nan)) == float('inf')


def tilted_poses(rng, n, max_tilt_deg):
    """Poses tilted by up to ``max_tilt_deg`` about horizontal axes (a board on a table)."""
    tilt = np.radians(rng.uniform(0, max_tilt_deg, n))
    heading = rng.uniform(0, 2 * np.pi, n)
    axis = np.column_stack([np.sin(heading), -np.cos(heading), np.zeros(n)])
    poses = Rotation.from_rotvec(tilt[:, None] * axis)
    up = np.column_stack([np.sin(tilt) * np.cos(heading), np.sin(tilt) * np.sin(heading),
                          np.cos(tilt)])
    assert np.allclose(poses.inv().apply([0.0, 0.0, 1.0]), up)
    return poses


def test_a_rotation_axis_never_turned_is_named_and_T_kept_at_identity():
    rng = np.random.default_rng(4)
    session = hand_held(4, directions=tilted_poses(rng, 16, 50.0))
    fit = fit_gyro(session.samples, accel=(session.sensor.T, session.sensor.bias))
    assert fit.missing_axes == ('z',)
    assert 'no turn about the z axis' in fit.message
    assert 'from x axis up to y axis up' in fit.message
    assert np.array_equal(fit.T, np.eye(3)) and not fit.converged
    assert fit.excitation_deg[2] < 30 < min(fit.excitation_deg[:2])
    # Turns about x only (gravity in the y-z plane): y and z are missing, x is not.
    angle = np.linspace(0, 10, 16)
    session = hand_held(5, directions=Rotation.from_rotvec(angle[:, None] * [1.0, 0.0, 0.0]))
    fit = fit_gyro(session.samples, accel=(session.sensor.T, session.sensor.bias))
    assert fit.missing_axes == ('y', 'z')
    assert 'no turn about the y and z axes' in fit.message
    # Every turn about the same tilted axis: x and y are never turned independently.
    axis = np.array([1.0, 1.0, 0.0]) / np.sqrt(2.0)
    session = hand_held(6, directions=Rotation.from_rotvec(angle[:, None] * axis))
    fit = fit_gyro(session.samples, accel=(session.sensor.T, session.sensor.bias))
    assert set(fit.missing_axes) >= {'x', 'y'}


def test_moves_that_clip_are_dropped_and_reported():
    full_scale = np.radians(250.0)
    session = hand_held(7, poses=30, full_scale=full_scale, move_s=0.5)
    accel = (session.sensor.T, session.sensor.bias)
    gyro, t = session.samples.gyro, session.samples.t
    windows = detect_static_windows(session.samples)
    results = [fit_gyro(session.samples, windows, accel=accel, full_scale=full_scale),
               fit_gyro(session.samples, windows, accel=accel)]      # limit found in the data
    for fit in results:
        at_limit = [bool(np.any(np.abs(gyro[(t >= m.t_start) & (t < m.t_stop)]) >= full_scale))
                    for m in fit.moves]
        assert 3 <= sum(at_limit) < len(fit.moves) - 10
        assert [not m.used for m in fit.moves] == at_limit
        assert all('clipped' in m.reason for m in fit.moves_dropped)
        assert 'clipped' in fit.message
        std = np.sqrt(np.diag(fit.covariance)).reshape(3, 3)
        assert np.max(np.abs(fit.T - session.sensor.gyro_T) / std) < 4.5
    # Integrating through the clipped stretches instead corrupts the fit.
    through = fit_gyro(session.samples, windows, accel=accel, full_scale=np.inf)
    assert through.moves_used == len(through.moves)
    assert (relative_error(through.T, session.sensor.gyro_T)
            > 10 * relative_error(results[0].T, session.sensor.gyro_T))


def test_clipping_is_found_at_the_rails_of_the_adc():
    counts = np.zeros((100, 3))
    counts[10:12, 0] = 32767            # touched twice: counts because -32768 is a rail
    counts[40:50, 0] = -32768
    counts[60, 1] = 20000               # one peak: not a rail
    counts[70:72, 2] = 15000            # repeated twice but below the rail
    at = clipped(counts)
    assert np.flatnonzero(at[:, 0]).tolist() == list(range(10, 12)) + list(range(40, 50))
    assert not at[:, 1:].any()
    assert not clipped(counts[:, 1:2].repeat(3, axis=1)).any()
    assert clipped(counts, full_scale=15000)[70:72, 2].all()


def test_degenerate_inputs_give_clear_errors():
    session = hand_held(8, poses=8, tremor_deg=0.0)
    samples = session.samples
    with pytest.raises(InputError, match='no gyro'):
        fit_gyro(Samples(samples.t, samples.accel))
    still = samples.subset(slice(0, 250))                  # one window, no move
    with pytest.raises(CalibrationError, match='static window'):
        fit_gyro(still)
    windows = detect_static_windows(samples)
    with pytest.raises(CalibrationError, match='at least 5'):
        fit_gyro(samples, windows.select(np.arange(3)))    # two moves
    with pytest.raises(InputError, match='accel'):
        fit_gyro(samples, windows, accel='calibrated')
    with pytest.raises(InputError, match='outside'):
        fit_gyro(samples.subset(slice(0, 300)), windows)   # windows of another recording
    # NaN rows in the gyro drop the moves they fall in, with the reason.
    gyro = samples.gyro.copy()
    t = samples.t
    hit = [1, 3]
    for k in hit:
        gyro[(windows.stop[k] + windows.start[k + 1]) // 2] = np.nan
    holey = Samples(samples.t, samples.accel, samples.temp, gyro)
    fit = fit_gyro(holey, windows, accel=(session.sensor.T, session.sensor.bias))
    assert [m.window for m in fit.moves_dropped] == hit
    assert all('NaN' in m.reason for m in fit.moves_dropped)
    assert np.all(np.isfinite(fit.T)) and t is samples.t
    gyro[:] = np.nan
    with pytest.raises(CalibrationError):
        fit_gyro(Samples(samples.t, samples.accel, samples.temp, gyro), windows)


@pytest.mark.skipif(not peer_data.available('mpu6050_tomisuarez2'),
                    reason='shared/data not present')
def test_mpu6050_session_calibrates_the_92_degree_validation_turn():
    samples = peer_data.mpu6050()
    windows = detect_static_windows(samples)
    # No y-up/y-down pose in this session: the 6-parameter accelerometer fit (the
    # 9-parameter one is undetermined off the diagonal).
    accel = calibrate(windows.mean, method='gn', weights=windows.count,
                      noise_std=windows.noise_std)
    fit = fit_gyro(samples, windows, accel=accel)
    assert fit.converged, fit.message
    assert len(fit.moves_dropped) == 3                   # the moves that hit ±250 °/s
    assert all('clipped' in m.reason for m in fit.moves_dropped)
    assert fit.moves == fit_gyro(samples, windows, accel=accel,
                                 full_scale=np.radians(250.0)).moves
    # The validation recording: still, a turn of about 92° about x, still.
    turn = peer_data.mpu6050_turn()
    held = detect_static_windows(turn)
    bias = turn.gyro[held.start[0]:held.stop[0]].mean(axis=0)
    n = 50
    a, b = held.stop[0] - n // 2, held.start[-1] + n // 2
    g0 = accel.correct(turn.accel[held.stop[0] - n:held.stop[0]].mean(axis=0))[0]
    g1 = accel.correct(turn.accel[held.start[-1]:held.start[-1] + n].mean(axis=0))[0]
    g0, g1 = g0 / np.linalg.norm(g0), g1 / np.linalg.norm(g1)

    def angle(u, v):
        return np.degrees(np.arctan2(np.linalg.norm(np.cross(u, v)), u @ v))

    def predicted(T):
        rate = np.linalg.solve(T, (turn.gyro[a:b + 1] - bias).T).T
        return integrate(rate, turn.t[a:b + 1]).T @ g0

    assert angle(g0, g1) == pytest.approx(92.3, abs=0.2)
    assert abs(angle(g0, predicted(fit.T)) - angle(g0, g1)) < 0.5
    assert angle(predicted(fit.T), g1) < 0.5
    assert angle(predicted(np.eye(3)), g1) > 1.0         # the nominal scale is not enough


@pytest.mark.skipif(not peer_data.available('imu_tk'), reason='shared/data not present')
def test_xsens_gyro_gain_matches_the_factory_calibration():
    gain = 4770.0
    samples = peer_data.imu_tk_imu(gain)
    windows = detect_static_windows(samples)
    accel = calibrate(windows.mean, peer_data.IMU_TK_GRAVITY, weights=windows.count,
                      noise_std=windows.noise_std)
    fit = fit_gyro(samples, windows, accel=accel)
    assert fit.converged and fit.moves_used >= 30, fit.message
    fitted = np.diag(fit.T) * gain
    std = np.sqrt(np.diag(fit.covariance)[[0, 4, 8]]) * gain
    assert np.all(np.abs(fitted / peer_data.IMU_TK_GYRO_GAIN - 1) < 2.5e-3)
    assert np.all(np.abs(fitted - peer_data.IMU_TK_GYRO_GAIN) < 4 * std)
    assert fit.residual_rms_deg < 1.0
