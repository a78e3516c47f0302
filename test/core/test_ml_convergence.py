"""Convergence of ML and GN: right at any noise level and in any unit of the readings."""

import os
import sys

from accel_calib_ros.core.accelerometer.gn import fit_gn
from accel_calib_ros.core.accelerometer.ml import _Problem, cramer_rao_bound, fit_ml, pack
from accel_calib_ros.core.errors import CalibrationError
from accel_calib_ros.sim.motion import face_directions, random_directions
import numpy as np
import pytest

sys.path.insert(0, os.path.join(os.path.dirname(__file__), '..', '..', 'bench'))
from ml_reference import fit_ml_reference  # noqa: E402, I100

G = 9.80665
T_TRUE = np.array([[1.02, 0.012, -0.006], [0.0, 0.98, 0.009], [0.0, 0.0, 1.01]])
B_TRUE = np.array([0.21, -0.32, 0.15])
P_TRUE = pack(T_TRUE, B_TRUE)
COUNTS_PER_SI = 16384.0 / G          # MPU-9250 at ±2 g: 16384 counts per g


def session(seed, noise, windows=12, T=T_TRUE, b=B_TRUE):
    """Window means in m/s²: the six faces plus random poses, per-window noise m/s²."""
    rng = np.random.default_rng(seed)
    u = np.vstack([face_directions(), random_directions(windows - 6, rng)])
    return u, G * u @ T.T + b + noise * rng.standard_normal(u.shape)


def faces(seed, noise, scale=(1.02, 0.97, 1.01), b=(0.3, -0.4, 0.6)):
    """Six faces twice, diagonal sensor (the Gui Yi model), m/s²."""
    rng = np.random.default_rng(seed)
    u = np.vstack([face_directions()] * 2)
    return G * u * np.asarray(scale) + np.asarray(b) + noise * rng.standard_normal(u.shape)


@pytest.mark.parametrize('noise', [1e-4, 1e-2])
def test_ml_converges_at_any_noise_level_and_is_right_within_the_bound(noise):
    pulls = []
    for seed in range(40):
        u, y = session(seed, noise)
        fit = fit_ml(y, radius=G)
        assert fit.converged, f'seed {seed}: not converged after {fit.iterations}'
        assert fit.iterations <= 10
        bound = np.sqrt(np.diag(cramer_rao_bound(T_TRUE, B_TRUE, u, noise, radius=G)))
        pulls.append((pack(fit.T, fit.bias) - P_TRUE) / bound)
    pulls = np.array(pulls)
    assert np.all(np.abs(pulls) < 6.0)
    assert 0.6 < np.sqrt(np.mean(pulls ** 2)) < 1.6


@pytest.mark.parametrize('noise', [1e-4, 1e-2])
def test_gn_converges_at_any_noise_level_and_is_right_within_its_noise(noise):
    scale, b = np.array([1.02, 0.97, 1.01]), np.array([0.3, -0.4, 0.6])
    for seed in range(40):
        fit = fit_gn(faces(seed, noise, scale, b), radius=G)
        assert fit.converged, f'seed {seed}: not converged after {fit.iterations}'
        # Each axis sees +g and -g twice: sigma(bias) = noise / 2, sigma(T_ii) = that / g.
        assert np.all(np.abs(fit.bias - b) < 6 * noise / 2)
        assert np.all(np.abs(np.diag(fit.T) - scale) < 6 * noise / 2 / G)


def test_ml_stops_at_the_optimum_not_before():
    """Iterating on with a far tighter tolerance moves the answer by < 1e-4 std errors."""
    for seed, noise in ((1, 1e-4), (2, 1e-2), (3, 0.3)):
        _, y = session(seed, noise, windows=30)
        fit = fit_ml(y, radius=G)
        tight = fit_ml(y, radius=G, tol=1e-12, max_iter=60)
        se = np.sqrt(np.diag(fit.covariance))
        assert fit.converged
        assert np.max(np.abs(pack(fit.T, fit.bias) - pack(tight.T, tight.bias)) / se) < 1e-4


def test_gn_stops_at_the_optimum_not_before():
    for seed, noise in ((1, 1e-4), (2, 1e-2), (3, 0.3)):
        y = faces(seed, noise)
        fit = fit_gn(y, radius=G)
        tight = fit_gn(y, radius=G, tol=1e-12, max_iter=60)
        se = np.sqrt(np.diag(fit.covariance))
        est = np.r_[np.diag(fit.T), fit.bias]
        assert fit.converged
        assert np.max(np.abs(est - np.r_[np.diag(tight.T), tight.bias]) / se) < 1e-4


@pytest.mark.parametrize('offset', [0.0, 32768.0])
def test_raw_counts_give_the_si_answer_in_ml(offset):
    """Counts with radius 16384 give T unchanged; counts with radius g give T in counts."""
    _, y = session(4, 1e-3)
    si = fit_ml(y, radius=G)
    counts = y * COUNTS_PER_SI + offset
    per_g = fit_ml(counts, radius=16384.0)
    per_si = fit_ml(counts, radius=G)
    assert si.converged and per_g.converged and per_si.converged
    np.testing.assert_allclose(per_g.T, si.T, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(per_si.T, si.T * COUNTS_PER_SI, rtol=1e-9, atol=1e-9)
    for fit in (per_g, per_si):
        np.testing.assert_allclose(fit.bias, si.bias * COUNTS_PER_SI + offset, rtol=1e-9)
        np.testing.assert_allclose(fit.sigma, si.sigma * COUNTS_PER_SI, rtol=1e-6)
        np.testing.assert_allclose(fit.covariance[6:, 6:],
                                   si.covariance[6:, 6:] * COUNTS_PER_SI ** 2, rtol=1e-6)
    np.testing.assert_allclose(per_g.covariance[:6, :6], si.covariance[:6, :6], rtol=1e-6)


@pytest.mark.parametrize('offset', [0.0, 32768.0])
@pytest.mark.parametrize('reps', [1, 2])
def test_raw_counts_give_the_si_answer_in_gn(offset, reps):
    """Six faces once (exact fit) or twice, in counts: the bug of 30 failures of 30."""
    rng = np.random.default_rng(5)
    u = np.vstack([face_directions()] * reps)
    y = G * u * np.array([1.02, 0.97, 1.01]) + np.array([0.3, -0.4, 0.6])
    y = y + 1e-3 * rng.standard_normal(y.shape)
    si = fit_gn(y, radius=G)
    counts = y * COUNTS_PER_SI + offset
    per_g = fit_gn(counts, radius=16384.0)
    per_si = fit_gn(counts, radius=G)
    assert si.converged and per_g.converged and per_si.converged
    np.testing.assert_allclose(per_g.T, si.T, rtol=1e-9)
    np.testing.assert_allclose(per_si.T, si.T * COUNTS_PER_SI, rtol=1e-9)
    for fit in (per_g, per_si):
        np.testing.assert_allclose(fit.bias, si.bias * COUNTS_PER_SI + offset, rtol=1e-9)


def test_noise_free_counts_converge_to_the_truth():
    """No noise at all: the roundoff floor, not the noise, ends the iteration."""
    u = np.vstack([face_directions(), random_directions(14, np.random.default_rng(6))])
    counts = COUNTS_PER_SI * (G * u @ T_TRUE.T + B_TRUE) + 32768.0
    fit = fit_ml(counts, radius=16384.0)
    assert fit.converged
    np.testing.assert_allclose(fit.T, T_TRUE, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(fit.bias, B_TRUE * COUNTS_PER_SI + 32768.0, rtol=1e-10)
    exact = faces(0, 0.0) * COUNTS_PER_SI + 32768.0
    gn = fit_gn(exact, radius=16384.0)
    assert gn.converged
    np.testing.assert_allclose(np.diag(gn.T), [1.02, 0.97, 1.01], rtol=1e-10)


def test_unsolvable_or_cut_short_reports_not_converged():
    _, y = session(7, 1e-2)
    assert not fit_ml(y, radius=G, max_iter=1).converged
    assert not fit_gn(faces(7, 1e-2), radius=G, max_iter=1).converged
    # Gravity never along z and z reads exactly constant: k_z and d_z are not determined.
    flat = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0.6, 0.8, 0],
                     [-0.8, 0.6, 0], [0.6, -0.8, 0.0]])
    y = G * flat
    y[:, :2] += 0.01 * np.random.default_rng(8).standard_normal((len(flat), 2))
    try:
        assert not fit_gn(y, radius=G).converged
    except CalibrationError:
        pass


def test_blocked_system_equals_one_block():
    """The blocked, batched accumulation gives the same Newton system as one block."""
    u, y = session(9, 0.05, windows=1500)
    fit = fit_ml(y, radius=G, max_iter=1)
    p, w = pack(fit.T, fit.bias / G), np.random.default_rng(9).uniform(0.5, 2, len(y))
    yt = np.ascontiguousarray(y.T) / G
    ut = np.ascontiguousarray(fit.directions.T)
    one = _Problem(yt, w, block=len(y)).schur(p, ut)
    many = _Problem(yt, w, block=700).schur(p, ut)
    for a, b in zip(one, many):
        np.testing.assert_allclose(a, b, rtol=1e-10, atol=1e-10 * np.max(np.abs(a)))


def test_same_answers_as_the_previous_solver():
    """More observations than one block: T and bias equal the old solver's to 1e-9."""
    rng = np.random.default_rng(10)
    u = random_directions(20000, rng)
    y = u @ T_TRUE.T + B_TRUE + 0.01 * rng.standard_normal(u.shape)
    new, old = fit_ml(y), fit_ml_reference(y)
    assert new.converged and old.converged
    np.testing.assert_allclose(pack(new.T, new.bias), pack(old.T, old.bias), rtol=1e-9)
    np.testing.assert_allclose(new.directions, old.directions, atol=1e-9)


@pytest.mark.parametrize('unit', [1e-3, 0.1019716, 1.0, 1670.7, 1e5])
@pytest.mark.parametrize('offset', [0.0, -5e4, 1e6])
def test_fits_are_equivariant_under_any_unit_and_offset(unit, offset):
    """Readings * unit + offset: same T, bias * unit + offset, same iterations."""
    u, y = session(11, 3e-3, windows=16)
    ml_si, gn_si = fit_ml(y, radius=G), fit_gn(faces(11, 3e-3), radius=G)
    ml = fit_ml(y * unit + offset, radius=G * unit)
    gn = fit_gn(faces(11, 3e-3) * unit + offset, radius=G * unit)
    assert ml.converged and gn.converged
    assert ml.iterations == ml_si.iterations
    # Relative precision of the shifted readings is eps * |offset| / (unit * g).
    rtol = 1e-9 + 1e-12 * abs(offset) / (unit * G)
    np.testing.assert_allclose(ml.T, ml_si.T, rtol=rtol, atol=rtol)
    np.testing.assert_allclose(ml.bias, ml_si.bias * unit + offset, rtol=rtol,
                               atol=rtol * unit * G)
    np.testing.assert_allclose(gn.T, gn_si.T, rtol=rtol)
    np.testing.assert_allclose(gn.bias, gn_si.bias * unit + offset, rtol=rtol,
                               atol=rtol * unit * G)
