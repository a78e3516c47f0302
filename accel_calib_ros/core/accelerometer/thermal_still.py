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
  more than ``MAX_POSES`` poses, or most of the recording moving, is refused.
"""

from dataclasses import dataclass, field

import numpy as np

from ..errors import CalibrationError
from ..windows import StaticWindows

BIN_S = 10.0
"""Default bin length, s: short against the temperature's changes, long against noise."""

MIN_SAMPLES_PER_BIN = 3
"""A bin needs at least this many samples (longer bins at rates below 0.3 Hz)."""

MIN_SPAN_C = 5.0
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

MAX_POSES = 6
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


def _bin_edges(t, bin_s, gap_s):
    """Return the sample index where each bin starts, and where each gap-free stretch does."""
    dt = np.diff(t)
    gaps = np.flatnonzero(dt > gap_s) + 1
    stretches = np.r_[0, gaps]
    starts = []
    for a, b in zip(stretches, np.r_[gaps, len(t)]):
        k = np.floor((t[a:b] - t[a]) / bin_s).astype(np.int64)
        starts.append(a + np.flatnonzero(np.diff(k, prepend=-1)))
    return np.concatenate(starts), stretches


def still_bins(samples, bin_s=BIN_S, min_span_c=MIN_SPAN_C, gap_s=None):
    """
    Reduce a still recording with temperature to bins, and check it can carry a thermal fit.

    :param samples: Samples (validated: finite readings, times non-decreasing).
    :param bin_s: bin length, s (lengthened to hold ``MIN_SAMPLES_PER_BIN`` samples).
    :param min_span_c: smallest temperature span, °C.
    :param gap_s: a longer pause in the samples splits the recording (default: 5 bins).
    :returns: StillRecording.
    :raises CalibrationError: with the reason and what to record.
    """
    if samples.temp is None:
        raise CalibrationError(
            "the recording has no temperature column: a thermal fit needs the IMU's "
            'temperature beside every reading (record temp, or the imu/temperature topic)')
    t, accel, temp = samples.t, samples.accel, samples.temp
    ok = np.isfinite(temp) & np.all(np.isfinite(accel), axis=1)
    skipped = int((~ok).sum())
    if ok.sum() < 2 * MIN_SAMPLES_PER_BIN:
        raise CalibrationError(
            f"only {int(ok.sum())} rows carry a temperature: record the IMU's temperature "
            'beside its readings for the whole warm-up')
    t, accel, temp = t[ok], accel[ok], temp[ok]
    gyro = None if samples.gyro is None else samples.gyro[ok]
    if gyro is not None and not np.all(np.isfinite(gyro)):
        gyro = None
    dt = np.diff(t)
    rate = 1.0 / float(np.median(dt[dt > 0])) if np.any(dt > 0) else 1.0
    bin_s = max(float(bin_s), MIN_SAMPLES_PER_BIN / rate)
    gap_s = 5.0 * bin_s if gap_s is None else float(gap_s)
    _check_temperature(t, temp, rate, gap_s)
    starts, stretches = _bin_edges(t, bin_s, gap_s)
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
    bins = StaticWindows(starts, stops, mean, scatter, count, t_mid, temp_mean,
                         gyro_mean=gyro_mean)
    full = count >= MIN_SAMPLES_PER_BIN
    keep, dropped = _knocks(bins, full)
    pose, moves = _poses(bins, keep, segment)
    share = 1.0 - keep.sum() / max(full.sum(), 1)
    if pose.max() + 1 > MAX_POSES or share > MAX_MOVING_SHARE:
        when = ', '.join(f'{m:.0f} s' for m in moves[:5])
        raise CalibrationError(
            f'the sensor moved during the recording ({len(moves)} moves'
            + (f', at {when}' if moves else '') + f'; {100 * share:.0f} % of it not still): '
            'hold one pose still for the whole warm-up or chamber cycle (fix the IMU to the '
            'bench, keep the robot off and untouched)')
    bins = bins.select(keep)
    _, pose = np.unique(pose[keep], return_inverse=True)
    from ..samples import Samples
    rows = Samples(t, accel, temp, gyro)
    rec = StillRecording(bins, pose, segment[keep], bins.noise_std, rate, dropped, skipped,
                         moves, rows)
    low, high = rec.temp_range_c
    if high - low < min_span_c:
        raise CalibrationError(
            f'the temperature spans only {high - low:.1f} °C ({low:.1f} .. {high:.1f} °C); a '
            f'thermal fit needs at least {min_span_c:g} °C: record from a cold start (the robot '
            'off overnight, or cooled in a fridge) while it warms up for 30-60 minutes, or '
            'a chamber cycle')
    return rec


def _check_temperature(t, temp, rate, gap_s):
    """Refuse a reported temperature that jumps or scatters too much to place offsets."""
    # Scatter about a local straight line: the second difference of neighbours.
    if len(temp) >= 3:
        second = temp[2:] - 2.0 * temp[1:-1] + temp[:-2]
        noise = 1.4826 * float(np.median(np.abs(second - np.median(second)))) / np.sqrt(6.0)
        if noise > MAX_TEMP_NOISE_C:
            raise CalibrationError(
                f'the temperature reading scatters by about ±{noise:.2f} °C from sample to '
                f'sample (more than {MAX_TEMP_NOISE_C:g} °C): average it over a few samples, '
                "or record the IMU's own temperature sensor")
    dt = np.diff(t)
    steps = np.abs(np.diff(temp))
    steps[dt > gap_s] = 0.0
    if steps.size and steps.max() > MAX_TEMP_STEP_C:
        k = int(np.argmax(steps))
        raise CalibrationError(
            f'the temperature jumps by {steps[k]:.1f} °C between two samples (at t = '
            f"{t[k + 1]:.1f} s): record the IMU's own temperature (0.003 °C steps) at least "
            f'once a second, not a coarse or intermittent thermometer (jumps up to '
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
