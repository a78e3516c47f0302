"""Algebraic ellipsoid fit (Sun & Xu 2020, eq. 16-18): the "LS method" and ML start."""

import numpy as np

from ..errors import CalibrationError

UPPER = np.triu_indices(3)
"""Row-major indices of the six upper-triangular entries of T."""

ROWS_PER_BLOCK = 8192
"""Observations processed at once by the blocked loops (temporaries stay in cache)."""

_BATCH = 512
"""Columns per BLAS call in :func:`cross_product` (small calls stay single-threaded)."""


def cross_product(a, b):
    """
    Return ``a @ bᵀ`` for wide (p, n) and (q, n) arrays, summed from small products.

    One product with a long inner dimension makes OpenBLAS start its threads; on a
    loaded machine that costs milliseconds per call. Here the columns go through one
    batched matmul in slices of :data:`_BATCH`, each BLAS call small enough to stay
    on one thread, and the partial products are summed.
    """
    p, n = a.shape
    q = b.shape[0]
    m = n - n % _BATCH
    out = np.zeros((p, q))
    if m:
        out += np.matmul(a[:, :m].reshape(p, -1, _BATCH).transpose(1, 0, 2),
                         b[:, :m].reshape(q, -1, _BATCH).transpose(1, 2, 0)).sum(axis=0)
    if m < n:
        out += a[:, m:] @ b[:, m:].T
    return out


def apply(A, x):
    """
    Return ``A @ x`` for a small matrix A (p, 3) and wide x (3, n), without BLAS.

    A BLAS product with a long dimension may start OpenBLAS threads (see
    :func:`cross_product`); einsum's own loop is as fast for three rows.
    """
    return np.einsum('ij,jn->in', A, x)


def _design(x):
    """Rows (x², y², z², 2xy, 2xz, 2yz, 2x, 2y, 2z, 1) of eq. 17 for x (3, n): (10, n)."""
    X, Y, Z = x
    D = np.empty((10, x.shape[1]))
    np.multiply(x, x, out=D[:3])
    np.multiply(X, Y, out=D[3])
    np.multiply(X, Z, out=D[4])
    np.multiply(Y, Z, out=D[5])
    D[3:6] *= 2.0
    np.multiply(x, 2.0, out=D[6:9])
    D[9] = 1.0
    return D


def fit_ellipsoid(readings, weights=None, radius=1.0):
    """
    Fit ``readings`` to an ellipsoid: ``readings = T @ u + bias`` with ``|u| = radius``.

    Algebraic least squares on eq. 17 (smallest eigenvector of the weighted normal
    matrix of the design, after centring and scaling the data for conditioning), then
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
    return fit_ellipsoid_columns(np.ascontiguousarray(y.T), w, radius)


def fit_ellipsoid_columns(yt, w, radius=1.0):
    """
    :func:`fit_ellipsoid` on readings stored by component, ``yt`` (3, N).

    :param yt: (3, N) readings, any unit (N >= 9).
    :param w: (N,) non-negative observation weights.
    :param radius: norm of the true vectors.
    :returns: (T (3, 3), bias (3,)) as :func:`fit_ellipsoid`.
    """
    n = yt.shape[1]
    wsum = float(np.sum(w))
    centre0 = np.einsum('in,n->i', yt, w) / wsum
    scale0 = 0.0
    for s in range(0, n, ROWS_PER_BLOCK):
        d = yt[:, s:s + ROWS_PER_BLOCK] - centre0[:, None]
        scale0 += float(np.sum(w[s:s + ROWS_PER_BLOCK] * np.sum(d * d, axis=0)))
    scale0 = np.sqrt(scale0 / wsum)
    if not scale0 > 0:
        raise CalibrationError('all observations are identical')
    # Smallest eigenvector of the weighted normal matrix D W Dᵀ of the design (the
    # data are centred and scaled, so its condition is that of the geometry), summed
    # over blocks so no (10, N) design matrix is held at once.
    gram = np.zeros((10, 10))
    for s in range(0, n, ROWS_PER_BLOCK):
        design = _design((yt[:, s:s + ROWS_PER_BLOCK] - centre0[:, None]) / scale0)
        gram += cross_product(design * w[s:s + ROWS_PER_BLOCK], design)
    coef = np.linalg.eigh(gram)[1][:, 0]
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
    scatter = np.zeros((3, 3))
    for s in range(0, n, ROWS_PER_BLOCK):
        u = apply(R, yt[:, s:s + ROWS_PER_BLOCK] - bias[:, None])
        u /= np.sqrt(np.sum(u * u, axis=0))
        scatter += cross_product(u * w[s:s + ROWS_PER_BLOCK], u)
    check_scatter(scatter / wsum)
    return T, bias


MIN_AXIS_RATIO = 0.2
"""Smallest accepted ratio of the ellipsoid's axes (a real triad's sensitivities agree)."""

MIN_DIRECTION_SPREAD = 0.01
"""Smallest eigenvalue of the weighted direction scatter E[u uᵀ] accepted (sphere: 1/3)."""


def check_coverage(directions, weights=None):
    """Raise CalibrationError unless unit vectors (N, 3) reach out along all three axes."""
    u = np.asarray(directions, float)
    u = u / np.linalg.norm(u, axis=1, keepdims=True)
    w = np.ones(len(u)) if weights is None else np.asarray(weights, float)
    return check_scatter((u * w[:, None]).T @ u / np.sum(w))


def check_scatter(scatter):
    """
    Raise CalibrationError unless the direction scatter reaches out along all axes.

    :param scatter: (3, 3) weighted mean of u uᵀ over unit directions u.
    :returns: its smallest eigenvalue (the coverage).
    """
    coverage = np.linalg.eigvalsh(scatter)[0]
    if coverage < MIN_DIRECTION_SPREAD:
        raise CalibrationError(
            f'the orientations do not cover all three axes (coverage {coverage:.3f}, '
            f'needs {MIN_DIRECTION_SPREAD}); tilt the sensor out of the plane it was turned in')
    return coverage
