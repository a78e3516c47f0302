"""Properties of the fits: ML (Sun & Xu), ellipsoid LS, Gauss-Newton (Gui Yi)."""

from accel_calib_ros.core.accelerometer.ellipsoid import fit_ellipsoid
from accel_calib_ros.core.accelerometer.gn import fit_gn
from accel_calib_ros.core.accelerometer.ml import (_Problem, cramer_rao_bound, fit_ml,
                                                   fit_ml_bias_corrected, pack, unpack)
from accel_calib_ros.core.errors import CalibrationError
from accel_calib_ros.sim.motion import face_directions, random_directions, sun_xu_directions
import numpy as np
import pytest

T_PAPER = np.array([[1.15, 0.0602, -0.0401], [0, 1.0985, 0.0575], [0, 0, 1.0978]])
B_PAPER = np.array([0.1, 0.15, 0.2])
P_PAPER = pack(T_PAPER, B_PAPER)


def sun_xu(rng, n=300, sigma=0.1):
    u = sun_xu_directions(n, rng)
    return u, u @ T_PAPER.T + B_PAPER + sigma * rng.standard_normal((n, 3))


def test_noise_free_data_are_recovered_exactly():
    u = random_directions(50, np.random.default_rng(0))
    y = u @ T_PAPER.T + B_PAPER
    for T, b in (fit_ellipsoid(y), (fit_ml(y).T, fit_ml(y).bias)):
        np.testing.assert_allclose(pack(T, b), P_PAPER, atol=1e-9)


def test_ml_converges_with_nonincreasing_objective():
    fit = fit_ml(sun_xu(np.random.default_rng(1))[1])
    assert fit.converged and fit.iterations < 15
    assert np.all(np.diff(fit.trace) <= 1e-12 * fit.trace[0])
    assert np.allclose(np.linalg.norm(fit.directions, axis=1), 1.0)
    assert np.all(np.tril(fit.T, -1) == 0) and np.all(np.diag(fit.T) > 0)


def test_schur_step_equals_dense_newton_step():
    """The 9x9 reduced system gives the same step as the dense (9 + 4N)² KKT system."""
    rng = np.random.default_rng(2)
    u_true, y = sun_xu(rng, n=15, sigma=0.05)
    T0, b0 = fit_ellipsoid(y)
    p = pack(T0, b0) + 0.01 * rng.standard_normal(9)
    T, b = unpack(p)
    u = np.linalg.solve(T, (y - b).T).T
    u = u / np.linalg.norm(u, axis=1, keepdims=True) + 0.01 * rng.standard_normal(u.shape)
    w = rng.uniform(0.5, 2.0, len(y))
    problem = _Problem(np.ascontiguousarray(y.T), w / w.mean(), block=4)
    system = problem.schur(p, u.T)
    S, rhs = system.S, system.rhs
    dp = np.linalg.solve(S, rhs)
    u_new = problem.step(p, u.T, dp, 0.0)[0].T

    # Dense Lagrangian Hessian of L = 1/2 sum w |r|² + 1/2 sum lambda (|u|² - 1).
    w = w / w.mean()
    n = len(y)
    r = y - u @ T.T - b
    lam = w * np.einsum('ij,ij->i', u @ T.T, r)       # u_kᵀ Tᵀ r_k: the KKT multiplier
    rows, cols = np.triu_indices(3)
    dim = 9 + 4 * n
    H, g = np.zeros((dim, dim)), np.zeros(dim)
    for k in range(n):
        J = np.zeros((3, 9))
        for c, (i, j) in enumerate(zip(rows, cols)):
            J[i, c] = u[k, j]
        J[:, 6:] = np.eye(3)
        H[:9, :9] += w[k] * J.T @ J
        g[:9] -= w[k] * J.T @ r[k]
        C = J.T @ T
        for c, (i, j) in enumerate(zip(rows, cols)):
            C[c, j] -= r[k, i]
        s = 9 + 4 * k
        H[:9, s:s + 3] = w[k] * C
        H[s:s + 3, :9] = w[k] * C.T
        H[s:s + 3, s:s + 3] = w[k] * T.T @ T + lam[k] * np.eye(3)
        H[s:s + 3, s + 3] = H[s + 3, s:s + 3] = u[k]
        g[s:s + 3] = -w[k] * T.T @ r[k] + lam[k] * u[k]
        g[s + 3] = 0.5 * (u[k] @ u[k] - 1)
    dense = np.linalg.solve(H, -g)
    np.testing.assert_allclose(dp, dense[:9], rtol=1e-7, atol=1e-10)
    # The Newton decrement gᵀ H⁻¹ g (convergence test) from the reduced pieces.
    np.testing.assert_allclose(rhs @ dp + system.decrement_u, -g @ dense, rtol=1e-7)
    du = dense[9:].reshape(n, 4)[:, :3]
    np.testing.assert_allclose(u_new, (u + du) / np.linalg.norm(u + du, axis=1)[:, None],
                               rtol=1e-7, atol=1e-10)


def test_weight_two_equals_a_duplicated_observation():
    u, y = sun_xu(np.random.default_rng(3), n=40, sigma=0.02)
    w = np.ones(40)
    w[7] = 2.0
    a = fit_ml(y, w)
    b = fit_ml(np.vstack([y, y[7:8]]))
    np.testing.assert_allclose(pack(a.T, a.bias), pack(b.T, b.bias), atol=1e-9)


def test_ml_beats_ls_and_reaches_the_cramer_rao_bound():
    """Sun & Xu's simulation: ML error below LS, RMS within 1.3x the CRB."""
    rng = np.random.default_rng(2020)
    err_ml, err_ls, crb = [], [], []
    for _ in range(60):
        u, y = sun_xu(rng)
        fit = fit_ml(y)
        err_ml.append(pack(fit.T, fit.bias) - P_PAPER)
        err_ls.append(pack(*fit_ellipsoid(y)) - P_PAPER)
        crb.append(np.trace(cramer_rao_bound(T_PAPER, B_PAPER, u, 0.1)))
    rms_ml = np.sqrt(np.mean(np.sum(np.square(err_ml), axis=1)))
    rms_ls = np.sqrt(np.mean(np.sum(np.square(err_ls), axis=1)))
    bound = np.sqrt(np.mean(crb))
    assert rms_ml < 0.7 * rms_ls
    assert rms_ml < 1.3 * bound
    assert rms_ml > 0.8 * bound          # an estimator cannot beat the bound by much


def test_reported_covariance_matches_the_scatter():
    rng = np.random.default_rng(4)
    pulls = []
    for _ in range(80):
        u = random_directions(60, rng)
        y = u @ T_PAPER.T + B_PAPER + 0.01 * rng.standard_normal((60, 3))
        fit = fit_ml(y)
        pulls.append((pack(fit.T, fit.bias) - P_PAPER) / np.sqrt(np.diag(fit.covariance)))
    spread = np.std(pulls)
    assert 0.8 < spread < 1.25


def test_bias_correction_removes_the_order_sigma_squared_bias():
    rng = np.random.default_rng(5)
    err_ml, err_bc = [], []
    for _ in range(8):
        _, y = sun_xu(rng, n=3000)
        err_ml.append(pack(*_tb(fit_ml(y))) - P_PAPER)
        err_bc.append(pack(*_tb(fit_ml_bias_corrected(y, replicates=16))) - P_PAPER)
    bias_ml = np.linalg.norm(np.mean(err_ml, axis=0))
    bias_bc = np.linalg.norm(np.mean(err_bc, axis=0))
    assert bias_bc < 0.5 * bias_ml


def _tb(fit):
    return fit.T, fit.bias


def test_units_scale_with_gravity():
    u = random_directions(30, np.random.default_rng(6))
    y = 9.81 * u @ T_PAPER.T + B_PAPER
    fit = fit_ml(y, radius=9.81)
    np.testing.assert_allclose(fit.T, T_PAPER, atol=1e-9)
    np.testing.assert_allclose(fit.bias, B_PAPER, atol=1e-8)


def test_gn_recovers_a_diagonal_sensor_from_six_faces_within_its_noise():
    rng = np.random.default_rng(7)
    g = 9.80665
    T = np.diag([1.02, 0.97, 1.01])
    b = np.array([0.3, -0.4, 0.6])
    u = np.vstack([face_directions()] * 2)
    sigma = 0.002
    y = g * u @ T.T + b + sigma * rng.standard_normal(u.shape)
    fit = fit_gn(y, radius=g)
    assert fit.converged
    err = np.r_[np.diag(fit.T) - np.diag(T), fit.bias - b]
    std = np.sqrt(np.diag(fit.covariance))
    assert np.all(np.abs(err) < 5 * std)
    assert np.all(np.abs(fit.bias - b) < 0.01)


def test_gn_starts_from_raw_counts():
    """Gui Yi's start (bias 0, scale 1) fails on counts; ours starts from the data."""
    u = np.vstack([face_directions(), random_directions(6, np.random.default_rng(8))])
    y = 415.0 * 9.81 * u + 32768.0
    fit = fit_gn(y, radius=9.81)
    np.testing.assert_allclose(np.diag(fit.T), 415.0, rtol=1e-9)
    np.testing.assert_allclose(fit.bias, 32768.0, rtol=1e-9)


@pytest.mark.parametrize('fit', [fit_ml, fit_ellipsoid])
def test_planar_or_too_few_observations_are_refused(fit):
    angle = np.linspace(0, 2 * np.pi, 40, endpoint=False)
    planar = np.column_stack([np.cos(angle), np.sin(angle), np.zeros(40)])
    with pytest.raises(CalibrationError):
        fit(planar + 0.001 * np.random.default_rng(9).standard_normal(planar.shape))
    with pytest.raises(CalibrationError):
        fit(random_directions(5, np.random.default_rng(10)))
