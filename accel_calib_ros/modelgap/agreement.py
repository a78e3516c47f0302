"""
What the still data and the jumps in time show: measurements the workflow checks effects by.

``still_drift``: the drift of the offset the still windows show directly, which a fitted
linear drift must agree with (``BiasDrift.contradiction``). ``best_step`` is the single
jump in time that ``pruning`` checks a time effect against when the gap is not closed.
A random walk's roughness is the walk's own (``walk``).
"""

import numpy as np

from .noise import RAMP_TEMP_C
from .probes import delta_bic
from ..core.constants import G0


def best_step(model, fit, c):
    """
    Return the best single jump in time of the offset, as an alternative to a time effect.

    Offsets that jump once, n . h for windows after a time t_j, scanned over the gaps
    between windows (linearised, after the model's Jacobian is projected out); the jump
    time counts as one more parameter in the BIC.

    :returns: dict with 'delta_chi2', 'delta_bic', 'time', 'size_mg', 'basis' (N, 3), or
        None when the session has too few windows.
    """
    order = np.argsort(c.time, kind='stable')
    n = len(c.time)
    if n < 12 or fit.jac is None:
        return None
    rho, s = model.residual_parts(fit.x, c)
    a = model.true_accel(fit.x, c)
    directions = a / np.linalg.norm(a, axis=1, keepdims=True)
    q = np.linalg.qr(fit.jac)[0]
    r = rho / s
    best = None
    for cut in range(3, n - 2):
        after = np.zeros(n)
        after[order[cut:]] = 1.0
        cols = after[:, None] * directions / s[:, None]
        cols = cols - q @ (q.T @ cols)
        u, sv, _ = np.linalg.svd(cols, full_matrices=False)
        u = u[:, sv > 1e-6 * max(sv.max(), 1e-300)]
        drop = float(np.sum((u.T @ r) ** 2))
        if best is None or drop > best['delta_chi2']:
            smooth = (u @ (u.T @ r)) * s
            best = {'delta_chi2': drop, 'basis': u,
                    'time': float(0.5 * (c.time[order[cut - 1]] + c.time[order[cut]])),
                    'size_mg': float(1000.0 * np.sqrt(np.mean(smooth ** 2)) / G0)}
    best['delta_bic'] = delta_bic(fit.chi2, best['delta_chi2'], best['basis'].shape[1] + 1, n)
    return best


SAME_POSE_DEG = 0.5
"""Consecutive windows whose mean directions differ less than this hold the same pose."""


def still_drift(samples, windows, noise=None):
    """
    Return the drift of the offset that the still data themselves show, or None.

    Within a pose the direction of gravity is fixed, so with a steady temperature (moved
    less than ``RAMP_TEMP_C``, or not recorded) the readings change only by a drift.
    Consecutive windows in the same pose (mean directions within ``SAME_POSE_DEG``: the
    detector may cut a long rest into pieces) form one still segment; the least-squares
    slope of its samples against time (one offset per segment) has variance
    R sigma² / sum (t - t̄)², R the noise's low-frequency factor (``window_noise``), and the
    segments are pooled by their inverse variances. A long still segment (a warm-up, an
    initial rest) dominates.

    :returns: dict 'slope' (3,) reading units per s, 'se' (3,), 'seconds' of still data
        used, 'longest_s' (the longest segment); None without a segment of 8 samples.
    """
    ratio = (noise.inflation / noise.taper) if noise is not None else np.ones(3)
    ratio = np.maximum(ratio, 1.0)
    order = np.argsort(windows.t_mid, kind='stable')
    unit = windows.mean / np.linalg.norm(windows.mean, axis=1, keepdims=True)
    segments, current = [], []
    for w in order:
        a, b = windows.start[w], windows.stop[w]
        steady = samples.temp is None or np.ptp(samples.temp[a:b]) <= RAMP_TEMP_C
        if not steady or b - a < 8:
            if current:
                segments.append(current)
            current = []
            continue
        if current and float(unit[current[-1]] @ unit[w]) < np.cos(np.radians(SAME_POSE_DEG)):
            segments.append(current)
            current = []
        current.append(w)
    if current:
        segments.append(current)
    num, den, seconds, longest = np.zeros(3), np.zeros(3), 0.0, 0.0
    for segment in segments:
        index = np.concatenate([np.arange(windows.start[w], windows.stop[w]) for w in segment])
        t = samples.t[index] - samples.t[index].mean()
        x = samples.accel[index] - samples.accel[index].mean(axis=0)
        sxx = float(t @ t)
        if sxx <= 0:
            continue
        slope = (t @ x) / sxx
        resid = x - np.outer(t, slope)
        var = ratio * np.sum(resid ** 2, axis=0) / max(len(t) - 2, 1) / sxx
        var = np.where(var > 0, var, np.inf)
        num += slope / var
        den += 1.0 / var
        span = float(t[-1] - t[0])
        seconds += span
        longest = max(longest, span)
    if not np.all(den > 0):
        return None
    return {'slope': num / den, 'se': 1.0 / np.sqrt(den), 'seconds': seconds,
            'longest_s': longest}
