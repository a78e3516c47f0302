"""
A still recording while the temperature sweeps, reduced to bins: the data of a thermal fit.

Flight stacks learn the offsets against temperature from one still pose while the board
warms up or a chamber cycles (PX4's thermal calibration, ArduPilot's INS_TCAL). Such a
recording is hours long at anything from a logger's 1 Hz to 1 kHz; :func:`still_bins`
cuts it into bins of ``bin_s`` seconds (one mean per bin and axis, as a static window:
``core.windows.StaticWindows``) and checks what a thermal fit needs, with the reason and
what to record when it is not there:

- a temperature column, finite in most rows (rows without one are skipped and counted);
- a temperature that is smooth: no jump between neighbouring samples beyond
  ``MAX_TEMP_STEP_C`` and a scatter about its own trend within a bin below
  ``MAX_TEMP_NOISE_C`` (a coarse or noisy thermometer cannot place the offsets);
- a span of at least ``min_span_c``;
- a sensor that stays put: a bin whose samples scatter far beyond the recording's own
  noise, or whose gyro turns, is left out (a knock); a step of the mean between bins that
  no temperature change can make starts a new pose (each pose gets its own constant);
  more than ``MAX_STILL_POSES`` poses, or most of the recording moving, is refused.
"""

from dataclasses import dataclass, field

import numpy as np

from ..errors import CalibrationError
from ..windows import StaticWindows

BIN_S = 10.0
"""Default bin length, s: short against the temperature's changes, long against noise."""

MIN_SAMPLES_PER_BIN = 3
"""A bin needs at least this many samples (longer bins at rates below 0.3 Hz)."""

MIN_THERMAL_SPAN_C = 5.0
"""Smallest temperature span a thermal fit takes, °C."""

MAX_TEMP_STEP_C = 2.0
"""Largest jump of the reported temperature between neighbouring samples, °C."""

MAX_TEMP_NOISE_C = 0.5
"""Largest scatter of the reported temperature about its trend within a bin, °C."""

MAX_TEMPCO_MG_C = 2.6
"""Fastest change of the reading with temperature believed, mg/°C (vector; the MPU-9250's
±1.5 mg/°C per axis), for telling a move from a temperature change."""

MOVE_MG = 5.0
"""A step of the mean between neighbouring bins beyond this (and beyond what noise and the
temperature change can make) is a move, mg."""

KNOCK_FACTOR = 6.0
"""A bin whose sample scatter exceeds this many times the recording's typical one moved."""

TURN_DEG_S = 0.5
"""A bin whose gyro departs from the recording's median by more than this turned, °/s."""

TURN_BINS = 11
"""Bins over which the gyro's own slow drift is followed (a running median)."""

MAX_STILL_POSES = 6
"""Most poses (still stretches between moves) a thermal recording may hold."""

MAX_MOVING_SHARE = 0.3
"""Largest share of the bins that may be left out as moving."""


@dataclass
class StillRecording:
    """
    A still recording's bins and what was left out.

    :param bins: StaticWindows, one per bin (mean, scatter, count, t_mid, temp, gyro_mean;
        ``start``/``stop`` index the samples).
    :param pose: (N,) index of the still stretch each bin belongs to (a new one after
        each move).
    :param segment: (N,) index of the stretch without a gap in time each bin belongs to
        (the temperature's lag restarts at a gap).
    :param noise_std: (3,) per-sample noise inside bins, m/s².
    :param rate_hz: median sample rate, Hz.
    :param dropped: bins left out: dicts t_start, t_stop (s) and reason.
    :param skipped_rows: rows without a finite temperature or reading.
    :param moves: times of the moves between poses, s.
    :param samples: the rows the bins index (``bins.start``/``stop``), or None.
    """

    bins: StaticWindows
    pose: np.ndarray
    segment: np.ndarray
    noise_std: np.ndarray
    rate_hz: float
    dropped: list = field(default_factory=list)
    skipped_rows: int = 0
    moves: list = field(default_factory=list)
    samples: object = None

    @property
    def temp_range_c(self):
        """(min, max) bin temperature, °C."""
        return float(np.min(self.bins.temp)), float(np.max(self.bins.temp))

    def directions(self):
        """Return each pose's mean raw reading direction, (P, 3) unit vectors."""
        m = np.array([self.bins.mean[self.pose == p].mean(axis=0)
                      for p in range(int(self.pose.max()) + 1)])
        return m / np.linalg.norm(m, axis=1, keepdims=True)


def _bin_edges(t, bin_s, gap_s, origin=None):
    """
    Return where each bin starts (sample index) and where each gap-free stretch does.

    Bins of ``bin_s`` counted from the start of their stretch (``origin`` for the first
    one, when the recording continues an earlier piece).
    """
    dt = np.diff(t)
    gaps = np.flatnonzero(~((dt >= 0) & (dt <= gap_s))) + 1
    stretches = np.r_[0, gaps]
    starts = []
    for a, b in zip(stretches, np.r_[gaps, len(t)]):
        zero = origin if (a == 0 and origin is not None) else t[a]
        k = np.floor((t[a:b] - zero) / bin_s).astype(np.int64)
        starts.append(a + np.flatnonzero(np.diff(k, prepend=-1)))
    return np.concatenate(starts), stretches


@dataclass
class RawBins:
    """
    A recording cut into bins, before any check: what the fit and the node both collect.

    :param bins: StaticWindows (one per bin; ``start``/``stop`` index the rows binned).
    :param segment: (N,) the gap-free stretch of each bin.
    :param temp_step: (N,) the largest jump of the temperature between neighbouring samples
        in (or into) each bin, °C.
    :param temp_wiggle: (N,) the median |second difference| of the temperature in each bin,
        °C (its noise: x 1.4826 / sqrt(6)).
    :param rate_hz: the median sample rate, Hz.
    :param skipped_rows: rows left out (no finite reading or temperature).
    """

    bins: StaticWindows
    segment: np.ndarray
    temp_step: np.ndarray
    temp_wiggle: np.ndarray
    rate_hz: float
    skipped_rows: int = 0


def bin_samples(t, accel, temp, gyro, bin_s, gap_s, origin=None, previous=None):
    """
    Cut finite rows into bins (vectorised; ``StillBinner`` calls it piece by piece).

    :param t: (n,) s, non-decreasing within stretches. :param accel: (n, 3) m/s².
    :param temp: (n,) °C. :param gyro: (n, 3) rad/s or None.
    :param origin: the bin grid's zero, s (default the first row).
    :param previous: (time, temperature) of the row before ``t[0]``, or None.
    :returns: RawBins.
    """
    starts, stretches = _bin_edges(t, bin_s, gap_s, origin)
    stops = np.r_[starts[1:], len(t)]
    count = stops - starts
    mean = np.add.reduceat(accel, starts, axis=0) / count[:, None]
    sq = np.add.reduceat(accel ** 2, starts, axis=0) / count[:, None]
    scatter = np.sqrt(np.maximum(sq - mean ** 2, 0.0) * count[:, None]
                      / np.maximum(count - 1, 1)[:, None])
    t_mid = np.add.reduceat(t, starts) / count
    temp_mean = np.add.reduceat(temp, starts) / count
    gyro_mean = None if gyro is None else np.add.reduceat(gyro, starts, axis=0) / count[:, None]
    segment = np.searchsorted(stretches, starts, side='right') - 1
    before_t = t[0] if previous is None else previous[0]
    before_x = temp[0] if previous is None else previous[1]
    dt = np.diff(np.r_[before_t, t])
    step = np.abs(np.diff(np.r_[before_x, temp]))
    step[~((dt >= 0) & (dt <= gap_s))] = 0.0
    temp_step = np.maximum.reduceat(step, starts)
    second = np.abs(np.r_[0.0, temp[2:] - 2.0 * temp[1:-1] + temp[:-2], 0.0]) \
        if len(temp) >= 3 else np.zeros(len(temp))
    wiggle = np.array([float(np.median(second[a + 1:b - 1])) if b - a >= 3 else np.nan
                       for a, b in zip(starts, stops)])
    bins = StaticWindows(starts, stops, mean, scatter, count, t_mid, temp_mean,
                         gyro_mean=gyro_mean)
    return RawBins(bins, segment, temp_step, wiggle, 0.0)


def _join(pieces):
    """Join RawBins of consecutive pieces (the start/stop indices are not kept)."""
    def cat(name, source=lambda p: p.bins):
        parts = [getattr(source(p), name) for p in pieces]
        return None if any(v is None for v in parts) else np.concatenate(parts)
    n = sum(len(p.bins) for p in pieces)
    bins = StaticWindows(np.zeros(n, int), np.zeros(n, int), cat('mean'), cat('scatter'),
                         cat('count'), cat('t_mid'), cat('temp'), gyro_mean=cat('gyro_mean'))
    return RawBins(bins, cat('segment', lambda p: p), cat('temp_step', lambda p: p),
                   cat('temp_wiggle', lambda p: p), pieces[-1].rate_hz,
                   sum(p.skipped_rows for p in pieces))


def _finite(samples):
    """Return the rows with a finite reading and temperature, and how many were not."""
    if samples.temp is None:
        raise CalibrationError(
            "the recording has no temperature column: a thermal fit needs the IMU's "
            'temperature beside every reading (record temp, or the imu/temperature topic)')
    ok = np.isfinite(samples.temp) & np.all(np.isfinite(samples.accel), axis=1)
    gyro = None if samples.gyro is None else samples.gyro[ok]
    if gyro is not None and not np.all(np.isfinite(gyro)):
        gyro = None
    return samples.t[ok], samples.accel[ok], samples.temp[ok], gyro, int((~ok).sum())


def _rate(t):
    dt = np.diff(t)
    return 1.0 / float(np.median(dt[dt > 0])) if np.any(dt > 0) else 1.0


def still_bins(samples, bin_s=BIN_S, min_span_c=MIN_THERMAL_SPAN_C, gap_s=None):
    """
    Reduce a still recording with temperature to bins, and check it can carry a thermal fit.

    :param samples: Samples (validated: finite readings, times non-decreasing).
    :param bin_s: bin length, s (lengthened to hold ``MIN_SAMPLES_PER_BIN`` samples).
    :param min_span_c: smallest temperature span, °C.
    :param gap_s: a longer pause in the samples splits the recording (default: 5 bins).
    :returns: StillRecording (``samples``: the rows the bins index).
    :raises CalibrationError: with the reason and what to record.
    """
    t, accel, temp, gyro, skipped = _finite(samples)
    if len(t) < 2 * MIN_SAMPLES_PER_BIN:
        raise CalibrationError(
            f"only {len(t)} rows carry a temperature: record the IMU's temperature "
            'beside its readings for the whole warm-up')
    rate = _rate(t)
    bin_s = max(float(bin_s), MIN_SAMPLES_PER_BIN / rate)
    gap_s = 5.0 * bin_s if gap_s is None else float(gap_s)
    raw = bin_samples(t, accel, temp, gyro, bin_s, gap_s)
    raw.rate_hz, raw.skipped_rows = rate, skipped
    from ..samples import Samples
    return still_recording(raw, min_span_c, Samples(t, accel, temp, gyro))


def still_recording(raw, min_span_c=MIN_THERMAL_SPAN_C, samples=None):
    """
    Check binned data can carry a thermal fit: the temperature, the moves, the span.

    :param raw: RawBins (``bin_samples``, or a node's ``StillBinner``).
    :param samples: the rows ``raw`` indexes (for the noise from their spectrum), or None.
    :returns: StillRecording.
    :raises CalibrationError: with the reason and what to record.
    """
    bins = raw.bins
    _check_temperature(raw)
    full = bins.count >= MIN_SAMPLES_PER_BIN
    keep, dropped = _knocks(bins, full)
    pose, moves = _poses(bins, keep, raw.segment)
    share = 1.0 - keep.sum() / max(full.sum(), 1)
    if not keep.any() or pose.max() + 1 > MAX_STILL_POSES or share > MAX_MOVING_SHARE:
        when = ', '.join(f'{m:.0f} s' for m in moves[:5])
        raise CalibrationError(
            f'the sensor moved during the recording ({len(moves)} moves'
            + (f', at {when}' if moves else '') + f'; {100 * share:.0f} % of it not still): '
            'hold one pose still for the whole warm-up or chamber cycle (fix the IMU to the '
            'bench, keep the robot off and untouched)')
    kept = bins.select(keep)
    _, pose = np.unique(pose[keep], return_inverse=True)
    rec = StillRecording(kept, pose, raw.segment[keep], kept.noise_std, raw.rate_hz, dropped,
                         raw.skipped_rows, moves, samples)
    low, high = rec.temp_range_c
    if high - low < min_span_c:
        raise CalibrationError(
            f'the temperature spans only {high - low:.1f} °C ({low:.1f} .. {high:.1f} °C); a '
            f'thermal fit needs at least {min_span_c:g} °C: record from a cold start (the robot '
            'off overnight, or cooled in a fridge) while it warms up for 30-60 minutes, or '
            'a chamber cycle')
    return rec


class StillBinner:
    """
    Bins of a live stream, collected as they close (the calibration node's thermal intake).

    Rows are kept until their bin closes, then cut by ``bin_samples`` (the same bins as a
    recording of them gives); at most ``max_bins`` are kept (the oldest go first).

    :param bin_s: bin length, s. :param gap_s: a longer silence starts a new stretch.
    """

    def __init__(self, bin_s=BIN_S, gap_s=None, max_bins=8640):
        self.bin_s = float(bin_s)
        self.gap_s = 5.0 * self.bin_s if gap_s is None else float(gap_s)
        self.max_bins = int(max_bins)
        self.pending = np.zeros((0, 8))         # t, ax, ay, az, temp, gx, gy, gz
        self.pieces, self.skipped = [], 0
        self.origin = self.previous = None
        self.segment = 0
        self.dt = []

    def add(self, t, accel, temp, gyro=None):
        """Take one row (s, (3,) m/s², °C, (3,) rad/s or None); non-finite rows are counted."""
        self.extend([t], [accel], [temp], None if gyro is None else [gyro])

    def extend(self, t, accel, temp, gyro=None):
        """
        Take rows (n,) s, (n, 3) m/s², (n,) °C, (n, 3) rad/s or None, in time order.

        Rows without a finite time, reading or temperature are counted and left out; a gyro
        row that is not finite leaves the gyro out of its bin.
        """
        t = np.asarray(t, float).reshape(-1)
        accel = np.asarray(accel, float).reshape(-1, 3)
        temp = np.asarray(temp, float).reshape(-1)
        gyro = np.full((len(t), 3), np.nan) if gyro is None \
            else np.asarray(gyro, float).reshape(-1, 3)
        ok = np.isfinite(t) & np.isfinite(temp) & np.all(np.isfinite(accel), axis=1)
        self.skipped += int((~ok).sum())
        rows = np.column_stack([t, accel, temp, gyro])[ok]
        if not len(rows):
            return
        last = self.pending[-1, 0] if len(self.pending) else \
            (self.previous[0] if self.previous is not None else rows[0, 0])
        dt = np.diff(np.r_[last, rows[:, 0]])
        breaks = np.flatnonzero(~((dt >= 0) & (dt <= self.gap_s)))
        starts = np.unique(np.r_[0, breaks])
        for a, b in zip(starts, np.r_[starts[1:], len(rows)]):
            if a in breaks:                         # a silence (or a step back) before it
                if len(self.pending):
                    self._close(everything=True)
                self.origin, self.previous = None, None
                self.segment += 1
            if b > a:
                self.pending = np.vstack([self.pending, rows[a:b]])
            if len(self.pending) and self.pending[-1, 0] - self.pending[0, 0] >= 2 * self.bin_s:
                self._close()

    def _close(self, everything=False, keep=False):
        """
        Bin the rows of every closed bin (``everything``: the open one too).

        ``keep``: return the piece without taking the rows (the open bin as it stands).
        """
        rows = self.pending
        t = rows[:, 0]
        origin = t[0] if self.origin is None else self.origin
        k = np.floor((t - origin) / self.bin_s)
        done = len(t) if everything else int(np.searchsorted(k, k[-1], side='left'))
        if done == 0:
            return None
        t, accel, temp = t[:done], rows[:done, 1:4], rows[:done, 4]
        gyro = rows[:done, 5:8]
        gyro = None if np.isnan(gyro).any() else gyro
        piece = bin_samples(t, accel, temp, gyro, self.bin_s, self.gap_s, origin,
                            self.previous)
        piece.segment = piece.segment + self.segment
        if keep:
            return piece
        self.origin = origin
        self.pieces.append(piece)
        self.previous = (t[-1], temp[-1])
        self.dt.append(np.median(np.diff(t)) if len(t) > 1 else np.nan)
        self.pending = self.pending[done:]
        while sum(len(p.bins) for p in self.pieces) > self.max_bins and len(self.pieces) > 1:
            self.pieces.pop(0)
        return piece

    def __len__(self):
        return sum(len(p.bins) for p in self.pieces) + int(len(self.pending) > 0)

    def span_c(self):
        """Return the temperature span of the bins so far, °C (0 with none)."""
        raw = self.raw()
        return 0.0 if raw is None else float(np.ptp(raw.bins.temp))

    def raw(self):
        """Return the bins so far, the open one as it stands (RawBins), or None."""
        pieces = list(self.pieces)
        if len(self.pending):
            pieces.append(self._close(everything=True, keep=True))
        if not pieces:
            return None
        out = _join(pieces)
        dt = np.array([v for v in self.dt if np.isfinite(v) and v > 0])
        if not len(dt) and len(self.pending) > 1:
            dt = np.diff(self.pending[:, 0])
        out.rate_hz = 1.0 / float(np.median(dt)) if len(dt) and np.median(dt) > 0 else 1.0
        out.skipped_rows = self.skipped
        return out

    def recording(self, min_span_c=MIN_THERMAL_SPAN_C):
        """Return the checked StillRecording of the bins so far (CalibrationError if not)."""
        raw = self.raw()
        if raw is None or len(raw.bins) < 2:
            raise CalibrationError('no thermal data collected yet: keep the robot still while '
                                   'it warms up (imu/data_raw with imu/temperature)')
        return still_recording(raw, min_span_c)

    def clear(self):
        """Forget everything collected."""
        self.__init__(self.bin_s, self.gap_s, self.max_bins)


def _check_temperature(raw):
    """Refuse a reported temperature that scatters or jumps too much to place offsets."""
    wiggle = raw.temp_wiggle[np.isfinite(raw.temp_wiggle)]
    if len(wiggle):
        noise = 1.4826 * float(np.median(wiggle)) / np.sqrt(6.0)
        if noise > MAX_TEMP_NOISE_C:
            raise CalibrationError(
                f'the temperature reading scatters by about ±{noise:.2f} °C from sample to '
                f'sample (more than {MAX_TEMP_NOISE_C:g} °C): average it over a few samples, '
                "or record the IMU's own temperature sensor")
    if len(raw.temp_step) and raw.temp_step.max() > MAX_TEMP_STEP_C:
        k = int(np.argmax(raw.temp_step))
        raise CalibrationError(
            f'the temperature jumps by {raw.temp_step[k]:.1f} °C between two samples (near t = '
            f"{raw.bins.t_mid[k]:.1f} s): record the IMU's own temperature (0.003 °C steps) at "
            f'least once a second, not a coarse or intermittent thermometer (jumps up to '
            f'{MAX_TEMP_STEP_C:g} °C are taken)')


def _knocks(bins, full):
    """Return the bins that held still (bool) and the ones left out (dicts)."""
    keep = full.copy()
    dropped = []
    scatter = np.linalg.norm(bins.scatter, axis=1)
    typical = float(np.median(scatter[full])) if full.any() else 0.0
    if typical > 0:
        knock = full & (scatter > KNOCK_FACTOR * typical)
        for k in np.flatnonzero(knock):
            dropped.append((k, 'the readings scatter '
                            f"{scatter[k] / typical:.0f} times the recording's noise (a knock "
                            'or a move)'))
        keep &= ~knock
    if bins.gyro_mean is not None and full.any():
        # Against the neighbouring bins' median: the zero-rate offset itself moves with
        # temperature (the MPU-9250's by up to ±30 °/s over its range), a turn is brief.
        from scipy.ndimage import median_filter
        local = median_filter(bins.gyro_mean, size=(TURN_BINS, 1), mode='nearest')
        rate = np.degrees(bins.gyro_mean - local)
        turn = full & keep & (np.linalg.norm(rate, axis=1) > TURN_DEG_S)
        for k in np.flatnonzero(turn):
            dropped.append((k, f'the gyro turns {np.linalg.norm(rate[k]):.2f} °/s'))
        keep &= ~turn
    out = [{'t_start': float(bins.t_mid[k]), 't_stop': float(bins.t_mid[k]), 'reason': why}
           for k, why in sorted(dropped)]
    return keep, out


def _poses(bins, keep, segment):
    """
    Return the pose index of every bin (a new pose after each move) and the move times.

    A move is a step of the mean between neighbouring kept bins larger than ``MOVE_MG``
    and than what the temperature change between them can make (``MAX_TEMPCO_MG_C``) plus
    ten times the noise of the two means. A pause in time also starts a new pose (the
    sensor may have been moved while nothing was recorded).
    """
    from ..constants import G0
    idx = np.flatnonzero(keep)
    pose = np.zeros(len(keep), int)
    moves = []
    if not len(idx):
        return pose, moves
    mean, temp = bins.mean[idx], bins.temp[idx]
    noise = bins.scatter[idx] / np.sqrt(bins.count[idx])[:, None]
    step = np.linalg.norm(np.diff(mean, axis=0), axis=1) * 1000.0 / G0
    allowed = (MOVE_MG + MAX_TEMPCO_MG_C * np.abs(np.diff(temp))
               + 10.0 * np.linalg.norm(noise[1:] + noise[:-1], axis=1) * 1000.0 / G0)
    new = (step > allowed) | (np.diff(segment[idx]) != 0)
    current = 0
    for j, k in enumerate(idx):
        if j and new[j - 1]:
            current += 1
            if segment[idx[j - 1]] == segment[k]:
                moves.append(float(bins.t_mid[k]))
        pose[k] = current
    return pose, moves
