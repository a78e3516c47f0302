"""
The whole IMU from one session: the gyroscope and magnetometer beside the accelerometer.

What every front door shares once the accelerometer is calibrated: run
:func:`core.gyroscope.fit.fit_gyro` and :func:`core.magnetometer.fit.fit_magnetometer` on
the same recording and static windows, and judge each sensor on its own
(:class:`SensorOutcome`). A sensor whose data are absent or insufficient is reported as
such and never fails the others:

- ``calibrated``: fitted, converged, plausible, and its predicted accuracy within the
  sensor's limit (relative for the gyroscope, µT for the magnetometer): stored;
- ``absent``: the data have no such columns (or no samples of that sensor);
- ``insufficient``: the session does not determine it (a rotation axis without a turn,
  too few moves, too little of the sphere of field directions, too few static
  windows for the alignment); the reason says what to do;
- ``refused``: fitted, but its predicted accuracy exceeds the limit or the result is
  implausible (wrong units): not stored;
- ``not fitted``: its data are there but the accelerometer calibration it builds on
  failed; ``not collected``: the calibration node did not keep what it needs.

numpy/scipy only (through the two fits); no files, no ROS, no front door's words (a
limit's name comes in as an argument).
"""

from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from .calibration import gyro_problems, magnetometer_problems, MagnetometerPart, MAX_GYRO_BIAS
from .errors import CalibrationError, InputError
from .finite import finite_list, finite_or_none

STATUSES = ('calibrated', 'absent', 'insufficient', 'refused', 'not fitted', 'not collected')
"""Words of :attr:`SensorOutcome.status`."""

DEFAULT_MAX_GYRO_ERROR = 0.01
"""
Acceptance limit of the gyroscope's predicted accuracy (relative RMS rate error: 1 %).

An uncalibrated MPU-9250 gyro is off by about 2-3 % (±3 % sensitivity, ±2 % cross
axis); a simulated hand-held session of 24 poses predicts 0.03-0.05 %, the real
MPU-6050 session of ../shared/data (7 usable moves) 0.6 %, the imu_tk Xsens session
0.2 %. A fit predicting worse than 1 % removes too little of the 2-3 % to be worth
trusting and is not stored.
"""

DEFAULT_MAX_MAG_ERROR = 1.0
"""
Acceptance limit of the magnetometer's predicted accuracy, µT (RMS over directions).

Uncalibrated: tens of µT (hard iron); a hand-held session predicts 0.02-0.1 µT. 1 µT is
about 2° of heading where the horizontal field is 25 µT.
"""


@dataclass
class SensorOutcome:
    """
    One sensor's result beside the accelerometer.

    :param sensor: 'gyroscope' or 'magnetometer'.
    :param status: one of :data:`STATUSES`.
    :param reason: why it is not calibrated (None when it is).
    :param result: the fit (GyroCalibration / MagnetometerCalibration) or None.
    :param limit: the acceptance limit its predicted accuracy was held to.
    :param unit: unit of the predicted accuracy ('relative' or 'uT').
    """

    sensor: str
    status: str
    reason: Optional[str] = None
    result: object = None
    limit: float = float('nan')
    unit: str = ''
    details: dict = field(default_factory=dict)

    @property
    def calibrated(self):
        """Tell whether the sensor's calibration is to be stored and used."""
        return self.status == 'calibrated'

    @property
    def predicted_accuracy(self):
        """Return the fit's predicted accuracy (None without a fit or when not finite)."""
        return None if self.result is None else finite_or_none(self.result.predicted_accuracy)

    def line(self):
        """One line for a person: the sensor, its status and the figure or the reason."""
        if self.calibrated:
            acc = self.predicted_accuracy
            figure = (f'{100 * acc:.3f} % of the rate' if self.unit == 'relative'
                      else f'{acc:.3f} µT')
            return f'{self.sensor}: calibrated, predicted accuracy {figure} RMS ' \
                f'({self.result.message})'
        return f'{self.sensor}: {self.status}: {self.reason}'

    def to_dict(self):
        """JSON-ready summary (numbers finite or None)."""
        d = {'status': self.status, 'reason': self.reason,
             'predicted_accuracy': self.predicted_accuracy,
             'max_predicted_error': finite_or_none(self.limit), 'unit': self.unit}
        d.update(self.details)
        return d


def absent(sensor, reason, unit=''):
    """Return the outcome of a sensor without data."""
    return SensorOutcome(sensor, 'absent', reason, unit=unit)


def _gyro_details(g):
    return {'T': finite_list(g.T) if g.converged else None, 'bias': finite_list(g.bias),
            'moves_used': g.moves_used,
            'moves_dropped': [{'window': m.window, 'reason': m.reason}
                              for m in g.moves_dropped],
            'excitation_deg': finite_list(g.excitation_deg), 'missing_axes': list(g.missing_axes),
            'residual_rms_deg': finite_or_none(g.residual_rms_deg), 'converged': bool(g.converged),
            'message': g.message}


def solve_gyro(samples, windows=None, accel=None, max_error=DEFAULT_MAX_GYRO_ERROR,
               full_scale=None, limit_name=''):
    """
    Calibrate the gyroscope's scale and misalignment from the session (interface.md §9).

    :param samples: Samples (with ``gyro`` rad/s, or None: absent).
    :param windows: the static windows (start/stop indices) or None to detect them.
    :param accel: the accelerometer Calibration (corrects the gravity directions).
    :param max_error: acceptance limit of the predicted accuracy (relative).
    :param full_scale: gyro range, rad/s, for the clipping test (None: from the data).
    :param limit_name: how the front door spells ``max_error`` ('': not named).
    :returns: SensorOutcome with the GyroCalibration as ``result`` when fitted.
    """
    if samples.gyro is None:
        return absent('gyroscope', 'no angular rate', 'relative')
    from .gyroscope.fit import fit_gyro
    out = SensorOutcome('gyroscope', 'insufficient', limit=max_error, unit='relative')
    try:
        g = fit_gyro(samples, windows, accel=accel, full_scale=full_scale)
    except (CalibrationError, InputError, np.linalg.LinAlgError) as err:
        out.reason = str(err)
        return out
    out.result = g
    out.details = _gyro_details(g)
    if g.missing_axes:
        out.reason = g.message
    elif np.abs(g.bias).max() > MAX_GYRO_BIAS:
        out.status = 'refused'
        out.reason = (f'implausible: a gyro bias of {np.abs(g.bias).max():.3g} rad/s (more '
                      f'than {MAX_GYRO_BIAS:g}); are gx gy gz in rad/s?')
    elif not g.converged:
        out.reason = f'the fit did not converge ({g.message})'
    elif gyro_problems(g.T):
        out.status = 'refused'
        out.reason = f'implausible ({gyro_problems(g.T)[0]}); are gx gy gz in rad/s?'
    elif not g.predicted_accuracy <= max_error:
        out.status = 'refused'
        out.reason = (f'predicted accuracy {100 * g.predicted_accuracy:.3f} % exceeds the '
                      f'limit {100 * max_error:.3g} %{_named(limit_name)}; turn through more '
                      'moves about every axis')
    else:
        out.status, out.reason = 'calibrated', None
    return out


def _mag_details(m):
    return {'T': finite_list(m.T), 'hard_iron_uT': finite_list(m.hard_iron_uT),
            'R': finite_list(m.R),
            'field_uT': finite_or_none(m.field_uT), 'dip_deg': finite_or_none(m.dip_deg),
            'coverage': finite_or_none(m.coverage), 'samples_used': int(m.samples_used),
            'windows_used': int(m.windows_used), 'alignment_fitted': bool(m.alignment_fitted),
            'residual_rms_uT': finite_or_none(m.residual_rms_uT), 'converged': bool(m.converged),
            'message': m.message}


def solve_magnetometer(samples, windows=None, accel=None, max_error=DEFAULT_MAX_MAG_ERROR,
                       field_uT=None, limit_name=''):
    """
    Calibrate the magnetometer: soft and hard iron, alignment, field and dip (interface.md §10).

    :param samples: Samples (with ``mag`` µT, NaN rows without a sample; None: absent).
    :param windows: the static windows or None to detect them.
    :param accel: the accelerometer Calibration (corrects the up directions).
    :param max_error: acceptance limit of the predicted accuracy, µT.
    :param field_uT: known field magnitude, µT, or None to fit it.
    :param limit_name: how the front door spells ``max_error`` ('': not named).
    :returns: SensorOutcome with the MagnetometerCalibration as ``result`` when fitted.
    """
    if samples.mag is None or not samples.mag_rows.any():
        return absent('magnetometer', 'no magnetic field' if samples.mag is None
                      else 'no magnetometer sample', 'uT')
    from .magnetometer.fit import fit_magnetometer
    out = SensorOutcome('magnetometer', 'insufficient', limit=max_error, unit='uT')
    try:
        m = fit_magnetometer(samples, windows, accel=accel, field_uT=field_uT)
    except (CalibrationError, InputError, np.linalg.LinAlgError) as err:
        out.reason = str(err)
        out.details = {'coverage': finite_or_none(magnetometer_coverage(samples.mag))}
        return out
    out.result = m
    out.details = _mag_details(m)
    problems = magnetometer_problems(m.T, m.hard_iron_uT, m.R, m.field_uT, m.dip_deg) \
        if np.isfinite(m.dip_deg) else ['no dip angle']
    if problems:
        out.status = 'refused'
        out.reason = f'implausible ({problems[0]})'
    elif not m.alignment_fitted:
        out.reason = m.message
    elif not m.converged:
        out.reason = f'the fit did not converge ({m.message})'
    elif not m.predicted_accuracy <= max_error:
        out.status = 'refused'
        out.reason = (f'predicted accuracy {m.predicted_accuracy:.3f} µT exceeds the limit '
                      f'{max_error:g} µT{_named(limit_name)}; turn the sensor through more '
                      'orientations and hold more poses')
    else:
        out.status, out.reason = 'calibrated', None
    return out


def _named(name):
    return f' ({name})' if name else ''


def store(cal, gyro=None, magnetometer=None):
    """
    Put the calibrated parts into the accelerometer Calibration ``cal`` (in place).

    A calibrated gyroscope brings its T, its predicted accuracy and its bias (the one the
    T was fitted with: one bias per calibration); a calibrated magnetometer its part.
    Outcomes that are not calibrated change nothing.
    """
    if gyro is not None and gyro.calibrated:
        g = gyro.result
        cal.gyro_T = np.array(g.T, float)
        cal.gyro_bias = np.array(g.bias, float)
        cal.gyro_predicted_accuracy = float(g.predicted_accuracy)
    if magnetometer is not None and magnetometer.calibrated:
        m = magnetometer.result
        noise = float(m.sigma_uT) if np.isfinite(m.sigma_uT) else None
        cal.magnetometer = MagnetometerPart(
            T=m.T, hard_iron_uT=m.hard_iron_uT, R=m.R, field_uT=m.field_uT,
            dip_deg=m.dip_deg, predicted_accuracy=m.predicted_accuracy,
            noise_std_uT=noise)
    return cal


def sensors_dict(accel_status, gyro, magnetometer, accel_reason=None):
    """Return the per-sensor status object of ``fit --json`` and the node."""
    return {'accelerometer': {'status': accel_status, 'reason': accel_reason},
            'gyroscope': gyro.to_dict(), 'magnetometer': magnetometer.to_dict()}


def json_keys(gyro, magnetometer):
    """Return the flat keys (interface.md §9, §10) ``gyro_*``, ``mag_*``: None if not fitted."""
    d = dict.fromkeys(('gyro_T', 'gyro_bias', 'gyro_predicted_accuracy', 'mag_T',
                       'mag_hard_iron_uT', 'mag_R', 'mag_field_uT', 'mag_dip_deg',
                       'mag_predicted_accuracy'))
    if gyro is not None and gyro.calibrated:
        g = gyro.result
        d.update(gyro_T=finite_list(g.T), gyro_bias=finite_list(g.bias),
                 gyro_predicted_accuracy=finite_or_none(g.predicted_accuracy))
    if magnetometer is not None and magnetometer.calibrated:
        m = magnetometer.result
        d.update(mag_T=finite_list(m.T), mag_hard_iron_uT=finite_list(m.hard_iron_uT),
                 mag_R=finite_list(m.R),
                 mag_field_uT=finite_or_none(m.field_uT), mag_dip_deg=finite_or_none(m.dip_deg),
                 mag_predicted_accuracy=finite_or_none(m.predicted_accuracy))
    return d


# -- advice ---------------------------------------------------------------------------------

def field_directions(mag):
    """
    Return the unit field directions (M, 3) of the magnetometer samples, hard iron removed.

    Seen from the centre of the best-fitting ellipsoid (soft iron removed too) when the
    samples determine one, else from the middle of their range. Samples that hardly
    change (their spread within ``MIN_FIELD_TO_NOISE`` times their noise) have seen one
    direction: none is returned for them.

    :param mag: (N, 3) µT, NaN rows ignored.
    """
    from .accelerometer.ml import fit_ml
    from .magnetometer.fit import MIN_FIELD_TO_NOISE
    m = np.asarray(mag, float).reshape(-1, 3)
    m = m[np.all(np.isfinite(m), axis=1)]
    if len(m) < 10:
        return np.zeros((0, 3))
    try:
        ml = fit_ml(m, radius=1.0)
        if float(np.linalg.det(ml.T)) ** (1.0 / 3.0) >= MIN_FIELD_TO_NOISE * ml.sigma:
            return ml.directions
    except (CalibrationError, InputError, np.linalg.LinAlgError, ValueError):
        pass
    step = np.diff(m, axis=0)                  # noise from successive samples (robust)
    noise = float(np.max(np.median(np.abs(step - np.median(step, axis=0)), axis=0))) \
        * 1.4826 / np.sqrt(2.0)
    extent = float(np.max(m.max(axis=0) - m.min(axis=0)))
    if not extent > MIN_FIELD_TO_NOISE * noise:
        return np.zeros((0, 3))
    d = m - 0.5 * (m.max(axis=0) + m.min(axis=0))
    return d / np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)


def magnetometer_coverage(mag):
    """Return the fraction of the sphere of field directions that samples (N, 3) µT visited."""
    from .magnetometer.fit import sphere_coverage
    return sphere_coverage(field_directions(mag))


def field_advice(mag, dip_deg=None):
    """
    Say how much of the sphere of field directions was seen and which part is missing.

    :param mag: (N, 3) µT (NaN rows ignored).
    :param dip_deg: the field's dip, degrees, when known (for the words).
    :returns: dict ``coverage`` (fraction), ``enough`` (bool: at least the fit's minimum),
        ``missing_direction`` ((3,) unit vector in the sensor frame towards the unseen
        cells, or None) and ``advice`` (words).
    """
    from .magnetometer.fit import coverage_cells, MIN_COVERAGE, MIN_SPREAD, visited_cells
    d = field_directions(mag)
    seen = visited_cells(d)
    cover = float(np.mean(seen))
    spread = float(np.linalg.eigvalsh(d.T @ d / len(d))[0]) if len(d) else 0.0
    out = {'coverage': cover, 'enough': cover >= MIN_COVERAGE and spread >= MIN_SPREAD,
           'missing_direction': None, 'advice': ''}
    if not len(d):
        out['advice'] = ('no magnetometer samples yet' if np.isfinite(
            np.asarray(mag, float)).all(axis=-1).sum() < 10 else 'the field has hardly changed '
            'direction yet (0% of the sphere)') + ': turn the sensor while recording'
        return out
    if cover >= MIN_COVERAGE and spread < MIN_SPREAD:
        out['advice'] = (f'the field has been seen from {cover:.0%} of the sphere but its '
                         'directions stay near one cone (the sensor turned about one axis '
                         'only): turn it upside down and onto each side too')
        return out
    if seen.all():
        out['advice'] = 'the field has been seen from the whole sphere'
        return out
    cells = coverage_cells(len(seen))
    gap = cells[~seen].sum(axis=0)
    if np.linalg.norm(gap) < 1e-9 * np.sum(~seen):
        gap = cells[~seen][0]
    gap = gap / np.linalg.norm(gap)
    out['missing_direction'] = gap.tolist()
    axis = int(np.argmax(np.abs(gap)))
    words = f'{"+" if gap[axis] > 0 else "-"}{"xyz"[axis]}'
    where = 'north and down' if dip_deg is None or dip_deg >= 0 else 'north and up'
    need = 'enough' if out['enough'] else f'needs {MIN_COVERAGE:.0%}'
    out['advice'] = (f'the field has been seen from {cover:.0%} of the sphere ({need}); to '
                     f'fill the rest turn the sensor so that its {words} axis points along '
                     f'the field ({where}), and through the orientations in between')
    return out


def gyro_advice(samples, windows=None, accel=None):
    """
    Say which rotation axis the moves between the static windows have not turned about.

    :param samples: Samples with ``gyro`` (None: nothing to say).
    :param windows: the static windows or None to detect them.
    :param accel: the accelerometer calibration, when there is one.
    :returns: dict ``status`` ('absent', 'insufficient' or 'ok'), ``missing_axes``
        (names; None while too few moves to tell), ``excitation_deg`` ((3,) or None),
        ``moves_used`` (None while too few) and ``advice`` (words: the turn to make, from
        ``core.gyroscope.fit.TURN_ADVICE``).
    """
    from .gyroscope.fit import fit_gyro, TURN_ADVICE
    out = {'status': 'absent', 'missing_axes': [], 'excitation_deg': None, 'moves_used': 0,
           'advice': 'the data have no gx gy gz'}
    if samples.gyro is None:
        return out
    try:
        g = fit_gyro(samples, windows, accel=accel)
    except (CalibrationError, InputError, np.linalg.LinAlgError) as err:
        out.update(status='insufficient', missing_axes=None, moves_used=None,
                   advice=f'{err}'.split('. Dropped')[0] + ', and '
                   'between them turn about each axis: '
                   + '; '.join(f'about {a}: {w}' for a, w in TURN_ADVICE.items()))
        return out
    out.update(missing_axes=list(g.missing_axes), excitation_deg=finite_list(g.excitation_deg),
               moves_used=g.moves_used)
    if g.missing_axes:
        out.update(status='insufficient',
                   advice='; '.join(f'turn about {a}: {TURN_ADVICE[a]}' for a in g.missing_axes))
    else:
        out.update(status='ok', advice='the moves turn about all three axes')
    return out
