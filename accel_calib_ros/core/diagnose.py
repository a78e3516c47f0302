"""
Model-gap workflow: where simulation and measurement disagree, and why.

1. Fit the baseline model (``ml``: upper-triangular T + bias; ``gn``: diagonal T +
   bias) to the session's static windows.
2. Compare the fitted model with the measurement under the session's own
   conditions: the gap is sqrt(chi²/dof) of the gravity-norm residuals, each
   divided by the noise of its window mean measured from the data itself
   (within-window scatter, inflated by batch means for correlated noise), so the
   gap is about 1 when they agree. The fitted model is re-simulated under the same
   poses, temperatures, times and window lengths to give the gap's own null
   distribution. Residuals are correlated with temperature, time and orientation
   (and their products) to say where they disagree.
3. Each effect of the library (``effects.EFFECTS``) that the session can show
   (``Effect.applicable``, enough degrees of freedom, ``visibility``) is added in
   turn and refitted; a nested-model F-test (robust to a mis-estimated noise level)
   and the BIC decide whether the data support it.
4. The best-supported effect is added and the loop repeats until nothing more is
   supported. When two candidates explain the data about equally well (their
   signatures nearly collinear in this session, e.g. temperature and time rising
   together), the result says so and what to record to tell them apart. What no
   effect explains is reported as a per-window excess scatter.

``diagnose(samples)`` runs it on a recording, ``diagnose_windows(windows)`` on static
windows (the calibration node), ``held_out_check`` cross-validates the finding.
"""

from dataclasses import dataclass, field

import numpy as np
from scipy import optimize, stats

from .accel.calibration import calibrate
from .effects import EFFECTS, G0
from .errors import CalibrationError
from .windows import detect_static_windows

P_SUPPORT = 1e-3
"""Largest F-test p-value for which an added effect counts as supported."""

RAMP_TEMP_C = 0.05
"""Temperature change inside a window above which its linear ramp is not counted as noise."""

MIN_VISIBILITY = 0.01
"""Effects that this session shows less than this (see ``visibility``) are not tested."""

COLLINEAR = 0.9
"""Supported runner-up whose signature correlates more than this with the winner's is a rival."""

WANDER_FACTOR = 20.0
"""A window whose block means wander this many times the pooled level holds motion."""
"""Supported runner-up whose signature correlates more than this with the winner's is a rival."""


@dataclass
class Conditions:
    """The session as the fit sees it: one row per static window."""

    readings: np.ndarray        # (N, 3) window means, m/s²
    sigma: np.ndarray           # (N, 3) noise of each window mean, m/s²
    temp: np.ndarray            # (N,) °C minus the session mean (zeros if unknown)
    time: np.ndarray            # (N,) s minus the session mean
    gravity: float
    temp_span: float
    time_span: float

    def subset(self, index):
        """Return the conditions of some windows (centring of temperature and time kept)."""
        return Conditions(self.readings[index], self.sigma[index], self.temp[index],
                          self.time[index], self.gravity, self.temp_span, self.time_span)


class Model:
    """Baseline calibration plus a list of effects, fitted by least squares."""

    def __init__(self, baseline, effects):
        self.baseline = baseline
        self.effects = list(effects)
        self.n_base = 9 if baseline == 'ml' else 6
        self.sizes = [len(EFFECTS[name].param_names) for name in self.effects]

    @property
    def n_params(self):
        return self.n_base + sum(self.sizes)

    def split(self, x):
        """Return (T, bias, {effect: params}) from the parameter vector."""
        T = np.zeros((3, 3))
        if self.baseline == 'ml':
            T[np.triu_indices(3)] = x[:6]
            bias = x[6:9]
        else:
            T[np.diag_indices(3)] = x[:3]
            bias = x[3:6]
        params, k = {}, self.n_base
        for name, size in zip(self.effects, self.sizes):
            params[name] = x[k:k + size]
            k += size
        return T, bias, params

    def pack_baseline(self, T, bias):
        head = T[np.triu_indices(3)] if self.baseline == 'ml' else np.diag(T)
        return np.concatenate([head, bias])

    def true_accel(self, x, c):
        """Invert the model for each window: return the true specific force (N, 3), m/s²."""
        T, bias, params = self.split(x)
        a = np.linalg.solve(T, (c.readings - bias).T).T
        for _ in range(2):          # the effects are small: two fixed-point passes
            extra = sum((EFFECTS[n].apply(p, a, c.temp, c.time, c.gravity)
                         for n, p in params.items()), np.zeros_like(a))
            a = np.linalg.solve(T, (c.readings - bias - extra).T).T
        return a

    def residual_parts(self, x, c):
        """
        Return the gravity-norm residuals and their noise, both (N,) m/s².

        The noise is the window mean's reading noise mapped to the true frame and taken
        along the normal a/|a|: sqrt(sum_i ((T^-T n)_i sigma_i)²).
        """
        a = self.true_accel(x, c)
        norm = np.linalg.norm(a, axis=1)
        along = np.linalg.solve(self.split(x)[0].T, (a / norm[:, None]).T).T
        s = np.sqrt(np.sum((along * c.sigma) ** 2, axis=1))
        return norm - c.gravity, s

    def residuals(self, x, c):
        """Return (|a| - g) / noise along a for each window, shape (N,)."""
        rho, s = self.residual_parts(x, c)
        return rho / s

    def predict(self, x, directions, c):
        """Return noise-free readings (N, 3) for unit directions under conditions ``c``."""
        T, bias, params = self.split(x)
        a = c.gravity * directions
        raw = a @ T.T + bias
        for name, p in params.items():
            raw = raw + EFFECTS[name].apply(p, a, c.temp, c.time, c.gravity)
        return raw

    def fit(self, c, start):
        """
        Fit the model to conditions ``c`` by least squares from ``start``.

        :returns: (parameters, chi², Jacobian of the normalised residuals (N, p)).
        """
        sol = optimize.least_squares(self.residuals, start, args=(c,), x_scale='jac',
                                     method='lm' if len(c.readings) > len(start) else 'trf')
        chi2 = float(np.sum(sol.fun ** 2))
        return sol.x, chi2, sol.jac

    def effect_jacobian(self, x, c, name):
        """
        Return d(normalised residual)/d(params of effect ``name``) at ``x``, shape (N, k).

        Evaluated whether or not the effect is in the model (zero parameters if not):
        the change of |a| per unit parameter is -n^T T^-1 columns, n = a/|a|.
        """
        T = self.split(x)[0]
        a = self.true_accel(x, c)
        norm = np.linalg.norm(a, axis=1)
        along = np.linalg.solve(T.T, (a / norm[:, None]).T).T
        s = np.sqrt(np.sum((along * c.sigma) ** 2, axis=1))
        cols = EFFECTS[name].columns(a, c.temp, c.time, c.gravity)
        return -np.einsum('ni,nik->nk', along, cols) / s[:, None]


@dataclass
class Fit:
    """One fitted model and its agreement with the measurement."""

    effects: list
    x: np.ndarray
    chi2: float
    dof: int
    residuals: np.ndarray
    jac: np.ndarray = None

    @property
    def gap(self):
        return float(np.sqrt(self.chi2 / max(self.dof, 1)))


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

MIN_EFFECT_MG = 1.0
"""Smallest practical threshold, mg: an effect smaller than this is never named."""

NEGLIGIBLE_FACTOR = 3.0
"""The rest is negligible when this many times its per-window scatter is below the threshold."""


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


@dataclass
class DiagnoseResult:
    """Outcome of the model-gap workflow (see :meth:`summary` for the JSON)."""

    baseline: str
    windows: int
    conditions: Conditions
    fits: list                       # Fit per step, baseline first
    steps: list = field(default_factory=list)
    ambiguities: list = field(default_factory=list)
    skipped: dict = field(default_factory=dict)
    null_gaps: list = field(default_factory=list)
    window_noise: WindowNoise = None
    noise_std: np.ndarray = None     # (3,) pooled per-sample scatter, reading units
    rate_hz: float = None
    threshold_mg: float = MIN_EFFECT_MG
    predicted_accuracy_mg: float = None
    candidates: list = field(default_factory=list)   # the last round's candidates
    below_threshold: list = field(default_factory=list)
    probes: dict = field(default_factory=dict)
    dropped_windows: int = 0
    partial: list = field(default_factory=list)

    @property
    def missing_effects(self):
        return [step['effect'] for step in self.steps]

    @property
    def gap_before(self):
        return self.fits[0].gap

    @property
    def gap_after(self):
        return self.fits[-1].gap

    @property
    def noise_inflation(self):
        """Return the mean over axes of the window-mean variance factor (1 = white)."""
        return float(np.mean(self.window_noise.inflation)) if self.window_noise else 1.0

    @property
    def noise_dof(self):
        return self.window_noise.dof if self.window_noise else float('inf')

    @property
    def null_limit(self):
        """Return the largest gap that noise explains for this session (``null_gap_limit``)."""
        return null_gap_limit(self.fits[-1].dof, self.noise_dof)

    @property
    def null_p(self):
        """Return P(a gap at least the measured one | noise alone)."""
        return null_gap_p(self.gap_after, self.fits[-1].dof, self.noise_dof)

    def excess_scatter(self):
        """
        Return the per-window error, m/s², that the final gap asks for beyond the noise.

        The sigma_x with sum rho_k² / (s_k² + sigma_x²) = dof: a scatter from window to
        window not tied to any modelled variable (bias instability, a mount that shifts
        between poses). 0 when the gap is at most 1.
        """
        fit = self.fits[-1]
        if fit.gap <= 1.0 or fit.dof < 1:
            return 0.0
        model = Model(self.baseline, fit.effects)
        rho, s = model.residual_parts(fit.x, self.conditions)

        def excess(sx):
            return np.sum(rho ** 2 / (s ** 2 + sx ** 2)) - fit.dof

        high = float(np.sqrt(np.mean(rho ** 2))) * 2.0 + 1e-12
        return float(optimize.brentq(excess, 0.0, high))

    @property
    def statistically_explained(self):
        """Tell whether the final gap lies within what noise alone produces."""
        return self.gap_after <= self.null_limit

    @property
    def negligible(self):
        """Tell whether what is left beyond the noise is too small to matter (see threshold)."""
        return NEGLIGIBLE_FACTOR * 1000.0 * self.excess_scatter() / G0 < self.threshold_mg

    @property
    def explained(self):
        """
        Tell whether nothing is left to find.

        True when the final gap is within the noise, or when ``NEGLIGIBLE_FACTOR`` times
        the scatter left beyond the noise is below the practical threshold (detectable,
        irrelevant).
        """
        return self.statistically_explained or self.negligible

    @property
    def outside_library(self):
        """Tell whether a disagreement that matters is left that no library effect explains."""
        return not self.explained

    def parameters(self):
        """
        Return the final model's parameters, JSON-ready.

        ``T`` (3x3, reading units per m/s²) and ``bias`` (3, reading units) of the
        baseline, and per added effect its values, names, unit and datasheet-style size.
        """
        model = Model(self.baseline, self.fits[-1].effects)
        T, bias, params = model.split(self.fits[-1].x)
        out = {'T': T.tolist(), 'bias': bias.tolist(), 'effects': {}}
        for name, values in params.items():
            effect = EFFECTS[name]
            out['effects'][name] = {
                'values': values.tolist(), 'names': list(effect.param_names),
                'unit': effect.unit,
                'magnitude': effect.magnitude(values, self.conditions.gravity, np.diag(T))}
        return out

    def noise(self):
        """Return the measured noise, JSON-ready (per-sample std, inflation, density)."""
        dof = self.noise_dof
        out = {'inflation': self.noise_inflation, 'dof': dof if np.isfinite(dof) else None}
        if self.window_noise is not None:
            out['inflation_per_axis'] = self.window_noise.inflation.tolist()
            out['relative_se'] = self.window_noise.relative_se.tolist()
            out['model'] = list(self.window_noise.method)
        if self.noise_std is not None:
            out['sample_std'] = np.asarray(self.noise_std, float).tolist()
            if self.rate_hz:
                T = np.diag(Model(self.baseline, []).split(self.fits[0].x)[0])
                inflation = (self.window_noise.inflation if self.window_noise is not None
                             else np.ones(3))
                density = (np.asarray(self.noise_std) * np.sqrt(inflation) / np.abs(T)
                           / np.sqrt(self.rate_hz / 2.0))
                out['density_ug_per_sqrt_hz'] = (density / G0 * 1e6).tolist()
        return out

    def verdict(self):
        """Return the one-line verdict on what is left after the named effects."""
        if self.statistically_explained:
            return 'explained by noise'
        if self.negligible:
            return (f'beyond the noise, but the rest ({1000 * self.excess_scatter() / G0:.2g} '
                    f'mg per window) is below the practical threshold '
                    f'({self.threshold_mg:.2g} mg)')
        return ('NOT explained by noise: no effect in the library brings the gap into the '
                'noise band; the cause may lie outside the effect library')

    def summary(self):
        """Return the JSON-ready machine summary of spec section 3 (plus extras)."""
        null = {'method': 'analytic F(dof, noise dof)', 'quantile': NULL_QUANTILE,
                'dof': self.fits[-1].dof,
                'noise_dof': self.noise_dof if np.isfinite(self.noise_dof) else None,
                'limit': self.null_limit, 'p_value': self.null_p,
                'replicates': len(self.null_gaps),
                'mean': float(np.mean(self.null_gaps)) if self.null_gaps else None,
                'p95': float(np.percentile(self.null_gaps, 95)) if self.null_gaps else None}
        return {
            'baseline': self.baseline, 'missing_effects': self.missing_effects,
            'gap_before': self.gap_before, 'gap_after': self.gap_after,
            'steps': self.steps, 'ambiguities': self.ambiguities,
            'windows': self.windows, 'dropped_windows': self.dropped_windows,
            'explained_by_noise': bool(self.explained),
            'statistically_explained': bool(self.statistically_explained),
            'outside_library': bool(self.outside_library), 'verdict': self.verdict(),
            'threshold_mg': self.threshold_mg,
            'predicted_accuracy_mg': self.predicted_accuracy_mg,
            'candidates': self.candidates, 'below_threshold': self.below_threshold,
            'partial': self.partial,
            'probes': {k: {kk: vv for kk, vv in v.items() if not kk.startswith('_')}
                       for k, v in self.probes.items()},
            'null': null, 'null_gap_limit': self.null_limit,
            'noise_inflation': self.noise_inflation, 'noise': self.noise(),
            'excess_scatter_m_s2': self.excess_scatter(),
            'parameters': self.parameters(),
            'not_testable': self.skipped,
        }

    def text(self):
        """Return the human summary."""
        lines = [f'baseline {self.baseline}: {self.windows} static windows, gap '
                 f'{self.gap_before:.2f} (1 = agrees with the noise); practical threshold '
                 f'{self.threshold_mg:.2g} mg']
        for step in self.steps:
            where = step['where'][0] if step['where'] else None
            lines.append(f'+ {step["effect"]}: gap {step["gap_before"]:.2f} -> '
                         f'{step["gap_after"]:.2f}  ({step["evidence"]["magnitude"]}; '
                         f'up to {step["evidence"]["worst_case_mg"]:.2g} mg; '
                         f'F = {step["evidence"]["F"]:.1f}, p = {step["evidence"]["p"]:.1e})')
            if where:
                lines.append(f'    before it, residuals followed {where["variable"]} '
                             f'(r = {where["r"]:+.2f})')
        if not self.steps:
            lines.append('no missing effect is supported by this session')
        for cand in self.below_threshold:
            lines.append(f'detectable but below the practical threshold: {cand["effect"]} '
                         f'(up to {cand["worst_case_mg"]:.2g} mg, p = {cand["p"]:.1e})')
        for item in self.partial:
            lines.append(f'not named: {item["effect"]} (up to {item["worst_case_mg"]:.2g} mg) '
                         f'explains only part of a dependence on {item["variable"]} of another '
                         f'shape ({item["left_rms_mg"]:.2g} mg RMS left, p = '
                         f'{item["left_p"]:.1e})')
        for note in self.ambiguities:
            lines.append('note: ' + note)
        for name, reason in self.skipped.items():
            lines.append(f'not testable here: {name} ({reason})')
        lines.append(f'final gap {self.gap_after:.2f} (noise limit {self.null_limit:.2f}, '
                     f'p = {self.null_p:.2g}): {self.verdict()}')
        if not self.statistically_explained:
            lines.append(f'the rest is a scatter of {self.excess_scatter():.2g} m/s² per window')
            found = [(name, p) for name, p in self.probes.items() if p['significant']]
            if found:
                lines.append('where the residual lives: ' + '; '.join(
                    f'{name} ({p["rms_mg"]:.2g} mg RMS, p = {p["p"]:.1e})'
                    for name, p in found))
            else:
                lines.append('no smooth trend in time, temperature, direction or magnitude: '
                             'a scatter from pose to pose (e.g. bias instability, the mount '
                             'shifting between poses, or noise correlated beyond a window)')
        return '\n'.join(lines)


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


def conditions_from_windows(windows, gravity, inflation=1.0):
    """
    Build the fit's Conditions from StaticWindows.

    :param windows: StaticWindows.
    :param gravity: local gravity, m/s².
    :param inflation: variance factor of a window mean over white noise, scalar or (3,).
    """
    noise = windows.noise_std
    noise = np.where(noise > 0, noise, np.max(noise) if np.max(noise) > 0 else 1e-3)
    sigma = noise[None, :] * np.sqrt(inflation / windows.count[:, None])
    temp = np.asarray(windows.temp, float)
    has_temp = np.all(np.isfinite(temp))
    temp = temp - temp.mean() if has_temp else np.zeros(len(temp))
    time = windows.t_mid - windows.t_mid.mean()
    return Conditions(windows.mean, sigma, temp, time, gravity,
                      float(np.ptp(temp)) if has_temp else 0.0, float(np.ptp(time)))


def where_variables(c, directions):
    """
    Return the session variables the residuals are compared with, by name.

    Temperature, time, each signed and absolute component n_i of the gravity direction,
    products of two components (a cross-axis term T_ij changes |a| by about
    g n_i n_j T_ij), and temperature and time times each component (an offset that
    moves with temperature changes |a| by n . c (θ - θ̄): it shows against
    temperature × x component, hardly against temperature alone).

    :param c: Conditions.
    :param directions: (N, 3) unit gravity directions of the windows.
    :returns: dict name -> (N,) values.
    """
    out = {'temperature': c.temp, 'time': c.time}
    for i, axis in enumerate('xyz'):
        out[f'{axis} component of gravity'] = directions[:, i]
        out[f'|{axis}| component of gravity'] = np.abs(directions[:, i])
    for i, j in ((0, 1), (0, 2), (1, 2)):
        out[f'{"xyz"[i]} × {"xyz"[j]} component'] = directions[:, i] * directions[:, j]
    for i, axis in enumerate('xyz'):
        out[f'temperature × {axis} component'] = c.temp * directions[:, i]
        out[f'time × {axis} component'] = c.time * directions[:, i]
    return out


def _where(residuals, c, directions, top=3):
    """Return the strongest correlations of the residuals, [{'variable', 'r'}], strongest first."""
    out = []
    for name, values in where_variables(c, directions).items():
        if np.ptp(values) > 0 and np.ptp(residuals) > 0:
            r = float(np.corrcoef(residuals, values)[0, 1])
            out.append({'variable': name, 'r': r})
    out.sort(key=lambda d: -round(abs(d['r']), 6))     # ties: the order of the variables
    return out[:top]


def _fit_model(baseline, effects, c, start):
    model = Model(baseline, effects)
    x, chi2, jac = model.fit(c, start)
    dof = len(c.readings) - model.n_params
    return model, Fit(list(effects), x, chi2, dof, model.residuals(x, c), jac)


def _null_gaps(model, fit, c, rng, replicates):
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


def column_correlation(model, fit, c, first, second):
    """
    Return how alike two candidate effects look in this session (0 to 1).

    The largest canonical correlation between the two effects' Jacobian columns after
    removing what the current model already absorbs: 1 when some combination of one
    is indistinguishable from the other (temperature and time rising together).
    """
    base = fit.jac if fit.jac is not None else np.zeros((len(c.readings), 0))
    q_base = np.linalg.qr(base)[0] if base.shape[1] else base

    def basis(name):
        j = model.effect_jacobian(fit.x, c, name)
        if q_base.shape[1]:
            j = j - q_base @ (q_base.T @ j)
        u, s, _ = np.linalg.svd(j, full_matrices=False)
        return u[:, s > 1e-9 * max(s.max(), 1e-300)]

    q1, q2 = basis(first), basis(second)
    if not q1.shape[1] or not q2.shape[1]:
        return 0.0
    return float(min(np.linalg.svd(q1.T @ q2, compute_uv=False).max(), 1.0))


def visibility(model, fit, c, name):
    """
    Return how well this session's poses and conditions can show effect ``name`` (0 to 1).

    For each parameter, the change of the normalised residuals per unit parameter, after
    removing what the current model absorbs, over the change of the raw reading itself
    (the residual only sees a change along gravity). The smallest singular value of
    those scaled columns: 0 when some combination of the effect's parameters is
    invisible, e.g. cross-axis terms with only the six faces, or a quadratic scale
    term that is indistinguishable from the linear one when each axis only sees ±g.
    """
    j = model.effect_jacobian(fit.x, c, name)
    a = model.true_accel(fit.x, c)
    T = model.split(fit.x)[0]
    # The change of the reading per unit parameter in the true frame (T^-1 columns),
    # in units of each window's noise.
    cols = np.einsum('ij,njk->nik', np.linalg.inv(T),
                     EFFECTS[name].columns(a, c.temp, c.time, c.gravity))
    _, s = model.residual_parts(fit.x, c)
    raw = np.linalg.norm(np.linalg.norm(cols, axis=1) / s[:, None], axis=0)
    if fit.jac is not None and fit.jac.shape[1]:
        q = np.linalg.qr(fit.jac)[0]
        j = j - q @ (q.T @ j)
    raw = np.where(raw > 0, raw, np.inf)
    return float(np.linalg.svd(j / raw, compute_uv=False).min())


def fibonacci_directions(n=200):
    """Return ``n`` unit vectors spread evenly over the sphere, shape (n, 3)."""
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    phi = np.pi * (1.0 + 5 ** 0.5) * k
    r = np.sqrt(1.0 - z ** 2)
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])


def effect_worst_case_mg(model, x, c, name, params):
    """
    Return the largest error, mg, effect ``name`` with ``params`` makes in corrected acceleration.

    The error T^-1 columns(a, θ, t) p of the corrected specific force, over every
    direction of gravity (200 spread over the sphere plus the session's own) and every
    temperature and time of the session (centred as in the fit, so what the baseline
    absorbs at the session mean is not counted).
    """
    T = model.split(x)[0]
    a_session = model.true_accel(x, c)
    dirs = np.vstack([fibonacci_directions(),
                      a_session / np.linalg.norm(a_session, axis=1, keepdims=True)])
    conds = np.unique(np.column_stack([c.temp, c.time]), axis=0)
    if len(conds) > 60:
        conds = conds[np.linspace(0, len(conds) - 1, 60).round().astype(int)]
    T_inv = np.linalg.inv(T)
    worst = 0.0
    for temp, time in conds:
        n = len(dirs)
        cols = EFFECTS[name].columns(c.gravity * dirs, np.full(n, temp), np.full(n, time),
                                     c.gravity)
        err = (cols @ np.asarray(params, float)) @ T_inv.T
        worst = max(worst, float(np.max(np.linalg.norm(err, axis=1))))
    return 1000.0 * worst / G0


def predicted_accuracy_mg(model, fit):
    """
    Return the baseline fit's predicted accuracy, mg (``core.accuracy``, spec section 5).

    The covariance (J^T J)^-1 of the baseline parameters (J: Jacobian of the
    noise-normalised residuals) in the (T upper row-major, bias) order; a ``gn``
    baseline's diagonal T takes the diagonal places (the rest fixed at zero).
    """
    from .accuracy import predicted_accuracy
    jac = fit.jac[:, :model.n_base]
    cov = np.linalg.pinv(jac.T @ jac)
    full = np.zeros((9, 9))
    index = np.arange(9) if model.baseline == 'ml' else np.array([0, 3, 5, 6, 7, 8])
    full[np.ix_(index, index)] = cov
    T = model.split(fit.x)[0]
    value = predicted_accuracy(T, full, G0)
    return 1000.0 * value / G0 if np.isfinite(value) else float('nan')


PROBE_P = 1e-3
"""A nonparametric probe is significant below this F-test p-value."""


def _cosine_basis(values, degree):
    """
    Return a smooth basis of ``values`` scaled to u in [0, 1].

    cos(k pi u), k = 1..degree (trends, steps, curves), and sin(2 pi k u),
    k = 1..(degree + 1) // 2 (cycles), shape (N, degree + (degree + 1) // 2).
    """
    span = np.ptp(values)
    if span <= 0 or degree < 1:
        return np.zeros((len(values), 0))
    u = (values - values.min()) / span
    cols = [np.cos(np.pi * k * u) for k in range(1, degree + 1)]
    cols += [np.sin(2 * np.pi * k * u) for k in range(1, (degree + 1) // 2 + 1)]
    return np.column_stack(cols)


def _sphere_basis(directions, degree):
    """Return the monomials x^a y^b z^c, 1 <= a+b+c <= degree (spherical harmonics span)."""
    cols = []
    for total in range(1, degree + 1):
        for i in range(total + 1):
            for j in range(total + 1 - i):
                k = total - i - j
                cols.append(directions[:, 0] ** i * directions[:, 1] ** j
                            * directions[:, 2] ** k)
    return np.column_stack(cols)


def residual_probes(model, fit, c):
    """
    Show where the final residual lives, without assuming a physical effect.

    Four smooth, nonparametric bases are fitted to the noise-normalised residuals, each
    after removing what the fitted model can already absorb (its Jacobian): a cosine and
    sine series in time and in temperature (alone and times each gravity-direction component,
    since an offset o(t) moves |a| by n . o(t)), low-degree spherical harmonics over the
    gravity direction, and a cosine series in the magnitude of the raw reading |y|. A nested
    F-test gives each its significance. A probe that is significant while no library
    effect is says which variable the missing cause follows.

    :returns: dict probe -> {'p', 'F', 'terms', 'rms_mg', 'max_mg', 'significant',
        '_x' (per-window variable), '_smooth' (per-window fitted values, m/s²)}.
    """
    n = len(c.readings)
    rho, s = model.residual_parts(fit.x, c)
    r = rho / s
    a = model.true_accel(fit.x, c)
    directions = a / np.linalg.norm(a, axis=1, keepdims=True)
    q = np.linalg.qr(fit.jac)[0] if fit.jac is not None and fit.jac.shape[1] else \
        np.zeros((n, 0))
    room = max(fit.dof - 3, 0)
    smooth_degree = int(min(6, room // 12))
    sphere_degree = 4 if room >= 40 else 3 if room >= 25 else 2 if room >= 12 else 0

    def offset_and_scale(values):
        # An offset o(v) changes |a| by n . o(v); a scale change by |a| s(v): the smooth
        # times each direction component, and alone.
        basis = _cosine_basis(values, smooth_degree)
        return np.hstack([basis] + [basis * directions[:, [i]] for i in range(3)])

    bases = {
        'time': (c.time, offset_and_scale(c.time)),
        'temperature': (c.temp, offset_and_scale(c.temp)),
        'direction': (directions, _sphere_basis(directions, sphere_degree)
                      if sphere_degree else np.zeros((n, 0))),
        'magnitude': (np.linalg.norm(c.readings, axis=1),
                      _cosine_basis(np.linalg.norm(c.readings, axis=1), 3)),
    }
    out = {}
    for name, (values, basis) in bases.items():
        if not basis.shape[1]:
            continue
        basis = basis / s[:, None]          # a smooth in m/s², seen in normalised units
        if q.shape[1]:
            basis = basis - q @ (q.T @ basis)
        u, sv, _ = np.linalg.svd(basis, full_matrices=False)
        u = u[:, sv > 1e-8 * max(sv.max(), 1e-300)]
        k = u.shape[1]
        if not k or fit.dof - k < 2:
            continue
        proj = u @ (u.T @ r)
        drop = float(proj @ proj)
        rest = max(fit.chi2 - drop, 1e-300)
        F = (drop / k) / (rest / (fit.dof - k))
        p = float(stats.f.sf(F, k, fit.dof - k))
        smooth = proj * s
        out[name] = {'p': p, 'F': float(F), 'terms': int(k), 'delta_chi2': drop,
                     'rms_mg': float(1000.0 * np.sqrt(np.mean(smooth ** 2)) / G0),
                     'max_mg': float(1000.0 * np.max(np.abs(smooth)) / G0),
                     'significant': bool(p < PROBE_P), '_x': values, '_smooth': smooth}
    return out


def _separation_advice(a, b, c):
    pair = {a, b}
    if 'bias_drift' in pair and pair & {'temperature_bias', 'temperature_scale'}:
        r = float(np.corrcoef(c.temp, c.time)[0, 1]) if c.temp_span > 0 else 0.0
        return (f'temperature and time move together in this session (r = {r:.2f}); hold '
                'the temperature steady for a while, or let it fall, so the two separate')
    if pair == {'temperature_bias', 'temperature_scale'}:
        return ('record poses with each axis both up and down at every temperature, so an '
                'offset and a scale change look different')
    return 'record more poses spread over the sphere (each axis up, down and sideways)'


def min_windows(baseline):
    """Return the fewest static windows the check needs for ``baseline`` (dof >= 3)."""
    return Model(baseline, []).n_base + 3


def diagnose_windows(windows, baseline='ml', gravity=9.80665, rate_hz=None, rng=None,
                     replicates=0, inflation=1.0, max_steps=4, noise=None, min_effect_mg=None):
    """
    Run the model-gap workflow on static windows (also used by the calibration node).

    :param windows: StaticWindows (needs mean, count, scatter, t_mid, temp).
    :param baseline: 'ml' or 'gn'.
    :param gravity: local gravity, m/s².
    :param rate_hz: sample rate, Hz; only for the noise density in the summary.
    :param rng: numpy Generator for the re-simulations (default seeded 0).
    :param replicates: re-simulations of the final model, reported next to the analytic
        null (the verdict uses the analytic F law, which has no simulation noise).
    :param inflation: variance factor of window means over white noise (scalar or (3,)),
        used when ``noise`` is not given; the noise level then counts as known.
    :param max_steps: most effects added.
    :param noise: WindowNoise measured in the samples (``window_noise``), or None.
    :param min_effect_mg: practical threshold, mg: an effect is named only when its
        worst-case error in corrected acceleration exceeds it (default: the baseline
        fit's predicted accuracy, at least ``MIN_EFFECT_MG``).
    :returns: DiagnoseResult.
    :raises CalibrationError: too few windows, or the baseline cannot be fitted.
    """
    if baseline not in ('ml', 'gn'):
        raise ValueError(f'baseline must be ml or gn, not {baseline!r}')
    if len(windows) < min_windows(baseline):
        raise CalibrationError(
            f'{len(windows)} static windows; the model-gap check with baseline {baseline} '
            f'needs at least {min_windows(baseline)} poses (more when effects are to be '
            'told apart)')
    rng = np.random.default_rng(0) if rng is None else rng
    if noise is None:
        noise = WindowNoise(np.broadcast_to(np.asarray(inflation, float), (3,)).copy(),
                            np.zeros(3), ['given'] * 3)
    c = conditions_from_windows(windows, gravity, noise.inflation)
    start_cal = calibrate(c.readings, gravity, baseline, windows.count.astype(float))
    model, fit = _fit_model(baseline, [], c, model_start(baseline, start_cal))
    accuracy = predicted_accuracy_mg(model, fit)
    threshold = (float(min_effect_mg) if min_effect_mg is not None
                 else max(MIN_EFFECT_MG, accuracy if np.isfinite(accuracy) else 0.0))
    has_temp = bool(np.all(np.isfinite(np.asarray(windows.temp, float))))
    context = {'temp_span': c.temp_span, 'time_span': c.time_span, 'windows': len(windows),
               'has_temp': has_temp}
    skipped = {}
    candidates = []
    for name, effect in EFFECTS.items():
        reason = effect.applicable(context, baseline)
        if not reason and fit.dof - len(effect.param_names) < 2:
            reason = f'{len(windows)} windows leave too few degrees of freedom'
        if not reason and visibility(model, fit, c, name) < MIN_VISIBILITY:
            reason = ('these poses cannot show it; turn each axis up, down and sideways, '
                      'not only the six faces')
        if reason:
            skipped[name] = reason
        else:
            candidates.append(name)
    result = DiagnoseResult(baseline, len(windows), c, [fit], skipped=skipped,
                            window_noise=noise, noise_std=windows.noise_std,
                            rate_hz=rate_hz, threshold_mg=threshold,
                            predicted_accuracy_mg=accuracy)
    n = len(c.readings)
    while candidates and len(result.steps) < max_steps:
        tried = []
        for name in candidates:
            k = len(EFFECTS[name].param_names)
            if fit.dof - k < 2:
                continue
            start = np.concatenate([fit.x, np.zeros(k)])
            try:
                new_model, new_fit = _fit_model(baseline, fit.effects + [name], c, start)
            except (ValueError, np.linalg.LinAlgError):
                continue
            drop = fit.chi2 - new_fit.chi2
            F = (drop / k) / max(new_fit.chi2 / new_fit.dof, 1e-300)
            p = float(stats.f.sf(F, k, new_fit.dof))
            bic = drop - k * np.log(n)
            params = new_model.split(new_fit.x)[2][name]
            worst = effect_worst_case_mg(new_model, new_fit.x, c, name, params)
            tried.append({'effect': name, 'drop': drop, 'model': new_model, 'fit': new_fit,
                          'F': float(F), 'p': p, 'bic': float(bic), 'worst_case_mg': worst,
                          'significant': bool(p < P_SUPPORT and bic > 0),
                          'large_enough': bool(worst > threshold)})
        result.candidates = [{key: t[key] for key in ('effect', 'F', 'p', 'worst_case_mg',
                                                      'significant', 'large_enough')}
                             | {'delta_chi2': float(t['drop']), 'delta_bic': t['bic']}
                             for t in tried]
        result.below_threshold = [cand for cand in result.candidates
                                  if cand['significant'] and not cand['large_enough']]
        supported = sorted((t for t in tried if t['significant'] and t['large_enough']),
                           key=lambda t: -t['drop'])
        if not supported:
            break
        # A tie (the columns are collinear in this session) goes to the effect with a
        # measured cause: temperature is recorded, a drift with time is the catch-all.
        tied = [t for t in supported if t['drop'] >= (1 - 1e-3) * supported[0]['drop']]
        tied.sort(key=lambda t: t['effect'] == 'bias_drift')
        supported.remove(tied[0])
        supported.insert(0, tied[0])
        best = supported[0]
        name, new_model, new_fit, drop = best['effect'], best['model'], best['fit'], best['drop']
        a = model.true_accel(fit.x, c)
        directions = a / np.linalg.norm(a, axis=1, keepdims=True)
        T_new, _, all_params = new_model.split(new_fit.x)
        params = all_params[name]
        result.steps.append({
            'effect': name, 'gap_before': fit.gap, 'gap_after': new_fit.gap,
            'evidence': {'F': best['F'], 'p': best['p'], 'delta_chi2': float(drop),
                         'delta_bic': best['bic'], 'params': params.tolist(),
                         'param_names': list(EFFECTS[name].param_names),
                         'unit': EFFECTS[name].unit,
                         'magnitude': EFFECTS[name].magnitude(params, gravity,
                                                              np.diag(T_new)),
                         'worst_case_mg': best['worst_case_mg'],
                         'description': EFFECTS[name].description},
            'where': _where(fit.residuals, c, directions)})
        for rival in supported[1:]:
            # A rival only when the two are confounded in this session's design: their
            # signatures (Jacobian columns) correlate.
            alike = column_correlation(model, fit, c, name, rival['effect'])
            if alike > COLLINEAR:
                result.ambiguities.append(
                    f'{name} and {rival["effect"]} are confounded in this session (their '
                    f'signatures correlate {alike:.2f}; chi² drops {drop:.1f} and '
                    f'{rival["drop"]:.1f}): '
                    + _separation_advice(name, rival['effect'], c))
        model, fit = new_model, new_fit
        result.fits.append(fit)
        candidates.remove(name)
    if fit.jac is not None:
        result.probes = residual_probes(model, fit, c)
        _demote_partial(result, c)
    model = Model(baseline, result.fits[-1].effects)
    fit = result.fits[-1]
    result.null_gaps = _null_gaps(model, fit, c, rng, replicates) if replicates else []
    return result


PARTIAL_SHARE = 0.05
"""A named effect is withdrawn when its variable's probe still finds this share of its Δχ²."""


def _demote_partial(result, c):
    """
    Withdraw named effects that only explain part of a dependence of another shape.

    When what is left is not explained (``DiagnoseResult.explained``) and the
    nonparametric probe in a time or temperature effect's own variable
    (``Effect.variable``: time for ``bias_drift``, temperature for the
    temperature effects) is still significant and still explains at least
    ``PARTIAL_SHARE`` of the chi² the effect removed, the effect is a projection of
    something the library lacks (a step, a curve, a cycle), not the cause: it is moved
    to ``result.partial`` and the model is refitted without it.
    """
    if result.explained:
        return
    partial = []
    for step in result.steps:
        if EFFECTS[step['effect']].variable not in ('time', 'temperature'):
            continue        # the direction probe also holds what the poses cannot tell apart
        probe = result.probes.get(EFFECTS[step['effect']].variable)
        worst = step['evidence']['worst_case_mg']
        share = PARTIAL_SHARE * step['evidence']['delta_chi2']
        if probe and probe['significant'] and probe['delta_chi2'] >= share:
            partial.append({'effect': step['effect'], 'worst_case_mg': worst,
                            'variable': EFFECTS[step['effect']].variable,
                            'left_rms_mg': probe['rms_mg'], 'left_p': probe['p']})
    if not partial:
        return
    gone = {p['effect'] for p in partial}
    kept = [step for step in result.steps if step['effect'] not in gone]
    fits = [result.fits[0]]
    for step in kept:
        effects = fits[-1].effects + [step['effect']]
        start = np.concatenate([fits[-1].x, np.zeros(len(EFFECTS[step['effect']].param_names))])
        _, new_fit = _fit_model(result.baseline, effects, c, start)
        step['gap_before'], step['gap_after'] = fits[-1].gap, new_fit.gap
        fits.append(new_fit)
    result.steps, result.fits, result.partial = kept, fits, partial
    model = Model(result.baseline, fits[-1].effects)
    result.probes = residual_probes(model, fits[-1], c)


def model_start(baseline, cal):
    """Return the parameter vector of the baseline model from a Calibration."""
    return Model(baseline, []).pack_baseline(cal.T, cal.bias)


VIBRATION_CUTOFF_HZ = 5.0
"""Low-pass corner used to find the poses under vibration (the statistics use raw samples)."""


def _detect_windows(samples, min_duration_s, threshold_factor):
    """
    Find the static windows, also under vibration.

    Strong vibration lifts the moving standard deviation so that the moves between poses
    no longer stand out and poses merge. The detection therefore also runs on a
    zero-phase low-passed copy (``VIBRATION_CUTOFF_HZ``, well below vibration, well
    above a pose change); the one with more windows is kept. The window means and
    scatters always come from the raw samples.
    """
    from scipy import signal
    from .samples import Samples
    from .windows import DEFAULTS, still_mask, still_runs, windows_from_ranges
    windows = detect_static_windows(samples, min_duration_s=min_duration_s,
                                    threshold_factor=threshold_factor)
    rate = samples.rate_hz
    if not np.isfinite(rate) or rate < 8 * VIBRATION_CUTOFF_HZ or len(samples) < 1000:
        return windows
    # Block means of k samples (about 100 Hz) first: cheap on 10⁷ rows, and a low-pass.
    k = max(int(rate // 100.0), 1)
    n = len(samples) // k
    coarse = samples.accel[:n * k].reshape(n, k, 3).mean(axis=1)
    b, a = signal.butter(2, VIBRATION_CUTOFF_HZ / (rate / k / 2))
    smooth = Samples(samples.t[:n * k:k], signal.filtfilt(b, a, coarse, axis=0))
    mask, floor = still_mask(smooth, threshold_factor=threshold_factor)
    trim = int(round(DEFAULTS['trim_s'] * rate))
    starts, stops = still_runs(mask)
    starts, stops = starts * k + trim, np.minimum(stops * k, len(samples)) - trim
    keep = stops - starts >= max(int(round(min_duration_s * rate)), 2)
    if keep.sum() <= len(windows):
        return windows
    return windows_from_ranges(samples, starts[keep], stops[keep], floor)


def diagnose(samples, baseline='ml', gravity=9.80665, min_duration_s=0.5,
             threshold_factor=3.0, max_weight_s=None, replicates=0, rng=None,
             min_effect_mg=None):
    """
    Run the model-gap workflow on a recording.

    :param samples: Samples (validated).
    :param baseline: 'ml' or 'gn'.
    :param gravity: local gravity, m/s² (in reading units per m/s² of T for raw counts).
    :param min_duration_s: shortest static window, s.
    :param threshold_factor: stillness threshold over the noise floor.
    :param max_weight_s: unused for the gap (each window's own noise weighs it);
        accepted for symmetry with ``fit``.
    :param replicates: re-simulations reported next to the analytic null.
    :param rng: numpy Generator (default seeded 0).
    :param min_effect_mg: practical threshold, mg (see ``diagnose_windows``).
    :returns: DiagnoseResult.
    :raises CalibrationError: too few windows, or the baseline cannot be fitted.
    """
    windows = _detect_windows(samples, min_duration_s, threshold_factor)
    rate = samples.rate_hz
    noise = window_noise(samples, windows)
    if noise.moving.any() and (~noise.moving).sum() >= min_windows(baseline):
        windows = windows.select(~noise.moving)
    else:
        noise.moving[:] = False
    result = diagnose_windows(windows, baseline, gravity, rate, rng, replicates,
                              noise=noise, min_effect_mg=min_effect_mg)
    result.dropped_windows = int(noise.moving.sum())
    return result


def held_out_check(windows, result, inflation=None):
    """
    Fit on alternate windows and test on the others (does the found model predict better).

    The baseline alone and the baseline plus ``result.missing_effects`` are fitted to
    the even-numbered windows; the gravity-norm residual |a| - g of the odd-numbered
    windows is evaluated with each (temperature and time centred as in the whole
    session). An effect that is real lowers the held-out residual; one that only
    fits noise does not.

    :param windows: StaticWindows the result came from.
    :param result: DiagnoseResult.
    :param inflation: noise inflation, scalar or (3,) (default the result's).
    :returns: dict with 'baseline_rms' and 'with_effects_rms' (m/s²), 'effects',
        'fit_windows' and 'test_windows'.
    """
    if inflation is None:
        inflation = (result.window_noise.inflation if result.window_noise is not None
                     else 1.0)
    c = conditions_from_windows(windows, result.conditions.gravity, inflation)
    even = np.arange(len(windows)) % 2 == 0
    train, test = c.subset(even), c.subset(~even)
    out = {'effects': list(result.missing_effects), 'fit_windows': int(even.sum()),
           'test_windows': int((~even).sum())}
    cal = calibrate(train.readings, train.gravity, result.baseline,
                    windows.count[even].astype(float))
    start = model_start(result.baseline, cal)
    for key, effects in (('baseline_rms', []), ('with_effects_rms', out['effects'])):
        model = Model(result.baseline, effects)
        x0 = np.concatenate([start, np.zeros(model.n_params - len(start))])
        x, _, _ = model.fit(train, x0)
        a = model.true_accel(x, test)
        rho = np.linalg.norm(a, axis=1) - test.gravity
        out[key] = float(np.sqrt(np.mean(rho ** 2)))
    return out
