"""
The ML solver as it was before the blocked rewrite (main at 2504f62), for bench_ml.py.

Reference only: the benchmark times it and measures the largest relative difference
of the new solver's answers to it. Its ellipsoid start (full SVD of the design) and
its Newton step ((9, N, 3) coupling temporaries) are kept verbatim; the coverage
checks and the result dataclass are left out.
"""

import time
from types import SimpleNamespace

from accel_calib_ros.core.accelerometer.ml import pack, unpack
from accel_calib_ros.core.errors import CalibrationError
import numpy as np

UPPER = np.triu_indices(3)


def _design(x):
    """Rows (x², y², z², 2xy, 2xz, 2yz, 2x, 2y, 2z, 1) of eq. 17, shape (N, 10)."""
    X, Y, Z = x.T
    return np.column_stack([X * X, Y * Y, Z * Z, 2 * X * Y, 2 * X * Z, 2 * Y * Z,
                            2 * X, 2 * Y, 2 * Z, np.ones(len(x))])


def fit_ellipsoid_reference(readings, weights=None, radius=1.0):
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
    if axes[-1] < 0.2 * axes[0]:
        raise CalibrationError(
            f'the fitted ellipsoid is flat (axis ratio {axes[-1] / axes[0]:.3f}): the '
            'orientations do not span three dimensions; tilt the sensor out of the plane')
    return T, bias


_ROW, _COL = UPPER
_UNIT = np.eye(3)


def _normalise(v):
    return v / np.linalg.norm(v, axis=1, keepdims=True)


class _Problem:
    """The ML objective in normalised units (radius 1) and its Newton step."""

    def __init__(self, y, w):
        self.y = y
        self.w = w

    def objective(self, p, u):
        T, b = unpack(p)
        r = self.y - u @ T.T - b
        return 0.5 * float(np.sum(self.w * np.einsum('ij,ij->i', r, r)))

    def schur(self, p, u, damping=0.0):
        """
        Reduced 9x9 Newton system ``S dp = rhs`` and the back-substitution pieces.

        Per observation the KKT block is ``[[M_k, u_k], [u_kᵀ, 0]]`` with
        ``M_k = w_k TᵀT + lambda_k I``. All ``M_k`` share the eigenvectors ``V`` of
        ``TᵀT``, so their inverses are diagonal in that basis; the sums over
        observations are BLAS matrix products over flattened (9, 3N) arrays.
        """
        T, b = unpack(p)
        w = self.w
        r = self.y - u @ T.T - b                                # (N, 3)
        wr = w[:, None] * r
        lam = np.einsum('ij,ij->i', u @ T, wr)                  # least-squares multipliers
        g_u = -(wr @ T) + lam[:, None] * u                       # dL/du_k
        g_l = 0.5 * (np.einsum('ij,ij->i', u, u) - 1.0)          # dL/dlambda_k
        # A = sum_k w_k J_kᵀ J_k and dL/dp from the weighted moments of u and r.
        Wuu = u.T @ (w[:, None] * u)
        Wu = w @ u
        A = np.zeros((9, 9))
        for a, (i, j) in enumerate(zip(_ROW, _COL)):
            for c, (k, m) in enumerate(zip(_ROW, _COL)):
                if i == k:
                    A[a, c] = Wuu[j, m]
            A[a, 6 + i] = A[6 + i, a] = Wu[j]
        A[6:, 6:] = np.sum(w) * np.eye(3)
        Wru = wr.T @ u
        g_p = -np.concatenate([Wru[UPPER], wr.sum(axis=0)])
        # Coupling d²L/(dp du_k) = w (Jᵀ T - D), D[T_ij, m] = r_i delta_jm, expressed
        # in the eigenbasis V of TᵀT and laid out (9, N, 3) so sums are BLAS products.
        TtT = T.T @ T
        evals, V = np.linalg.eigh(TtT)
        TV = T @ V
        Cv = np.empty((9, len(w), 3))
        for a, (i, j) in enumerate(zip(_ROW, _COL)):
            Cv[a] = u[:, j:j + 1] * TV[i] - r[:, i:i + 1] * V[j]
        Cv[6:] = TV[:, None, :]
        Cv *= w[None, :, None]
        diag = w[:, None] * evals[None, :] + lam[:, None]         # M_k in the V basis
        if damping:
            diag = diag + damping * np.mean(evals) * w[:, None]
        dinv = 1.0 / diag                                        # (N, 3)
        u_v = u @ V
        Mu_v = dinv * u_v                                        # Vᵀ M⁻¹ u
        uMu = np.einsum('ni,ni->n', u_v, Mu_v)
        flat = Cv.reshape(9, -1)
        CMu = np.einsum('ink,nk->in', Cv, Mu_v)                   # C M⁻¹ u, (9, N)
        S = A - (Cv * dinv[None]).reshape(9, -1) @ flat.T + (CMu / uMu) @ CMu.T
        if damping:
            S = S + damping * np.diag(np.diag(A))
        # rhs = -g_p + sum C (P g_u + q g_l),  P = M⁻¹ - M⁻¹u uᵀM⁻¹ / uMu.
        g_uv = g_u @ V
        Pg = dinv * g_uv - Mu_v * (np.einsum('ni,ni->n', Mu_v, g_uv) / uMu)[:, None]
        Pg += Mu_v * (g_l / uMu)[:, None]
        rhs = -g_p + flat @ Pg.reshape(-1)
        return S, rhs, (V, dinv, Mu_v, uMu, Cv, g_uv, g_l)

    def step(self, p, u, damping):
        """Damped Newton step: new (p, u) with u projected back onto the sphere."""
        S, rhs, (V, dinv, Mu_v, uMu, Cv, g_uv, g_l) = self.schur(p, u, damping)
        dp = np.linalg.solve(S, rhs)
        a = -g_uv - np.tensordot(dp, Cv, axes=1)                   # in the V basis
        du_v = dinv * a - Mu_v * (np.einsum('ni,ni->n', Mu_v, a) / uMu)[:, None]
        du_v -= Mu_v * (g_l / uMu)[:, None]
        return p + dp, _normalise(u + du_v @ V.T), dp


def _initial_directions(y, T, b):
    return _normalise(np.linalg.solve(T, (y - b).T).T)


def fit_ml_reference(readings, weights=None, radius=1.0, start=None, max_iter=100, tol=1e-12):
    """
    Maximum-likelihood calibration by damped Newton iteration (Sun & Xu 2020).

    :param readings: (N, 3) raw readings (window means or samples), N >= 10.
    :param weights: (N,) relative weights, e.g. samples per window (default 1).
        The noise of observation k is sigma / sqrt(w_k).
    :param radius: magnitude of the true vectors (local gravity, same unit as readings).
    :param start: optional (T, bias) start; default the ellipsoid fit (eq. 16-18).
    :param max_iter: iteration limit.
    :param tol: relative objective change and step size that count as converged.
    :returns: namespace with T dimensionless and bias in reading units.
    :raises CalibrationError: too few observations or a degenerate geometry.
    """
    t0 = time.perf_counter()
    y_raw = np.asarray(readings, dtype=float).reshape(-1, 3)
    n = len(y_raw)
    if n < 10:
        raise CalibrationError(
            f'the 9-parameter ML model needs at least 10 observations, got {n}')
    w = np.ones(n) if weights is None else np.asarray(weights, dtype=float).reshape(n)
    w = w / np.mean(w)
    y = y_raw / radius
    if start is None:
        T0, b0 = fit_ellipsoid_reference(y, w)
    else:
        T0, b0 = np.asarray(start[0], float), np.asarray(start[1], float) / radius
    problem = _Problem(y, w)
    p = pack(np.triu(T0), b0)
    u = _initial_directions(y, unpack(p)[0], b0)
    f = problem.objective(p, u)
    trace = [f]
    damping, converged, it = 0.0, False, 0
    for it in range(1, max_iter + 1):
        while True:
            try:
                p_new, u_new, dp = problem.step(p, u, damping)
                f_new = problem.objective(p_new, u_new)
            except np.linalg.LinAlgError:
                f_new = np.inf
            if np.isfinite(f_new) and f_new <= f * (1 + 1e-12) + 1e-300:
                damping = damping / 10.0 if damping > 1e-9 else 0.0
                break
            damping = max(damping * 10.0, 1e-6)
            if damping > 1e8:
                break
        if damping > 1e8:
            break
        small_step = np.linalg.norm(dp) <= np.sqrt(tol) * (1.0 + np.linalg.norm(p))
        small_change = f - f_new <= tol * max(f, 1e-300)
        p, u, f = p_new, u_new, f_new
        trace.append(f)
        if small_step and small_change:
            converged = True
            break
    T, b = unpack(p)
    if np.any(np.diag(T) <= 0) or not np.all(np.isfinite(p)):
        raise CalibrationError('ML iteration diverged to a non-physical T; '
                               'the observations do not constrain the model')
    S, _, _ = problem.schur(p, u)
    dof = n - 9
    sigma2 = 2.0 * f / dof
    try:
        cov = sigma2 * np.linalg.inv(S)
    except np.linalg.LinAlgError:
        cov = np.full((9, 9), np.nan)
    scale = np.r_[np.ones(6), np.full(3, radius)]
    cov = cov * np.outer(scale, scale)
    return SimpleNamespace(
        T=T, bias=b * radius, directions=u, covariance=cov,
        sigma=float(np.sqrt(sigma2) * radius), objective=f * radius ** 2,
        iterations=it, converged=converged, seconds=time.perf_counter() - t0)
