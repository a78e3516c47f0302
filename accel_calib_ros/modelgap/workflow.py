"""
Model-gap workflow: where simulation and measurement disagree, and why.

1. Fit the baseline model (``ml``: upper-triangular T + bias; ``gn``: diagonal T +
   bias) to the session's static windows, each residual divided by the noise of its
   window mean measured from the data itself (``noise.window_noise``), so that the gap
   sqrt(chi²/dof) is about 1 when model and measurement agree; its null law is
   F(dof, noise dof).
2. One model selection (``selection``) over sets of the library effects the session can
   show (``Effect.applicable``, enough degrees of freedom, ``visibility``): each set fitted
   jointly (``setfit``), searched parameters too, compared by one criterion
   (``criterion``: BIC with the pooled noise level, held-out chi² where the margin is small,
   Occam among confounded ties); a member that the others make redundant, refitted jointly,
   is withdrawn. Measurements about one effect (``Effect.contradiction``: the still data of
   a drift, the roughness of a walk) can contradict it; no rule between two effects and no
   probe vetoes a set.
3. What the noise and the probes say after it (``pruning``): an effect no larger than slow
   noise's wander, or one that only projects a dependence of another shape while the gap
   stays open, is withdrawn; the probes say where what is left lives. With a gn baseline,
   only what the ml baseline also finds is named, or a term ml holds and gn lacks
   (``Effect.in_baseline``) when ml's own terms are significant (``_confirm_with_ml``).
4. The power: how large each library effect must be for this workflow to name it on this
   session's design, by simulation (``power``); a verdict of noise that could not have
   named a library effect of practical size says "cannot tell".

``diagnose(samples)`` runs it on a recording, ``diagnose_windows(windows)`` on static
windows (the calibration node), ``held_out_check`` cross-validates the finding.
"""

import numpy as np

from .agreement import still_drift
from .criterion import P_SUPPORT, support_stats
from .effect import Measurements
from .effects import EFFECTS, G0
from .evidence import visibility
from .model import conditions_from_windows, fit_model, min_windows, Model, model_start
from .noise import simulated_null_gaps, window_noise, WindowNoise
from .power import calibrate_power
from .probes import residual_probes
from .pruning import withdraw_projections, within_slow_noise
from .result import DiagnoseResult, MIN_EFFECT_MG
from .setfit import SessionFits
from .steps import select_into
from ..core.accelerometer.fit import calibrate
from ..core.errors import CalibrationError
from ..core.windows import DEFAULTS, detect_static_windows, MAX_WEIGHT_S

MIN_VISIBILITY = 0.01
"""Effects that this session shows less than this (see ``visibility``) are not tested."""


def diagnose_windows(windows, baseline='ml', gravity=9.80665, rate_hz=None, rng=None,
                     replicates=0, inflation=1.0, max_steps=4, noise=None, min_effect_mg=None,
                     still=None, confirm=True, power=True):
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
    :param power: simulate the naming power of the session's design (``power``); without
        it the verdict rests on the gap test's power alone.
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
    if power and max_steps > 0:
        _naming_power(result)
    model = Model(baseline, result.fits[-1].effects)
    fit = result.fits[-1]
    result.null_gaps = (simulated_null_gaps(model, fit, result.conditions, rng, replicates)
                        if replicates else [])
    return result


def _search(windows, baseline, gravity, rate_hz, noise, min_effect_mg, max_steps, still,
            allowed=None):
    """
    Select the effects the session supports (``selection.select``) and judge what is left.

    :param allowed: names that may be named (all when None).
    """
    c = conditions_from_windows(windows, gravity, noise.inflation)
    start_cal = calibrate(c.readings, gravity, baseline, windows.count.astype(float))
    accuracy, noise_only = _fit_accuracy_mg(windows, gravity, baseline, rate_hz)
    threshold = (float(min_effect_mg) if min_effect_mg is not None
                 else max(MIN_EFFECT_MG, noise_only if np.isfinite(noise_only) else 0.0))
    # A model that fits is judged with the within-window noise level pooled in, unless that
    # noise is correlated: noise slower than a window then escapes the level (step 2).
    pooled = 0.0 if noise.coloured else noise.dof
    fits = SessionFits(baseline, c, model_start(baseline, start_cal), threshold, pooled,
                       measured=Measurements(c, still, noise.dof), noise_dof=noise.dof)
    base = fits.fit(())
    model, fit = base.model, base.fit
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
    select_into(result, fits, candidates, max_steps)
    if result.steps and noise.coloured:
        within_slow_noise(result)
    final = result.final_set
    result.probes = residual_probes(final.model, final.fit, c)
    withdraw_projections(result)
    return result


def _lacks(baseline):
    """Return the library effects whose terms the ml baseline holds and ``baseline`` lacks."""
    return [name for name, effect in EFFECTS.items()
            if 'ml' in effect.in_baseline and baseline not in effect.in_baseline]


def _naming_power(result):
    """Simulate how large each tested effect not named must be for the workflow to name it."""
    names = [n for n in result.tested if n not in result.missing_effects]
    if not names or result.final_set is None:
        result.naming_power = {}
        return
    fits = result.session_fits
    # The scatter beyond the within-window level is simulated too: added to every window
    # when the null uses the scatter between windows or the gap stays open; when the noise
    # inside the windows is correlated (noise slower than a window may escape the level,
    # step 2) and the gap is within the noise, the noise is scaled to the final model's
    # own scatter (gap², at least 1).
    coloured = bool(result.window_noise.coloured)
    open_gap = result.noise_source == 'between windows' or not result.statistically_explained
    excess = result.excess_scatter() if open_gap else 0.0
    scale = max(1.0, result.gap_after ** 2) if coloured and not open_gap else 1.0
    extra = None
    lacking = _lacks(result.baseline)
    if lacking and (result.ml_check or {}).get('checked'):
        extra = np.hstack([fits._columns(result.final_set, EFFECTS[name].bind(fits.c))
                           for name in lacking])
    try:
        result.naming_power = calibrate_power(
            fits, result.final_set, names, coloured=coloured, excess=excess, ml_extra=extra,
            scale=scale)
    except (ValueError, np.linalg.LinAlgError):
        result.naming_power = None


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


def _confirm_with_ml(result, windows, search):
    """
    Name for a gn baseline only what the richer ml baseline also finds.

    The effect search is run with the ml baseline too (with gn's practical threshold, so
    that only the baseline differs). An effect gn names is kept when
    the ml search names it as well, or when it is a term ml holds and gn lacks
    (``Effect.in_baseline``: nonorthogonality) and the ml baseline's cross-axis terms are
    significant and large enough beside the effects the ml search names (a time effect must
    not be taken for cross-axis terms).
    An effect the ml baseline cannot test in this session (too few windows for its
    parameters beside ml's nine) is kept, and its step says so. When gn named something
    else, the gn search is run again over the confirmed effects only, and the rest is listed
    in ``unconfirmed`` with the reason.
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
    lacking = _lacks('gn')
    untested = {name: reason for name, reason in ml.skipped.items()
                if name not in lacking and name not in result.skipped}
    allowed = set(found) | set(untested)
    cross = _cross_axis_evidence(ml, search)
    if cross['significant']:
        allowed.update(lacking)
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
                      if name in lacking else
                      'not found with the ml baseline (it names '
                      + (', '.join(ml.missing_effects) or 'nothing') + ')')
            again.unconfirmed.append({'effect': name, 'reason': reason})
        result = again
    for step in result.steps:
        name = step['effect']
        step['confirmed'] = ('found with the ml baseline too' if name in found
                             else 'not checked with the ml baseline: ' + untested[name]
                             if name in untested
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
    F, p, bic = (float(v[0]) for v in support_stats(
        [fit_gn.chi2], [fit_ml.chi2], 3, fit_ml.dof, len(c.readings), ml.session_fits.nu))
    worst = 1000.0 * float(np.max(np.abs(T[np.triu_indices(3, 1)]) / np.diag(T)[[0, 0, 1]]))
    significant = bool(p < P_SUPPORT and bic > 0 and worst > ml.threshold_mg)
    return {'significant': significant, 'p': p, 'F': F, 'delta_bic': bic,
            'worst_case_mg': worst}


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
