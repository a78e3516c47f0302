"""
The calibration model as data: what a fitted calibration is and how it corrects.

Convention (spec section 3)::

    raw  = T @ true + bias + drift(raw, temperature)
    true = T⁻¹ @ (raw - bias - drift(raw, temperature))

``T`` is upper triangular and dimensionless (scale x non-orthogonality, Sun & Xu
eq. 1-4), ``bias`` in m/s², ``drift`` from the temperature-band tables (zero when
there are none). The gyroscope bias (spec section 6) is ``raw = true + gyro_bias``
in rad/s. This module is numpy and the standard library only (no scipy, no file
I/O): reading and writing files lives in ``accel_calib_ros.dataio.calibration_file``.
"""

from dataclasses import dataclass, field
import datetime

import numpy as np

from .accel.thermal import ThermalTable

METHODS = ('ml', 'ml-bc', 'gn', 'ellipsoid')
"""Fitting methods a calibration can come from."""

PARAMETER_NAMES = ('T_xx', 'T_xy', 'T_xz', 'T_yy', 'T_yz', 'T_zz', 'b_x', 'b_y', 'b_z')
"""Order of the 9 calibration parameters in covariances (same as ``core.ml``)."""


def _optional_vector(value, size):
    """Return ``value`` as a float array of ``size`` entries, or None."""
    if value is None:
        return None
    return np.asarray(value, dtype=float).reshape(size).copy()


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
    :param predicted_accuracy: RMS error of the corrected acceleration at 1 g over
        orientations uniform on the sphere, from the covariance, m/s² (spec §5), or None.
    :param gyro_bias: (3,) gyroscope bias, rad/s (raw = true + bias), or None.
    :param temperature_range_c: (min, max) temperature of the data the fit used, °C.
    :param level_roll_pitch_rad: (roll, pitch) of the sensor relative to the robot
        base, rad ("level trim"), or None.
    :param sensor_id: name of the sensor the calibration belongs to, or None.
    :param cross_axis: ``gn`` only: what the cross-axis terms it holds at zero cost
        (``core.information.CrossAxis``, part of ``predicted_accuracy``), or None.
    :param information: the information of the observations of the fit
        (``core.information.Information``: the source of the poses a refusal names);
        not stored in files.
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
    predicted_accuracy: float = None
    gyro_bias: np.ndarray = None
    temperature_range_c: tuple = None
    level_roll_pitch_rad: tuple = None
    sensor_id: str = None
    cross_axis: object = None
    information: object = None

    def __post_init__(self):
        self.T = np.asarray(self.T, dtype=float).reshape(3, 3)
        self.bias = np.asarray(self.bias, dtype=float).reshape(3)
        self.noise_std = np.broadcast_to(
            np.asarray(np.nan if self.noise_std is None else self.noise_std, float),
            (3,)).copy()
        if self.covariance is not None:
            self.covariance = np.asarray(self.covariance, dtype=float).reshape(9, 9)
        self.gyro_bias = _optional_vector(self.gyro_bias, 3)
        if self.temperature_range_c is not None:
            self.temperature_range_c = tuple(float(v) for v in self.temperature_range_c)
        if self.level_roll_pitch_rad is not None:
            self.level_roll_pitch_rad = tuple(float(v) for v in self.level_roll_pitch_rad)
        if self.predicted_accuracy is not None:
            self.predicted_accuracy = float(self.predicted_accuracy)
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

    def gyro_bias_at(self, temp=None, count=1):
        """
        Gyroscope bias to subtract, rad/s, shape (N, 3).

        Per temperature band when the thermal tables carry a gyro bias (interpolated
        like the drift), else the single ``gyro_bias``, else zero.

        :param temp: (N,) temperatures, °C, or None.
        :param count: N when ``temp`` is None.
        """
        n = count if temp is None else len(np.atleast_1d(temp))
        if self.thermal is not None and temp is not None:
            banded = self.thermal.gyro_bias(temp)
            if banded is not None:
                if self.gyro_bias is not None:
                    missing = ~np.all(np.isfinite(banded), axis=1)
                    banded[missing] = self.gyro_bias
                return np.where(np.isfinite(banded), banded, 0.0)
        if self.gyro_bias is None:
            return np.zeros((n, 3))
        return np.tile(self.gyro_bias, (n, 1))

    def correct_gyro(self, gyro, temp=None):
        """Angular rate (N, 3) rad/s with the gyroscope bias removed."""
        gyro = np.atleast_2d(np.asarray(gyro, float))
        return gyro - self.gyro_bias_at(temp, len(gyro))

    def level_rotation(self):
        """
        Rotation (3, 3) from the sensor frame to the robot base frame ("level trim").

        ``level_roll_pitch_rad`` = (roll, pitch) are the ZYX Euler angles (yaw 0) of
        the sensor relative to the base, as read from gravity while the robot rests
        level: roll = atan2(a_y, a_z), pitch = atan2(-a_x, hypot(a_y, a_z)). The
        rotation is ``Ry(pitch) @ Rx(roll)``, so ``level_rotation() @ a`` is
        (0, 0, |a|) for that resting reading ``a``. Identity when no trim is stored.
        """
        if self.level_roll_pitch_rad is None:
            return np.eye(3)
        roll, pitch = self.level_roll_pitch_rad
        cr, sr, cp, sp = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch)
        rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
        ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
        return ry @ rx

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
