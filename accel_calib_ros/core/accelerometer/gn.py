"""
Six-parameter Gauss-Newton calibration (Gui Yi, eq. 11-17).

Model (eq. 11): ``a_i = k_i (y_i - d_i)`` for each axis i, with the constraint
``|a| = g`` (eq. 12). Gauss-Newton on the squared-norm residual of eq. 13-14,
``f_k = sum_i k_i² (y_ki - d_i)² - g²``, with the partial derivatives of eq. 15 and
the normal equations of eq. 16-17. In this package's convention ``raw = T true + bias``
that is ``T = diag(1 / k)`` and ``bias = d``.
"""

from dataclasses import dataclass, field
import time

import numpy as np

from .ml import PRECISION_FACTOR, STEP_TOLERANCE
from ..errors import CalibrationError


@dataclass(eq=False)          # arrays: equal only to itself
class GNResult:
    """
    Outcome of :func:`fit_gn`.

    :param scale: (3,) k_i of eq. 11, dimensionless true per raw (T = diag(1 / scale)).
    :param bias: (3,) d_i, reading units.
    :param covariance: (6, 6) covariance of (1/k_x, 1/k_y, 1/k_z, d_x, d_y, d_z).
    :param trace: sum of squared residuals f_k after each iteration (dimensionless:
        f_k = |k (y_k - d)|² / g² - 1).
    """

    scale: np.ndarray
    bias: np.ndarray
    covariance: np.ndarray
    iterations: int
    converged: bool
    seconds: float
    trace: list = field(default_factory=list)

    @property
    def T(self):
        """Diagonal T = diag(1 / k), readings per true unit."""
        return np.diag(1.0 / self.scale)


def _axis_aligned_start(y, w):
    """Closed-form start: algebraic fit of an axis-aligned ellipsoid, else min/max."""
    design = np.column_stack([y ** 2, 2 * y, np.ones(len(y))])
    try:
        _, _, vt = np.linalg.svd(design * np.sqrt(w)[:, None], full_matrices=False)
        coef = vt[-1]
        a, p, c = coef[:3], coef[3:6], coef[6]
        if np.all(a > 0) or np.all(a < 0):
            if a[0] < 0:
                a, p, c = -a, -p, -c
            centre = -p / a
            k = np.sum(a * centre ** 2) - c
            if k > 0:
                return np.sqrt(a / k), centre
    except np.linalg.LinAlgError:
        pass
    lo, hi = y.min(axis=0), y.max(axis=0)
    half = np.maximum((hi - lo) / 2.0, 1e-9)
    return 1.0 / half, (hi + lo) / 2.0


def fit_gn(readings, weights=None, radius=1.0, max_iter=100, tol=STEP_TOLERANCE):
    """
    Six-parameter Gauss-Newton calibration (Gui Yi 2016, eq. 11-17).

    The paper starts from bias 0 and scale 1; that start only works for readings
    already near SI units. Here the readings are first centred and scaled to unit RMS
    radius (so nothing depends on their unit or offset: m/s², g, counts), the
    iteration starts from an axis-aligned algebraic ellipsoid fit (falling back to the
    min/max of each axis) and uses Levenberg-Marquardt damping when a plain
    Gauss-Newton step does not reduce the residual. Convergence: the last undamped
    step changed the residuals f_k by at most ``tol`` noise standard deviations in
    total (sum w Δf² <= tol² sigma², i.e. below ``tol`` standard errors of every
    parameter), or by no more than their roundoff (six exact observations or
    noise-free data), and the normal matrix is positive definite.

    :param readings: (N, 3) raw readings, N >= 6 (the six faces).
    :param weights: (N,) observation weights (default 1).
    :param radius: gravity magnitude in reading units.
    :param max_iter: iteration limit.
    :param tol: largest last step, in standard errors, that counts as converged.
    :returns: GNResult.
    :raises CalibrationError: too few observations or a degenerate geometry.
    """
    t0 = time.perf_counter()
    y_raw = np.asarray(readings, dtype=float).reshape(-1, 3)
    n = len(y_raw)
    if n < 6:
        raise CalibrationError(
            f'the 6-parameter model needs at least 6 observations (six faces), got {n}')
    w = np.ones(n) if weights is None else np.asarray(weights, float).reshape(n)
    w = w / np.mean(w)
    # Normalised readings y = (y_raw - centre) / spread; the model |k (y - d)| = 1
    # there maps back to k_raw = k radius / spread, d_raw = centre + spread d.
    centre = (w @ y_raw) / n
    y = y_raw - centre
    spread = float(np.sqrt(np.sum(w * np.sum(y * y, axis=1)) / n))
    if not (np.isfinite(spread) and spread > 0):
        raise CalibrationError('all observations are identical (or not finite)')
    y /= spread
    k, d = _axis_aligned_start(y, w)

    def residual(k, d):
        return np.sum((k * (y - d)) ** 2, axis=1) - 1.0

    def jacobian(k, d):
        e = y - d
        return np.column_stack([-2.0 * e * k ** 2, 2.0 * e ** 2 * k])   # eq. 15: (d, k)

    def roundoff_scale(k, d):
        return float(np.sum(w * (1.0 + np.sum((k * (y - d)) ** 2, axis=1)) ** 2))

    eps = np.finfo(float).eps
    f = residual(k, d)
    cost = float(np.sum(w * f ** 2))
    trace, damping, converged, it = [cost], 0.0, False, 0
    dof = n - 6
    for it in range(1, max_iter + 1):
        J = jacobian(k, d)
        N = J.T @ (w[:, None] * J)                                      # a_ij, eq. 17
        g = J.T @ (w * -f)                                              # A_i, eq. 17
        scale = roundoff_scale(k, d)
        floor = (PRECISION_FACTOR * eps) ** 2 * scale
        slack = PRECISION_FACTOR * eps * np.sqrt(cost * scale) + floor
        while True:
            try:
                delta = np.linalg.solve(N + damping * np.diag(np.diag(N)), g)
            except np.linalg.LinAlgError:
                delta = np.full(6, np.nan)
            d_new, k_new = d + delta[:3], k + delta[3:]
            f_new = residual(k_new, d_new)
            cost_new = float(np.sum(w * f_new ** 2))
            if np.isfinite(cost_new) and cost_new <= cost + slack:
                break
            damping = max(damping * 10.0, 1e-6)
            if damping > 1e8:
                break
        if damping > 1e8:
            break
        change = float(delta @ N @ delta)                # sum_k w_k (J_k delta)²
        sigma2 = min(cost, cost_new) / dof if dof > 0 else 0.0
        small = not damping and change <= tol ** 2 * sigma2 + floor
        k, d, f, cost = k_new, d_new, f_new, cost_new
        trace.append(cost)
        damping = damping / 10.0 if damping > 1e-9 else 0.0
        if small:
            converged = True
            break
    if np.any(k <= 0) or not np.all(np.isfinite(np.r_[k, d])):
        raise CalibrationError('Gauss-Newton diverged: the observations do not constrain '
                               'scale and bias (record all six faces)')
    J = jacobian(k, d)
    info = J.T @ (w[:, None] * J)
    try:
        np.linalg.cholesky(info)
    except np.linalg.LinAlgError:
        converged = False
    # Six observations determine the six parameters exactly: no residual is left to
    # estimate the noise from, so the covariance is unknown (NaN), not zero.
    sigma2 = cost / dof if dof > 0 else np.nan
    try:
        cov_dk = sigma2 * np.linalg.inv(info)
    except np.linalg.LinAlgError:
        cov_dk = np.full((6, 6), np.nan)
    # Reorder to (1/k, d) and restore reading units: 1/k_raw = spread / (radius k).
    jac = np.zeros((6, 6))
    jac[:3, 3:] = np.diag(-spread / (radius * k ** 2))
    jac[3:, :3] = np.eye(3) * spread
    cov = jac @ cov_dk @ jac.T
    return GNResult(scale=k * radius / spread, bias=centre + d * spread, covariance=cov,
                    iterations=it, converged=bool(converged),
                    seconds=time.perf_counter() - t0,
                    trace=trace)
