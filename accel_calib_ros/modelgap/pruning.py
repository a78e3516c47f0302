"""
After the selection: what the noise and the probes say about the named effects.

Neither acts when the named set closes the gap: the probes detect where structure lives
and say "outside the library", they never veto a set that brings the gap into the noise.

- ``within_slow_noise``: when the noise inside the windows is correlated, an effect in time
  or temperature no larger than the noise's own slow wander is withdrawn;
- ``withdraw_projections``: when the gap is not closed (and the rest is neither negligible
  nor a walk's or slow noise's), a named effect that only projects a dependence of another
  shape is withdrawn: the probe in its own variable still finds a good share of what it
  removed, or it adds nothing beside the structure the probes (and a single jump in time)
  find in other variables.
"""

import numpy as np

from .agreement import best_step
from .criterion import COLLINEAR, P_SUPPORT, support_stats
from .effects import EFFECTS, G0
from .probes import added_on_top, FAMILY, residual_probes
from .steps import record_steps


def _refit(result, kept):
    """Refit the kept effects jointly (in their order) and update steps and probes."""
    record_steps(result, kept)
    final = result.final_set
    result.probes = residual_probes(final.model, final.fit, result.conditions)


SLOW_FACTOR = 2.0
"""A time or temperature effect must stand this many times above the slow noise's scatter."""


def within_slow_noise(result):
    """
    Withdraw time and temperature effects no larger than the noise's own slow wander.

    When the noise inside the windows is correlated (``WindowNoise.coloured``), noise
    slower than a window makes the window means scatter beyond the within-window level,
    and part of that scatter is smooth in time: an offset that wanders by itself. A named
    effect in time or temperature whose signal (RMS over the windows, along gravity) is
    not ``SLOW_FACTOR`` times the scatter left beyond the within-window noise
    (``DiagnoseResult.excess_scatter``) is no larger than that wander: it is withdrawn
    (to ``vetoed``) and the rest refitted. Only when that scatter is there: the gap beyond
    its null limit.
    """
    excess = result.excess_scatter()
    if excess <= 0 or result.statistically_explained:
        return
    final = result.final_set
    c = result.conditions
    _, s = final.model.residual_parts(final.fit.x, c)
    gone = []
    for step in result.steps:
        name = step['effect']
        if FAMILY.get(EFFECTS[name].variable) not in ('time', 'temperature'):
            continue
        j = final.model.effect_jacobian(final.fit.x, c, name)
        signal = float(np.sqrt(np.mean((s * (j @ final.params(name))) ** 2)))
        if signal < SLOW_FACTOR * excess:
            gone.append(name)
            result.vetoed.append({
                'effect': name, 'worst_case_mg': step['evidence']['worst_case_mg'],
                'F': step['evidence']['F'], 'p': step['evidence']['p'],
                'step': result.steps.index(step) + 1,
                'reason': f'no larger than the wander of the slow noise: its signal is '
                          f'{1000 * signal / G0:.2g} mg RMS against {1000 * excess / G0:.2g} '
                          'mg per window of scatter beyond the within-window noise, which is '
                          'correlated'})
    if gone:
        _refit(result, [s['effect'] for s in result.steps if s['effect'] not in gone])


PARTIAL_SHARE = 0.05
"""A named effect is withdrawn when its variable's probe still finds this share of its Δχ²."""


def _own_variable(result, name, joint_drop):
    """Return the significant probe in the effect's own variable holding a share of its Δχ²."""
    family = FAMILY.get(EFFECTS[name].variable, EFFECTS[name].variable)
    probes = [(probe, p) for probe, p in result.probes.items()
              if FAMILY[probe] == family and p['significant']
              and p['delta_chi2'] >= PARTIAL_SHARE * joint_drop]
    return max(probes, key=lambda item: item[1]['delta_chi2']) if probes else None


def _span(cols):
    u, sv, _ = np.linalg.svd(cols, full_matrices=False)
    return u[:, sv > 1e-6 * max(sv.max(), 1e-300)]


def _beside_structure(result, name, kept):
    """
    Return the structure of another shape that leaves effect ``name`` nothing to add, or None.

    Fitted to the residuals of the set without ``name`` (linearised): the significant
    probes of other variables (free shapes), and a single jump in time (a parametric shape).
    ``name`` is a projection of that structure when the structure is the better explanation
    by the selection's criterion (its BIC gain at least ``name``'s), ``name``'s columns add
    nothing beside it (F-test), and the structure can judge it: ``name``'s fitted signal
    lies mostly outside the probes' span (inside it, the two variables are confounded in
    this session, e.g. a temperature that rises with time, and a free shape follows
    anything), and the jump adds something beside ``name`` (else the two are one shape).

    :returns: (what the structure is, the F-test p-value of ``name`` beside it) or None.
    """
    fits, c = result.session_fits, result.conditions
    without = fits.fit([n for n in kept if n != name])
    full = fits.fit(kept)
    if without is None or full is None:
        return None
    family = FAMILY.get(EFFECTS[name].variable, EFFECTS[name].variable)
    r, chi2, dof = without.fit.residuals, without.fit.chi2, without.fit.dof
    q = without.basis
    j = fits._columns(without, full.bound[name])
    j = j - q @ (q.T @ j)
    # The structure must be the better explanation by the same criterion (BIC gain on the
    # set without the effect), and leave the effect nothing to add.
    k_e = full.k(name)
    own_bic = float(support_stats([chi2], [full.chi2], k_e, full.dof, fits.n, fits.nu)[2][0])

    def preferred(u, extra=0):
        span = _span(u)
        drop = float(np.sum((span.T @ r) ** 2))
        k = span.shape[1] + extra
        _, p, bic = support_stats([chi2], [chi2 - drop], k, dof - k, fits.n, fits.nu)
        return p[0] < P_SUPPORT and bic[0] >= own_bic
    probes = residual_probes(without.model, without.fit, c)
    found = [(f'the {probe} probe ({p["rms_mg"]:.2g} mg RMS)', p['_basis'])
             for probe, p in probes.items() if FAMILY[probe] != family and p['significant']]
    if found:
        u = np.hstack([basis for _, basis in found])
        signal = j @ np.linalg.lstsq(j, r, rcond=None)[0]
        span = _span(u)
        inside = float(np.sum((span.T @ signal) ** 2) / max(signal @ signal, 1e-300))
        on_top = added_on_top(r, chi2, dof, u, j)
        if inside <= COLLINEAR and on_top >= P_SUPPORT and preferred(u):
            return ' and '.join(label for label, _ in found), on_top
    step = best_step(without.model, without.fit, c)
    if step:
        on_top = added_on_top(r, chi2, dof, step['basis'], j)
        back = added_on_top(r, chi2, dof, j, step['basis'])
        if on_top >= P_SUPPORT and back < P_SUPPORT and preferred(step['basis'], 1):
            return (f'a single jump in time at t = {step["time"]:+.0f} s (about '
                    f'{step["size_mg"]:.2g} mg RMS; the mount shifting?)'), on_top
    return None


def withdraw_projections(result):
    """
    Withdraw named effects that only project a dependence of another shape (gap not closed).

    Nothing happens when the named set closes the gap (within the null limit). Otherwise
    each named effect is checked in turn: the probe
    in its own variable (``Effect.variable``) still finds ``PARTIAL_SHARE`` of the Δχ² it
    removed (it fits part of a curve, a step, a cycle, a direction term of higher degree),
    or it adds nothing beside the structure the probes and a single jump find elsewhere.
    Such an effect moves to ``partial`` and the rest is refitted jointly.
    """
    if result.statistically_explained or not result.steps:
        return
    fits = result.session_fits
    kept = [s['effect'] for s in result.steps]
    partial = []
    for name in list(kept):
        without = fits.fit([n for n in kept if n != name])
        full = fits.fit(kept)
        if without is None or full is None:
            continue
        worst = fits.worst(full, name)
        own = _own_variable(result, name, without.chi2 - full.chi2)
        if own:
            probe, p = own
            partial.append({'effect': name, 'worst_case_mg': worst, 'variable': probe,
                            'left_rms_mg': p['rms_mg'], 'left_p': p['p'],
                            'reason': f'explains only part of a dependence on {probe} of '
                                      f'another shape ({p["rms_mg"]:.2g} mg RMS left, p = '
                                      f'{p["p"]:.1e})'})
            continue
        other = _beside_structure(result, name, kept)
        if other:
            label, on_top = other
            partial.append({'effect': name, 'worst_case_mg': worst,
                            'variable': label.split(' ')[1] if label.startswith('the ')
                            else 'time', 'left_rms_mg': None, 'left_p': on_top,
                            'reason': f'adds nothing beside {label} (p = {on_top:.2g}): a '
                                      'projection of a dependence of another shape'})
    if not partial:
        return
    gone = {p['effect'] for p in partial}
    _refit(result, [n for n in kept if n not in gone])
    result.partial = partial
