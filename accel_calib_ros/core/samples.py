"""The sample stream every part of the package passes around."""

from dataclasses import dataclass
from typing import Optional

import numpy as np

from .errors import InputError
from .stats import median

MAX_ABS = {'time': 1e12, 'acceleration': 1e6, 'temperature': 1e3, 'gyro': 1e6,
           'magnetic field': 1e6}
"""Largest magnitude believed per quantity (s, m/s² or raw counts, °C, rad/s, µT)."""


def _bad_rows(values, limit):
    """Boolean (N,) rows holding a NaN, an infinity or a magnitude beyond ``limit``."""
    with np.errstate(invalid='ignore'):
        ok = np.isfinite(values) & (np.abs(values) <= limit)
    return ~(ok if ok.ndim == 1 else ok.all(axis=1))


@dataclass(eq=False)          # arrays: equal only to itself
class Samples:
    """
    A recording of accelerometer samples, SI units (REP-103).

    :param t: sample times, shape (N,), seconds, non-decreasing.
    :param accel: raw specific force, shape (N, 3), m/s².
    :param temp: sensor temperature, shape (N,), °C, or None when not recorded.
    :param gyro: angular rate, shape (N, 3), rad/s, or None when not recorded.
    :param mag: magnetic field, shape (N, 3), µT in the accelerometer's frame, or None
        when not recorded; a row of three NaN where that row has no magnetometer sample
        (the magnetometer runs slower than the accelerometer).
    """

    t: np.ndarray
    accel: np.ndarray
    temp: Optional[np.ndarray] = None
    gyro: Optional[np.ndarray] = None
    mag: Optional[np.ndarray] = None

    def __post_init__(self):
        self.t = np.asarray(self.t, dtype=float).reshape(-1)
        self.accel = np.asarray(self.accel, dtype=float).reshape(-1, 3)
        n = len(self.t)
        if len(self.accel) != n:
            raise InputError(f'{len(self.accel)} acceleration rows for {n} times')
        if self.temp is not None:
            self.temp = np.asarray(self.temp, dtype=float).reshape(-1)
            if len(self.temp) != n:
                raise InputError(f'{len(self.temp)} temperature rows for {n} times')
        if self.gyro is not None:
            self.gyro = np.asarray(self.gyro, dtype=float).reshape(-1, 3)
            if len(self.gyro) != n:
                raise InputError(f'{len(self.gyro)} gyro rows for {n} times')
        if self.mag is not None:
            self.mag = np.asarray(self.mag, dtype=float).reshape(-1, 3)
            if len(self.mag) != n:
                raise InputError(f'{len(self.mag)} magnetometer rows for {n} times')

    def __len__(self):
        return len(self.t)

    def validate(self):
        """Raise InputError unless the samples are usable (finite, time-ordered, non-empty)."""
        if len(self) == 0:
            raise InputError('no samples: the recording is empty')
        if _bad_rows(self.t, MAX_ABS['time']).any():
            raise InputError(f'{int(_bad_rows(self.t, MAX_ABS["time"]).sum())} rows hold a '
                             'NaN, infinite or implausible time')
        for what, values in (('acceleration', self.accel), ('gyro', self.gyro),
                             ('temperature', self.temp)):
            if values is None:
                continue
            bad = _bad_rows(values, MAX_ABS[what])
            if bad.any():
                first = int(np.argmax(bad))
                raise InputError(
                    f'{int(bad.sum())} rows hold NaN, infinite or implausibly large '
                    f'(beyond {MAX_ABS[what]:g}) {what} (first at row {first}, '
                    f't={self.t[first]:.3f} s); clean or drop them')
        if self.mag is not None:
            # Rows without a magnetometer sample are all NaN; anything else must be sane.
            bad = _bad_rows(self.mag[~np.all(np.isnan(self.mag), axis=1)],
                            MAX_ABS['magnetic field'])
            if bad.any():
                raise InputError(
                    f'{int(bad.sum())} magnetometer rows hold a partly missing, infinite or '
                    f'implausibly large (beyond {MAX_ABS["magnetic field"]:g} µT) field; '
                    'a row without a sample must leave all three cells empty')
        if np.any(np.diff(self.t) < 0):
            raise InputError('time column is not in increasing order')
        return self

    @property
    def mag_rows(self):
        """Boolean (N,) rows holding a magnetometer sample (all False without one)."""
        if self.mag is None:
            return np.zeros(len(self), bool)
        return np.all(np.isfinite(self.mag), axis=1)

    @property
    def rate_hz(self):
        """Median sample rate in Hz (NaN with fewer than two samples)."""
        if len(self) < 2:
            return float('nan')
        dt = median(np.diff(self.t))
        return float(1.0 / dt) if dt > 0 else float('nan')

    def subset(self, index):
        """Return the samples selected by a slice or index array."""
        return Samples(
            self.t[index], self.accel[index],
            None if self.temp is None else self.temp[index],
            None if self.gyro is None else self.gyro[index],
            None if self.mag is None else self.mag[index])
