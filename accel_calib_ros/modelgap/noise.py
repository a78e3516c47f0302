"""
How much a window mean scatters, and the largest gap noise alone explains.

``window_noise`` measures the noise of each window mean from the data's own
within-window spectrum (batch means and a tapered periodogram); ``null_gap_limit`` and
``null_gap_p`` give the gap's law under noise alone (an F distribution whose second
degrees of freedom say how well the noise itself was measured).
"""

from dataclasses import dataclass, replace

import numpy as np
from scipy import optimize, stats

from .effects import G0
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
    :param method: per axis, 'white', 'correlated', 'averaging down', 'vibration',
        'tapered spectrum' (an axis without vibration when the means are tapered),
        'assumed white' (windows too short to measure) or 'given'.
    :param moving: (W,) bool, windows whose block means wander more than
        ``WANDER_FACTOR`` times the pooled level: they hold motion, not a pose.
    :param means: (W, 3) Hann-tapered window means when vibration made them the better
        estimate (``hann_means``), else None (the plain means are used).
    :param taper: white-noise variance of a window mean over a plain mean's (1.5 for
        Hann means, 1 for plain ones); ``inflation`` includes it.
    :param spectrum_bins: periodogram bins pooled per axis for tapered means.
    :param measured: (R(n/8), its standard error), each (3,): R as measured with 8 blocks.
    """

    inflation: np.ndarray
    relative_se: np.ndarray
    method: list
    moving: np.ndarray = None
    means: np.ndarray = None
    taper: float = 1.0
    spectrum_bins: list = None
    measured: tuple = None

    def apply(self, windows):
        """Return the windows with the means the noise level describes (tapered or not)."""
        return windows if self.means is None else replace(windows, mean=self.means)

    @property
    def coloured(self):
        """
        Tell whether some axis's noise is measurably correlated over many samples.

        R(n/8) as measured (not extrapolated) above 1, beyond three standard errors and
        20 %: noise slower than a sample, so noise slower than a window (flicker, AR
        noise, bias instability) is to be expected too, and the window means may scatter
        more than R shows.
        """
        if self.measured is None:
            return False
        ratio, se = self.measured
        return bool(np.any((ratio > 1.2) & (ratio - 1.0 > 3.0 * se)))

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


POWER = 0.8
"""The power figure is the smallest error detected with this probability."""


def detection_probability(error_mg, dof, noise_dof, inv_var_sum, n, quantile=NULL_QUANTILE):
    """
    Return the probability that the gap test detects a systematic error of ``error_mg``.

    The same error model as ``min_detectable_mg`` (an error of that size in every window,
    in a pattern the model cannot absorb).
    """
    dof = max(int(dof), 1)
    x = null_gap_limit(dof, noise_dof, quantile) ** 2
    lam = (error_mg * G0 / 1000.0) ** 2 * inv_var_sum * dof / n
    if not np.isfinite(noise_dof):
        return float(stats.ncx2.sf(x * dof, dof, lam))
    return float(stats.ncf.sf(x, dof, max(noise_dof, 1e-3), lam))


def min_detectable_mg(dof, noise_dof, inv_var_sum, n, quantile=NULL_QUANTILE, power=POWER):
    """
    Return the smallest systematic error per window, mg, that the gap test detects.

    An error of the same size δ in every window, along gravity, in a pattern the model
    cannot absorb (on average it absorbs p / n of a pattern), makes the model's chi²
    noncentral with λ = δ² sum(1/s_k²) dof / n; the gap then exceeds the null limit
    (``null_gap_limit``) with probability ``power`` when λ reaches the root of the
    noncentral F(dof, nu, λ) (chi² when nu is infinite) tail. inf when no error size
    gets there (a noise level measured with too few degrees of freedom).

    :param dof: the model's degrees of freedom, N - p.
    :param noise_dof: the noise level's degrees of freedom (inf when known).
    :param inv_var_sum: sum over windows of 1 / s_k², (m/s²)⁻².
    :param n: number of windows.
    """
    dof = max(int(dof), 1)
    x = null_gap_limit(dof, noise_dof, quantile) ** 2

    def detected(lam):
        if not np.isfinite(noise_dof):
            return float(stats.ncx2.sf(x * dof, dof, lam)) - power
        return float(stats.ncf.sf(x, dof, max(noise_dof, 1e-3), lam)) - power

    high = 1.0 + 10.0 * dof
    while detected(high) < 0:
        high *= 4.0
        if high > 1e9:
            return float('inf')
    lam = optimize.brentq(detected, 0.0, high, xtol=1e-6 * high)
    delta = np.sqrt(lam * n / (dof * inv_var_sum))
    return float(1000.0 * delta / G0)


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


SPECTRUM_BINS = 16
"""Most Hann-periodogram bins (from bin 2) pooled for the noise floor under a taper."""


HANN_BIN_CORRELATION = 0.44
"""Correlation of the powers of neighbouring Hann-periodogram bins ((2/3)²)."""


def _low_frequency_spectrum(x, bins=SPECTRUM_BINS):
    """
    Return the noise power near 0 Hz over the sample variance, per bin and axis.

    Hann-tapered periodogram of one window (mean removed), bins 2, 3, ... (bins 0 and 1
    hold what is left of the mean): 1 for white noise. The taper's side lobes fall fast,
    so vibration at tens of Hz does not leak into these bins as it does into block means.

    :returns: (bins, 3), NaN beyond the window's own bins.
    """
    n = len(x)
    taper = np.hanning(n)
    spectrum = np.abs(np.fft.rfft(x * taper[:, None], axis=0)) ** 2 / np.sum(taper ** 2)
    var = np.sum(x ** 2, axis=0) / max(n - 1, 1)
    out = np.full((bins, 3), np.nan)
    got = spectrum[2:2 + bins]
    with np.errstate(divide='ignore', invalid='ignore'):
        out[:len(got)] = np.where(var > 0, got / var, np.nan)
    return out


def _bin_mean_median(k):
    """Return the median of the mean of k neighbouring Hann bins over its expectation."""
    dof = 2.0 * k / (1.0 + 2.0 * HANN_BIN_CORRELATION * (k - 1) / k)
    return stats.chi2.median(dof) / dof


def _low_frequency_ratio(spectra, bins=2):
    """Return each window's mean of the first ``bins`` spectrum bins, median-corrected, (W, 3)."""
    return np.nanmean(spectra[:, :bins], axis=1) / _bin_mean_median(bins)


def hann_means(samples, windows):
    """
    Return Hann-weighted window means, (W, 3), and each one's white-noise variance factor.

    A tapered mean hardly sees vibration: its weights' spectrum falls like 1/f³ away
    from 0 Hz, where a plain mean's falls like 1/f, so vibration at tens of Hz leaks
    into a plain window mean but not into a tapered one. The price is a variance
    n sum w² / (sum w)² (1.5 for long windows) times a plain mean's for white noise.

    :returns: (means (W, 3), factor (W,)).
    """
    means = np.array(windows.mean, float, copy=True)
    factor = np.ones(len(windows))
    for w, (a, b) in enumerate(zip(windows.start, windows.stop)):
        if b - a < 3:
            continue
        taper = np.hanning(b - a + 2)[1:-1]
        means[w] = taper @ samples.accel[a:b] / taper.sum()
        factor[w] = (b - a) * np.sum(taper ** 2) / taper.sum() ** 2
    return means, factor


def _spectral_floor(spectra):
    """
    Return the pooled low-frequency noise floor of one axis, its standard error and bins.

    A tapered mean sees the spectrum within about 2 bins of 0 Hz; bin 2 is the nearest
    one that the window's own mean leaves intact. The next bins are pooled with it as
    long as each one's level (median over windows) agrees with the floor so far within
    twice their standard errors and a factor 1.5: a flat floor below a vibration band.
    A rising skirt of the vibration, or correlated noise rolling off, stops the pooling.
    Each window's mean over those bins is then pooled over windows.

    :param spectra: (W, bins) ratios of one axis (``_low_frequency_spectrum``).
    """
    count = np.sum(np.isfinite(spectra), axis=0)
    with np.errstate(invalid='ignore'):
        levels = np.nanmedian(spectra, axis=0) / np.log(2.0)     # exponential median
    se = 1.2533 * levels / np.sqrt(np.maximum(count, 1))
    k = 1
    while k < spectra.shape[1] and count[k] >= 3 and levels[k] > 0:
        floor = np.mean(levels[:k])
        floor_se = np.sqrt(np.sum(se[:k] ** 2)) / k
        if (abs(levels[k] - floor) > 2.0 * np.hypot(se[k], floor_se)
                or abs(np.log(levels[k] / floor)) > np.log(1.5)):
            break
        k += 1
    value, value_se = _pooled(np.nanmean(spectra[:, :k], axis=1) / _bin_mean_median(k))
    return value, value_se, k


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


AXES_AGREE_P = 0.01
"""The three axes share one R when their estimates agree at this level (chi², 2 dof)."""


def _common(inflation, rel):
    """
    Return the per-axis R, pooled into one value when the three axes agree.

    Estimates of R from a few blocks per window scatter a lot when the noise is correlated
    over a good part of a window; three estimates of one filter's R that differ only by
    that scatter would otherwise weigh windows by their direction (the wrong way on
    the underestimated axes). When the axes agree within their standard errors (chi² test
    at ``AXES_AGREE_P``), each gets the inverse-variance mean and its standard error
    (sqrt(3) times each axis's share, so that ``WindowNoise.dof`` counts it once).
    """
    se = rel * inflation
    if not np.all(np.isfinite(se)) or np.any(se <= 0):
        return inflation, rel
    weight = 1.0 / se ** 2
    mean = float(np.sum(weight * inflation) / np.sum(weight))
    chi2 = float(np.sum(weight * (inflation - mean) ** 2))
    if stats.chi2.sf(chi2, 2) < AXES_AGREE_P:
        return inflation, rel
    common_rel = np.sqrt(1.0 / np.sum(weight)) / mean
    return np.full(3, mean), np.full(3, np.sqrt(3.0) * common_rel)


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
      enough, equal to R(n/8)) on every axis: white at these scales, R(n/8) is used;
    - otherwise (on any axis: the noise's filter is shared) R approaches its limit like
      R_inf + C/m and is extrapolated to the whole window on every axis,
      R(n) = 1.875 R(n/8) - 0.875 R(n/16) (the more precise pair), or
      1.75 R(n/4) - 0.75 R(n/8) for short windows: larger for longer blocks is correlated
      noise; when R(n/4) leaves the line of the first pair (noise correlated over much of
      a window), a quadratic in 1/m through all three,
      R(n) = 2.1875 R(n/4) - 1.40625 R(n/8) + 0.21875 R(n/16).

    Vibration: when on some axis the Hann-tapered spectrum near 0 Hz is well below
    R(n/8) (half, and 3 standard errors), the sample scatter is power well above 0 Hz.
    Vibration leaks into a plain window mean through its side lobes, by an amount that
    depends on each window's length and phase, so the window means are then taken with a
    Hann taper instead (``hann_means``; ``WindowNoise.means``), whose side lobes fall
    fast, and their noise is the tapered spectrum's floor below the vibration band,
    pooled over windows and over as many bins as stay flat (``_spectral_floor``), times
    the taper's variance factor (about 1.5). Estimated outside the vibration band, the
    noise level keeps many degrees of freedom however strong the vibration.

    :param samples: Samples the windows were detected in.
    :param windows: StaticWindows (start, stop index the samples).
    :param blocks: blocks per window for the short batches (even, >= 8).
    :returns: WindowNoise ('assumed white', unit inflation, when no window is long enough).
    """
    half = blocks // 2
    short, long_, finest, spectra, tested, wanders = [], [], [], [], [], []
    for w, (a, b) in enumerate(zip(windows.start, windows.stop)):
        if (b - a) // blocks < 8:
            continue
        tested.append(w)
        x = samples.accel[a:b]
        x = x - x.mean(axis=0)
        ramp = np.linspace(-1.0, 1.0, len(x))[:, None]
        detrended = x - ramp * (ramp * x).sum(axis=0) / (ramp ** 2).sum()
        # Motion is judged without the window's linear ramp: a long rest under a drifting
        # bias is still a pose (and the best evidence on the drift), not a move.
        wanders.append(_batch_ratios(detrended, blocks, 2))
        removed = 1
        if samples.temp is not None and np.ptp(samples.temp[a:b]) > RAMP_TEMP_C:
            # The temperature moved inside the window: its ramp is the model's business.
            # (Removing a ramp also removes some slow noise, so only when needed.)
            x, removed = detrended, 2
        spectra.append(_low_frequency_spectrum(x))
        finest.append(_batch_ratios(x, 2 * blocks, removed) if (b - a) // (2 * blocks) >= 8
                      else np.full(3, np.nan))
        short.append(_batch_ratios(x, blocks, removed))
        long_.append(_batch_ratios(x, half, removed))
    inflation, rel, method = np.ones(3), np.zeros(3), ['white'] * 3
    moving = np.zeros(len(windows), bool)
    if len(short) < 3:
        return WindowNoise(inflation, rel, ['assumed white'] * 3, moving)
    short, long_, wanders = np.asarray(short), np.asarray(long_), np.asarray(wanders)
    level = np.nanmedian(wanders, axis=0)
    with np.errstate(invalid='ignore', divide='ignore'):
        wander = np.nanmax(wanders / np.where(level > 0, level, np.nan), axis=1)
    moving[np.asarray(tested)[wander > WANDER_FACTOR]] = True
    keep = ~(wander > WANDER_FACTOR)
    short, long_, spectra = short[keep], long_[keep], np.asarray(spectra)[keep]
    finest = np.asarray(finest)[keep]
    spectral = _low_frequency_ratio(spectra)
    vibrating = np.zeros(3, bool)
    pooled = [[_pooled(ratios[:, i]) for ratios in (finest, short, long_)] for i in range(3)]
    # Correlation is a property of the sensor's noise (its filter), not of one axis: when
    # any axis shows R changing with the block length, every axis is extrapolated, so
    # that a marginal test does not split alike axes into 'white' and 'correlated'.
    changing, bending = [], []
    for (r16, se16), (r8, se8), (r4, se4) in pooled:
        fine = np.isfinite(r16) and abs(r8 - r16) > 2.0 * np.hypot(se8, se16)
        changing.append(fine or (np.isfinite(r4) and abs(r4 - r8) > 2.0 * np.hypot(se4, se8)))
        # R(n/4) off the line of R(n/16) and R(n/8): noise correlated over a good part of
        # a window, where R still bends (on any axis, as above).
        bend = r4 - (1.5 * r8 - 0.5 * r16)
        bending.append(bool(np.isfinite(bend) and abs(bend) > 2.0 * np.sqrt(
            se4 ** 2 + (1.5 * se8) ** 2 + (0.5 * se16) ** 2)))
    for i, ((r16, se16), (r8, se8), (r4, se4)) in enumerate(pooled):
        if not (np.isfinite(r8) and np.isfinite(r4)) or r8 <= 0:
            continue
        if not any(changing):
            value, se = r8, se8
        elif np.isfinite(r16):
            # R(m) = R_inf + C/m: C < 0 for correlated noise (a DLPF, AR noise), C > 0 for
            # vibration without power at 0 Hz (its block means average down like 1/m).
            # Extrapolated from n/16 and n/8 to the whole window (the precise pair) ...
            value = max(1.875 * r8 - 0.875 * r16, 0.125 * r8)
            se = np.hypot(1.875 * se8, 0.875 * se16)
            # ... unless R still bends at n/4: a quadratic in 1/m through all three then.
            if any(bending):
                value = max(2.1875 * r4 - 1.40625 * r8 + 0.21875 * r16, 0.125 * r8)
                se = np.sqrt((2.1875 * se4) ** 2 + (1.40625 * se8) ** 2
                             + (0.21875 * se16) ** 2)
            method[i] = 'correlated' if value > r8 else 'averaging down'
        else:
            # The same from n/8 and n/4 (windows too short for 16 blocks).
            value = max(1.75 * r4 - 0.75 * r8, 0.25 * r4)
            se = np.hypot(1.75 * se4, 0.75 * se8)
            method[i] = 'correlated' if value > r8 else 'averaging down'
        rs, ses = _pooled(spectral[:, i])
        vibrating[i] = bool(np.isfinite(rs) and rs < 0.5 * r8
                            and rs < r8 - 3.0 * np.hypot(ses, se8))
        inflation[i] = max(value, 1e-3)
        rel[i] = se / inflation[i]
    measured = (np.array([r[1][0] for r in pooled]), np.array([r[1][1] for r in pooled]))
    if not vibrating.any():
        inflation, rel = _common(inflation, rel)
        return WindowNoise(inflation, rel, method, moving, measured=measured)
    # Vibration: tapered means, and their noise from the spectrum below the vibration.
    means, factor = hann_means(samples, windows)
    taper = float(np.median(factor[np.asarray(tested)[keep]]))
    bins = []
    for i in range(3):
        value, se, k = _spectral_floor(spectra[:, :, i])
        if not (np.isfinite(value) and value > 0):
            continue
        inflation[i] = value * taper
        rel[i] = se / value
        method[i] = 'vibration' if vibrating[i] else 'tapered spectrum'
        bins.append(k)
    inflation, rel = _common(inflation, rel)
    return WindowNoise(inflation, rel, method, moving, means=means, taper=taper,
                       spectrum_bins=bins, measured=measured)


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
