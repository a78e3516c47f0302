"""
What static windows tell about a calibration: covariance, accuracy, cross-axis, poses.

Its covariance, its predicted accuracy, the cross-axis allowance of ``gn`` and the poses
that would add most.

This is the one accuracy model of ``fit``, the calibration node, ``advise`` and
``diagnose`` (through :func:`core.accelerometer.fit.calibrate`), and the one source of
the poses their refusals and advice name.

**Noise of a window mean** (m/s² per axis): ``var_k = sigma² / w_k + floor²``, with sigma
the per-sample noise measured inside the windows, ``w_k`` the samples behind the mean
(capped at a few seconds by the callers; 1 for single samples) and ``floor`` what no
averaging removes (:data:`SIGMA_FLOOR`: bias instability, the hand). When the windows
scatter about the fit more than that (χ²/dof > 1) the covariance is inflated by χ²/dof,
so data that disagree with the model never look better than they are.

**Covariance**: the information rows ``h_k`` of :func:`core.poses.fisher_rows` at the
fitted T and the fitted gravity direction of each window, restricted to the parameters
the method fits (``gn``: diagonal T and bias), ``C = inflation · (Σ h hᵀ / var_k)⁻¹``.
The predicted accuracy (interface §5) is ``sqrt(tr(M C))`` with ``M`` of
:func:`core.accuracy.sphere_average_matrix`.

**Cross-axis allowance** (``gn`` only): ``gn`` holds the three cross-axis terms of T
at zero, and what that costs is always charged: for each term the posterior mean square
``m² + s²`` given a Gaussian prior from the datasheet (cross-axis sensitivity ±2 %,
:data:`CROSS_AXIS_BOUND`, taken as uniform: RMS 2 %/√3) and the 9-parameter (ML)
information of the same windows. When the windows measure a term (ML identifiable,
9 or more distinct orientations), ``m`` is the ML estimate shrunk by the prior;
otherwise ``m = 0`` and ``s`` is the prior. So ``gn`` never becomes more confident
with fewer orientations. No pose removes a cross-axis error that ``gn`` cannot model
(before it is measured its expected charge is the prior whatever is held next), so
the poses advised for ``gn`` are ranked by the part they can lower.

**Poses to add**: the candidate (the 26 cube poses of :mod:`core.poses`) whose one more
window of typical weight lowers the predicted accuracy most (a Sherman-Morrison update
of the covariance: all candidates cost one inverse), never one within
:data:`NEAR_DEG` of a direction already held; greedily, for several poses. While the
windows cannot yet determine the model a weak prior over all candidates ranks them.
numpy only.
"""

from dataclasses import dataclass
import math

import numpy as np

from .accuracy import sphere_average_matrix
from .constants import G0
from .poses import CANDIDATE_DIRECTIONS, CANDIDATE_NAMES, FACE_COUNT, fisher_rows

SIGMA_FLOOR = 1e-3
"""Error of a window mean that no averaging removes, m/s² (about 0.1 mg: bias
instability of a consumer MEMS accelerometer over a session, a hand on a table)."""
CROSS_AXIS_BOUND = 0.02
"""Datasheet cross-axis sensitivity bound (MPU-9250: ±2 %), dimensionless."""
CROSS_AXIS_PRIOR = CROSS_AXIS_BOUND / math.sqrt(3.0)
"""RMS of one cross-axis term of T under the datasheet bound taken as uniform."""
CROSS_AXIS_INDEX = (1, 2, 4)
"""T_xy, T_xz, T_yz in the 9-parameter order (``core.calibration.PARAMETER_NAMES``)."""
CROSS_AXIS_PAIRS = ('xy', 'xz', 'yz')
GN_INDEX = (0, 3, 5, 6, 7, 8)
"""T_xx, T_yy, T_zz, b: the parameters of the 6-parameter ``gn`` model."""
NEAR_DEG = 25.0
"""A pose within this angle of a direction already held is never advised."""
DISTINCT_DEG = 15.0
"""Two windows closer than this are the same orientation."""
PRIOR_WEIGHT = 1e-3
"""Weight, in typical windows, of the weak all-candidate prior used before a solve."""
MAX_INFORMATION_CONDITION = 1e12
"""Condition number (of the scaled information) beyond which a parameter is undetermined."""


def parameter_index(method):
    """Return the indices of the parameters ``method`` fits, in the 9-parameter order."""
    return list(GN_INDEX) if method == 'gn' else list(range(9))


def _inverse(matrix):
    """Invert a symmetric positive matrix; None when singular or ill-conditioned."""
    if not np.all(np.isfinite(matrix)):
        return None
    scale = np.sqrt(np.maximum(np.diag(matrix), 1e-300))
    normed = matrix / np.outer(scale, scale)
    with np.errstate(all='ignore'):
        if not np.linalg.cond(normed) <= MAX_INFORMATION_CONDITION:
            return None
        return np.linalg.inv(normed) / np.outer(scale, scale)


def window_variance(weights, noise_std, count, floor=None):
    """
    Return the variance of each window mean, (m/s²)², shape (count,).

    :param weights: (N,) samples behind each mean (capped), or None for single samples.
    :param noise_std: (3,) or scalar per-sample noise, m/s², or None (unknown: 0).
    :param floor: error no averaging removes, m/s² (default :data:`SIGMA_FLOOR`).
    """
    w = np.ones(count) if weights is None else np.asarray(weights, float).reshape(count)
    sigma = 0.0
    if noise_std is not None:
        noise = np.asarray(noise_std, float)
        if np.all(np.isfinite(noise)):
            sigma = float(np.sqrt(np.mean(np.square(noise))))
    floor = SIGMA_FLOOR if floor is None else float(floor)
    return np.maximum(sigma ** 2 / np.maximum(w, 1e-300) + floor ** 2, 1e-18)


@dataclass(eq=False)          # arrays: equal only to itself
class Information:
    """
    The information static windows hold about a calibration (see the module docstring).

    :param T: (3, 3) fitted T; ``bias`` (3,) m/s²; ``gravity`` m/s²; ``method``.
    :param directions: (N, 3) fitted unit gravity direction of each window.
    :param rows: (N, 9) information rows per unit noise.
    :param variance: (N,) variance of each window mean (not inflated), (m/s²)².
    :param inflation: residual χ²/dof factor on the covariance (≥ 1).
    """

    T: np.ndarray
    bias: np.ndarray
    gravity: float
    method: str
    directions: np.ndarray
    rows: np.ndarray
    variance: np.ndarray
    inflation: float = 1.0

    @property
    def index(self):
        """Return the indices of the fitted parameters."""
        return parameter_index(self.method)

    @property
    def matrix(self):
        """Return the information (9, 9) of all 9 parameters, not inflated."""
        return (self.rows / self.variance[:, None]).T @ self.rows

    @property
    def typical_variance(self):
        """Return the variance of a window of typical (median) weight, (m/s²)²."""
        return float(np.median(self.variance)) if len(self.variance) else 1.0

    def covariance(self, matrix=None):
        """
        Covariance (9, 9) of the fitted parameters, inflated; zero outside them.

        :param matrix: information to invert instead of :attr:`matrix`.
        :return: (9, 9), or None when the windows leave a parameter undetermined.
        """
        index = self.index
        info = self.matrix if matrix is None else matrix
        inverse = _inverse(info[np.ix_(index, index)])
        if inverse is None:
            return None
        cov = np.zeros((9, 9))
        cov[np.ix_(index, index)] = self.inflation * inverse
        return cov

    def distinct(self):
        """Return the number of distinct orientations (:data:`DISTINCT_DEG` apart)."""
        from .windows import distinct_directions
        return distinct_directions(self.directions, DISTINCT_DEG) if len(self.directions) \
            else 0

    def accuracy_after(self, rows, matrix=None):
        """
        Predicted accuracy (fitted parameters only) after one more window at each row, m/s².

        :param rows: (K, 9) information rows of the candidates.
        :param matrix: current information (default :attr:`matrix`).
        :return: (K,) m/s², inf where the information cannot be inverted.
        """
        index = self.index
        info = self.matrix if matrix is None else matrix
        C = _inverse(info[np.ix_(index, index)])
        if C is None:
            return np.full(len(rows), math.inf)
        M = sphere_average_matrix(self.T, self.gravity)[np.ix_(index, index)]
        H = np.asarray(rows, float)[:, index]
        CH = H @ C
        denom = self.typical_variance + np.einsum('ij,ij->i', H, CH)
        reduction = np.einsum('ij,jk,ik->i', CH, M, CH) / denom
        value = self.inflation * (float(np.sum(M * C)) - reduction)
        return np.sqrt(np.maximum(value, 0.0))


def information(readings, T, bias, gravity=G0, method='ml', weights=None,
                noise_std=None, floor=None):
    """
    Return the information of window means (or samples) about a fitted calibration.

    :param readings: (N, 3) observations, m/s².
    :param T: (3, 3) fitted T; ``bias`` (3,) fitted bias, m/s².
    :param gravity: local gravity, m/s².
    :param method: 'ml', 'ml-bc', 'ellipsoid' (9 parameters) or 'gn' (6).
    :param weights: (N,) samples behind each observation (capped), or None.
    :param noise_std: (3,) per-sample noise, m/s², or None.
    :param floor: see :func:`window_variance` (m/s² of true acceleration: readings in
        other units, e.g. raw counts, get it scaled by T).
    :return: :class:`Information`.
    """
    y = np.asarray(readings, float).reshape(-1, 3)
    T = np.asarray(T, float).reshape(3, 3)
    bias = np.asarray(bias, float).reshape(3)
    x = np.linalg.solve(T, (y - bias).T).T
    u = x / np.maximum(np.linalg.norm(x, axis=1, keepdims=True), 1e-300)
    # The floor is m/s² of true acceleration: in reading units it scales with T (counts).
    scale = float(abs(np.linalg.det(T))) ** (1.0 / 3.0)
    floor = (SIGMA_FLOOR if floor is None else float(floor)) * (scale if scale > 0 else 1.0)
    var = window_variance(weights, noise_std, len(y), floor)
    info = Information(T, bias, float(gravity), method, u, fisher_rows(T, u, gravity), var)
    dof = len(y) - len(info.index)
    if dof >= 1:
        resid = y - (gravity * u) @ T.T - bias
        chi2 = float(np.sum(np.einsum('ij,ij->i', resid, resid) / var))
        info.inflation = max(1.0, chi2 / dof)
    return info


@dataclass(eq=False)          # arrays: equal only to itself
class CrossAxis:
    """
    What the cross-axis terms that ``gn`` holds at zero cost (see the module docstring).

    :param values: (3,) posterior mean of T_xy, T_xz, T_yz (0 where not measured).
    :param std: (3,) their posterior standard deviation.
    :param measured: (3,) whether the windows measure each term (not the prior).
    :param accuracy: its share of the predicted accuracy, m/s² (RMS over orientations).
    :param distinct: distinct orientations among the windows.
    :param ml_accuracy: predicted accuracy of the 9-parameter (ml) fit of the same
        windows, m/s², or None when they cannot determine it.
    :param poses: names of the poses that would measure the terms not measured yet
        (best first; empty when all are measured).
    :param covariance: (9, 9) second moment of the error they cause in the gn fit
        (the terms themselves and what they alias into its scale and bias).
    """

    values: np.ndarray
    std: np.ndarray
    measured: np.ndarray
    accuracy: float
    distinct: int
    ml_accuracy: float = None
    poses: tuple = ()
    covariance: np.ndarray = None

    @property
    def mean_square(self):
        """Return the (3,) posterior mean square of each term."""
        return self.values ** 2 + self.std ** 2

    @property
    def source(self):
        """Say where the charge comes from, in words."""
        if self.measured.all():
            return (f'measured by the ml fit of the same windows, {self.distinct} distinct '
                    'orientations')
        bound = f'the datasheet bound ±{CROSS_AXIS_BOUND:.0%}'
        if not self.measured.any():
            return f'{bound} (these {self.distinct} distinct orientations cannot measure them)'
        unmeasured = ', '.join(p for p, m in zip(CROSS_AXIS_PAIRS, self.measured) if not m)
        return (f'{bound} for {unmeasured}, which the poses do not determine (the others '
                'measured by the ml fit of the same windows)')

    def largest_deg(self):
        """Return the largest measured cross-axis angle, degrees (0 when none is)."""
        measured = np.abs(self.values[self.measured])
        return float(np.degrees(np.arcsin(min(measured.max(), 1.0)))) if len(measured) \
            else 0.0

    def to_dict(self):
        """Return a JSON-ready summary."""
        return {'accuracy_m_s2': float(self.accuracy), 'source': self.source,
                'distinct_orientations': int(self.distinct),
                'ml_predicted_accuracy_m_s2': self.ml_accuracy,
                'terms': {p: {'value': float(v), 'std': float(s), 'measured': bool(m)}
                          for p, v, s, m in zip(CROSS_AXIS_PAIRS, self.values, self.std,
                                                self.measured)}}


def cross_axis_allowance(info, readings, weights=None, noise_std=None, floor=None):
    """
    Return the cost of the cross-axis terms a ``gn`` fit holds at zero.

    :param info: :class:`Information` of the ``gn`` fit.
    :param readings: (N, 3) the same observations, m/s² (for the ML fit).
    :param weights: (N,) as for :func:`information`.
    :param noise_std: (3,) per-sample noise, m/s², or None.
    :return: :class:`CrossAxis`.
    """
    from .errors import CalibrationError
    distinct = info.distinct()
    base, ml_T, ml_accuracy = info, None, None
    if distinct >= 9:
        try:
            from .accelerometer.ml import fit_ml
            fit = fit_ml(readings, weights, info.gravity)
            if fit.converged and np.all(np.isfinite(fit.T)):
                ml_T = fit.T
                base = information(readings, fit.T, fit.bias, info.gravity, 'ml', weights,
                                   noise_std, floor)
                ml_cov = base.covariance()
                if ml_cov is not None:
                    ml_accuracy = float(np.sqrt(max(np.sum(
                        sphere_average_matrix(fit.T, info.gravity) * ml_cov), 0.0)))
        except (CalibrationError, np.linalg.LinAlgError, ValueError):
            ml_T = None
    k = list(CROSS_AXIS_INDEX)
    data = base.matrix / base.inflation
    posterior = data.copy()
    posterior[k, k] += 1.0 / CROSS_AXIS_PRIOR ** 2
    post_cov = _inverse(posterior) if ml_T is not None else None
    if post_cov is None:            # not measurable here: the datasheet prior, unreduced
        std = np.full(3, CROSS_AXIS_PRIOR)
    else:
        std = np.sqrt(np.minimum(np.diag(post_cov)[k], CROSS_AXIS_PRIOR ** 2))
    values, measured = np.zeros(3), std < CROSS_AXIS_PRIOR / math.sqrt(2.0)
    data_cov = _inverse(data) if ml_T is not None else None
    if data_cov is not None:
        v = np.diag(data_cov)[k]
        values = ml_T[np.triu_indices(3, 1)] * np.minimum(std ** 2 / np.maximum(v, 1e-300),
                                                          1.0)
    else:
        measured[:] = False
    covariance = _misfit_covariance(info, values, std)
    M = sphere_average_matrix(info.T, info.gravity)
    accuracy = math.sqrt(max(float(np.sum(M * covariance)), 0.0))
    poses = ()
    if not measured.all():          # the poses that determine the 9-parameter model
        ml_info = Information(base.T, base.bias, base.gravity, 'ml', base.directions,
                              base.rows, base.variance, base.inflation)
        poses = tuple(name for name, _, _ in poses_to_add(ml_info, 3))
    return CrossAxis(values, std, measured, accuracy, distinct, ml_accuracy, poses, covariance)


def _misfit_covariance(info, values, std):
    """
    Second moment (9, 9) of the error the cross-axis terms c cause in a ``gn`` fit.

    gn fits the diagonal terms d with c held at zero, so to first order it returns
    ``d + A c`` (A the alias matrix of the weighted least squares: what the misfit of c
    does to d on these windows) and ``0`` for c: its error is ``L c`` with ``L = [A; -I]``,
    whose second moment is ``L E[c cᵀ] Lᵀ`` with ``E[c cᵀ] = m mᵀ + diag(s²)``. On a
    balanced design (the six faces, all 26 poses) A is zero; on a lopsided one the
    cross-axis terms also spoil the scale and bias gn reports.
    """
    gn, k = list(GN_INDEX), list(CROSS_AXIS_INDEX)
    weights = 1.0 / info.variance[:, None]
    Hd, Hc = info.rows[:, gn], info.rows[:, k]
    inverse = _inverse(Hd.T @ (weights * Hd))
    alias = np.zeros((6, 3)) if inverse is None else inverse @ (Hd.T @ (weights * Hc))
    L = np.zeros((9, 3))
    L[gn] = alias
    L[k] = -np.eye(3)
    second = np.outer(values, values) + np.diag(std ** 2)
    return L @ second @ L.T


def poses_to_add(info, count=3, near_deg=NEAR_DEG, extra=0.0, faces_first=False):
    """
    Return the poses that would lower the predicted accuracy most, best first (greedy).

    :param info: :class:`Information` of the windows so far.
    :param count: at most this many poses.
    :param near_deg: never a pose within this angle of a direction already held (or
        advised before it in the list).
    :param extra: predicted-accuracy share no pose lowers (the ``gn`` cross-axis
        allowance), m/s²; added in quadrature to the reported values.
    :param faces_first: first the faces no window is near (z up, z down, x up, x down,
        y up, y down: the walk of the advice before a solve), then the greedy choice.
    :return: list of (name, direction (3,), predicted accuracy m/s² once this pose and
        the ones before it are held, or None while the model stays undetermined).
    """
    cand = fisher_rows(info.T, CANDIDATE_DIRECTIONS, info.gravity)
    index = info.index
    actual = info.matrix
    prior = np.zeros((9, 9))
    if _inverse(actual[np.ix_(index, index)]) is None:
        prior = (cand.T @ cand) * PRIOR_WEIGHT / info.typical_variance
    held = [np.asarray(d, float) for d in info.directions]
    cos_near = math.cos(math.radians(near_deg))
    out = []
    for _ in range(count):
        after = info.accuracy_after(cand, actual + prior)
        if held:
            near = (CANDIDATE_DIRECTIONS @ np.array(held).T).max(axis=1) >= cos_near
            after = np.where(near, math.inf, after)
        if not np.isfinite(after).any():
            break
        k = int(np.argmin(after))
        if faces_first and np.isfinite(after[:FACE_COUNT]).any():
            k = int(np.flatnonzero(np.isfinite(after[:FACE_COUNT]))[0])
        h = cand[k]
        actual = actual + np.outer(h, h) / info.typical_variance
        cov = info.covariance(actual)
        value = None
        if cov is not None:
            M = sphere_average_matrix(info.T, info.gravity)
            value = math.sqrt(max(float(np.sum(M * cov)), 0.0) + extra ** 2)
        out.append((CANDIDATE_NAMES[k], CANDIDATE_DIRECTIONS[k].copy(), value))
        held.append(CANDIDATE_DIRECTIONS[k])
    return out


def words(poses, limit=None):
    """
    Return the poses of :func:`poses_to_add` in words: 'A (then about X m/s²), then B'.

    :param limit: mention the predicted accuracy once it is at most this, m/s².
    """
    parts = []
    for name, _, value in poses:
        if value is not None and (limit is None or value <= limit or not parts):
            parts.append(f'{name} (then about {value:.3g} m/s²)')
        else:
            parts.append(name)
    return ', then '.join(parts)
