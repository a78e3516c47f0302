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

from .calibration import calibrate
from .effects import EFFECTS, G0
from .errors import CalibrationError
from .windows import detect_static_windows

P_SUPPORT = 1e-3
"""Largest F-test p-value for which an added effect counts as supported."""

AMBIGUOUS_RATIO = 0.8
"""Runner-up whose chi² reduction is at least this fraction of the winner's is a rival."""

RAMP_TEMP_C = 0.05
"""Temperature change inside a window above which its linear ramp is not counted as noise."""

MIN_VISIBILITY = 0.01
"""Effects that this session shows less than this (see ``visibility``) are not tested."""

COLLINEAR = 0.95
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


NULL_Z = 2.326
"""One-sided 99 % point of the normal: the null gap limit is mean + NULL_Z std."""

NULL_TOLERANCE = 0.05
"""Relative margin on the null gap limit for the uncertainty of the measured noise itself."""


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
    noise_std: np.ndarray = None     # (3,) pooled per-sample scatter, reading units
    rate_hz: float = None

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
        """
        Return the largest gap that noise explains for this session.

        The gaps of the fitted model re-simulated under the session's own conditions
        are close to normal; their mean + ``NULL_Z`` std (a 99 % point, steadier than an
        empirical percentile of 20 replicates) times 1 + ``NULL_TOLERANCE``. Without
        re-simulations the chi² approximation (mean 1, std sqrt(1 / (2 dof))) is used.
        """
        if len(self.null_gaps) < 5:
            mean, std = 1.0, np.sqrt(0.5 / max(self.fits[-1].dof, 1))
        else:
            mean, std = np.mean(self.null_gaps), np.std(self.null_gaps, ddof=1)
        return float((mean + NULL_Z * std) * (1.0 + NULL_TOLERANCE))

    @property
    def null_p(self):
        """Return the fraction of re-simulated gaps at least the measured one (None if none)."""
        if not self.null_gaps:
            return None
        above = np.sum(np.asarray(self.null_gaps) >= self.gap_after)
        return float((above + 1) / (len(self.null_gaps) + 1))

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
    def explained(self):
        """Tell whether the final gap lies within what noise alone produces."""
        return self.gap_after <= self.null_limit

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
        out = {'inflation': float(self.noise_inflation)}
        if self.noise_std is not None:
            out['sample_std'] = np.asarray(self.noise_std, float).tolist()
            if self.rate_hz:
                T = np.diag(Model(self.baseline, []).split(self.fits[0].x)[0])
                density = np.asarray(self.noise_std) / np.abs(T) / np.sqrt(self.rate_hz / 2.0)
                out['density_ug_per_sqrt_hz'] = (density / G0 * 1e6).tolist()
        return out

    def summary(self):
        """Return the JSON-ready machine summary of spec section 3 (plus extras)."""
        return {
            'baseline': self.baseline, 'missing_effects': self.missing_effects,
            'gap_before': self.gap_before, 'gap_after': self.gap_after,
            'steps': self.steps, 'ambiguities': self.ambiguities,
            'windows': self.windows, 'explained_by_noise': bool(self.explained),
            'null': {'replicates': len(self.null_gaps),
                     'mean': float(np.mean(self.null_gaps)) if self.null_gaps else None,
                     'p95': float(np.percentile(self.null_gaps, 95))
                     if self.null_gaps else None,
                     'limit': self.null_limit, 'p_value': self.null_p},
            'null_gap_limit': self.null_limit, 'null_gaps': len(self.null_gaps),
            'noise_inflation': self.noise_inflation, 'noise': self.noise(),
            'excess_scatter_m_s2': self.excess_scatter(),
            'parameters': self.parameters(),
            'not_testable': self.skipped,
        }

    def text(self):
        """Return the human summary."""
        lines = [f'baseline {self.baseline}: {self.windows} static windows, gap '
                 f'{self.gap_before:.2f} (1 = agrees with the noise)']
        for step in self.steps:
            where = step['where'][0] if step['where'] else None
            lines.append(f'+ {step["effect"]}: gap {step["gap_before"]:.2f} -> '
                         f'{step["gap_after"]:.2f}  ({step["evidence"]["magnitude"]}; '
                         f'F = {step["evidence"]["F"]:.1f}, p = {step["evidence"]["p"]:.1e})')
            if where:
                lines.append(f'    before it, residuals followed {where["variable"]} '
                             f'(r = {where["r"]:+.2f})')
        if not self.steps:
            lines.append('no missing effect is supported by this session')
        for note in self.ambiguities:
            lines.append('note: ' + note)
        for name, reason in self.skipped.items():
            lines.append(f'not testable here: {name} ({reason})')
        verdict = 'explained by noise' if self.explained else 'NOT explained by noise'
        if self.null_gaps:
            floor = 1.0 / (len(self.null_gaps) + 1)
            p = (f'p < {floor + 1e-9:.2f}' if self.null_p <= floor
                 else f'p = {self.null_p:.2f}')
            verdict += (f' (re-simulated gaps {np.mean(self.null_gaps):.2f}, 95th percentile '
                        f'{np.percentile(self.null_gaps, 95):.2f}, limit '
                        f'{self.null_limit:.2f}; {p})')
        lines.append(f'final gap {self.gap_after:.2f}: {verdict}')
        if not self.explained:
            lines.append(f'the rest is a scatter of {self.excess_scatter():.2g} m/s² per window '
                         'that no tested effect explains: e.g. bias instability, the mount '
                         'shifting between poses, or noise correlated beyond a window')
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


def _noise_inflation(samples, windows, blocks=8):
    """
    Return the variance of a window mean over its white-noise value (>= 1), by batch means.

    Each window (less a linear ramp if the temperature moved more than ``RAMP_TEMP_C``
    inside it: the ramp is the model's business, not noise) is cut into ``blocks``
    blocks of m samples: R(m) = m var(block means) / var(samples) is 1 for white noise
    and grows with the noise's correlation time. R(m) approaches its limit like
    R_inf - C / m, so blocks of m = n/8 understate the whole window's factor R(n) when
    the correlation time is not much shorter than a block (by 30 % for AR(1) noise with
    a 10-sample correlation time in 2.5 s windows). The factor is therefore measured
    with ``blocks`` and ``blocks / 2`` blocks and extrapolated: R_inf = 2 R(2m) - R(m),
    R(n) = R_inf - (R_inf - R(m)) / blocks (when R(m) < 1.2 the noise is next to white
    and R(m) is used as it is). Each R is the median over windows and axes of
    chi²-median-corrected ratios (see ``_batch_ratios``). On simulated AR(1) noise in
    260-sample windows this gives 1.0, 3.1, 20.6 and 55 for true 1.0, 3.0, 19.7 and 57
    (correlation 0, 0.5, 0.9, 0.97 per sample; true = variance of the window mean over
    the within-window scatter / n, which is itself slightly low for correlated noise).

    :param samples: Samples the windows were detected in.
    :param windows: StaticWindows (start, stop index the samples).
    :param blocks: blocks per window for the short batches (even, >= 8).
    """
    half = blocks // 2
    short, long_ = [], []
    for a, b in zip(windows.start, windows.stop):
        if (b - a) // blocks < 8:
            continue
        x = samples.accel[a:b]
        x = x - x.mean(axis=0)
        removed = 1
        if samples.temp is not None and np.ptp(samples.temp[a:b]) > RAMP_TEMP_C:
            # The temperature moved inside the window: its ramp is the model's business.
            # (Removing a ramp also removes some slow noise, so only when needed.)
            ramp = np.linspace(-1.0, 1.0, len(x))[:, None]
            x = x - ramp * (ramp * x).sum(axis=0) / (ramp ** 2).sum()
            removed = 2
        short.extend(_batch_ratios(x, blocks, removed))
        long_.extend(_batch_ratios(x, half, removed))
    short, long_ = np.asarray(short), np.asarray(long_)
    short, long_ = short[np.isfinite(short)], long_[np.isfinite(long_)]
    if not len(short) or not len(long_):
        return 1.0
    r_short, r_long = np.median(short), np.median(long_)
    if r_short < 1.2:
        # Next to white: the extrapolation would only add its own scatter.
        return float(max(1.0, r_short))
    r_inf = 2.0 * r_long - r_short
    r_window = r_inf - (r_inf - r_short) / blocks
    return float(max(1.0, r_short, r_window))


def conditions_from_windows(windows, gravity, inflation=1.0):
    """
    Build the fit's Conditions from StaticWindows.

    :param windows: StaticWindows.
    :param gravity: local gravity, m/s².
    :param inflation: variance factor of a window mean over white noise (>= 1).
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
                     replicates=20, inflation=1.0, max_steps=4):
    """
    Run the model-gap workflow on static windows (also used by the calibration node).

    :param windows: StaticWindows (needs mean, count, scatter, t_mid, temp).
    :param baseline: 'ml' or 'gn'.
    :param gravity: local gravity, m/s².
    :param rate_hz: sample rate, Hz; only for the noise density in the summary.
    :param rng: numpy Generator for the re-simulations (default seeded 0).
    :param replicates: re-simulations of the final model for its null gap distribution
        (0 for speed: the chi² approximation then gives the noise limit).
    :param inflation: variance factor of window means over white noise (>= 1).
    :param max_steps: most effects added.
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
    c = conditions_from_windows(windows, gravity, inflation)
    start_cal = calibrate(c.readings, gravity, baseline, windows.count.astype(float))
    model, fit = _fit_model(baseline, [], c, model_start(baseline, start_cal))
    context = {'temp_span': c.temp_span, 'time_span': c.time_span, 'windows': len(windows)}
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
                            noise_inflation=inflation, noise_std=windows.noise_std,
                            rate_hz=rate_hz)
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
            alike = column_correlation(model, fit, c, name, rival[1])
            if rival[0] >= AMBIGUOUS_RATIO * drop or alike > COLLINEAR:
                result.ambiguities.append(
                    f'{name} and {rival[1]} explain this session about equally well '
                    f'(chi² drops {drop:.1f} and {rival[0]:.1f}; their signatures correlate '
                    f'{alike:.2f}): ' + _separation_advice(name, rival[1], c))
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
    :param baseline: 'ml' or 'gn'.
    :param gravity: local gravity, m/s² (in reading units per m/s² of T for raw counts).
    :param min_duration_s: shortest static window, s.
    :param threshold_factor: stillness threshold over the noise floor.
    :param max_weight_s: unused for the gap (each window's own noise weighs it);
        accepted for symmetry with ``fit``.
    :param replicates: re-simulations for the null gap distribution.
    :param rng: numpy Generator (default seeded 0).
    :returns: DiagnoseResult.
    :raises CalibrationError: too few windows, or the baseline cannot be fitted.
    """
    windows = detect_static_windows(samples, min_duration_s=min_duration_s,
                                    threshold_factor=threshold_factor)
    rate = samples.rate_hz
    return diagnose_windows(windows, baseline, gravity, rate, rng, replicates,
                            _noise_inflation(samples, windows))


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
    :param inflation: noise inflation (default the result's).
    :returns: dict with 'baseline_rms' and 'with_effects_rms' (m/s²), 'effects',
        'fit_windows' and 'test_windows'.
    """
    inflation = result.noise_inflation if inflation is None else inflation
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
