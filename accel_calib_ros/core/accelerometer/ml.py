"""
Maximum-likelihood accelerometer calibration (Sun & Xu 2020, eq. 9-15).

Model (eq. 4), in units of the gravity magnitude::

    y_k = T @ u_k + b + e_k,   |u_k| = 1,   e_k ~ N(0, sigma² / w_k · I)

with ``T`` upper triangular (scale x non-orthogonality) and ``b`` the bias. The
unknowns are the 9 entries of ``T`` and ``b`` plus one unit vector ``u_k`` and one
Lagrange multiplier ``lambda_k`` per observation (eq. 12). Newton's method on this
Lagrangian has a block-arrow Hessian (eq. 14-15): a dense 9x9 global block, a 4x4
block per observation and 9x4 couplings. Each iteration eliminates the per-observation
blocks in closed form (Schur complement) and solves one 9x9 system; the sums over
observations are accumulated block by block from per-observation moments (no coupling
matrices are formed), so one iteration is a few passes over the data. The readings are
centred and scaled first, so nothing depends on their unit; convergence is judged by
the Newton decrement against the fit's own noise level (see :func:`fit_ml`).
Levenberg-Marquardt damping with a step acceptance test on the ML objective makes
it converge from the ellipsoid start on real data; near the optimum it is the
undamped Newton iteration of the paper and converges quadratically.
"""

from dataclasses import dataclass, field
import time
from typing import NamedTuple

import numpy as np

from .ellipsoid import (apply, check_scatter, cross_product, fit_ellipsoid_columns,
                        ROWS_PER_BLOCK, UPPER)
from ..calibration import PARAMETER_NAMES  # noqa: F401 - the order of its vectors
from ..errors import CalibrationError


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

STEP_TOLERANCE = 1e-6
"""Converged when the next Newton step would move the fit by at most this many std errors."""

PRECISION_FACTOR = 1e3
"""Steps below this many machine epsilons of the (normalised) readings are roundoff."""


def _normalise(v):
    return v / np.linalg.norm(v, axis=1, keepdims=True)


@dataclass(eq=False)          # arrays: equal only to itself
class MLResult:
    """
    Outcome of :func:`fit_ml`, in the units of the readings.

    :param T: (3, 3) upper-triangular, dimensionless (readings per true unit).
    :param bias: (3,) in reading units.
    :param directions: (N, 3) fitted unit vectors u_k (true acceleration / gravity).
    :param covariance: (9, 9) parameter covariance, order :data:`PARAMETER_NAMES`.
    :param sigma: estimated per-weight noise standard deviation, reading units.
    :param objective: final value of sum_k w_k |y_k - T u_k - b|² / 2, reading units².
    :param iterations: Newton iterations taken.
    :param converged: the Newton step from the result is below ``tol`` (default
        :data:`STEP_TOLERANCE`) standard errors, or at the roundoff floor, and the
        reduced Hessian there is positive definite.
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


class _System(NamedTuple):
    """
    The reduced Newton system at one point, in normalised units.

    :param S: (9, 9) Schur complement (reduced Hessian) of the KKT system.
    :param rhs: (9,) reduced negative gradient: ``S dp = rhs`` is the Newton step.
    :param objective: sum_k w_k |r_k|² / 2.
    :param scatter: (3, 3) weighted mean of u uᵀ.
    :param decrement_u: sum_k g_kᵀ P_k g_k, the directions' part of the Newton decrement.
    """

    S: np.ndarray
    rhs: np.ndarray
    objective: float
    scatter: np.ndarray
    decrement_u: float


class _Problem:
    """
    The ML objective (readings normalised to radius 1) and its Newton system.

    Per observation the KKT block is ``[[M_k, u_k], [u_kᵀ, 0]]`` with
    ``M_k = w_k TᵀT + lambda_k I``. All ``M_k`` share the eigenvectors ``V`` of
    ``TᵀT``, so their inverses are diagonal in that basis. The Schur complement
    ``S = A - sum_k C_k P_k C_kᵀ`` (``C_k`` the 9x3 coupling, ``P_k`` the projected
    inverse) is accumulated without forming the couplings: each ``C_k`` is linear in
    ``u_k`` and ``r_k``, so ``sum_k C_k diag(1/d_k) C_kᵀ`` is a fixed contraction of
    the moments ``sum_k w_k²/d_km (1, u, r, u uᵀ, u rᵀ, r rᵀ)``, and those moments
    (with the plain weighted ones that give ``A``, the gradient and the objective)
    come from one BLAS product per block of observations. Data are held by component
    (3, N) so every elementwise operation runs over long contiguous rows, and blocks
    of :data:`ROWS_PER_BLOCK` observations keep the temporaries in cache: the cost is a few
    passes over the data per iteration.

    :param yt: (3, N) normalised readings.
    :param w: (N,) weights, mean 1.
    """

    def __init__(self, yt, w, block=ROWS_PER_BLOCK):
        self.yt = yt
        self.w = w
        self.n = yt.shape[1]
        self.block = int(block)
        self.data_energy = float(np.einsum('n,n->', w, np.sum(yt * yt, axis=0)))
        self._work = {}

    def _blocks(self):
        for start in range(0, self.n, self.block):
            yield slice(start, start + self.block)

    @staticmethod
    def _basis(p):
        T, b = unpack(p)
        evals, V = np.linalg.eigh(T.T @ T)
        return T, b, evals, V, T @ V

    @staticmethod
    def _local(basis, y, w, u, damping):
        """Residuals and the per-observation (V basis) pieces of the KKT solve."""
        T, b, evals, V, TV = basis
        Tu = apply(T, u)
        r = y - Tu - b[:, None]
        wr = w * r
        lam = np.sum(Tu * wr, axis=0)                          # u_kᵀ Tᵀ w_k r_k
        u_v = apply(V.T, u)
        g_uv = lam * u_v - apply(TV.T, wr)                           # Vᵀ dL/du_k
        g_l = 0.5 * (np.sum(u * u, axis=0) - 1.0)               # dL/dlambda_k
        dinv = 1.0 / ((evals + damping * np.mean(evals))[:, None] * w + lam)
        Mu_v = dinv * u_v                                       # M_k⁻¹ u_k, V basis
        uMu = np.sum(u_v * Mu_v, axis=0)
        return r, wr, g_uv, g_l, dinv, Mu_v, uMu

    def _workspace(self, n):
        """Buffers for one block of ``n`` observations, allocated once per size."""
        work = self._work.get(n)
        if work is None:
            X, Z, H, G = (np.empty((rows, n)) for rows in (4, 34, 9, 12))
            Z[0] = 1.0
            work = self._work[n] = {
                'X': X, 'Z': Z, 'H': H, 'Hs': np.empty((9, n)), 'G': G,
                'uu': Z[7:16].reshape(3, 3, n), 'ur': Z[16:25].reshape(3, 3, n),
                'rr': Z[25:34].reshape(3, 3, n)}
            for name in ('uu', 'ur', 'rr'):      # reshape must give views to write into
                assert np.shares_memory(work[name], Z)
        return work

    def _accumulate(self, acc, basis, y, w, u, damping):
        """Add one block's moments, rank-one terms and right-hand side to ``acc``."""
        T, b, evals, V, TV = basis
        r, wr, g_uv, g_l, dinv, Mu_v, uMu = self._local(basis, y, w, u, damping)
        work = self._workspace(len(w))
        X, Z, H, G = work['X'], work['Z'], work['H'], work['G']
        np.multiply(w * w, dinv, out=X[:3])
        X[3] = w
        Z[1:4] = u
        Z[4:7] = r
        np.multiply(u[:, None], u[None], out=work['uu'])
        np.multiply(u[:, None], r[None], out=work['ur'])
        np.multiply(r[:, None], r[None], out=work['rr'])
        acc['moments'] += cross_product(X, Z)
        # Rank-one part: C_k M_k⁻¹ u_k (9,) per observation, over u_kᵀ M_k⁻¹ u_k.
        alpha = apply(TV, Mu_v)
        beta = apply(V, Mu_v)
        np.multiply(u[_COL], alpha[_ROW], out=H[:6])
        H[:6] -= r[_ROW] * beta[_COL]
        H[6:] = alpha
        H *= w
        np.divide(H, uMu, out=work['Hs'])
        acc['rank_one'] += cross_product(work['Hs'], H)
        # Right-hand side: sum_k C_k (P_k g_u + q_k g_l), from (w γ, -δ) against (u, w r).
        t = (np.sum(Mu_v * g_uv, axis=0) - g_l) / uMu
        Pg = dinv * g_uv - Mu_v * t
        np.multiply(w, apply(TV, Pg), out=G[:3])
        np.negative(apply(V, Pg), out=G[3:6])
        G[6:9] = u
        G[9:] = wr
        acc['rhs'] += cross_product(G[:6], G[6:])
        acc['rhs_b'] += np.sum(G[:3], axis=1)
        # [g_u; g_l]ᵀ K_k⁻¹ [g_u; g_l] of the per-observation KKT block K_k.
        acc['decrement_u'] += float(np.sum(g_uv * Pg) + g_l @ t)

    @staticmethod
    def _new_accumulator():
        return {'moments': np.zeros((4, 34)), 'rank_one': np.zeros((9, 9)),
                'rhs': np.zeros((6, 6)), 'rhs_b': np.zeros(3), 'decrement_u': 0.0}

    @staticmethod
    def _system(acc, basis, damping):
        """Assemble the :class:`_System` from the block sums."""
        T, b, evals, V, TV = basis
        M = acc['moments']
        m1, mu, mr = M[:3, 0], M[:3, 1:4], M[:3, 4:7]
        muu, mur, mrr = (M[:3, s].reshape(3, 3, 3) for s in
                         (slice(7, 16), slice(16, 25), slice(25, 34)))
        wsum, wu, wr = M[3, 0], M[3, 1:4], M[3, 4:7]
        wuu, wur, wrr = (M[3, s].reshape(3, 3) for s in
                         (slice(7, 16), slice(16, 25), slice(25, 34)))
        # sum_k C_k diag(1/d_k) C_kᵀ over all (i, j) pairs of T, then the bias rows.
        Q = (np.einsum('im,km,mjl->ijkl', TV, TV, muu)
             - np.einsum('im,lm,mjk->ijkl', TV, V, mur)
             - np.einsum('jm,km,mli->ijkl', V, TV, mur)
             + np.einsum('jm,lm,mik->ijkl', V, V, mrr))
        Qb = np.einsum('im,km,mj->ijk', TV, TV, mu) - np.einsum('jm,km,mi->ijk', V, TV, mr)
        Qbb = np.einsum('im,km,m->ik', TV, TV, m1)
        A = np.zeros((9, 9))
        K = np.zeros((9, 9))
        for a, (i, j) in enumerate(zip(_ROW, _COL)):
            for c, (k, m) in enumerate(zip(_ROW, _COL)):
                if i == k:
                    A[a, c] = wuu[j, m]
                K[a, c] = Q[i, j, k, m]
            A[a, 6 + i] = A[6 + i, a] = wu[j]
            K[a, 6:] = K[6:, a] = Qb[i, j]
        A[6:, 6:] = wsum * np.eye(3)
        K[6:, 6:] = Qbb
        S = A - K + acc['rank_one']
        if damping:
            S = S + damping * np.diag(np.diag(A))
        # rhs = -dL/dp + sum_k C_k P g: rows (i, j) are sum w γ_i u_j - w r_i δ_j.
        R = acc['rhs']
        coupled = R[:3, :3] + R[3:, 3:].T
        rhs = np.concatenate([(wur.T + coupled)[UPPER], wr + acc['rhs_b']])
        return _System(S, rhs, 0.5 * float(np.trace(wrr)), wuu / wsum, acc['decrement_u'])

    def schur(self, p, ut, damping=0.0):
        """
        Reduced 9x9 Newton system ``S dp = rhs`` at (p, u), and the objective.

        :param ut: (3, N) directions by component.
        :returns: :class:`_System`.
        """
        basis = self._basis(p)
        acc = self._new_accumulator()
        for s in self._blocks():
            self._accumulate(acc, basis, self.yt[:, s], self.w[s], ut[:, s], damping)
        return self._system(acc, basis, damping)

    def step(self, p, ut, dp, damping):
        """
        Back-substitute ``dp`` for the direction steps, move, and evaluate the new point.

        One pass over the data: per block the old point's KKT pieces are recomputed,
        the directions stepped and projected back onto the sphere, and the new
        point's moments accumulated.

        :returns: (u_new (3, N), :class:`_System` at the new point).
        """
        basis = self._basis(p)
        dT, db = unpack(dp)
        basis_new = self._basis(p + dp)
        T, _, _, V, TV = basis
        u_new = np.empty_like(ut)
        acc = self._new_accumulator()
        for s in self._blocks():
            y, w, u = self.yt[:, s], self.w[s], ut[:, s]
            r, wr, g_uv, g_l, dinv, Mu_v, uMu = self._local(basis, y, w, u, damping)
            Jdp = apply(dT, u) + db[:, None]
            a = -g_uv - w * (apply(TV.T, Jdp) - apply(V.T @ dT.T, r))
            du = apply(V, dinv * a - Mu_v * ((np.sum(Mu_v * a, axis=0) + g_l) / uMu))
            un = u_new[:, s]
            np.add(u, du, out=un)
            un /= np.sqrt(np.sum(un * un, axis=0))
            self._accumulate(acc, basis_new, y, w, un, 0.0)
        return u_new, self._system(acc, basis_new, 0.0)


def _initial_directions(yt, T, b):
    """Directions (3, N) of the readings seen through the start (T, b)."""
    Tinv = np.linalg.inv(T)
    u = np.empty_like(yt)
    for s in range(0, yt.shape[1], ROWS_PER_BLOCK):
        v = u[:, s:s + ROWS_PER_BLOCK]
        v[...] = apply(Tinv, yt[:, s:s + ROWS_PER_BLOCK] - b[:, None])
        v /= np.sqrt(np.sum(v * v, axis=0))
    return u


def fit_ml(readings, weights=None, radius=1.0, start=None, max_iter=100,
           tol=STEP_TOLERANCE):
    """
    Maximum-likelihood calibration by damped Newton iteration (Sun & Xu 2020).

    The readings are centred and scaled to unit RMS radius first, so the iteration,
    its damping and its convergence test do not depend on the unit of the readings
    (m/s², g, counts) nor on an offset. Convergence is declared at a point where the
    full Newton step (parameters and directions) would change the objective by at
    most ``tol²`` noise variances: its Newton decrement ``delta²`` (the reduced part
    ``rhsᵀ S⁻¹ rhs`` plus the directions' part) satisfies ``delta² <= tol² sigma²``, so
    that point is within ``tol`` standard errors of the optimum in every parameter;
    or where ``delta²`` is below the roundoff of the readings (noise-free data). The
    reduced Hessian there must be positive definite (a minimum, not a saddle). The
    test is the same at 1e-7 m/s² window noise and at 0.5 m/s², in counts or in g.

    :param readings: (N, 3) raw readings (window means or samples), N >= 10.
    :param weights: (N,) relative weights, e.g. samples per window (default 1).
        The noise of observation k is sigma / sqrt(w_k).
    :param radius: magnitude of the true vectors (local gravity, same unit as readings).
    :param start: optional (T, bias) start; default the ellipsoid fit (eq. 16-18).
    :param max_iter: iteration limit.
    :param tol: largest remaining Newton step, in standard errors, that counts as
        converged.
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
    # Normalised readings by component: yt = (y_raw - centre)ᵀ / spread, so that
    # yt = (radius / spread) T u + b_n whatever the unit and offset of the readings.
    centre = np.einsum('n,ni->i', w, y_raw) / n
    yt = np.ascontiguousarray(y_raw.T)
    yt -= centre[:, None]
    spread = float(np.sqrt(np.einsum('n,n->', w, np.sum(yt * yt, axis=0)) / n))
    if not (np.isfinite(spread) and spread > 0):
        raise CalibrationError('all observations are identical (or not finite)')
    yt /= spread
    if start is None:
        T0, b0 = fit_ellipsoid_columns(yt, w)
    else:
        T0 = np.asarray(start[0], float) * (radius / spread)
        b0 = (np.asarray(start[1], float) - centre) / spread
    problem = _Problem(yt, w)
    p = pack(np.triu(T0), b0)
    u = _initial_directions(yt, unpack(p)[0], b0)
    system = problem.schur(p, u)
    trace = [system.objective]
    eps = np.finfo(float).eps
    floor = (PRECISION_FACTOR * eps) ** 2 * problem.data_energy
    damping, converged, it = 0.0, False, 0
    while True:
        # Newton decrement at the current point (Schur identity: reduced part plus the
        # directions' part): the objective change the full Newton step would make.
        f = system.objective
        try:
            dp = np.linalg.solve(system.S, system.rhs)
            decrement = float(system.rhs @ dp) + system.decrement_u
        except np.linalg.LinAlgError:
            dp, decrement = None, np.inf
        if (abs(decrement) <= tol ** 2 * 2.0 * f / (n - 9) + floor
                and _positive_definite(system.S)):
            converged = True
            break
        if it == max_iter:
            break
        it += 1
        while True:
            try:
                if damping or dp is None:
                    damping = max(damping, 1e-6)
                    damped = problem.schur(p, u, damping)
                    dp = np.linalg.solve(damped.S, damped.rhs)
                u_new, new = problem.step(p, u, dp, damping)
                f_new = new.objective
            except np.linalg.LinAlgError:
                f_new = np.inf
            # Accept any decrease, and increases no larger than the objective's roundoff.
            slack = PRECISION_FACTOR * eps * np.sqrt(2.0 * f * problem.data_energy) + floor
            if np.isfinite(f_new) and f_new <= f + slack and np.all(np.isfinite(dp)):
                break
            damping = max(damping * 10.0, 1e-6)
            if damping > 1e8:
                break
        if damping > 1e8:
            break
        p, u, system = p + dp, u_new, new
        trace.append(system.objective)
        damping = damping / 10.0 if damping > 1e-9 else 0.0
    S, f, scatter = system.S, system.objective, system.scatter
    T, b = unpack(p)
    if np.any(np.diag(T) <= 0) or not np.all(np.isfinite(p)):
        raise CalibrationError('ML iteration diverged to a non-physical T; '
                               'the observations do not constrain the model')
    check_scatter(scatter)
    dof = n - 9
    sigma2 = 2.0 * f / dof
    try:
        cov = sigma2 * np.linalg.inv(S)
    except np.linalg.LinAlgError:
        cov = np.full((9, 9), np.nan)
    unit = np.r_[np.full(6, spread / radius), np.full(3, spread)]
    cov = cov * np.outer(unit, unit)
    return MLResult(
        T=T * (spread / radius), bias=centre + b * spread, directions=u.T, covariance=cov,
        sigma=float(np.sqrt(sigma2) * spread), objective=f * spread ** 2,
        iterations=it, converged=bool(converged), seconds=time.perf_counter() - t0,
        trace=[v * spread ** 2 for v in trace])


def _positive_definite(S):
    try:
        np.linalg.cholesky(0.5 * (S + S.T))
    except np.linalg.LinAlgError:
        return False
    return True


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
