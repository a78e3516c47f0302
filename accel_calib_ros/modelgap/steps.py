"""
The named effects as steps: one object per effect, in the order the selection added them.

Step i compares the joint fit of the first i - 1 effects with that of the first i (gap
before and after, F, p, ΔBIC); the effect's parameters, size and time constant are those of
the final joint fit, and ``joint`` says how it holds beside all the others there.
"""

import numpy as np

from .criterion import evaluate, Trial
from .effects import EFFECTS
from .selection import ambiguity_notes, member_support


def record_steps(result, chosen):
    """
    Set ``result.steps``, ``result.fits`` (baseline first), the ambiguity notes and alternatives.

    :param result: DiagnoseResult with ``session_fits`` and ``selection``.
    :param chosen: names in the order they were added.
    """
    fits, c = result.session_fits, result.conditions
    chain = [fits.fit(chosen[:i]) for i in range(len(chosen) + 1)]
    while chain[-1] is None:            # a set that could not be fitted: keep what was
        chosen, chain = chosen[:-1], chain[:-1]
    steps = []
    for i, name in enumerate(chosen):
        before, after = chain[i], chain[i + 1]
        trial = Trial(name, EFFECTS[name].variable, after.k(name), [after.chi2], after.dof,
                      [fits.size(after, before, name)], [fits.cv(after)], [''])
        ev = evaluate(np.array([before.chi2]), fits.cv(before)[None, :], [trial], fits.n,
                      fits.nu, fits.threshold)
        # The effect as found: fitted jointly with all the others in the final set.
        final = chain[-1]
        effect = final.bound[name]
        params = final.params(name)
        T = final.model.split(final.fit.x)[0]
        evidence = {'F': float(ev['F'][0, 0]), 'p': float(ev['p'][0, 0]),
                    'delta_chi2': float(before.chi2 - after.chi2),
                    'delta_bic': float(ev['bic'][0, 0]), 'params': params.tolist(),
                    'param_names': list(effect.param_names), 'unit': effect.unit,
                    'magnitude': effect.magnitude(params, c.gravity, np.diag(T)),
                    'worst_case_mg': float(trial.worst[0]),
                    'effect_worst_case_mg': float(fits.worst(final, name)),
                    'description': effect.description}
        evidence.update(effect.searched_values())
        if len(chosen) > 1:
            _, joint, _ = member_support(fits, chosen, name)
            if joint is not None:
                evidence['joint'] = {'F': float(joint['F'][0, 0]),
                                     'p': float(joint['p'][0, 0]),
                                     'delta_chi2': float(joint['drop'][0]),
                                     'delta_bic': float(joint['bic'][0, 0])}
        steps.append({'effect': name, 'gap_before': before.gap, 'gap_after': after.gap,
                      'evidence': evidence,
                      'where': fits.where(before)})
    result.steps = steps
    result.fits = [s.fit for s in chain]
    result.final_set = chain[-1]
    if result.selection is not None:
        result.ambiguities, result.alternatives = ambiguity_notes(result.selection, chosen, c)
    return chosen


def select_into(result, fits, candidates, max_steps):
    """
    Run the one selection over ``candidates`` and record it in ``result`` (any geometry).

    Sets ``session_fits``, ``tested``, ``selection``, the steps (``record_steps``), the last
    round's ``candidates``, those ``below_threshold`` and the ``vetoed``.
    """
    from .selection import select, Selection
    result.session_fits = fits
    result.tested = candidates
    selection = select(fits, candidates, max_steps) if max_steps > 0 else Selection()
    result.selection = selection
    record_steps(result, selection.chosen)
    result.candidates = selection.candidates
    result.below_threshold = [cand for cand in result.candidates
                              if cand['significant'] and not cand['large_enough']]
    result.vetoed = list(selection.vetoed)
    return selection
