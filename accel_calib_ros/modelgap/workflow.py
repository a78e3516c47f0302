"""
Model-gap workflow: where simulation and measurement disagree, and why.

1. Fit the baseline model (``ml``: upper-triangular T + bias; ``gn``: diagonal T +
   bias) to the session's static windows, each residual divided by the noise of its
   window mean measured from the data itself (``noise.window_noise``), so that the gap
   sqrt(chi²/dof) is about 1 when model and measurement agree; its null law is
   F(dof, noise dof), and the test's power is reported with the verdict.
2. Each effect of the library (``effects.EFFECTS``) that the session can show
   (``Effect.applicable``, enough degrees of freedom, ``visibility``) is added in
   turn and refitted; a nested-model F-test (robust to a mis-estimated noise level)
   and the BIC decide whether the data support it.
3. The supported effects are ranked by ΔBIC and the first that agrees with all the
   evidence (``agreement.disagreement``: the probes as alternatives, the still data, its
   confounders) is named; the loop repeats until nothing more is supported. With a gn
   baseline, only what the ml baseline also finds is named (``_confirm_with_ml``).
4. Named effects that the whole model no longer supports are withdrawn
   (``pruning``); what is left is judged: noise, no power to tell, negligible, the rest
   of a random walk, slow noise, or NOT explained with where it lives (``probes``).

``diagnose(samples)`` runs it on a recording, ``diagnose_windows(windows)`` on static
windows (the calibration node), ``held_out_check`` cross-validates the finding.
"""

import numpy as np
from scipy import stats

from .agreement import (COLLINEAR, disagreement, lag_against_pair, P_SUPPORT, still_drift,
                        walk_against_drift)
from .effects import EFFECTS, G0
from .evidence import (column_correlation, effect_worst_case_mg, separation_advice,
                       strongest_correlations, visibility)
from .model import conditions_from_windows, fit_model, min_windows, Model, model_start
from .noise import simulated_null_gaps, window_noise, WindowNoise
from .probes import delta_bic, residual_probes
from .pruning import demote_partial, drop_redundant, within_slow_noise
from .result import DiagnoseResult, MIN_EFFECT_MG
from ..core.accelerometer.fit import calibrate
from ..core.errors import CalibrationError
from ..core.windows import DEFAULTS, detect_static_windows, MAX_WEIGHT_S

MIN_VISIBILITY = 0.01
"""Effects that this session shows less than this (see ``visibility``) are not tested."""


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
    (``disagreement``): the probes as alternatives, and the still windows for a drift.

    :param allowed: names that may be named (all when None).
    """
    c = conditions_from_windows(windows, gravity, noise.inflation)
    start_cal = calibrate(c.readings, gravity, baseline, windows.count.astype(float))
    model, fit = fit_model(baseline, [], c, model_start(baseline, start_cal))
    accuracy, noise_only = _fit_accuracy_mg(windows, gravity, baseline, rate_hz)
    threshold = (float(min_effect_mg) if min_effect_mg is not None
                 else max(MIN_EFFECT_MG, noise_only if np.isfinite(noise_only) else 0.0))
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
            reason = (disagreement(cand, alternatives, model, fit, c, still)
                      or lag_against_pair(cand, tried, model, fit, c))
            if not reason and walk_against_drift(cand, tried, model, fit, c):
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
        model, fit = drop_redundant(result, c)
    if result.steps and noise.coloured:
        model, fit = within_slow_noise(result, c)
    if fit.jac is not None:
        result.probes = residual_probes(model, fit, c)
        demote_partial(result, c)
    return result


def _fit_accuracy_mg(windows, gravity, baseline, rate_hz):
    """
    Return fit's predicted accuracy for these windows and the same before its inflation, mg.

    The first is what ``accel-calib fit`` reports; the second, without the inflation by
    the residual χ²/dof, is the practical threshold.

    ``core.accelerometer.fit.calibrate`` with fit's weights (samples per window, capped
    at ``MAX_WEIGHT_S`` of data when the rate is known) and noise. For a ``gn`` baseline
    the share fit charges for the cross-axis terms gn leaves out is not counted: those
    terms are what this check looks for (``nonorthogonality``), so they must not raise
    the practical threshold. Nor does the threshold carry fit's inflation by the
    residual χ²/dof: a misfit is what this check explains, and a first missing effect
    must not hide a second one behind an inflated threshold.
    """
    from ..core.acceptance import estimation_accuracy
    weights = windows.weights(MAX_WEIGHT_S, rate_hz)
    try:
        cal = calibrate(windows.mean, gravity, baseline, weights, noise_std=windows.noise_std)
    except (CalibrationError, np.linalg.LinAlgError, ValueError):
        return float('nan'), float('nan')
    value = estimation_accuracy(cal)
    if value is None:
        return float('nan'), float('nan')
    inflation = getattr(getattr(cal, 'information', None), 'inflation', 1.0) or 1.0
    mg = float(value) * 1000.0 / G0
    return mg, mg / float(np.sqrt(max(inflation, 1.0)))


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


def diagnose(samples, baseline='ml', gravity=9.80665, min_duration_s=DEFAULTS['min_duration_s'],
             threshold_factor=DEFAULTS['threshold_factor'], max_weight_s=None, replicates=0,
             rng=None, min_effect_mg=None):
    """
    Run the model-gap workflow on a recording.

    :param samples: Samples (validated).
    :param baseline: 'ml' or 'gn'.
    :param gravity: local gravity, m/s² (in reading units per m/s² of T for raw counts).
    :param min_duration_s: shortest static window, s (the same default as ``fit``).
    :param threshold_factor: stillness threshold over the noise floor.
    :param max_weight_s: unused for the gap (each window's own noise weighs it);
        accepted for symmetry with ``fit``.
    :param replicates: re-simulations reported next to the analytic null.
    :param rng: numpy Generator (default seeded 0).
    :param min_effect_mg: practical threshold, mg (see ``diagnose_windows``).
    :returns: DiagnoseResult.
    :raises CalibrationError: too few windows, or the baseline cannot be fitted.
    """
    windows = detect_static_windows(samples, min_duration_s=min_duration_s,
                                    threshold_factor=threshold_factor)   # fit's detector
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
