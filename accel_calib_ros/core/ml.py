"""
Maximum-likelihood accelerometer calibration (Sun & Xu 2020, eq. 9-15).

Model (eq. 4), in units of the gravity magnitude::

    y_k = T @ u_k + b + e_k,   |u_k| = 1,   e_k ~ N(0, sigma² / w_k · I)

with ``T`` upper triangular (scale x non-orthogonality) and ``b`` the bias. The
unknowns are the 9 entries of ``T`` and ``b`` plus one unit vector ``u_k`` and one
Lagrange multiplier ``lambda_k`` per observation (eq. 12). Newton's method on this
Lagrangian has a block-arrow Hessian (eq. 14-15): a dense 9x9 global block, a 4x4
block per observation and 9x4 couplings. Each iteration eliminates the per-observation
blocks in closed form (Schur complement) and solves one 9x9 system, so the cost is
O(N) vectorised numpy work instead of O(N³) for the dense (9 + 4N)² Hessian.
Levenberg-Marquardt damping with a step acceptance test on the ML objective makes
it converge from the ellipsoid start on real data; near the optimum it is the
undamped Newton iteration of the paper and converges quadratically.
"""

from dataclasses import dataclass, field
import time

import numpy as np

from .ellipsoid import check_coverage, fit_ellipsoid, UPPER
from .errors import CalibrationError

PARAMETER_NAMES = ('T_xx', 'T_xy', 'T_xz', 'T_yy', 'T_yz', 'T_zz', 'b_x', 'b_y', 'b_z')
"""Order of the 9 calibration parameters in vectors and covariances."""


def pack(T, bias):
    """Parameter vector (9,) = upper-triangular T (row-major) then bias."""
    return np.concatenate([np.asarray(T, float)[UPPER], np.asarray(bias, float)])


def unpack(p):
    """Inverse of :func:`pack`: (T (3, 3), bias (3,))."""
    T = np.zeros((3, 3))
    T[UPPER] = p[:6]
    return T, np.array(p[6:9], dtype=float)


def _jacobian(u):
    """d(T @ u + b)/dp for each observation, shape (N, 3, 9)."""
    J = np.zeros((len(u), 3, 9))
    for col, (i, j) in enumerate(zip(*UPPER)):
        J[:, i, col] = u[:, j]
    J[:, 0, 6] = J[:, 1, 7] = J[:, 2, 8] = 1.0
    return J


_ROW, _COL = UPPER
_UNIT = np.eye(3)


def _normalise(v):
    return v / np.linalg.norm(v, axis=1, keepdims=True)


@dataclass
class MLResult:
    """
    Outcome of :func:`fit_ml`, in the units of the readings.

    :param T: (3, 3) upper-triangular, dimensionless (readings per true unit).
    :param bias: (3,) in reading units.
    :param directions: (N, 3) fitted unit vectors u_k (true acceleration / gravity).
    :param covariance: (9, 9) parameter covariance, order :data:`PARAMETER_NAMES`.
    :param sigma: estimated per-weight noise standard deviation, reading units.
    :param objective: final value of sum_k w_k |y_k - T u_k - b|² / 2, reading units².
    :param trace: objective after each iteration (first entry: the start).
    """

    T: np.ndarray
    bias: np.ndarray
    directions: np.ndarray
    covariance: np.ndarray
    sigma: float
    objective: float
    iterations: int
    converged: bool
    seconds: float
    trace: list = field(default_factory=list)


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


def fit_ml(readings, weights=None, radius=1.0, start=None, max_iter=100, tol=1e-12):
    """
    Maximum-likelihood calibration by damped Newton iteration (Sun & Xu 2020).

    :param readings: (N, 3) raw readings (window means or samples), N >= 10.
    :param weights: (N,) relative weights, e.g. samples per window (default 1).
        The noise of observation k is sigma / sqrt(w_k).
    :param radius: magnitude of the true vectors (local gravity, same unit as readings).
    :param start: optional (T, bias) start; default the ellipsoid fit (eq. 16-18).
    :param max_iter: iteration limit.
    :param tol: relative objective change and step size that count as converged.
    :returns: MLResult with T dimensionless and bias in reading units.
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
        T0, b0 = fit_ellipsoid(y, w)
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
    check_coverage(u, w)
    S, _, _ = problem.schur(p, u)
    dof = n - 9
    sigma2 = 2.0 * f / dof
    try:
        cov = sigma2 * np.linalg.inv(S)
    except np.linalg.LinAlgError:
        cov = np.full((9, 9), np.nan)
    scale = np.r_[np.ones(6), np.full(3, radius)]
    cov = cov * np.outer(scale, scale)
    return MLResult(
        T=T, bias=b * radius, directions=u, covariance=cov,
        sigma=float(np.sqrt(sigma2) * radius), objective=f * radius ** 2,
        iterations=it, converged=converged, seconds=time.perf_counter() - t0,
        trace=[v * radius ** 2 for v in trace])


def fit_ml_bias_corrected(readings, weights=None, radius=1.0, replicates=64, seed=0, **kw):
    """
    ML with its O(sigma²) bias removed by a parametric bootstrap.

    Plain ML on a sphere constraint is biased by O(sigma²) (the curvature of the
    ellipsoid): at sigma = 0.1 g and N in the thousands that bias is as large as the
    standard deviation. Here the fitted model is re-simulated ``replicates`` times
    with the fitted directions and noise level, each replicate is re-fitted (warm
    started), and the mean shift of the estimates is subtracted. The bootstrap adds
    a variance of about 1/replicates of the estimator's own.

    :returns: MLResult whose T/bias are corrected; ``covariance`` is the plain ML one
        scaled by (1 + 1/replicates).
    """
    base = fit_ml(readings, weights, radius, **kw)
    y = np.asarray(readings, dtype=float).reshape(-1, 3)
    n = len(y)
    w = np.ones(n) if weights is None else np.asarray(weights, dtype=float).reshape(n)
    w = w / np.mean(w)
    rng = np.random.default_rng(seed)
    p_hat = pack(base.T, base.bias)
    clean = radius * base.directions @ base.T.T + base.bias
    shifts = []
    for _ in range(replicates):
        noisy = clean + rng.standard_normal(y.shape) * base.sigma / np.sqrt(w)[:, None]
        try:
            rep = fit_ml(noisy, w, radius, start=(base.T, base.bias), max_iter=30)
        except CalibrationError:
            continue
        shifts.append(pack(rep.T, rep.bias) - p_hat)
    if not shifts:
        raise CalibrationError('bias correction failed: no bootstrap replicate converged')
    p_bc = p_hat - np.mean(shifts, axis=0)
    T, b = unpack(p_bc)
    base.T, base.bias = T, b
    base.covariance = base.covariance * (1.0 + 1.0 / len(shifts))
    base.seconds = base.seconds * (1 + len(shifts))
    return base


def cramer_rao_bound(T, bias, directions, sigma, weights=None, radius=1.0):
    """
    Cramér-Rao bound for (T upper, bias) under the ML model.

    For each observation the information is ``g gᵀ / sigma²`` with ``g = Gᵀ n``: ``G``
    the (3, 9) Jacobian of the ideal reading ``T (radius u) + b`` and ``n`` the unit
    normal of the ellipsoid there (the tangential noise is absorbed by ``u``).

    :param directions: (N, 3) true unit vectors u_k.
    :param sigma: noise standard deviation per unit weight, reading units.
    :returns: (9, 9) covariance bound, order :data:`PARAMETER_NAMES`.
    """
    u = np.asarray(directions, float).reshape(-1, 3)
    w = np.ones(len(u)) if weights is None else np.asarray(weights, float)
    G = _jacobian(radius * u)
    normal = _normalise(np.linalg.solve(np.asarray(T, float).T, u.T).T)
    g = np.einsum('nki,nk->ni', G, normal)
    F = np.einsum('ni,nj,n->ij', g, g, w) / sigma ** 2
    return np.linalg.inv(F)
