"""
Pose advice: how good the calibration would be now, which pose to hold next, when to stop.

Everything is in the sensor frame; the poses are the 26 of :mod:`core.poses` (a cube
resting on a table: 6 faces, 12 edges at 45°, 8 corners), named by their gravity
direction (the sensor axis pointing up).

Predicted accuracy (interface §5, :func:`.accuracy.predicted_accuracy`) is the RMS
error of the corrected acceleration vector at 1 g averaged over orientations uniform
on the sphere. It is exactly the number ``accel-calib fit`` and the calibration node
report for the same windows: once the windows can determine the model, the advice
fits them with :func:`.accel.calibration.calibrate`, whose covariance comes from the
one accuracy model of :mod:`core.information` (the window means' noise taken from the
data plus a floor no averaging removes, inflated by the residual χ²/dof; for ``gn``
the cross-axis terms it cannot model are charged, so ``gn`` on six faces is never
"enough").

The next pose is the candidate that minimises the predicted accuracy after one more
window of typical weight there (A-optimal design in the metric the user asked for).
A direction within 25° of one already held is never advised while another candidate
helps. Before the
windows can determine the model the advice walks the faces (z up, z down, x up, ...)
and then adds the most informative distinct poses, so the fit becomes solvable after
the fewest windows (6 for ``gn``, 10 in 9 distinct directions for ``ml``).
"""

from dataclasses import dataclass
import math

import numpy as np

from .accuracy import predicted_accuracy
from .constants import G0
from .errors import CalibrationError, InputError
from .finite import finite_or_none
from .information import (DISTINCT_DEG, Information, NEAR_DEG, parameter_index,
                          PRIOR_WEIGHT, SIGMA_FLOOR, window_variance)
from .poses import (CANDIDATE_DIRECTIONS, CANDIDATE_NAMES, CANDIDATE_POSES, fisher_rows,
                    pose_name)

DEFAULT_TARGET = 0.01
"""Default predicted accuracy target, m/s²."""
DEFAULT_SIGMA_FLOOR = SIGMA_FLOOR
"""Error of a window mean that no averaging removes, m/s² (``core.information``)."""
MIN_WINDOWS = {'ml': 10, 'gn': 6}
MIN_DIRECTIONS = {'ml': 9, 'gn': 6}
INFLATION_NOTE = 4.0
"""Residual χ²/dof above which the advice says the windows scatter too much."""
__all__ = ['Advice', 'CANDIDATE_DIRECTIONS', 'CANDIDATE_NAMES', 'CANDIDATE_POSES',
           'DEFAULT_TARGET', 'NextPose', 'advise', 'coverage', 'fisher_rows', 'pose_name',
           'predicted_accuracy', 'true_accuracy']


# -- predicted accuracy ---------------------------------------------------------------------

def true_accuracy(T_est, bias_est, T_true, bias_true, gravity=G0):
    """
    RMS error of the corrected vector at |g| over the sphere, for known true parameters.

    :param T_est: (3, 3) estimate; ``bias_est`` (3,) m/s².
    :param T_true: (3, 3) truth; ``bias_true`` (3,) m/s².
    :return: m/s².
    """
    R = np.linalg.inv(np.asarray(T_est, float))
    M = R @ np.asarray(T_true, float) - np.eye(3)
    c = R @ (np.asarray(bias_true, float) - np.asarray(bias_est, float))
    return math.sqrt(gravity ** 2 / 3.0 * float(np.sum(M ** 2)) + float(c @ c))


# -- advice ---------------------------------------------------------------------------------

@dataclass
class NextPose:
    """
    The pose to hold next.

    :param gravity_direction: (3,) unit vector, sensor frame (the axis pointing up).
    :param name: words a person can follow.
    :param predicted_accuracy_after: m/s² once it is held (None while unsolvable).
    """

    gravity_direction: np.ndarray
    name: str
    predicted_accuracy_after: float = None

    def to_dict(self):
        """Return the interface.md §5 ``next_pose`` object."""
        after = self.predicted_accuracy_after
        return {'gravity_direction': [round(float(v), 6) for v in self.gravity_direction],
                'name': self.name,
                'predicted_accuracy_after': finite_or_none(after)}


@dataclass
class Advice:
    """
    What to do next.

    :param windows: static windows seen.
    :param predicted_accuracy: m/s², None while the windows cannot determine the model.
    :param target: m/s².
    :param enough: predicted accuracy ≤ target.
    :param next_pose: NextPose, None when enough.
    :param method: 'ml' or 'gn'.
    :param held: (26,) windows near each candidate pose.
    :param reason: why it is not solvable yet, or a warning about the data once it is.
    :param noise_inflation: residual χ²/dof factor applied to the covariance (≥ 1).
    :param directions: (N, 3) estimated unit gravity direction of each window.
    """

    windows: int
    predicted_accuracy: float
    target: float
    enough: bool
    next_pose: NextPose = None
    method: str = 'ml'
    held: np.ndarray = None
    reason: str = ''
    noise_inflation: float = 1.0
    directions: np.ndarray = None

    def to_dict(self):
        """Return exactly the §5 keys plus ``method``, ``held_poses`` and ``reason``."""
        d = {'windows': int(self.windows),
             'predicted_accuracy': finite_or_none(self.predicted_accuracy),
             'target': float(self.target), 'enough': bool(self.enough),
             'next_pose': None if self.next_pose is None else self.next_pose.to_dict(),
             'method': self.method}
        if self.held is not None:
            d['held_poses'] = {name: int(n) for name, n in zip(CANDIDATE_NAMES, self.held)
                               if n}
        if self.reason:
            d['reason'] = self.reason
        return d

    def text(self):
        """Return a few lines for people."""
        lines = [f'{self.windows} static windows']
        if self.predicted_accuracy is None:
            lines.append(f'not solvable yet: {self.reason}')
        else:
            lines.append(f'predicted accuracy {self.predicted_accuracy:.4f} m/s² '
                         f'(target {self.target:g})')
            if self.reason:
                lines.append(f'note: {self.reason}')
        if self.enough:
            lines.append('enough: fit and save the calibration now')
        elif self.next_pose is not None:
            after = self.next_pose.predicted_accuracy_after
            extra = f' (then about {after:.4f} m/s²)' if after is not None else ''
            lines.append(f'next pose: {self.next_pose.name}{extra}')
        return '\n'.join(lines)


def _check_inputs(means, weights, noise_std, gravity, method, target):
    means = np.asarray(means, float).reshape(-1, 3)
    n = len(means)
    weights = np.ones(n) if weights is None else np.asarray(weights, float).reshape(-1)
    if len(weights) != n:
        raise InputError(f'{len(weights)} weights for {n} windows')
    if not np.all(np.isfinite(means)):
        raise InputError('window means must be finite')
    if not np.all(np.isfinite(weights)) or np.any(weights <= 0):
        raise InputError('window weights must be finite and positive')
    noise = np.broadcast_to(np.asarray(noise_std, float), (3,))
    if not np.all(np.isfinite(noise)) or np.any(noise < 0):
        raise InputError('noise_std must be finite and not negative')
    if not (math.isfinite(gravity) and gravity > 0):
        raise InputError('gravity must be a positive number of m/s²')
    if method not in MIN_WINDOWS:
        raise InputError(f'advice is for method ml or gn, not {method!r}')
    if not (math.isfinite(target) and target > 0):
        raise InputError('target must be a positive number of m/s²')
    return means, weights, float(np.sqrt(np.mean(noise ** 2)))


def _held_counts(u):
    """Windows within :data:`DISTINCT_DEG` of each candidate (26,)."""
    if len(u) == 0:
        return np.zeros(len(CANDIDATE_DIRECTIONS), int)
    near = CANDIDATE_DIRECTIONS @ u.T >= math.cos(math.radians(DISTINCT_DEG))
    return near.sum(axis=1)


def coverage(directions):
    """
    Sphere coverage of unit directions (N, 3).

    :return: (3 x smallest eigenvalue of the scatter matrix: 1 for an even spread, 0 for
        a plane; number of directions at least :data:`DISTINCT_DEG` apart).
    """
    from .windows import distinct_directions
    u = np.asarray(directions, float).reshape(-1, 3)
    if len(u) == 0:
        return 0.0, 0
    scatter = u.T @ u / len(u)
    return (max(0.0, float(3.0 * np.linalg.eigvalsh(scatter)[0])),
            distinct_directions(u, DISTINCT_DEG))


def _solvable(u, method):
    """Return '' when the windows can determine ``method``'s model, else the reason."""
    from .windows import distinct_directions
    need_n, need_d = MIN_WINDOWS[method], MIN_DIRECTIONS[method]
    if len(u) < need_n:
        return f'{len(u)} windows; {method} needs {need_n} in {need_d} distinct directions'
    distinct = distinct_directions(u, DISTINCT_DEG)
    if distinct < need_d:
        return f'{distinct} distinct directions; {method} needs {need_d}'
    scatter = u.T @ u / len(u)
    if np.linalg.eigvalsh(scatter)[0] < 0.05:
        return 'the poses do not cover all three axes'
    return ''


def _accuracy(T, cov, gravity):
    """Predicted accuracy (m/s²), inf when it cannot be computed."""
    value = predicted_accuracy(T, cov, gravity)
    return value if math.isfinite(value) else math.inf


def _fit(means, weights, noise, gravity, method, floor):
    """Fit ``method`` as ``fit`` does; return the Calibration or raise CalibrationError."""
    from .accelerometer.fit import calibrate
    cal = calibrate(means, gravity, method, weights, noise_std=noise, sigma_floor=floor)
    if not (np.all(np.isfinite(cal.T)) and np.all(np.isfinite(cal.bias))) \
            or np.any(np.abs(np.diag(cal.T) - 1.0) > 0.5):
        raise CalibrationError('the fit is not physical yet')
    return cal


def advise(means, weights, noise_std, gravity=G0, method='ml', target=DEFAULT_TARGET,
           sigma_floor=None):
    """
    Predict the accuracy of the calibration so far and advise the next pose.

    :param means: (N, 3) static-window mean readings, m/s².
    :param weights: (N,) samples per window (the window means' noise is noise/√w).
    :param noise_std: (3,) or scalar per-sample noise, m/s² (within-window scatter).
    :param gravity: local gravity, m/s².
    :param method: 'ml' (9 parameters) or 'gn' (6: diagonal T and bias).
    :param target: predicted accuracy that is enough, m/s².
    :param sigma_floor: error of a window mean that does not average down, m/s²
        (default :data:`DEFAULT_SIGMA_FLOOR`).
    :return: Advice.
    :raises InputError: malformed input.
    """
    means, weights, sigma = _check_inputs(means, weights, noise_std, gravity, method,
                                          float(target))
    floor = DEFAULT_SIGMA_FLOOR if sigma_floor is None else float(sigma_floor)
    if not (math.isfinite(floor) and floor >= 0):
        raise InputError('sigma_floor must be finite and not negative')
    n = len(means)
    index = parameter_index(method)
    noise = np.full(3, sigma)
    var = window_variance(weights, noise, n, floor)
    typical_var = float(np.median(var)) if n else max(sigma ** 2 + floor ** 2, 1e-18)

    # Current estimate: the fit of ``accel-calib fit`` once solvable, else the ideal sensor.
    u = means / np.maximum(np.linalg.norm(means, axis=1, keepdims=True), 1e-12) if n \
        else np.zeros((0, 3))
    info = Information(np.eye(3), np.zeros(3), gravity, method, u,
                       fisher_rows(np.eye(3), u, gravity), var)
    reason = _solvable(u, method) if n else \
        f'no static windows yet; {method} needs {MIN_WINDOWS[method]}'
    cal = None
    if not reason:
        try:
            cal = _fit(means, weights, noise, gravity, method, floor)
            info = cal.information
            reason = _solvable(info.directions, method)
        except (CalibrationError, np.linalg.LinAlgError, ValueError) as err:
            cal, reason = None, str(err)
    u = info.directions
    held = _held_counts(u)
    solved = not reason
    current, extra = None, 0.0
    if solved:
        if info.inflation > INFLATION_NOTE:
            reason = (f'the windows scatter {math.sqrt(info.inflation):.1f}x more than their '
                      'noise (the sensor moved while held, or the model lacks an effect: '
                      + ('try method ml, ' if method == 'gn' else '') + 'run diagnose)')
        if not math.isfinite(cal.predicted_accuracy):
            solved, reason = False, 'the poses leave a parameter undetermined'
        else:
            current = cal.predicted_accuracy
            if cal.cross_axis is not None:
                from .acceptance import cross_axis_words, estimation_accuracy
                extra = cal.cross_axis.accuracy
                if extra > target and (not reason or extra >= estimation_accuracy(cal)):
                    reason = cross_axis_words(cal.cross_axis, 'use method ml')
    cand_rows = fisher_rows(info.T, CANDIDATE_DIRECTIONS, gravity)
    info.variance = np.maximum(info.variance, 1e-18)
    matrix = info.matrix
    if not solved:
        matrix = matrix + (cand_rows.T @ cand_rows) * PRIOR_WEIGHT / typical_var
    probe = Information(info.T, info.bias, gravity, method, u, info.rows, info.variance,
                        info.inflation if solved else 1.0)
    if not n:
        probe.variance = np.array([typical_var])
        probe.rows = np.zeros((1, 9))
    after = np.sqrt(probe.accuracy_after(cand_rows, matrix) ** 2 + extra ** 2)
    exact = np.full(len(CANDIDATE_DIRECTIONS), math.inf)
    if not solved and n + 1 >= MIN_WINDOWS[method]:
        # The accuracy once this pose makes the model solvable (no prior), if it does.
        for k, h in enumerate(cand_rows):
            if _solvable(np.vstack([u, CANDIDATE_DIRECTIONS[k]]), method):
                continue
            cov = probe.covariance(info.matrix + np.outer(h, h) / typical_var)
            if cov is not None:
                exact[k] = _accuracy(info.T, cov, gravity)
    enough = bool(solved and current is not None and current <= target)
    if enough and n - len(index) < 1:
        # As many windows as parameters fit exactly: nothing checks the noise level or
        # the model yet (a 6-face gn session would look perfect whatever the sensor).
        enough = False
        reason = 'one more window checks the noise level and the model'
    next_pose = None
    if not enough:
        choice = _choose(after, u)
        if not solved:             # the walk of the refusals (check_geometry) before a solve
            from .accelerometer.fit import geometry_poses
            poses = geometry_poses(means, method, 1, weights, noise, floor) if n else []
            choice = CANDIDATE_NAMES.index(poses[0][0]) if poses else 0
        elif cal.cross_axis is not None and cal.cross_axis.poses:
            choice = CANDIDATE_NAMES.index(cal.cross_axis.poses[0])   # measure what gn lacks
        value = after[choice] if solved else exact[choice]
        next_pose = NextPose(CANDIDATE_DIRECTIONS[choice].copy(), CANDIDATE_NAMES[choice],
                             finite_or_none(value))
    return Advice(windows=n, predicted_accuracy=current, target=float(target), enough=enough,
                  next_pose=next_pose, method=method, held=held, reason=reason,
                  noise_inflation=info.inflation if solved else 1.0, directions=u)


def _choose(after, directions):
    """
    Index of the candidate to advise once the model is solvable.

    The most informative candidate not within :data:`core.information.NEAR_DEG` of a
    direction already held (a message never asks for what is there), unless none is.
    """
    allowed = np.arange(len(after))
    if len(directions):
        cos_near = math.cos(math.radians(NEAR_DEG))
        allowed = np.flatnonzero((CANDIDATE_DIRECTIONS @ directions.T).max(axis=1) < cos_near)
    if len(allowed) and np.isfinite(after[allowed]).any():
        return int(allowed[np.argmin(after[allowed])])
    return int(np.argmin(after))
