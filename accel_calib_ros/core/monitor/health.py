"""
Calibration health: whether the corrected acceleration at rest still reads gravity.

Each still period of at least ``min_still_s`` gives one observation: the direction ``u``
of its mean corrected acceleration and the disagreement ``d = |mean| - g`` (``g`` the
calibration's gravity). Observations within ``cluster_deg`` of each other are one
orientation; the newest period at each orientation stands for it (older ones are
forgotten after ``memory_s``).

**The null hypothesis** (the calibration is as good as it said, nothing changed) gives
the vector ``d`` over the k orientations a covariance of three parts:

- the calibration's own error: at a given orientation it is *systematic*, the same in
  every still period there, not noise: ``J(u) Σ J(u')ᵀ`` with ``Σ`` the fit's parameter
  covariance and ``J`` the derivative of ``|T⁻¹(raw - b)|`` (so it is correlated across
  orientations, and more still periods at one orientation do not shrink it), scaled up
  to the predicted accuracy when that is larger (a ``gn`` fit's cross-axis allowance);
  without a covariance, ``predicted_accuracy² / 3`` per orientation, independent;
- an ``allowance`` for the bias changes these parts make between power-ups (about 1 mg
  measured on the MPU-6050 recordings) that no one would recalibrate for: a random bias
  of that size per axis, ``a² U Uᵀ``;
- the fit's residual (its misfit at its own windows) and the noise of this mean.

The statistic ``dᵀ C⁻¹ d`` is χ² with k degrees of freedom under the null; the check
fails when it exceeds the ``1 - false_alarm`` quantile: ``false_alarm`` is the chance
that one check fails on a calibration that is fine (Gaussian errors of the stated
sizes; checks at the same orientations repeat nearly the same test, so the daily rate
is far below ``false_alarm`` x checks).

**The cause**, named only as far as the orientations allow: a temperature outside the
calibrated range (plus ``margin_c``) is named first, and fails the check on its own;
else a bias shift (``d = u·δb``) and a scale change (``d = g Σ uᵢ² δsᵢ``) are fitted to
``d`` by generalised least squares; a model is ruled out when its residual χ² is beyond
the 1 % quantile of its degrees of freedom (orientations minus the parameters they
determine). With too few orientations to tell, the words say so.

A bias shift perpendicular to every orientation seen changes no ``|a|``: no
accelerometer-only check can see it (a wheeled robot that only rests upright sees only
the z axis).
"""

from dataclasses import dataclass, field
import math

import numpy as np

from .stats import chi2_quantile, chi2_survival
from ..constants import G0
from ..finite import finite_or_none

MG = G0 * 1e-3
"""One milli-g, m/s²."""
RULE_OUT = 0.01
"""A cause is ruled out when its residual χ² is beyond this upper quantile."""


class ErrorModel:
    """
    What a calibration says about its own error at rest, per orientation.

    :param cal: a Calibration (``core.calibration``): T, gravity, covariance,
        predicted_accuracy, residual_rms, temperature_range_c, thermal, level_rotation().
    """

    def __init__(self, cal):
        self.gravity = float(cal.gravity)
        self.L = np.asarray(cal.level_rotation(), float)
        self.R = np.linalg.inv(np.asarray(cal.T, float))
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
            faces = np.vstack([np.eye(3), -np.eye(3)])
            sphere = np.mean([np.trace(self._vector_jacobian(f) @ self.cov
                                       @ self._vector_jacobian(f).T) for f in faces])
            if sphere > 0:
                self.inflation = max(1.0, self.predicted ** 2 / sphere)

    def _vector_jacobian(self, u_sensor):
        """(3, 9) derivative of the corrected vector at g u (sensor frame) by the parameters."""
        c = self.gravity * np.asarray(u_sensor, float)
        J = np.zeros((3, 9))
        for k, (i, j) in enumerate(zip(*np.triu_indices(3))):
            J[:, k] = -self.R[:, i] * c[j]
        J[:, 6:] = -self.R
        return J

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
        J = np.array([u @ self._vector_jacobian(u) for u in Us])
        return self.inflation * (J @ self.cov @ J.T)

    def outside(self, temp):
        """Return how far ``temp`` °C lies outside the calibrated range (0 inside or unknown)."""
        if self.temperature_range is None or not math.isfinite(temp):
            return 0.0
        low, high = self.temperature_range
        return max(low - temp, temp - high, 0.0)


@dataclass
class HealthResult:
    """
    The latest health check, in numbers and words.

    ``level``: 'ok', 'warn' (recalibrate) or 'unknown' (nothing to judge yet).
    Accelerations in mg (1 mg = 9.80665e-3 m/s²), temperatures in °C.
    """

    level: str = 'unknown'
    message: str = 'no still period checked yet'
    time_s: float = float('nan')
    cause: str = ''
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
    bias_shift_mg: list = None
    scale_change_ppm: list = None
    notes: list = field(default_factory=list)

    @property
    def healthy(self):
        """Return True (ok), False (recalibrate) or None (unknown)."""
        return None if self.level == 'unknown' else self.level == 'ok'

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
        out['recalibrate'] = self.level == 'warn'
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
    The health check of one calibration, fed with still periods (see the module docstring).

    :param model: :class:`ErrorModel` of the calibration in use.
    :param false_alarm: chance that one check fails on a calibration that is fine.
    :param allowance: bias change per axis that is not worth a recalibration, m/s².
    :param min_still_s: shortest still period used, s.
    :param cluster_deg: periods closer than this are one orientation, degrees.
    :param memory_s: an orientation not seen for this long is forgotten, s.
    :param margin_c: temperatures this far outside the calibrated range are flagged, °C.
    :param max_orientations: most orientations remembered (the oldest goes).
    """

    def __init__(self, model, false_alarm=1e-4, allowance=1.0 * MG, min_still_s=2.0,
                 cluster_deg=10.0, memory_s=3600.0, margin_c=2.0, max_orientations=12):
        self.model = model
        self.false_alarm, self.allowance = float(false_alarm), float(allowance)
        self.min_still_s, self.memory_s = float(min_still_s), float(memory_s)
        self.cos_cluster = math.cos(math.radians(cluster_deg))
        self.margin_c, self.max_orientations = float(margin_c), int(max_orientations)
        self.clusters = []          # dicts: u, d, se, t, temp
        self.periods = 0            # still periods checked
        self.failures = 0           # checks that said recalibrate
        self.first_failure = None   # the first of them (HealthResult)
        self.result = HealthResult(false_alarm=self.false_alarm,
                                   temperature_range_c=model.temperature_range)

    def observe(self, run):
        """
        Add one still period (:class:`~.blocks.Run`) and check again.

        :return: the new :class:`HealthResult`, or None when the period is too short.
        """
        if run.duration < self.min_still_s or run.n < 2:
            return None
        mean = run.accel_mean
        norm = float(np.linalg.norm(mean))
        if not (math.isfinite(norm) and norm > 0):
            return None
        u = mean / norm
        obs = {'u': u, 'd': norm - self.model.gravity, 'se': run.accel_noise / math.sqrt(run.n),
               't': run.t_stop, 'temp': run.temp}
        self.periods += 1
        self.clusters = [c for c in self.clusters if run.t_stop - c['t'] <= self.memory_s
                         and float(c['u'] @ u) < self.cos_cluster]
        self.clusters.append(obs)
        self.clusters = self.clusters[-self.max_orientations:]
        self.result = self.check(obs['temp'])
        self.result.time_s = float(run.t_stop)
        if self.result.level == 'warn':
            self.failures += 1
            if self.first_failure is None:
                self.first_failure = self.result
        return self.result

    def check(self, temp=float('nan')):
        """Return the :class:`HealthResult` of the orientations held now at ``temp`` °C."""
        m = self.model
        r = HealthResult(periods=self.periods, orientations=len(self.clusters),
                         false_alarm=self.false_alarm, temperature_c=temp,
                         temperature_range_c=m.temperature_range)
        if not self.clusters:
            r.message = f'no still period of at least {self.min_still_s:g} s yet'
            return r
        U = np.array([c['u'] for c in self.clusters])
        d = np.array([c['d'] for c in self.clusters])
        se = np.array([c['se'] for c in self.clusters])
        base = m.systematic(U) + np.diag(m.residual ** 2 + se ** 2)
        C = base + self.allowance ** 2 * (U @ U.T)
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
        hot = r.temperature_outside_c > self.margin_c
        failed = r.chi2 > r.threshold
        stats = (f'χ² {r.chi2:.1f} on {k} orientation{"s" if k > 1 else ""}, limit '
                 f'{r.threshold:.1f} at a false-alarm rate of {self.false_alarm:g} per check')
        size = (f'|a| - g = {r.disagreement_mg:+.2f} mg at {where} (expected within '
                f"±{r.predicted_mg:.2f} mg 1σ: the calibration's predicted error there, "
                f'the fit residual, the noise and a {self.allowance / MG:g} mg allowance for '
                'power-up changes)')
        if failed:
            self._cause(r, U, d, base)
        if hot:
            lo, hi = m.temperature_range
            r.cause = 'temperature outside the calibrated range' + (
                f' (the acceleration disagrees too: {r.cause})' if failed else '')
            r.level = 'warn'
            r.message = (f'recalibrate: the temperature {temp:.1f} degC is '
                         f'{r.temperature_outside_c:.1f} degC outside the calibrated range '
                         f"{lo:.1f} .. {hi:.1f} degC, where the calibration's accuracy is "
                         'unknown (fit --thermal with data at this temperature); '
                         + (f'the acceleration disagrees: {size}; {stats}' if failed else
                            f'the acceleration still agrees: {size}; {stats}'))
        elif failed:
            r.level = 'warn'
            r.message = f'recalibrate: {size}; {stats}; likely cause: {r.cause}'
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
