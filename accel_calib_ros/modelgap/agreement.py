"""
Does a supported effect agree with all the evidence? The still data, the probes, its rivals.

``disagreement`` gives the reason a candidate is not named (or ''): a probe of another
variable that explains the disagreement better, a temperature that a time effect only
follows, the drift the still data show (``still_drift``), a single jump in time, the
lag's two-term confounder, a straight drift before a wander.
"""

import numpy as np
from scipy import stats

from .effects import EFFECTS, G0
from .model import fit_model
from .noise import RAMP_TEMP_C
from .probes import added_on_top, delta_bic, FAMILY, residual_probes

P_SUPPORT = 1e-3
"""Largest F-test p-value for which an added effect counts as supported."""

COLLINEAR = 0.9
"""Supported runner-up whose signature correlates more than this with the winner's is a rival."""


def disagreement(cand, alternatives, model, fit, c, still):
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
        reason = still_contradicts(cand, still)
        if reason:
            return reason
    step = best_step(model, fit, c)
    if step and step['delta_bic'] > cand['bic']:
        on_top = added_on_top(fit.residuals, fit.chi2, fit.dof, step['basis'], j)
        if on_top >= P_SUPPORT:
            return (f'a single jump in time at t = {step["time"]:+.0f} s (about '
                    f'{step["size_mg"]:.2g} mg RMS; the mount shifting?) explains the '
                    'disagreement '
                    f'better (ΔBIC {step["delta_bic"]:.0f} against {cand["bic"]:.0f}) than '
                    f'{name}, which adds nothing beside it (p = {on_top:.2g})')
    return ''


def lag_against_pair(cand, tried, model, fit, c):
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


def walk_against_drift(cand, tried, model, fit, c):
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


def best_step(model, fit, c):
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


def still_contradicts(cand, still):
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
