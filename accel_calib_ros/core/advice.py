"""
Pose advice: how good the calibration would be now, which pose to hold next, when to stop.

Everything is in the sensor frame. A *pose* is named by its gravity direction: the unit
vector along which the accelerometer reads +1 g while the pose is held (the sensor axis
pointing up). The poses a person can hold without a fixture are the 26 of a cube
resting on a table: 6 faces, 12 edges at 45° and 8 corners (:data:`CANDIDATE_POSES`).

Predicted accuracy (interface §5, :func:`.accuracy.predicted_accuracy`) is the RMS
error of the corrected acceleration vector at 1 g averaged over orientations uniform
on the sphere, propagated from the covariance of (T, bias). Here the covariance is
the Cramér-Rao bound of the ML model at the current estimate (the fit's own
covariance near the optimum), with the noise
of each window mean taken from the data: the within-window scatter divided by the
window's samples, plus a small floor for what does not average down (bias
instability, the hand), and inflated by the residual χ²/dof when the windows scatter
more than that (untrustworthy data never look better than they are).

The next pose is the candidate that minimises the predicted accuracy after one more
window of typical weight there (A-optimal design in the metric the user asked for).
A direction already held twice is skipped while another candidate helps. Before the
windows can determine the model the advice walks the faces (z up, z down, x up, ...)
and then adds the most informative distinct poses, so the fit becomes solvable after
the fewest windows (6 for ``gn``, 10 in 9 distinct directions for ``ml``).
"""

from dataclasses import dataclass
import math

import numpy as np

from .accuracy import predicted_accuracy
from .errors import CalibrationError, InputError

G0 = 9.80665
DEFAULT_TARGET = 0.01
"""Default predicted accuracy target, m/s²."""
DEFAULT_SIGMA_FLOOR = 1e-3
"""Error of a window mean that no averaging removes, m/s² (about 0.1 mg: bias
instability of a consumer MEMS accelerometer over a session, a hand on a table)."""
DISTINCT_DEG = 15.0
"""Two windows closer than this are the same direction (matches check_geometry)."""
HELD_LIMIT = 2
"""A direction held this often is advised again only when no other one helps."""
PRIOR_WEIGHT = 1e-3
"""Weight, in typical windows, of the weak all-candidate prior used before a solve."""
MIN_WINDOWS = {'ml': 10, 'gn': 6}
MIN_DIRECTIONS = {'ml': 9, 'gn': 6}
GN_PARAMETERS = (0, 3, 5, 6, 7, 8)
"""Indices of T_xx, T_yy, T_zz, b in the 9-parameter order (the ``gn`` model)."""
INFLATION_NOTE = 4.0
"""Residual χ²/dof above which the advice says the windows scatter too much."""
_UPPER = np.triu_indices(3)


def _cube_poses():
    """Return the 26 cube poses: faces first (z up, z down, x, y), then edges, corners."""
    faces = [(0, 0, 1), (0, 0, -1), (1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0)]
    edges, corners = [], []
    for x in (1, -1, 0):
        for y in (1, -1, 0):
            for z in (1, -1, 0):
                nonzero = abs(x) + abs(y) + abs(z)
                if nonzero == 2:
                    edges.append((x, y, z))
                elif nonzero == 3:
                    corners.append((x, y, z))
    poses = faces + edges + corners
    return tuple(np.array(v, float) / np.linalg.norm(v) for v in poses), tuple(poses)


_POSE_VECTORS, _POSE_CODES = _cube_poses()
CANDIDATE_DIRECTIONS = np.array(_POSE_VECTORS)
"""(26, 3) unit gravity directions of the candidate poses: faces, 45° edges, corners."""


def _axis_words(code):
    axes = [(('+' if c > 0 else '-') + a) for c, a in zip(code, 'xyz') if c]
    n = len(axes)
    if n == 1:
        sign, axis = axes[0][0], axes[0][1]
        return f'{axis} axis {"up" if sign == "+" else "down"}'
    if n == 2:
        first, second = axes
        if first[0] == '-' and second[0] == '+':
            first, second = second, first
        if first[0] == '+':
            return f'{first[1]} axis up, tilted 45° toward {second}'
        return f'{first} axis up, tilted 45° toward {second}'
    return 'corner: ' + ' '.join(axes) + ' up'


CANDIDATE_NAMES = tuple(_axis_words(c) for c in _POSE_CODES)
CANDIDATE_POSES = tuple(zip(CANDIDATE_DIRECTIONS, CANDIDATE_NAMES))
"""(direction (3,), name) of the 26 poses a person can hold: 6 faces, 12 edges, 8 corners."""
FACE_COUNT = 6


def pose_name(direction):
    """
    Words for the pose whose gravity direction (sensor axis up) is ``direction``.

    The nearest of :data:`CANDIDATE_POSES` is named; a direction more than 10° from
    every candidate is prefixed with 'about'.

    :param direction: (3,) vector in the sensor frame (any length > 0).
    :return: e.g. 'z axis up', 'x axis up, tilted 45° toward +y', 'corner: +x +y +z up'.
    """
    v = np.asarray(direction, float).reshape(3)
    norm = np.linalg.norm(v)
    if not np.isfinite(norm) or norm == 0.0:
        raise InputError('a pose direction must be a finite non-zero vector')
    cosines = CANDIDATE_DIRECTIONS @ (v / norm)
    best = int(np.argmax(cosines))
    name = CANDIDATE_NAMES[best]
    if cosines[best] < math.cos(math.radians(10.0)):
        name = 'about ' + name
    return name


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


def fisher_rows(T, directions, gravity=G0):
    """
    Information rows of window means in the 9 ML parameters, per unit noise.

    A window at unit direction ``u`` measures ``y = T (g u) + b``; only the error along
    the ellipsoid normal ``n ∝ T⁻ᵀ u`` informs the parameters (the tangential part is
    absorbed by ``u``), so its Fisher information is ``h hᵀ / σ²`` with ``h = Gᵀ n``.

    :param T: (3, 3) current estimate.
    :param directions: (N, 3) unit gravity directions.
    :return: (N, 9) rows ``h``.
    """
    u = np.asarray(directions, float).reshape(-1, 3)
    n = np.linalg.solve(np.asarray(T, float).T, u.T).T
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    rows, cols = _UPPER
    h = np.empty((len(u), 9))
    h[:, :6] = n[:, rows] * gravity * u[:, cols]
    h[:, 6:] = n
    return h


def _accuracy(T, cov, gravity):
    """Predicted accuracy (m/s²), inf when it cannot be computed."""
    value = predicted_accuracy(T, cov, gravity)
    return value if math.isfinite(value) else math.inf


def _accuracy_after(T, info, rows, var, index, inflation, gravity):
    """
    Predicted accuracy after one more window along each candidate, (K,) m/s².

    One window adds ``h hᵀ / var`` to the information; the new covariance follows from
    the current one by the Sherman-Morrison formula, so all candidates cost one inverse.
    """
    from .accuracy import sphere_average_matrix
    cov = _covariance(info, index)
    if cov is None:
        return np.full(len(rows), math.inf)
    C = cov[np.ix_(index, index)]
    M = sphere_average_matrix(T, gravity)[np.ix_(index, index)]
    H = rows[:, index]
    CH = H @ C
    denom = var + np.einsum('ij,ij->i', H, CH)
    reduction = np.einsum('ij,jk,ik->i', CH, M, CH) / denom
    value = inflation * (float(np.sum(M * C)) - reduction)
    return np.sqrt(np.maximum(value, 0.0))


def _covariance(info, index):
    """Invert the information restricted to ``index``; embed in (9, 9); None if singular."""
    sub = info[np.ix_(index, index)]
    if not np.all(np.isfinite(sub)):
        return None
    scale = np.sqrt(np.maximum(np.diag(sub), 1e-300))
    normed = sub / np.outer(scale, scale)
    if np.linalg.cond(normed) > 1e12:
        return None
    cov = np.zeros((9, 9))
    cov[np.ix_(index, index)] = np.linalg.inv(normed) / np.outer(scale, scale)
    return cov


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
        """Return the spec §5 ``next_pose`` object."""
        after = self.predicted_accuracy_after
        return {'gravity_direction': [round(float(v), 6) for v in self.gravity_direction],
                'name': self.name,
                'predicted_accuracy_after': _finite_or_none(after)}


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
        """Return exactly the spec §5 keys plus ``method``, ``held_poses`` and ``reason``."""
        d = {'windows': int(self.windows),
             'predicted_accuracy': _finite_or_none(self.predicted_accuracy),
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


def _finite_or_none(value):
    if value is None:
        return None
    value = float(value)
    return value if math.isfinite(value) else None


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


def _estimate(means, weights, gravity, method):
    """Fit ``method``; return (T, bias, unit directions) or raise CalibrationError."""
    if method == 'gn':
        from .accel.gn import fit_gn
        fit = fit_gn(means, weights, gravity)
        T, bias = fit.T, fit.bias
    else:
        from .accel.ml import fit_ml
        fit = fit_ml(means, weights, gravity, max_iter=60)
        T, bias = fit.T, fit.bias
    if not (np.all(np.isfinite(T)) and np.all(np.isfinite(bias))) \
            or np.any(np.abs(np.diag(T) - 1.0) > 0.5):
        raise CalibrationError('the fit is not physical yet')
    u = np.linalg.solve(T, (means - bias).T).T
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return T, bias, u


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
    index = list(range(9)) if method == 'ml' else list(GN_PARAMETERS)
    var_k = sigma ** 2 / weights + floor ** 2          # variance of each window mean
    var_k = np.maximum(var_k, 1e-18)
    typical_w = float(np.median(weights)) if n else 1.0
    typical_var = max(sigma ** 2 / typical_w + floor ** 2, 1e-18)

    # Current estimate: a fit once solvable, else the ideal sensor.
    T, bias, u, reason, inflation = np.eye(3), np.zeros(3), None, '', 1.0
    if n:
        u0 = means / np.maximum(np.linalg.norm(means, axis=1, keepdims=True), 1e-12)
        reason = _solvable(u0, method)
        u = u0
        if not reason:
            try:
                T, bias, u = _estimate(means, weights, gravity, method)
                reason = _solvable(u, method)
            except (CalibrationError, np.linalg.LinAlgError, ValueError) as err:
                T, bias, u = np.eye(3), np.zeros(3), u0
                reason = str(err)
    else:
        u = np.zeros((0, 3))
        reason = f'no static windows yet; {method} needs {MIN_WINDOWS[method]}'
    if method == 'gn':
        T = np.diag(np.diag(T))
    held = _held_counts(u)
    rows = fisher_rows(T, u, gravity)
    info = (rows * (1.0 / var_k)[:, None]).T @ rows
    solved = not reason
    current = None
    if solved:
        dof = n - len(index)
        if dof >= 3:
            resid = means - (gravity * u) @ T.T - bias
            chi2 = float(np.sum(np.einsum('ij,ij->i', resid, resid) / var_k))
            inflation = max(1.0, chi2 / dof)
        if inflation > INFLATION_NOTE:
            reason = (f'the windows scatter {math.sqrt(inflation):.1f}x more than their noise '
                      '(the sensor moved while held, or the model lacks an effect: '
                      + ('try method ml, ' if method == 'gn' else '') + 'run diagnose)')
        cov = _covariance(info, index)
        if cov is None:
            solved, reason = False, 'the poses leave a parameter undetermined'
        else:
            current = _accuracy(T, cov * inflation, gravity)

    cand_rows = fisher_rows(T, CANDIDATE_DIRECTIONS, gravity)
    prior = (cand_rows.T @ cand_rows) * PRIOR_WEIGHT / typical_var
    after = _accuracy_after(T, info if solved else info + prior, cand_rows, typical_var,
                            index, inflation, gravity)
    if not solved:
        if n + 1 >= MIN_WINDOWS[method]:
            # The accuracy once this pose makes the model solvable (no prior), if it does.
            exact = np.full(len(CANDIDATE_DIRECTIONS), math.inf)
            for k, h in enumerate(cand_rows):
                cov = _covariance(info + np.outer(h, h) / typical_var, index)
                if cov is not None and not _solvable(np.vstack([u, CANDIDATE_DIRECTIONS[k]]),
                                                     method):
                    exact[k] = _accuracy(T, cov, gravity)
        else:
            exact = np.full(len(CANDIDATE_DIRECTIONS), math.inf)
    enough = bool(solved and current is not None and current <= target)
    if enough and n - len(index) < 1:
        # As many windows as parameters fit exactly: nothing checks the noise level or
        # the model yet (a 6-face gn session would look perfect whatever the sensor).
        enough = False
        reason = 'one more window checks the noise level and the model'
    next_pose = None
    if not enough:
        choice = _choose(after, held, solved)
        value = after[choice] if solved else exact[choice]
        next_pose = NextPose(CANDIDATE_DIRECTIONS[choice].copy(), CANDIDATE_NAMES[choice],
                             _finite_or_none(value))
    return Advice(windows=n, predicted_accuracy=current, target=float(target), enough=enough,
                  next_pose=next_pose, method=method, held=held, reason=reason,
                  noise_inflation=inflation, directions=u)


def _choose(after, held, solved):
    """
    Index of the candidate to advise.

    Before a solve: the first face not yet held (z up, z down, x up, ...), then the most
    informative direction not yet held, so each new window adds a distinct direction.
    After: the most informative candidate held fewer than :data:`HELD_LIMIT` times.
    """
    if not solved:
        for k in range(FACE_COUNT):
            if held[k] == 0:
                return k
        fresh = np.flatnonzero(held == 0)
        if len(fresh):
            return int(fresh[np.argmin(after[fresh])])
    allowed = np.flatnonzero(held < HELD_LIMIT)
    if len(allowed) and np.isfinite(after[allowed]).any():
        return int(allowed[np.argmin(after[allowed])])
    return int(np.argmin(after))
