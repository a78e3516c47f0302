"""
Streaming static-window detection for a node: the offline detector's steps, in bounded memory.

:class:`OnlineStaticDetector` takes samples as they arrive and gives back the same
windows as :func:`~accel_calib_ros.core.windows.offline.detect_static_windows` would on
the whole recording, with the sample rate tracked continuously.
"""

from collections import deque

import numpy as np

from .offline import DEFAULTS, still_runs
from ..constants import G0


class FloorHistogram:
    """
    Running low quantile of a positive quantity, in bounded memory (a log histogram).

    100 bins per decade from 1e-9 to 1e3: the quantile is known to about 1 %. Shared
    with the field monitor's still test (``core.monitor.still``), which forgets old
    values with :meth:`decay`.
    """

    LOW, DECADES, PER_DECADE = -9.0, 12, 100

    def __init__(self):
        self.counts = np.zeros(self.DECADES * self.PER_DECADE + 1, np.int64)
        self.total = 0

    def add(self, values):
        """Count the finite values of an array."""
        v = np.asarray(values, float)
        v = v[np.isfinite(v)]
        if not len(v):
            return
        pos = (np.log10(np.maximum(v, 1e-300)) - self.LOW) * self.PER_DECADE
        idx = np.clip(pos, 0, len(self.counts) - 1).astype(np.int64)
        self.counts += np.bincount(idx, minlength=len(self.counts))
        self.total += len(v)

    def decay(self, factor=0.5):
        """Weigh everything counted so far by ``factor`` (0..1): old values fade out."""
        self.counts = np.floor(self.counts * float(factor)).astype(np.int64)
        self.total = int(self.counts.sum())

    def quantile(self, q):
        """Return the ``q`` quantile of everything added (NaN before any value)."""
        if self.total == 0:
            return float('nan')
        cum = np.cumsum(self.counts)
        target = q * (self.total - 1) + 1          # rank as np.quantile counts it
        k = int(np.searchsorted(cum, target))
        before = cum[k - 1] if k else 0
        frac = (target - before) / max(self.counts[k], 1)
        return float(10.0 ** (self.LOW + (k + min(max(frac, 0.0), 1.0)) / self.PER_DECADE))


def received_rate(dt):
    """
    Return the samples received per second from stamp intervals ``dt`` (s, positive).

    Lost samples lengthen some intervals, so this is below the nominal rate (the
    median interval) when the stream drops messages: the window lengths counted in
    samples then still span the intended seconds. Gaps beyond 20 median intervals (a
    reconnect) are left out. Equal to the nominal rate on a lossless stream.
    """
    dt = np.asarray(dt, float)
    kept = dt[dt <= 20.0 * np.median(dt)]
    return len(kept) / float(np.sum(kept))


class _MedianHistogram:
    """Running per-axis median of values within ±``span`` (bins of ``step``), bounded."""

    def __init__(self, span=0.5, step=2.5e-4, axes=3):
        self.span, self.step = span, step
        self.counts = np.zeros((axes, int(round(2 * span / step)) + 1), np.int64)
        self.total = 0

    def add(self, values):
        """Count the rows of (N, axes) values (clipped to the span)."""
        v = np.asarray(values, float)
        if not len(v):
            return
        idx = np.clip(np.rint((v + self.span) / self.step), 0, self.counts.shape[1] - 1)
        for axis in range(self.counts.shape[0]):
            self.counts[axis] += np.bincount(idx[:, axis].astype(np.int64),
                                             minlength=self.counts.shape[1])
        self.total += len(v)

    def median(self):
        """Return the per-axis median, or zeros before any value."""
        if not self.total:
            return np.zeros(self.counts.shape[0])
        k = np.argmax(np.cumsum(self.counts, axis=1) >= (self.total + 1) / 2.0, axis=1)
        return k * self.step - self.span


class OnlineStaticDetector:
    """
    Streaming :func:`detect_static_windows`: the same windows, in bounded memory.

    Feed chunks of samples as they arrive (:meth:`feed`); finished windows come back
    as dicts. The steps are those of the offline detector, in the same units:

    - the sample rate is the rate at which samples arrive (:func:`received_rate` of
      the last ``rate_memory`` stamp intervals: the median rate of a lossless stream,
      lower when messages are lost), tracked continuously: a burst of stale samples
      at start-up is forgotten within ``rate_memory`` samples; when the estimate moves
      by more than 0.5 % the sample counts below follow it (samples still waiting for
      their moving window, e.g. a start-up burst, get the new one);
    - the centred moving standard deviation of the acceleration over ``window_s``
      (edges padded with the first and last sample, like the offline one);
    - the noise floor is the ``floor_quantile`` of every moving standard deviation so
      far (kept as a log histogram), never below 1e-5 g;
    - still = the standard deviation below ``threshold_factor`` x the floor; a run of
      still samples loses ``trim_s`` at each end and is kept when at least
      ``min_duration_s`` remains;
    - with a gyro (and ``use_gyro``), a run must also turn slower than
      ``max_rotation_rad_s`` (and 5x the median rate of the still samples): the
      centred moving mean of the rate over ``window_s`` minus the gyro bias (the
      median rate of the still samples so far). A run that
      turns is cut to its longest part that does not (``trim_s`` more where it meets
      the rotation), or dropped and listed in :attr:`dropped`.

    Stretches that may be still (below ``floor_slack`` x the threshold) are kept until
    they end, then judged with the floor known at that time (in the first
    ``warmup_s`` of data they wait until then), so a floor that is still settling
    early in a session does not cut windows differently from the offline pass. A
    stretch longer than ``max_run_s`` is folded into running sums (memory stays
    O(``max_run_s`` x rate)).

    A window is a dict: mean (3,) m/s², scatter (3,) per-axis sample std m/s², count,
    t_start, t_stop, t_mid (s), temp (mean °C, NaN if none), gyro_mean ((3,) rad/s or
    None).

    :param rate_hz: sample rate to start with, Hz (None: measured from the stamps).
    """

    def __init__(self, rate_hz=None, window_s=DEFAULTS['window_s'],
                 min_duration_s=DEFAULTS['min_duration_s'],
                 threshold_factor=DEFAULTS['threshold_factor'], trim_s=DEFAULTS['trim_s'],
                 floor_quantile=DEFAULTS['floor_quantile'], use_gyro=True,
                 max_rotation_rad_s=DEFAULTS.get('max_rotation_rad_s', 0.0349066),
                 rate_memory=256, max_run_s=30.0, floor_slack=1.5, gravity=G0,
                 warmup_s=5.0):
        self.window_s, self.min_duration_s, self.trim_s = window_s, min_duration_s, trim_s
        self.factor, self.quantile = threshold_factor, floor_quantile
        self.use_gyro, self.max_run_s, self.slack = use_gyro, max_run_s, floor_slack
        self.max_rotation = max_rotation_rad_s if use_gyro and max_rotation_rad_s \
            and np.isfinite(max_rotation_rad_s) else None
        self._gyro_hist = _MedianHistogram()
        self._spin_hist = FloorHistogram()     # rotation rate of the still samples
        self.dropped = deque(maxlen=100)
        self.warmup_s = warmup_s
        self._seen = 0                  # samples with a moving std so far
        self.min_floor = 1e-5 * gravity
        self._dt = deque(maxlen=max(int(rate_memory), 8))
        self._last_t = None
        self._acc_hist = FloorHistogram()
        self._ready = deque()
        self.rate_tolerance = 0.005
        self.rate_hz = None
        self.relocks = 0
        self._pre = []                  # samples held until the rate is known (bounded)
        if rate_hz:
            self._lock(float(rate_hz))
        self._restart()

    # -- configuration ---------------------------------------------------------------------
    def _lock(self, rate):
        self.rate_hz = rate
        self.n = max(int(round(self.window_s * rate)), 3)
        self.trim = int(round(self.trim_s * rate))
        self.min_len = max(int(round(self.min_duration_s * rate)), 2)
        self.cap = max(int(round(self.max_run_s * rate)), 4 * (self.n + self.trim) + 8)
        self.warmup = int(round(self.warmup_s * rate))

    def _restart(self):
        """Forget the stream position (not the floor or the rate): a new stream begins."""
        self._ref = self._gref = None
        self._hist = None               # last n//2 samples (left context), arrays
        self._buf = None                # samples waiting for their right context
        self._region = None             # possibly-still samples with their std, arrays
        self._waiting = []              # closed stretches kept until the floor settles
        self._fold = None               # running sums of a long still run folded away

    @property
    def noise_floor(self):
        """Return the accelerometer noise floor so far, m/s² (NaN before any data)."""
        q = self._acc_hist.quantile(self.quantile)
        return max(q, self.min_floor) if np.isfinite(q) else float('nan')

    @property
    def gyro_bias(self):
        """Return the median angular rate of the still samples so far, rad/s (3,)."""
        return self._gyro_hist.median()

    def retained_samples(self):
        """Return how many samples the detector holds now (bounded)."""
        def n(block):
            return 0 if block is None else len(block['t'])
        return n(self._hist) + n(self._buf) + n(self._region) + len(self._pre) \
            + sum(n(r) for r in self._waiting)

    # -- input -----------------------------------------------------------------------------
    def update(self, t, accel, temp=float('nan'), gyro=None):
        """
        Add one sample; return one finished window or None (compatibility API).

        :param t: time, s. :param accel: (3,) m/s². :param temp: °C.
        :param gyro: (3,) rad/s or None.
        """
        self._ready.extend(self.feed([t], [accel], [temp], None if gyro is None else [gyro]))
        return self._ready.popleft() if self._ready else None

    def flush(self):
        """End the stream now; return one finished window or None (compatibility API)."""
        self._ready.extend(self.finish())
        return self._ready.popleft() if self._ready else None

    def feed(self, t, accel, temp=None, gyro=None):
        """
        Add a chunk of samples in time order; return the windows finished by it.

        :param t: (N,) s. :param accel: (N, 3) m/s². :param temp: (N,) °C or None.
        :param gyro: (N, 3) rad/s or None (then the gyro takes no part).
        :return: list of window dicts.
        """
        block = _block(t, accel, temp, gyro)
        if not len(block['t']):
            return []
        if self.rate_hz and self._last_t is not None:
            gap = np.flatnonzero(np.diff(np.r_[self._last_t, block['t']])
                                 > max(20.0 / self.rate_hz, 0.25))
            if len(gap):
                # A gap (reconnect, pause): the data either side are not one stream.
                k = int(gap[0])
                out = []
                if k:
                    out += self.feed(block['t'][:k], block['a'][:k], block['temp'][:k],
                                     None if block['g'] is None else block['g'][:k])
                out += self.finish()
                self._last_t = None
                rest = _take(block, slice(k, None))
                return out + self.feed(rest['t'], rest['a'], rest['temp'], rest['g'])
        out = []
        dt = np.diff(np.r_[self._last_t if self._last_t is not None else np.nan, block['t']])
        self._dt.extend(dt[np.isfinite(dt) & (dt > 0)].tolist())
        self._last_t = float(block['t'][-1])
        if len(self._dt) >= 8:
            rate = received_rate(self._dt)
            if self.rate_hz is None or abs(rate / self.rate_hz - 1.0) > self.rate_tolerance:
                # The counts follow the new rate from the next samples on; samples that
                # still wait for their moving window (e.g. after a burst) get the new one.
                self.relocks += self.rate_hz is not None
                self._lock(rate)
        if self.rate_hz is None:
            self._pre.append(block)
            while sum(len(b['t']) for b in self._pre) > 4096:
                self._pre.pop(0)
            return out
        if self._pre:
            block = _concat(self._pre + [block])
            self._pre = []
        return out + self._process(block)

    def finish(self):
        """
        End the stream: judge what is held and return the windows (the state restarts).

        Like the offline pass at the end of a recording: the last sample is repeated
        to complete the moving window and the current still run ends here.
        """
        out = []
        if self._pre and self.rate_hz is None:
            self._pre = []
        if self._buf is not None and len(self._buf['t']):
            pad = self.n - self.n // 2 - 1
            last = _take(self._buf, np.full(pad, len(self._buf['t']) - 1))
            out += self._process(last)
        out += self._judge_waiting()
        if self._region is not None:
            out += self._judge(final=True)
        self._restart()
        return out

    def release(self):
        """Judge the stretches waiting for the floor to settle now; return their windows."""
        return self._judge_waiting()

    def peek(self):
        """Return the windows :meth:`finish` would give now, without ending the stream."""
        import copy
        return copy.deepcopy(self).finish()

    # -- the offline steps, chunk by chunk -----------------------------------------------
    def _process(self, block):
        n = self.n
        left, right = n // 2, n - n // 2 - 1
        if self._ref is None:
            self._ref = block['a'][0].copy()
            self._hist = _take(block, np.zeros(left, int))          # edge padding
        if self._gref is None and block['g'] is not None:
            self._gref = block['g'][0].copy()
        hist = self._hist
        if len(hist['t']) < left:           # the window grew (rate change): pad the edge
            hist = _concat([_take(hist if len(hist['t']) else block,
                                  np.zeros(left - len(hist['t']), int)), hist])
        buf = block if self._buf is None else _concat([self._buf, block])
        self._buf = None
        x = _concat([hist, buf])
        h, size = len(hist['t']), len(x['t'])
        end = size - right                  # samples [h, end) get their full window now
        if end <= h:
            self._buf = buf
            return []
        span = slice(h - left, end + right)
        acc_std = _moving_std_valid(x['a'][span] - self._ref, n)
        gyro_mean = None
        if self.max_rotation is not None and x['g'] is not None:
            gyro_mean = _moving_mean_valid(x['g'][span] - self._gref, n) + self._gref
        done = _take(x, slice(h, end))
        done['s'] = acc_std
        done['mg'] = gyro_mean
        self._buf = _take(x, slice(end, size)) if end < size else None
        # Keep a little more left context than needed, so the window can grow a bit.
        self._hist = _take(x, slice(max(0, end - left - n // 4), end))
        return self._stage(done)

    def _still(self, block, slack=1.0):
        return block['s'] <= slack * self.factor * self.noise_floor

    def rotation_limit(self):
        """
        Return the rotation rate above which a sample turns, rad/s.

        ``max_rotation_rad_s``, or 5x the median rate of the still samples so far when
        that is higher (gyro noise and hand tremor, or a gyro logged in other units).
        """
        level = self._spin_hist.quantile(0.5)
        return max(self.max_rotation, 5.0 * level) if np.isfinite(level) \
            else self.max_rotation

    def _turning(self, r, a, b):
        """Boolean (b - a,) of the samples r[a:b] that turn faster than allowed."""
        if self.max_rotation is None or r.get('mg') is None:
            return np.zeros(max(b - a, 0), bool)
        spin = np.linalg.norm(r['mg'][a:b] - self.gyro_bias, axis=1)
        return spin > self.rotation_limit()

    def _rotation_cut(self, r, a, b, keep_start):
        """
        Apply the gyro test to the run r[a:b] as the offline detector does.

        :param keep_start: the run continues a folded beginning: keep the part at ``a``.
        :return: (a, b) of the part kept, or None when none is long enough.
        """
        turning = self._turning(r, a, b)
        if not turning.any():
            return a, b
        sub_a, sub_b = still_runs(~turning)
        sub_a = np.where(sub_a > 0, sub_a + self.trim, sub_a) + a
        sub_b = np.where(sub_b < b - a, sub_b - self.trim, sub_b) + a
        lengths = sub_b - sub_a
        if keep_start:
            return (a, max(sub_b[0], a)) if len(sub_a) and sub_a[0] == a else (a, a)
        if len(lengths) and lengths.max() >= self.min_len:
            k = int(np.argmax(lengths))
            return int(sub_a[k]), int(sub_b[k])
        spin = np.linalg.norm(r['mg'][a:b] - self.gyro_bias, axis=1)
        self.dropped.append({'t_start': float(r['t'][a]), 't_stop': float(r['t'][b - 1]),
                             'reason': f'rotating: gyro shows up to '
                                       f'{np.degrees(spin.max()):.1f} deg/s (limit '
                                       f'{np.degrees(self.rotation_limit()):.1f} deg/s)'})
        return None

    def _stage(self, done):
        self._acc_hist.add(done['s'])
        if done['g'] is not None and self.max_rotation is not None:
            still = self._still(done)
            self._gyro_hist.add(done['g'][still])
            if done.get('mg') is not None:
                self._spin_hist.add(np.linalg.norm(done['mg'][still] - self.gyro_bias, axis=1))
        self._seen += len(done['t'])
        candidate = self._still(done, self.slack)
        out = []
        # Each stretch of candidates is held until a non-candidate sample closes it.
        starts, stops = still_runs(candidate)
        for a, b in zip(starts, stops):
            if a > 0 and self._region is not None:
                out += self._close()
            self._extend_region(_take(done, np.arange(a, b)))
            if b < len(candidate):
                out += self._close()
            elif len(self._region['t']) > self.cap:
                out += self._judge_waiting() + self._judge(final=False)
        if not len(starts) and self._region is not None:
            out += self._close()
        if self._seen >= self.warmup:
            out += self._judge_waiting()
        return out

    def _close(self):
        """Judge the stretch that just ended, or keep it until the floor has settled."""
        if self._seen < self.warmup:
            self._waiting.append(self._region)
            self._region = None
            return []
        return self._judge_waiting() + self._judge(final=True)

    def _judge_waiting(self):
        out = []
        held, self._region = self._region, None
        while self._waiting:
            self._region = self._waiting.pop(0)
            out += self._judge(final=True)
        self._region = held
        return out

    def _extend_region(self, block):
        self._region = block if self._region is None else _concat([self._region, block])

    def _judge(self, final):
        """Cut the held stretch into windows with the current floor (offline rules)."""
        r = self._region
        mask = self._still(r)
        starts, stops = still_runs(mask)
        out = []
        m = len(r['t'])
        open_end = not final and len(stops) and stops[-1] == m
        fold = self._fold
        self._fold = None
        if fold is not None and not (len(starts) and starts[0] == 0):
            # The floor moved: the folded run ended where it was folded.
            window = _summary(fold, r, 0, 0)
            if window['count'] >= self.min_len:
                out.append(window)
            fold = None
        for k, (a, b) in enumerate(zip(starts, stops)):
            continued = fold is not None and k == 0 and a == 0
            if open_end and k == len(starts) - 1:
                # Still running: fold all but the tail into running sums.
                first = a if continued else a + self.trim
                keep_from = max(m - (self.trim + self.n), first)
                turning = np.flatnonzero(self._turning(r, first, keep_from))
                if len(turning):
                    # It turned: what came before ends here, the rest starts afresh.
                    end = first + turning[0] - (self.trim if turning[0] or continued else 0)
                    window = _summary(fold if continued else None, r, first,
                                      max(end, first))
                    if window is not None and window['count'] >= self.min_len:
                        out.append(window)
                    self._fold = None
                    self._region = _take(r, np.arange(first + turning[-1] + 1, m))
                    return out
                if keep_from > first:
                    fold = _fold(fold if continued else None, r, first, keep_from)
                    self._fold = fold
                    self._region = _take(r, np.arange(keep_from, m))
                else:
                    self._fold = fold if continued else None
                    self._region = _take(r, np.arange(a, m))
                return out
            a_cut = a if continued else a + self.trim
            b_cut = b - self.trim
            total = b_cut - a_cut + (fold['n'] if continued else 0)
            if total < self.min_len:
                continue
            part = self._rotation_cut(r, a_cut, b_cut, continued)
            if part is None:
                continue
            window = _summary(fold if continued else None, r, part[0], part[1])
            if window is not None and window['count'] >= self.min_len:
                out.append(window)
        self._region = None
        return out


def _block(t, accel, temp=None, gyro=None):
    t = np.asarray(t, float).reshape(-1)
    a = np.asarray(accel, float).reshape(-1, 3)
    temp = np.full(len(t), np.nan) if temp is None else \
        np.asarray(temp, float).reshape(-1)
    g = None if gyro is None else np.asarray(gyro, float).reshape(-1, 3)
    if g is not None and not np.all(np.isfinite(g)):
        g = None
    return {'t': t, 'a': a, 'temp': temp, 'g': g}


def _take(block, index):
    out = {}
    for key, value in block.items():
        out[key] = None if value is None else value[index]
    return out


def _concat(blocks):
    blocks = [b for b in blocks if b is not None]
    out = {}
    for key in blocks[0]:
        values = [b.get(key) for b in blocks]
        out[key] = None if any(v is None for v in values) else np.concatenate(values)
    return out


def _moving_std_valid(x, n):
    """Return the moving std (as :func:`_moving_std`) of each full window x[k:k+n]."""
    c1 = np.cumsum(np.vstack([np.zeros((1, x.shape[1])), x]), axis=0)
    c2 = np.cumsum(np.vstack([np.zeros((1, x.shape[1])), x ** 2]), axis=0)
    s1 = c1[n:] - c1[:-n]
    s2 = c2[n:] - c2[:-n]
    var = np.maximum(s2 / n - (s1 / n) ** 2, 0.0)
    return np.sqrt(var.sum(axis=1) / x.shape[1])


def _moving_mean_valid(x, n):
    """Return the moving mean of each full window x[k:k+n], shape (len - n + 1, k)."""
    c = np.cumsum(np.vstack([np.zeros((1, x.shape[1])), x]), axis=0)
    return (c[n:] - c[:-n]) / n


def _fold(fold, r, a, b):
    """Add the samples r[a:b] to the running sums ``fold`` (None = new ones)."""
    if fold is None:
        ref = r['a'][a].copy()
        fold = {'n': 0, 'ref': ref, 's1': np.zeros(3), 's2': np.zeros(3), 't0': r['t'][a],
                't1': r['t'][a], 'temp_sum': 0.0, 'temp_n': 0,
                'g_sum': None if r['g'] is None else np.zeros(3)}
    d = r['a'][a:b] - fold['ref']
    fold['n'] += b - a
    fold['s1'] += d.sum(axis=0)
    fold['s2'] += (d ** 2).sum(axis=0)
    fold['t1'] = r['t'][b - 1]
    temp = r['temp'][a:b]
    temp = temp[np.isfinite(temp)]
    fold['temp_sum'] += float(temp.sum())
    fold['temp_n'] += len(temp)
    if fold['g_sum'] is not None:
        fold['g_sum'] = None if r['g'] is None else fold['g_sum'] + r['g'][a:b].sum(axis=0)
    return fold


def _summary(fold, r, a, b):
    """Window dict of the samples r[a:b] (plus a folded beginning), or None if empty."""
    if b > a:
        fold = _fold(fold, r, a, b) if fold is None else _fold(dict(fold), r, a, b)
    if fold is None or fold['n'] == 0:
        return None
    n = fold['n']
    mean_d = fold['s1'] / n
    var = np.maximum(fold['s2'] - n * mean_d ** 2, 0.0) / max(n - 1, 1)
    return {'mean': fold['ref'] + mean_d, 'scatter': np.sqrt(var), 'count': int(n),
            't_start': float(fold['t0']), 't_stop': float(fold['t1']),
            't_mid': 0.5 * (float(fold['t0']) + float(fold['t1'])),
            'temp': fold['temp_sum'] / fold['temp_n'] if fold['temp_n'] else float('nan'),
            'gyro_mean': None if fold['g_sum'] is None else fold['g_sum'] / n}
