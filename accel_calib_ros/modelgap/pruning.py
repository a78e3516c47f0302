"""
After the search: withdraw named effects that the whole model no longer supports.

``drop_redundant`` (backward elimination), ``within_slow_noise`` (no larger than the
noise's own wander) and ``demote_partial`` (a projection of a dependence of another
shape) each move an effect out of the steps and refit the rest (``refit_steps``).
"""

import numpy as np
from scipy import stats

from .agreement import P_SUPPORT
from .effects import EFFECTS, G0
from .model import fit_model, Model
from .probes import delta_bic, FAMILY, residual_probes


def drop_redundant(result, c):
    """
    Withdraw a named effect that a later one makes redundant (backward elimination).

    Each named effect is tested against the final model without it (nested F-test and
    ΔBIC, as when it was added): a linear drift named before a random walk that also
    follows it, for example, then adds nothing. The weakest redundant one is withdrawn
    (to ``vetoed``) and the rest refitted, until every named effect holds its place.
    """
    n = len(c.readings)
    while len(result.steps) > 1:
        fit = result.fits[-1]
        objects = Model(result.baseline, fit.effects).objects
        worst = None
        for step in result.steps:
            kept = [s for s in result.steps if s is not step]
            effects = [objects[s['effect']] for s in kept]
            model = Model(result.baseline, effects)
            T, bias, params = Model(result.baseline, fit.effects).split(fit.x)
            start = np.concatenate([model.pack_baseline(T, bias)]
                                   + [params[s['effect']] for s in kept])
            try:
                _, without = fit_model(result.baseline, effects, c, start)
            except (ValueError, np.linalg.LinAlgError):
                continue
            bound = objects[step['effect']]
            k = len(bound.param_names) + bound.searched
            drop = without.chi2 - fit.chi2
            F = (drop / k) / max(fit.chi2 / max(fit.dof, 1), 1e-300)
            p = float(stats.f.sf(F, k, max(fit.dof, 1)))
            bic = delta_bic(without.chi2, drop, k, n)
            if (p >= P_SUPPORT or bic <= 0) and (worst is None or p > worst[1]):
                worst = (step, p, bic)
        if worst is None:
            break
        step, p, bic = worst
        later = [s['effect'] for s in result.steps if s is not step]
        result.vetoed.append({'effect': step['effect'], 'worst_case_mg':
                              step['evidence']['worst_case_mg'], 'F': step['evidence']['F'],
                              'p': p, 'step': result.steps.index(step) + 1,
                              'reason': f'redundant beside {", ".join(later)} (p = {p:.2g}, '
                                        f'ΔBIC {bic:.0f})'})
        refit_steps(result, [s for s in result.steps if s is not step], c, objects)
    fit = result.fits[-1]
    return Model(result.baseline, fit.effects), fit


SLOW_FACTOR = 2.0
"""A time or temperature effect must stand this many times above the slow noise's scatter."""


def within_slow_noise(result, c):
    """
    Withdraw time and temperature effects no larger than the noise's own slow wander.

    When the noise inside the windows is correlated (``WindowNoise.coloured``), noise
    slower than a window makes the window means scatter beyond the within-window level,
    and part of that scatter is smooth in time: an offset that wanders by itself. A named
    effect in time or temperature whose signal (RMS over the windows, along gravity) is
    not ``SLOW_FACTOR`` times the scatter left beyond the within-window noise
    (``DiagnoseResult.excess_scatter``) is no larger than that wander: it is withdrawn
    (to ``vetoed``) and the rest refitted.
    """
    fit = result.fits[-1]
    model = Model(result.baseline, fit.effects)
    excess = result.excess_scatter()
    if excess <= 0:
        return model, fit
    _, s = model.residual_parts(fit.x, c)
    params = model.split(fit.x)[2]
    gone = []
    for step in result.steps:
        if FAMILY.get(EFFECTS[step['effect']].variable) not in ('time', 'temperature'):
            continue
        j = model.effect_jacobian(fit.x, c, step['effect'])
        signal = float(np.sqrt(np.mean((s * (j @ params[step['effect']])) ** 2)))
        if signal < SLOW_FACTOR * excess:
            gone.append(step)
            result.vetoed.append({
                'effect': step['effect'], 'worst_case_mg': step['evidence']['worst_case_mg'],
                'F': step['evidence']['F'], 'p': step['evidence']['p'],
                'step': result.steps.index(step) + 1,
                'reason': f'no larger than the wander of the slow noise: its signal is '
                          f'{1000 * signal / G0:.2g} mg RMS against {1000 * excess / G0:.2g} '
                          'mg per window of scatter beyond the within-window noise, which is '
                          'correlated'})
    if gone:
        refit_steps(result, [s for s in result.steps if s not in gone], c, model.objects)
    fit = result.fits[-1]
    return Model(result.baseline, fit.effects), fit


def refit_steps(result, kept, c, objects):
    """Refit the named effects ``kept`` one after another; update steps, fits and notes."""
    names = {step['effect'] for step in kept}
    # A note on what a withdrawn effect was confounded with goes with it.
    result.ambiguities = [note for note in result.ambiguities
                          if note.split(' and ', 1)[0] in names]
    fits = [result.fits[0]]
    for step in kept:
        bound = objects[step['effect']]
        effects = fits[-1].effects + [bound]
        start = np.concatenate([fits[-1].x, np.zeros(len(bound.param_names))])
        _, new_fit = fit_model(result.baseline, effects, c, start)
        new_fit.dof -= bound.searched
        step['gap_before'], step['gap_after'] = fits[-1].gap, new_fit.gap
        fits.append(new_fit)
    result.steps, result.fits = kept, fits


PARTIAL_SHARE = 0.05
"""A named effect is withdrawn when its variable's probe still finds this share of its Δχ²."""


def demote_partial(result, c):
    """
    Withdraw named effects that only explain part of a dependence of another shape.

    When what is left is not explained (``DiagnoseResult.explained``) and the
    nonparametric probe in a named effect's own variable (``Effect.variable``: time for
    ``bias_drift``, temperature for the temperature effects, direction or |y| for the
    orientation effects) is still significant and still explains at least
    ``PARTIAL_SHARE`` of the chi² the effect removed, the effect is a projection of
    something the library lacks (a step, a curve, a cycle, a higher-order direction
    term), not the cause: it is moved to ``result.partial`` and the model is refitted
    without it.
    """
    if result.explained:
        return
    partial = []
    for step in result.steps:
        variable = EFFECTS[step['effect']].variable
        probes = [(name, p) for name, p in result.probes.items()
                  if FAMILY[name] == FAMILY.get(variable, variable) and p['significant']]
        worst = step['evidence']['worst_case_mg']
        share = PARTIAL_SHARE * step['evidence']['delta_chi2']
        probes = [(name, p) for name, p in probes if p['delta_chi2'] >= share]
        if probes:
            name, probe = max(probes, key=lambda item: item[1]['delta_chi2'])
            partial.append({'effect': step['effect'], 'worst_case_mg': worst,
                            'variable': name, 'left_rms_mg': probe['rms_mg'],
                            'left_p': probe['p']})
    if not partial:
        return
    gone = {p['effect'] for p in partial}
    objects = Model(result.baseline, result.fits[-1].effects).objects
    refit_steps(result, [step for step in result.steps if step['effect'] not in gone], c,
                objects)
    result.partial = partial
    model = Model(result.baseline, result.fits[-1].effects)
    result.probes = residual_probes(model, result.fits[-1], c)
