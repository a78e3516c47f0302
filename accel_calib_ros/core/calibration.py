"""
The calibration model: fit it, apply it, check it, save and load it.

Convention (spec section 3)::

    raw  = T @ true + bias + drift(raw, temperature)
    true = T⁻¹ @ (raw - bias - drift(raw, temperature))

``T`` is upper triangular and dimensionless (scale x non-orthogonality, Sun & Xu
eq. 1-4), ``bias`` in m/s², ``drift`` from the temperature-band tables (zero when
there are none). Files are versioned, human-readable YAML with units in the keys.
"""

from dataclasses import dataclass, field
import datetime
import os
import time

import numpy as np
import yaml

from .ellipsoid import fit_ellipsoid
from .errors import CalibrationError, InputError
from .gn import fit_gn
from .ml import fit_ml, fit_ml_bias_corrected, PARAMETER_NAMES
from .thermal import fit_thermal_table, ThermalTable
from .windows import distinct_directions

FORMAT = 'accel_calib_ros/calibration'
VERSION = 1
METHODS = ('ml', 'ml-bc', 'gn', 'ellipsoid')


@dataclass
class Calibration:
    """
    A fitted accelerometer calibration (see module docstring for the model).

    :param T: (3, 3) upper triangular, dimensionless.
    :param bias: (3,) m/s².
    :param gravity: local gravity magnitude used for the fit, m/s².
    :param covariance: (9, 9) covariance of (T upper row-major, bias), or None.
    :param residual_rms: RMS of |corrected| - gravity over the observations, m/s².
    :param noise_std: (3,) per-sample noise measured inside static windows, m/s².
    """

    T: np.ndarray
    bias: np.ndarray
    gravity: float = 9.80665
    method: str = 'ml'
    covariance: np.ndarray = None
    residual_rms: float = float('nan')
    noise_std: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))
    observations: int = 0
    iterations: int = 0
    converged: bool = True
    seconds: float = 0.0
    trace: list = field(default_factory=list)
    thermal: ThermalTable = None
    created: str = ''
    source: str = ''

    def __post_init__(self):
        self.T = np.asarray(self.T, dtype=float).reshape(3, 3)
        self.bias = np.asarray(self.bias, dtype=float).reshape(3)
        self.noise_std = np.broadcast_to(np.asarray(self.noise_std, float), (3,)).copy()
        if not self.created:
            self.created = datetime.datetime.now(datetime.timezone.utc).isoformat(
                timespec='seconds')

    # -- physics -----------------------------------------------------------------------
    @property
    def scale(self):
        """Sensitivity of each axis (row norms of T), raw per true, dimensionless (3,)."""
        return np.linalg.norm(self.T, axis=1)

    @property
    def nonorthogonality_deg(self):
        """Angles between the sensitive axes minus 90°, (xy, xz, yz) in degrees."""
        axes = self.T / self.scale[:, None]
        pairs = ((0, 1), (0, 2), (1, 2))
        return np.array([90.0 - np.degrees(np.arccos(np.clip(axes[i] @ axes[j], -1, 1)))
                         for i, j in pairs])

    def drift(self, raw, temp=None):
        """Return the temperature drift, m/s² (N, 3), of raw readings (N, 3) at temps °C (N,)."""
        raw = np.atleast_2d(np.asarray(raw, float))
        if self.thermal is None or temp is None:
            return np.zeros_like(raw)
        return self.thermal.drift(raw, temp)

    def correct(self, raw, temp=None):
        """Calibrated acceleration (N, 3) m/s² from raw readings (N, 3) m/s²."""
        raw = np.atleast_2d(np.asarray(raw, float))
        return np.linalg.solve(self.T, (raw - self.bias - self.drift(raw, temp)).T).T

    def distort(self, true, temp=None):
        """Raw readings (N, 3) that this model predicts for true acceleration (N, 3)."""
        true = np.atleast_2d(np.asarray(true, float))
        raw = true @ self.T.T + self.bias
        if self.thermal is not None and temp is not None:
            for _ in range(4):            # drift depends on raw: fixed point, converges fast
                raw = true @ self.T.T + self.bias + self.drift(raw, temp)
        return raw

    def acceleration_covariance(self):
        """
        3x3 covariance of one corrected sample at rest, (m/s²)², row-major.

        Sensor noise mapped through T⁻¹ plus the parameter uncertainty propagated to
        a gravity-sized vector, averaged over directions.
        """
        R = np.linalg.inv(self.T)
        noise = np.where(np.isfinite(self.noise_std), self.noise_std, 0.0)
        cov = R @ np.diag(noise ** 2) @ R.T
        if self.covariance is not None and np.all(np.isfinite(self.covariance)):
            rows, cols = np.triu_indices(3)
            acc = np.zeros((3, 3))
            for a0 in np.vstack([np.eye(3), -np.eye(3)]) * self.gravity:
                J = np.zeros((3, 9))
                for k, (i, j) in enumerate(zip(rows, cols)):
                    J[:, k] = -R[:, i] * a0[j]
                J[:, 6:] = -R
                acc += J @ self.covariance @ J.T
            cov = cov + acc / 6.0
        return cov

    def physical_problems(self, max_scale_error=0.2, max_cross_axis=0.1, max_bias_g=0.25):
        """Reasons this calibration is not physical for an accelerometer in m/s², or []."""
        problems = []
        scale_error = np.abs(np.diag(self.T) - 1.0)
        if np.any(scale_error > max_scale_error):
            problems.append(f'scale error {scale_error.max():.1%} exceeds '
                            f'{max_scale_error:.0%}')
        cross = np.abs(self.T[np.triu_indices(3, 1)]) / np.diag(self.T)[[0, 0, 1]]
        if np.any(cross > max_cross_axis):
            problems.append(f'cross-axis term {cross.max():.1%} exceeds {max_cross_axis:.0%}')
        if np.any(np.abs(self.bias) > max_bias_g * self.gravity):
            problems.append(f'bias {np.abs(self.bias).max():.2f} m/s² exceeds '
                            f'{max_bias_g} g')
        return problems

    # -- files -------------------------------------------------------------------------
    def to_dict(self):
        """Versioned, YAML-ready mapping with units in the key names."""
        d = {
            'format': FORMAT, 'version': VERSION, 'created': self.created, 'source': self.source,
            'model': 'raw = T @ true + bias + drift(raw, temp); '
            'true = inv(T) @ (raw - bias - drift(raw, temp))',
            'method': self.method, 'gravity_m_s2': float(self.gravity),
            'T': [[float(v) for v in row] for row in self.T],
            'bias_m_s2': [float(v) for v in self.bias],
            'scale': [float(v) for v in self.scale],
            'nonorthogonality_deg': dict(zip(('xy', 'xz', 'yz'),
                                             (float(v) for v in self.nonorthogonality_deg))),
            'fit': {'observations': int(self.observations), 'iterations': int(self.iterations),
                    'converged': bool(self.converged), 'seconds': float(self.seconds),
                    'residual_rms_m_s2': float(self.residual_rms),
                    'noise_std_m_s2': [float(v) for v in self.noise_std]},
        }
        if self.covariance is not None:
            d['covariance'] = {
                'order': list(PARAMETER_NAMES), 'units': 'T dimensionless, b in m/s2',
                'matrix': [[float(v) for v in row] for row in self.covariance]}
        if self.thermal is not None:
            d['thermal'] = self.thermal.to_dict()
        return d

    @classmethod
    def from_dict(cls, d):
        """Build from :meth:`to_dict` output; InputError on anything malformed."""
        if not isinstance(d, dict) or d.get('format') != FORMAT:
            raise InputError(f'not an accel_calib_ros calibration file (format != {FORMAT})')
        if d.get('version') != VERSION:
            raise InputError(f'calibration file version {d.get("version")} is not supported '
                             f'(this is version {VERSION})')
        try:
            fit = d.get('fit', {})
            cov = d.get('covariance')
            cal = cls(
                T=np.asarray(d['T'], float), bias=np.asarray(d['bias_m_s2'], float),
                gravity=float(d['gravity_m_s2']), method=str(d['method']),
                covariance=None if cov is None else np.asarray(cov['matrix'], float),
                residual_rms=float(fit.get('residual_rms_m_s2', float('nan'))),
                noise_std=np.asarray(fit.get('noise_std_m_s2', [np.nan] * 3), float),
                observations=int(fit.get('observations', 0)),
                iterations=int(fit.get('iterations', 0)),
                converged=bool(fit.get('converged', True)),
                seconds=float(fit.get('seconds', 0.0)),
                thermal=ThermalTable.from_dict(d['thermal']) if d.get('thermal') else None,
                created=str(d.get('created', '')), source=str(d.get('source', '')))
        except (KeyError, TypeError, ValueError) as err:
            raise InputError(f'calibration file is malformed: {err!r}') from None
        if not np.all(np.isfinite(cal.T)) or np.any(np.diag(cal.T) <= 0) \
                or np.any(np.tril(cal.T, -1) != 0) or not np.all(np.isfinite(cal.bias)):
            raise InputError('calibration file holds a non-physical T or bias')
        return cal

    def to_yaml(self):
        """YAML text of :meth:`to_dict`."""
        return yaml.safe_dump(self.to_dict(), sort_keys=False, default_flow_style=None,
                              width=100)

    def save(self, path):
        """Write the calibration atomically (a reader never sees a half-written file)."""
        from ..dataio.atomic import atomic_write_text
        atomic_write_text(path, self.to_yaml())

    @classmethod
    def load(cls, path):
        """Read a calibration file; InputError with a one-line reason if unusable."""
        try:
            with open(path, encoding='utf-8') as f:
                data = yaml.safe_load(f)
        except FileNotFoundError:
            raise InputError(f'calibration file not found: {path}') from None
        except (OSError, yaml.YAMLError) as err:
            raise InputError(f'cannot read calibration file {path}: '
                             f'{str(err).splitlines()[0]}') from None
        return cls.from_dict(data)


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
    """Where the nodes keep the calibration unless told otherwise."""
    root = os.environ.get('ROS_HOME', os.path.join(os.path.expanduser('~'), '.ros'))
    return os.path.join(root, 'accel_calib_ros', 'calibration.yaml')
