"""
Blocks: the corrected stream summarised a short stretch of time at a time, cut one way.

The monitor never looks at single samples. :class:`BlockCutter` cuts the samples (the
node's, a few at a time, or a recording's, in pieces: the same code) into blocks of
``block_s`` of stream time, longer at low rates so that a block holds at least
:data:`MIN_BLOCK_SAMPLES` samples; a step of the sample clock (backwards, or forwards by
more than a gap) ends the block in progress and is reported, so that every time-ordered
state can restart there. One :class:`Block` holds what every later step needs: the
sample count, the mean time, per-axis mean and within-block variance of the
acceleration, the angular rate and the magnetic field, the mean temperature, and how
many samples repeat the previous one exactly (a frozen sensor). A :class:`Run` adds
blocks up into the sums of a still period, including the sums of a straight-line fit of
the block means over time (the slope says whether the sensor tilts, turns or
accelerates while it looks still; the scatter about the line whether it wanders).

A simulator may also draw blocks directly from their distribution (``sim/field_stream.py``).
"""

import math

import numpy as np

MIN_BLOCK_SAMPLES = 8
"""Fewest samples a block holds (its standard deviation must mean something)."""
STILL_MIN_RATE_HZ = 20.0
"""Slowest stream the still test works on, Hz (blocks of at most 0.4 s)."""
RATE_INTERVALS = 16
"""Sample intervals seen before the rate (and so the block length) is fixed."""
STALL_BLOCKS = 20
"""A block holding this many blocks' worth of samples means the clock stands still."""
MAX_HELD = 4096
"""Most samples held while the rate is unknown, and magnetometer samples held."""
GAP_S = 0.25
"""A forward step of the sample clock longer than this (and 5 intervals) is a gap, s."""


def cross(a, b):
    """Return the cross product of two 3-vectors (np.cross is slow for one pair)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                     a[0] * b[1] - a[1] * b[0]])


class Block:
    """
    Sums of the corrected samples of one short stretch of time.

    :param n: accelerometer (and gyro) samples.
    :param t: mean time, s.
    :param duration: time the samples stand for (n sample intervals), s.
    :param a_mean: (3,) mean corrected acceleration, m/s².
    :param a_var: (3,) within-block variance per axis, (m/s²)².
    :param g_mean: (3,) mean corrected angular rate, rad/s, or None.
    :param g_var: (3,) its within-block variance, or None.
    :param temp: mean temperature, °C (NaN unknown).
    :param m_n: magnetometer samples in the block (0: none).
    :param m_mean: (3,) mean corrected field, µT, or None.
    :param m_var: (3,) its within-block variance, or None.
    :param a_repeats: samples equal to the one before, on the accelerometer axis that
        repeats least (a stuck sensor repeats on every axis).
    :param g_repeats: the same for the gyro.
    """

    __slots__ = ('n', 't', 'duration', 'a_mean', 'a_var', 'g_mean', 'g_var', 'temp', 'm_n',
                 'm_mean', 'm_var', 'a_repeats', 'g_repeats')

    def __init__(self, n, t, duration, a_mean, a_var, g_mean=None, g_var=None,
                 temp=float('nan'), m_n=0, m_mean=None, m_var=None, a_repeats=0,
                 g_repeats=0):
        self.n, self.t, self.duration = int(n), float(t), float(duration)
        self.a_mean, self.a_var = a_mean, a_var
        self.g_mean, self.g_var = g_mean, g_var
        self.temp = float(temp)
        self.m_n, self.m_mean, self.m_var = int(m_n), m_mean, m_var
        self.a_repeats, self.g_repeats = int(a_repeats), int(g_repeats)

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
        g_rep = 0
        if gyro is not None:
            g = np.asarray(gyro, float)
            g_mean, g_var = g.mean(axis=0), g.var(axis=0)
            g_rep = int(np.min(np.count_nonzero(g[1:] == g[:-1], axis=0)))
        m_n = 0
        if mag is not None and len(mag):
            m = np.asarray(mag, float)
            m_n, m_mean, m_var = len(m), m.mean(axis=0), m.var(axis=0)
        tc = float('nan')
        if temp is not None:
            tv = np.asarray(temp, float)
            tv = tv[np.isfinite(tv)]
            tc = float(tv.mean()) if len(tv) else float('nan')
        a_rep = int(np.min(np.count_nonzero(a[1:] == a[:-1], axis=0)))
        span = float(t[-1] - t[0]) * len(t) / (len(t) - 1)      # n samples stand for n dt
        return cls(len(t), float(t.mean()), span, a.mean(axis=0), a.var(axis=0),
                   g_mean, g_var, tc, m_n, m_mean, m_var, a_rep, g_rep)

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


class BlockCutter:
    """
    Cut samples into :class:`Block` s on the stream's own clock (see the module docstring).

    Feed samples in arrival order (:meth:`cut`); a block ends when the sample clock
    passes the next multiple of :attr:`step_s`, or at a clock step. The block length is
    fixed once :data:`RATE_INTERVALS` sample intervals are known: ``block_s``, or a
    multiple of it holding at least :data:`MIN_BLOCK_SAMPLES` samples at that rate.

    :param block_s: shortest block, s.
    """

    def __init__(self, block_s=0.1):
        self.block_s = float(block_s)
        self.step_s = None              # the block length in use (None: rate not known)
        self.rate_hz = None
        self.steps = 0                  # clock steps seen (backwards or gaps)
        self.backwards = 0              # of them, steps back
        self._carry = None              # samples of the block in progress (arrays)
        self._mag = None                # (t, field) magnetometer samples not yet used
        self._last_t = None

    def cut(self, t, a, g=None, temp=None, mag=None, mag_t=None):
        """
        Add samples (finite rows, in arrival order); return the events they complete.

        :param t: (N,) s. :param a: (N, 3) m/s². :param g: (N, 3) rad/s or None.
        :param temp: (N,) °C or None. :param mag: (K, 3) µT magnetometer samples or None.
        :param mag_t: (K,) their times, s.
        :return: list of ('block', Block) and ('step', words) in stream order.
        """
        if mag is not None and len(mag):
            mt, mv = np.asarray(mag_t, float), np.asarray(mag, float)
            self._mag = (mt, mv) if self._mag is None else \
                (np.r_[self._mag[0], mt][-MAX_HELD:], np.vstack([self._mag[1], mv])[-MAX_HELD:])
        if not len(t):
            return []
        if self._carry is not None:
            ct, ca, cg, ctemp = self._carry
            if (cg is None) != (g is None) or (ctemp is None) != (temp is None):
                out = self._emit(ct, ca, cg, ctemp)       # the columns changed: a new block
            else:
                out = []
                t, a = np.r_[ct, t], np.vstack([ca, a])
                g = None if g is None else np.vstack([cg, g])
                temp = None if temp is None else np.r_[ctemp, temp]
            self._carry = None
        else:
            out = []
        dt = np.diff(t)
        if self.step_s is None:
            good = dt[dt > 0]
            if len(good) < RATE_INTERVALS:
                keep = slice(-MAX_HELD, None)           # a clock that never moves: bounded
                self._carry = (t[keep], a[keep], None if g is None else g[keep],
                               None if temp is None else temp[keep])
                return out
            self._lock(float(1.0 / np.median(good)))
        # Clock steps: backwards, or forwards by more than a gap (the last block's end too).
        gap = max(GAP_S, 5.0 / self.rate_hz)
        before = np.r_[self._last_t if self._last_t is not None else t[0], t[:-1]]
        jumps = np.flatnonzero((t < before) | (t - before > gap))
        start = 0
        for k in list(jumps) + [len(t)]:
            out += self._cut_run(t[start:k], a[start:k], None if g is None else g[start:k],
                                 None if temp is None else temp[start:k], final=k < len(t))
            if k < len(t):
                back = t[k] < before[k]
                self.steps += 1
                self.backwards += bool(back)
                out.append(('step', f'the sample clock stepped {"back" if back else "forward"} '
                                    f'by {abs(t[k] - before[k]):.3g} s'))
                self._last_t = None
            start = k
        return out

    def finish(self):
        """End of the stream: the block in progress is emitted (the cutter restarts)."""
        out = []
        if self._carry is not None:
            ct, ca, cg, ctemp = self._carry
            self._carry = None
            if self.step_s is None and len(ct) >= 2:
                dt = np.diff(ct)
                if np.any(dt > 0):
                    self._lock(float(1.0 / np.median(dt[dt > 0])))
            if self.step_s is not None:
                out = self._cut_run(ct, ca, cg, ctemp, final=True)
        self._last_t = None
        return out

    @property
    def too_slow(self):
        """Return True when the stream is slower than :data:`STILL_MIN_RATE_HZ`."""
        return self.rate_hz is not None and self.rate_hz < STILL_MIN_RATE_HZ

    def _lock(self, rate):
        self.rate_hz = rate
        per_block = self.block_s * rate
        self.step_s = self.block_s * max(1, math.ceil(MIN_BLOCK_SAMPLES / per_block - 1e-9))

    def _cut_run(self, t, a, g, temp, final):
        """Blocks of one stretch without clock steps; keep the unfinished one unless final."""
        if not len(t):
            return []
        index = np.floor(np.round(t / self.step_s, 6)).astype(np.int64)
        cuts = np.flatnonzero(np.diff(index)) + 1
        starts, stops = np.r_[0, cuts], np.r_[cuts, len(t)]
        out = []
        last = len(starts) if final else len(starts) - 1
        for a0, b0 in zip(starts[:last], stops[:last]):
            out += self._emit(t[a0:b0], a[a0:b0], None if g is None else g[a0:b0],
                              None if temp is None else temp[a0:b0])
        if not final:
            a0 = starts[-1]
            if len(t) - a0 > STALL_BLOCKS * self.step_s * self.rate_hz + RATE_INTERVALS:
                # The clock stands still (stamps that do not advance): not one block forever.
                out += self._emit(t[a0:], a[a0:], None if g is None else g[a0:],
                                  None if temp is None else temp[a0:])
                self.steps += 1
                self._last_t = None
                return out + [('step', 'the sample clock does not advance')]
            self._carry = (t[a0:], a[a0:], None if g is None else g[a0:],
                           None if temp is None else temp[a0:])
            if a0 > 0:                  # the carry is fed again: steps counted from here
                self._last_t = float(t[a0 - 1])
        else:
            self._last_t = float(t[-1])
        return out

    def _emit(self, t, a, g, temp):
        mag = None
        if self._mag is not None:
            mt, mv = self._mag
            inside = (mt >= t[0] - 0.5 * self.step_s) & (mt <= t[-1])
            mag = mv[inside]
            later = mt > t[-1]
            self._mag = (mt[later], mv[later]) if later.any() else None
        block = Block.of(t, a, g, temp, mag)
        return [] if block is None else [('block', block)]


class _Line:
    """Weighted straight-line sums of 3-vectors over time (block means, weights = counts)."""

    __slots__ = ('t0', 'ref', 'w', 'k', 'st', 'stt', 'sx', 'stx', 'sxx', 'within')

    def __init__(self, t0):
        self.t0 = t0
        self.ref = None                 # the first mean (sums are of differences from it)
        self.w = self.st = self.stt = 0.0
        self.k = 0                      # blocks added
        self.sx = np.zeros(3)
        self.stx = np.zeros(3)
        self.sxx = np.zeros(3)
        self.within = np.zeros(3)      # sum of n x within-block variance

    def add(self, t, n, mean, var):
        if self.ref is None:
            self.ref = np.array(mean, float)
        x = mean - self.ref
        tau = t - self.t0
        self.w += n
        self.k += 1
        self.st += n * tau
        self.stt += n * tau * tau
        self.sx = self.sx + n * x
        self.stx = self.stx + (n * tau) * x
        self.sxx = self.sxx + n * x * x
        if var is not None:
            self.within = self.within + n * var

    def mean(self):
        return self.ref + self.sx / self.w

    def time_spread(self):
        """Return the weighted spread of the times, s² x samples (0 for one block)."""
        return max(self.stt - self.st * self.st / self.w, 0.0)

    def slope(self):
        """Return the slopes (3,) per second, the per-sample noise variance and the time spread."""
        sxx = self.time_spread()
        noise = float(self.within.sum()) / (3.0 * max(self.w, 1.0))
        if sxx <= 0.0:
            return np.zeros(3), noise, 0.0
        return (self.stx - self.st * self.sx / self.w) / sxx, noise, sxx

    def scatter(self):
        """
        Return the per-sample variance (3,) the block means' scatter about the line implies.

        ``sum n (x - line)² / (blocks - 2)``: the within-block variance for white noise,
        more when the means wander (a moving platform, slow noise); NaN below 3 blocks.
        """
        if self.k < 3:
            return np.full(3, np.nan)
        syy = self.sxx - self.sx * self.sx / self.w
        spread = self.time_spread()
        sty = self.stx - self.st * self.sx / self.w
        rss = syy - (sty * sty / spread if spread > 0 else 0.0)
        return np.maximum(rss, 0.0) / (self.k - 2)


class Run:
    """
    The sums of a still period: means, noise, and the drift of the block means.

    :param block: the first block.
    """

    def __init__(self, block):
        self.t_start = block.t - 0.5 * block.duration
        self.t_stop = self.t_start
        self.n = 0
        self.blocks = []
        self.acc = _Line(block.t)
        self.gyro = _Line(block.t) if block.g_mean is not None else None
        self.mag = _Line(block.t)
        self.temp_sum = 0.0
        self.temp_n = 0
        self.inflation = 1.0            # variance of slow averages over white (:mod:`.mean_noise`)
        self.add(block)

    def add(self, block):
        """Add one block."""
        self.blocks.append(block)
        self.n += block.n
        self.t_stop = block.t + 0.5 * block.duration
        self.acc.add(block.t, block.n, block.a_mean, block.a_var)
        if self.gyro is not None:
            if block.g_mean is None:
                self.gyro = None
            else:
                self.gyro.add(block.t, block.n, block.g_mean, block.g_var)
        if block.m_n >= 1 and block.m_mean is not None:
            self.mag.add(block.t, block.m_n, block.m_mean, None)
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

    def up(self):
        """Return the unit direction of the mean acceleration (3,)."""
        mean = self.acc.mean()
        return mean / math.sqrt(float(mean @ mean))

    def tilt_rate(self):
        """
        Return how fast gravity turns in the sensor frame: (rate, its std), rad/s.

        From the slope of the block means of the acceleration across gravity (a turn
        about a horizontal axis at ω tilts gravity at ω); (0, inf) before two blocks.
        The noise is the within-block noise times :attr:`inflation` (correlated noise
        makes slopes scatter more than white noise would).
        """
        slope, noise, sxx = self.acc.slope()
        noise *= self.inflation
        if sxx <= 0.0:
            return 0.0, float('inf')
        mean = self.acc.mean()
        g = math.sqrt(float(mean @ mean))
        u = mean / g
        across = slope - u * float(u @ slope)
        return math.sqrt(float(across @ across)) / g, math.sqrt(noise / sxx) / g

    def magnitude_rate(self):
        """Return how fast |a| changes across the period: (rate, its std), m/s³."""
        slope, noise, sxx = self.acc.slope()
        noise *= self.inflation
        if sxx <= 0.0:
            return 0.0, float('inf')
        return float(self.up() @ slope), math.sqrt(noise / sxx)

    def wander(self):
        """
        Return how much more the block means scatter than the within-block noise says.

        The scatter of the block means about the period's straight line, per sample
        (:meth:`_Line.scatter`), over the within-block variance, the largest of the
        axes: about 1 for white noise (its χ²_{k-2}/(k-2) spread), a few for flicker,
        hundreds on a ship's heave. NaN below 3 blocks.
        """
        within = self.acc.within / max(self.acc.w, 1.0)
        scatter = self.acc.scatter()
        with np.errstate(divide='ignore', invalid='ignore'):
            ratio = np.where(within > 0, scatter / within, np.nan)
        return float(np.nanmax(ratio)) if np.any(np.isfinite(ratio)) else float('nan')

    def heading_rate(self):
        """
        Return the turn about gravity the magnetometer sees: (rate, its std), rad/s.

        The horizontal part ``h`` of the field turns at -ω about the up direction when
        the body turns at ω: ``ω = -(h x dh/dt) . up / |h|²``, from the straight line
        through the field's block means across the whole period (blocks with one
        sample count: an 8 Hz magnetometer works). The noise is the means' scatter
        about that line. (0, inf) with fewer than six magnetometer blocks or no
        horizontal field.
        """
        line = self.mag
        if line.k < 6:
            return 0.0, float('inf')
        slope, _, sxx = line.slope()
        if sxx <= 0.0:
            return 0.0, float('inf')
        noise = float(np.mean(line.scatter()))     # per sample and axis
        up = self.up()
        m = line.mean()
        h = m - up * float(up @ m)
        h2 = float(h @ h)
        if not h2 > 0.0 or not math.isfinite(noise):
            return 0.0, float('inf')
        rate = -float(cross(h, slope) @ up) / h2
        return rate, math.sqrt(noise / (sxx * h2))
