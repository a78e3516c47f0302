"""
Block sums: the corrected stream summarised a tenth of a second at a time.

The monitor never looks at single samples. A node appends each corrected sample to a
list (a few hundred nanoseconds) and hands the list over every ``block_s``; one
:class:`Block` then holds what every later step needs: the sample count, the mean time,
per-axis mean and within-block variance of the acceleration, the angular rate and the
magnetic field, and the mean temperature. A :class:`Run` adds blocks up into the sums
of a still period, including the sums of a straight-line fit of the block means over
time (the slope says whether the sensor tilts or turns while it looks still).

A simulator may also draw blocks directly from their distribution (``sim/field_stream.py``):
the 24 h false-alarm bench runs at block level.
"""

import math

import numpy as np


def cross(a, b):
    """Return the cross product of two 3-vectors (np.cross is slow for one pair)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                     a[0] * b[1] - a[1] * b[0]])


class Block:
    """
    Sums of the corrected samples of one short stretch of time.

    :param n: accelerometer (and gyro) samples.
    :param t: mean time, s.
    :param duration: time spanned, s.
    :param a_mean: (3,) mean corrected acceleration, m/s².
    :param a_var: (3,) within-block variance per axis, (m/s²)².
    :param g_mean: (3,) mean corrected angular rate, rad/s, or None.
    :param g_var: (3,) its within-block variance, or None.
    :param temp: mean temperature, °C (NaN unknown).
    :param m_n: magnetometer samples in the block (0: none).
    :param m_mean: (3,) mean corrected field, µT, or None.
    :param m_var: (3,) its within-block variance, or None.
    """

    __slots__ = ('n', 't', 'duration', 'a_mean', 'a_var', 'g_mean', 'g_var', 'temp', 'm_n',
                 'm_mean', 'm_var')

    def __init__(self, n, t, duration, a_mean, a_var, g_mean=None, g_var=None,
                 temp=float('nan'), m_n=0, m_mean=None, m_var=None):
        self.n, self.t, self.duration = int(n), float(t), float(duration)
        self.a_mean, self.a_var = a_mean, a_var
        self.g_mean, self.g_var = g_mean, g_var
        self.temp = float(temp)
        self.m_n, self.m_mean, self.m_var = int(m_n), m_mean, m_var

    @classmethod
    def of(cls, t, accel, gyro=None, temp=None, mag=None):
        """
        Summarise arrays of samples (all rows finite; see :func:`finite_rows`).

        :param t: (N,) s. :param accel: (N, 3) m/s². :param gyro: (N, 3) rad/s or None.
        :param temp: (N,) °C or None. :param mag: (K, 3) µT samples of the same stretch.
        :return: Block, or None when there are fewer than 2 samples.
        """
        t = np.asarray(t, float)
        if len(t) < 2:
            return None
        a = np.asarray(accel, float)
        g_mean = g_var = m_mean = m_var = None
        if gyro is not None:
            g = np.asarray(gyro, float)
            g_mean, g_var = g.mean(axis=0), g.var(axis=0)
        m_n = 0
        if mag is not None and len(mag):
            m = np.asarray(mag, float)
            m_n, m_mean, m_var = len(m), m.mean(axis=0), m.var(axis=0)
        tc = float('nan')
        if temp is not None:
            tv = np.asarray(temp, float)
            tv = tv[np.isfinite(tv)]
            tc = float(tv.mean()) if len(tv) else float('nan')
        return cls(len(t), float(t.mean()), float(t[-1] - t[0]), a.mean(axis=0), a.var(axis=0),
                   g_mean, g_var, tc, m_n, m_mean, m_var)

    @property
    def a_std(self):
        """Return the within-block standard deviation of the acceleration (RMS of the axes)."""
        return math.sqrt(float(self.a_var.mean()))

    @property
    def g_std(self):
        """Return the within-block standard deviation of the rate (RMS of the axes), or NaN."""
        return float('nan') if self.g_var is None else math.sqrt(float(self.g_var.mean()))


def finite_rows(*arrays):
    """Boolean (N,) rows finite in every given array ((N,) or (N, 3); None skipped)."""
    ok = None
    for x in arrays:
        if x is None:
            continue
        x = np.asarray(x, float)
        good = np.isfinite(x) if x.ndim == 1 else np.all(np.isfinite(x), axis=1)
        ok = good if ok is None else ok & good
    return ok


class _Line:
    """Weighted straight-line sums of 3-vectors over time (block means, weights = counts)."""

    __slots__ = ('t0', 'w', 'st', 'stt', 'sx', 'stx', 'within')

    def __init__(self, t0):
        self.t0 = t0
        self.w = self.st = self.stt = 0.0
        self.sx = np.zeros(3)
        self.stx = np.zeros(3)
        self.within = np.zeros(3)      # sum of n x within-block variance

    def add(self, t, n, mean, var):
        tau = t - self.t0
        self.w += n
        self.st += n * tau
        self.stt += n * tau * tau
        self.sx = self.sx + n * mean
        self.stx = self.stx + (n * tau) * mean
        self.within = self.within + n * var

    def mean(self):
        return self.sx / self.w

    def sxx(self):
        """Return the weighted spread of the times, s² x samples (0 for one block)."""
        return max(self.stt - self.st * self.st / self.w, 0.0)

    def slope(self):
        """Return the slopes (3,) per second, the per-sample noise variance and the time spread."""
        sxx = self.sxx()
        noise = float(self.within.sum()) / (3.0 * max(self.w, 1.0))
        if sxx <= 0.0:
            return np.zeros(3), noise, 0.0
        return (self.stx - self.st * self.sx / self.w) / sxx, noise, sxx


class Run:
    """
    The sums of a still period: means, noise, and the drift of the block means.

    :param block: the first block.
    """

    def __init__(self, block):
        self.t_start = block.t - 0.5 * block.duration
        self.t_stop = self.t_start
        self.blocks = 0
        self.n = 0
        self.acc = _Line(block.t)
        self.gyro = _Line(block.t) if block.g_mean is not None else None
        self.mag = _Line(block.t)
        self.temp_sum = 0.0
        self.temp_n = 0
        self.add(block)

    def add(self, block):
        """Add one block."""
        self.blocks += 1
        self.n += block.n
        self.t_stop = block.t + 0.5 * block.duration
        self.acc.add(block.t, block.n, block.a_mean, block.a_var)
        if self.gyro is not None:
            if block.g_mean is None:
                self.gyro = None
            else:
                self.gyro.add(block.t, block.n, block.g_mean, block.g_var)
        if block.m_n >= 2 and block.m_mean is not None:
            self.mag.add(block.t, block.m_n, block.m_mean, block.m_var)
        if math.isfinite(block.temp):
            self.temp_sum += block.temp * block.n
            self.temp_n += block.n

    @property
    def duration(self):
        """Return the time the period spans, s."""
        return self.t_stop - self.t_start

    @property
    def accel_mean(self):
        """Return the mean corrected acceleration (3,), m/s²."""
        return self.acc.mean()

    @property
    def accel_noise(self):
        """Return the per-sample noise of the acceleration (one axis), m/s²."""
        return math.sqrt(float(self.acc.within.sum()) / (3.0 * self.n))

    @property
    def gyro_mean(self):
        """Return the mean corrected rate (3,), rad/s, or None without a gyro."""
        return None if self.gyro is None else self.gyro.mean()

    @property
    def gyro_noise(self):
        """Return the per-sample noise of the rate (one axis), rad/s (NaN without a gyro)."""
        if self.gyro is None:
            return float('nan')
        return math.sqrt(float(self.gyro.within.sum()) / (3.0 * self.n))

    @property
    def temp(self):
        """Return the mean temperature, °C (NaN unknown)."""
        return self.temp_sum / self.temp_n if self.temp_n else float('nan')

    def tilt_rate(self):
        """
        Return how fast gravity turns in the sensor frame: (rate, its std), rad/s.

        From the slope of the block means of the acceleration across gravity (a turn
        about a horizontal axis at ω tilts gravity at ω); (0, inf) before two blocks.
        """
        slope, noise, sxx = self.acc.slope()
        if sxx <= 0.0:
            return 0.0, float('inf')
        mean = self.acc.mean()
        g = math.sqrt(float(mean @ mean))
        u = mean / g
        across = slope - u * float(u @ slope)
        return math.sqrt(float(across @ across)) / g, math.sqrt(noise / sxx) / g

    def heading_rate(self):
        """
        Return the turn about gravity the magnetometer sees: (rate, its std), rad/s.

        The horizontal part ``h`` of the field turns at -ω about the up direction when
        the body turns at ω: ``ω = -(h x dh/dt) . up / |h|²``. (0, inf) when the period
        has fewer than two magnetometer blocks or no horizontal field.
        """
        if self.mag.w <= 0:
            return 0.0, float('inf')
        slope, noise, sxx = self.mag.slope()
        if sxx <= 0.0:
            return 0.0, float('inf')
        up = self.acc.mean()
        up = up / math.sqrt(float(up @ up))
        m = self.mag.mean()
        h = m - up * float(up @ m)
        h2 = float(h @ h)
        if not h2 > 0.0:
            return 0.0, float('inf')
        rate = -float(cross(h, slope) @ up) / h2
        return rate, math.sqrt(noise / (sxx * h2))
