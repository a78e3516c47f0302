"""
The model-gap workflow on one still pose: the run, the result and the held-out legs.

:func:`diagnose_still` runs the workflow's selection on a still recording (``still_pose``: its
conditions, model and joint fits), :class:`StillResult` is its verdict (also which
hysteresis term a thermal fit carries), :func:`held_out_legs` how the named effects predict
one leg of a cycle from the other.
"""

from dataclasses import dataclass

import numpy as np

from .effects import EFFECTS
from .result import DiagnoseResult, MIN_EFFECT_MG
from .still_pose import StillConditions, StillFits, StillModel


@dataclass
class StillResult(DiagnoseResult):
    """A DiagnoseResult of a still recording (residuals per axis, the reference's T)."""

    def _model(self, fit):
        return StillModel(self.conditions, fit.effects)

    def excess_scatter(self):
        fit = self.fits[-1]
        if fit.gap <= 1.0 or fit.dof < 1:
            return 0.0
        s = self.conditions.flat_sigma
        rho = fit.residuals * s
        from scipy import optimize

        def excess(sx):
            return np.sum(rho ** 2 / (s ** 2 + sx ** 2)) - fit.dof
        high = float(np.sqrt(np.mean(rho ** 2))) * 2.0 + 1e-12
        return float(optimize.brentq(excess, 0.0, high))

    def walk_roughness(self):
        return 0.0

    def gap_power(self):
        from .noise import detection_probability, min_detectable_mg
        fit = self.fits[-1]
        s = self.conditions.flat_sigma
        between = self.noise_source == 'between windows'
        scale = self.gap_after ** 2 if between else 1.0
        nu = float(fit.dof) if between else self.noise_dof
        inv = float(np.sum(1.0 / (s ** 2 * scale)))
        mde = min_detectable_mg(fit.dof, nu, inv, len(s))
        known = min_detectable_mg(fit.dof, float('inf'), inv, len(s))
        at = detection_probability(self.threshold_mg, fit.dof, nu, inv, len(s))
        return (mde if np.isfinite(mde) else None, known if np.isfinite(known) else None,
                at, nu)

    def parameters(self):
        c = self.conditions
        model = self._model(self.fits[-1])
        _, _, params = model.split(self.fits[-1].x)
        out = {'T': c.T.tolist(), 'bias': c.bias.tolist(), 'effects': {}}
        for name, values in params.items():
            effect = model.objects[name]
            out['effects'][name] = {
                'values': values.tolist(), 'names': list(effect.param_names),
                'unit': effect.unit,
                'magnitude': effect.magnitude(values, c.gravity, np.diag(c.T))}
        return out

    def hysteresis(self):
        """
        Return the heating/cooling term a thermal fit carries (``Hysteresis``), or None.

        The first named effect that turns with the heating (``Effect.heating``: a gradient,
        a die's lag): the thermal fit carries it in the
        gradient form (the offset per °C of θ - θ_lag), its time constant and per-axis
        coefficients fitted to the data in that form (a die lag named here is carried as
        the gradient that imitates it best).
        """
        from ..core.accelerometer.thermal_lag import Hysteresis
        for step in self.steps:
            if step['effect'] in self.hysteresis_named():
                return Hysteresis(None, np.zeros(3), step['effect'])
        return None

    held_out: dict = None

    def summary(self):
        """Return the JSON of ``DiagnoseResult.summary`` plus the one-pose keys."""
        out = super().summary()
        c = self.conditions
        out.update(reference_c=c.reference_c, band_width_c=c.band_width_c,
                   calibrated_range_c=list(c.rec.temp_range_c),
                   poses=int(c.rec.pose.max()) + 1,
                   heating_bins=int((c.legs > 0).sum()), cooling_bins=int((c.legs < 0).sum()),
                   held_out_legs=self.held_out or {},
                   hysteresis_named=self.hysteresis_named())
        return out

    def text(self):
        """Return the human summary, with the held-out legs."""
        lines = [super().text().replace('static windows', 'bins of one still pose', 1)]
        for name, entry in (self.held_out or {}).items():
            before, after = entry['baseline'], entry['with_effects']
            lines.append(f'{name.replace("_", " ")} ({entry["bins"]} bins held out): gap '
                         f'{before["gap"]:.2f} -> {after["gap"]:.2f}, RMS [mg] '
                         + ' '.join(f'{v:.2f}' for v in before['rms_mg']) + ' -> '
                         + ' '.join(f'{v:.2f}' for v in after['rms_mg']))
        return '\n'.join(lines)

    def hysteresis_named(self):
        """Return the named effects that turn with the heating, in the order named."""
        final = self.final_set
        return [s['effect'] for s in self.steps
                if final is not None and final.bound[s['effect']].heating]

    def rest_words(self):
        return ('a scatter from bin to bin beyond the noise inside the bins (bias instability, '
                'noise correlated beyond a bin)')

    def brief(self):
        """Return the verdict in a few keys (for ``fit``'s JSON)."""
        return {'missing_effects': self.missing_effects, 'gap_before': self.gap_before,
                'gap_after': self.gap_after, 'verdict': self.verdict(),
                'explained_by_noise': bool(self.explained),
                'steps': [{'effect': s['effect'], 'gap_before': s['gap_before'],
                           'gap_after': s['gap_after'],
                           'magnitude': s['evidence']['magnitude'],
                           'worst_case_mg': s['evidence']['worst_case_mg'],
                           'p': s['evidence']['p'],
                           **({'tau_s': s['evidence']['tau_s']}
                              if 'tau_s' in s['evidence'] else {})}
                          for s in self.steps],
                'alternatives': self.alternatives}


def diagnose_still(rec, reference, reference_c, band_width_c, gravity=9.80665,
                   min_effect_mg=None, samples=None, max_steps=3, power=True):
    """
    Run the model-gap workflow on a still recording (see the module docstring).

    :param rec: StillRecording. :param reference: the reference Calibration.
    :param reference_c: its temperature, °C. :param band_width_c: the tables' band width.
    :param min_effect_mg: practical threshold, mg (default ``MIN_EFFECT_MG``).
    :param samples: the Samples of ``rec`` (the noise of a bin from its own spectrum).
    :returns: StillResult.
    """
    from .noise import window_noise, WindowNoise
    from .steps import select_into
    noise = WindowNoise(np.ones(3), np.zeros(3), ['assumed white'] * 3)
    if samples is not None and getattr(rec, 'samples', None) is not None:
        noise = window_noise(rec.samples, rec.bins)
    c = StillConditions(rec, reference, reference_c, band_width_c, gravity, noise.inflation)
    threshold = float(min_effect_mg) if min_effect_mg is not None else MIN_EFFECT_MG
    pooled = 0.0 if noise.coloured else noise.dof
    fits = StillFits(c, threshold, pooled, noise_dof=noise.dof)
    base = fits.fit(())
    from scipy import stats
    context = {'temp_span': c.temp_span, 'time_span': c.time_span, 'windows': len(c),
               'has_temp': True,
               'time_temp_rank': float(stats.spearmanr(c.time, c.temp)[0])
               if np.ptp(c.temp) > 0 else 1.0}
    skipped, candidates = {}, []
    for name, effect in EFFECTS.items():
        reason = ('' if effect.one_pose else 'one still pose cannot show it (no direction or '
                  'scale changes; the offset against temperature is the baseline)')
        reason = reason or effect.applicable(context, 'still')
        if not reason:
            bound = effect.bind(c)
            if base.fit.dof - len(bound.param_names) - bound.searched < 2:
                reason = f'{len(c)} bins leave too few degrees of freedom'
        if reason:
            skipped[name] = reason
        else:
            candidates.append(name)
    result = StillResult('still', len(c), c, [base.fit], skipped=skipped, window_noise=noise,
                         noise_std=rec.noise_std, threshold_mg=threshold)
    select_into(result, fits, candidates, max_steps)
    if power:
        _naming_power(result)
    result.held_out = held_out_legs(result)
    return result


def _naming_power(result):
    """Simulate how large each tested effect not named must be to be named (``power``)."""
    from .power import calibrate_power
    names = [n for n in result.tested if n not in result.missing_effects]
    if not names or result.final_set is None:
        result.naming_power = {}
        return
    coloured = bool(result.window_noise.coloured)
    open_gap = result.noise_source == 'between windows' or not result.statistically_explained
    excess = result.excess_scatter() if open_gap else 0.0
    scale = max(1.0, result.gap_after ** 2) if coloured and not open_gap else 1.0
    try:
        result.naming_power = calibrate_power(result.session_fits, result.final_set, names,
                                              coloured=coloured, excess=excess, scale=scale)
    except (ValueError, np.linalg.LinAlgError):
        result.naming_power = None


def held_out_legs(result):
    """
    Fit on one direction of the temperature's change and predict the other, before and after.

    The baseline alone and the baseline plus the named effects (as bound to the whole
    recording: their temperature history) are fitted to the heating bins and evaluated on
    the cooling bins, and the other way round. A pose held only in the predicted leg takes
    its constant from there.

    :returns: dict 'heating_to_cooling' and 'cooling_to_heating' (when both legs hold at
        least 10 bins), each {'baseline' and 'with_effects': {'gap', 'rms_mg' (3)}, 'bins'}.
    """
    c = result.conditions
    legs = c.legs
    out = {}
    sets = {'baseline': [], 'with_effects': result.fits[-1].effects}
    for name, fit_leg in (('heating_to_cooling', 1), ('cooling_to_heating', -1)):
        train, test = legs == fit_leg, legs == -fit_leg
        if train.sum() < 10 or test.sum() < 10:
            continue
        entry = {'bins': int(test.sum())}
        for key, effects in sets.items():
            model = StillModel(c, effects)
            r = (c.flat_readings - model.matrix() @ model.fit_rows(train)).reshape(3, -1).T[test]
            for p in np.flatnonzero(~c.design.pose_cols[train].any(axis=0)):
                mine = c.rec.pose[test] == p
                r[mine] -= r[mine].mean(axis=0)
            sigma = c.sigma[test]
            entry[key] = {'gap': float(np.sqrt(np.mean((r / sigma) ** 2))),
                          'rms_mg': (1000.0 * np.sqrt(np.mean(r ** 2, axis=0))
                                     / c.gravity).tolist()}
        out[name] = entry
    return out
