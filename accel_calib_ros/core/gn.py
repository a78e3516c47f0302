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

from .errors import CalibrationError


@dataclass
class GNResult:
    """
    Outcome of :func:`fit_gn`.

    :param scale: (3,) k_i of eq. 11, dimensionless true per raw (T = diag(1 / scale)).
    :param bias: (3,) d_i, reading units.
    :param covariance: (6, 6) covariance of (1/k_x, 1/k_y, 1/k_z, d_x, d_y, d_z).
    :param trace: sum of squared residuals f_k after each iteration.
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


def fit_gn(readings, weights=None, radius=1.0, max_iter=100, tol=1e-12):
    """
    Six-parameter Gauss-Newton calibration (Gui Yi 2016, eq. 11-17).

    The paper starts from bias 0 and scale 1; that start only works for readings
    already near SI units, so the iteration here starts from an axis-aligned
    algebraic ellipsoid fit (falling back to the min/max of each axis) and uses
    Levenberg-Marquardt damping when a plain Gauss-Newton step does not reduce the
    residual.

    :param readings: (N, 3) raw readings, N >= 6 (the six faces).
    :param weights: (N,) observation weights (default 1).
    :param radius: gravity magnitude in reading units.
    :returns: GNResult.
    :raises CalibrationError: too few observations or a degenerate geometry.
    """
    t0 = time.perf_counter()
    y = np.asarray(readings, dtype=float).reshape(-1, 3) / radius
    n = len(y)
    if n < 6:
        raise CalibrationError(
            f'the 6-parameter model needs at least 6 observations (six faces), got {n}')
    w = np.ones(n) if weights is None else np.asarray(weights, float).reshape(n)
    w = w / np.mean(w)
    k, d = _axis_aligned_start(y, w)

    def residual(k, d):
        return np.sum((k * (y - d)) ** 2, axis=1) - 1.0

    def jacobian(k, d):
        e = y - d
        return np.column_stack([-2.0 * e * k ** 2, 2.0 * e ** 2 * k])   # eq. 15: (d, k)

    f = residual(k, d)
    cost = float(np.sum(w * f ** 2))
    trace, damping, converged, it = [cost], 0.0, False, 0
    for it in range(1, max_iter + 1):
        J = jacobian(k, d)
        N = J.T @ (w[:, None] * J)                                      # a_ij, eq. 17
        g = J.T @ (w * -f)                                              # A_i, eq. 17
        while True:
            try:
                delta = np.linalg.solve(N + damping * np.diag(np.diag(N)), g)
            except np.linalg.LinAlgError:
                delta = np.full(6, np.nan)
            d_new, k_new = d + delta[:3], k + delta[3:]
            f_new = residual(k_new, d_new)
            cost_new = float(np.sum(w * f_new ** 2))
            if np.isfinite(cost_new) and cost_new <= cost * (1 + 1e-12) + 1e-300:
                damping = damping / 10.0 if damping > 1e-9 else 0.0
                break
            damping = max(damping * 10.0, 1e-6)
            if damping > 1e8:
                break
        if damping > 1e8:
            break
        small = np.linalg.norm(delta) <= np.sqrt(tol) * (1 + np.linalg.norm(np.r_[k, d]))
        flat = cost - cost_new <= tol * max(cost, 1e-300)
        k, d, f, cost = k_new, d_new, f_new, cost_new
        trace.append(cost)
        if small and flat:
            converged = True
            break
    if np.any(k <= 0) or not np.all(np.isfinite(np.r_[k, d])):
        raise CalibrationError('Gauss-Newton diverged: the observations do not constrain '
                               'scale and bias (record all six faces)')
    J = jacobian(k, d)
    info = J.T @ (w[:, None] * J)
    # Six observations determine the six parameters exactly: no residual is left to
    # estimate the noise from, so the covariance is unknown (NaN), not zero.
    sigma2 = cost / (n - 6) if n > 6 else np.nan
    try:
        cov_dk = sigma2 * np.linalg.inv(info)
    except np.linalg.LinAlgError:
        cov_dk = np.full((6, 6), np.nan)
    # Reorder to (1/k, d) and restore reading units.
    jac = np.zeros((6, 6))
    jac[:3, 3:] = np.diag(-1.0 / k ** 2)
    jac[3:, :3] = np.eye(3) * radius
    cov = jac @ cov_dk @ jac.T
    return GNResult(scale=k, bias=d * radius, covariance=cov, iterations=it,
                    converged=converged, seconds=time.perf_counter() - t0,
                    trace=[c * radius ** 4 for c in trace])
