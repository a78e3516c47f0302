"""
Fit and accept: the one decision every front door makes the same way.

:func:`fit_and_accept` fits the accelerometer to the observations of a session
(``core.accelerometer.fit.calibrate``, temperature tables when the door asks), judges
the result (``core.acceptance.review``: convergence, predicted accuracy, physics; the
gravity-norm residual against the noise of the windows; what a calibration file may
hold) and, once it is accepted, fits the gyroscope and the magnetometer beside it
(``core.outcomes``), each judged on its own. It returns an :class:`Outcome`: the
calibration, the verdict, the refusal with the advice that fixes it, the two other
sensors' outcomes and the message. Nothing is written here (:mod:`.finish` saves and
records, :mod:`.persist` holds how).

A door differs only in its :class:`~.settings.Settings` and in how it spells things
(:class:`~.settings.Words`).
"""

import math

import numpy as np

from .settings import (FIT, GUIDE, NODE, Settings, SI_UNITS, THERMAL_MODES,  # noqa: F401
                       Words)
from ..core.acceptance import review
from ..core.errors import CalibrationError, InputError
from ..core.outcomes import absent, json_keys, SensorOutcome, sensors_dict

MIN_WINDOW_NOISE = 0.005
"""Floor of the expected window-mean error, m/s² (about 0.5 mg).

White noise averages down to a few 1e-3 m/s² in a 2 s window, but a consumer MEMS
accelerometer's bias does not repeat between poses better than about 0.5 mg (bias
instability, hand and table vibration), and a 6-parameter ``gn`` fit leaves a
residual of that order on a sensor with small cross-axis terms. Below this floor a
residual is never a reason to refuse."""
NOT_FITTED = 'not fitted: the accelerometer calibration was refused'
"""Reason of a gyroscope or magnetometer that was not fitted because of the accelerometer."""


class Outcome:
    """
    The result of a session: :func:`fit_and_accept`, then ``finish.finish_session``.

    :param calibration: the fitted Calibration (with the gyroscope and magnetometer parts
        that passed, when accepted), or None when no fit could be made.
    :param verdict: the review of the fit (None without a fit).
    :param refusal: why it may not be used (None: accepted), with the advice that fixes it.
    :param gyro: the gyroscope's SensorOutcome; ``magnetometer``: the magnetometer's.
    :param warnings: what the user should know about an accepted calibration.
    :param thermal: whether temperature tables were fitted.
    :param observations: the observations the fit was given.
    :param carried: what the file being replaced carried forward (:mod:`.persist`).
    :param saved_to: where it was written, or None.
    :param limit: the predicted-accuracy limit it was held to, m/s².
    :param history: what the history recorded (``db``, ``session``, ``windows_added``), or
        None.
    :param notes: what went wrong after an accepted calibration was saved (the history
        could not take it): the door shows each as a warning.
    :param cause: None when the data decided; 'input' when the settings cannot be fitted
        as given (an unknown method, temperature tables without temperatures); 'output'
        when a file it was asked to write could not be written (the refusal, or a note
        after the saved calibration, says which and why). A command line reports those
        two as errors of its arguments (exit status 2).
    """

    __slots__ = ('calibration', 'verdict', 'refusal', 'gyro', 'magnetometer', 'warnings',
                 'thermal', 'observations', 'carried', 'saved_to', 'limit', 'history', 'notes',
                 'cause')

    def __init__(self, calibration=None, verdict=None, refusal=None, gyro=None,
                 magnetometer=None, warnings=None, thermal=False, observations=0, carried=None,
                 saved_to=None, limit=math.nan, history=None, notes=None, cause=None):
        self.calibration, self.verdict, self.refusal = calibration, verdict, refusal
        self.gyro, self.magnetometer = gyro, magnetometer
        self.warnings = [] if warnings is None else warnings
        self.thermal, self.observations = thermal, observations
        self.carried = [] if carried is None else carried
        self.saved_to, self.limit, self.history = saved_to, limit, history
        self.notes = [] if notes is None else notes
        self.cause = cause

    def replace(self, **changes):
        """Return a copy with ``changes``."""
        fields = {name: getattr(self, name) for name in self.__slots__}
        fields.update(changes)
        return Outcome(**fields)

    def __repr__(self):
        return f'Outcome(refusal={self.refusal!r}, observations={self.observations})'

    @property
    def accepted(self):
        """Whether the calibration may be used (and written)."""
        return self.refusal is None and self.calibration is not None

    @property
    def predicted_accuracy(self):
        """Return the accelerometer's predicted accuracy, m/s² (None without a fit)."""
        cal = self.calibration
        acc = None if cal is None else cal.predicted_accuracy
        return acc if acc is not None and math.isfinite(acc) else None

    def refuse(self, reason):
        """Return this outcome refused for ``reason`` (the other sensors then not fitted)."""
        return refused(reason, outcome=self)

    def sensors(self, accel_status=None):
        """Return the per-sensor status object (``fit --json`` and the node's ``sensors``)."""
        status = accel_status or ('calibrated' if self.accepted else 'refused')
        return sensors_dict(status, self.gyro, self.magnetometer, self.refusal)

    def json_keys(self):
        """Return the flat ``gyro_*`` / ``mag_*`` keys (interface.md §9, §10)."""
        return json_keys(self.gyro if self.accepted else None,
                         self.magnetometer if self.accepted else None)

    def sensor_lines(self):
        """Return one line per sensor for a person."""
        return ['accelerometer: ' + ('calibrated' if self.accepted
                                     else f'refused: {self.refusal}'),
                self.gyro.line(), self.magnetometer.line()] + list(self.carried)

    def message(self):
        """Return the one-line summary (the node's ``~/calibrate`` response)."""
        if not self.accepted:
            return f'refused: {self.refusal}'
        cal = self.calibration
        bands = 0 if cal.thermal is None else len(cal.thermal.usable)
        unit = 'm/s2'
        with np.printoptions(precision=5, suppress=True):
            msg = (f'{cal.method} calibration from {self.observations} windows '
                   + (f'saved to {self.saved_to}' if self.saved_to else 'accepted')
                   + f': predicted accuracy {self.predicted_accuracy or math.nan:.4f} {unit} '
                   f'(limit {self.limit:g}), scale {np.round(cal.scale, 5).tolist()}, '
                   f'bias {np.round(cal.bias, 4).tolist()} {unit}, non-orthogonality '
                   f'{np.round(cal.nonorthogonality_deg, 3).tolist()} deg (xy, xz, yz), '
                   f'residual {cal.residual_rms:.4f} {unit}, thermal bands {bands}')
        if cal.gyro_bias is not None:
            msg += f', gyro bias {np.round(cal.gyro_bias, 5).tolist()} rad/s'
        msg += ''.join(f'. {o.line()}' for o in (self.gyro, self.magnetometer))
        msg += ''.join(f'. {line}' for line in self.carried)
        return msg


def refused(reason, imu=None, outcome=None, words=FIT, **fields):
    """
    Return a refused :class:`Outcome`: the one way every door makes one.

    :param reason: why (the door's words).
    :param imu: the session's :class:`RecordingImu` or :class:`CollectedImu` (says whether
        the gyroscope and magnetometer had data), or None (no other sensor).
    :param outcome: an outcome to refuse (its calibration kept for the message; its other
        sensors become not fitted), or None.
    :param words: the door's :class:`~.settings.Words` (why a sensor is absent).
    :param fields: other :class:`Outcome` fields (``observations``, ``limit``, ...).
    """
    if outcome is not None:
        return outcome.replace(refusal=reason, gyro=_not_fitted(outcome.gyro),
                               magnetometer=_not_fitted(outcome.magnetometer), **fields)
    gyro, magnetometer = (imu or NoImu()).not_fitted(words)
    return Outcome(refusal=reason, gyro=gyro, magnetometer=magnetometer, **fields)


def _not_fitted(outcome):
    """Return the outcome of a sensor whose accelerometer calibration was refused."""
    if outcome is None or outcome.status in ('absent', 'not collected'):
        return outcome
    return SensorOutcome(outcome.sensor, 'not fitted', NOT_FITTED, unit=outcome.unit)


def _unfitted(sensor, present, absent_reason, unit):
    if not present:
        return absent(sensor, absent_reason, unit)
    return SensorOutcome(sensor, 'not fitted', NOT_FITTED, unit=unit)


# -- the other two sensors ---------------------------------------------------------------

class NoImu:
    """A session without a gyroscope or magnetometer (the door's words say why)."""

    def solve(self, cal, settings):
        """Return (gyro, magnetometer): both absent."""
        return self.not_fitted(settings.words)

    @staticmethod
    def not_fitted(words=FIT):
        """Return (gyro, magnetometer): both absent."""
        w = words
        return absent('gyroscope', w.no_gyro, 'relative'), absent('magnetometer', w.no_mag, 'uT')


class RecordingImu:
    """
    The gyroscope and magnetometer of one recording (``accel-calib fit``).

    :param samples: the recording (``gyro`` rad/s, ``mag`` µT, or None).
    :param windows: its static windows (sample index ranges), or None to detect them.
    """

    def __init__(self, samples, windows=None):
        self.samples, self.windows = samples, windows

    def solve(self, cal, settings):
        """Fit both beside the accelerometer calibration ``cal``; return (gyro, magnetometer)."""
        from ..core.outcomes import solve_gyro, solve_magnetometer
        s, w = self.samples, settings.words
        gyro = absent('gyroscope', w.no_gyro, 'relative') if s.gyro is None else \
            solve_gyro(s, self.windows, cal, settings.max_gyro_error, limit_name=w.gyro_limit)
        if s.mag is None or not s.mag_rows.any():
            mag = absent('magnetometer', w.no_mag if s.mag is None else w.mag_unusable, 'uT')
        else:
            mag = solve_magnetometer(s, self.windows, cal, settings.max_mag_error,
                                     settings.field_uT, limit_name=w.mag_limit)
        return gyro, mag

    def not_fitted(self, words=FIT):
        """Return (gyro, magnetometer) when no accelerometer calibration was accepted."""
        s, w = self.samples, words
        return (_unfitted('gyroscope', s.gyro is not None, w.no_gyro, 'relative'),
                _unfitted('magnetometer', s.mag is not None, w.no_mag, 'uT'))


class CollectedImu:
    """
    The gyroscope and magnetometer a live session kept (``core.collector``).

    :param collector: an ``ImuCollector`` or its ``ImuSnapshot`` (None: neither was
        collected).
    :param windows: the session's WindowSet (their times place them in the samples).
    """

    def __init__(self, collector, windows):
        snapshot = getattr(collector, 'snapshot', None)
        self.collector = snapshot() if snapshot is not None else collector
        self.windows = windows

    def solve(self, cal, settings):
        """Fit both beside ``cal``; a failing fit is reported, never raised."""
        if self.collector is None:
            return self.not_fitted(settings.words)
        try:
            return self._gyro(cal, settings), self._magnetometer(cal, settings)
        except (CalibrationError, InputError, ValueError, np.linalg.LinAlgError) as err:
            return (SensorOutcome('gyroscope', 'insufficient', f'fit failed: {err}',
                                  unit='relative'),
                    SensorOutcome('magnetometer', 'insufficient', f'fit failed: {err}',
                                  unit='uT'))

    def _gyro(self, cal, settings):
        from ..core.collector import ImuCollector
        from ..core.outcomes import solve_gyro
        snap, w = self.collector, settings.words
        raw = snap.raw
        if snap.capacity <= 0:
            return SensorOutcome('gyroscope', 'not collected', w.gyro_not_kept, unit='relative')
        if raw is None or raw.gyro is None:
            return absent('gyroscope', w.no_gyro if raw is not None else w.no_samples,
                          'relative')
        gyro = solve_gyro(raw, ImuCollector.windows_in(raw.t, self.windows), cal,
                          settings.max_gyro_error, limit_name=w.gyro_limit)
        if gyro.status == 'insufficient' and snap.ring_full:
            gyro.reason += w.ring_short.format(seconds=raw.t[-1] - raw.t[0])
        return gyro

    def _magnetometer(self, cal, settings):
        from ..core.collector import ImuCollector
        from ..core.outcomes import solve_magnetometer
        snap, w = self.collector, settings.words
        mags = snap.mags
        if snap.max_mag <= 0:
            return SensorOutcome('magnetometer', 'not collected', w.mag_not_kept, unit='uT')
        if mags is None:
            return absent('magnetometer', w.mag_unusable if snap.mag_received else w.no_mag,
                          'uT')
        return solve_magnetometer(mags, ImuCollector.windows_in(mags.t, self.windows), cal,
                                  settings.max_mag_error, settings.field_uT,
                                  limit_name=w.mag_limit)

    def not_fitted(self, words=FIT):
        """Return (gyro, magnetometer) when no accelerometer calibration was accepted."""
        c, w = self.collector, words
        return (_unfitted('gyroscope', c is not None and c.gyro_seen, w.no_gyro, 'relative'),
                _unfitted('magnetometer', c is not None and c.mag_received > 0, w.no_mag,
                          'uT'))


# -- the decision --------------------------------------------------------------------------

def thermal_wanted(mode, temps, band_width_c, words=FIT):
    """
    Decide whether to fit temperature tables.

    :param mode: 'on', 'off' or 'auto' (when two bands hold enough windows each).
    :param temps: (N,) °C or None.
    :raises InputError: 'on' without any temperature (in the door's words, when it has them).
    """
    from ..core.accelerometer.thermal import MIN_WINDOWS_PER_BAND
    if mode == 'off':
        return False
    finite = np.zeros(0) if temps is None else np.asarray(temps, float)
    finite = finite[np.isfinite(finite)]
    if mode == 'on':
        if not len(finite) and words.no_temperature:
            raise InputError(words.no_temperature)
        return True
    _, counts = np.unique(np.floor(finite / band_width_c), return_counts=True)
    return int(np.sum(counts >= MIN_WINDOWS_PER_BAND)) >= 2


def fit_and_accept(obs, settings, imu=None):
    """
    Fit the accelerometer, judge it and, once accepted, fit the other sensors beside it.

    :param obs: :class:`~.windows.Observations` of the session.
    :param settings: :class:`Settings` of the door.
    :param imu: :class:`RecordingImu`, :class:`CollectedImu` or :class:`NoImu` (None: no
        other sensor).
    :return: :class:`Outcome` (``refusal`` says why when it is not accepted).
    :raises InputError: the input cannot be fitted as given (unknown method, non-finite
        observations, temperature tables without temperatures): the door's usage error
        (``finish.finish_session`` makes it a refusal with ``cause`` 'input').
    """
    from ..core.accelerometer.fit import calibrate
    s, words = settings, settings.words
    imu = imu or NoImu()
    out = Outcome(observations=len(obs), limit=s.max_predicted_error)
    out.gyro, out.magnetometer = imu.not_fitted(words)
    if not len(obs):
        out.refusal = words.no_windows
        return out
    out.thermal = thermal_wanted(s.thermal, obs.temps, s.band_width_c, words)
    try:
        cal = calibrate(obs.readings, gravity=s.gravity, method=s.method, weights=obs.weights,
                        temps=obs.temps, thermal=out.thermal, band_width_c=s.band_width_c,
                        noise_std=obs.noise, source=s.source, gyro_means=obs.gyro_means)
    except CalibrationError as err:
        out.refusal = str(err)
        return out
    except np.linalg.LinAlgError as err:
        out.refusal = f'the fit failed numerically ({err}): add more distinct poses'
        return out
    _complete(cal, obs, s)
    out.calibration = cal
    out.warnings += _drop_implausible_gyro_bias(cal)
    out.verdict = verdict = review(
        cal, s.max_predicted_error, allow_unconverged=s.allow_unconverged,
        refuse_unphysical=s.refuse_unphysical, max_scale_error=s.max_scale_error,
        max_cross_axis=s.max_cross_axis, max_bias_g=s.max_bias_g, limit_name=words.limit,
        unit=words.unit, ml_hint=words.ml_hint)
    refusal = None
    if not verdict.converged and verdict.refusal:
        refusal = verdict.refusal + words.unconverged
    else:
        refusal = _residual_refusal(cal, obs, s, out.thermal) or verdict.refusal
    refusal = refusal or _unstorable(cal, words)
    if refusal is not None:
        out.refusal = refusal
        return out
    out.warnings += verdict.warnings
    from ..core.outcomes import store
    out.gyro, out.magnetometer = imu.solve(cal, s)
    store(cal, out.gyro, out.magnetometer)
    return out


def _complete(cal, obs, s):
    """Fill what the fit leaves to the door: accuracy, sensor, units, temperature range."""
    if cal.predicted_accuracy is None and cal.covariance is not None:
        from ..core.accuracy import predicted_accuracy
        try:
            acc = float(predicted_accuracy(cal.T, cal.covariance, cal.gravity))
        except (ValueError, np.linalg.LinAlgError):
            acc = math.inf
        cal.predicted_accuracy = acc if math.isfinite(acc) else None
    if cal.temperature_range_c is None and obs.temps is not None:
        finite = np.asarray(obs.temps, float)
        finite = finite[np.isfinite(finite)]
        if len(finite):
            cal.temperature_range_c = (float(finite.min()), float(finite.max()))
    if cal.sensor_id is None and s.sensor_id:
        cal.sensor_id = s.sensor_id
    if s.input_units is not None:
        cal.input_units = dict(s.input_units)


def _residual_refusal(cal, obs, s, thermal):
    """Refuse a residual far beyond the noise of the windows: the sensor moved, or the model."""
    if s.max_residual_ratio is None:
        return None
    expected = obs.expected_window_noise(MIN_WINDOW_NOISE)
    if expected is None or cal.residual_rms <= s.max_residual_ratio * expected:
        return None
    words = s.words
    name = f', {words.residual_limit}' if words.residual_limit else ''
    hint = ''
    if not thermal and thermal_wanted('auto', obs.temps, s.band_width_c):
        hint = f'; the windows fill two temperature bands: {words.thermal_hint}'
    return (f'gravity-norm residual {cal.residual_rms:.4f} {words.unit} is '
            f'{cal.residual_rms / expected:.0f}x the expected window noise {expected:.4f} '
            f'{words.unit} (limit {s.max_residual_ratio:g}x{name}): the sensor moved during '
            f'the poses or the model does not fit this sensor{hint}{words.follow_up}')


def _drop_implausible_gyro_bias(cal):
    """Leave out a gyro bias no gyro in rad/s has (the accelerometer fit still counts)."""
    from ..core.calibration import MAX_GYRO_BIAS
    biases = [cal.gyro_bias] + ([b.gyro_bias for b in cal.thermal.bands]
                                if cal.thermal is not None else [])
    if all(b is None or np.all(np.abs(b) <= MAX_GYRO_BIAS) for b in biases):
        return []
    warning = (f'gyro bias {np.round(cal.gyro_bias, 3).tolist()} exceeds {MAX_GYRO_BIAS:g} '
               'rad/s (are gx gy gz in rad/s?); not stored')
    cal.gyro_bias = None
    if cal.thermal is not None:
        for band in cal.thermal.bands:
            band.gyro_bias = None
    return [warning]


def _unstorable(cal, words):
    """Return why no calibration file may hold ``cal`` (None when one may)."""
    from ..dataio.calibration_file import calibration_from_dict, calibration_to_dict
    try:
        calibration_from_dict(calibration_to_dict(cal))
    except InputError as err:
        return words.implausible.format(err=err)
    return None
