"""
Fit the calibration model to static observations.

Convention (interface.md §3)::

    raw  = T @ true + bias + drift(raw, temperature)
    true = T⁻¹ @ (raw - bias - drift(raw, temperature))

``T`` is upper triangular and dimensionless (scale x non-orthogonality, Sun & Xu
eq. 1-4), ``bias`` in m/s², ``drift`` from the temperature-band tables (zero when
there are none). The :class:`~accel_calib_ros.core.calibration.Calibration` data class
lives in ``core.calibration`` (re-exported here); files are read and written by
``accel_calib_ros.dataio.calibration_file``.
"""

import time

import numpy as np

from .ellipsoid import fit_ellipsoid
from .gn import fit_gn
from .ml import fit_ml, fit_ml_bias_corrected
from .thermal import fit_thermal_table
from ..accuracy import predicted_accuracy
from ..calibration import Calibration, METHODS
from ..constants import G0
from ..errors import CalibrationError, InputError
from ..stats import median
from ..windows import distinct_directions

__all__ = ['Calibration', 'METHODS', 'accuracy_from_windows', 'calibrate', 'check_geometry',
           'estimate_gyro_bias', 'find_outlier_windows', 'gravity_residuals', 'missing_faces']


def gravity_residuals(cal_or_T, bias, readings, gravity, temps=None):
    """|corrected| - gravity for each reading (N,), m/s²."""
    if isinstance(cal_or_T, Calibration):
        corrected = cal_or_T.correct(readings, temps)
    else:
        corrected = np.linalg.solve(cal_or_T, (np.atleast_2d(readings) - bias).T).T
    return np.linalg.norm(corrected, axis=1) - gravity


def check_geometry(readings, method, weights=None, noise_std=None, sigma_floor=None):
    """
    Raise CalibrationError unless the observations can determine ``method``'s model.

    The message names the poses that would help most (:func:`geometry_poses`, the
    source of ``advise`` before a solve), never one already held.

    :param weights: (N,), ``noise_std`` (3,), ``sigma_floor``: as for :func:`calibrate`
        (they weigh the windows when the poses are ranked).
    """
    n = len(readings)
    need_obs, need_dirs = (6, 6) if method == 'gn' else (10, 9)
    centred = readings - _direction_centre(readings) if n else readings
    hint = {'weights': weights, 'noise_std': noise_std, 'sigma_floor': sigma_floor}
    if n < need_obs:
        dirs = distinct_directions(centred, 15.0, limit=need_dirs) if n else 0
        raise CalibrationError(
            f'{n} static observations; method {method} needs at least {need_obs} '
            f'in {need_dirs} distinct orientations: '
            + _poses_hint(readings, method, max(need_obs - n, need_dirs - dirs), **hint))
    dirs = distinct_directions(centred, 15.0, limit=need_dirs)
    if dirs < need_dirs:
        faces = not missing_faces(centred, 15.0)
        why = (' (all six faces are held: its 3 cross-axis terms need tilted poses)'
               if faces and method != 'gn' else '')
        other = ('; or the 6-parameter gn method, which assumes orthogonal axes'
                 if method != 'gn' and dirs >= 6 else '')
        raise CalibrationError(
            f'only {dirs} distinct orientations among {n} observations; method {method} '
            f'needs {need_dirs}{why}: '
            + _poses_hint(readings, method, need_dirs - dirs, **hint) + other)
    centred = readings - median(readings, axis=0)
    spread = np.linalg.svd(centred / (np.linalg.norm(centred, axis=1).max() + 1e-300),
                           compute_uv=False)
    if spread[-1] < 1e-3 * spread[0]:
        raise CalibrationError('all orientations lie in one plane: tilt the sensor out of it: '
                               + _poses_hint(readings, method, 1, **hint))


def observation_directions(readings):
    """
    Return the unit gravity directions (N, 3) of raw readings before any fit.

    Taken from :func:`_direction_centre` (the origin for readings in physical units, the
    mid-range for raw codes with an offset); a zero vector stays zero.
    """
    y = np.asarray(readings, float).reshape(-1, 3)
    if not len(y):
        return y
    centred = y - _direction_centre(y)
    return centred / np.maximum(np.linalg.norm(centred, axis=1, keepdims=True), 1e-300)


def geometry_poses(readings, method, count=3, weights=None, noise_std=None, sigma_floor=None):
    """
    Return the poses to hold next while the observations cannot determine the model.

    The faces no observation is near come first (z up, z down, x up, ...), then the
    poses that add most information (``core.information.poses_to_add`` with a weak prior
    over all candidates), never one within 25° of a direction held.

    :param readings: (N, 3) observations (any unit).
    :param method: 'ml', 'ml-bc', 'ellipsoid' or 'gn'.
    :param weights: (N,) samples behind each observation, or None.
    :return: list of (name, direction (3,), None).
    """
    from ..information import Information, poses_to_add, window_variance
    from ..poses import fisher_rows
    u = observation_directions(readings)
    u = u[np.linalg.norm(u, axis=1) > 0.5]
    var = window_variance(weights if weights is None or len(u) == len(weights) else None,
                          noise_std, len(u), sigma_floor)
    info = Information(np.eye(3), np.zeros(3), G0, method, u,
                       fisher_rows(np.eye(3), u), var)
    with np.errstate(all='ignore'):
        return [(name, d, None) for name, d, _ in
                poses_to_add(info, max(1, min(int(count), 3)), faces_first=True)]


def _poses_hint(readings, method, count, **kw):
    """Return 'hold next: A, then B (still, ...)': the poses of :func:`geometry_poses`."""
    poses = geometry_poses(readings, method, count, **kw)
    if not poses:
        return 'turn the sensor so each axis points up and down, and tilted between'
    return ('hold next: ' + ', then '.join(name for name, _, _ in poses)
            + ' (still, a few seconds each) and record again')


CONE_DEG = 45.0
"""Readings all within this angle of one direction from the origin may hold an offset."""


def _direction_centre(readings):
    """
    Return the point (3,) from which the readings' directions are taken.

    Static readings lie on the gravity ellipsoid around the bias. In physical units the
    bias is small and the origin is the centre. Raw codes with an offset (e.g. unsigned
    ADC codes, zero near 32768) all point the same way from the origin; then the
    mid-range is the centre when the readings are nearly equidistant from it (a sphere
    of poses). The noise cloud of a single pose, or a few poses in physical units, keep
    the origin.
    """
    y = np.asarray(readings, float).reshape(-1, 3)
    norm = np.linalg.norm(y, axis=1, keepdims=True)
    u = y / np.maximum(norm, 1e-300)
    mean = u.mean(axis=0)
    mean /= max(np.linalg.norm(mean), 1e-300)
    if not len(y) or np.min(u @ mean) < np.cos(np.radians(CONE_DEG)):
        return np.zeros(3)                      # spread around the origin: physical units
    mid = (y.max(axis=0) + y.min(axis=0)) / 2.0
    spread = np.linalg.norm(y - mid, axis=1)
    if np.std(spread) < 0.1 * np.mean(spread):  # a sphere of poses about the mid-range
        return mid
    return np.zeros(3)


def missing_faces(readings, within_deg=50.0):
    """
    Names of the faces ('x axis up', ...) no observation came within ``within_deg`` of.

    :param readings: (N, 3) raw readings; their direction is the sensor axis pointing up.
    """
    from ..accuracy import FACE_DIRECTIONS, FACE_NAMES
    y = np.asarray(readings, float).reshape(-1, 3)
    u = y / np.maximum(np.linalg.norm(y, axis=1, keepdims=True), 1e-300)
    best = (u @ FACE_DIRECTIONS.T).max(axis=0)
    return [name for name, c in zip(FACE_NAMES, best) if c < np.cos(np.radians(within_deg))]


THERMAL_ROUNDS = 4
"""Alternations between the reference fit and the drift tables."""


def _fit_reference(y, gravity, method, weights):
    """Fit T, bias by ``method``; return (T, bias, covariance (9, 9) or None, info)."""
    if method in ('ml', 'ml-bc'):
        fit = (fit_ml if method == 'ml' else fit_ml_bias_corrected)(y, weights, gravity)
        T, bias, cov = fit.T, fit.bias, fit.covariance
    elif method == 'gn':
        fit = fit_gn(y, weights, gravity)
        T, bias = fit.T, fit.bias
        cov = np.zeros((9, 9))
        idx = [0, 3, 5, 6, 7, 8]            # T_xx, T_yy, T_zz, b in PARAMETER_NAMES order
        cov[np.ix_(idx, idx)] = fit.covariance
    else:
        t0 = time.perf_counter()
        T, bias = fit_ellipsoid(y, weights, gravity)
        return T, bias, None, {'iterations': 0, 'converged': True,
                               'seconds': time.perf_counter() - t0, 'trace': []}
    info = {'iterations': fit.iterations, 'converged': fit.converged, 'seconds': fit.seconds,
            'trace': fit.trace}
    return T, bias, cov, info


def accuracy_from_windows(cal, y, weights=None, noise_std=None, sigma_floor=None):
    """
    Fill ``cal.covariance``, ``predicted_accuracy``, ``information`` and ``cross_axis``.

    The one accuracy model (:mod:`core.information`): the information of the window
    means at the fitted parameters with the noise taken from the data (within-window
    noise over the samples behind each mean, a floor no averaging removes, inflated by
    the residual χ²/dof), restricted to the parameters the method fits; a ``gn`` fit is
    charged for the cross-axis terms it holds at zero (measured by the ML fit of the
    same windows when they can, else the datasheet bound).

    :param cal: fitted Calibration (T, bias, gravity, method); changed in place.
    :param y: (N, 3) the observations it was fitted to (drift removed), m/s².
    :param weights: (N,) samples behind each observation (capped), or None.
    :param noise_std: (3,) per-sample noise, m/s², or None.
    :param sigma_floor: error of a window mean no averaging removes, m/s².
    """
    from ..information import cross_axis_allowance, information
    with np.errstate(all='ignore'):
        info = information(y, cal.T, cal.bias, cal.gravity, cal.method, weights, noise_std,
                           sigma_floor)
        cov = info.covariance()
        cal.information = info
        if cov is None:
            cal.covariance = np.full((9, 9), np.inf)
            cal.predicted_accuracy = float('inf')
            return cal
        if cal.method == 'gn':
            cal.cross_axis = cross_axis_allowance(info, y, weights, noise_std, sigma_floor)
            cov = cov + cal.cross_axis.covariance
        cal.covariance = cov
        acc = predicted_accuracy(cal.T, cov, cal.gravity)
    cal.predicted_accuracy = acc if np.isfinite(acc) else float('inf')
    return cal


def estimate_gyro_bias(gyro_means, weights=None):
    """
    Gyroscope bias (3,) rad/s: weighted mean of the static windows' mean rates.

    :param gyro_means: (W, 3) window mean angular rates, rad/s (raw = true + bias).
    :param weights: (W,) samples per window (default equal).
    :returns: (3,) or None when there is no finite window.
    """
    g = np.asarray(gyro_means, float).reshape(-1, 3)
    ok = np.all(np.isfinite(g), axis=1)
    if not ok.any():
        return None
    w = np.ones(len(g)) if weights is None else np.asarray(weights, float).reshape(-1)
    return np.average(g[ok], axis=0, weights=w[ok])


def calibrate(readings, gravity=G0, method='ml', weights=None, temps=None,
              thermal=False, band_width_c=10.0, noise_std=None, source='', gyro_means=None,
              mean_count=None, sigma_floor=None):
    """
    Fit a Calibration to static observations (window means or samples).

    :param readings: (N, 3) raw readings, m/s².
    :param gravity: local gravity, m/s².
    :param method: 'ml' (Sun & Xu), 'ml-bc' (ML with bootstrap bias correction),
        'gn' (Gui Yi 6-parameter) or 'ellipsoid' (algebraic LS).
    :param weights: (N,) samples behind each observation (per window, capped), or None.
    :param temps: (N,) observation temperatures, °C, for the drift tables.
    :param thermal: fit temperature-band tables (needs ``temps``).
    :param noise_std: (3,) per-sample noise measured in the windows, m/s².
    :param gyro_means: (N, 3) mean angular rate of each observation, rad/s: gives the
        gyroscope bias (and per temperature band with ``thermal``).
    :param mean_count: unused (kept for callers): the weights are the samples behind
        each observation (1 without weights).
    :param sigma_floor: error of a window mean no averaging removes, m/s² (default
        ``core.information.SIGMA_FLOOR``).
    :returns: Calibration with ``predicted_accuracy`` (interface.md §5), ``covariance``,
        ``information`` and, for ``gn``, ``cross_axis`` (:func:`accuracy_from_windows`).
    :raises CalibrationError: the data cannot determine the model (with the reason).
    """
    if method not in METHODS:
        raise InputError(f'unknown method {method!r}; choose one of {", ".join(METHODS)}')
    y = np.asarray(readings, float).reshape(-1, 3)
    if not np.all(np.isfinite(y)):
        raise InputError('observations hold NaN or infinite values')
    check_geometry(y, method, weights, noise_std, sigma_floor)
    T, bias, cov, info = _fit_reference(y, gravity, method, weights)
    cal = Calibration(T=T, bias=bias, gravity=gravity, method=method, covariance=cov,
                      observations=len(y), source=source,
                      noise_std=np.full(3, np.nan) if noise_std is None else noise_std,
                      **info)
    if temps is not None and np.any(np.isfinite(temps)):
        tf = np.asarray(temps, float)[np.isfinite(temps)]
        cal.temperature_range_c = (float(tf.min()), float(tf.max()))
    if thermal:
        if temps is None or not np.any(np.isfinite(temps)):
            raise InputError('thermal tables need temperatures (a temp column) in the data')
        # The reference fitted while ignoring temperature is pulled by the drift
        # (temperature and orientation are correlated in any real session), and the
        # per-axis tables cannot undo an error in its cross-axis terms. Alternate:
        # tables given the reference, then the reference on drift-free readings.
        for _ in range(THERMAL_ROUNDS):
            cal.thermal = fit_thermal_table(y, temps, cal.T, cal.bias, gravity, weights,
                                            band_width_c)
            if not cal.thermal.usable:
                break
            clean = y - cal.thermal.drift(y, temps)
            cal.T, cal.bias, cal.covariance, _ = _fit_reference(clean, gravity, method,
                                                                weights)
        cal.thermal = fit_thermal_table(y, temps, cal.T, cal.bias, gravity, weights,
                                        band_width_c)
    clean = y if cal.thermal is None or temps is None else y - cal.thermal.drift(y, temps)
    accuracy_from_windows(cal, clean, weights, noise_std, sigma_floor)
    if gyro_means is not None:
        cal.gyro_bias = estimate_gyro_bias(gyro_means, weights)
        if cal.thermal is not None:
            index = np.floor(np.asarray(temps, float) / band_width_c)
            for band in cal.thermal.bands:
                sel = np.isfinite(temps) & (index == np.floor(band.low_c / band_width_c))
                if sel.any():
                    band.gyro_bias = estimate_gyro_bias(
                        np.asarray(gyro_means, float)[sel],
                        None if weights is None else np.asarray(weights, float)[sel])
    cal.residual_rms = float(np.sqrt(np.mean(gravity_residuals(cal, None, y, gravity,
                                                               temps) ** 2)))
    return cal


OUTLIER_FACTOR = 8.0
"""A window is an outlier when its gravity-norm residual exceeds this many times its noise."""
MAX_OUTLIER_FRACTION = 0.25
"""Never drop more than this fraction of the windows (beyond it the session is refused)."""


def _norm_residuals_fit(y, w, dt, gravity, start, iterations=30):
    """
    Weighted least-squares fit of |T⁻¹ (y - b - k dt)| = gravity; return the residuals.

    T upper triangular, b the bias and k (3,) a linear temperature coefficient of the
    bias (``dt`` °C from the mean, zeros without temperatures): a model general enough
    for every window of a session that the outlier test can trust. Levenberg-Marquardt
    with the analytic Jacobian (12 parameters): for a = T⁻¹ x, n = a/|a| and u = T⁻ᵀ n,
    d|a|/dT_ij = -u_i a_j, d|a|/db = -u and d|a|/dk = -u dt.
    """
    rows, cols = np.triu_indices(3)

    def unpack(p):
        T = np.zeros((3, 3))
        T[rows, cols] = p[:6]
        return T, y - p[6:9] - np.outer(dt, p[9:12])

    def residual(p):
        T, x = unpack(p)
        return np.linalg.norm(np.linalg.solve(T, x.T).T, axis=1) - gravity

    def jacobian(p):
        T, x = unpack(p)
        a = np.linalg.solve(T, x.T).T
        u = np.linalg.solve(T.T, (a / np.linalg.norm(a, axis=1, keepdims=True)).T).T
        return -np.hstack([u[:, rows] * a[:, cols], u, u * dt[:, None]])

    p = np.r_[start[0][rows, cols], start[1], np.zeros(3)]
    use = slice(None) if np.any(dt != 0) else slice(0, 9)
    r = residual(p)
    cost, damping = float(np.sum(w * r ** 2)), 1e-3
    for _ in range(iterations):
        J = jacobian(p)[:, use]
        A = J.T @ (w[:, None] * J)
        g = J.T @ (w * r)
        try:
            step = np.linalg.solve(A + damping * np.diag(np.diag(A) + 1e-300), -g)
        except np.linalg.LinAlgError:
            break
        trial = p.copy()
        trial[use] += step
        with np.errstate(all='ignore'):
            r_new = residual(trial)
        cost_new = float(np.sum(w * r_new ** 2))
        if np.isfinite(cost_new) and cost_new <= cost:
            done = cost - cost_new <= 1e-12 * cost
            p, r, cost, damping = trial, r_new, cost_new, damping / 10
            if done:
                break
        else:
            damping *= 10
            if damping > 1e8:
                break
    return r


def find_outlier_windows(readings, weights, counts, noise_std, gravity=G0, temps=None,
                         thermal=False, band_width_c=10.0, method='ml', rounds=8):
    """
    Windows whose gravity-norm residual after a robust fit is far beyond their noise.

    A slow turn leaking into a hold, a bump, or a hand still settling moves a window's
    mean off the ellipsoid every other window lies on. The fit is made robust by
    iteratively reweighting the windows with Tukey's biweight of their residuals (so an
    outlier cannot pull the fit towards itself), then a window is an outlier when its
    residual exceeds :data:`OUTLIER_FACTOR` times the larger of its own noise
    (``noise_std`` / sqrt(count)) and 1.4826 x the median absolute residual (model errors
    every window shares). The fit carries a linear temperature coefficient of the bias
    when the temperatures spread (``thermal`` is accepted for symmetry with
    :func:`calibrate`), so drift is not mistaken for motion. More than
    :data:`MAX_OUTLIER_FRACTION` of the windows, or a
    set the model cannot be fitted on without them, is never dropped (the fit then
    judges the session).

    :param readings: (W, 3) window means, m/s²; ``counts``: (W,) samples per window.
    :returns: (keep mask (W,), list of (index, reason)).
    """
    y = np.asarray(readings, float).reshape(-1, 3)
    n = len(y)
    keep = np.ones(n, bool)
    if n < 12:
        return keep, []
    counts = np.asarray(counts, float).reshape(n)
    noise = float(np.sqrt(np.mean(np.square(noise_std)))) if noise_std is not None \
        and np.all(np.isfinite(noise_std)) else 0.0
    own = np.maximum(noise / np.sqrt(np.maximum(counts, 1.0)), 1e-7 * gravity)
    w = np.ones(n) if weights is None else np.asarray(weights, float).reshape(n)
    t = None if temps is None else np.asarray(temps, float).reshape(n)
    robust_w = np.ones(n)
    dt = np.zeros(n)
    if t is not None and np.all(np.isfinite(t)) and np.ptp(t) > 1.0:
        dt = t - np.average(t, weights=w)
    try:
        with np.errstate(all='ignore'):
            start = _fit_reference(y, gravity, 'ml', w)[:2]
    except (CalibrationError, np.linalg.LinAlgError):
        return keep, []
    r = scale = None
    for _ in range(rounds):
        with np.errstate(all='ignore'):
            r_new = np.abs(_norm_residuals_fit(y, w * np.maximum(robust_w, 1e-6), dt, gravity,
                                               start))
        if not np.all(np.isfinite(r_new)):
            break
        r = r_new
        trusted = robust_w > 0.5
        spread = 1.4826 * median(r[trusted]) if trusted.any() else median(r)
        scale = np.maximum(own, spread)
        z = r / (4.685 * scale)
        new_w = np.where(z < 1.0, (1.0 - z ** 2) ** 2, 0.0)
        if np.allclose(new_w, robust_w, atol=1e-3):
            break
        robust_w = new_w
    if r is None:
        return keep, []
    bad = r > OUTLIER_FACTOR * scale
    if bad.sum() > MAX_OUTLIER_FRACTION * n:
        return keep, []
    if bad.any():
        try:
            check_geometry(y[~bad], method)
        except CalibrationError:
            return keep, []
    reasons = [(int(k), f'gravity-norm residual {r[k]:.4f} m/s² is {r[k] / scale[k]:.0f}x '
                        f'its noise {scale[k]:.2g} m/s² (moved during the hold?)')
               for k in np.flatnonzero(bad)]
    return ~bad, reasons
