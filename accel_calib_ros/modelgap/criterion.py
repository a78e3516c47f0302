"""
The one criterion by which sets of library effects are compared.

Every comparison in the model selection is between two jointly fitted sets, one with and
one without some effects (``support``), or between sets of equal footing (``decide``):

- the variance of a normalised residual is the noise level measured inside the windows
  pooled with the larger model's chi² when that model fits (its gap within the noise), so
  that it is judged with all the degrees of freedom of both (never below its own
  chi²/dof); the model's own chi²/dof when it does not, so that a disagreement still
  unexplained is not taken for noise (``variance``);
- an added set of k parameters is supported when its nested F-test is significant
  (``P_SUPPORT``), its BIC gain ``delta_chi2 / v - k ln N`` is positive, its worst-case
  error exceeds the practical threshold, no measurement contradicts it, and, when the BIC
  gain is short of very strong evidence (``STRONG_BIC``), it also lowers the chi² of
  held-out windows (``cv_folds``, blocked in time);
- among supported candidates, the largest BIC gain wins; confounded candidates (signature
  correlation above ``COLLINEAR``) within ``TIE_BIC`` of it are decided by the held-out
  chi², and where that does not separate them either, by Occam: fewer parameters first,
  then a recorded cause (direction, temperature) before a catch-all in time, then the
  larger BIC gain.

The functions take arrays over replicates (R,), so that the power simulation
(``power``) replays exactly the decisions the workflow takes on the session (R = 1).
"""

import numpy as np
from scipy import stats

P_SUPPORT = 1e-3
"""Largest F-test p-value for which an added effect counts as supported."""

COLLINEAR = 0.9
"""Two candidates whose signatures correlate more than this are confounded in the session."""

TIE_BIC = 6.0
"""BIC gains closer than this are a tie: short of strong evidence (Kass & Raftery: 6)."""

STRONG_BIC = 10.0
"""A BIC gain beyond this is very strong evidence; below it, held-out windows must agree."""

RIVAL_BIC = 10.0
"""A confounded runner-up within this of the winner's BIC gain is reported as an alternative."""

VARIABLE_RANK = {'direction': 0, 'magnitude': 0, 'temperature': 0, 'time': 1}
"""Occam's order among equally simple tied candidates: a recorded cause (direction,
temperature) before a catch-all in time; between recorded causes, the larger BIC gain."""

CV_FOLDS = 10
"""Held-out folds (blocks of consecutive windows in time); fewer windows: leave one out."""


def variance(chi2, dof, nu):
    """
    Return the variance of a normalised residual and the degrees of freedom of its estimate.

    When the model's own chi²/dof is within what noise gives (its F(dof, nu) law, or chi²
    for a known noise level, at ``P_SUPPORT``), the model fits: the measured noise level is
    pooled with it, (chi² + nu) / (dof + nu), with dof + nu degrees of freedom (1 and inf
    for a known level), but never below the model's own chi²/dof (a scatter from a few
    degrees of freedom that happens to be high is not pooled away). Otherwise a
    disagreement is still unexplained and is not taken for noise: chi²/dof with dof degrees
    of freedom. nu = 0 pools nothing.

    :param chi2: (R,) chi² of the model. :param dof: its degrees of freedom (scalar or (R,)).
    :param nu: noise level's degrees of freedom (inf: known).
    :returns: (variance (R,), degrees of freedom (R,)).
    """
    chi2 = np.asarray(chi2, float)
    dof = np.maximum(np.asarray(dof, float), 1.0) * np.ones_like(chi2)
    own = chi2 / dof
    if np.isfinite(nu):
        fits = stats.f.sf(own, dof, max(nu, 1.0)) >= P_SUPPORT
        pooled = (chi2 + nu) / (dof + nu)
    else:
        fits = stats.chi2.sf(chi2, dof) >= P_SUPPORT
        pooled = np.ones_like(own)
    return np.where(fits, np.maximum(pooled, own), own), np.where(fits, dof + nu, dof)


def support_stats(chi2_without, chi2_with, k, dof_with, n, nu):
    """
    Return (F, p, delta_bic) of k parameters that lower chi² from one model to another.

    From ``chi2_without`` to ``chi2_with``, arrays over replicates (``k`` and ``dof_with``
    may be too). ``delta_bic`` is the BIC
    gain with the variance of ``variance``: delta_chi2 / v - k ln n (the Gaussian BIC at that
    variance).
    """
    v, dof_v = variance(chi2_with, dof_with, nu)
    k = np.maximum(np.asarray(k, float), 1.0)
    drop = np.maximum(np.asarray(chi2_without, float) - np.asarray(chi2_with, float), 0.0)
    F = drop / k / v
    finite = np.isfinite(dof_v)
    p = np.where(finite, stats.f.sf(F, k, np.where(finite, dof_v, 1.0)),
                 stats.chi2.sf(drop / v, k))
    return F, p, drop / v - k * np.log(n)


def make_folds(time):
    """Return the held-out folds: blocks of consecutive windows in time (or single windows)."""
    n = len(time)
    order = np.argsort(time, kind='stable')
    if n < 3 * CV_FOLDS:
        return [order[i:i + 1] for i in range(n)]
    return [np.sort(block) for block in np.array_split(order, CV_FOLDS)]


class FoldMap:
    """
    The map (I - q qᵀ)⁻¹ = I + q (I - qᵀ q)⁻¹ qᵀ of one fold, applied without forming it.

    ``r @ m`` (or ``r @ m.T``: it is symmetric) for rows ``r`` (R, b) costs O(R b p) and the
    map O(b p) memory: a long still recording's folds hold hundreds of bins.
    """

    __slots__ = ('q', 'k')
    __array_ufunc__ = None          # ndarray @ FoldMap defers to __rmatmul__

    def __init__(self, q, k):
        self.q, self.k = q, k

    @property
    def T(self):                    # noqa: N802 - numpy's name
        return self

    def __rmatmul__(self, r):
        return r + (r @ self.q) @ self.k


class NoMap:
    """The map of a fold the others cannot predict: every held-out residual NaN."""

    __array_ufunc__ = None

    @property
    def T(self):                    # noqa: N802 - numpy's name
        return self

    def __rmatmul__(self, r):
        return np.full(np.shape(r), np.nan)


def fold_maps(basis, folds):
    """
    Return, per fold, the map from a fitted residual to the held-out one, (I - H_BB)^-1.

    ``basis`` (N, p) orthonormal columns the model can fit (its Jacobian's span); H its
    hat matrix. For a linear model the residual of fold B predicted from the others is
    (I - H_BB)^-1 r_B exactly (a :class:`FoldMap`); a fold the others cannot predict (H_BB
    near 1) gets None.
    """
    maps = []
    for block in folds:
        q = basis[block]
        # I - q qᵀ has the eigenvalues 1 - s² of q's singular values s (and 1): its inverse
        # is I + q (I - qᵀ q)⁻¹ qᵀ (Woodbury), a p x p solve instead of a b x b one.
        gram = q.T @ q
        s2 = np.linalg.eigvalsh(gram) if gram.size else np.zeros(0)
        least = min(1.0 - float(s2.max()) if s2.size else 1.0,
                    1.0 if len(block) > q.shape[1] else float(1.0 - s2.min()))
        if least < 1e-6:
            maps.append(None)
        else:
            maps.append(FoldMap(q, np.linalg.solve(np.eye(q.shape[1]) - gram, q.T)))
    return maps


def cv_folds(residuals, maps, folds):
    """
    Return the held-out chi² of each fold, (R, K) (or (K,) for one residual vector).

    :param residuals: (R, N) or (N,) fitted normalised residuals.
    """
    r = np.atleast_2d(residuals)
    out = np.empty((len(r), len(folds)))
    for j, (block, m) in enumerate(zip(folds, maps)):
        out[:, j] = np.inf if m is None else np.sum((r[:, block] @ m.T) ** 2, axis=1)
    return out if np.ndim(residuals) > 1 else out[0]


def cv_better(cv_with, cv_without):
    """Tell (R,) whether the held-out chi² with the effect is lower than without it."""
    a = np.atleast_2d(cv_with)
    b = np.atleast_2d(cv_without)
    return np.sum(a, axis=1) < np.sum(b, axis=1)


def cv_tied(cv_a, cv_b):
    """Tell whether two held-out chi² per fold (K,) differ by less than twice their paired SE."""
    with np.errstate(invalid='ignore'):
        d = np.asarray(cv_a, float) - np.asarray(cv_b, float)
    if not np.all(np.isfinite(d)):
        return True
    se = np.sqrt(len(d)) * float(np.std(d, ddof=1)) if len(d) > 1 else 0.0
    return abs(float(np.sum(d))) <= 2.0 * se


class Trial:
    """
    One candidate effect added to the current set, over R replicates.

    :param name: library name. :param variable: its ``Effect.variable``.
    :param k: parameters it adds, searched ones included (scalar or (R,)).
    :param chi2: (R,) chi² of the set with it. :param dof: that set's degrees of freedom
        (scalar or (R,)).
    :param worst: (R,) worst-case error of the fitted effect, mg.
    :param cv: (R, K) held-out chi² per fold of the set with it.
    :param veto: (R,) '' or the reason a measurement contradicts it (still data, roughness).
    """

    def __init__(self, name, variable, k, chi2, dof, worst, cv, veto):
        self.name, self.variable = name, variable
        self.chi2 = np.atleast_1d(np.asarray(chi2, float))
        self.k = np.broadcast_to(np.asarray(k, int), self.chi2.shape)
        self.dof = np.broadcast_to(np.asarray(dof, int), self.chi2.shape)
        self.worst = np.atleast_1d(np.asarray(worst, float))
        self.cv = np.atleast_2d(cv)
        self.veto = np.atleast_1d(np.asarray(veto, object))


def evaluate(base_chi2, base_cv, trials, n, nu, threshold):
    """
    Return each trial's evidence over replicates: F, p, BIC gain, the gates, supported.

    :param base_chi2: (R,) chi² of the current set. :param base_cv: (R, K) its held-out chi².
    :returns: dict of (R, m) arrays 'F', 'p', 'bic', 'significant', 'large', 'held',
        'vetoed', 'supported', and 'score', the BIC gains on one scale for ranking (the
        variance of the best-fitting trial: ``bic`` uses each trial's own, for its gate).
    """
    cols = {key: [] for key in ('F', 'p', 'bic', 'significant', 'large', 'held', 'vetoed')}
    for t in trials:
        F, p, bic = support_stats(base_chi2, t.chi2, t.k, t.dof, n, nu)
        cols['F'].append(F)
        cols['p'].append(p)
        cols['bic'].append(bic)
        cols['significant'].append((p < P_SUPPORT) & (bic > 0))
        cols['large'].append(t.worst > threshold)
        cols['held'].append((bic >= STRONG_BIC) | cv_better(t.cv, base_cv))
        cols['vetoed'].append(np.array([bool(v) for v in t.veto]))
    empty = {key: np.zeros((len(base_chi2), 0), float if key in ('F', 'p', 'bic') else bool)
             for key in cols}
    out = {key: np.column_stack(value) if value else empty[key]
           for key, value in cols.items()}
    out['supported'] = (out['significant'] & out['large'] & out['held'] & ~out['vetoed'])
    # Candidates are ranked on one scale: the variance of the best-fitting one.
    if trials:
        chi2 = np.column_stack([t.chi2 for t in trials])
        best = np.argmin(chi2, axis=1)
        rows = np.arange(len(chi2))
        dof = np.column_stack([t.dof for t in trials])[rows, best]
        v, _ = variance(chi2[rows, best], dof, nu)
        k = np.column_stack([t.k for t in trials])
        out['score'] = ((np.asarray(base_chi2, float)[:, None] - chi2) / v[:, None]
                        - k * np.log(n))
    else:
        out['score'] = out['bic']
    return out


def decide(evidence, trials, corr):
    """
    Return the winning trial per replicate (index, -1 for none) and the ties it settled.

    The largest BIC gain among supported trials wins; confounded supported trials
    (``corr`` > ``COLLINEAR``) within ``TIE_BIC`` of it are a tie, settled by the held-out
    chi² when it separates them (``cv_tied``), else by Occam (``occam_key``).

    :param corr: (m, m) signature correlations of the trials in this session.
    :returns: (winner (R,), tie (R,) bool: a tie was settled).
    """
    bic = np.where(evidence['supported'], evidence['score'], -np.inf)
    if not bic.shape[1]:
        return np.full(len(bic), -1), np.zeros(len(bic), bool)
    best = np.argmax(bic, axis=1)
    winner = np.where(np.isfinite(bic[np.arange(len(bic)), best]), best, -1)
    tie = np.zeros(len(bic), bool)
    close = (bic >= bic[np.arange(len(bic)), best][:, None] - TIE_BIC) & np.isfinite(bic)
    for r in np.flatnonzero((winner >= 0) & (close.sum(axis=1) > 1)):
        group = [j for j in np.flatnonzero(close[r])
                 if j == best[r] or corr[j, best[r]] > COLLINEAR]
        if len(group) < 2:
            continue
        tie[r] = True
        cv = {j: trials[j].cv[min(r, len(trials[j].cv) - 1)] for j in group}
        lowest = min(group, key=lambda j: float(np.sum(cv[j])))
        still = [j for j in group if j == lowest or cv_tied(cv[j], cv[lowest])]
        winner[r] = min(still, key=lambda j: occam_key(trials[j], bic[r, j], r))
    return winner, tie


def occam_key(trial, bic, r=0):
    """Return the sort key of Occam's rule: fewer parameters, a recorded cause, then BIC."""
    return (int(trial.k[r]), VARIABLE_RANK.get(trial.variable, 3), -bic)


def rivals(evidence, trials, corr, winner, r=0):
    """Return the supported trials confounded with the winner and within ``RIVAL_BIC`` of it."""
    if winner < 0:
        return []
    bic = evidence['score'][r]
    return [j for j in range(len(trials))
            if j != winner and evidence['supported'][r, j] and corr[j, winner] > COLLINEAR
            and bic[j] >= bic[winner] - RIVAL_BIC]
