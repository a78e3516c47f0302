"""
Fit the calibration model to static observations.

Convention (spec section 3)::

    raw  = T @ true + bias + drift(raw, temperature)
    true = T⁻¹ @ (raw - bias - drift(raw, temperature))

``T`` is upper triangular and dimensionless (scale x non-orthogonality, Sun & Xu
eq. 1-4), ``bias`` in m/s², ``drift`` from the temperature-band tables (zero when
there are none). The :class:`~accel_calib_ros.core.model.Calibration` data class
lives in ``core.model`` (re-exported here); files are read and written by
``accel_calib_ros.dataio.calibration_file``.
"""

import time

import numpy as np

from .ellipsoid import fit_ellipsoid
from .errors import CalibrationError, InputError
from .gn import fit_gn
from .ml import fit_ml, fit_ml_bias_corrected
from .model import Calibration, METHODS
from .thermal import fit_thermal_table
from .windows import distinct_directions

__all__ = ['Calibration', 'METHODS', 'calibrate', 'check_geometry', 'gravity_residuals']


def gravity_residuals(cal_or_T, bias, readings, gravity, temps=None):
    """|corrected| - gravity for each reading (N,), m/s²."""
    if isinstance(cal_or_T, Calibration):
        corrected = cal_or_T.correct(readings, temps)
    else:
        corrected = np.linalg.solve(cal_or_T, (np.atleast_2d(readings) - bias).T).T
    return np.linalg.norm(corrected, axis=1) - gravity


def check_geometry(readings, method):
    """Raise CalibrationError unless the observations can determine ``method``'s model."""
    n = len(readings)
    need_obs, need_dirs = (6, 6) if method == 'gn' else (10, 9)
    if n < need_obs:
        raise CalibrationError(
            f'{n} static observations; method {method} needs at least {need_obs} '
            f'in {need_dirs} distinct orientations: hold more poses')
    centred = readings - np.median(readings, axis=0)
    dirs = distinct_directions(readings - (readings.max(0) + readings.min(0)) / 2, 15.0)
    if dirs < need_dirs:
        raise CalibrationError(
            f'only {dirs} distinct orientations among {n} observations; method {method} '
            f'needs {need_dirs}: turn the sensor so each axis points up and down')
    spread = np.linalg.svd(centred / (np.linalg.norm(centred, axis=1).max() + 1e-300),
                           compute_uv=False)
    if spread[-1] < 1e-3 * spread[0]:
        raise CalibrationError('all orientations lie in one plane: tilt the sensor out of it')


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


def calibrate(readings, gravity=9.80665, method='ml', weights=None, temps=None,
              thermal=False, band_width_c=10.0, noise_std=None, source=''):
    """
    Fit a Calibration to static observations (window means or samples).

    :param readings: (N, 3) raw readings, m/s².
    :param gravity: local gravity, m/s².
    :param method: 'ml' (Sun & Xu), 'ml-bc' (ML with bootstrap bias correction),
        'gn' (Gui Yi 6-parameter) or 'ellipsoid' (algebraic LS).
    :param weights: (N,) observation weights (samples per window).
    :param temps: (N,) observation temperatures, °C, for the drift tables.
    :param thermal: fit temperature-band tables (needs ``temps``).
    :param noise_std: (3,) per-sample noise measured in the windows, m/s².
    :returns: Calibration.
    :raises CalibrationError: the data cannot determine the model (with the reason).
    """
    if method not in METHODS:
        raise InputError(f'unknown method {method!r}; choose one of {", ".join(METHODS)}')
    y = np.asarray(readings, float).reshape(-1, 3)
    check_geometry(y, method)
    T, bias, cov, info = _fit_reference(y, gravity, method, weights)
    cal = Calibration(T=T, bias=bias, gravity=gravity, method=method, covariance=cov,
                      observations=len(y), source=source,
                      noise_std=np.full(3, np.nan) if noise_std is None else noise_std,
                      **info)
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
    cal.residual_rms = float(np.sqrt(np.mean(gravity_residuals(cal, None, y, gravity,
                                                               temps) ** 2)))
    return cal


def default_calibration_path():
    """Where the nodes keep the calibration (moved to ``dataio.calibration_file``)."""
    from ..dataio.calibration_file import default_calibration_path as path
    return path()
