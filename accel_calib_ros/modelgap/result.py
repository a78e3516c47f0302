"""The outcome of the model-gap workflow: the steps, the verdict, the JSON and the words."""

from dataclasses import dataclass, field

import numpy as np
from scipy import optimize

from .effects import EFFECTS, G0
from .model import Conditions, Model
from .noise import null_gap_limit, null_gap_p, NULL_QUANTILE, WindowNoise
from ..core.allan import NOISE_DENSITY_CONVENTION

MIN_EFFECT_MG = 1.0
"""Smallest practical threshold, mg: an effect smaller than this is never named."""


NEGLIGIBLE_FACTOR = 3.0
"""The rest is negligible when this many times its per-window scatter is below the threshold."""


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
                # The package's one convention (core.allan): the white-noise density N
                # with Allan deviation N/sqrt(tau), so white samples have std N sqrt(rate)
                # (what allan reads at the shortest cluster times); at the windows' time
                # scale the window means see N sqrt(inflation). In true units, µg/√Hz.
                T = np.diag(Model(self.baseline, []).split(self.fits[0].x)[0])
                inflation = (self.window_noise.inflation if self.window_noise is not None
                             else np.ones(3))
                white = np.asarray(self.noise_std) / np.abs(T) / np.sqrt(self.rate_hz)
                out['noise_density_ug_rthz'] = (white / G0 * 1e6).tolist()
                out['window_noise_density_ug_rthz'] = (white * np.sqrt(inflation)
                                                       / G0 * 1e6).tolist()
                out['noise_density_convention'] = NOISE_DENSITY_CONVENTION
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
