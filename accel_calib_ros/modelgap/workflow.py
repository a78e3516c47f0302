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

import numpy as np
from scipy import stats

from .effects import EFFECTS, G0
from .evidence import (column_correlation, effect_worst_case_mg, predicted_accuracy_mg,
                       separation_advice, strongest_correlations, visibility)
from .model import conditions_from_windows, fit_model, min_windows, Model, model_start
from .noise import RAMP_TEMP_C, simulated_null_gaps, window_noise, WindowNoise
from .probes import added_on_top, delta_bic, FAMILY, residual_probes
from .result import DiagnoseResult, MIN_EFFECT_MG
from ..core.accel.calibration import calibrate
from ..core.errors import CalibrationError
from ..core.windows import detect_static_windows

P_SUPPORT = 1e-3
"""Largest F-test p-value for which an added effect counts as supported."""

MIN_VISIBILITY = 0.01
"""Effects that this session shows less than this (see ``visibility``) are not tested."""


COLLINEAR = 0.9
"""Supported runner-up whose signature correlates more than this with the winner's is a rival."""

RIVAL_BIC = 10.0
"""A rival's ΔBIC is within this of the winner's (beyond it, the evidence is very strong)."""


def diagnose_windows(windows, baseline='ml', gravity=9.80665, rate_hz=None, rng=None,
                     replicates=0, inflation=1.0, max_steps=4, noise=None, min_effect_mg=None,
                     still=None, confirm=True):
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
    :param still: the drift the still windows show (``still_drift``), or None.
    :param confirm: with baseline 'gn', name only effects the ``ml`` baseline also finds
        (or nonorthogonality, the term gn lacks, when the ml fit's cross-axis terms are
        significant beside them); see ``_confirm_with_ml``.
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
    search = {'gravity': gravity, 'rate_hz': rate_hz, 'noise': noise,
              'min_effect_mg': min_effect_mg, 'max_steps': max_steps, 'still': still}
    result = _search(windows, baseline, **search)
    if baseline == 'gn' and confirm:
        result = _confirm_with_ml(result, windows, search)
    model = Model(baseline, result.fits[-1].effects)
    fit = result.fits[-1]
    result.null_gaps = (simulated_null_gaps(model, fit, result.conditions, rng, replicates)
                        if replicates else [])
    return result


def _search(windows, baseline, gravity, rate_hz, noise, min_effect_mg, max_steps, still,
            allowed=None):
    """
    Search the library for the effects the session supports, one step at a time.

    Each round fits every candidate (``_try``), ranks the significant and large enough
    ones by ΔBIC, and names the first that agrees with all the evidence
    (``_disagreement``): the probes as alternatives, and the still windows for a drift.

    :param allowed: names that may be named (all when None).
    """
    c = conditions_from_windows(windows, gravity, noise.inflation)
    start_cal = calibrate(c.readings, gravity, baseline, windows.count.astype(float))
    model, fit = fit_model(baseline, [], c, model_start(baseline, start_cal))
    accuracy = predicted_accuracy_mg(model, fit)
    threshold = (float(min_effect_mg) if min_effect_mg is not None
                 else max(MIN_EFFECT_MG, accuracy if np.isfinite(accuracy) else 0.0))
    has_temp = bool(np.all(np.isfinite(np.asarray(windows.temp, float))))
    context = {'temp_span': c.temp_span, 'time_span': c.time_span, 'windows': len(windows),
               'has_temp': has_temp}
    skipped = {}
    candidates = []
    for name, effect in EFFECTS.items():
        if allowed is not None and name not in allowed:
            continue
        reason = effect.applicable(context, baseline)
        bound = effect.bind(c) if not reason else None
        if not reason and fit.dof - len(bound.param_names) - bound.searched < 2:
            reason = f'{len(windows)} windows leave too few degrees of freedom'
        if not reason and visibility(model, fit, c, bound) < MIN_VISIBILITY:
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
    result.still = still
    while candidates and len(result.steps) < max_steps:
        tried = [t for t in (_try(name, model, fit, c, threshold) for name in candidates) if t]
        result.candidates = [{key: t[key] for key in ('effect', 'F', 'p', 'worst_case_mg',
                                                      'significant', 'large_enough')}
                             | {'delta_chi2': float(t['drop']), 'delta_bic': t['bic']}
                             for t in tried]
        result.below_threshold = [cand for cand in result.candidates
                                  if cand['significant'] and not cand['large_enough']]
        supported = sorted((t for t in tried if t['significant'] and t['large_enough']),
                           key=lambda t: -t['bic'])
        if not supported:
            break
        # A tie (the columns are collinear in this session) goes to the effect with a
        # measured cause: temperature is recorded, a drift with time is the catch-all.
        tied = [t for t in supported if t['bic'] >= supported[0]['bic']
                - 1e-3 * abs(supported[0]['drop'])]
        tied.sort(key=lambda t: EFFECTS[t['effect']].variable == 'time')
        supported.remove(tied[0])
        supported.insert(0, tied[0])
        alternatives = residual_probes(model, fit, c)
        best = deferred = None
        for cand in supported:
            reason = (_disagreement(cand, alternatives, model, fit, c, still)
                      or _lag_against_pair(cand, tried, model, fit, c))
            if not reason and _walk_against_drift(cand, tried, model, fit, c):
                deferred = deferred or cand     # the straight drift first, if it holds
                continue
            if not reason:
                best = cand
                break
            result.vetoed.append({'effect': cand['effect'], 'reason': reason,
                                  'worst_case_mg': cand['worst_case_mg'], 'F': cand['F'],
                                  'p': cand['p'], 'step': len(result.steps) + 1})
            candidates.remove(cand['effect'])
        best = best or deferred
        if best is None:
            break
        best = _refine(best, model, fit, c, threshold)
        _name_step(result, best, model, fit, c, supported)
        model, fit = best['model'], best['fit']
        result.fits.append(fit)
        candidates.remove(best['effect'])
    if len(result.steps) > 1:
        model, fit = _drop_redundant(result, c)
    if result.steps and noise.coloured:
        model, fit = _within_slow_noise(result, c)
    if fit.jac is not None:
        result.probes = residual_probes(model, fit, c)
        _demote_partial(result, c)
    return result


def _drop_redundant(result, c):
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
        _refit_steps(result, [s for s in result.steps if s is not step], c, objects)
    fit = result.fits[-1]
    return Model(result.baseline, fit.effects), fit


SLOW_FACTOR = 2.0
"""A time or temperature effect must stand this many times above the slow noise's scatter."""


def _within_slow_noise(result, c):
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
        _refit_steps(result, [s for s in result.steps if s not in gone], c, model.objects)
    fit = result.fits[-1]
    return Model(result.baseline, fit.effects), fit


def _refit_steps(result, kept, c, objects):
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


def _try(name, model, fit, c, threshold, bound=None):
    """
    Fit the current model plus effect ``name``; return its evidence, or None.

    An effect with a searched parameter (the time constant of ``temperature_lag``) is
    bound to the session with the value that best explains the current residuals
    (linearised, ``Effect.search``), and that parameter counts in the F-test and the BIC.
    """
    n = len(c.readings)
    effect = EFFECTS[name]
    r = fit.residuals
    q = np.linalg.qr(fit.jac)[0] if fit.jac is not None and fit.jac.shape[1] else None

    def explained(bound):
        j = model.effect_jacobian(fit.x, c, bound)
        if q is not None:
            j = j - q @ (q.T @ j)
        u, sv, _ = np.linalg.svd(j, full_matrices=False)
        u = u[:, sv > 1e-9 * max(sv.max(), 1e-300)]
        return float(np.sum((u.T @ r) ** 2))

    bound = effect.search(c, explained) if bound is None else bound
    k = len(bound.param_names) + bound.searched
    if fit.dof - k < 2:
        return None
    start = np.concatenate([fit.x, np.zeros(len(bound.param_names))])
    try:
        new_model, new_fit = fit_model(model.baseline, fit.effects + [bound], c, start)
    except (ValueError, np.linalg.LinAlgError):
        return None
    new_fit.dof -= bound.searched
    drop = fit.chi2 - new_fit.chi2
    F = (drop / k) / max(new_fit.chi2 / new_fit.dof, 1e-300)
    p = float(stats.f.sf(F, k, new_fit.dof))
    bic = delta_bic(fit.chi2, drop, k, n)
    params = new_model.split(new_fit.x)[2][name]
    worst = effect_worst_case_mg(new_model, new_fit.x, c, name, params)
    return {'effect': name, 'bound': bound, 'drop': drop, 'model': new_model, 'fit': new_fit,
            'F': float(F), 'p': p, 'bic': float(bic), 'worst_case_mg': worst, 'k': k,
            'significant': bool(p < P_SUPPORT and bic > 0),
            'large_enough': bool(worst > threshold)}


def _refine(best, model, fit, c, threshold):
    """
    Refine a searched parameter (a time constant) of the effect about to be named.

    The search picked it on the linearised residuals; here the full model is refitted
    over a narrow bracket (a factor 1.5 either way, in log) and the best fit is kept.
    """
    bound = best['bound']
    if not bound.searched or not hasattr(bound, 'tau'):
        return best
    from scipy import optimize
    effect = EFFECTS[best['effect']]
    start = np.concatenate([fit.x, np.zeros(len(bound.param_names))])

    def chi2(log_tau):
        try:
            return fit_model(model.baseline, fit.effects + [effect.bind(c, np.exp(log_tau))],
                             c, start)[1].chi2
        except (ValueError, np.linalg.LinAlgError):
            return np.inf

    centre = np.log(bound.tau)
    found = optimize.minimize_scalar(chi2, bounds=(centre - 0.4, centre + 0.4),
                                     method='bounded', options={'xatol': 0.01})
    if not found.fun < best['fit'].chi2:
        return best
    refined = _try(best['effect'], model, fit, c, threshold,
                   bound=effect.bind(c, np.exp(found.x)))
    return refined if refined and refined['significant'] and refined['large_enough'] else best


def _name_step(result, best, model, fit, c, supported):
    """Record a named effect as a step, with the rivals it is confounded with."""
    name, new_model, new_fit, drop = best['effect'], best['model'], best['fit'], best['drop']
    a = model.true_accel(fit.x, c)
    directions = a / np.linalg.norm(a, axis=1, keepdims=True)
    T_new, _, all_params = new_model.split(new_fit.x)
    params = all_params[name]
    effect = best['bound']
    evidence = {'F': best['F'], 'p': best['p'], 'delta_chi2': float(drop),
                'delta_bic': best['bic'], 'params': params.tolist(),
                'param_names': list(effect.param_names), 'unit': effect.unit,
                'magnitude': effect.magnitude(params, c.gravity, np.diag(T_new)),
                'worst_case_mg': best['worst_case_mg'], 'description': effect.description}
    if getattr(effect, 'tau', None) is not None:
        evidence['tau_s'] = float(effect.tau)
    result.steps.append({'effect': name, 'gap_before': fit.gap, 'gap_after': new_fit.gap,
                         'evidence': evidence,
                         'where': strongest_correlations(fit.residuals, c, directions)})
    for rival in supported[1:]:
        # A rival only when the two are confounded in this session's design (their
        # signatures, the Jacobian columns, correlate) and about as well supported: a
        # rival with many more terms that only contains the winner's signature is not one.
        if rival['effect'] == name or rival['bic'] < best['bic'] - RIVAL_BIC:
            continue
        alike = column_correlation(model, fit, c, effect, rival['bound'])
        if alike > COLLINEAR:
            result.ambiguities.append(
                f'{name} and {rival["effect"]} are confounded in this session (their '
                f'signatures correlate {alike:.2f}; chi² drops {drop:.1f} and '
                f'{rival["drop"]:.1f}): ' + separation_advice(name, rival['effect'], c))


def _disagreement(cand, alternatives, model, fit, c, still):
    """
    Return why a supported candidate disagrees with the rest of the evidence, or ''.

    - A probe of another variable (``probes.FAMILY``) that explains the current
      disagreement better (larger ΔBIC), stays significant after the candidate is added,
      and leaves the candidate nothing to add on top of it (``added_on_top``), while the
      candidate's fitted signal lies mostly outside the probe's span (more than
      ``COLLINEAR`` of it inside means the two are confounded in this session, e.g. a
      temperature that is a smooth function of time, and the probe cannot judge): the
      candidate is only a projection of a dependence on that variable.
    - A time effect against the temperature probe: a wander that is a function of the
      temperature in this session and no better than the temperature probe is left to
      the temperature (a recorded cause comes first).
    - A time effect (or a lagged temperature, which acts through time) against the still
      windows (``still_drift``): a drift that the still data contradict, or a single jump
      in time (a mount shifting) that explains the disagreement better than a drift, a
      wander or a lag does.
    """
    name = cand['effect']
    family = FAMILY.get(EFFECTS[name].variable, EFFECTS[name].variable)
    q = np.linalg.qr(fit.jac)[0] if fit.jac is not None and fit.jac.shape[1] else None
    j = model.effect_jacobian(fit.x, c, cand['bound'])
    if q is not None:
        j = j - q @ (q.T @ j)
    # The candidate's fitted signal in the current residual space (linearised).
    signal = j @ np.linalg.lstsq(j, fit.residuals, rcond=None)[0]
    after = None
    for probe, alt in alternatives.items():
        if FAMILY[probe] == family or not alt['significant'] or alt['delta_bic'] <= cand['bic']:
            continue
        u = alt['_basis']
        inside = float(np.sum((u.T @ signal) ** 2) / max(signal @ signal, 1e-300))
        if inside > COLLINEAR:
            continue        # confounded here (temperature smooth in time): no verdict
        if after is None:
            after = residual_probes(cand['model'], cand['fit'], c)
        if not after.get(probe, {}).get('significant'):
            continue
        on_top = added_on_top(fit.residuals, fit.chi2, fit.dof, u, j)
        if on_top >= P_SUPPORT:
            return (f'the {probe} probe explains the disagreement better (ΔBIC '
                    f'{alt["delta_bic"]:.0f} against {cand["bic"]:.0f}), stays significant '
                    f'after {name} (p = {after[probe]["p"]:.1e}), and {name} adds nothing '
                    f'beside it (p = {on_top:.2g})')
    if family != 'time' and not cand['bound'].searched:
        return ''
    temp = alternatives.get('temperature') if family == 'time' else None
    if temp and temp['significant'] and temp['delta_chi2'] >= cand['drop']:
        u = temp['_basis']
        inside = float(np.sum((u.T @ signal) ** 2) / max(signal @ signal, 1e-300))
        if inside > COLLINEAR:
            return (f'it follows the temperature: the temperature probe explains as much '
                    f'(Δχ² {temp["delta_chi2"]:.0f} against {cand["drop"]:.0f}) and '
                    f'{100 * inside:.0f} % of its signal is a function of temperature in this '
                    'session; a recorded cause comes before a wander in time')
    if name == 'bias_drift' and still is not None:
        reason = _still_contradicts(cand, still)
        if reason:
            return reason
    step = _best_step(model, fit, c)
    if step and step['delta_bic'] > cand['bic']:
        on_top = added_on_top(fit.residuals, fit.chi2, fit.dof, step['basis'], j)
        if on_top >= P_SUPPORT:
            return (f'a single jump in time at t = {step["time"]:+.0f} s (about '
                    f'{step["size_mg"]:.2g} mg RMS; the mount shifting?) explains the '
                    'disagreement '
                    f'better (ΔBIC {step["delta_bic"]:.0f} against {cand["bic"]:.0f}) than '
                    f'{name}, which adds nothing beside it (p = {on_top:.2g})')
    return ''


def _lag_against_pair(cand, tried, model, fit, c):
    """
    Return why a lagged temperature is not needed, or ''.

    A lag shows as the offset following temperature and its rate of change; an offset
    that follows the temperature plus a drift in time can look much the same. The lag is
    named only when it explains the disagreement better (ΔBIC) than ``temperature_bias``
    and ``bias_drift`` together, its two-term confounder.
    """
    if cand['effect'] != 'temperature_lag':
        return ''
    names = [t['effect'] for t in tried]
    if 'temperature_bias' not in names or 'bias_drift' not in names:
        return ''
    pair = [EFFECTS['temperature_bias'].bind(c), EFFECTS['bias_drift'].bind(c)]
    start = np.concatenate([fit.x, np.zeros(6)])
    try:
        _, both = fit_model(model.baseline, fit.effects + pair, c, start)
    except (ValueError, np.linalg.LinAlgError):
        return ''
    bic = delta_bic(fit.chi2, fit.chi2 - both.chi2, 6, len(c.readings))
    if bic < cand['bic']:
        return ''
    return (f'an offset following the temperature plus a drift in time explains the '
            f'disagreement as well (ΔBIC {bic:.0f} against {cand["bic"]:.0f} for a lag of '
            f'tau = {cand["bound"].tau:.3g} s)')


def _walk_against_drift(cand, tried, model, fit, c):
    """
    Return why a wandering offset is not needed beside a straight drift, or ''.

    A random walk's smooth terms also follow a straight drift; the walk comes after
    ``bias_drift``, the simpler time effect, unless it adds significantly to it (F-test,
    ΔBIC). (It is named still when the drift turns out not to hold.)
    """
    if cand['effect'] != 'bias_random_walk':
        return ''
    drift = [t for t in tried if t['effect'] == 'bias_drift']
    if not drift or not drift[0]['significant']:
        return ''
    both = fit.effects + [drift[0]['bound'], cand['bound']]
    k = len(cand['bound'].param_names)
    start = np.concatenate([drift[0]['fit'].x, np.zeros(k)])
    try:
        _, joint = fit_model(model.baseline, both, c, start)
    except (ValueError, np.linalg.LinAlgError):
        return ''
    drop = drift[0]['fit'].chi2 - joint.chi2
    F = (drop / k) / max(joint.chi2 / max(joint.dof, 1), 1e-300)
    p = float(stats.f.sf(F, k, max(joint.dof, 1)))
    bic = delta_bic(drift[0]['fit'].chi2, drop, k, len(c.readings))
    if p < P_SUPPORT and bic > 0:
        return ''
    return (f'a straight drift in time explains it as well: the wander adds nothing beside '
            f'bias_drift (p = {p:.2g}, ΔBIC {bic:.0f})')


def _best_step(model, fit, c):
    """
    Return the best single jump in time of the offset, as an alternative to a time effect.

    Offsets that jump once, n . h for windows after a time t_j, scanned over the gaps
    between windows (linearised, after the model's Jacobian is projected out); the jump
    time counts as one more parameter in the BIC.

    :returns: dict with 'delta_chi2', 'delta_bic', 'time', 'size_mg', 'basis' (N, 3), or
        None when the session has too few windows.
    """
    order = np.argsort(c.time, kind='stable')
    n = len(c.time)
    if n < 12 or fit.jac is None:
        return None
    rho, s = model.residual_parts(fit.x, c)
    a = model.true_accel(fit.x, c)
    directions = a / np.linalg.norm(a, axis=1, keepdims=True)
    q = np.linalg.qr(fit.jac)[0]
    r = rho / s
    best = None
    for cut in range(3, n - 2):
        after = np.zeros(n)
        after[order[cut:]] = 1.0
        cols = after[:, None] * directions / s[:, None]
        cols = cols - q @ (q.T @ cols)
        u, sv, _ = np.linalg.svd(cols, full_matrices=False)
        u = u[:, sv > 1e-6 * max(sv.max(), 1e-300)]
        drop = float(np.sum((u.T @ r) ** 2))
        if best is None or drop > best['delta_chi2']:
            smooth = (u @ (u.T @ r)) * s
            best = {'delta_chi2': drop, 'basis': u,
                    'time': float(0.5 * (c.time[order[cut - 1]] + c.time[order[cut]])),
                    'size_mg': float(1000.0 * np.sqrt(np.mean(smooth ** 2)) / G0)}
    best['delta_bic'] = delta_bic(fit.chi2, best['delta_chi2'], best['basis'].shape[1] + 1, n)
    return best


def _still_contradicts(cand, still):
    """
    Return why the still windows contradict a fitted linear drift, or ''.

    The drift the still windows show (``still_drift``: the slope of the readings inside
    windows whose temperature held steady) against the fitted one, each with its
    covariance: chi² with 3 degrees of freedom, contradicted below ``P_SUPPORT``.
    """
    fit = cand['fit']
    model = cand['model']
    params = model.split(fit.x)[2][cand['effect']]
    k = len(params)
    jac = fit.jac
    cov = np.linalg.pinv(jac.T @ jac)[-k:, -k:] * max(fit.gap ** 2, 1.0)
    delta = params - still['slope']
    total = cov + np.diag(np.asarray(still['se']) ** 2)
    chi2 = float(delta @ np.linalg.solve(total, delta))
    p = float(stats.chi2.sf(chi2, k))
    if p >= P_SUPPORT:
        return ''
    per_min = 60000.0 / G0
    return ('contradicted by the still windows: over '
            f'{still["seconds"]:.0f} s of still data (longest {still["longest_s"]:.0f} s) the '
            'offset drifts ' + ', '.join(
                f'{axis} {per_min * v:+.3g} ± {per_min * e:.2g}'
                for axis, v, e in zip('xyz', still['slope'], still['se']))
            + ' mg/min, not ' + ', '.join(f'{axis} {per_min * v:+.3g}'
                                          for axis, v in zip('xyz', params))
            + f' (p = {p:.1e})')


SAME_POSE_DEG = 0.5
"""Consecutive windows whose mean directions differ less than this hold the same pose."""


def still_drift(samples, windows, noise=None):
    """
    Return the drift of the offset that the still data themselves show, or None.

    Within a pose the direction of gravity is fixed, so with a steady temperature (moved
    less than ``RAMP_TEMP_C``, or not recorded) the readings change only by a drift.
    Consecutive windows in the same pose (mean directions within ``SAME_POSE_DEG``: the
    detector may cut a long rest into pieces) form one still segment; the least-squares
    slope of its samples against time (one offset per segment) has variance
    R sigma² / sum (t - t̄)², R the noise's low-frequency factor (``window_noise``), and the
    segments are pooled by their inverse variances. A long still segment (a warm-up, an
    initial rest) dominates.

    :returns: dict 'slope' (3,) reading units per s, 'se' (3,), 'seconds' of still data
        used, 'longest_s' (the longest segment); None without a segment of 8 samples.
    """
    ratio = (noise.inflation / noise.taper) if noise is not None else np.ones(3)
    ratio = np.maximum(ratio, 1.0)
    order = np.argsort(windows.t_mid, kind='stable')
    unit = windows.mean / np.linalg.norm(windows.mean, axis=1, keepdims=True)
    segments, current = [], []
    for w in order:
        a, b = windows.start[w], windows.stop[w]
        steady = samples.temp is None or np.ptp(samples.temp[a:b]) <= RAMP_TEMP_C
        if not steady or b - a < 8:
            if current:
                segments.append(current)
            current = []
            continue
        if current and float(unit[current[-1]] @ unit[w]) < np.cos(np.radians(SAME_POSE_DEG)):
            segments.append(current)
            current = []
        current.append(w)
    if current:
        segments.append(current)
    num, den, seconds, longest = np.zeros(3), np.zeros(3), 0.0, 0.0
    for segment in segments:
        index = np.concatenate([np.arange(windows.start[w], windows.stop[w]) for w in segment])
        t = samples.t[index] - samples.t[index].mean()
        x = samples.accel[index] - samples.accel[index].mean(axis=0)
        sxx = float(t @ t)
        if sxx <= 0:
            continue
        slope = (t @ x) / sxx
        resid = x - np.outer(t, slope)
        var = ratio * np.sum(resid ** 2, axis=0) / max(len(t) - 2, 1) / sxx
        var = np.where(var > 0, var, np.inf)
        num += slope / var
        den += 1.0 / var
        span = float(t[-1] - t[0])
        seconds += span
        longest = max(longest, span)
    if not np.all(den > 0):
        return None
    return {'slope': num / den, 'se': 1.0 / np.sqrt(den), 'seconds': seconds,
            'longest_s': longest}


def _confirm_with_ml(result, windows, search):
    """
    Name for a gn baseline only what the richer ml baseline also finds.

    The effect search is run with the ml baseline too (with gn's practical threshold, so
    that only the baseline differs). An effect gn names is kept when
    the ml search names it as well, or when it is nonorthogonality (the term gn lacks)
    and the ml baseline's cross-axis terms are significant and large enough beside the
    effects the ml search names (a time effect must not be taken for cross-axis terms).
    When gn named something else, the gn search is run again over the confirmed
    effects only, and the rest is listed in ``unconfirmed`` with the reason.
    """
    try:
        # The same practical threshold: the question is the baseline, not the size.
        ml = _search(windows, 'ml', **(search | {'min_effect_mg': result.threshold_mg}))
    except (CalibrationError, ValueError, np.linalg.LinAlgError) as err:
        result.ml_check = {'checked': False, 'reason': str(err)}
        for step in result.steps:
            step['confirmed'] = 'not checked with the ml baseline: ' + str(err)
        return result
    found = set(ml.missing_effects)
    allowed = set(found)
    cross = _cross_axis_evidence(ml, search)
    if cross['significant']:
        allowed.add('nonorthogonality')
    result.ml_check = {'checked': True, 'missing_effects': ml.missing_effects,
                       'verdict': ml.verdict(), 'cross_axis': cross}
    unconfirmed = [s['effect'] for s in result.steps if s['effect'] not in allowed]
    if unconfirmed:
        again = _search(windows, 'gn', allowed=allowed, **search)
        again.ml_check = result.ml_check
        again.vetoed = result.vetoed + again.vetoed
        for name in unconfirmed:
            reason = ('the ml baseline leaves no significant cross-axis term beside '
                      + (', '.join(ml.missing_effects) or 'its baseline')
                      if name == 'nonorthogonality' else
                      'not found with the ml baseline (it names '
                      + (', '.join(ml.missing_effects) or 'nothing') + ')')
            again.unconfirmed.append({'effect': name, 'reason': reason})
        result = again
    for step in result.steps:
        step['confirmed'] = ('found with the ml baseline too' if step['effect'] in found
                             else "a term gn lacks: the ml fit's cross-axis terms are "
                             'significant')
    return result


def _cross_axis_evidence(ml, search):
    """
    Test the ml baseline's cross-axis terms beside the effects the ml search named.

    The ml model with its named effects against the same model with a diagonal T (gn):
    F-test on the 3 cross-axis terms and their worst case (nonorthogonality's).
    """
    c = ml.conditions
    fit_ml = ml.fits[-1]
    effects = fit_ml.effects
    T, bias, _ = Model('ml', effects).split(fit_ml.x)
    gn = Model('gn', effects)
    start = np.concatenate([gn.pack_baseline(np.diag(np.diag(T)), bias),
                            fit_ml.x[9:]])
    try:
        _, fit_gn = fit_model('gn', effects, c, start)
    except (ValueError, np.linalg.LinAlgError):
        return {'significant': False, 'p': 1.0, 'worst_case_mg': 0.0}
    drop = fit_gn.chi2 - fit_ml.chi2
    dof = max(fit_ml.dof, 1)
    F = (drop / 3.0) / max(fit_ml.chi2 / dof, 1e-300)
    p = float(stats.f.sf(F, 3, dof))
    worst = 1000.0 * float(np.max(np.abs(T[np.triu_indices(3, 1)]) / np.diag(T)[[0, 0, 1]]))
    significant = bool(p < P_SUPPORT and drop - 3 * np.log(len(c.readings)) > 0
                       and worst > ml.threshold_mg)
    return {'significant': significant, 'p': p, 'F': float(F), 'worst_case_mg': worst}


PARTIAL_SHARE = 0.05
"""A named effect is withdrawn when its variable's probe still finds this share of its Δχ²."""


def _demote_partial(result, c):
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
    _refit_steps(result, [step for step in result.steps if step['effect'] not in gone], c,
                 objects)
    result.partial = partial
    model = Model(result.baseline, result.fits[-1].effects)
    result.probes = residual_probes(model, result.fits[-1], c)


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
    from ..core.samples import Samples
    from ..core.windows import DEFAULTS, still_mask, still_runs, windows_from_ranges
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
    windows = noise.apply(windows)
    if noise.moving.any() and (~noise.moving).sum() >= min_windows(baseline):
        windows = windows.select(~noise.moving)
    else:
        noise.moving[:] = False
    result = diagnose_windows(windows, baseline, gravity, rate, rng, replicates,
                              noise=noise, min_effect_mg=min_effect_mg,
                              still=still_drift(samples, windows, noise))
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
    # The effects as bound to this session (a lag's temperature history, a walk's span).
    found = result.fits[-1].effects
    for key, effects in (('baseline_rms', []), ('with_effects_rms', found)):
        model = Model(result.baseline, effects)
        x0 = np.concatenate([start, np.zeros(model.n_params - len(start))])
        x, _, _ = model.fit(train, x0)
        a = model.true_accel(x, test)
        rho = np.linalg.norm(a, axis=1) - test.gravity
        out[key] = float(np.sqrt(np.mean(rho ** 2)))
    return out
