"""
What a live node keeps for the gyroscope and the magnetometer, in bounded memory.

The accelerometer needs only the static windows' means (``core.windows.streaming``);
the gyroscope's scale and misalignment need every raw rate of the moves between the
windows (the integral depends on the T being fitted, so a move cannot be reduced to a
few numbers before the fit), and the magnetometer needs its samples from many
directions. :class:`ImuCollector` keeps

- the last ``max_samples`` raw samples (t, acceleration, rate, temperature) in a ring
  (float32 values, float64 times: 36 bytes a sample; 200 000 samples = 7 MB, 16 min at
  200 Hz, 3 min at 1 kHz): the moves between the windows still in the ring are used;
- up to ``max_mag_samples`` magnetometer samples, each with the acceleration at its
  time: when full, every other one is dropped and from then on only every second
  message is kept (and so on), so the whole session stays covered with ever coarser
  spacing, which is what the ellipsoid fit needs.

:meth:`ImuCollector.snapshot` copies what was kept, for the fits
(``core.outcomes.solve_gyro`` and ``solve_magnetometer``, run by the session floor with
the session's windows: their ``t_start``/``t_stop`` place them in the samples). numpy
only.
"""

from types import SimpleNamespace

import numpy as np

from .samples import Samples

DEFAULT_MAX_SAMPLES = 200_000
DEFAULT_MAX_MAG_SAMPLES = 20_000
MAX_PENDING = 1000
"""Magnetometer samples waiting for the Imu samples of their time, at most."""
COVERAGE_SAMPLES = 2000
"""Magnetometer samples used for the live coverage figure (every k-th of those kept)."""


class _Ring:
    """A ring of the last ``capacity`` rows: times (float64) and values (float32)."""

    def __init__(self, capacity, width):
        self.capacity, self.width = int(capacity), width
        self.t = np.zeros(0)
        self.v = np.zeros((0, width), np.float32)
        self.next = 0           # where the next row goes
        self.full = False

    def __len__(self):
        return self.capacity if self.full else self.next

    def add(self, t, values):
        """Append rows (times (n,), values (n, width)), overwriting the oldest."""
        if self.capacity <= 0 or not len(t):
            return
        if len(self.t) < self.capacity:        # allocated on first use
            self.t = np.zeros(self.capacity)
            self.v = np.zeros((self.capacity, self.width), np.float32)
        t, values = t[-self.capacity:], values[-self.capacity:]
        n = len(t)
        first = min(n, self.capacity - self.next)
        self.t[self.next:self.next + first] = t[:first]
        self.v[self.next:self.next + first] = values[:first]
        if n > first:
            self.t[:n - first] = t[first:]
            self.v[:n - first] = values[first:]
        self.full = self.full or self.next + n >= self.capacity
        self.next = (self.next + n) % self.capacity

    def ordered(self):
        """Return (times (m,), values (m, width) float64) in time order."""
        if not self.full:
            return self.t[:self.next].copy(), self.v[:self.next].astype(float)
        order = np.r_[self.next:self.capacity, 0:self.next]
        return self.t[order], self.v[order].astype(float)

    def span(self):
        """Return the seconds from the oldest row to the newest (0 with fewer than two)."""
        if len(self) < 2:
            return 0.0
        oldest = self.t[self.next] if self.full else self.t[0]
        return float(self.t[(self.next - 1) % self.capacity] - oldest)

    def clear(self):
        """Forget every row (keep the memory)."""
        self.next, self.full = 0, False


class ImuCollector:
    """
    Keep the raw samples and magnetometer samples the gyroscope and magnetometer need.

    :param max_samples: raw samples kept for the gyroscope (0: none, no gyro T).
    :param max_mag_samples: magnetometer samples kept (0: none).
    """

    def __init__(self, max_samples=DEFAULT_MAX_SAMPLES, max_mag_samples=DEFAULT_MAX_MAG_SAMPLES):
        self.ring = _Ring(max_samples, 7)            # ax ay az gx gy gz temp
        self.max_mag = int(max_mag_samples)
        self._mag = np.zeros((0, 8))                 # t, mx my mz (µT), ax ay az, temp
        self._n_mag = 0
        self._pending_mag = []                       # (t, mx, my, mz) before their accel
        self.stride = 1                              # keep every stride-th message
        self._count = 0                              # magnetometer messages seen
        self.mag_received = 0
        self.gyro_seen = False
        self._last = None                            # (ax, ay, az, temp) of the last sample

    # -- input -------------------------------------------------------------------------------
    def add_samples(self, rows):
        """
        Keep raw samples and give the waiting magnetometer samples their acceleration.

        :param rows: (n, 8) t (s), ax ay az (m/s²), gx gy gz (rad/s, NaN when unknown),
            temp (°C, NaN when unknown), in time order.
        """
        rows = np.asarray(rows, float).reshape(-1, 8)
        if not len(rows):
            return
        self.gyro_seen = self.gyro_seen or bool(np.isfinite(rows[:, 4:7]).all(axis=1).any())
        self.ring.add(rows[:, 0], rows[:, 1:8])
        if self._pending_mag:
            pending = np.array(self._pending_mag, float)
            ready = pending[:, 0] <= rows[-1, 0]
            i = np.clip(np.searchsorted(rows[:, 0], pending[ready, 0]), 0, len(rows) - 1)
            self._keep_mag(pending[ready], rows[i][:, [1, 2, 3, 7]])
            self._pending_mag = [tuple(p) for p in pending[~ready]]
        self._last = rows[-1, [1, 2, 3, 7]]

    def add_mag(self, t, field_uT):
        """
        Offer one magnetometer sample (kept or skipped by the decimation).

        :param t: its time, s (the clock of the Imu stamps).
        :param field_uT: (3,) µT, accelerometer frame.
        """
        self.mag_received += 1
        if self.max_mag <= 0 or not np.all(np.isfinite(field_uT)):
            return
        self._count += 1
        if self._count % self.stride:
            return
        self._pending_mag.append((float(t),) + tuple(float(v) for v in field_uT))
        if len(self._pending_mag) > MAX_PENDING:    # no Imu past them: the last one seen
            if self._last is not None:
                pending = np.array(self._pending_mag, float)
                self._keep_mag(pending, np.tile(self._last, (len(pending), 1)))
                self._pending_mag = []
            else:
                del self._pending_mag[0]

    @property
    def mag(self):
        """Return the kept magnetometer rows (k, 8): t, mx my mz (µT), ax ay az, temp."""
        return self._mag[:self._n_mag]

    def _keep_mag(self, mag_rows, accel_temp):
        """Append magnetometer rows (k, 4) with their (k, 4) ax ay az temp; decimate."""
        rows = np.column_stack([mag_rows, accel_temp])
        if len(self._mag) < self.max_mag:              # allocated on first use
            self._mag = np.zeros((self.max_mag, 8))
        for row in rows:
            if self._n_mag == self.max_mag:            # full: every other one goes
                half = self._mag[:self._n_mag:2]
                self._n_mag = len(half)
                self._mag[:self._n_mag] = half
                self.stride *= 2
            self._mag[self._n_mag] = row
            self._n_mag += 1

    def clear(self):
        """Forget everything collected."""
        self.ring.clear()
        self._n_mag = 0
        self._pending_mag = []
        self.stride, self._count = 1, 0

    # -- what was kept -----------------------------------------------------------------------
    def raw_samples(self):
        """Return the kept raw samples as Samples (gyro None when it never came), or None."""
        t, v = self.ring.ordered()
        if len(t) < 2:
            return None
        temp = v[:, 6] if np.isfinite(v[:, 6]).all() else None
        return Samples(t, v[:, :3], temp, v[:, 3:6] if self.gyro_seen else None)

    def mag_samples(self):
        """Return the kept magnetometer samples (with their accel) as Samples, or None."""
        m = self.mag
        if not len(m):
            return None
        temp = m[:, 7] if np.isfinite(m[:, 7]).all() else None
        return Samples(m[:, 0], m[:, 4:7], temp, None, m[:, 1:4])

    @staticmethod
    def windows_in(t, windows):
        """
        Map windows to sample ranges of times ``t``.

        :param windows: an object with ``t_start`` and ``t_stop`` arrays (s), or a sequence of
            windows with those times (objects or dicts).
        :returns: an object with ``start`` and ``stop`` (int arrays) for the windows that
            lie inside ``t`` (with at least one sample).
        """
        t_start, t_stop = _window_times(windows)
        start = np.searchsorted(t, t_start, side='left')
        stop = np.searchsorted(t, t_stop, side='right')
        keep = (stop > start) & (t_start >= t[0]) & (t_stop <= t[-1])
        return SimpleNamespace(start=start[keep], stop=stop[keep])

    def coverage(self):
        """Fraction of the sphere of field directions seen so far (a subsample)."""
        from .outcomes import magnetometer_coverage
        step = max(1, len(self.mag) // COVERAGE_SAMPLES)
        return magnetometer_coverage(self.mag[::step, 1:4])

    def state(self, coverage=None):
        """Return what was kept, as a JSON-ready dict."""
        return {'raw_samples': len(self.ring), 'raw_capacity': self.ring.capacity,
                'raw_seconds': self.ring.span(),
                'gyro_received': self.gyro_seen, 'mag_received': self.mag_received,
                'mag_samples': int(len(self.mag)), 'mag_decimation': self.stride,
                'mag_coverage': coverage}

    # -- the fits ----------------------------------------------------------------------------
    def snapshot(self):
        """
        Return a copy of what was kept, for a fit that runs while collection goes on.

        :returns: :class:`ImuSnapshot` (its own arrays: the collector may change at once).
        """
        mags = None
        if len(self.mag):
            m = self.mag.copy()
            temp = m[:, 7] if np.isfinite(m[:, 7]).all() else None
            mags = Samples(m[:, 0], m[:, 4:7], temp, None, m[:, 1:4])
        return ImuSnapshot(raw=self.raw_samples(), mags=mags, capacity=self.ring.capacity,
                           ring_full=len(self.ring) == self.ring.capacity,
                           max_mag=self.max_mag, mag_received=self.mag_received,
                           gyro_seen=self.gyro_seen)


class ImuSnapshot:
    """
    What an :class:`ImuCollector` kept at one moment: copies, safe to fit in another thread.

    :param raw: the raw samples (Samples, ``gyro`` None when it never came), or None.
    :param mags: the magnetometer samples with their acceleration (Samples), or None.
    :param capacity: raw samples the ring keeps (0: none kept).
    :param ring_full: whether the ring had dropped samples already.
    :param max_mag: magnetometer samples kept at most (0: none kept).
    :param mag_received: magnetometer messages received.
    :param gyro_seen: whether an angular rate ever came.
    """

    __slots__ = ('raw', 'mags', 'capacity', 'ring_full', 'max_mag', 'mag_received',
                 'gyro_seen')

    def __init__(self, raw, mags, capacity, ring_full, max_mag, mag_received, gyro_seen):
        self.raw, self.mags = raw, mags
        self.capacity, self.ring_full = capacity, ring_full
        self.max_mag, self.mag_received, self.gyro_seen = max_mag, mag_received, gyro_seen


def _window_times(windows):
    """Return (t_start, t_stop) arrays, s, of windows given as arrays or one by one."""
    if isinstance(getattr(windows, 't_start', None), np.ndarray):
        return (np.asarray(windows.t_start, float).reshape(-1),
                np.asarray(windows.t_stop, float).reshape(-1))
    rows = [(w['t_start'], w['t_stop']) if isinstance(w, dict) else (w.t_start, w.t_stop)
            for w in windows]
    times = np.array(rows, float).reshape(-1, 2)
    return times[:, 0], times[:, 1]
