"""
The correction of one calibration, sample by sample: what the correction node applies.

:class:`Corrector` precomputes a calibration (``core.calibration.Calibration``) into
plain-float 3x3 arithmetic, so that one sample costs a few microseconds in Python:

- acceleration ``L · T⁻¹ · (raw − bias − drift(raw, temperature) − hysteresis)`` and its
  covariance; the hysteresis term of a one-pose thermal calibration follows the
  temperature stream's lag (``take_temperature``: the same ``LagState`` as ``apply``'s
  stream, restarted by a gap, carried over a reload of the same term: ``adopt``);
- angular rate ``L · Tg⁻¹ · (raw − gyro bias at the temperature)`` (or ``L · (raw −
  bias)`` without a gyro T) and the covariance to publish for the driver's;
- magnetic field ``L · Rᵀ · T⁻¹ · (raw − hard iron)`` (tesla in, tesla out) and its
  covariance.

``L`` is the level trim (identity without one). The filter and node split of imu_tools:
this module is the filter (numpy and the standard library, no ROS); the correction node
keeps the parameters, the messages and the diagnostics.
"""

import math

import numpy as np

from .constants import TESLA_PER_UT
from .errors import InputError

UNCALIBRATED_STD = 0.5
"""Per-axis standard deviation reported while no calibration is loaded, m/s²."""
UNCALIBRATED_COVARIANCE = np.diag([UNCALIBRATED_STD ** 2] * 3).reshape(9)
UNCALIBRATED_GYRO_BIAS_STD = math.radians(2.5)
"""Zero-rate offset left in an uncorrected gyro, rad/s (MPU-9250 datasheet ±5 °/s as 2σ)."""


def _matrix_tuple(m):
    return tuple(tuple(float(v) for v in row) for row in m)


def _apply(m, x, y, z):
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = m
    return (r00 * x + r01 * y + r02 * z,
            r10 * x + r11 * y + r12 * z,
            r20 * x + r21 * y + r22 * z)


class Corrector:
    """
    Precomputed correction of one calibration: plain-float 3x3 math per sample.

    :param cal: Calibration, or None for the pass-through.
    """

    def __init__(self, cal=None):
        self.cal = cal
        if cal is None:
            self.M = None
            self.L = None
            self.bias = (0.0, 0.0, 0.0)
            self.covariance = UNCALIBRATED_COVARIANCE.copy()
            self.gyro_bias = None
        else:
            L = np.asarray(cal.level_rotation(), float)
            R = np.linalg.inv(np.asarray(cal.T, float))
            self.M = _matrix_tuple(L @ R)
            self.L = None if np.array_equal(L, np.eye(3)) else _matrix_tuple(L)
            self.bias = tuple(float(v) for v in cal.bias)
            cov = L @ np.asarray(cal.acceleration_covariance(), float) @ L.T
            self.covariance = np.ascontiguousarray(cov, dtype=np.float64).reshape(9)
            self.gyro_bias = None if cal.gyro_bias is None else \
                tuple(float(v) for v in cal.gyro_bias)
            if not (np.all(np.isfinite(self.covariance)) and np.all(np.isfinite(self.M))
                    and all(map(math.isfinite, self.bias))):
                raise InputError('the calibration gives non-finite corrections')
        self._drift_temp = None
        self._coef = None
        h = None if cal is None else cal.hysteresis
        self.hysteresis = None if h is None else tuple(float(v) for v in h.offset_per_c)
        self.lag = None
        if h is not None:
            from .accelerometer.thermal_lag import LagState
            self.lag = LagState(h.tau_s, h.gap_s)
        self._hysteresis_offset = (0.0, 0.0, 0.0)
        self.cov_key = None         # incoming covariances last judged (bytes) ...
        self.wcov = None            # ... the angular-velocity covariance to publish for
        self.cov_finite = True      # them (None = as it came), and whether all are finite
        self._gyro_temp = None
        self.trimmed = cal is not None and cal.level_roll_pitch_rad is not None
        self._banded_gyro = cal is not None and cal.thermal is not None and \
            cal.thermal.gyro_bias(np.array([25.0])) is not None
        self._imu_parts(cal)

    def _imu_parts(self, cal):
        """Precompute the gyroscope T and the magnetometer correction (interface.md §9, §10)."""
        self.gyro_M = None          # L Tg⁻¹, or None without a gyro T
        self.gyro_rate_var = 0.0    # (predicted accuracy)² / 3: variance per axis per |ω|²
        self.mag_M = None           # L Rᵀ T⁻¹ of the magnetometer, or None
        self.mag_hard_iron = (0.0, 0.0, 0.0)
        self.mag_base_cov = None    # (9,) T²: calibration part, plus the fit's noise
        self.mag_cal_var = 0.0      # T² per axis from the calibration's uncertainty
        if cal is None:
            return
        L = np.asarray(cal.level_rotation(), float)
        if cal.gyro_T is not None:
            M = L @ np.linalg.inv(cal.gyro_T)
            if not np.all(np.isfinite(M)):
                raise InputError('the gyro calibration gives non-finite corrections')
            self.gyro_M = _matrix_tuple(M)
            acc = cal.gyro_predicted_accuracy
            self.gyro_rate_var = 0.0 if acc is None else acc ** 2 / 3.0
        mag = cal.magnetometer
        if mag is not None:
            M = L @ mag.correction
            acc = mag.predicted_accuracy
            self.mag_cal_var = 0.0 if acc is None else (acc * TESLA_PER_UT) ** 2 / 3.0
            noise = mag.noise_std_uT     # without it an unknown covariance stays unknown
            base = np.zeros((3, 3)) if noise is None else \
                np.eye(3) * self.mag_cal_var + M @ M.T * (noise * TESLA_PER_UT) ** 2
            self.mag_base_cov = np.ascontiguousarray(base, dtype=np.float64).reshape(9)
            if not (np.all(np.isfinite(M)) and np.all(np.isfinite(mag.hard_iron_uT))):
                raise InputError('the magnetometer calibration gives non-finite corrections')
            self.mag_M = _matrix_tuple(M)
            self.mag_hard_iron = tuple(float(v) for v in mag.hard_iron_uT)

    def gyro_words(self):
        """Say what the angular-velocity correction does ('none' without one)."""
        if self.gyro_M is not None:
            return 'bias, scale and misalignment'
        return 'bias' if self.gyro_bias is not None else 'none'

    def correct_mag(self, x, y, z):
        """Corrected field (x, y, z) tesla from a raw one in tesla (needs ``mag_M``)."""
        hx, hy, hz = self.mag_hard_iron
        k = 1.0 / TESLA_PER_UT
        x, y, z = _apply(self.mag_M, x * k - hx, y * k - hy, z * k - hz)
        return x * TESLA_PER_UT, y * TESLA_PER_UT, z * TESLA_PER_UT

    def mag_covariance(self, cov):
        """
        Return the covariance (9,) tesla² of a corrected field for the driver's ``cov`` (9,).

        A known driver covariance is mapped through the correction; an unknown one (all
        zeros or ``[0] = -1``) is replaced by the fit's per-sample noise mapped the same
        way (zeros, unknown, when the file has no noise); the calibration's own
        uncertainty is added on the diagonal.
        """
        c = np.asarray(cov, float).reshape(3, 3)
        if c[0, 0] < 0.0 or not np.any(c):
            return self.mag_base_cov
        M = np.asarray(self.mag_M)
        out = M @ c @ M.T + np.eye(3) * self.mag_cal_var
        return np.ascontiguousarray(out, dtype=np.float64).reshape(9)

    def coefficients(self, temp):
        """Drift (quadratic, linear, offset) per axis at ``temp`` °C, or None (no drift)."""
        cal = self.cal
        if cal is None or cal.thermal is None or not cal.thermal.usable \
                or not math.isfinite(temp):
            return None
        if temp != self._drift_temp:      # temperature changes far slower than samples
            quad, lin, off = cal.thermal.coefficients(np.array([temp]))
            coef = tuple(zip(quad[0].tolist(), lin[0].tolist(), off[0].tolist()))
            self._coef = coef if all(map(math.isfinite, sum(coef, ()))) else None
            self._drift_temp = temp
        return self._coef

    def take_temperature(self, time_s, temp):
        """
        Follow the temperature stream (stamp s, °C) for the hysteresis term; return its gradient.

        The lag restarts (gradient 0) after a silence longer than its ``gap_s`` or a step
        back in time (``lag.restarts`` counts them); without a hysteresis term, 0.
        """
        if self.lag is None:
            return 0.0
        g = self.lag.update(time_s, temp)
        kx, ky, kz = self.hysteresis
        self._hysteresis_offset = (kx * g, ky * g, kz * g)
        return g

    def adopt(self, previous):
        """
        Keep the temperature lag of the corrector this one replaces (a reload of the file).

        Only when both carry a hysteresis term with the same time constant: the lag is a
        property of the temperature stream, not of the file.
        """
        if (self.lag is not None and previous is not None and previous.lag is not None
                and previous.lag.tau_s == self.lag.tau_s):
            self.lag = previous.lag
            if self.lag.lag is not None:
                g = self.lag.gradient
                kx, ky, kz = self.hysteresis
                self._hysteresis_offset = (kx * g, ky * g, kz * g)

    def outside(self, temp, margin_c=0.0):
        """Tell whether ``temp`` °C lies beyond the calibrated temperature range (+ margin)."""
        cal = self.cal
        if cal is None or not math.isfinite(temp):
            return False
        span = cal.thermal.range_c if cal.thermal is not None else None
        span = span or cal.temperature_range_c
        return span is not None and not span[0] - margin_c <= temp <= span[1] + margin_c

    def correct(self, x, y, z, temp):
        """Corrected (and levelled) (x, y, z) m/s² for one raw sample at ``temp`` °C."""
        if self.M is None:
            return x, y, z
        bx, by, bz = self.bias
        if self.lag is not None:
            hx, hy, hz = self._hysteresis_offset
            bx, by, bz = bx + hx, by + hy, bz + hz
        coef = self.coefficients(temp)
        if coef is not None:
            (qx, lx, ox), (qy, ly, oy), (qz, lz, oz) = coef
            bx += qx * x * x + lx * x + ox
            by += qy * y * y + ly * y + oy
            bz += qz * z * z + lz * z + oz
        return _apply(self.M, x - bx, y - by, z - bz)

    def gyro_bias_at(self, temp):
        """Return the gyro bias (3,) rad/s to subtract at ``temp`` °C, or None."""
        if not self._banded_gyro or not math.isfinite(temp):
            return self.gyro_bias
        if temp != self._gyro_temp:
            bias = self.cal.gyro_bias_at(np.array([temp]))[0]
            self._gyro_at = tuple(float(v) for v in bias) \
                if np.all(np.isfinite(bias)) else self.gyro_bias
            self._gyro_temp = temp
        return self._gyro_at

    def correct_gyro(self, x, y, z, temp):
        """Angular rate (x, y, z) rad/s without the bias (and T), in the levelled frame."""
        bias = self.gyro_bias_at(temp)
        if bias is not None:
            x, y, z = x - bias[0], y - bias[1], z - bias[2]
        if self.gyro_M is not None:
            return _apply(self.gyro_M, x, y, z)
        if self.L is not None:
            return _apply(self.L, x, y, z)
        return x, y, z

    def gyro_covariance(self, cov):
        """
        Return the angular-velocity covariance to publish for the driver's ``cov`` (9,).

        None (publish it as it came) when the driver reports none (``[0] = -1``) or
        unknown (all zeros), or when the gyro bias is removed and neither a gyro T nor a
        level trim maps it; else what is left (plus the uncorrected zero-rate offset),
        mapped by ``L Tg⁻¹`` (the rate-dependent part of the calibration's uncertainty is
        added per message: :attr:`gyro_rate_var`).
        """
        c = np.asarray(cov, float).reshape(3, 3)
        if (self.gyro_bias is not None and self.L is None and self.gyro_M is None) \
                or c[0, 0] < 0.0 or not np.any(c):
            return None
        if self.gyro_bias is None:
            c = c + np.eye(3) * UNCALIBRATED_GYRO_BIAS_STD ** 2
        M = self.gyro_M if self.gyro_M is not None else self.L
        if M is not None:
            M = np.asarray(M)
            c = M @ c @ M.T
        return np.ascontiguousarray(c, dtype=np.float64).reshape(9)


def without_level(cal):
    """Return a copy of ``cal`` without its level trim (the trim is measured afresh)."""
    import copy
    plain = copy.copy(cal)
    plain.level_roll_pitch_rad = None
    return plain
