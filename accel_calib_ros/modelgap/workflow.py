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
from .evidence import (column_correlation, effect_worst_case_mg, separation_advice,
                       strongest_correlations, visibility)
from .model import conditions_from_windows, fit_model, min_windows, Model, model_start
from .noise import simulated_null_gaps, window_noise, WindowNoise
from .probes import residual_probes
from .result import DiagnoseResult, MIN_EFFECT_MG
from ..core.accel.calibration import calibrate
from ..core.errors import CalibrationError
from ..core.windows import DEFAULTS, detect_static_windows, MAX_WEIGHT_S

P_SUPPORT = 1e-3
"""Largest F-test p-value for which an added effect counts as supported."""

MIN_VISIBILITY = 0.01
"""Effects that this session shows less than this (see ``visibility``) are not tested."""


COLLINEAR = 0.9
"""Supported runner-up whose signature correlates more than this with the winner's is a rival."""


def diagnose_windows(windows, baseline='ml', gravity=9.80665, rate_hz=None, rng=None,
                     replicates=0, inflation=1.0, max_steps=4, noise=None, min_effect_mg=None):
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
    c = conditions_from_windows(windows, gravity, noise.inflation)
    start_cal = calibrate(c.readings, gravity, baseline, windows.count.astype(float))
    model, fit = fit_model(baseline, [], c, model_start(baseline, start_cal))
    accuracy = _fit_accuracy_mg(windows, gravity, baseline, rate_hz)
    threshold = (float(min_effect_mg) if min_effect_mg is not None
                 else max(MIN_EFFECT_MG, accuracy if np.isfinite(accuracy) else 0.0))
    has_temp = bool(np.all(np.isfinite(np.asarray(windows.temp, float))))
    context = {'temp_span': c.temp_span, 'time_span': c.time_span, 'windows': len(windows),
               'has_temp': has_temp}
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
                            window_noise=noise, noise_std=windows.noise_std,
                            rate_hz=rate_hz, threshold_mg=threshold,
                            predicted_accuracy_mg=accuracy)
    n = len(c.readings)
    while candidates and len(result.steps) < max_steps:
        tried = []
        for name in candidates:
            k = len(EFFECTS[name].param_names)
            if fit.dof - k < 2:
                continue
            start = np.concatenate([fit.x, np.zeros(k)])
            try:
                new_model, new_fit = fit_model(baseline, fit.effects + [name], c, start)
            except (ValueError, np.linalg.LinAlgError):
                continue
            drop = fit.chi2 - new_fit.chi2
            F = (drop / k) / max(new_fit.chi2 / new_fit.dof, 1e-300)
            p = float(stats.f.sf(F, k, new_fit.dof))
            bic = drop - k * np.log(n)
            params = new_model.split(new_fit.x)[2][name]
            worst = effect_worst_case_mg(new_model, new_fit.x, c, name, params)
            tried.append({'effect': name, 'drop': drop, 'model': new_model, 'fit': new_fit,
                          'F': float(F), 'p': p, 'bic': float(bic), 'worst_case_mg': worst,
                          'significant': bool(p < P_SUPPORT and bic > 0),
                          'large_enough': bool(worst > threshold)})
        result.candidates = [{key: t[key] for key in ('effect', 'F', 'p', 'worst_case_mg',
                                                      'significant', 'large_enough')}
                             | {'delta_chi2': float(t['drop']), 'delta_bic': t['bic']}
                             for t in tried]
        result.below_threshold = [cand for cand in result.candidates
                                  if cand['significant'] and not cand['large_enough']]
        supported = sorted((t for t in tried if t['significant'] and t['large_enough']),
                           key=lambda t: -t['drop'])
        if not supported:
            break
        # A tie (the columns are collinear in this session) goes to the effect with a
        # measured cause: temperature is recorded, a drift with time is the catch-all.
        tied = [t for t in supported if t['drop'] >= (1 - 1e-3) * supported[0]['drop']]
        tied.sort(key=lambda t: t['effect'] == 'bias_drift')
        supported.remove(tied[0])
        supported.insert(0, tied[0])
        best = supported[0]
        name, new_model, new_fit, drop = best['effect'], best['model'], best['fit'], best['drop']
        a = model.true_accel(fit.x, c)
        directions = a / np.linalg.norm(a, axis=1, keepdims=True)
        T_new, _, all_params = new_model.split(new_fit.x)
        params = all_params[name]
        result.steps.append({
            'effect': name, 'gap_before': fit.gap, 'gap_after': new_fit.gap,
            'evidence': {'F': best['F'], 'p': best['p'], 'delta_chi2': float(drop),
                         'delta_bic': best['bic'], 'params': params.tolist(),
                         'param_names': list(EFFECTS[name].param_names),
                         'unit': EFFECTS[name].unit,
                         'magnitude': EFFECTS[name].magnitude(params, gravity,
                                                              np.diag(T_new)),
                         'worst_case_mg': best['worst_case_mg'],
                         'description': EFFECTS[name].description},
            'where': strongest_correlations(fit.residuals, c, directions)})
        for rival in supported[1:]:
            # A rival only when the two are confounded in this session's design: their
            # signatures (Jacobian columns) correlate.
            alike = column_correlation(model, fit, c, name, rival['effect'])
            if alike > COLLINEAR:
                result.ambiguities.append(
                    f'{name} and {rival["effect"]} are confounded in this session (their '
                    f'signatures correlate {alike:.2f}; chi² drops {drop:.1f} and '
                    f'{rival["drop"]:.1f}): '
                    + separation_advice(name, rival['effect'], c))
        model, fit = new_model, new_fit
        result.fits.append(fit)
        candidates.remove(name)
    if fit.jac is not None:
        result.probes = residual_probes(model, fit, c)
        _demote_partial(result, c)
    model = Model(baseline, result.fits[-1].effects)
    fit = result.fits[-1]
    result.null_gaps = simulated_null_gaps(model, fit, c, rng, replicates) if replicates else []
    return result


def _fit_accuracy_mg(windows, gravity, baseline, rate_hz):
    """
    Return the predicted accuracy ``accel-calib fit`` reports for these windows, mg.

    ``core.accel.calibration.calibrate`` with fit's weights (samples per window, capped
    at ``MAX_WEIGHT_S`` of data when the rate is known) and noise. For a ``gn`` baseline
    the share fit charges for the cross-axis terms gn leaves out is not counted: those
    terms are what this check looks for (``nonorthogonality``), so they must not raise
    the practical threshold.
    """
    from ..core.acceptance import estimation_accuracy
    weights = windows.weights(MAX_WEIGHT_S, rate_hz)
    try:
        cal = calibrate(windows.mean, gravity, baseline, weights, noise_std=windows.noise_std)
    except (CalibrationError, np.linalg.LinAlgError, ValueError):
        return float('nan')
    value = estimation_accuracy(cal)
    return float(value) * 1000.0 / G0 if value is not None else float('nan')


PARTIAL_SHARE = 0.05
"""A named effect is withdrawn when its variable's probe still finds this share of its Δχ²."""


def _demote_partial(result, c):
    """
    Withdraw named effects that only explain part of a dependence of another shape.

    When what is left is not explained (``DiagnoseResult.explained``) and the
    nonparametric probe in a time or temperature effect's own variable
    (``Effect.variable``: time for ``bias_drift``, temperature for the
    temperature effects) is still significant and still explains at least
    ``PARTIAL_SHARE`` of the chi² the effect removed, the effect is a projection of
    something the library lacks (a step, a curve, a cycle), not the cause: it is moved
    to ``result.partial`` and the model is refitted without it.
    """
    if result.explained:
        return
    partial = []
    for step in result.steps:
        if EFFECTS[step['effect']].variable not in ('time', 'temperature'):
            continue        # the direction probe also holds what the poses cannot tell apart
        probe = result.probes.get(EFFECTS[step['effect']].variable)
        worst = step['evidence']['worst_case_mg']
        share = PARTIAL_SHARE * step['evidence']['delta_chi2']
        if probe and probe['significant'] and probe['delta_chi2'] >= share:
            partial.append({'effect': step['effect'], 'worst_case_mg': worst,
                            'variable': EFFECTS[step['effect']].variable,
                            'left_rms_mg': probe['rms_mg'], 'left_p': probe['p']})
    if not partial:
        return
    gone = {p['effect'] for p in partial}
    kept = [step for step in result.steps if step['effect'] not in gone]
    fits = [result.fits[0]]
    for step in kept:
        effects = fits[-1].effects + [step['effect']]
        start = np.concatenate([fits[-1].x, np.zeros(len(EFFECTS[step['effect']].param_names))])
        _, new_fit = fit_model(result.baseline, effects, c, start)
        step['gap_before'], step['gap_after'] = fits[-1].gap, new_fit.gap
        fits.append(new_fit)
    result.steps, result.fits, result.partial = kept, fits, partial
    model = Model(result.baseline, fits[-1].effects)
    result.probes = residual_probes(model, fits[-1], c)


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
    if noise.moving.any() and (~noise.moving).sum() >= min_windows(baseline):
        windows = windows.select(~noise.moving)
    else:
        noise.moving[:] = False
    result = diagnose_windows(windows, baseline, gravity, rate, rng, replicates,
                              noise=noise, min_effect_mg=min_effect_mg)
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
    for key, effects in (('baseline_rms', []), ('with_effects_rms', out['effects'])):
        model = Model(result.baseline, effects)
        x0 = np.concatenate([start, np.zeros(model.n_params - len(start))])
        x, _, _ = model.fit(train, x0)
        a = model.true_accel(x, test)
        rho = np.linalg.norm(a, axis=1) - test.gravity
        out[key] = float(np.sqrt(np.mean(rho ** 2)))
    return out
