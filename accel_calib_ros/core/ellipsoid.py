"""Algebraic ellipsoid fit (Sun & Xu 2020, eq. 16-18): the "LS method" and ML start."""

import numpy as np

from .errors import CalibrationError

UPPER = np.triu_indices(3)
"""Row-major indices of the six upper-triangular entries of T."""


def _design(x):
    """Rows (x², y², z², 2xy, 2xz, 2yz, 2x, 2y, 2z, 1) of eq. 17, shape (N, 10)."""
    X, Y, Z = x.T
    return np.column_stack([X * X, Y * Y, Z * Z, 2 * X * Y, 2 * X * Z, 2 * Y * Z,
                            2 * X, 2 * Y, 2 * Z, np.ones(len(x))])


def fit_ellipsoid(readings, weights=None, radius=1.0):
    """
    Fit ``readings`` to an ellipsoid: ``readings = T @ u + bias`` with ``|u| = radius``.

    Algebraic least squares on eq. 17 (smallest singular vector of the weighted design
    matrix, after centring and scaling the data for conditioning), then
    ``R = chol(E)``, ``bias = -E⁻¹ F`` (eq. 18) and ``T = R⁻¹`` (upper triangular).

    :param readings: (N, 3) readings, any unit (N >= 9).
    :param weights: (N,) non-negative observation weights (default all 1).
    :param radius: norm of the true vectors, same unit as ``bias``/``T`` scale.
    :returns: (T (3, 3) upper triangular with positive diagonal, bias (3,)).
    :raises CalibrationError: if the points do not determine an ellipsoid.
    """
    y = np.asarray(readings, dtype=float).reshape(-1, 3)
    if len(y) < 9:
        raise CalibrationError(
            f'an ellipsoid needs at least 9 observations, got {len(y)}')
    w = np.ones(len(y)) if weights is None else np.asarray(weights, dtype=float)
    centre0 = np.average(y, axis=0, weights=w)
    scale0 = np.sqrt(np.average(np.sum((y - centre0) ** 2, axis=1), weights=w))
    if not scale0 > 0:
        raise CalibrationError('all observations are identical')
    x = (y - centre0) / scale0
    design = _design(x) * np.sqrt(w)[:, None]
    _, sv, vt = np.linalg.svd(design, full_matrices=False)
    coef = vt[-1]
    a, b, c, f, g, h, p, q, r, d = coef
    E = np.array([[a, f, g], [f, b, h], [g, h, c]])
    F = np.array([p, q, r])
    eig = np.linalg.eigvalsh(E)
    if eig[0] * eig[-1] <= 0:
        raise CalibrationError(
            'the readings do not lie on an ellipsoid (too few distinct orientations, '
            'or all in one plane); turn the sensor through more poses')
    if eig[0] < 0:
        E, F, d = -E, -F, -d
    centre = -np.linalg.solve(E, F)
    k = -(F @ centre) - d
    if not k > 0:
        raise CalibrationError('ellipsoid fit is degenerate (imaginary ellipsoid)')
    E_phys = E / (k * scale0 ** 2) * radius ** 2
    bias = centre0 + scale0 * centre
    try:
        R = np.linalg.cholesky(E_phys).T
    except np.linalg.LinAlgError as err:
        raise CalibrationError(f'ellipsoid fit is degenerate: {err}') from None
    T = np.linalg.inv(R)
    T[np.tril_indices(3, -1)] = 0.0
    axes = np.linalg.svd(T, compute_uv=False)
    if axes[-1] < MIN_AXIS_RATIO * axes[0]:
        raise CalibrationError(
            f'the fitted ellipsoid is flat (axis ratio {axes[-1] / axes[0]:.3f}): the '
            'orientations do not span three dimensions; tilt the sensor out of the plane')
    check_coverage((y - bias) @ R.T / radius, w)
    return T, bias


MIN_AXIS_RATIO = 0.2
"""Smallest accepted ratio of the ellipsoid's axes (a real triad's sensitivities agree)."""

MIN_COVERAGE = 0.01
"""Smallest eigenvalue of the weighted direction scatter E[u uᵀ] accepted (sphere: 1/3)."""


def check_coverage(directions, weights=None):
    """Raise CalibrationError unless unit vectors (N, 3) reach out along all three axes."""
    u = np.asarray(directions, float)
    u = u / np.linalg.norm(u, axis=1, keepdims=True)
    w = np.ones(len(u)) if weights is None else np.asarray(weights, float)
    scatter = (u * w[:, None]).T @ u / np.sum(w)
    coverage = np.linalg.eigvalsh(scatter)[0]
    if coverage < MIN_COVERAGE:
        raise CalibrationError(
            f'the orientations do not cover all three axes (coverage {coverage:.3f}, '
            f'needs {MIN_COVERAGE}); tilt the sensor out of the plane it was turned in')
    return coverage
