"""
The calibration model as data: what a fitted calibration is and how it corrects.

Convention (interface.md §3)::

    raw  = T @ true + bias + drift(raw, temperature)
    true = T⁻¹ @ (raw - bias - drift(raw, temperature))

``T`` is upper triangular and dimensionless (scale x non-orthogonality, Sun & Xu
eq. 1-4), ``bias`` in m/s², ``drift`` from the temperature-band tables (zero when
there are none). The gyroscope bias (interface.md §6) is ``raw = true + gyro_bias``
in rad/s. Optional parts for the other two sensors of the IMU (interface.md §9, §10):

    raw_gyro = gyro_T @ true_rate + gyro_bias            (rad/s)
    raw_mag  = mag.T @ mag.R @ field_body + mag.hard_iron_uT   (µT)

``gyro_T`` is None when the gyroscope's scale and misalignment were not calibrated
(then the rate is only bias-corrected); ``magnetometer`` is None without a
magnetometer calibration. There is one gyro bias, ``gyro_bias`` (a file stores it as
``gyro_bias_rad_s`` and as ``gyro.bias``, always equal). This module is numpy and the
standard library only (no scipy, no file I/O): reading and writing files lives in
``accel_calib_ros.dataio.calibration_file``.
"""

from dataclasses import dataclass, field
import datetime

import numpy as np

from .accelerometer.thermal import ThermalTable
from .constants import G0

METHODS = ('ml', 'ml-bc', 'gn', 'ellipsoid')
"""Fitting methods a calibration can come from."""

PARAMETER_NAMES = ('T_xx', 'T_xy', 'T_xz', 'T_yy', 'T_yz', 'T_zz', 'b_x', 'b_y', 'b_z')
"""Order of the 9 calibration parameters in vectors and covariances (every fit's)."""


MAX_SCALE_ERROR = 0.2
"""Largest accelerometer scale error ``|T_ii - 1|`` believed (consumer MEMS: a few per cent)."""
MAX_CROSS_AXIS = 0.1
"""Largest accelerometer cross-axis term ``|T_ij| / T_ii`` believed."""
MAX_BIAS_G = 0.25
"""Largest accelerometer bias believed, g."""
MAX_GYRO_BIAS = 1.0
"""Largest gyroscope bias believed, rad/s (57 °/s: a larger one means other units)."""
GYRO_T_DIAGONAL_RANGE = (0.5, 2.0)
"""Diagonal of the gyroscope's T believed (a MEMS gyro is within a few per cent of 1)."""
MAX_GYRO_CROSS_AXIS = 0.5
"""Largest off-diagonal entry of the gyroscope's T believed."""
MAG_T_DIAGONAL_RANGE = (0.2, 5.0)
"""Diagonal of the magnetometer's soft iron T believed."""
MAX_HARD_IRON_UT = 5000.0
"""Largest hard iron believed, µT (the AK8963 reads ±4912 µT)."""
FIELD_RANGE_UT = (1.0, 1000.0)
"""Field magnitudes believed, µT (the Earth's is 22-67 µT)."""
MAX_CONDITION = 10.0
"""Largest condition number of a T believed (a real sensor is within a few per cent of 1)."""
ROTATION_TOLERANCE = 1e-6
"""How far a stored rotation may be from one (max |RᵀR - I| and |det R - 1|)."""


def matrix_problems(T, name, diagonal_range):
    """
    Reasons a 3x3 sensor matrix is implausible, or [] (diagonal, orientation, condition).

    :param T: (3, 3) finite matrix.
    :param name: its name in the messages (e.g. 'gyro.T').
    :param diagonal_range: (low, high) allowed for each diagonal entry.
    """
    T = np.asarray(T, float).reshape(3, 3)
    diag = np.diag(T)
    low, high = diagonal_range
    if np.any(diag < low) or np.any(diag > high):
        return [f'the diagonal of {name} must lie in [{low:g}, {high:g}], got '
                f'{np.array2string(diag, precision=4)}']
    if not np.linalg.det(T) > 0:
        return [f'{name} must have a positive determinant (a reflection swaps an axis)']
    cond = np.linalg.cond(T)
    if not cond <= MAX_CONDITION:
        return [f'{name} is ill-conditioned (condition number {cond:.3g} > '
                f'{MAX_CONDITION:g})']
    return []


def gyro_problems(T):
    """Reasons a gyroscope T (3, 3) is implausible for a MEMS gyro in rad/s, or []."""
    problems = matrix_problems(T, 'gyro.T', GYRO_T_DIAGONAL_RANGE)
    off = np.abs(np.asarray(T, float).reshape(3, 3)[~np.eye(3, dtype=bool)])
    if not problems and np.any(off > MAX_GYRO_CROSS_AXIS):
        problems.append(f'gyro.T has a cross-axis term {off.max():.3g} above '
                        f'{MAX_GYRO_CROSS_AXIS:g}')
    return problems


def magnetometer_problems(T, hard_iron_uT, R, field_uT, dip_deg):
    """Reasons a magnetometer calibration is implausible (µT, degrees), or []."""
    problems = matrix_problems(T, 'magnetometer.T', MAG_T_DIAGONAL_RANGE)
    h = np.asarray(hard_iron_uT, float).reshape(3)
    if np.any(np.abs(h) > MAX_HARD_IRON_UT):
        problems.append(f'hard iron {np.abs(h).max():.0f} µT exceeds {MAX_HARD_IRON_UT:g} µT '
                        '(are mx my mz in µT?)')
    R = np.asarray(R, float).reshape(3, 3)
    if np.max(np.abs(R.T @ R - np.eye(3))) > ROTATION_TOLERANCE or \
            abs(np.linalg.det(R) - 1.0) > ROTATION_TOLERANCE:
        problems.append('magnetometer.R must be a rotation matrix (orthonormal, '
                        'determinant +1)')
    low, high = FIELD_RANGE_UT
    if not low <= field_uT <= high:
        problems.append(f'field {field_uT:.3g} µT outside [{low:g}, {high:g}] µT '
                        '(are mx my mz in µT?)')
    if not -90.0 <= dip_deg <= 90.0:
        problems.append(f'dip {dip_deg:.3g}° outside [-90, 90]°')
    return problems


@dataclass(eq=False)          # arrays: equal only to itself
class MagnetometerPart:
    """
    A fitted magnetometer calibration (interface.md §10): ``raw = T @ R @ field + hard_iron``.

    :param T: (3, 3) soft iron, dimensionless (upper triangular as fitted).
    :param hard_iron_uT: (3,) µT, magnetometer frame.
    :param R: (3, 3) rotation from the accelerometer frame to the magnetometer's.
    :param field_uT: local field magnitude, µT.
    :param dip_deg: inclination of the field below the horizontal, degrees.
    :param predicted_accuracy: RMS error of the corrected field over field directions
        uniform on the sphere, µT (from the fit's covariance), or None when unknown.
    :param noise_std_uT: per-sample noise of one axis seen in the fit, µT, or None.
    """

    T: np.ndarray
    hard_iron_uT: np.ndarray
    R: np.ndarray
    field_uT: float
    dip_deg: float
    predicted_accuracy: float = None
    noise_std_uT: float = None

    def __post_init__(self):
        self.T = np.asarray(self.T, dtype=float).reshape(3, 3)
        self.R = np.asarray(self.R, dtype=float).reshape(3, 3)
        self.hard_iron_uT = np.asarray(self.hard_iron_uT, dtype=float).reshape(3).copy()
        self.field_uT = float(self.field_uT)
        self.dip_deg = float(self.dip_deg)
        if self.predicted_accuracy is not None:
            self.predicted_accuracy = float(self.predicted_accuracy)
        if self.noise_std_uT is not None:
            self.noise_std_uT = float(self.noise_std_uT)

    @property
    def correction(self):
        """(3, 3) matrix M with ``field = M @ (raw - hard_iron)``: ``Rᵀ T⁻¹``."""
        return self.R.T @ np.linalg.inv(self.T)

    def correct(self, raw):
        """Field (N, 3) µT in the accelerometer frame from raw readings (N, 3) µT."""
        raw = np.atleast_2d(np.asarray(raw, float))
        return (raw - self.hard_iron_uT) @ self.correction.T


def _optional_vector(value, size):
    """Return ``value`` as a float array of ``size`` entries, or None."""
    if value is None:
        return None
    return np.asarray(value, dtype=float).reshape(size).copy()


@dataclass(eq=False)          # arrays: equal only to itself
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
        orientations uniform on the sphere, from the covariance, m/s² (interface.md §5), or None.
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
    :param gyro_T: (3, 3) gyroscope scale x misalignment (raw = gyro_T @ true + bias),
        or None when only the bias is calibrated (interface.md §9).
    :param gyro_predicted_accuracy: RMS relative error of the corrected rate over rate
        directions uniform on the sphere (0.001 = 0.1 %), or None.
    :param magnetometer: MagnetometerPart, or None (interface.md §10).
    :param input_units: how the fitted readings were turned into m/s², or None (not
        recorded): ``{'accel': 'm/s2' | 'g' | 'counts'}``, with ``counts_per_g`` and
        ``counts_offset`` for counts. ``T`` absorbs a counts conversion, so the
        calibration is right only for readings converted the same way.
    """

    T: np.ndarray
    bias: np.ndarray
    gravity: float = G0
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
    gyro_T: np.ndarray = None
    gyro_predicted_accuracy: float = None
    magnetometer: MagnetometerPart = None
    input_units: dict = None

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
        if self.gyro_T is not None:
            self.gyro_T = np.asarray(self.gyro_T, dtype=float).reshape(3, 3).copy()
        if self.gyro_predicted_accuracy is not None:
            self.gyro_predicted_accuracy = float(self.gyro_predicted_accuracy)
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

    @property
    def hysteresis(self):
        """Return the heating/cooling term of the thermal tables (``Hysteresis``), or None."""
        return None if self.thermal is None else self.thermal.hysteresis

    def lag_stream(self):
        """Return the temperature lag to carry across pieces of a recording, or None."""
        from .accelerometer.thermal_lag import LagStream
        h = self.hysteresis
        return None if h is None else LagStream(h.tau_s, h.gap_s)

    def hysteresis_offset(self, time, temp, stream=None):
        """
        Return the heating/cooling offset (N, 3) m/s² of readings at ``time`` (N,) s.

        Zero without a hysteresis term, times or temperatures. ``stream`` (``lag_stream``)
        carries the temperature's lag from one piece of a recording to the next; without
        it the lag starts in equilibrium at the first reading.
        """
        h = self.hysteresis
        if h is None or time is None or temp is None:
            return 0.0
        stream = stream or self.lag_stream()
        return np.outer(stream.gradient(time, temp), h.offset_per_c)

    def correct(self, raw, temp=None, time=None, stream=None):
        """
        Calibrated acceleration (N, 3) m/s² from raw readings (N, 3) m/s².

        :param temp: (N,) °C, or None. :param time: (N,) s: with ``temp``, the thermal
            tables' hysteresis term applies (``hysteresis_offset``; ``stream`` carries it
            across pieces).
        """
        raw = np.atleast_2d(np.asarray(raw, float))
        offset = self.bias + self.drift(raw, temp) + self.hysteresis_offset(time, temp, stream)
        return np.linalg.solve(self.T, (raw - offset).T).T

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
        """
        Angular rate (N, 3) rad/s: ``gyro_T⁻¹ (raw - bias)``, or ``raw - bias`` without T.

        The bias is the one of :meth:`gyro_bias_at` (per temperature band when the tables
        carry one); without any gyro calibration the rate passes through.
        """
        gyro = np.atleast_2d(np.asarray(gyro, float))
        rate = gyro - self.gyro_bias_at(temp, len(gyro))
        if self.gyro_T is None:
            return rate
        return np.linalg.solve(self.gyro_T, rate.T).T

    def correct_mag(self, mag):
        """
        Magnetic field (N, 3) µT in the accelerometer frame from raw readings (N, 3) µT.

        Without a magnetometer calibration the field passes through; NaN rows stay NaN.
        """
        mag = np.atleast_2d(np.asarray(mag, float))
        if self.magnetometer is None:
            return mag
        return self.magnetometer.correct(mag)

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

    def physical_problems(self, max_scale_error=MAX_SCALE_ERROR, max_cross_axis=MAX_CROSS_AXIS,
                          max_bias_g=MAX_BIAS_G):
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
