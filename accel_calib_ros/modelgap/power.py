"""
A power figure that is true: the size at which the workflow names each library effect.

The gap test alone (``noise.min_detectable_mg``) says how large a systematic error makes
the gap exceed its null limit; naming an effect asks more (significance beside its rivals,
the practical threshold, the held-out check, the slow-noise check, the ml confirmation of
a gn baseline). So the naming itself is simulated, on the session's own design: its windows,
directions, temperatures and times, the noise of each window mean as measured (with the
noise level's own uncertainty, chi²_nu / nu, and the scatter beyond it when the null uses
the scatter between windows), and the model found, linearised about its fit (``Design``).
Each library effect not named is injected at a size (worst case in corrected acceleration,
mg) into ``REPLICATES`` replicates drawn by the effect itself (``Effect.simulate_shapes``:
a random direction of its parameters at one of its simulated bindings, e.g. a random time
constant for the lag; a Brownian path for the walk), and the selection's decision is
replayed on them with the same ``criterion`` as on the session, an effect's own
contradiction included (``Effect.replay_veto``: a walk too smooth to be one): the effect
counts as named when it wins the first round and passes the gates after it. The stated
size is the smallest of a ladder from the practical threshold up (factor ``LADDER``, one
bisection) where it is named in at least ``TARGET`` of the replicates. Vectorised over
replicates; seeded from the data, so the same session always gets the same figure.

What it leaves out: the later rounds (an injected effect alone is named in the first), the
still-data check of a drift, and the probes (they act only when the gap stays open), and
the linearisation (effects of a few percent of g); noise the within-window spectrum cannot
see is only there as the scatter between windows.
"""

import zlib

import numpy as np

from .criterion import (COLLINEAR, cv_folds, decide, evaluate, fold_maps, NoMap, P_SUPPORT,
                        RIVAL_BIC, support_stats, Trial)
from .effects import EFFECTS, G0
from .evidence import worst_case_mg
from .noise import null_gap_limit
from .probes import FAMILY
from .pruning import SLOW_FACTOR
from .result import NEGLIGIBLE_FACTOR
from .setfit import orthonormal

REPLICATES = 128
"""Simulated sessions per size."""

TARGET = 0.85
"""Share of the replicates that must name the effect at the stated size (80 % with margin)."""

LADDER = 2 ** 0.5
"""Sizes tried: the practical threshold times LADDER^j (twice the threshold at j = 2)."""

STEPS = 9
"""Most sizes on the ladder (up to LADDER^8 = 16 times the threshold)."""

LIMIT_STEP = 2
"""The ladder step at twice the threshold, where the verdict asks to be noticed."""

SIM_CONDITIONS = 8
"""Temperatures and times at which the worst case is evaluated in the simulation (the
extremes of each among them)."""

SIM_DIRECTIONS = 24
"""Directions spread over the sphere, and of the session's own, for the simulated worst case."""


class Binding:
    """One session-bound version of an effect as the linearised design sees it."""

    def __init__(self, design, effect):
        self.effect = effect
        self.cols = design.fits._columns(design.final, effect)          # (N, k)
        projected = self.cols - design.q @ (design.q.T @ self.cols)
        self.u = orthonormal(projected)
        self.pinv = np.linalg.pinv(projected)
        nested = [n for n in effect.nests if n in design.final.names]
        self.k = (len(effect.param_names) + effect.searched
                  - sum(design.final.k(n) for n in nested))
        self.coef_var = np.sum(self.pinv ** 2, axis=1)
        self._maps = self._worst = self._own = None
        self.memo = {}
        """What the effect's own methods keep between replays (``Effect.replay_veto``)."""
        self.design = design

    @property
    def maps(self):
        if self._maps is None:
            self._maps = fold_maps(np.hstack([self.design.q, self.u]), self.design.folds)
        return self._maps

    @property
    def worst(self):
        """
        Return what the effect's parameters change in corrected acceleration, (D, 3, k) mg.

        Its own error (-T^-1 columns) plus what the model it is added to takes up of it when
        refitted (``Design.absorbed``): the linear form of ``SessionFits.contribution``.
        """
        if self._worst is None:
            d = self.design
            self._worst = self.own - d.absorbed @ self.cols
        return self._worst

    @property
    def own(self):
        """
        Return the effect's own error per unit parameter, (D, 3, k) mg.

        ``worst`` without what the model takes up: the size is the smaller of the two, as
        in the fit (``SessionFits.size``).
        """
        if self._own is None:
            self._own = -self.design.grid.matrix(self.effect, full=True)
        return self._own

    def size_mg(self, params):
        """Return the size of parameters (R, k), mg: the smaller of ``worst`` and ``own``."""
        return np.minimum(worst_case_mg(self.worst, params), worst_case_mg(self.own, params))

    def joint_basis(self):
        """Return an orthonormal basis of the final model's columns and these, (N, p + k)."""
        return orthonormal(np.hstack([self.design.q, self.u]))


class Design:
    """
    The session's design, linearised about the final fit: what the selection sees.

    :param fits: setfit.SessionFits. :param final: the final SetFit.
    :param names: the library effects to simulate (applicable, not named).
    :param extra: (N, j) more baseline columns (the ml baseline's cross-axis terms).
    """

    def __init__(self, fits, final, names, extra=None, coloured=False):
        # nu: the criterion's pooling (as on the session); noise_dof: the noise level's own
        # uncertainty, drawn per replicate and in the null limit.
        self.fits, self.final, self.n, self.nu = fits, final, fits.n, fits.nu
        self.noise_dof = fits.noise_dof
        self.coloured = coloured
        self.grid = fits.power_grid(final, SIM_CONDITIONS, SIM_DIRECTIONS)
        self.absorbed = fits.absorbed(final, self.grid)
        self.threshold, self.folds = fits.threshold, fits.folds
        searched = sum(e.searched for e in final.bound.values())
        cols = final.fit.jac if extra is None else np.hstack([final.fit.jac, extra])
        self.q = orthonormal(cols)
        self.dof = self.n - self.q.shape[1] - searched
        self.base_maps = fold_maps(self.q, self.folds)
        self.limit = null_gap_limit(self.dof, self.noise_dof)
        self.names = list(names)
        self.testable = [n for n in names if self.dof - self._size(n) >= 2]
        self.options = {n: [Binding(self, b) for b in EFFECTS[n].simulated_bindings(fits.c)]
                        for n in self.names}
        self.stacks = {n: _stack(options) for n, options in self.options.items()}
        self.offset = fits._columns(final, _Offset())        # (N, 3): per unit offset
        self._mark_confounded()
        self.s = fits.noise_scale(final)             # the noise of each residual
        self.T_inv = np.linalg.inv(final.model.split(final.fit.x)[0])
        self.row_window = fits.row_window            # the window of each residual
        self.corr = self._correlations()

    def _mark_confounded(self):
        """
        Mark each binding confounded with a named effect (beyond the baseline alone).

        An effect that a named one can imitate in this session (signature correlation above
        ``COLLINEAR``) is not missing when present: the named one takes it up, and the
        result reports it as an alternative. The simulation injects only the others.
        """
        final = self.final
        base = orthonormal(final.fit.jac[:, :final.model.n_base])
        named = [orthonormal(self.fits._columns(final, final.bound[n]), base)
                 for n in final.names]
        self.confounded = {}
        for name, options in self.options.items():
            for b in options:
                own = orthonormal(b.cols, base)
                # Every direction of the effect imitated: its smallest canonical correlation.
                b.confounded = next(
                    (n for n, q in zip(final.names, named)
                     if 0 < own.shape[1] <= q.shape[1]
                     and np.linalg.svd(own.T @ q, compute_uv=False).min() > COLLINEAR), None)
            if all(b.confounded for b in options):
                self.confounded[name] = options[0].confounded

    def _size(self, name):
        options = EFFECTS[name].simulated_bindings(self.fits.c)
        return min(len(b.param_names) + b.searched for b in options)

    def _correlations(self):
        m = len(self.testable)
        corr = np.eye(m)
        mid = [self.options[n][len(self.options[n]) // 2].u for n in self.testable]
        for a in range(m):
            for b in range(a + 1, m):
                if mid[a].shape[1] and mid[b].shape[1]:
                    corr[a, b] = corr[b, a] = min(
                        np.linalg.svd(mid[a].T @ mid[b], compute_uv=False).max(), 1.0)
        return corr


class _Offset:
    """A constant offset per axis, as an effect's columns (a wander of the offset)."""

    param_names = ('x', 'y', 'z')
    searched = 0

    def columns(self, accel, temp, time, gravity):
        return np.broadcast_to(np.eye(3), (len(accel), 3, 3))


class Stack:
    """The bindings of one effect with one size, stacked for vectorised replays."""

    def __init__(self, options, idx):
        self.idx = idx
        self.options = [options[j] for j in idx]
        self.u = np.stack([b.u for b in self.options])             # (B, N, k)
        self._pinv = self._worst = self._maps = self._own = None

    @property
    def pinv(self):
        if self._pinv is None:
            self._pinv = np.stack([b.pinv for b in self.options])  # (B, k, N)
        return self._pinv

    @property
    def worst(self):
        if self._worst is None:
            self._worst = np.stack([b.worst for b in self.options])   # (B, D, 3, k)
        return self._worst

    @property
    def own(self):
        if self._own is None:
            self._own = np.stack([b.own for b in self.options])
        return self._own

    @property
    def maps(self):
        """Per fold, the held-out map of every binding (``criterion.FoldMap``; NaN: none)."""
        if self._maps is None:
            per = [b.maps for b in self.options]
            self._maps = [[m[f] if m[f] is not None else NoMap() for m in per]
                          for f in range(len(self.options[0].design.folds))]
        return self._maps


def _stack(options):
    """Return the bindings stacked by size: [Stack]."""
    groups = {}
    for j, b in enumerate(options):
        groups.setdefault(b.u.shape[1], []).append(j)
    return [Stack(options, np.array(idx)) for idx in groups.values()]


def _evidence_of(stack, pick, y, folds):
    """
    Return the fitted signal, held-out chi² per fold, parameters and worst case of replicates.

    :param pick: (R,) the binding of each replicate, an index into ``stack``.
    """
    signal = np.empty_like(y)
    cv = np.empty((len(y), len(folds)))
    params = np.empty((len(y), stack.u.shape[2]))
    worst = np.empty(len(y))
    for j in np.unique(pick):
        rows = np.flatnonzero(pick == j)
        u = stack.u[j]
        part = (y[rows] @ u) @ u.T
        signal[rows] = part
        rest = y[rows] - part
        for f, block in enumerate(folds):
            held = rest[:, block] @ stack.maps[f][j].T
            cv[rows, f] = np.where(np.all(np.isfinite(held), axis=1),
                                   np.sum(held ** 2, axis=1), np.inf)
        params[rows] = y[rows] @ stack.pinv[j].T
        worst[rows] = np.minimum(worst_case_mg(stack.worst[j], params[rows]),
                                 worst_case_mg(stack.own[j], params[rows]))
    return signal, cv, params, worst


def replay(design, y):
    """
    Replay the selection's first round on replicated residuals ``y`` (R, N).

    Every binding of every testable effect is scored at once (its chi²), the binding the
    search would take is picked, and the rest of a trial's evidence (size, held-out chi²,
    the effect's own contradiction, ``Effect.replay_veto``) is computed where the trial is
    significant: elsewhere it cannot be supported whatever its size.

    :returns: (winner index (R,), the trials, per trial its fitted signal (R, N), the
        residuals of the final model (R, N), the evidence of ``criterion.evaluate``).
    """
    q = design.q
    y = y - (y @ q) @ q.T
    base = np.sum(y ** 2, axis=1)
    base_cv = cv_folds(y, design.base_maps, design.folds)
    trials, fitted = [], []
    r_count = len(y)
    rows = np.arange(r_count)
    for name in design.testable:
        effect = EFFECTS[name]
        options = design.options[name]
        chi2 = np.empty((r_count, len(options)))
        for stack in design.stacks[name]:
            chi2[:, stack.idx] = base[:, None] - np.sum(
                np.einsum('rn,bnk->rbk', y, stack.u) ** 2, axis=2)
        k = np.array([b.k for b in options])
        # The binding the search would take (``Effect.search``: the residual explained,
        # less the choice's own BIC penalty for a choice of size).
        pick = np.argmin(chi2 + k[None, :] * np.log(design.n), axis=1)
        chosen = chi2[rows, pick]
        _, p, bic = support_stats(base, chosen, k[pick], design.dof - k[pick], design.n,
                                  design.nu)
        need = (p < P_SUPPORT) & (bic > 0)
        worst = np.zeros(r_count)
        cv = np.full((r_count, len(design.folds)), np.inf)
        veto = np.full(r_count, '', object)
        signal = np.zeros_like(y)
        for stack in design.stacks[name]:
            where = np.flatnonzero(need & np.isin(pick, stack.idx))
            if not len(where):
                continue
            local = np.searchsorted(stack.idx, pick[where])
            part, cv[where], params, worst[where] = _evidence_of(stack, local, y[where],
                                                                 design.folds)
            signal[where] = part
            # The contradictions the selection heard, replayed (none where the session's
            # fits hold no measurements: ``SessionFits.measured``, as on one still pose).
            reasons = None if design.fits.measured is None else \
                effect.replay_veto(stack, params, chosen[where], design)
            if reasons is not None:
                veto[where] = reasons
        trials.append(Trial(name, effect.variable, k[pick], chosen,
                            design.dof - k[pick], worst, cv, veto))
        fitted.append(signal)
    evidence = evaluate(base, base_cv, trials, design.n, design.nu, design.threshold)
    winner, _ = decide(evidence, trials, design.corr)
    return winner, trials, fitted, y, evidence


def _excess(rho, s, dof):
    """Return sigma_x² (R,): sum rho²/(s² + sigma_x²) = dof (0 when chi² <= dof), bisected."""
    low = np.zeros(len(rho))
    high = np.full(len(rho), 4.0 * float(np.max(np.mean(rho ** 2, axis=1))) + 1e-24)
    need = np.sum(rho ** 2 / s ** 2, axis=1) > dof
    for _ in range(40):
        mid = 0.5 * (low + high)
        over = np.sum(rho ** 2 / (s ** 2 + mid[:, None]), axis=1) > dof
        low = np.where(over, mid, low)
        high = np.where(over, high, mid)
    return np.where(need, 0.5 * (low + high), 0.0)


class Simulation:
    """
    The replicates for one effect: its shape, the noise draws; scaled to any size.

    :param design: Design. :param name: the effect. :param rng: Generator.
    :param excess: scatter per window beyond the measured noise to add, m/s² (0: none).
    :param scale: variance factor of the noise over the measured level (1: as measured).
    """

    def __init__(self, design, name, rng, excess=0.0, scale=1.0):
        self.design, self.name, self.excess = design, name, excess
        n, count = design.n, REPLICATES
        self.noise = rng.standard_normal((count, n)) * np.sqrt(scale)
        if np.isfinite(design.noise_dof):
            self.noise /= np.sqrt(rng.chisquare(max(design.noise_dof, 1.0), count)
                                  / max(design.noise_dof, 1.0))[:, None]
        if excess > 0:
            self.noise += rng.standard_normal((count, n)) * excess / design.s[None, :]
        self.shape = EFFECTS[name].simulate_shapes(design, rng, count)

    def named(self, size, ml=None):
        """
        Return the shares of replicates in which the effect of ``size`` mg is named, noticed.

        Named: the effect wins, or a confounded effect wins with it as the alternative the
        result reports (``criterion.rivals``: Occam named the simpler one); then the gates
        after the selection (slow noise) and, for gn, the ml confirmation. Noticed: named
        as anything, or the gap left beyond the null limit (the verdict is not "explained").
        """
        d = self.design
        y = self.noise + size * self.shape
        winner, trials, fitted, y_res, evidence = replay(d, y)
        rows = np.arange(len(y))
        w = np.maximum(winner, 0)
        if self.name in d.testable:
            index = d.testable.index(self.name)
            alternative = ((winner >= 0) & evidence['supported'][:, index]
                           & (d.corr[w, index] > COLLINEAR)
                           & (evidence['score'][:, index]
                              >= evidence['score'][rows, w] - RIVAL_BIC))
            hit = (winner == index) | alternative
        else:
            alternative = hit = np.zeros(len(y), bool)
        kept = np.ones(len(y), bool)
        if d.coloured:
            # Withdrawn as no larger than the slow noise's wander (``pruning``) when the
            # gap stays open beyond the null limit.
            for j in np.unique(winner[winner >= 0]):
                if FAMILY.get(EFFECTS[d.testable[j]].variable) not in ('time', 'temperature'):
                    continue
                idx = np.flatnonzero(winner == j)
                rest = y_res[idx] - fitted[j][idx]
                dof = float(np.mean(trials[j].dof))
                sx2 = _excess(rest * d.s, d.s[None, :], dof)
                sx2 = np.where(np.sum(rest ** 2, axis=1) / dof
                               > null_gap_limit(dof, d.noise_dof) ** 2,
                               sx2, 0.0)
                signal = np.sqrt(np.mean((fitted[j][idx] * d.s) ** 2, axis=1))
                kept[idx] = signal >= SLOW_FACTOR * np.sqrt(sx2)
        hit &= kept
        if ml is not None and self.name in ml.testable:
            ml_winner = replay(ml, y)[0]
            hit &= (ml_winner == ml.testable.index(self.name)) | alternative
        # The gap left open is a notice when the verdict would be "not explained": beyond
        # the null limit and not negligible (3 sigma_x above the threshold); under slow
        # noise (the scatter between windows is the null) it would read as that noise.
        chi2 = np.sum(y_res ** 2, axis=1)
        open_gap = chi2 / max(d.dof, 1) > d.limit ** 2
        if np.any(open_gap):
            sx = np.sqrt(_excess(y_res * d.s, d.s[None, :], max(d.dof, 1)))
            open_gap &= NEGLIGIBLE_FACTOR * 1000.0 * sx / G0 >= d.threshold
        noticed = ((winner >= 0) & kept) | (open_gap & (self.excess == 0))
        return float(np.mean(hit)), float(np.mean(noticed))


def _seed(design):
    data = np.ascontiguousarray(design.fits.c.readings).tobytes()
    return zlib.crc32(data) ^ zlib.crc32(design.fits.baseline.encode())


def _ladder(sim, threshold, ml):
    """
    Return the smallest sizes on the ladder at which the effect is named and noticed.

    Also the share noticed at ``LIMIT_STEP`` (twice the threshold; when the ladder stopped
    before it, the share at the last size tried, which is at least ``TARGET``).
    """
    sizes = threshold * LADDER ** np.arange(STEPS)
    rates = []
    for size in sizes:
        rates.append(sim.named(size, ml))
        if rates[-1][0] >= TARGET and rates[-1][1] >= TARGET:
            break
    out = {'rate_at_threshold': rates[0][0],
           'noticed_at_limit': rates[min(LIMIT_STEP, len(rates) - 1)][1]}
    for which, key in ((0, 'min_named_mg'), (1, 'min_noticed_mg')):
        first = next((j for j, r in enumerate(rates) if r[which] >= TARGET), None)
        found = None if first is None else (float(sizes[first]), rates[first][which])
        if first:
            middle = float(np.sqrt(sizes[first - 1] * sizes[first]))
            rate = sim.named(middle, ml)[which]
            if rate >= TARGET:
                found = (middle, rate)
        out[key] = found[0] if found else None
        out['rate' if which == 0 else 'noticed_rate'] = (found[1] if found
                                                         else rates[-1][which])
    return out


def calibrate_power(fits, final, names, coloured=False, excess=0.0, ml_extra=None, scale=1.0):
    """
    Return the naming power of each effect in ``names`` on this session's design.

    :param fits: setfit.SessionFits. :param final: the final SetFit.
    :param names: applicable library effects not named.
    :param coloured: the noise inside the windows is correlated (the slow-noise check acts).
    :param excess: scatter per window beyond the measured noise, m/s² (when the null uses
        the scatter between windows).
    :param scale: variance factor of the noise over the measured level (the final model's
        own scatter when the noise inside the windows is correlated).
    :param ml_extra: for a gn baseline, (N, j) columns of the terms ml holds and gn lacks
        (``Effect.in_baseline``: the cross-axis terms; the ml confirmation is replayed too),
        else None.
    :returns: dict name -> {'min_named_mg': size or None, 'rate': share named at it (as
        itself or as the alternative to a simpler confounded effect), 'min_noticed_mg' and
        'noticed_rate' (named as anything, or the gap left open), 'rate_at_threshold',
        'noticed_at_limit' (the share noticed at twice the threshold)}; or,
        for an effect a named one imitates in this session, {'confounded_with': name}.
    """
    design = Design(fits, final, names, coloured=coloured)
    ml = None
    if ml_extra is not None:
        ml = Design(fits, final, [n for n in names if 'ml' not in EFFECTS[n].in_baseline],
                    ml_extra)
    rng = np.random.default_rng(_seed(design))
    out = {}
    for name in names:
        if name in design.confounded:
            out[name] = {'min_named_mg': None, 'min_noticed_mg': None,
                         'confounded_with': design.confounded[name]}
            continue
        sim = Simulation(design, name, rng, excess, scale)
        out[name] = _ladder(sim, fits.threshold, ml)
    return out
