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

from dataclasses import dataclass

import numpy as np

from .criterion import make_folds
from .effects import EFFECTS
from .model import Fit
from .result import DiagnoseResult, MIN_EFFECT_MG
from .setfit import SessionFits, SetFit
from ..core.accelerometer.thermal_pose import _legs, StillDesign

HYSTERESIS_EFFECTS = ('temperature_rate', 'temperature_lag')
"""The library effects that make heating and cooling read differently (carried to the robot
as ``core.accelerometer.thermal_lag.Hysteresis``)."""


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
        self.design = StillDesign(rec, reference_c, band_width_c)
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

    def __init__(self, c, threshold, nu, veto=None, noise_dof=None):
        self.baseline, self.c, self.threshold, self.nu = 'still', c, threshold, nu
        self.noise_dof = nu if noise_dof is None else noise_dof
        n = len(c)
        self.n = 3 * n
        self.veto = veto or (lambda name, setfit: '')
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


@dataclass
class StillResult(DiagnoseResult):
    """A DiagnoseResult of a still recording (residuals per axis, the reference's T)."""

    def _model(self, fit):
        return StillModel(self.conditions, fit.effects)

    def excess_scatter(self):
        fit = self.fits[-1]
        if fit.gap <= 1.0 or fit.dof < 1:
            return 0.0
        s = self.conditions.flat_sigma
        rho = fit.residuals * s
        from scipy import optimize

        def excess(sx):
            return np.sum(rho ** 2 / (s ** 2 + sx ** 2)) - fit.dof
        high = float(np.sqrt(np.mean(rho ** 2))) * 2.0 + 1e-12
        return float(optimize.brentq(excess, 0.0, high))

    def walk_roughness(self):
        return 0.0

    def gap_power(self):
        from .noise import detection_probability, min_detectable_mg
        fit = self.fits[-1]
        s = self.conditions.flat_sigma
        between = self.noise_source == 'between windows'
        scale = self.gap_after ** 2 if between else 1.0
        nu = float(fit.dof) if between else self.noise_dof
        inv = float(np.sum(1.0 / (s ** 2 * scale)))
        mde = min_detectable_mg(fit.dof, nu, inv, len(s))
        known = min_detectable_mg(fit.dof, float('inf'), inv, len(s))
        at = detection_probability(self.threshold_mg, fit.dof, nu, inv, len(s))
        return (mde if np.isfinite(mde) else None, known if np.isfinite(known) else None,
                at, nu)

    def parameters(self):
        c = self.conditions
        model = self._model(self.fits[-1])
        _, _, params = model.split(self.fits[-1].x)
        out = {'T': c.T.tolist(), 'bias': c.bias.tolist(), 'effects': {}}
        for name, values in params.items():
            effect = model.objects[name]
            out['effects'][name] = {
                'values': values.tolist(), 'names': list(effect.param_names),
                'unit': effect.unit,
                'magnitude': effect.magnitude(values, c.gravity, np.diag(c.T))}
        return out

    def hysteresis(self):
        """
        Return the heating/cooling term a thermal fit carries (``Hysteresis``), or None.

        The first named effect of ``HYSTERESIS_EFFECTS``: the thermal fit carries it in the
        gradient form (the offset per °C of θ - θ_lag), its time constant and per-axis
        coefficients fitted to the data in that form (a die lag named here is carried as
        the gradient that imitates it best).
        """
        from ..core.accelerometer.thermal_lag import Hysteresis
        for step in self.steps:
            if step['effect'] in HYSTERESIS_EFFECTS:
                return Hysteresis(None, np.zeros(3), step['effect'])
        return None

    held_out: dict = None

    def summary(self):
        """Return the JSON of ``DiagnoseResult.summary`` plus the one-pose keys."""
        out = super().summary()
        c = self.conditions
        out.update(reference_c=c.reference_c, band_width_c=c.band_width_c,
                   calibrated_range_c=list(c.rec.temp_range_c),
                   poses=int(c.rec.pose.max()) + 1,
                   heating_bins=int((c.legs > 0).sum()), cooling_bins=int((c.legs < 0).sum()),
                   held_out_legs=self.held_out or {},
                   hysteresis_named=[s['effect'] for s in self.steps
                                     if s['effect'] in HYSTERESIS_EFFECTS])
        return out

    def text(self):
        """Return the human summary, with the held-out legs."""
        lines = [super().text().replace('static windows', 'bins of one still pose', 1)]
        for name, entry in (self.held_out or {}).items():
            before, after = entry['baseline'], entry['with_effects']
            lines.append(f'{name.replace("_", " ")} ({entry["bins"]} bins held out): gap '
                         f'{before["gap"]:.2f} -> {after["gap"]:.2f}, RMS [mg] '
                         + ' '.join(f'{v:.2f}' for v in before['rms_mg']) + ' -> '
                         + ' '.join(f'{v:.2f}' for v in after['rms_mg']))
        return '\n'.join(lines)

    def rest_words(self):
        return ('a scatter from bin to bin beyond the noise inside the bins (bias instability, '
                'noise correlated beyond a bin)')

    def brief(self):
        """Return the verdict in a few keys (for ``fit``'s JSON)."""
        return {'missing_effects': self.missing_effects, 'gap_before': self.gap_before,
                'gap_after': self.gap_after, 'verdict': self.verdict(),
                'explained_by_noise': bool(self.explained),
                'steps': [{'effect': s['effect'], 'gap_before': s['gap_before'],
                           'gap_after': s['gap_after'],
                           'magnitude': s['evidence']['magnitude'],
                           'worst_case_mg': s['evidence']['worst_case_mg'],
                           'p': s['evidence']['p'],
                           **({'tau_s': s['evidence']['tau_s']}
                              if 'tau_s' in s['evidence'] else {})}
                          for s in self.steps],
                'alternatives': self.alternatives}


def diagnose_still(rec, reference, reference_c, band_width_c, gravity=9.80665,
                   min_effect_mg=None, samples=None, max_steps=3, power=True):
    """
    Run the model-gap workflow on a still recording (see the module docstring).

    :param rec: StillRecording. :param reference: the reference Calibration.
    :param reference_c: its temperature, °C. :param band_width_c: the tables' band width.
    :param min_effect_mg: practical threshold, mg (default ``MIN_EFFECT_MG``).
    :param samples: the Samples of ``rec`` (the noise of a bin from its own spectrum).
    :returns: StillResult.
    """
    from .noise import window_noise, WindowNoise
    from .selection import select, Selection
    from .steps import record_steps
    noise = WindowNoise(np.ones(3), np.zeros(3), ['assumed white'] * 3)
    if samples is not None and getattr(rec, 'samples', None) is not None:
        noise = window_noise(rec.samples, rec.bins)
    c = StillConditions(rec, reference, reference_c, band_width_c, gravity, noise.inflation)
    threshold = float(min_effect_mg) if min_effect_mg is not None else MIN_EFFECT_MG
    pooled = 0.0 if noise.coloured else noise.dof
    fits = StillFits(c, threshold, pooled, noise_dof=noise.dof)
    base = fits.fit(())
    from scipy import stats
    context = {'temp_span': c.temp_span, 'time_span': c.time_span, 'windows': len(c),
               'has_temp': True,
               'time_temp_rank': float(stats.spearmanr(c.time, c.temp)[0])
               if np.ptp(c.temp) > 0 else 1.0}
    skipped, candidates = {}, []
    for name, effect in EFFECTS.items():
        reason = ('' if effect.one_pose else 'one still pose cannot show it (no direction or '
                  'scale changes; the offset against temperature is the baseline)')
        reason = reason or effect.applicable(context, 'still')
        if not reason:
            bound = effect.bind(c)
            if base.fit.dof - len(bound.param_names) - bound.searched < 2:
                reason = f'{len(c)} bins leave too few degrees of freedom'
        if reason:
            skipped[name] = reason
        else:
            candidates.append(name)
    result = StillResult('still', len(c), c, [base.fit], skipped=skipped, window_noise=noise,
                         noise_std=rec.noise_std, threshold_mg=threshold)
    result.session_fits = fits
    result.tested = candidates
    selection = select(fits, candidates, max_steps) if max_steps > 0 else Selection()
    result.selection = selection
    record_steps(result, selection.chosen)
    result.candidates = selection.candidates
    result.below_threshold = [cand for cand in result.candidates
                              if cand['significant'] and not cand['large_enough']]
    result.vetoed = list(selection.vetoed)
    if power:
        _naming_power(result)
    result.held_out = held_out_legs(result)
    return result


def _naming_power(result):
    """Simulate how large each tested effect not named must be to be named (``power``)."""
    from .power import calibrate_power
    names = [n for n in result.tested if n not in result.missing_effects]
    if not names or result.final_set is None:
        result.naming_power = {}
        return
    coloured = bool(result.window_noise.coloured)
    open_gap = result.noise_source == 'between windows' or not result.statistically_explained
    excess = result.excess_scatter() if open_gap else 0.0
    scale = max(1.0, result.gap_after ** 2) if coloured and not open_gap else 1.0
    try:
        result.naming_power = calibrate_power(result.session_fits, result.final_set, names,
                                              coloured=coloured, excess=excess, scale=scale)
    except (ValueError, np.linalg.LinAlgError):
        result.naming_power = None


def held_out_legs(result):
    """
    Fit on one direction of the temperature's change and predict the other, before and after.

    The baseline alone and the baseline plus the named effects (as bound to the whole
    recording: their temperature history) are fitted to the heating bins and evaluated on
    the cooling bins, and the other way round. A pose held only in the predicted leg takes
    its constant from there.

    :returns: dict 'heating_to_cooling' and 'cooling_to_heating' (when both legs hold at
        least 10 bins), each {'baseline' and 'with_effects': {'gap', 'rms_mg' (3)}, 'bins'}.
    """
    c = result.conditions
    legs = c.legs
    out = {}
    sets = {'baseline': [], 'with_effects': result.fits[-1].effects}
    for name, fit_leg in (('heating_to_cooling', 1), ('cooling_to_heating', -1)):
        train, test = legs == fit_leg, legs == -fit_leg
        if train.sum() < 10 or test.sum() < 10:
            continue
        entry = {'bins': int(test.sum())}
        for key, effects in sets.items():
            model = StillModel(c, effects)
            X = model.matrix()
            s = c.flat_sigma
            rows = np.tile(train, 3)
            keep = np.any(X[rows] != 0, axis=0)
            x = np.zeros(X.shape[1])
            x[keep] = np.linalg.lstsq(X[rows][:, keep] / s[rows, None],
                                      c.flat_readings[rows] / s[rows], rcond=None)[0]
            r = (c.flat_readings - X @ x).reshape(3, -1).T[test]
            for p in np.flatnonzero(~c.design.pose_cols[train].any(axis=0)):
                mine = c.rec.pose[test] == p
                r[mine] -= r[mine].mean(axis=0)
            sigma = c.sigma[test]
            entry[key] = {'gap': float(np.sqrt(np.mean((r / sigma) ** 2))),
                          'rms_mg': (1000.0 * np.sqrt(np.mean(r ** 2, axis=0))
                                     / c.gravity).tolist()}
        out[name] = entry
    return out
