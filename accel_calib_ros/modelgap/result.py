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
"""Without a naming simulation: below this probability of the gap test detecting an error of
the practical threshold's size, cannot tell."""


CANNOT_TELL_FACTOR = 2.0
"""A verdict of noise needs every tested effect of this many thresholds noticed (half the
time at least, ``CANNOT_TELL_POWER``): its ``power.LIMIT_STEP``."""


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
    alternatives: list = field(default_factory=list)  # confounded rivals of named effects
    tested: list = field(default_factory=list)        # the library effects the session shows
    naming_power: dict = None                         # power.calibrate_power, or None
    session_fits: object = field(default=None, repr=False)   # setfit.SessionFits
    selection: object = field(default=None, repr=False)      # selection.Selection
    final_set: object = field(default=None, repr=False)      # setfit.SetFit of the steps
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
        Return the scatter per window, m/s², that the named effects leave beyond their terms.

        0 unless one is rough: a named random walk leaves the wander its smooth terms cannot
        follow (``Effect.roughness``); the variances of several add.
        """
        fit = self.fits[-1]
        model = Model(self.baseline, fit.effects)
        variance = sum(effect.roughness(model, fit.x, self.conditions)
                       for effect in model.objects.values())
        return float(np.sqrt(variance))

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

    def gap_power(self):
        """
        Return the gap test's own power, the figures of a systematic error per window.

        (smallest error detected, the same with the noise level known, the probability of
        detecting an error of the practical threshold's size, the noise dof used). A
        systematic error of one size in every window, along gravity, in a pattern the model
        cannot absorb (``noise.min_detectable_mg``), with the noise level from
        ``noise_source``. Sizes are None when no error size gets there.
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
            self._power_memo[key] = (mde if np.isfinite(mde) else None,
                                     known if np.isfinite(known) else None, at_threshold, nu)
        return self._power_memo[key]

    def power(self):
        """
        Return the power of the verdict, JSON-ready: the sizes the workflow would name.

        ``per_effect``: for each tested library effect not named, ``min_named_mg``, the
        smallest worst-case size at which the workflow names it (or reports it as the
        alternative to a simpler confounded effect) in at least ``power.TARGET`` of
        simulated sessions of this design (``power``; None when not up to 17 thresholds),
        ``rate`` there, ``rate_at_threshold``, and ``min_noticed_mg``, from which it changes
        the verdict (something is named, or the gap stays open). ``min_detectable_mg``: the
        largest ``min_noticed_mg``, the size from which no tested library effect goes
        unnoticed (None when one would; without a simulation the gap test's figure).
        ``gap_test``: what the gap test alone sees, a systematic error per window
        (``gap_power``).
        """
        mde, known, at_threshold, nu = self.gap_power()
        out = {'probability': POWER, 'quantile': NULL_QUANTILE,
               'noise_source': self.noise_source,
               'noise_dof': nu if np.isfinite(nu) else None,
               'gap_test': {'min_error_mg': mde, 'min_error_mg_known_noise': known,
                            'at_threshold': at_threshold},
               'at_threshold': at_threshold}
        if self.naming_power is None:
            out.update(method='gap test', min_detectable_mg=mde, per_effect={})
            return out
        sizes = [v['min_noticed_mg'] for v in self.naming_power.values()
                 if 'confounded_with' not in v]
        out.update(method="naming simulated on this session's design",
                   min_detectable_mg=(None if None in sizes else max(sizes, default=None)),
                   per_effect={name: dict(value)
                               for name, value in self.naming_power.items()})
        return out

    def weak_effects(self):
        """
        Return the tested effects that would go unnoticed at ``CANNOT_TELL_FACTOR`` thresholds.

        Noticed in less than ``CANNOT_TELL_POWER`` of the simulated sessions at that size:
        {name: the size from which it is noticed with 80 %, or None}.
        """
        if not self.naming_power:
            return {}
        return {name: value['min_noticed_mg'] for name, value in self.naming_power.items()
                if 'confounded_with' not in value
                and value.get('noticed_at_limit', 0.0) < CANNOT_TELL_POWER}

    @property
    def cannot_tell(self):
        """
        Tell whether a verdict of noise would claim more than this session can know.

        The gap is within its null limit (or what is left is slow noise), but either some
        tested library effect of ``CANNOT_TELL_FACTOR`` times the practical threshold would
        go unnoticed (nothing named, the gap closed) more often than not (``weak_effects``:
        the naming simulated on this session's design, ``power``), or an error of the
        practical threshold's size would be missed by the gap test itself more often than
        seen (``CANNOT_TELL_POWER``): the rest could then be anything, not only noise.
        """
        if self.kind not in ('explained', 'slow noise'):
            return False
        return bool(self.weak_effects()) or self.gap_power()[2] < CANNOT_TELL_POWER

    @property
    def kind(self):
        """Return what is left, before the power is asked: see ``outcome``."""
        if self.statistically_explained:
            return 'explained'
        if self.negligible:
            return 'negligible'
        if self.walk_explains_rest:
            return 'walk'
        if self.slow_noise:
            return 'slow noise'
        return 'not explained'

    @property
    def benign_rest(self):
        """Tell whether what is left is noise, negligible, a walk's rest or slow noise."""
        return self.kind != 'not explained'

    @property
    def outcome(self):
        """
        Return the kind of verdict.

        'explained', 'cannot tell' (no power, see ``cannot_tell``), 'negligible',
        'walk' (the rest is a named random walk's roughness), 'slow noise' or
        'not explained'.
        """
        kind = self.kind
        if kind in ('explained', 'slow noise') and self.cannot_tell:
            return 'cannot tell'
        return kind

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
            return self._cannot_tell_text()
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

    def _cannot_tell_text(self):
        power = self.power()
        source = (f'noise level from {power["noise_source"]}, '
                  f'{_dof_text(power["noise_dof"])}')
        gap = power['gap_test']
        mde, known = gap['min_error_mg'], gap['min_error_mg_known_noise']
        cause = ('noise too uncertain' if known is not None and known <= self.threshold_mg
                 and (mde is None or mde > self.threshold_mg)
                 else 'noise too large' if known is None or known > self.threshold_mg
                 else 'this design shows some effects only weakly')
        weak = self.weak_effects()
        if weak:
            limit = CANNOT_TELL_FACTOR * self.threshold_mg
            sizes = ', '.join(f'{name} only from {mg:.2g} mg' if mg is not None
                              else f'{name} not even at {16 * self.threshold_mg:.2g} mg'
                              for name, mg in weak.items())
            return (f"cannot tell: {cause} ({source}); on this session's design an effect "
                    f'of {limit:.2g} mg (twice the practical threshold) would go unnoticed '
                    f'more often than not: the workflow notices {sizes} (80 % of simulated '
                    'sessions)')
        size = 'no error' if mde is None else f'an error of {mde:.2g} mg per window'
        return (f'cannot tell: {cause} ({source}); an error of the practical threshold '
                f'({self.threshold_mg:.2g} mg) would be detected with only '
                f'{100 * power["at_threshold"]:.0f} % probability, and {size} with '
                f'{100 * power["probability"]:.0f} %')

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
            'alternatives': self.alternatives,
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

    def rest_words(self):
        """Return what a rest without a smooth trend is, in words."""
        return ('no smooth trend in time, temperature, direction or magnitude: a scatter from '
                'pose to pose (e.g. bias instability, the mount shifting between poses, or '
                'noise correlated beyond a window)')

    def power_text(self):
        """Return the power line of the text: what the workflow would have named."""
        power = self.power()
        per = power['per_effect']
        gap = power['gap_test']['min_error_mg']
        tail = (f'the gap test alone sees {gap:.2g} mg per window' if gap is not None
                else 'the gap test alone would see no error')
        if not per:
            return (f'power: {tail} with {100 * power["probability"]:.0f} % probability '
                    f'(noise level from {power["noise_source"]}, '
                    f'{_dof_text(power["noise_dof"])})')
        sizes = ', '.join(
            f'{name} taken up by {value["confounded_with"]}' if 'confounded_with' in value
            else f'{name} {value["min_named_mg"]:.2g} mg' if value['min_named_mg'] is not None
            else f'{name} only noticed, from {value["min_noticed_mg"]:.2g} mg'
            if value['min_noticed_mg'] is not None else f'{name} not noticed'
            for name, value in per.items())
        return (f'power: the workflow would name {sizes} (worst case; '
                f'{100 * power["probability"]:.0f} % of simulated sessions of this design, '
                f'noise level from {power["noise_source"]}, {_dof_text(power["noise_dof"])}); '
                + tail)

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
                         + item['reason'])
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
        lines.append(self.power_text())
        if self.outcome in ('negligible', 'not explained'):
            lines.append(f'the rest is a scatter of {self.excess_scatter():.2g} m/s² per window')
            found = [(name, p) for name, p in self.probes.items() if p['significant']]
            if found:
                lines.append('where the residual lives: ' + '; '.join(
                    f'{name} ({p["rms_mg"]:.2g} mg RMS, p = {p["p"]:.1e})'
                    for name, p in found))
            else:
                lines.append(self.rest_words())
        return '\n'.join(lines)
