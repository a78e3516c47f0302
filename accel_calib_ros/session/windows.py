"""
Static windows as every front door collects them, and the observations a fit gets.

A :class:`Window` is one held pose: the mean and scatter of its acceleration, its sample
count, its times, its temperature and (when the source gives the rate) its mean angular
rate. The node's streaming detector and the guide's hold tracker produce them one at a
time (:meth:`Window.from_detector` reads their dicts); ``accel-calib fit`` detects them
all at once (:meth:`WindowSet.from_static`). A :class:`WindowSet` holds them as arrays:
the weights (samples, capped at a few seconds), the pooled noise, the gyro bias they
show, and :class:`Observations`, what :func:`~accel_calib_ros.session.accept.fit_and_accept`
fits. numpy only; plain records (a NamedTuple, ``__slots__`` classes) for start-up.
"""

import math
from typing import NamedTuple, Optional

import numpy as np

DEFAULT_RATE_HZ = 100.0
"""Rate assumed for the weight cap while the sample rate is not known yet, Hz."""


class Window(NamedTuple):
    """
    One static window: a pose held still.

    :param mean: (3,) mean acceleration, m/s².
    :param scatter: (3,) per-axis sample standard deviation, m/s².
    :param count: samples in the window.
    :param t_start: time of its first sample, s.
    :param t_stop: time of its last sample, s.
    :param temp: mean temperature, °C (NaN when unknown).
    :param gyro_mean: (3,) mean angular rate, rad/s, or None without a gyro.
    :param rate_hz: sample rate inside it, Hz (NaN: the session's rate applies).
    """

    mean: np.ndarray
    scatter: np.ndarray
    count: int = 0
    t_start: float = math.nan
    t_stop: float = math.nan
    temp: float = math.nan
    gyro_mean: Optional[np.ndarray] = None
    rate_hz: float = math.nan

    @property
    def t_mid(self):
        """Mid time, s."""
        return 0.5 * (self.t_start + self.t_stop)

    @property
    def duration_s(self):
        """Seconds from its first sample to its last."""
        return self.t_stop - self.t_start

    @classmethod
    def from_detector(cls, d):
        """
        Build a Window from the dict of ``core.windows.OnlineStaticDetector`` or the guide.

        :param d: keys ``mean``, ``scatter``, ``count``, ``t_start``, ``t_stop``, ``temp``;
            optional ``gyro_mean``, ``rate_hz``.
        """
        gyro = d.get('gyro_mean')
        temp = d.get('temp', math.nan)
        return cls(mean=np.asarray(d['mean'], float).reshape(3).copy(),
                   scatter=np.asarray(d['scatter'], float).reshape(3).copy(),
                   count=int(d['count']), t_start=float(d['t_start']),
                   t_stop=float(d['t_stop']),
                   temp=math.nan if temp is None else float(temp),
                   gyro_mean=None if gyro is None else np.asarray(gyro, float).reshape(3).copy(),
                   rate_hz=float(d.get('rate_hz', math.nan)))


class Observations:
    """
    What a fit is given: one row per window (or per sample in ``fit --mode samples``).

    :param readings: (N, 3) m/s².
    :param weights: (N,) samples behind each row (capped), or None (one each).
    :param temps: (N,) °C (NaN where unknown), or None.
    :param noise: (3,) per-sample noise in the windows, m/s², or None (unknown).
    :param gyro_means: (N, 3) rad/s (NaN rows without a gyro), or None.
    """

    __slots__ = ('readings', 'weights', 'temps', 'noise', 'gyro_means')

    def __init__(self, readings, weights=None, temps=None, noise=None, gyro_means=None):
        self.readings, self.weights, self.temps = readings, weights, temps
        self.noise, self.gyro_means = noise, gyro_means

    def __len__(self):
        return len(self.readings)

    def expected_window_noise(self, floor):
        """
        Return the error expected of a window mean from the noise, m/s², at least ``floor``.

        None when the noise or the weights are unknown (samples, not windows).
        """
        if self.noise is None or self.weights is None or not len(self.readings):
            return None
        noise = np.asarray(self.noise, float)
        from ..core.stats import median
        value = float(np.sqrt(np.mean(noise ** 2) / median(self.weights)))
        return max(value, floor) if math.isfinite(value) else None


class WindowSet:
    """
    Static windows as arrays, one row per window, in the order they were held.

    :param mean: (W, 3) m/s².
    :param scatter: (W, 3) m/s².
    :param count: (W,) samples.
    :param t_start: (W,) s; ``t_stop``: (W,) s.
    :param temp: (W,) °C (NaN where unknown).
    :param gyro_mean: (W, 3) rad/s (NaN rows without the rate), or None when none has it.
    :param rate_hz: (W,) the rate inside each window, Hz (NaN: the session's), or None.
    """

    __slots__ = ('mean', 'scatter', 'count', 't_start', 't_stop', 'temp', 'gyro_mean',
                 'rate_hz')

    def __init__(self, mean, scatter, count, t_start, t_stop, temp, gyro_mean=None,
                 rate_hz=None):
        self.mean = np.asarray(mean, float).reshape(-1, 3)
        n = len(self.mean)
        self.scatter = np.asarray(scatter, float).reshape(n, 3)
        self.count = np.asarray(count, float).reshape(n)
        self.t_start = np.asarray(t_start, float).reshape(n)
        self.t_stop = np.asarray(t_stop, float).reshape(n)
        self.temp = np.asarray(temp, float).reshape(n)
        self.gyro_mean = None if gyro_mean is None else \
            np.asarray(gyro_mean, float).reshape(n, 3)
        self.rate_hz = np.full(n, np.nan) if rate_hz is None else \
            np.asarray(rate_hz, float).reshape(n)

    def __len__(self):
        return len(self.mean)

    @classmethod
    def from_windows(cls, windows):
        """Return the WindowSet of a sequence of :class:`Window` (or detector dicts)."""
        w = [x if isinstance(x, Window) else Window.from_detector(x) for x in windows]
        gyro = None
        if any(x.gyro_mean is not None for x in w):
            gyro = np.array([np.full(3, np.nan) if x.gyro_mean is None else x.gyro_mean
                             for x in w], float).reshape(-1, 3)
        return cls(mean=np.array([x.mean for x in w], float).reshape(-1, 3),
                   scatter=np.array([x.scatter for x in w], float).reshape(-1, 3),
                   count=[x.count for x in w], t_start=[x.t_start for x in w],
                   t_stop=[x.t_stop for x in w], temp=[x.temp for x in w], gyro_mean=gyro,
                   rate_hz=[x.rate_hz for x in w])

    @classmethod
    def from_static(cls, windows, t):
        """
        Return the WindowSet of ``core.windows.StaticWindows`` found in a recording.

        :param windows: StaticWindows (sample index ranges).
        :param t: (N,) the recording's times, s.
        """
        t = np.asarray(t, float)
        n = len(windows)
        return cls(mean=windows.mean, scatter=windows.scatter, count=windows.count,
                   t_start=t[windows.start] if n else np.zeros(0),
                   t_stop=t[windows.stop - 1] if n else np.zeros(0), temp=windows.temp,
                   gyro_mean=windows.gyro_mean)

    @property
    def t_mid(self):
        """(W,) mid times, s."""
        return 0.5 * (self.t_start + self.t_stop)

    def windows(self):
        """Return the rows as :class:`Window` objects."""
        return [Window(self.mean[k], self.scatter[k], int(self.count[k]),
                       float(self.t_start[k]), float(self.t_stop[k]), float(self.temp[k]),
                       None if self.gyro_mean is None or not np.all(np.isfinite(
                           self.gyro_mean[k])) else self.gyro_mean[k],
                       float(self.rate_hz[k])) for k in range(len(self))]

    def weights(self, max_weight_s=None, rate_hz=None):
        """
        Observation weights: samples per window, capped at ``max_weight_s`` of samples.

        The cap uses each window's own rate when it has one, else ``rate_hz`` (else
        ``DEFAULT_RATE_HZ``). Averaging beyond a few seconds stops helping on a real MEMS
        sensor (bias instability, flicker noise) while model errors do not average out,
        so long windows do not dominate the fit.
        """
        w = self.count.astype(float)
        if not max_weight_s:
            return w
        rate = np.where(np.isfinite(self.rate_hz), self.rate_hz,
                        rate_hz if rate_hz else DEFAULT_RATE_HZ)
        return np.minimum(w, max_weight_s * rate)

    def noise(self):
        """Return the pooled within-window per-sample noise, m/s² per axis (3,), or None."""
        if not len(self):
            return None
        dof = np.maximum(self.count - 1, 0)
        return np.sqrt(np.sum(dof[:, None] * self.scatter ** 2, axis=0) / max(dof.sum(), 1.0))

    def observations(self, max_weight_s=None, rate_hz=None):
        """Return the :class:`Observations` of the windows (one row each)."""
        return Observations(readings=self.mean, weights=self.weights(max_weight_s, rate_hz),
                            temps=self.temp, noise=self.noise(), gyro_means=self.gyro_mean)

    def to_static_windows(self):
        """Return them as ``core.windows.StaticWindows`` (for the model-gap check)."""
        from ..core.windows import StaticWindows
        count = self.count.astype(int)
        return StaticWindows(start=np.zeros(len(self), int), stop=count, mean=self.mean,
                             scatter=self.scatter, count=count, t_mid=self.t_mid,
                             temp=self.temp, gyro_mean=self.gyro_mean)

    def select(self, index):
        """Return the windows picked by a boolean mask or an index array."""
        return WindowSet(self.mean[index], self.scatter[index], self.count[index],
                         self.t_start[index], self.t_stop[index], self.temp[index],
                         None if self.gyro_mean is None else self.gyro_mean[index],
                         self.rate_hz[index])
