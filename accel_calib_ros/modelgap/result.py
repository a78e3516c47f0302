"""The outcome of the model-gap workflow: the steps, the verdict, the JSON and the words."""

from dataclasses import dataclass, field

import numpy as np
from scipy import optimize, stats

from .effects import G0
from .model import Conditions, Model
from .noise import (detection_probability, min_detectable_mg, null_gap_limit, null_gap_p,
                    NULL_QUANTILE, POWER, WindowNoise)
from ..core.allan import NOISE_DENSITY_CONVENTION

MIN_EFFECT_MG = 1.0
"""Smallest practical threshold, mg: an effect smaller than this is never named."""


WALK_TOLERANCE = 2.0
"""The rest is a named random walk's roughness when its scatter is within this factor of it."""


CANNOT_TELL_POWER = 0.5
"""Below this probability of detecting an error of the practical threshold: cannot tell."""


NEGLIGIBLE_FACTOR = 3.0
"""The rest is negligible when this many times its per-window scatter is below the threshold."""


def _dof_text(dof):
    return 'known' if dof is None else f'{dof:.3g} degrees of freedom'


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
    vetoed: list = field(default_factory=list)       # supported, but against the evidence
    unconfirmed: list = field(default_factory=list)  # gn effects the ml baseline does not find
    ml_check: dict = None                            # gn: what the ml baseline search found
    still: dict = None                               # the drift the still windows show
    _power_memo: dict = field(default_factory=dict, repr=False)

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
    def smooth_trend(self):
        """Tell whether a probe finds a smooth trend in the final residual."""
        return any(p['significant'] for p in self.probes.values())

    @property
    def slow_noise(self):
        """
        Tell whether the window means scatter as noise slower than a window would.

        The gap is beyond the within-window noise, no probe finds a smooth trend in time,
        temperature, direction or magnitude, and the noise inside the windows is itself
        correlated (``WindowNoise.coloured``): the scatter of the window means is noise
        at the scale of a window (flicker, AR noise, bias instability), which the
        within-window spectrum cannot reach. The null and the power then use the scatter
        between windows.
        """
        return bool(not self.statistically_explained and self.window_noise is not None
                    and self.window_noise.coloured and not self.smooth_trend)

    def walk_roughness(self):
        """
        Return the scatter per window, m/s², that a named random walk leaves, 0 without one.

        ``bias_random_walk`` follows the offset with a few cosine terms; a random walk
        of K per √s has cosine coefficients of variance 2 K² T / (k pi)² over a session
        of T seconds, so the terms beyond the d fitted leave a wander of variance about
        K² T / (pi² d) per axis that varies from window to window. K is estimated from the
        fitted coefficients; the scatter is taken along gravity, averaged over windows.
        """
        fit = self.fits[-1]
        model = Model(self.baseline, fit.effects)
        walk = model.objects.get('bias_random_walk')
        if walk is None:
            return 0.0
        T, _, params = model.split(fit.x)
        d = walk.degree
        coef = params['bias_random_walk'].reshape(3, d) / np.abs(np.diag(T))[:, None]
        k = np.arange(1, d + 1)
        k2 = np.mean(coef ** 2 * (k * np.pi) ** 2 / (2.0 * walk.span), axis=1)
        rough = k2 * walk.span / (np.pi ** 2 * d)                  # variance per axis
        a = model.true_accel(fit.x, self.conditions)
        n = a / np.linalg.norm(a, axis=1, keepdims=True)
        return float(np.sqrt(np.mean(n ** 2 @ rough)))

    @property
    def walk_explains_rest(self):
        """Tell whether what is left is the roughness of a named random walk (no smooth trend)."""
        rough = self.walk_roughness()
        return bool(rough > 0 and not self.smooth_trend
                    and self.excess_scatter() <= WALK_TOLERANCE * rough)

    @property
    def scatter_below_noise(self):
        """Tell whether the windows scatter significantly less than the noise level says."""
        fit = self.fits[-1]
        if fit.dof < 1:
            return False
        x = self.gap_after ** 2
        nu = self.noise_dof
        p = (stats.chi2.cdf(x * fit.dof, fit.dof) if not np.isfinite(nu)
             else stats.f.cdf(x, fit.dof, max(nu, 1e-3)))
        return bool(p < 1e-3)

    @property
    def noise_source(self):
        """
        Return which scatter the null and the power use: 'within windows' or 'between windows'.

        Between windows (the final model's own residual scatter, with its dof) when the
        window means scatter as slow noise (``slow_noise``) or significantly less than
        the within-window noise says (a vibration skirt in the lowest bins): what the
        window means show is then the better measure.
        """
        return ('between windows' if self.slow_noise or self.scatter_below_noise
                else 'within windows')

    def power(self):
        """
        Return the test's power, JSON-ready: the smallest error it could have detected.

        ``min_detectable_mg``: the smallest systematic error per window, mg, that makes
        the gap exceed its null limit with probability ``probability`` (see
        ``noise.min_detectable_mg``), with the noise level from ``noise_source``
        (within windows: its measured degrees of freedom; between windows: the model's
        dof); ``min_detectable_mg_known_noise``: the same with the level known exactly,
        so the difference is what the noise level's own uncertainty costs. None when no
        error size would be detected. ``at_threshold``: the probability of detecting an
        error of the practical threshold's size.
        """
        fit = self.fits[-1]
        key = (id(fit), self.gap_after, self.noise_dof, self.noise_source)
        if key not in self._power_memo:
            model = Model(self.baseline, fit.effects)
            _, s = model.residual_parts(fit.x, self.conditions)
            between = self.noise_source == 'between windows'
            scale = self.gap_after ** 2 if between else 1.0
            nu = float(fit.dof) if between else self.noise_dof
            inv = float(np.sum(1.0 / (s ** 2 * scale)))
            n = len(s)
            mde = min_detectable_mg(fit.dof, nu, inv, n)
            known = min_detectable_mg(fit.dof, float('inf'), inv, n)
            at_threshold = detection_probability(self.threshold_mg, fit.dof, nu, inv, n)
            self._power_memo.clear()
            self._power_memo[key] = {
                'min_detectable_mg': mde if np.isfinite(mde) else None,
                'min_detectable_mg_known_noise': known if np.isfinite(known) else None,
                'probability': POWER, 'quantile': NULL_QUANTILE,
                'at_threshold': at_threshold,
                'noise_source': self.noise_source,
                'noise_dof': nu if np.isfinite(nu) else None}
        return dict(self._power_memo[key])

    @property
    def cannot_tell(self):
        """
        Tell whether the test accepts the gap without the power to see a practical error.

        The gap is within its null limit (or what is left is slow noise), but an error of
        the practical threshold's size would be missed more often than seen (detection
        probability below ``CANNOT_TELL_POWER``, see ``power``): "explained by noise" would
        be vacuous (a noise level measured with a few degrees of freedom accepts any gap;
        slow noise of a few mg hides an error of a few mg).
        """
        if not (self.statistically_explained or self.slow_noise):
            return False
        return self.power()['at_threshold'] < CANNOT_TELL_POWER

    @property
    def outcome(self):
        """
        Return the kind of verdict.

        'explained', 'cannot tell' (no power, see ``cannot_tell``), 'negligible',
        'walk' (the rest is a named random walk's roughness), 'slow noise' or
        'not explained'.
        """
        if self.statistically_explained:
            return 'cannot tell' if self.cannot_tell else 'explained'
        if self.negligible:
            return 'negligible'
        if self.walk_explains_rest:
            return 'walk'
        if self.slow_noise:
            return 'cannot tell' if self.cannot_tell else 'slow noise'
        return 'not explained'

    @property
    def explained(self):
        """
        Tell whether nothing is left to find.

        True when the final gap is within the noise (and the test had the power to see a
        practical error), when ``NEGLIGIBLE_FACTOR`` times the scatter left beyond the
        noise is below the practical threshold (detectable, irrelevant), or when what is
        left is an unstructured scatter of noise slower than a window (``slow_noise``).
        """
        return self.outcome in ('explained', 'negligible', 'slow noise', 'walk')

    @property
    def outside_library(self):
        """Tell whether a disagreement that matters is left that no library effect explains."""
        return self.outcome == 'not explained'

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
            effect = model.objects[name]
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
                # The package's one convention (core.allan): the white-noise density N
                # with Allan deviation N/sqrt(tau), so white samples have std N sqrt(rate)
                # (what allan reads at the shortest cluster times); at the windows' time
                # scale the window means see N sqrt(inflation). In true units, µg/√Hz.
                T = np.diag(Model(self.baseline, []).split(self.fits[0].x)[0])
                inflation = (self.window_noise.inflation / self.window_noise.taper
                             if self.window_noise is not None else np.ones(3))
                white = np.asarray(self.noise_std) / np.abs(T) / np.sqrt(self.rate_hz)
                out['noise_density_ug_rthz'] = (white / G0 * 1e6).tolist()
                out['window_noise_density_ug_rthz'] = (white * np.sqrt(inflation)
                                                       / G0 * 1e6).tolist()
                out['noise_density_convention'] = NOISE_DENSITY_CONVENTION
        return out

    def verdict(self):
        """Return the one-line verdict on what is left after the named effects."""
        kind = self.outcome
        if kind == 'explained':
            return 'explained by noise'
        if kind == 'cannot tell':
            power = self.power()
            mde, known = power['min_detectable_mg'], power['min_detectable_mg_known_noise']
            size = 'no error' if mde is None else f'an error of {mde:.2g} mg per window'
            cause = ('noise too uncertain' if known is not None and known <= self.threshold_mg
                     else 'noise too large')
            return (f'cannot tell: {cause} (noise level from {power["noise_source"]}, '
                    f'{_dof_text(power["noise_dof"])}); an error of the practical threshold '
                    f'({self.threshold_mg:.2g} mg) would be detected with only '
                    f'{100 * power["at_threshold"]:.0f} % probability, and {size} with '
                    f'{100 * power["probability"]:.0f} %')
        if kind == 'negligible':
            return (f'beyond the noise, but the rest ({1000 * self.excess_scatter() / G0:.2g} '
                    f'mg per window) is below the practical threshold '
                    f'({self.threshold_mg:.2g} mg)')
        if kind == 'walk':
            return (f'explained by noise and the random walk: the rest '
                    f'({1000 * self.excess_scatter() / G0:.2g} mg per window) is what the '
                    f'walk wanders between its smooth terms (about '
                    f'{1000 * self.walk_roughness() / G0:.2g} mg), with no smooth trend left')
        if kind == 'slow noise':
            return (f'explained by noise slower than a window: the window means scatter '
                    f'{self.gap_after:.2g} times the noise inside them, with no smooth trend '
                    'in time, temperature, direction or magnitude, and that noise is '
                    'correlated (flicker, bias instability)')
        return ('NOT explained by noise: no effect in the library brings the gap into the '
                'noise band; the cause may lie outside the effect library')

    def still_drift(self):
        """Return the drift the still windows show, JSON-ready (mg/min per axis), or None."""
        if not self.still:
            return None
        per_min = 60000.0 / G0
        T = np.abs(np.diag(Model(self.baseline, []).split(self.fits[0].x)[0]))
        return {'mg_per_min': (per_min * np.asarray(self.still['slope']) / T).tolist(),
                'se_mg_per_min': (per_min * np.asarray(self.still['se']) / T).tolist(),
                'seconds': self.still['seconds'], 'longest_s': self.still['longest_s']}

    def summary(self):
        """Return the JSON-ready machine summary of interface.md §3 (plus extras)."""
        null = {'method': 'analytic F(dof, noise dof)', 'quantile': NULL_QUANTILE,
                'dof': self.fits[-1].dof, 'noise_source': self.noise_source,
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
            'partial': self.partial, 'vetoed': self.vetoed, 'unconfirmed': self.unconfirmed,
            'ml_check': self.ml_check, 'still_drift': self.still_drift(),
            'probes': {k: {kk: vv for kk, vv in v.items() if not kk.startswith('_')}
                       for k, v in self.probes.items()},
            'null': null, 'null_gap_limit': self.null_limit, 'power': self.power(),
            'cannot_tell': bool(self.outcome == 'cannot tell'),
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
            if step.get('confirmed'):
                lines.append(f'    with the ml baseline: {step["confirmed"]}')
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
        for item in self.vetoed:
            lines.append(f'not named: {item["effect"]} (up to {item["worst_case_mg"]:.2g} mg): '
                         f'{item["reason"]}')
        for item in self.unconfirmed:
            lines.append(f'not named with baseline {self.baseline}: {item["effect"]} '
                         f'({item["reason"]})')
        if self.ml_check and not self.ml_check.get('checked'):
            lines.append(f'not checked with the ml baseline: {self.ml_check["reason"]}')
        for note in self.ambiguities:
            lines.append('note: ' + note)
        for name, reason in self.skipped.items():
            lines.append(f'not testable here: {name} ({reason})')
        lines.append(f'final gap {self.gap_after:.2f} (noise limit {self.null_limit:.2f}, '
                     f'p = {self.null_p:.2g}): {self.verdict()}')
        power = self.power()
        if power['min_detectable_mg'] is not None:
            lines.append(f'power: a systematic error of {power["min_detectable_mg"]:.2g} mg per '
                         f'window would be detected with {100 * power["probability"]:.0f} % '
                         f'probability (noise level from {power["noise_source"]}, '
                         f'{_dof_text(power["noise_dof"])})')
        if self.outcome in ('negligible', 'not explained'):
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
