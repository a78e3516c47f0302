"""The sample stream every part of the package passes around."""

from dataclasses import dataclass
from typing import Optional

import numpy as np

from .errors import InputError


@dataclass
class Samples:
    """
    A recording of accelerometer samples, SI units (REP-103).

    :param t: sample times, shape (N,), seconds, non-decreasing.
    :param accel: raw specific force, shape (N, 3), m/s².
    :param temp: sensor temperature, shape (N,), °C, or None when not recorded.
    :param gyro: angular rate, shape (N, 3), rad/s, or None when not recorded.
    """

    t: np.ndarray
    accel: np.ndarray
    temp: Optional[np.ndarray] = None
    gyro: Optional[np.ndarray] = None

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

    def __len__(self):
        return len(self.t)

    def validate(self):
        """Raise InputError unless the samples are usable (finite, time-ordered, non-empty)."""
        if len(self) == 0:
            raise InputError('no samples: the recording is empty')
        if not np.all(np.isfinite(self.t)):
            raise InputError('time column holds NaN or infinite values')
        bad = ~np.all(np.isfinite(self.accel), axis=1)
        if bad.any():
            first = int(np.argmax(bad))
            raise InputError(
                f'{int(bad.sum())} rows hold NaN or infinite acceleration '
                f'(first at row {first}, t={self.t[first]:.3f} s); clean or drop them')
        if self.temp is not None and not np.all(np.isfinite(self.temp)):
            raise InputError('temperature column holds NaN or infinite values')
        if np.any(np.diff(self.t) < 0):
            raise InputError('time column is not in increasing order')
        return self

    @property
    def rate_hz(self):
        """Median sample rate in Hz (NaN with fewer than two samples)."""
        if len(self) < 2:
            return float('nan')
        dt = np.median(np.diff(self.t))
        return float(1.0 / dt) if dt > 0 else float('nan')

    def subset(self, index):
        """Return the samples selected by a slice or index array."""
        return Samples(
            self.t[index], self.accel[index],
            None if self.temp is None else self.temp[index],
            None if self.gyro is None else self.gyro[index])
