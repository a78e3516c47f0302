"""
The model-gap workflow on one still pose while the temperature sweeps (a thermal recording).

A warm-up or chamber cycle in one pose cannot show the gravity norm's dependence on
direction, but it shows every axis's offset against temperature and time. The session is
its bins (``core.accelerometer.thermal_still``), the baseline per axis a constant per pose
plus the offset against the reported temperature (the one-pose thermal tables:
``core.accelerometer.thermal_pose``, zero at the reference calibration's temperature), and
the residuals are per axis, each bin mean minus the model over its noise (3 N of them,
axis by axis). The model is linear in its parameters, so each set of effects is one least
squares; everything after it is the workflow's own: the library effects the session can
show (``Effect.applicable`` with the baseline 'still'), the one model selection
(``selection.select``: BIC with the pooled noise level, held-out bins, Occam among
confounded ties, the joint refit), the steps, the verdict and the naming power.

:class:`StillConditions` is the session, :class:`StillModel` the linear model of a set,
:class:`StillFits` the joint fits (``setfit.SessionFits`` with this geometry), and
:func:`diagnose_still` the workflow; the result (:class:`StillResult`) also says which
hysteresis term a thermal fit carries (:meth:`StillResult.hysteresis`) and how the named
effects predict one leg of the cycle from the other (:func:`held_out_legs`).
"""

import numpy as np

from .criterion import make_folds
from .effects import EFFECTS
from .model import Fit
from .setfit import SessionFits, SetFit
from ..core.accelerometer.thermal_pose import _legs, StillDesign


class StillConditions:
    """
    A still recording as the fit sees it: one row per bin, residuals per axis.

    :param rec: StillRecording. :param reference: the reference Calibration (T, bias).
    :param reference_c: its temperature, °C. :param band_width_c: the tables' band width.
    :param gravity: m/s². :param inflation: (3,) variance of a bin mean over white noise.
    """

    def __init__(self, rec, reference, reference_c, band_width_c, gravity, inflation=1.0):
        bins = rec.bins
        self.rec, self.reference_c, self.band_width_c = rec, reference_c, band_width_c
        self.readings = np.asarray(bins.mean, float)
        noise = np.where(rec.noise_std > 0, rec.noise_std, np.max(rec.noise_std) or 1e-3)
        self.sigma = noise[None, :] * np.sqrt(np.asarray(inflation, float)[None, :]
                                              / bins.count[:, None])
        self.temp_abs, self.time_abs = np.asarray(bins.temp, float), np.asarray(bins.t_mid)
        self.temp = self.temp_abs - self.temp_abs.mean()
        self.time = self.time_abs - self.time_abs.mean()
        self.gravity = float(gravity)
        self.temp_span, self.time_span = float(np.ptp(self.temp)), float(np.ptp(self.time))
        self.design = StillDesign(rec, reference_c, band_width_c, smooth=True)
        self.T = np.asarray(reference.T, float)
        self.bias = np.asarray(reference.bias, float)
        self.T_inv = np.linalg.inv(self.T)
        a = (self.readings - self.bias) @ self.T_inv.T
        self.accel = gravity * a / np.linalg.norm(a, axis=1, keepdims=True)
        self.slope = self._slope()
        self.legs = _legs(self.time_abs, self.temp_abs, rec.segment)

    def _slope(self):
        """Return d(reading)/dθ per bin and axis (N, 3): a cubic per axis beside the poses."""
        t = self.temp_abs - self.reference_c
        X = np.hstack([self.design.pose_cols, np.column_stack([t, t ** 2, t ** 3])])
        coef = np.linalg.lstsq(X, self.readings, rcond=None)[0][-3:]
        return coef[0][None, :] + 2 * coef[1][None, :] * t[:, None] \
            + 3 * coef[2][None, :] * t[:, None] ** 2

    def __len__(self):
        return len(self.readings)

    @property
    def flat_sigma(self):
        """Return the noise of every residual, axis by axis (3 N,)."""
        return self.sigma.T.ravel()

    @property
    def flat_readings(self):
        return self.readings.T.ravel()

    def flatten(self, cols):
        """Return effect columns (N, 3, k) as rows axis by axis, (3 N, k)."""
        return np.concatenate([cols[:, i, :] for i in range(3)], axis=0)


class StillModel:
    """
    The linear model of one set of effects on a still recording.

    Parameters: per axis the pose constants and the referenced node values (axis x first),
    then each effect's (``Effect.columns`` per axis at the pose's true specific force).
    """

    baseline = 'still'

    def __init__(self, c, effects):
        from .effects import effect_of, name_of
        self.c = c
        self.effects = list(effects)
        self.objects = {name_of(e): effect_of(e) for e in self.effects}
        self.per_axis = c.design.pose_cols.shape[1] + c.design.node_cols.shape[1]
        self.n_base = 3 * self.per_axis
        self.sizes = [len(effect_of(e).param_names) for e in self.effects]

    @property
    def n_params(self):
        return self.n_base + sum(self.sizes)

    def base_matrix(self):
        """Return the baseline's columns, (3 N, 3 per_axis): block diagonal by axis."""
        block = np.hstack([self.c.design.pose_cols, self.c.design.node_cols])
        n, k = block.shape
        out = np.zeros((3 * n, 3 * k))
        for i in range(3):
            out[i * n:(i + 1) * n, i * k:(i + 1) * k] = block
        return out

    def effect_matrix(self, effect):
        """Return an effect's columns as rows axis by axis, (3 N, k)."""
        c = self.c
        return c.flatten(effect.columns(c.accel, c.temp, c.time, c.gravity))

    def matrix(self):
        return np.hstack([self.base_matrix()] + [self.effect_matrix(self.objects[n])
                                                 for n in self.objects])

    def fit(self, c, start=None):
        """Return (parameters, chi², Jacobian of the normalised residuals (3 N, p))."""
        s = c.flat_sigma
        X = self.matrix() / s[:, None]
        y = c.flat_readings / s
        x = np.linalg.lstsq(X, y, rcond=None)[0]
        r = y - X @ x
        return x, float(r @ r), -X

    def fit_rows(self, rows):
        """
        Return the parameters fitted to some bins only (``rows``: (N,) bool), the rest zero.

        A parameter those bins cannot show (a pose they do not hold) stays zero.
        """
        c = self.c
        X = self.matrix()
        s = c.flat_sigma
        flat = np.tile(rows, 3)
        keep = np.any(X[flat] != 0, axis=0)
        x = np.zeros(X.shape[1])
        x[keep] = np.linalg.lstsq(X[flat][:, keep] / s[flat, None],
                                  c.flat_readings[flat] / s[flat], rcond=None)[0]
        return x

    def residuals(self, x, c):
        return (c.flat_readings - self.matrix() @ x) / c.flat_sigma

    def split(self, x):
        """Return (reference T, reference bias, {effect: params})."""
        params, k = {}, self.n_base
        for name, size in zip(self.objects, self.sizes):
            params[name] = np.asarray(x[k:k + size])
            k += size
        return self.c.T, self.c.bias, params

    def correction(self, x, reverse=False):
        """
        Return what the model subtracts from each bin beyond its pose constant, (N, 3) m/s².

        The referenced offset curve plus the effects: what a calibration made of it
        would correct (the pose constants are the session's, not the calibration's);
        ``reverse``: at the same temperatures run the other way (heating for cooling,
        ``Effect.reverse_heating``).
        """
        c = self.c
        n, k = len(c), self.per_axis
        p = c.design.pose_cols.shape[1]
        out = np.empty((n, 3))
        for i in range(3):
            out[:, i] = c.design.node_cols @ x[i * k + p:(i + 1) * k]
        for name, size in zip(self.objects, self.sizes):
            start = self.n_base + sum(s for nm, s in zip(self.objects, self.sizes)
                                      if list(self.objects).index(nm)
                                      < list(self.objects).index(name))
            effect = self.objects[name]
            cols = effect.columns(c.accel, c.temp, c.time, c.gravity)
            if reverse:
                cols = effect.reverse_heating(cols)
            out += cols @ x[start:start + size]
        return out

    def true_accel(self, x, c):
        """Return the pose's true specific force per bin, (N, 3) m/s² (what the bins hold)."""
        return c.accel

    def pack_baseline(self, T, bias):
        return np.zeros(self.n_base)


class StillFits(SessionFits):
    """``setfit.SessionFits`` for a still recording: linear fits, residuals per axis."""

    def __init__(self, c, threshold, nu, noise_dof=None):
        self.baseline, self.c, self.threshold, self.nu = 'still', c, threshold, nu
        self.noise_dof = nu if noise_dof is None else noise_dof
        n = len(c)
        self.n = 3 * n
        # A drift's still windows and a walk's roughness are measured along gravity: no
        # measurement here contradicts an effect (``Effect.contradiction``).
        self.measured = None
        self.folds = [np.concatenate([f + i * n for i in range(3)]) for f in still_folds(c)]
        self.candidates = []
        self._grid = None
        self.cache = {}
        model = StillModel(c, [])
        x, chi2, jac = model.fit(c)
        fit = Fit([], x, chi2, self.n - _rank(jac), model.residuals(x, c), jac)
        self.cache[frozenset()] = SetFit((), {}, model, fit)
        self.order = list(EFFECTS)

    def _full(self, names, bound, ref):
        effects = [bound[n] for n in names]
        model = StillModel(self.c, effects)
        try:
            x, chi2, jac = model.fit(self.c)
        except (ValueError, np.linalg.LinAlgError):
            return None
        dof = self.n - _rank(jac) - sum(e.searched for e in effects)
        return SetFit(names, dict(bound), model,
                      Fit(list(effects), x, chi2, dof, model.residuals(x, self.c), jac))

    def _columns(self, setfit, effect):
        c = self.c
        cols = c.flatten(effect.columns(c.accel, c.temp, c.time, c.gravity))
        return -cols / c.flat_sigma[:, None]

    def worst(self, setfit, name):
        """
        Return the largest change effect ``name`` makes in corrected acceleration, mg.

        Over the session's bins and the same temperatures run the other way (an effect of
        the heating direction shows there what one leg alone hides), about its mean.
        """
        if name not in setfit._worst:
            c = self.c
            effect = setfit.bound[name]
            cols = effect.columns(c.accel, c.temp, c.time, c.gravity)
            p = setfit.params(name)
            part = np.vstack([cols @ p, effect.reverse_heating(cols) @ p])
            part = (part - (cols @ p).mean(axis=0)) @ c.T_inv.T
            setfit._worst[name] = 1000.0 * float(np.max(np.linalg.norm(part, axis=1))) \
                / c.gravity
        return setfit._worst[name]

    def contribution(self, full, without):
        """
        Return how much a set changes the corrected acceleration over another, worst case, mg.

        The difference of what the two subtract from each bin (``StillModel.correction``:
        the referenced offsets and the effects, not the pose constants), through T⁻¹, at
        the session's bins and at the same temperatures run the other way: a heating term
        that one leg's curve absorbs still changes the other leg's correction.
        """
        key = ('contribution', without.names)
        if key not in full._worst:
            c = self.c
            diff = np.vstack([full.model.correction(full.fit.x, reverse)
                              - without.model.correction(without.fit.x, reverse)
                              for reverse in (False, True)]) @ c.T_inv.T
            full._worst[key] = 1000.0 * float(np.max(np.linalg.norm(diff, axis=1))) \
                / c.gravity
        return full._worst[key]

    # -- the geometry of the naming simulation (``power.Design``) --------------------------

    @property
    def row_window(self):
        """Return the bin of each residual, (3 N,): axis by axis."""
        return np.tile(np.arange(len(self.c)), 3)

    def noise_scale(self, setfit):
        """Return the noise of each residual, m/s², (3 N,)."""
        return self.c.flat_sigma

    def power_grid(self, setfit, conditions, directions):
        """Return the bins (and the same run the other way) over which a worst case is taken."""
        return StillGrid(self.c, GRID_BINS)

    def absorbed(self, setfit, grid):
        """
        Return what the model takes up of a residual, in corrected acceleration, (D, 3, 3 N) mg.

        What the model subtracts at the grid's bins (``StillModel.correction``: the offsets
        and the named effects, not the pose constants) changes by A dx per parameter
        change; the least-squares map from a residual to dx is the pseudo-inverse of the
        fit's Jacobian; through -T⁻¹ into corrected acceleration.
        """
        c, model = self.c, setfit.model
        rows = grid.rows_index
        k, p = model.per_axis, c.design.pose_cols.shape[1]
        slopes = np.zeros((2 * len(rows), 3, model.n_params))
        for i in range(3):
            slopes[:, i, i * k + p:(i + 1) * k] = np.tile(c.design.node_cols[rows], (2, 1))
        start = model.n_base
        for name, size in zip(model.objects, model.sizes):
            effect = model.objects[name]
            cols = effect.columns(c.accel, c.temp, c.time, c.gravity)
            slopes[:, :, start:start + size] = np.concatenate(
                [cols[rows], effect.reverse_heating(cols)[rows]])
            start += size
        slopes = -np.einsum('ij,njk->nik', c.T_inv, slopes)
        return 1000.0 / c.gravity * slopes @ np.linalg.pinv(setfit.fit.jac)

    def where(self, setfit, top=3):
        """Return the strongest correlations of the residuals with the session's variables."""
        c = self.c
        r = setfit.fit.residuals.reshape(3, -1)
        variables = {'temperature': c.temp, 'time': c.time,
                     'heating (+1) or cooling (-1)': c.legs.astype(float)}
        out = []
        for i, axis in enumerate('xyz'):
            for name, values in variables.items():
                if np.ptp(values) > 0 and np.ptp(r[i]) > 0:
                    out.append({'variable': f'{name} ({axis} axis)',
                                'r': float(np.corrcoef(r[i], values)[0, 1])})
        out.sort(key=lambda d: -round(abs(d['r']), 6))
        return out[:top]


FOLD_BLOCK_S = 60.0
"""Held-out folds of a still recording are made of stretches this long (at least 3 bins)."""


def still_folds(c):
    """
    Return the held-out folds of a still recording: short stretches dealt round the folds.

    Blocks of consecutive bins (``FOLD_BLOCK_S``) go to the ``CV_FOLDS`` folds in turn, so
    every fold spans the whole temperature range: a node of the offset curve is never
    held out whole (blocked folds in time would hold out one temperature band of a ramp),
    while the bins of a fold are not each other's neighbours.
    """
    from .criterion import CV_FOLDS
    n = len(c)
    order = np.argsort(c.time, kind='stable')
    spacing = float(np.median(np.diff(c.time[order]))) if n > 1 else 1.0
    size = max(3, int(round(FOLD_BLOCK_S / max(spacing, 1e-9))))
    if n < CV_FOLDS * size:
        return make_folds(c.time)
    block = np.arange(n) // size
    return [np.sort(order[block % CV_FOLDS == k]) for k in range(CV_FOLDS)]


GRID_BINS = 60
"""Bins (evenly spread, the extremes of temperature and time among them) of the naming
simulation's worst case; each is also taken run the other way."""


class StillGrid:
    """
    The bins of a still recording over which the naming simulation takes a worst case.

    ``GRID_BINS`` bins spread over the recording, each as recorded and with the heating
    direction reversed (``Effect.reverse_heating``): an effect's error in corrected
    acceleration (about its mean over the session: the pose constant takes that) there.
    """

    def __init__(self, c, count):
        n = len(c)
        idx = set(np.linspace(0, n - 1, min(count, n)).round().astype(int))
        idx |= {int(np.argmin(c.temp)), int(np.argmax(c.temp))}
        self.c, self.rows_index = c, np.array(sorted(idx))

    def matrix(self, effect, full=True):
        """Return the error per unit parameter in corrected acceleration, (2 D, 3, k), mg."""
        c = self.c
        cols = effect.columns(c.accel, c.temp, c.time, c.gravity)
        mean = cols.mean(axis=0)
        rows = np.concatenate([cols[self.rows_index],
                               effect.reverse_heating(cols)[self.rows_index]]) - mean
        return 1000.0 / c.gravity * np.einsum('ij,njk->nik', c.T_inv, rows)


def _rank(jac):
    sv = np.linalg.svd(jac, compute_uv=False)
    return int(np.sum(sv > 1e-9 * max(sv.max(), 1e-300)))
