"""
Joint fits of sets of library effects to one session: the candidates of the selection.

``SessionFits.fit(names)`` fits the baseline plus every effect in ``names`` together, with
the searched parameters (the lag's time constant, the walk's number of terms) chosen again
for that set: first on the residuals of the set without them, linearised (cheap: every
binding is one projection), then, for a continuous parameter, once more about the joint
fit itself (the effect's own contribution swapped for another binding), so that an effect
is never judged against another one's stale parameter. Fits are cached by set.
"""

from dataclasses import dataclass, field

import numpy as np

from .criterion import cv_folds, fold_maps, make_folds, Trial
from .effects import EFFECTS, G0
from .evidence import effect_worst_case_mg, WorstGrid
from .model import Conditions, fit_model, Model

RANK_TOL = 1e-9
"""Singular values below this share of the largest are not columns (a degenerate binding)."""


def orthonormal(cols, against=None, tol=RANK_TOL):
    """Return an orthonormal basis of ``cols`` (N, k) after projecting out ``against``."""
    if against is not None and against.shape[1]:
        cols = cols - against @ (against.T @ cols)
    if not cols.shape[1]:
        return cols
    u, sv, _ = np.linalg.svd(cols, full_matrices=False)
    return u[:, sv > tol * max(sv.max(), 1e-300)] if sv.size else u[:, :0]


def added(names, name):
    """Return (the set ``names`` with ``name`` added, less what it contains; what it replaced)."""
    replaced = [n for n in names if n in EFFECTS[name].nests]
    return [n for n in names if n not in replaced] + [name], replaced


@dataclass
class SetFit:
    """One set of library effects fitted jointly to the session."""

    names: tuple                 # library names, in library order
    bound: dict                  # name -> session-bound Effect
    model: Model
    fit: object                  # model.Fit (dof counts the searched parameters)
    _worst: dict = field(default_factory=dict, repr=False)
    _cv: object = field(default=None, repr=False)
    _basis: object = field(default=None, repr=False)
    _along: object = field(default=None, repr=False)

    @property
    def chi2(self):
        return self.fit.chi2

    @property
    def dof(self):
        return self.fit.dof

    @property
    def gap(self):
        return self.fit.gap

    def params(self, name):
        """Return the fitted parameters of effect ``name``."""
        return self.model.split(self.fit.x)[2][name]

    def k(self, name):
        """Return the parameters effect ``name`` costs, searched ones included."""
        effect = self.bound[name]
        return len(effect.param_names) + effect.searched

    @property
    def basis(self):
        """Return an orthonormal basis of the fit's Jacobian, (N, p)."""
        if self._basis is None:
            self._basis = orthonormal(self.fit.jac)
        return self._basis


class SessionFits:
    """
    Joint fits of sets of effects to one session, cached by set.

    :param baseline: 'ml' or 'gn'. :param c: model.Conditions.
    :param start: baseline parameter vector to start from.
    :param threshold: practical threshold, mg.
    :param nu: degrees of freedom of the noise level the criterion pools with a model that
        fits (``criterion.variance``): the measured noise level's; 0 when the noise inside
        the windows is correlated, since noise slower than a window then escapes it and
        only the model's own residual scatter can be trusted.
    :param noise_dof: the measured noise level's degrees of freedom (default ``nu``).
    :param measured: ``effect.Measurements`` of the session, which can contradict an effect
        as fitted (``Effect.contradiction``: the still data, a walk's roughness); None: none.
    """

    def __init__(self, baseline, c, start, threshold, nu, measured=None, noise_dof=None):
        self.baseline, self.c, self.threshold, self.nu = baseline, c, threshold, nu
        self.noise_dof = nu if noise_dof is None else noise_dof
        self.n = len(c.readings)
        self.measured = measured
        self.folds = make_folds(c.time)
        self.candidates = []
        self._grid = None
        self.cache = {}
        model, fit = fit_model(baseline, [], c, start)
        self.cache[frozenset()] = SetFit((), {}, model, fit)
        self.order = list(EFFECTS)

    # -- fitting ------------------------------------------------------------------------

    def fit(self, names):
        """Return the joint fit of the baseline plus effects ``names`` (cached)."""
        key = frozenset(names)
        if key in self.cache:
            return self.cache[key]
        names = tuple(n for n in self.order if n in key)
        free = [n for n in names if len(EFFECTS[n].bindings(self.c)) > 1]
        fixed = tuple(n for n in names if n not in free)
        if free:
            ref = self.fit(fixed)
            bound = {n: ref.bound[n] for n in fixed}
            bound.update(self._profile(ref, free))
        else:
            ref = self._nearest(names)
            bound = {n: ref.bound.get(n) or EFFECTS[n].bind(self.c) for n in names}
        setfit = self._full(names, bound, ref)
        if setfit is None:
            return None
        if any(bound[n].continuous_search for n in free):
            setfit = self._swap_profile(setfit, ref)
        self.cache[key] = setfit
        return setfit

    def _nearest(self, names):
        """Return the cached fit of the largest subset of ``names`` (a warm start)."""
        best = self.cache[frozenset()]
        for key, setfit in self.cache.items():
            if setfit is not None and key <= set(names) and len(key) > len(best.names):
                best = setfit
        return best

    def _full(self, names, bound, ref):
        """Fit the set with these bindings by least squares, from ``ref``'s parameters."""
        effects = [bound[n] for n in names]
        T, bias, params = ref.model.split(ref.fit.x)
        model = Model(self.baseline, effects)
        start = np.concatenate([model.pack_baseline(T, bias)] + [
            params[n] if n in params and len(params[n]) == len(bound[n].param_names)
            else np.zeros(len(bound[n].param_names)) for n in names])
        try:
            model, fit = fit_model(self.baseline, effects, self.c, start)
        except (ValueError, np.linalg.LinAlgError):
            return None
        fit.dof -= sum(e.searched for e in effects)
        return SetFit(names, dict(bound), model, fit)

    def _columns(self, setfit, effect):
        """
        Return d(normalised residual)/d(params) of a bound effect at ``setfit``'s solution.

        The change of |a| per unit parameter is -n^T T^-1 columns (as
        ``Model.effect_jacobian``, but for any binding, also one the model holds another of).
        """
        if setfit._along is None:
            x = setfit.fit.x
            T = setfit.model.split(x)[0]
            a = setfit.model.true_accel(x, self.c)
            along = np.linalg.solve(T.T, (a / np.linalg.norm(a, axis=1)[:, None]).T).T
            s = np.sqrt(np.sum((along * self.c.sigma) ** 2, axis=1))
            setfit._along = (a, along / s[:, None])
        a, along = setfit._along
        cols = effect.columns(a, self.c.temp, self.c.time, self.c.gravity)
        return -np.einsum('ni,nik->nk', along, cols)

    def _profile(self, ref, free):
        """
        Choose the bindings of the searched effects on ``ref``'s residuals (linearised).

        Each searched effect in turn keeps the binding whose columns, with the others' at
        their current binding, explain the most of the residual (``Effect.search``, which
        adds its own penalty for a choice of size); two passes when two are searched.
        """
        q = ref.basis
        r = ref.fit.residuals
        current = {}
        for name in free:
            smaller = [s for key, s in self.cache.items()
                       if s is not None and name in key and key <= set(ref.names) | set(free)]
            current[name] = (max(smaller, key=lambda s: len(s.names)).bound[name] if smaller
                             else EFFECTS[name].bindings(self.c)[len(
                                 EFFECTS[name].bindings(self.c)) // 2])
        for _ in range(2 if len(free) > 1 else 1):
            for name in free:
                others = [self._columns(ref, current[o]) for o in free if o != name]

                def explained(bound, others=others):
                    u = orthonormal(np.hstack(others + [self._columns(ref, bound)]), q)
                    return float(np.sum((u.T @ r) ** 2))
                current[name] = EFFECTS[name].search(self.c, explained)
        return current

    def _swap_profile(self, setfit, ref, passes=2):
        """
        Re-choose continuous searched parameters (the lag's tau) about the joint fit.

        Linearised about the joint fit, changing tau swaps the lag's columns: the residual
        without the lag is r - J(tau) c, and each other tau is scored by what [the other
        columns, J(tau')] leave of it. The best is refitted when it lowers the chi²; each
        effect with a continuous search (``Effect.continuous_search``) in turn, until a pass
        moves none.
        """
        for _ in range(passes):
            moved = False
            for name in [n for n in setfit.names if setfit.bound[n].continuous_search]:
                trial = self._swap(setfit, name)
                if trial is not None:
                    setfit, moved = trial, True
            if not moved:
                return setfit
        return setfit

    def _swap(self, setfit, name):
        """Return ``setfit`` refitted with ``name``'s binding re-chosen, or None (no better)."""
        model, fit = setfit.model, setfit.fit
        k = model.n_base
        for n in setfit.names:
            if n == name:
                break
            k += len(setfit.bound[n].param_names)
        size = len(setfit.bound[name].param_names)
        rest = np.delete(fit.jac, np.s_[k:k + size], axis=1)
        q = orthonormal(rest)
        cols = self._columns(setfit, setfit.bound[name])
        r = fit.residuals - cols @ fit.x[k:k + size]
        r = r - q @ (q.T @ r)

        def explained(bound, q=q, r=r):
            u = orthonormal(self._columns(setfit, bound), q)
            return float(np.sum((u.T @ r) ** 2))
        new = EFFECTS[name].search(self.c, explained)
        if setfit.bound[name].same_binding(new):
            return None
        bound = dict(setfit.bound)
        bound[name] = new
        trial = self._full(setfit.names, bound, setfit)
        if trial is None or trial.chi2 >= setfit.chi2:
            return None
        return trial

    # -- what the selection asks ------------------------------------------------------------

    def veto(self, name, setfit):
        """Return why a measurement contradicts effect ``name`` as fitted in ``setfit``, or ''."""
        if self.measured is None:
            return ''
        return setfit.bound[name].contradiction(setfit, self.measured)

    def worst(self, setfit, name):
        """Return the worst-case error of effect ``name`` as fitted in ``setfit``, mg."""
        if name not in setfit._worst:
            setfit._worst[name] = effect_worst_case_mg(
                setfit.model, setfit.fit.x, self.c, name, setfit.params(name))
        return setfit._worst[name]

    def size(self, full, without, name):
        """
        Return the size of effect ``name`` for the practical threshold, mg.

        The smaller of its own worst case (``worst``) and what it changes beside the others
        (``contribution``): it matters only when both exceed the threshold. The first alone
        is inflated when two nearly collinear effects carry large opposite parameters; the
        second alone when the baseline is poorly determined in directions the session did
        not hold (its shift there is not the effect).
        """
        return min(self.worst(full, name), self.contribution(full, without))

    def contribution(self, full, without):
        """
        Return how much a set changes the corrected acceleration over another, worst case, mg.

        Readings that follow ``full`` (every direction of ``WorstGrid``, every temperature
        and time of the session), corrected by ``without`` (refitted without the effect):
        the largest |a - g n|. What an effect adds beside the others, with what they and the
        baseline take up when it is left out; two nearly collinear effects with large
        opposite parameters add only what their sum changes.
        """
        key = ('contribution', without.names)
        if key not in full._worst:
            grid = self.grid
            n_dir, n_cond = len(grid.dirs), len(grid.conds)
            dirs = np.repeat(grid.dirs, n_cond, axis=0)
            cond = np.tile(grid.conds, (n_dir, 1))
            c = self.c
            at = Conditions(np.zeros_like(dirs), np.ones_like(dirs), cond[:, 0], cond[:, 1],
                            c.gravity, c.temp_span, c.time_span)
            at.readings = full.model.predict(full.fit.x, dirs, at)
            a = without.model.true_accel(without.fit.x, at)
            err = np.linalg.norm(a - c.gravity * dirs, axis=1)
            full._worst[key] = 1000.0 * float(np.max(err)) / G0
        return full._worst[key]

    # -- the geometry the power simulation asks for (``power.Design``) -------------------

    @property
    def row_window(self):
        """Return the window each residual belongs to, (N,): one residual per window."""
        return np.arange(self.n)

    def noise_scale(self, setfit):
        """Return the noise of each residual, m/s²: each window mean's along gravity."""
        x = setfit.fit.x
        a = setfit.model.true_accel(x, self.c)
        along = np.linalg.solve(setfit.model.split(x)[0].T,
                                (a / np.linalg.norm(a, axis=1)[:, None]).T).T
        return np.sqrt(np.sum((along * self.c.sigma) ** 2, axis=1))

    def power_grid(self, setfit, conditions, directions):
        """Return the worst-case grid of the naming simulation (``evidence.WorstGrid``)."""
        return WorstGrid(setfit.model, setfit.fit.x, self.c, conditions, directions, directions)

    def absorbed(self, setfit, grid):
        """
        Return what the model takes up of a residual, in corrected acceleration, (D, 3, N).

        Readings on the worst-case grid that follow the model; d(corrected acceleration)/
        d(parameters) by differences, times the least-squares map from a residual to the
        parameters' change (the pseudo-inverse of the fit's Jacobian), mg.
        """
        c = self.c
        dirs, temp, time = grid.rows()
        at = Conditions(np.zeros_like(dirs), np.ones_like(dirs), temp, time, c.gravity,
                        c.temp_span, c.time_span)
        x = setfit.fit.x
        at.readings = setfit.model.predict(x, dirs, at)
        a0 = setfit.model.true_accel(x, at)
        slopes = np.empty(dirs.shape + (len(x),))
        for j in range(len(x)):
            step = 1e-6 * max(abs(x[j]), 1e-3)
            moved = x.copy()
            moved[j] += step
            slopes[:, :, j] = (setfit.model.true_accel(moved, at) - a0) / step
        return 1000.0 / G0 * slopes @ np.linalg.pinv(setfit.fit.jac)

    @property
    def grid(self):
        """Return the directions and conditions of the worst case (``evidence.WorstGrid``)."""
        if self._grid is None:
            base = self.cache[frozenset()]
            self._grid = WorstGrid(base.model, base.fit.x, self.c)
        return self._grid

    def cv(self, setfit):
        """Return the held-out chi² per fold of ``setfit``, (K,)."""
        if setfit._cv is None:
            setfit._cv = cv_folds(setfit.fit.residuals, fold_maps(setfit.basis, self.folds),
                                  self.folds)
        return setfit._cv

    def trial(self, names, name):
        """
        Return the ``criterion.Trial`` of adding effect ``name`` to the set ``names``.

        An effect that contains another as a special case (``Effect.nests``: a wander
        contains a straight drift) takes its place: the set is ``names`` without it plus
        ``name``, and the parameters added are the difference.
        """
        kept, replaced = added(names, name)
        setfit = self.fit(kept)
        if setfit is None or setfit.dof < 2:
            return None, None
        base = self.fit(names)
        k = setfit.k(name) - sum(base.k(n) for n in replaced)
        trial = Trial(name, EFFECTS[name].variable, k, [setfit.chi2], setfit.dof,
                      [self.size(setfit, base, name)], [self.cv(setfit)],
                      [self.veto(name, setfit)])
        return trial, setfit

    def where(self, setfit, top=3):
        """Return the strongest correlations of the residuals of ``setfit`` with the variables."""
        from .evidence import strongest_correlations
        a = setfit.model.true_accel(setfit.fit.x, self.c)
        return strongest_correlations(setfit.fit.residuals, self.c,
                                      a / np.linalg.norm(a, axis=1, keepdims=True), top)

    def signature(self, setfit, name, given):
        """Return the orthonormal signature of ``name`` (as in ``setfit``) past ``given``."""
        return orthonormal(self._columns(given, setfit.bound[name]), given.basis)

    def correlation(self, given, first, second):
        """
        Return how alike two effects look beyond the set ``given`` (0 to 1).

        The largest canonical correlation of their Jacobian columns after what ``given``
        absorbs is projected out: 1 when a combination of one is the other here.
        """
        q1 = self.signature(first[1], first[0], given)
        q2 = self.signature(second[1], second[0], given)
        if not q1.shape[1] or not q2.shape[1]:
            return 0.0
        return float(min(np.linalg.svd(q1.T @ q2, compute_uv=False).max(), 1.0))
