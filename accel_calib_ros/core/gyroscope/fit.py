"""
Gyroscope scale and misalignment from the moves between static windows (interface.md §9).

The imu_tk method (Tedaldi, Pretto & Menegatti 2014): between two static windows the
sensor turns; integrating the calibrated rate over that move must turn the gravity
direction seen at the end of one window into the one seen at the start of the next.
Model, per sample::

    raw_gyro  = T @ true_rate + bias      (T: (3, 3) scale x misalignment; bias rad/s)
    true_rate = K @ (raw_gyro - bias),     K = T⁻¹

``bias`` comes from the static windows (``calibration.estimate_gyro_bias``); ``K`` is
fitted. The frame of the result is the accelerometer's (the gravity directions come
from it, calibrated when an accelerometer correction is given).

One observation per move k (window k to window k+1):

- ``g0``: gravity direction (unit) over the last ``edge_s`` of window k and ``g1`` over
  the first ``edge_s`` of window k+1 (not the whole windows: a hand-held pose drifts,
  and only the ends touch the move);
- the rotation from the middle of the first portion to the middle of the second is
  integrated sample by sample, each sample's rate held until the next sample's time
  (the exact exponential of each step: ``C_{i+1} = C_i exp([K (raw_i - bias) dt_i]x)``,
  ``C`` mapping the current body frame into the body frame at the start);
- the residual is the predicted direction ``C_nᵀ g0`` projected on the plane
  perpendicular to ``g1`` (two components, radians for small errors).

The 9 entries of ``K`` are fitted by Gauss-Newton with Levenberg-Marquardt damping
from ``start`` (default identity), with an analytic Jacobian: a change ``dK``
perturbs step i by ``J_r(phi_i) dK (raw_i - bias) dt_i`` (``J_r`` the right
Jacobian of SO(3)), which moves the end rotation by ``sum_i C_{i+1} J_r dphi_i``
(body frame at the start) and the predicted direction by ``C_nᵀ [g0]x`` times that.

Covariance: ``sigma² (JᵀJ)⁻¹`` with ``sigma²`` the residual scatter over its degrees
of freedom (2 per move minus 9), plus the bias estimate's own uncertainty carried
through the moves. Predicted accuracy: the RMS relative error of the corrected rate,
``sqrt(E_u |T̂⁻¹ T u - u|²)``, averaged over rate directions u uniform on the sphere
in closed form (``E[u uᵀ] = I/3``, see :func:`predicted_accuracy`).

Identifiability: the columns of ``K`` belong to the raw axes. A turn about sensor axis
c determines column c except its component along gravity at that moment, so column c
needs turns about c with gravity in two directions across c. The information left
for column c once the other columns are fitted (the Schur complement of its 3x3 block
of JᵀJ) has the units of a squared angle: its smallest eigenvalue, as an angle, is the
effective turn about axis c (``excitation_deg``). An axis below ``min_turn_deg`` is
named ("no turn about the z axis") and T is kept at identity, as interface.md asks.

Moves where a raw gyro channel sits at its full-scale limit (clipping) are dropped
and reported: the integral through them is wrong. numpy/scipy only.
"""

from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from .moves import clipped, Moves, portion_means, window_ranges
from ..accelerometer.fit import estimate_gyro_bias
from ..constants import AXES
from ..errors import CalibrationError, InputError
from ..stats import median

TURN_ADVICE = {'x': 'from y axis up to z axis up', 'y': 'from z axis up to x axis up',
               'z': 'from x axis up to y axis up'}
"""A move that turns the sensor about each axis with gravity across it."""

EDGE_S = 0.5
"""Seconds at the end/start of each static window that give its gravity direction."""

MIN_TURN_DEG = 30.0
"""Smallest effective turn about an axis (gravity across it) that calibrates that axis."""

MIN_MOVES = 5
"""Moves needed for 9 parameters (2 residuals each) and a noise estimate."""


GAP_FACTOR = 5.0
"""A time step longer than this many median steps inside a move drops the move."""

GYRO_STEP_TOLERANCE = 1e-4
"""Converged when the next Gauss-Newton step moves K by at most this many std errors."""


@dataclass
class GyroMove:
    """
    One move between consecutive static windows.

    :param window: the move goes from static window ``window`` to ``window + 1``.
    :param t_start: time the integration starts (middle of window k's end portion), s.
    :param t_stop: time it stops (middle of window k+1's start portion), s.
    :param turn_deg: angle of the rotation integrated with the result, degrees.
    :param residual_deg: angle between the predicted and the measured gravity direction
        at the end, degrees (NaN when the move was dropped before integration).
    :param reason: why the move was left out of the fit, or None when it was used.
    """

    window: int
    t_start: float
    t_stop: float
    turn_deg: float = float('nan')
    residual_deg: float = float('nan')
    reason: Optional[str] = None

    @property
    def used(self):
        """Tell whether the move is part of the fit."""
        return self.reason is None


@dataclass
class GyroCalibration:
    """
    Result of :func:`fit_gyro` (interface.md §9): ``raw = T @ true_rate + bias``.

    :param T: (3, 3) scale x misalignment, dimensionless (identity when not fitted).
    :param bias: (3,) zero-rate offset, rad/s (raw units).
    :param covariance: (9, 9) covariance of T's entries, row-major (NaN when T was not
        fitted).
    :param bias_covariance: (3, 3) covariance of ``bias``, (rad/s)² (zeros when the bias
        was given).
    :param predicted_accuracy: RMS relative error of the corrected rate over rate
        directions uniform on the sphere (dimensionless, 0.001 = 0.1 %), from
        ``covariance``; inf when T was not fitted.
    :param residual_rms_deg: RMS angle between predicted and measured gravity
        directions over the moves used, degrees.
    :param sigma_deg: noise of one residual component from their scatter, degrees.
    :param moves: every move between consecutive windows, used or dropped
        (:class:`GyroMove`).
    :param excitation_deg: (3,) effective turn about each sensor axis with gravity
        across it, degrees (see the module docstring).
    :param missing_axes: names of the axes below ``min_turn_deg`` ('x', 'y', 'z').
    :param converged: T was fitted and the iteration converged.
    :param iterations: Gauss-Newton iterations.
    :param message: a sentence on the outcome (what is missing and what to do).
    """

    T: np.ndarray
    bias: np.ndarray
    covariance: np.ndarray
    bias_covariance: np.ndarray
    predicted_accuracy: float
    residual_rms_deg: float
    sigma_deg: float
    moves: list = field(default_factory=list)
    excitation_deg: np.ndarray = field(default_factory=lambda: np.zeros(3))
    missing_axes: tuple = ()
    converged: bool = False
    iterations: int = 0
    message: str = ''

    @property
    def moves_used(self):
        """Count the moves in the fit."""
        return sum(move.used for move in self.moves)

    @property
    def moves_dropped(self):
        """List the moves left out, each with its ``reason``."""
        return [move for move in self.moves if not move.used]

    def correct(self, raw_gyro):
        """Return the true rate (N, 3) rad/s from raw rates (N, 3) rad/s: ``T⁻¹ (raw - bias)``."""
        raw = np.atleast_2d(np.asarray(raw_gyro, float))
        return np.linalg.solve(self.T, (raw - self.bias).T).T


def predicted_accuracy(T, covariance):
    """
    RMS relative error of the corrected rate over directions uniform on the sphere.

    The corrected rate ``T̂⁻¹ (raw - b)`` at true rate ``|w| u`` is off by
    ``-T⁻¹ dT u |w|`` (first order). Averaged over u uniform on the sphere
    (``E[u uᵀ] = I/3``) and over ``dT`` with the given covariance::

        E |T⁻¹ dT u|² = tr(M C),  M[(i,j),(k,l)] = (T⁻ᵀ T⁻¹)[i,k] δ_jl / 3.

    Closed form; the bias error (rad/s, not relative) is not part of it.

    :param T: (3, 3) gyroscope T.
    :param covariance: (9, 9) covariance of T's entries, row-major.
    :returns: float, dimensionless (inf when the covariance is not finite).
    """
    T = np.asarray(T, float).reshape(3, 3)
    C = np.asarray(covariance, float).reshape(9, 9)
    if not (np.all(np.isfinite(C)) and np.all(np.isfinite(T))):
        return float('inf')
    A = np.linalg.inv(T)
    M = np.kron(A.T @ A, np.eye(3)) / 3.0
    return float(np.sqrt(max(float(np.sum(M * (0.5 * (C + C.T)))), 0.0)))


def accel_corrector(accel):
    """Return f(readings (N, 3), temps (N,) or None) -> calibrated readings."""
    if accel is None:
        return lambda y, temp: y
    if hasattr(accel, 'correct'):
        return lambda y, temp: accel.correct(y, temp)
    if callable(accel):
        return lambda y, temp: accel(y)
    try:
        T, bias = accel
        T = np.asarray(T, float).reshape(3, 3)
        bias = np.asarray(bias, float).reshape(3)
    except (TypeError, ValueError):
        raise InputError('accel must be None, a callable, an object with correct() or a '
                         '(T, bias) pair') from None
    return lambda y, temp: np.linalg.solve(T, (y - bias).T).T


def _identifiability(F, prior):
    """
    Effective turn (3,) about each sensor axis, degrees.

    For axis c, the information on column c of K (its 3x3 block of ``F = JᵀJ``, units
    rad²) left once the other columns are fitted: the Schur complement
    ``F_cc - F_co (F_oo + prior I)⁻¹ F_oc``, whose smallest eigenvalue is reported as
    an angle. ``prior`` (rad²) keeps a column that nothing turns from absorbing the
    others (without it, an axis seen only through gyro noise would make every axis
    look unidentifiable); columns turned only together (every turn about the same
    tilted axis) still leave each other less than ``prior``.
    """
    out = np.zeros(3)
    for c in range(3):
        own = [3 * b + c for b in range(3)]
        other = [j for j in range(9) if j not in own]
        S = F[np.ix_(own, own)] - F[np.ix_(own, other)] @ np.linalg.solve(
            F[np.ix_(other, other)] + prior * np.eye(6), F[np.ix_(other, own)])
        out[c] = np.degrees(np.sqrt(max(float(np.linalg.eigvalsh(0.5 * (S + S.T))[0]), 0.0)))
    return out


def fit_gyro(samples, windows=None, accel=None, bias=None, full_scale=None, edge_s=EDGE_S,
             start=None, min_turn_deg=MIN_TURN_DEG, max_iter=50):
    """
    Fit the gyroscope's scale and misalignment T from a multi-pose session (interface.md §9).

    :param samples: Samples with ``gyro`` (rad/s), hand-held or on a table: static
        windows with moves between them.
    :param windows: StaticWindows (start/stop sample indices) or None to detect them.
    :param accel: accelerometer correction for the gravity directions: None (raw
        directions, which carry the accelerometer's own errors), a callable
        ``f(readings (N, 3)) -> (N, 3)``, an object with ``correct(readings, temp)``
        (a Calibration) or a ``(T, bias)`` pair (raw = T a + bias).
    :param bias: (3,) gyro bias, rad/s; None to estimate it from the static windows.
    :param full_scale: gyro range, rad/s, for the clipping test; None to find the
        limit in the data (see :func:`clipped`).
    :param edge_s: seconds at the end/start of each window for its gravity direction.
    :param start: (3, 3) starting T (default identity: the nominal sensitivity).
    :param min_turn_deg: smallest effective turn about an axis that calibrates it.
    :param max_iter: Gauss-Newton iteration limit.
    :returns: GyroCalibration.
    :raises InputError: no gyro data, or malformed arguments.
    :raises CalibrationError: fewer than two static windows, or fewer than
        ``MIN_MOVES`` usable moves (the message lists the dropped ones and why).
    """
    if samples.gyro is None:
        raise InputError('no gyro data: the recording needs gx gy gz columns (rad/s)')
    t = np.asarray(samples.t, float)
    gyro = np.asarray(samples.gyro, float)
    if len(t) < 2 or not np.all(np.isfinite(t)) or np.any(np.diff(t) < 0):
        raise InputError('sample times must be finite and increasing, at least two rows')
    w_start, w_stop = window_ranges(samples, windows)
    if len(w_start) < 2:
        raise CalibrationError(
            f'{len(w_start)} static window(s): the gyroscope fit needs poses held still with '
            f'moves between them (at least {MIN_MOVES} moves)')
    correct_accel = accel_corrector(accel)
    finite = np.all(np.isfinite(gyro), axis=1)
    count = w_stop - w_start
    # Bias from the static windows (weighted by samples), with its standard error.
    ok_window = np.array([finite[a:b].all() for a, b in zip(w_start, w_stop)])
    means = portion_means(np.where(finite[:, None], gyro, 0.0), w_start, w_stop)
    if bias is None:
        if ok_window.sum() < 1:
            raise CalibrationError('no static window has a complete gyro record for the bias')
        bias = estimate_gyro_bias(means[ok_window], count[ok_window])
        w = count[ok_window].astype(float)
        spread = means[ok_window] - bias
        n_ok = int(ok_window.sum())
        bias_cov = (np.einsum('k,ki,kj->ij', w, spread, spread) / w.sum()
                    * np.sum(w ** 2) / w.sum() ** 2 * n_ok / max(n_ok - 1, 1)
                    if n_ok > 1 else np.zeros((3, 3)))
    else:
        bias = np.asarray(bias, float).reshape(3)
        bias_cov = np.zeros((3, 3))
    # Gravity over the end portion of each window and the start portion of the next.
    rate = samples.rate_hz
    n_edge = np.clip(np.minimum(int(round(edge_s * rate)) if np.isfinite(rate) else 1,
                                count // 2), 1, None)
    g_end = portion_means(samples.accel, w_stop - n_edge, w_stop)
    g_begin = portion_means(samples.accel, w_start, w_start + n_edge)
    temps = None
    if samples.temp is not None:
        temps = (portion_means(samples.temp[:, None], w_stop - n_edge, w_stop)[:, 0],
                 portion_means(samples.temp[:, None], w_start, w_start + n_edge)[:, 0])
    g_end = correct_accel(g_end, None if temps is None else temps[0])
    g_begin = correct_accel(g_begin, None if temps is None else temps[1])
    g_end = g_end / np.linalg.norm(g_end, axis=1, keepdims=True)
    g_begin = g_begin / np.linalg.norm(g_begin, axis=1, keepdims=True)
    # The moves: from the middle of window k's end portion to the middle of k+1's start.
    at_rail = clipped(gyro, full_scale)
    median_dt = median(np.diff(t))
    moves, rates, steps, used = [], [], [], []
    for k in range(len(w_start) - 1):
        a = int(w_stop[k] - n_edge[k] + n_edge[k] // 2)
        b = int(w_start[k + 1] + n_edge[k + 1] // 2)
        move = GyroMove(k, float(t[a]), float(t[b]))
        moves.append(move)
        dt = np.diff(t[a:b + 1])
        if not np.all(finite[a:b]):
            move.reason = f'gyro missing (NaN) in {int(np.sum(~finite[a:b]))} samples'
        elif at_rail[a:b].any():
            axes = ', '.join(AXES[i] for i in range(3) if at_rail[a:b, i].any())
            move.reason = (f'clipped: gyro {axes} at its full-scale limit in '
                           f'{int(at_rail[a:b].any(axis=1).sum())} samples')
        elif len(dt) and dt.max() > GAP_FACTOR * median_dt:
            move.reason = f'gap of {dt.max():.3f} s in the data'
        elif not (np.all(np.isfinite(g_end[k])) and np.all(np.isfinite(g_begin[k + 1]))):
            move.reason = 'no finite gravity direction at its ends'
        else:
            rates.append(gyro[a:b] - bias)
            steps.append(dt)
            used.append(k)
    if len(used) < MIN_MOVES:
        dropped = '; '.join(f'move {m.window}->{m.window + 1}: {m.reason}'
                            for m in moves if not m.used)
        raise CalibrationError(
            f'{len(used)} usable move(s) between static windows; the gyroscope fit needs at '
            f'least {MIN_MOVES} (turn the sensor between more held poses)'
            + (f'. Dropped: {dropped}' if dropped else ''))
    data = Moves(rates, steps, g_end[used], g_begin[np.asarray(used) + 1])
    T0 = np.eye(3) if start is None else np.asarray(start, float).reshape(3, 3)
    K = np.linalg.inv(T0)
    r, J, Jb, C = data.evaluate(K)
    excitation = _identifiability(np.einsum('mki,mkj->ij', J, J),
                                  np.radians(min_turn_deg) ** 2)
    missing = tuple(AXES[c] for c in range(3) if excitation[c] < min_turn_deg)
    dof = 2 * len(data) - 9
    iterations, converged = 0, False
    if not missing:
        K, r, J, Jb, C, iterations, converged = _gauss_newton(data, K, r, J, Jb, C, dof,
                                                              max_iter)
    residual, turn = data.angles_deg(C)
    for k, res, ang in zip(used, residual, turn):
        moves[k].residual_deg, moves[k].turn_deg = float(res), float(ang)
    ssr = float(np.sum(r * r))
    sigma2 = ssr / max(dof, 1)
    result = GyroCalibration(
        T=np.eye(3), bias=bias, covariance=np.full((9, 9), np.nan), bias_covariance=bias_cov,
        predicted_accuracy=float('inf'),
        residual_rms_deg=float(np.sqrt(np.mean(residual ** 2))),
        sigma_deg=float(np.degrees(np.sqrt(sigma2))), moves=moves, excitation_deg=excitation,
        missing_axes=missing, converged=False, iterations=iterations)
    n_drop = len(moves) - len(used)
    dropped_text = f', {n_drop} dropped ({_reasons(moves)})' if n_drop else ''
    if missing:
        names = ' and '.join(missing) + (' axes' if len(missing) > 1 else ' axis')
        result.message = (
            f'no turn about the {names}: the moves turn the sensor by an effective '
            + ', '.join(f'{excitation[AXES.index(a)]:.0f}°' for a in missing)
            + f' about {" and ".join(missing)} with gravity across (need {min_turn_deg:.0f}°); '
            f'gyro T kept at identity. Between poses, also turn the sensor about its '
            f'{names} ({"; ".join(f"about {a}: {TURN_ADVICE[a]}" for a in missing)}) '
            f'[{len(used)} moves used{dropped_text}]')
        return result
    F = np.einsum('mki,mkj->ij', J, J)
    try:
        F_inv = np.linalg.inv(F)
    except np.linalg.LinAlgError:
        F_inv = np.full((9, 9), np.nan)
    H = F_inv @ np.einsum('mki,mkj->ij', J, Jb)
    cov_K = sigma2 * F_inv + H @ bias_cov @ H.T
    T = np.linalg.inv(K)
    G = -np.einsum('ib,cj->ijbc', T, T).reshape(9, 9)
    result.T = T
    result.covariance = G @ cov_K @ G.T
    result.predicted_accuracy = predicted_accuracy(T, result.covariance)
    result.converged = bool(converged and np.isfinite(result.predicted_accuracy))
    result.message = (
        f'gyro T from {len(used)} moves{dropped_text}: predicted accuracy '
        f'{100 * result.predicted_accuracy:.3f} % of the rate, residual '
        f'{result.residual_rms_deg:.3f}° RMS'
        + ('' if result.converged else '; the iteration did not converge'))
    return result


def _reasons(moves):
    """Summarise the dropped moves by reason: 'clipped 2, gap of 1.2 s 1'."""
    counts = {}
    for move in moves:
        if not move.used:
            key = move.reason.split(':')[0]
            counts[key] = counts.get(key, 0) + 1
    return ', '.join(f'{key} {n}' for key, n in counts.items())


def _gauss_newton(data, K, r, J, Jb, C, dof, max_iter):
    """Levenberg-Marquardt on the 9 entries of K; returns the state and convergence."""
    eps = np.finfo(float).eps
    floor = (1e3 * eps) ** 2 * r.size
    cost = float(np.sum(r * r))
    damping, converged, it = 0.0, False, 0
    while True:
        Jm = J.reshape(-1, 9)
        F = Jm.T @ Jm
        g = Jm.T @ r.reshape(-1)
        try:
            step = -np.linalg.solve(F, g)
            decrement = float(-g @ step)
        except np.linalg.LinAlgError:
            step, decrement = None, np.inf
        if step is not None and decrement <= GYRO_STEP_TOLERANCE ** 2 * cost / max(dof, 1) + floor:
            converged = True
            break
        if it == max_iter:
            break
        it += 1
        while True:
            try:
                if damping or step is None:
                    damping = max(damping, 1e-6)
                    step = -np.linalg.solve(F + damping * np.diag(np.diag(F)), g)
                new = data.evaluate(K + step.reshape(3, 3))
                new_cost = float(np.sum(new[0] ** 2))
            except np.linalg.LinAlgError:
                new_cost = np.inf
            if np.isfinite(new_cost) and new_cost <= cost * (1 + 1e3 * eps) + floor:
                break
            damping = max(damping * 10.0, 1e-6)
            if damping > 1e8:
                return K, r, J, Jb, C, it, False
        K = K + step.reshape(3, 3)
        r, J, Jb, C = new
        cost = new_cost
        damping = damping / 10.0 if damping > 1e-9 else 0.0
    return K, r, J, Jb, C, it, converged
