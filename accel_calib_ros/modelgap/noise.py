"""
How much a window mean scatters, and the largest gap noise alone explains.

``window_noise`` measures the noise of each window mean from the data's own
within-window spectrum (batch means and a tapered periodogram); ``null_gap_limit`` and
``null_gap_p`` give the gap's law under noise alone (an F distribution whose second
degrees of freedom say how well the noise itself was measured).
"""

from dataclasses import dataclass

import numpy as np
from scipy import stats

from .model import Conditions

RAMP_TEMP_C = 0.05
"""Temperature change inside a window above which its linear ramp is not counted as noise."""


WANDER_FACTOR = 20.0
"""A window whose block means wander this many times the pooled level holds motion."""


@dataclass
class WindowNoise:
    """
    How much a window mean scatters, measured inside the windows.

    :param inflation: (3,) variance of a window mean over the white-noise value
        sample variance / n: 1 for white noise, more for correlated noise (a DLPF, AR
        noise, flicker), less for vibration that averages out within a window.
    :param relative_se: (3,) standard error of ``inflation`` over its value.
    :param method: per axis, 'white', 'correlated', 'averaging down', 'vibration' or
        'given'.
    :param moving: (W,) bool, windows whose block means wander more than
        ``WANDER_FACTOR`` times the pooled level: they hold motion, not a pose.
    """

    inflation: np.ndarray
    relative_se: np.ndarray
    method: list
    moving: np.ndarray = None

    @property
    def dof(self):
        """Effective degrees of freedom of the noise level (chi² of 2 / relative variance)."""
        rel = float(np.mean(self.relative_se ** 2)) / 3.0
        return float(2.0 / rel) if rel > 0 else float('inf')


NULL_QUANTILE = 0.999
"""The null gap limit is this quantile of the gap's distribution under noise alone."""


NULL_TOLERANCE = 0.05
"""Relative margin on the null gap limit for a bias of the measured noise level."""


def null_gap_limit(dof, noise_dof, quantile=NULL_QUANTILE):
    """
    Return the largest gap that noise alone gives with probability ``quantile``.

    Under noise alone gap² = (chi²_dof / dof) / (chi²_nu / nu): the model's chi² over
    the noise level's own estimate, nu = ``noise_dof`` its effective degrees of freedom
    (``WindowNoise.dof``; inf when the noise is known). So gap² follows F(dof, nu),
    analytic: no re-simulation noise, the same verdict from run to run.
    """
    dof = max(int(dof), 1)
    if not np.isfinite(noise_dof):
        q = stats.chi2.ppf(quantile, dof) / dof
    else:
        q = stats.f.ppf(quantile, dof, max(noise_dof, 1.0))
    return float(np.sqrt(q) * (1.0 + NULL_TOLERANCE))


def null_gap_p(gap, dof, noise_dof):
    """Return P(gap >= ``gap`` | noise alone) from the F(dof, nu) law of ``null_gap_limit``."""
    dof = max(int(dof), 1)
    x = (gap / (1.0 + NULL_TOLERANCE)) ** 2
    if not np.isfinite(noise_dof):
        return float(stats.chi2.sf(x * dof, dof))
    return float(stats.f.sf(x, dof, max(noise_dof, 1.0)))


def _batch_ratios(x, blocks, removed):
    """
    Return m var(block means) / var(samples) per axis for one window, shape (3,).

    :param x: (n, 3) samples of one window with ``removed`` fitted terms taken out
        (1: the mean; 2: mean and linear ramp), which cost as many degrees of freedom
        among the block means.
    :param blocks: number of blocks.
    :param removed: 1 or 2.
    :returns: each ratio divided by the median of chi²(d)/d, d = blocks - removed, so that
        the median over windows is an unbiased estimate for chi²-distributed ratios.
    """
    n = len(x) // blocks
    x = x[:n * blocks].reshape(blocks, n, 3)
    var_sample = np.sum(x.reshape(-1, 3) ** 2, axis=0) / (n * blocks - removed)
    dof = blocks - removed
    var_block = np.sum(x.mean(axis=1) ** 2, axis=0) / dof * n
    with np.errstate(divide='ignore', invalid='ignore'):
        ratio = np.where(var_sample > 0, var_block / var_sample, np.nan)
    return ratio / (stats.chi2.median(dof) / dof)


def _low_frequency_ratio(x):
    """
    Return the noise power near 0 Hz over the sample variance, per axis, shape (3,).

    Hann-tapered periodogram of one window (mean removed), bins 2 and 3 (bins 0 and 1
    hold what is left of the mean): 1 for white noise. The taper's side lobes fall fast,
    so vibration at tens of Hz does not leak into these bins as it does into block means.
    """
    n = len(x)
    taper = np.hanning(n)
    spectrum = np.abs(np.fft.rfft(x * taper[:, None], axis=0)) ** 2 / np.sum(taper ** 2)
    var = np.sum(x ** 2, axis=0) / max(n - 1, 1)
    with np.errstate(divide='ignore', invalid='ignore'):
        ratio = np.where(var > 0, spectrum[2:4].mean(axis=0) / var, np.nan)
    return ratio / (stats.chi2.median(4) / 4)


def _pooled(ratios):
    """
    Return the median of per-window ratios and its standard error.

    The spread is the robust 1.4826 MAD (a window that holds a move must not swamp it);
    the median's standard error is 1.2533 spread / sqrt(n).
    """
    ratios = ratios[np.isfinite(ratios)]
    if len(ratios) < 3:
        return np.nan, np.nan
    median = float(np.median(ratios))
    spread = 1.4826 * float(np.median(np.abs(ratios - median)))
    return median, 1.2533 * spread / np.sqrt(len(ratios))


def window_noise(samples, windows, blocks=8):
    """
    Measure the variance of each window mean from the data's own within-window spectrum.

    Each window (less a linear ramp if the temperature moved more than ``RAMP_TEMP_C``
    inside it: the ramp is the model's business, not noise) is cut into 2 ``blocks``,
    ``blocks`` and ``blocks / 2`` blocks of m samples. R(m) = m var(block means) /
    var(samples) is the low-frequency noise power over the total: 1 for white noise, more
    for noise correlated over many samples (a DLPF at 1 kHz, AR noise), less when the
    sample scatter is vibration that averages out. R is pooled per axis as the median
    over windows (chi²-median corrected, see ``_batch_ratios``) and compared between the
    block lengths:

    - equal within twice their standard error (and R(n/16), when the windows are long
      enough, equal to R(n/8)): white at these scales, R(n/8) is used;
    - otherwise R approaches its limit like R_inf + C/m and is extrapolated to the
      whole window, R(n) = 1.875 R(n/8) - 0.875 R(n/16) (the more precise pair), or
      1.75 R(n/4) - 0.75 R(n/8) for short windows: larger for longer blocks is
      correlated noise;
    - when the Hann-tapered spectrum near 0 Hz (``_low_frequency_ratio``) is well below
      that, the sample scatter is vibration above 0 Hz: the spectral value plus the
      vibration's leak into a rectangular mean, (R(n/8) - spectral) / 8, is used.

    :param samples: Samples the windows were detected in.
    :param windows: StaticWindows (start, stop index the samples).
    :param blocks: blocks per window for the short batches (even, >= 8).
    :returns: WindowNoise (white, unit inflation when no window is long enough).
    """
    half = blocks // 2
    short, long_, finest, spectral, tested = [], [], [], [], []
    for w, (a, b) in enumerate(zip(windows.start, windows.stop)):
        if (b - a) // blocks < 8:
            continue
        tested.append(w)
        x = samples.accel[a:b]
        x = x - x.mean(axis=0)
        removed = 1
        if samples.temp is not None and np.ptp(samples.temp[a:b]) > RAMP_TEMP_C:
            # The temperature moved inside the window: its ramp is the model's business.
            # (Removing a ramp also removes some slow noise, so only when needed.)
            ramp = np.linspace(-1.0, 1.0, len(x))[:, None]
            x = x - ramp * (ramp * x).sum(axis=0) / (ramp ** 2).sum()
            removed = 2
        spectral.append(_low_frequency_ratio(x))
        finest.append(_batch_ratios(x, 2 * blocks, removed) if (b - a) // (2 * blocks) >= 8
                      else np.full(3, np.nan))
        short.append(_batch_ratios(x, blocks, removed))
        long_.append(_batch_ratios(x, half, removed))
    inflation, rel, method = np.ones(3), np.zeros(3), ['white'] * 3
    moving = np.zeros(len(windows), bool)
    if len(short) < 3:
        return WindowNoise(inflation, rel, method, moving)
    short, long_ = np.asarray(short), np.asarray(long_)
    level = np.nanmedian(short, axis=0)
    with np.errstate(invalid='ignore', divide='ignore'):
        wander = np.nanmax(short / np.where(level > 0, level, np.nan), axis=1)
    moving[np.asarray(tested)[wander > WANDER_FACTOR]] = True
    keep = ~(wander > WANDER_FACTOR)
    short, long_, spectral = short[keep], long_[keep], np.asarray(spectral)[keep]
    finest = np.asarray(finest)[keep]
    for i in range(3):
        r8, se8 = _pooled(short[:, i])
        r4, se4 = _pooled(long_[:, i])
        if not (np.isfinite(r8) and np.isfinite(r4)) or r8 <= 0:
            continue
        r16, se16 = _pooled(finest[:, i])
        fine = np.isfinite(r16) and abs(r8 - r16) > 2.0 * np.hypot(se8, se16)
        if abs(r4 - r8) <= 2.0 * np.hypot(se4, se8) and not fine:
            value, se = r8, se8
        elif fine:
            # R(m) = R_inf + C/m: C < 0 for correlated noise (a DLPF, AR noise), C > 0 for
            # vibration without power at 0 Hz (its block means average down like 1/m).
            # Extrapolated from n/16 and n/8 to the whole window (the precise pair).
            value = max(1.875 * r8 - 0.875 * r16, 0.125 * r8)
            se = np.hypot(1.875 * se8, 0.875 * se16)
            method[i] = 'correlated' if r8 > r16 else 'averaging down'
        else:
            # The same from n/8 and n/4 (windows too short for 16 blocks).
            value = max(1.75 * r4 - 0.75 * r8, 0.25 * r4)
            se = np.hypot(1.75 * se4, 0.75 * se8)
            method[i] = 'correlated' if r4 > r8 else 'averaging down'
        rs, ses = _pooled(spectral[:, i])
        if (np.isfinite(rs) and rs < 0.5 * min(value, r8)
                and rs < r8 - 3.0 * np.hypot(ses, se8)):
            # Vibration: the sample scatter is power well above 0 Hz. The tapered
            # low-frequency spectrum gives the noise under it; what the vibration leaks
            # into a rectangular mean falls like 1/m, from R(n/8) to R(n) by 8.
            value = rs + (r8 - rs) / blocks
            se, method[i] = np.hypot(ses, se8 / blocks), 'vibration'
        inflation[i] = max(value, 1e-3)
        rel[i] = se / inflation[i]
    return WindowNoise(inflation, rel, method, moving)


def simulated_null_gaps(model, fit, c, rng, replicates):
    """Return the gaps of the fitted model re-simulated under the session's conditions."""
    a = model.true_accel(fit.x, c)
    directions = a / np.linalg.norm(a, axis=1, keepdims=True)
    clean = model.predict(fit.x, directions, c)
    gaps = []
    for _ in range(replicates):
        sim = Conditions(clean + rng.standard_normal(clean.shape) * c.sigma, c.sigma,
                         c.temp, c.time, c.gravity, c.temp_span, c.time_span)
        try:
            _, chi2, _ = model.fit(sim, fit.x)
        except (ValueError, np.linalg.LinAlgError):
            continue
        gaps.append(float(np.sqrt(chi2 / max(fit.dof, 1))))
    return gaps
