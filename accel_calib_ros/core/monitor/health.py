"""
Calibration health: whether the corrected acceleration at rest still reads gravity.

Each rest (a still period of at least ``min_still_s`` that is a rest in the inertial
sense and that the next rest confirmed, :mod:`.inertial`) gives one observation: the
direction ``u`` of its mean corrected acceleration and the disagreement
``d = |mean| - g`` (``g`` the calibration's gravity). Observations within ``cluster_deg``
of each other are one orientation; the newest one stands for it (older ones are
forgotten after ``memory_s``).

**The null hypothesis** (the calibration is as good as it said, nothing changed beyond
what a sensor does between sessions) gives the vector ``d`` over the k orientations a
covariance of four parts:

- the calibration's own error: at a given orientation it is *systematic*, the same in
  every still period there: ``J(u) Σ J(u')ᵀ`` with ``Σ`` the fit's parameter covariance
  and ``J`` the derivative of ``|T⁻¹(raw - b)|`` (``core.accuracy.norm_jacobians``),
  scaled up to the predicted accuracy when that is larger; without a covariance,
  ``predicted_accuracy² / 3`` per orientation, independent;
- the **allowance**: a random bias change per axis between sessions
  (:mod:`.prior`: the sensor's own history, else the setting), ``Us diag(a²) Usᵀ``;
- the **temperature**: outside the calibrated range by ``o`` °C, a bias change of
  ``c o`` per axis, ``c`` the temperature coefficient (:mod:`.prior`: the thermal
  tables' slope, the history's, or the datasheet's ±1.5 mg/°C, taken as two standard
  deviations), the same ``c`` at every orientation;
- the fit's residual and the noise of the period's mean (:mod:`.mean_noise`: measured from
  the data's own batch means, so correlated noise is allowed for).

The statistic ``dᵀ C⁻¹ d`` is χ² with k degrees of freedom under the null; the check
says **recalibrate** when it exceeds the ``1 - false_alarm`` quantile. A temperature more
than ``margin_c`` outside the calibrated range that the data do not contradict is a
**warning** with the size it could explain, not a recalibration.

**The cause**, named only as far as the orientations allow: a bias shift
(``d = u·δb``) and a scale change (``d = g Σ uᵢ² δsᵢ``) are fitted to ``d`` by generalised
least squares; a model is ruled out when its residual χ² is beyond the 1 % quantile of
its degrees of freedom. A bias shift perpendicular to every orientation seen changes no
``|a|``: no accelerometer-only check can see it.
"""

from dataclasses import dataclass, field
import math

import numpy as np

from .prior import MG, sensor_prior, table_tempco
from .stats import chi2_quantile, chi2_survival
from ..accuracy import direction_errors, FACE_DIRECTIONS, norm_jacobians
from ..finite import finite_or_none

RULE_OUT = 0.01
"""A cause is ruled out when its residual χ² is beyond this upper quantile."""
TEMPCO_SIGMAS = 2.0
"""A temperature coefficient (a ± figure) is taken as this many standard deviations."""
LEVELS = ('unknown', 'ok', 'warn', 'recalibrate', 'error')
"""Health levels: nothing judged yet, fine, a warning, recalibrate, a sensor fault."""


class ErrorModel:
    """
    What a calibration says about its own error at rest, per orientation.

    :param cal: a Calibration (``core.calibration``): T, bias, gravity, covariance,
        predicted_accuracy, residual_rms, temperature_range_c, thermal, level_rotation().
    """

    def __init__(self, cal):
        self.cal = cal
        self.gravity = float(cal.gravity)
        self.L = np.asarray(cal.level_rotation(), float)
        self.T = np.asarray(cal.T, float)
        self.bias = np.asarray(cal.bias, float)
        cov = cal.covariance
        self.cov = None if cov is None or not np.all(np.isfinite(cov)) \
            else np.asarray(cov, float)
        acc = cal.predicted_accuracy
        self.predicted = float(acc) if acc is not None and math.isfinite(acc) else None
        res = cal.residual_rms
        self.residual = float(res) if res is not None and math.isfinite(res) else 0.0
        rng = cal.temperature_range_c
        if rng is None and cal.thermal is not None:
            rng = cal.thermal.range_c
        self.temperature_range = None if rng is None else (float(rng[0]), float(rng[1]))
        self.inflation = 1.0
        if self.cov is not None and self.predicted is not None:
            sphere = float(np.mean(direction_errors(self.T, self.cov, FACE_DIRECTIONS,
                                                    self.gravity) ** 2))
            if sphere > 0:
                self.inflation = max(1.0, self.predicted ** 2 / sphere)

    def sensor_directions(self, U):
        """Return the rows of ``U`` (directions in the corrected, levelled frame) unlevelled."""
        return np.asarray(U, float) @ self.L

    def systematic(self, U):
        """
        Return the (k, k) covariance of the calibration's |a| error at directions ``U``.

        :param U: (k, 3) unit directions in the corrected frame.
        """
        Us = self.sensor_directions(U)
        if self.cov is None:
            var = 0.0 if self.predicted is None else self.predicted ** 2 / 3.0
            return np.eye(len(Us)) * var
        J = norm_jacobians(self.T, Us, self.gravity)
        return self.inflation * (J @ self.cov @ J.T)

    def outside(self, temp):
        """Return how far ``temp`` °C lies outside the calibrated range (0 inside or unknown)."""
        if self.temperature_range is None or not math.isfinite(temp):
            return 0.0
        low, high = self.temperature_range
        return max(low - temp, temp - high, 0.0)

    def tempco(self, u, temp, prior):
        """
        Return the bias temperature coefficient per axis at direction ``u``, and its source.

        The thermal tables' slope at their edge when the calibration has them, else the
        prior's (history or datasheet). m/s² per °C, (3,).
        """
        if self.cal.thermal is not None and self.outside(temp) > 0:
            us = self.sensor_directions(np.reshape(u, (1, 3)))[0]
            raw = self.T @ (self.gravity * us) + self.bias
            slope = table_tempco(self.cal, raw, temp)
            if slope is not None:
                return slope, "the calibration's thermal tables (their slope at the edge)"
        return prior.tempco, prior.tempco_source


@dataclass
class HealthResult:
    """
    The latest health check, in numbers and words.

    ``level``: one of :data:`LEVELS`. Accelerations in mg (1 mg = 9.80665e-3 m/s²),
    temperatures in °C.
    """

    level: str = 'unknown'
    message: str = 'no still period checked yet'
    time_s: float = float('nan')
    cause: str = ''
    warning: str = ''
    periods: int = 0
    orientations: int = 0
    disagreement_mg: float = float('nan')
    predicted_mg: float = float('nan')
    chi2: float = float('nan')
    threshold: float = float('nan')
    p_value: float = float('nan')
    false_alarm: float = float('nan')
    temperature_c: float = float('nan')
    temperature_range_c: tuple = None
    temperature_outside_c: float = 0.0
    temperature_explains_mg: list = None
    tempco_source: str = ''
    allowance_mg: list = None
    allowance_source: str = ''
    mean_noise_ratio: float = float('nan')
    bias_shift_mg: list = None
    scale_change_ppm: list = None
    notes: list = field(default_factory=list)

    @property
    def healthy(self):
        """Return True (ok or a warning), False (recalibrate, a fault) or None (unknown)."""
        return None if self.level == 'unknown' else self.level in ('ok', 'warn')

    def to_dict(self):
        """Return a JSON-ready dict (NaN and infinities as None)."""
        def clean(v):
            if isinstance(v, float):
                return finite_or_none(v)
            if isinstance(v, (list, tuple)):
                return [clean(x) for x in v]
            return v
        out = {k: clean(getattr(self, k)) for k in self.__dataclass_fields__}
        out['healthy'] = self.healthy
        out['recalibrate'] = self.level == 'recalibrate'
        return out


def orientation_words(u):
    """Name an orientation: the sensor axis nearest up and the tilt from it ('+z up')."""
    u = np.asarray(u, float)
    k = int(np.argmax(np.abs(u)))
    sign = '+' if u[k] > 0 else '-'
    tilt = math.degrees(math.acos(min(abs(float(u[k])) / float(np.linalg.norm(u)), 1.0)))
    return f'{sign}{"xyz"[k]} up' + (f' (tilted {tilt:.0f} deg)' if tilt >= 1.0 else '')


class CalibrationHealth:
    """
    The health check of one calibration, fed with rests (see the module docstring).

    :param model: :class:`ErrorModel` of the calibration in use.
    :param false_alarm: chance that one check says recalibrate on a calibration that is fine.
    :param allowance: bias change per axis between sessions without a history, m/s².
    :param min_still_s: shortest still period used, s.
    :param cluster_deg: periods closer than this are one orientation, degrees.
    :param memory_s: an orientation not seen for this long is forgotten, s.
    :param margin_c: temperatures this far outside the calibrated range are a warning, °C.
    :param max_orientations: most orientations remembered (the oldest goes).
    """

    def __init__(self, model, false_alarm=1e-4, allowance=1.0 * MG, min_still_s=2.0,
                 cluster_deg=10.0, memory_s=3600.0, margin_c=2.0, max_orientations=12):
        self.model = model
        self.false_alarm = float(false_alarm)
        self.prior = sensor_prior(allowance)
        self.min_still_s, self.memory_s = float(min_still_s), float(memory_s)
        self.cos_cluster = math.cos(math.radians(cluster_deg))
        self.margin_c, self.max_orientations = float(margin_c), int(max_orientations)
        self.clusters = []          # dicts: u, d, se, t, temp, ratio
        self.periods = 0            # still periods checked
        self.failures = 0           # checks that said recalibrate
        self.warnings = 0           # checks that warned (temperature) without failing
        self.first_failure = None   # the first of them (HealthResult)
        self.first_warning = None
        self.result = HealthResult(false_alarm=self.false_alarm,
                                   temperature_range_c=model.temperature_range)

    def observation(self, run, ratio=1.0):
        """
        Return the observation of a still period (:class:`~.blocks.Run`), or None.

        :param ratio: variance of its mean over the white-noise value (:mod:`.mean_noise`).
        """
        if run.duration < self.min_still_s or run.n < 2:
            return None
        mean = run.accel_mean
        norm = float(np.linalg.norm(mean))
        if not (math.isfinite(norm) and norm > 0):
            return None
        u = mean / norm
        white = float((u * u) @ run.acc.within) / max(run.acc.w, 1.0) / run.n
        return {'u': u, 'd': norm - self.model.gravity, 'se': math.sqrt(white * ratio),
                't': run.t_stop, 'temp': run.temp, 'ratio': float(ratio)}

    def observe(self, obs):
        """Add one confirmed observation and check again; return the :class:`HealthResult`."""
        u = obs['u']
        self.periods += 1
        self.clusters = [c for c in self.clusters if obs['t'] - c['t'] <= self.memory_s
                         and float(c['u'] @ u) < self.cos_cluster]
        self.clusters.append(obs)
        self.clusters = self.clusters[-self.max_orientations:]
        self.result = self.check(obs['temp'])
        self.result.time_s = float(obs['t'])
        self.result.mean_noise_ratio = obs.get('ratio', float('nan'))
        if self.result.level == 'recalibrate':
            self.failures += 1
            if self.first_failure is None:
                self.first_failure = self.result
        elif self.result.level == 'warn':
            self.warnings += 1
            if self.first_warning is None:
                self.first_warning = self.result
        return self.result

    def explained(self, u1, u2, temp1, temp2):
        """
        Return how much |a| may differ between two rests on a calibration that is fine, m/s².

        Four standard deviations of the difference of the calibration's error, the
        allowance and the temperature's share at the two directions (the same bias
        moves |a| by ``(u1 - u2)·δb`` between them); used by :mod:`.inertial`.
        """
        U = np.array([u1, u2])
        C = self._null(U, np.array([temp1, temp2]))[0]
        var = C[0, 0] + C[1, 1] - 2.0 * C[0, 1]
        return 4.0 * math.sqrt(max(var, 0.0))

    def _null(self, U, temps):
        """Return (C, base, explains (3,) m/s², tempco source) at directions ``U``, temps."""
        m = self.model
        Us = m.sensor_directions(U)
        base = m.systematic(U) + np.eye(len(U)) * m.residual ** 2
        a = np.asarray(self.prior.allowance, float)
        C = base + (Us * a) @ (Us * a).T
        out = np.array([m.outside(t) for t in temps])
        explains, source = np.zeros(3), ''
        if np.any(out > 0):
            rows = []
            for u, t, o in zip(U, temps, out):
                c, source = m.tempco(u, t, self.prior)
                rows.append(np.asarray(c, float) * o)
            W = Us * np.array(rows) / TEMPCO_SIGMAS
            C = C + W @ W.T
            explains = np.max(np.abs(np.array(rows)), axis=0)
        return C, base, explains, source

    def check(self, temp=float('nan')):
        """Return the :class:`HealthResult` of the orientations held now at ``temp`` °C."""
        m = self.model
        r = HealthResult(periods=self.periods, orientations=len(self.clusters),
                         false_alarm=self.false_alarm, temperature_c=temp,
                         temperature_range_c=m.temperature_range,
                         allowance_mg=[float(v / MG) for v in self.prior.allowance],
                         allowance_source=self.prior.allowance_source)
        if not self.clusters:
            r.message = f'no still period of at least {self.min_still_s:g} s yet'
            return r
        U = np.array([c['u'] for c in self.clusters])
        d = np.array([c['d'] for c in self.clusters])
        se = np.array([c['se'] for c in self.clusters])
        C, base, explains, source = self._null(U, np.array([c['temp'] for c in self.clusters]))
        C = C + np.diag(se ** 2)
        base = base + np.diag(se ** 2)
        k = len(d)
        r.chi2 = float(d @ np.linalg.solve(C, d))
        r.threshold = chi2_quantile(self.false_alarm, k)
        r.p_value = chi2_survival(r.chi2, k)
        z = np.abs(d) / np.sqrt(np.diag(C))
        worst = int(np.argmax(z))
        r.disagreement_mg = float(d[worst] / MG)
        r.predicted_mg = float(math.sqrt(C[worst, worst]) / MG)
        where = orientation_words(m.sensor_directions(U[worst:worst + 1])[0])
        r.temperature_outside_c = m.outside(temp)
        r.temperature_explains_mg = [float(v / MG) for v in explains]
        r.tempco_source = source
        failed = r.chi2 > r.threshold
        stats = (f'χ² {r.chi2:.1f} on {k} orientation{"s" if k > 1 else ""}, limit '
                 f'{r.threshold:.1f} at a false-alarm rate of {self.false_alarm:g} per check')
        size = (f'|a| - g = {r.disagreement_mg:+.2f} mg at {where} (expected within '
                f"±{r.predicted_mg:.2f} mg 1σ: the calibration's predicted error there, "
                f'the fit residual, the noise, the allowance for changes between sessions'
                + (' and the temperature' if np.any(explains > 0) else '') + ')')
        if r.temperature_outside_c > self.margin_c:
            lo, hi = m.temperature_range
            r.warning = (f'the temperature {temp:.1f} degC is {r.temperature_outside_c:.1f} degC '
                         f'outside the calibrated range {lo:.1f} .. {hi:.1f} degC: it could '
                         f'explain up to ±{float(np.max(explains)) / MG:.1f} mg per axis '
                         f'({source}); a calibration at this temperature (fit --thermal) '
                         'removes the doubt')
        if failed:
            self._cause(r, U, d, base)
            r.level = 'recalibrate'
            r.message = (f'recalibrate: {size}; {stats}; likely cause: {r.cause}'
                         + (f'; besides, {r.warning}' if r.warning else ''))
        elif r.warning:
            r.level = 'warn'
            r.cause = 'temperature outside the calibrated range'
            r.message = (f'warning: {r.warning}; the acceleration agrees within that, no need '
                         f'to recalibrate: {size}; {stats}')
        else:
            r.level = 'ok'
            r.message = f'consistent with gravity: {size}; {stats}'
        if m.cov is None:
            r.notes.append('the calibration file has no parameter covariance: its error is '
                           'taken as predicted_accuracy/√3 per orientation, independent')
        if m.temperature_range is None:
            r.notes.append('the calibration has no temperature range: temperature not checked')
        return r

    def _cause(self, r, U, d, C):
        """Fit a bias shift and a scale change to ``d``; name what the data allow."""
        Us = self.model.sensor_directions(U)
        W = np.linalg.cholesky(np.linalg.inv(C)).T       # whitening: WᵀW = C⁻¹
        fits = {}
        for name, X in (('bias', Us), ('scale', self.model.gravity * Us ** 2)):
            A, y = W @ X, W @ d
            beta, _, rank, _ = np.linalg.lstsq(A, y, rcond=1e-8)
            resid = float(np.sum((y - A @ beta) ** 2))
            dof = len(d) - int(rank)
            fits[name] = (beta, resid, dof,
                          dof > 0 and resid > chi2_quantile(RULE_OUT, dof))
        r.bias_shift_mg = [float(v / MG) for v in fits['bias'][0]]
        r.scale_change_ppm = [float(v * 1e6) for v in fits['scale'][0]]
        bias_out, scale_out = fits['bias'][3], fits['scale'][3]
        shift = np.array(r.bias_shift_mg)
        shift_words = ('a bias shift of about ('
                       + ', '.join(f'{v:+.1f}' for v in shift) + ') mg on (x, y, z)'
                       + (' (its part along the orientations seen)' if fits['bias'][2] <= 0
                          or len(d) < 3 else ''))
        if bias_out and scale_out:
            r.cause = ('neither a bias shift nor a scale change alone explains it '
                       '(the sensor changed in more than one way, or was damaged)')
        elif scale_out:
            r.cause = shift_words
        elif bias_out:
            big = int(np.argmax(np.abs(r.scale_change_ppm)))
            r.cause = (f'a scale change (about {r.scale_change_ppm[big] / 1e4:+.2f} % on '
                       f'{"xyz"[big]}; a different local gravity looks the same)')
        else:
            r.cause = (f'{shift_words}, or a scale change: {len(d)} orientation'
                       f'{"s" if len(d) > 1 else ""} cannot tell them apart (a bias shift '
                       'is the usual one after a knock, a re-mount or a power-up)')
