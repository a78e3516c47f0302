"""
Measurements that contradict an effect as fitted: the still data, a random walk's roughness.

Neither compares two effects: each asks whether one fitted effect is what its own physics
says it is. ``still_contradicts``: a fitted linear drift against the drift the still
windows show directly (``still_drift``). ``walk_too_smooth``: a fitted random walk whose
smooth terms leave a residual far smoother than a random walk of that size would.
``best_step`` is the single jump in time that ``pruning`` checks a time effect against
when the gap is not closed.
"""

import numpy as np
from scipy import stats

from .criterion import P_SUPPORT
from .effects import G0
from .noise import RAMP_TEMP_C
from .probes import delta_bic


def walk_design(basis, offset_jac, time, start):
    """
    Return what a random walk's rough part does to the residuals of a fit that holds its terms.

    A walk of K_i per √s on axis i has covariance K_i² min(t_a - t0, t_b - t0) between
    windows; seen along gravity and with what the fit absorbs (its Jacobian's span, the
    walk's smooth terms included) projected out, it adds A_i = P (J_i J_iᵀ ∘ M) P per
    unit K_i² to the residual covariance.

    :param basis: (N, p) orthonormal basis of the fit's Jacobian.
    :param offset_jac: (N, 3) change of the normalised residuals per unit offset per axis.
    :param time: (N,) window times, s. :param start: the walk's start, s.
    :returns: (tr A_i (3,), tr A_i A_j (3, 3), residual dof).
    """
    n = len(time)
    p = np.eye(n) - basis @ basis.T
    m = np.minimum.outer(time - start, time - start)
    a = [p @ (np.outer(offset_jac[:, i], offset_jac[:, i]) * m) @ p for i in range(3)]
    traces = np.array([np.trace(x) for x in a])
    cross = np.array([[np.sum(x * y) for y in a] for x in a])
    return traces, cross, float(np.trace(p))


def walk_rate_low(coef, coef_var, factors):
    """
    Return a 99.9 % lower bound of K_i² per axis from a walk's fitted cosine terms, (R, 3).

    A walk of K per √s gives each cosine coefficient a variance K² f_k
    (``BiasRandomWalk.brownian``: about 2 T / (k pi)²): each fitted coefficient, less its
    own estimation variance, over f_k estimates K²; their mean over the 3d terms, times
    3d / chi²_3d(0.999), bounds K² from below.

    :param coef: (R, 3, d) fitted coefficients. :param coef_var: their variances, same shape
        or broadcastable. :param factors: (d,) the f_k.
    """
    d = coef.shape[-1]
    k2 = np.mean(np.maximum(coef ** 2 - coef_var, 0.0) / factors, axis=-1)
    return k2 * (3 * d) / stats.chi2.ppf(1.0 - P_SUPPORT, 3 * d)


def walk_smoothness_p(chi2, k2, design, nu):
    """
    Return P(chi² this low | the fitted walk is a random walk), (R,).

    The walk's rough part (what its smooth terms cannot follow) adds sum_i K_i² A_i to the
    residual covariance (``walk_design``); chi² then has mean dof + sum K_i² tr A_i and the
    variance of a quadratic form in Gaussians (plus what the noise level's own uncertainty
    adds), matched to a scaled chi² (Satterthwaite). A wander whose terms leave a residual at
    the noise level while its size says it should be rough was not a walk: it followed a
    smooth dependence (another effect's leftovers).
    """
    traces, cross, dof = design
    k2 = np.atleast_2d(k2)
    mean = dof + k2 @ traces
    var = 2.0 * (dof + 2.0 * k2 @ traces + np.einsum('ri,ij,rj->r', k2, cross, k2))
    if np.isfinite(nu):
        var = var + 2.0 * dof ** 2 / max(nu, 1.0)
    scale = var / (2.0 * mean)
    return stats.chi2.cdf(np.asarray(chi2, float) / scale, 2.0 * mean ** 2 / var)


def walk_too_smooth(model, fit, c, basis, nu):
    """
    Return why a fitted bias_random_walk is not a random walk, or ''.

    See ``walk_smoothness_p``: too smooth at p < ``P_SUPPORT``.
    """
    walk = model.objects['bias_random_walk']
    T, _, params = model.split(fit.x)
    coef = walk.cosines(params['bias_random_walk'])
    index = model.index('bias_random_walk')
    cov = np.linalg.pinv(fit.jac.T @ fit.jac)
    coef_var = walk.cosines(np.diag(cov)[index:index + len(walk.param_names)])
    k2 = walk_rate_low(coef[None], coef_var[None], walk.brownian(c.time)[0])
    a = model.true_accel(fit.x, c)
    along = np.linalg.solve(T.T, (a / np.linalg.norm(a, axis=1)[:, None]).T).T
    s = np.sqrt(np.sum((along * c.sigma) ** 2, axis=1))
    design = walk_design(basis, -along / s[:, None], c.time, walk.start)
    p = float(walk_smoothness_p([fit.chi2], k2, design, nu)[0])
    if p >= P_SUPPORT:
        return ''
    rate = 1000.0 * np.sqrt(np.max(k2)) / G0 / np.max(np.abs(np.diag(T)))
    expected = design[2] + float((k2 @ design[0])[0])
    return (f'too smooth for a random walk: a walk of at least {rate:.2g} mg/√s (the 99.9 % '
            f'lower bound from its fitted terms) would leave chi² about {expected:.0f} beyond '
            f'its smooth terms, but {fit.chi2:.0f} is left (p = {p:.1e}): its terms follow a '
            'smooth dependence, not a wander')


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


def still_contradicts(model, fit, name, still):
    """
    Return why the still windows contradict a fitted linear drift, or ''.

    The drift the still windows show (``still_drift``: the slope of the readings inside
    windows whose temperature held steady) against the fitted one, each with its
    covariance: chi² with 3 degrees of freedom, contradicted below ``P_SUPPORT``.
    """
    params = model.split(fit.x)[2][name]
    k = len(params)
    index = model.index(name)
    cov = (np.linalg.pinv(fit.jac.T @ fit.jac)[index:index + k, index:index + k]
           * max(fit.gap ** 2, 1.0))
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
