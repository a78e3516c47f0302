"""
Static-window detection: find the stretches where the sensor was held still.

A sample is still when the moving standard deviation of the acceleration (and,
if asked, of the angular rate) over ``window_s`` stays below ``threshold_factor``
times the recording's own noise floor. The floor is a low quantile of that moving
standard deviation, so no threshold has to be tuned per sensor. A run of still
samples longer than ``min_duration_s`` becomes a window after ``trim_s`` is cut
from each end (the hand is still settling there).

When the recording has an angular rate, the gyro joins the offline test: a still
run is also required to turn slower than ``max_rotation_rad_s`` (moving mean of the
bias-free rate over ``window_s``), so a slow turn that the accelerometer alone
cannot see does not leak into a window. A run that rotates is cut to its longest
non-rotating part, or dropped and reported in ``StaticWindows.dropped``.
"""


from dataclasses import dataclass, field

import numpy as np

from ..errors import CalibrationError, InputError
from ..stats import median, quantile

MAX_WEIGHT_S = 5.0
"""A window weighs at most this many seconds of samples (see StaticWindows.weights)."""
DEFAULTS = {'window_s': 0.25, 'min_duration_s': 0.3, 'threshold_factor': 3.0, 'trim_s': 0.1,
            'floor_quantile': 0.02, 'max_rotation_rad_s': float(np.radians(2.0))}


@dataclass(eq=False)          # arrays: equal only to itself
class StaticWindows:
    """
    Static windows of a recording, one row per window.

    :param start: (W,) first sample index (inclusive).
    :param stop: (W,) last sample index (exclusive).
    :param mean: (W, 3) mean raw acceleration, m/s².
    :param scatter: (W, 3) per-axis sample standard deviation, m/s².
    :param count: (W,) samples in the window.
    :param t_mid: (W,) mid time, s.
    :param temp: (W,) mean temperature, °C (NaN when not recorded).
    :param noise_floor: per-sample noise level the thresholds were set from, m/s².
    :param gyro_mean: (W, 3) mean angular rate, rad/s, or None without gyro.
    :param dropped: windows left out, one dict each (t_start, t_stop s, reason).
    :param low_passed: found on the low-passed copy (vibration hid the holds; the
        node's streaming detector has no such pass).
    """

    start: np.ndarray
    stop: np.ndarray
    mean: np.ndarray
    scatter: np.ndarray
    count: np.ndarray
    t_mid: np.ndarray
    temp: np.ndarray
    noise_floor: float = float('nan')
    gyro_mean: np.ndarray = None
    dropped: list = field(default_factory=list)
    low_passed: bool = False

    def __len__(self):
        return len(self.count)

    @property
    def noise_std(self):
        """Pooled within-window per-sample noise, m/s² per axis (3,)."""
        dof = np.maximum(self.count - 1, 0)
        return np.sqrt(np.sum(dof[:, None] * self.scatter ** 2, axis=0) / max(dof.sum(), 1))

    def select(self, index):
        """Windows picked by a boolean mask or index array."""
        return StaticWindows(self.start[index], self.stop[index], self.mean[index],
                             self.scatter[index], self.count[index], self.t_mid[index],
                             self.temp[index], self.noise_floor,
                             None if self.gyro_mean is None else self.gyro_mean[index],
                             list(self.dropped), self.low_passed)

    def weights(self, max_weight_s=None, rate_hz=None):
        """
        Observation weights: samples per window, capped at ``max_weight_s`` of data.

        Averaging beyond a few seconds stops helping on a real MEMS sensor (bias
        instability, flicker noise) while model errors do not average out, so very
        long windows are not allowed to dominate the fit.
        """
        w = self.count.astype(float)
        if max_weight_s and rate_hz:
            w = np.minimum(w, max_weight_s * rate_hz)
        return w


def _moving_std(x, n, block=1 << 18):
    """
    Centred moving standard deviation over ``n`` samples, shape (N,) for ``x`` (N, k).

    Computed ``block`` rows at a time (each with its ``n`` neighbours), so a long
    recording needs a few blocks of scratch memory, not several copies of itself.
    """
    n = max(int(n), 2)
    if len(x) <= block:
        return _moving_std_block(x - x.mean(axis=0), n)
    mean = x.mean(axis=0)
    out = np.empty(len(x))
    before, after = n // 2, n - n // 2 - 1
    for a in range(0, len(x), block):
        b = min(a + block, len(x))
        rows = np.clip(np.arange(a - before, b + after), 0, len(x) - 1)  # edge padding
        out[a:b] = _moving_std_block(x[rows] - mean, n, padded=True)
    return out


def _moving_std_block(x, n, padded=False):
    """Return the moving std of ``x`` (rows already padded by n - 1 when ``padded``)."""
    pad = x if padded else np.pad(x, ((n // 2, n - n // 2 - 1), (0, 0)), mode='edge')
    c1 = np.cumsum(np.vstack([np.zeros((1, x.shape[1])), pad]), axis=0)
    c2 = np.cumsum(np.vstack([np.zeros((1, x.shape[1])), pad ** 2]), axis=0)
    s1 = c1[n:] - c1[:-n]
    s2 = c2[n:] - c2[:-n]
    var = np.maximum(s2 / n - (s1 / n) ** 2, 0.0)
    return np.sqrt(var.sum(axis=1) / x.shape[1])


def still_runs(mask):
    """Return the (start, stop) index arrays of the True runs of a boolean array."""
    edges = np.diff(np.r_[0, mask.astype(np.int8), 0])
    return np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)


def still_mask(samples, window_s=DEFAULTS['window_s'],
               threshold_factor=DEFAULTS['threshold_factor'],
               floor_quantile=DEFAULTS['floor_quantile'], use_gyro=False):
    """
    Boolean (N,) mask of still samples and the accelerometer noise floor (m/s²).

    The gyro is off by default: a pose held by hand shakes the gyro far above the
    floor of a table-still stretch while the specific force stays steady, and a
    steady specific force is all the calibration needs.
    """
    rate = samples.rate_hz
    if not np.isfinite(rate):
        if len(samples) >= 2:       # the median step is 0: most stamps repeat
            raise InputError(f'most of the {len(samples)} rows share their time stamp with '
                             'the row before: write t with more digits (seconds with at '
                             'least 1 ms resolution)')
        raise CalibrationError('cannot find static windows in fewer than two samples')
    n = max(int(round(window_s * rate)), 3)
    acc_std = _moving_std(samples.accel, n)
    g = median(np.linalg.norm(samples.accel, axis=1))
    floor = max(quantile(acc_std, floor_quantile), 1e-5 * g)
    mask = acc_std <= threshold_factor * floor
    if use_gyro and samples.gyro is not None and np.all(np.isfinite(samples.gyro)):
        gyr_std = _moving_std(samples.gyro, n)
        gyr_floor = max(float(np.quantile(gyr_std, floor_quantile)), 1e-6)
        mask &= gyr_std <= threshold_factor * gyr_floor
    return mask, floor


def _moving_mean(x, n):
    """Centred moving mean over ``n`` samples, shape like ``x`` (N, k)."""
    n = max(int(n), 1)
    pad = np.pad(x, ((n // 2, n - n // 2 - 1), (0, 0)), mode='edge')
    c = np.cumsum(np.vstack([np.zeros((1, x.shape[1])), pad]), axis=0)
    return (c[n:] - c[:-n]) / n


def rotation_rate(samples, accel_still, window_s=DEFAULTS['window_s']):
    """
    Bias-free rotation rate (N,) rad/s: |moving mean of gyro - gyro bias|, or None.

    The gyro bias is the median rate over the accelerometer-still samples.
    """
    gyro = samples.gyro
    if gyro is None or len(gyro) < 2 or not np.all(np.isfinite(gyro)):
        return None
    n = max(int(round(window_s * samples.rate_hz)), 3)
    still = accel_still if np.any(accel_still) else np.ones(len(gyro), bool)
    bias = median(gyro[still], axis=0)
    return np.linalg.norm(_moving_mean(gyro - bias, n), axis=1)


VIBRATION_CUTOFF_HZ = 5.0
"""Low-pass corner of the vibration-robust pass (well below vibration, above a pose change)."""
VIBRATION_GAIN = 1.25
"""The low-passed pass is kept when its windows hold this much more still time."""
MERGED_POSES_DEG = 10.0
"""A plain window holding low-passed windows this far apart in direction merged poses."""


def detect_static_windows(samples, window_s=DEFAULTS['window_s'],
                          min_duration_s=DEFAULTS['min_duration_s'],
                          threshold_factor=DEFAULTS['threshold_factor'],
                          trim_s=DEFAULTS['trim_s'],
                          floor_quantile=DEFAULTS['floor_quantile'],
                          max_rotation_rad_s=DEFAULTS['max_rotation_rad_s'],
                          vibration_robust=True):
    """
    Find the static windows of a recording (the one detector of ``fit``, ``advise``, ``diagnose``).

    Strong vibration lifts the moving standard deviation so that the holds no longer
    stand out from the moves. With ``vibration_robust`` the same test therefore also
    runs on a zero-phase low-passed copy (block means to about 100 Hz, then a centred
    moving mean over 1 / (2 ``VIBRATION_CUTOFF_HZ``), twice); its windows are kept only
    when they hold more than ``VIBRATION_GAIN`` times the still time of the plain pass
    (vibration hid the holds) or when a plain window holds low-passed windows whose
    directions differ by more than ``MERGED_POSES_DEG`` (vibration hid the moves: poses
    merged into one window), so a hand-held or table-still session keeps the plain
    windows, which the streaming detector of the node reproduces. Window means and
    scatters always come from the raw samples.

    :param samples: Samples (validated).
    :param window_s: moving standard deviation window, s.
    :param min_duration_s: shortest window kept (after trimming), s.
    :param threshold_factor: still when the moving std < factor x noise floor.
    :param trim_s: cut from each end of a still run, s.
    :param floor_quantile: quantile of the moving std taken as the noise floor.
    :param max_rotation_rad_s: with a gyro, still also means turning slower than
        this (bias-free moving mean, rad/s) and than 5x the median rate of the
        accelerometer-still samples; None or inf switches the gyro test off.
    :param vibration_robust: also try the low-passed copy (see above).
    :returns: StaticWindows (possibly empty), with the runs the gyro rejected in
        ``dropped`` and ``low_passed`` True when the vibration-robust pass won.
    """
    mask, floor = still_mask(samples, window_s, threshold_factor, floor_quantile)
    settings = (samples, window_s, min_duration_s, trim_s, max_rotation_rad_s)
    windows = _windows_of_mask(mask, floor, *settings)
    if vibration_robust:
        low = _low_passed_mask(samples, window_s, threshold_factor, floor_quantile)
        if low is not None:
            robust = _windows_of_mask(*low, *settings)
            if robust.count.sum() > VIBRATION_GAIN * windows.count.sum() \
                    or _merged_poses(windows, robust):
                robust.low_passed = True
                return robust
    return windows


def _merged_poses(plain, robust):
    """Tell whether a plain window spans low-passed windows of different directions."""
    if not len(robust):
        return False
    u = robust.mean / np.maximum(np.linalg.norm(robust.mean, axis=1, keepdims=True), 1e-300)
    cos_min = np.cos(np.radians(MERGED_POSES_DEG))
    for a, b in zip(plain.start, plain.stop):
        inside = u[(robust.start >= a) & (robust.stop <= b)]
        if len(inside) > 1 and np.min(inside @ inside.T) < cos_min:
            return True
    return False


def _low_passed_mask(samples, window_s, threshold_factor, floor_quantile):
    """Still mask (N,) and floor of a low-passed copy, or None when too short or slow."""
    rate = samples.rate_hz
    if not np.isfinite(rate) or rate < 8 * VIBRATION_CUTOFF_HZ or len(samples) < 1000:
        return None
    from ..samples import Samples
    # Block means of k samples (about 100 Hz) first: cheap on 10⁷ rows, and a low-pass.
    k = max(int(rate // 100.0), 1)
    n = len(samples) // k
    coarse = samples.accel[:n * k].reshape(n, k, 3).mean(axis=1)
    # Then a centred moving mean of 1 / (2 cutoff) applied twice: zero phase, numpy
    # only (fit must not pull in scipy), -3 dB near 3 Hz, -27 dB at 15 Hz.
    width = max(int(round(rate / k / (2.0 * VIBRATION_CUTOFF_HZ))), 1)
    smooth = Samples(samples.t[:n * k:k], _moving_mean(_moving_mean(coarse, width), width))
    mask, floor = still_mask(smooth, window_s, threshold_factor, floor_quantile)
    full = np.zeros(len(samples), bool)
    full[:n * k] = np.repeat(mask, k)
    return full, floor


def _windows_of_mask(mask, floor, samples, window_s, min_duration_s, trim_s,
                     max_rotation_rad_s):
    """Cut the still runs of ``mask`` into windows: trim, shortest length, gyro test."""
    rate = samples.rate_hz
    trim = int(round(trim_s * rate))
    min_len = max(int(round(min_duration_s * rate)), 2)
    starts, stops = still_runs(mask)
    starts, stops = starts + trim, stops - trim
    keep = stops - starts >= min_len
    starts, stops = starts[keep], stops[keep]
    dropped = []
    spin = None
    if max_rotation_rad_s is not None and np.isfinite(max_rotation_rad_s):
        spin = rotation_rate(samples, mask, window_s)
    if spin is not None:
        # Turning clearly faster than the recording's own still level (its gyro noise and
        # hand tremor, or a gyro logged in other units), and than the limit.
        level = median(spin[mask]) if mask.any() else 0.0
        limit = max(max_rotation_rad_s, 5.0 * level)
        turning = spin > limit
        new_starts, new_stops = [], []
        for a, b in zip(starts, stops):
            if not turning[a:b].any():
                new_starts.append(a)
                new_stops.append(b)
                continue
            sub_a, sub_b = still_runs(~turning[a:b])
            # Cut ``trim`` more where a part meets the rotation (not at the run's ends).
            sub_a = np.where(sub_a > 0, sub_a + trim, sub_a) + a
            sub_b = np.where(sub_b < b - a, sub_b - trim, sub_b) + a
            lengths = sub_b - sub_a
            if len(lengths) and lengths.max() >= min_len:
                k = int(np.argmax(lengths))
                new_starts.append(sub_a[k])
                new_stops.append(sub_b[k])
            else:
                dropped.append({'t_start': float(samples.t[a]),
                                't_stop': float(samples.t[b - 1]),
                                'reason': f'rotating: gyro shows up to '
                                          f'{np.degrees(spin[a:b].max()):.1f} °/s '
                                          f'(limit {np.degrees(limit):.1f} °/s)'})
        starts = np.asarray(new_starts, dtype=int)
        stops = np.asarray(new_stops, dtype=int)
    windows = windows_from_ranges(samples, starts, stops, floor)
    windows.dropped = dropped
    return windows


def windows_from_ranges(samples, starts, stops, noise_floor=float('nan')):
    """Summarise given sample ranges [start, stop) as StaticWindows."""
    starts = np.asarray(starts, dtype=int)
    stops = np.asarray(stops, dtype=int)
    count = stops - starts
    mean = np.array([samples.accel[a:b].mean(axis=0) if b > a else np.zeros(3)
                     for a, b in zip(starts, stops)]).reshape(-1, 3)  # no (N, 3) scratch
    scatter = np.array([samples.accel[a:b].std(axis=0, ddof=1) if b - a > 1 else np.zeros(3)
                        for a, b in zip(starts, stops)]).reshape(-1, 3)
    t_mid = 0.5 * (samples.t[starts] + samples.t[np.maximum(stops - 1, starts)]) \
        if len(starts) else np.zeros(0)
    if samples.temp is None:
        temp = np.full(len(starts), np.nan)
    else:
        ct = np.r_[0.0, np.cumsum(samples.temp)]
        temp = (ct[stops] - ct[starts]) / np.maximum(count, 1)
    gyro_mean = None
    if samples.gyro is not None:
        cg = np.vstack([np.zeros((1, 3)), np.cumsum(samples.gyro, axis=0)])
        gyro_mean = (cg[stops] - cg[starts]) / np.maximum(count, 1)[:, None]
    return StaticWindows(starts, stops, mean, scatter, count, t_mid, temp, noise_floor,
                         gyro_mean)


def distinct_directions(vectors, min_angle_deg=10.0, limit=None):
    """
    Count the directions among ``vectors`` (N, 3) at least ``min_angle_deg`` apart.

    :param limit: stop counting once this many are found (a check needs no more).
    """
    u = np.asarray(vectors, float)
    u = u / np.linalg.norm(u, axis=1, keepdims=True)
    cos_min = np.cos(np.radians(min_angle_deg))
    remaining = np.ones(len(u), bool)
    count = 0
    while remaining.any():            # greedy: take one, drop all its neighbours
        pick = u[np.argmax(remaining)]
        remaining &= u @ pick < cos_min
        count += 1
        if limit is not None and count >= limit:
            break
    return count
