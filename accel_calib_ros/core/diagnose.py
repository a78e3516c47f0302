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
   to say where they disagree.
3. Each applicable effect of the library (``effects.EFFECTS``) is added in turn and
   refitted; a nested-model F-test (robust to a mis-estimated noise level) and the
   BIC decide whether the data support it.
4. The best-supported effect is added and the loop repeats until nothing more is
   supported. When two candidates explain the data about equally well (their
   columns nearly collinear in this session, e.g. temperature and time rising
   together), the result says so and what to record to tell them apart.
"""

from dataclasses import dataclass, field

import numpy as np
from scipy import optimize, stats

from .calibration import calibrate
from .effects import EFFECTS
from .errors import CalibrationError
from .windows import detect_static_windows

P_SUPPORT = 1e-3
"""Largest F-test p-value for which an added effect counts as supported."""

AMBIGUOUS_RATIO = 0.8
"""Runner-up whose chi² reduction is at least this fraction of the winner's is a rival."""


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

    def residuals(self, x, c):
        """Return (|a| - g) / noise along a for each window, shape (N,)."""
        a = self.true_accel(x, c)
        norm = np.linalg.norm(a, axis=1)
        # Reading noise mapped to the true frame, then taken along the normal a/|a|.
        along = np.linalg.solve(self.split(x)[0].T, (a / norm[:, None]).T).T
        s = np.sqrt(np.sum((along * c.sigma) ** 2, axis=1))
        return (norm - c.gravity) / s

    def predict(self, x, directions, c):
        """Return noise-free readings (N, 3) for unit directions under conditions ``c``."""
        T, bias, params = self.split(x)
        a = c.gravity * directions
        raw = a @ T.T + bias
        for name, p in params.items():
            raw = raw + EFFECTS[name].apply(p, a, c.temp, c.time, c.gravity)
        return raw

    def fit(self, c, start):
        sol = optimize.least_squares(self.residuals, start, args=(c,), x_scale='jac',
                                     method='lm' if len(c.readings) > len(start) else 'trf')
        chi2 = float(np.sum(sol.fun ** 2))
        return sol.x, chi2


@dataclass
class Fit:
    """One fitted model and its agreement with the measurement."""

    effects: list
    x: np.ndarray
    chi2: float
    dof: int
    residuals: np.ndarray

    @property
    def gap(self):
        return float(np.sqrt(self.chi2 / max(self.dof, 1)))


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
    noise_inflation: float = 1.0

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
    def null_limit(self):
        """Largest gap noise explains: mean + 3 std of the re-simulated gaps."""
        if len(self.null_gaps) < 3:
            dof = max(self.fits[-1].dof, 1)
            return float(1.0 + 3.0 * np.sqrt(0.5 / dof))       # chi² approximation
        return float(np.mean(self.null_gaps) + 3.0 * np.std(self.null_gaps, ddof=1))

    @property
    def explained(self):
        """Tell whether the final gap lies within what noise alone produces."""
        return self.gap_after <= self.null_limit

    def summary(self):
        """Return the JSON-ready machine summary of spec section 3."""
        return {
            'baseline': self.baseline, 'missing_effects': self.missing_effects,
            'gap_before': self.gap_before, 'gap_after': self.gap_after,
            'steps': self.steps, 'ambiguities': self.ambiguities,
            'windows': self.windows, 'explained_by_noise': bool(self.explained),
            'null_gap_limit': self.null_limit, 'null_gaps': len(self.null_gaps),
            'noise_inflation': self.noise_inflation,
            'not_testable': self.skipped,
        }

    def text(self):
        """Return the human summary."""
        lines = [f'baseline {self.baseline}: {self.windows} static windows, gap '
                 f'{self.gap_before:.2f} (1 = agrees with the noise)']
        for step in self.steps:
            lines.append(f'+ {step["effect"]}: gap {step["gap_before"]:.2f} -> '
                         f'{step["gap_after"]:.2f}  ({step["evidence"]["magnitude"]}; '
                         f'F = {step["evidence"]["F"]:.1f}, p = {step["evidence"]["p"]:.1e})')
        if not self.steps:
            lines.append('no missing effect is supported by this session')
        for note in self.ambiguities:
            lines.append('note: ' + note)
        for name, reason in self.skipped.items():
            lines.append(f'not testable here: {name} ({reason})')
        verdict = 'explained by noise' if self.explained else 'NOT explained by noise'
        lines.append(f'final gap {self.gap_after:.2f}: {verdict}')
        return '\n'.join(lines)


def _noise_inflation(samples, windows, blocks=8):
    """Return the variance of a window mean over its white-noise value (>= 1), by batch means."""
    ratios = []
    for a, b in zip(windows.start, windows.stop):
        n = (b - a) // blocks
        if n < 8:
            continue
        x = samples.accel[a:a + n * blocks]
        # A slow ramp inside a window (temperature) is the model's business, not noise.
        ramp = np.linspace(-1.0, 1.0, len(x))[:, None]
        x = x - ramp * (ramp * (x - x.mean(axis=0))).sum(axis=0) / (ramp ** 2).sum()
        x = x.reshape(blocks, n, 3)
        var_sample = x.reshape(-1, 3).var(axis=0, ddof=1)
        var_block = x.mean(axis=1).var(axis=0, ddof=1) * n
        ok = var_sample > 0
        ratios.extend(var_block[ok] / var_sample[ok])
    return float(max(1.0, np.median(ratios))) if ratios else 1.0


def conditions_from_windows(windows, gravity, inflation=1.0):
    """Build the fit's Conditions from StaticWindows."""
    noise = windows.noise_std
    noise = np.where(noise > 0, noise, np.max(noise) if np.max(noise) > 0 else 1e-3)
    sigma = noise[None, :] * np.sqrt(inflation / windows.count[:, None])
    temp = np.asarray(windows.temp, float)
    has_temp = np.all(np.isfinite(temp))
    temp = temp - temp.mean() if has_temp else np.zeros(len(temp))
    time = windows.t_mid - windows.t_mid.mean()
    return Conditions(windows.mean, sigma, temp, time, gravity,
                      float(np.ptp(temp)) if has_temp else 0.0, float(np.ptp(time)))


def _where(residuals, c, directions):
    """Return the strongest correlations of the residuals with the session's variables."""
    candidates = {'temperature': c.temp, 'time': c.time}
    for i, axis in enumerate('xyz'):
        candidates[f'{axis} component of gravity'] = directions[:, i]
        candidates[f'|{axis}| component of gravity'] = np.abs(directions[:, i])
    out = []
    for name, values in candidates.items():
        if np.ptp(values) > 0:
            r = float(np.corrcoef(residuals, values)[0, 1])
            out.append({'variable': name, 'r': r})
    out.sort(key=lambda d: -abs(d['r']))
    return out[:3]


def _fit_model(baseline, effects, c, start):
    model = Model(baseline, effects)
    x, chi2 = model.fit(c, start)
    dof = len(c.readings) - model.n_params
    return model, Fit(list(effects), x, chi2, dof, model.residuals(x, c))


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
            _, chi2 = model.fit(sim, fit.x)
        except (ValueError, np.linalg.LinAlgError):
            continue
        gaps.append(float(np.sqrt(chi2 / max(fit.dof, 1))))
    return gaps


def _separation_advice(a, b, c):
    pair = {a, b}
    if 'bias_drift' in pair and pair & {'temperature_bias', 'temperature_scale'}:
        r = float(np.corrcoef(c.temp, c.time)[0, 1]) if c.temp_span > 0 else 0.0
        return (f'temperature and time rise together in this session (r = {r:.2f}); hold '
                'the temperature steady for a while, or let it fall, so the two separate')
    if pair == {'temperature_bias', 'temperature_scale'}:
        return ('record poses with each axis both up and down at every temperature, so an '
                'offset and a scale change look different')
    return 'record more poses spread over the sphere (each axis up, down and sideways)'


def diagnose_windows(windows, baseline='ml', gravity=9.80665, rng=None, replicates=20,
                     inflation=1.0, max_steps=4):
    """
    Run the model-gap workflow on static windows.

    :param windows: StaticWindows (needs mean, count, noise_std, t_mid, temp).
    :param baseline: 'ml' or 'gn'.
    :param gravity: local gravity, m/s².
    :param rng: numpy Generator for the re-simulations (default seeded 0).
    :param replicates: re-simulations of the final model for its null gap distribution.
    :param inflation: variance factor of window means over white noise (>= 1).
    :returns: DiagnoseResult.
    :raises CalibrationError: the baseline cannot be fitted.
    """
    if baseline not in ('ml', 'gn'):
        raise ValueError(f'baseline must be ml or gn, not {baseline!r}')
    rng = np.random.default_rng(0) if rng is None else rng
    c = conditions_from_windows(windows, gravity, inflation)
    start_cal = calibrate(c.readings, gravity, baseline, windows.count.astype(float))
    model, fit = _fit_model(baseline, [], c, model_start(baseline, start_cal))
    context = {'temp_span': c.temp_span, 'time_span': c.time_span}
    skipped = {}
    candidates = []
    for name, effect in EFFECTS.items():
        reason = effect.applicable(context, baseline)
        if reason:
            skipped[name] = reason
        else:
            candidates.append(name)
    result = DiagnoseResult(baseline, len(windows), c, [fit], skipped=skipped,
                            noise_inflation=inflation)
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
            tried.append((drop, name, new_model, new_fit, F, p, bic))
        supported = sorted((t for t in tried if t[5] < P_SUPPORT and t[6] > 0),
                           key=lambda t: -t[0])
        if not supported:
            break
        # A tie (the columns are collinear in this session) goes to the effect with a
        # measured cause: temperature is recorded, a drift with time is the catch-all.
        tied = [t for t in supported if t[0] >= (1 - 1e-3) * supported[0][0]]
        tied.sort(key=lambda t: t[1] == 'bias_drift')
        supported.remove(tied[0])
        supported.insert(0, tied[0])
        drop, name, new_model, new_fit, F, p, bic = supported[0]
        a = model.true_accel(fit.x, c)
        directions = a / np.linalg.norm(a, axis=1, keepdims=True)
        T_new, _, all_params = new_model.split(new_fit.x)
        params = all_params[name]
        result.steps.append({
            'effect': name, 'gap_before': fit.gap, 'gap_after': new_fit.gap,
            'evidence': {'F': float(F), 'p': p, 'delta_chi2': float(drop),
                         'delta_bic': float(bic), 'params': params.tolist(),
                         'param_names': list(EFFECTS[name].param_names),
                         'unit': EFFECTS[name].unit,
                         'magnitude': EFFECTS[name].magnitude(params, gravity,
                                                              np.diag(T_new)),
                         'description': EFFECTS[name].description},
            'where': _where(fit.residuals, c, directions)})
        for rival in supported[1:]:
            if rival[0] >= AMBIGUOUS_RATIO * drop:
                result.ambiguities.append(
                    f'{name} and {rival[1]} explain this session about equally well '
                    f'(chi² drops {drop:.1f} and {rival[0]:.1f}): '
                    + _separation_advice(name, rival[1], c))
        model, fit = new_model, new_fit
        result.fits.append(fit)
        candidates.remove(name)
    result.null_gaps = _null_gaps(model, fit, c, rng, replicates) if replicates else []
    return result


def model_start(baseline, cal):
    """Return the parameter vector of the baseline model from a Calibration."""
    return Model(baseline, []).pack_baseline(cal.T, cal.bias)


def diagnose(samples, baseline='ml', gravity=9.80665, min_duration_s=0.5,
             threshold_factor=3.0, max_weight_s=None, replicates=20, rng=None):
    """
    Run the model-gap workflow on a recording.

    :param samples: Samples (validated).
    :param max_weight_s: unused for the gap (each window's own noise weighs it);
        accepted for symmetry with ``fit``.
    :returns: DiagnoseResult.
    """
    windows = detect_static_windows(samples, min_duration_s=min_duration_s,
                                    threshold_factor=threshold_factor)
    if len(windows) < 12:
        raise CalibrationError(
            f'{len(windows)} static windows; the model-gap check needs at least 12 poses '
            '(more when effects are to be told apart)')
    result = diagnose_windows(windows, baseline, gravity, rng, replicates,
                              _noise_inflation(samples, windows))
    return result
