"""
Persistence of an accepted session: the calibration file and the per-sensor history.

:func:`save` writes an accepted :class:`~.accept.Outcome`'s calibration atomically. The
file it replaces may hold what this session did not calibrate: the level trim (the
mounting has not changed), the gyroscope's scale and misalignment or the magnetometer
calibration when this session has no usable rates or field (an accelerometer-only
session, a sensor left out); those are carried forward into the new file, for the same
sensor only, and the outcome says so (``Outcome.carried``). A refused outcome is never
saved: the old file stays byte for byte as it was, and in force.

:func:`record_history` records an accepted session (its windows and its calibration) in
the history, one transaction. Files only through ``dataio``.
"""

import os
import time

import numpy as np

from ..core.errors import InputError


def previous_calibration(path):
    """Return the calibration in ``path`` (None when there is none or it cannot be read)."""
    if not path or not os.path.exists(path):
        return None
    from ..dataio.calibration_file import load_calibration
    try:
        return load_calibration(path)
    except InputError:
        return None


def _same_sensor(old, new):
    return old.sensor_id is None or new.sensor_id is None or old.sensor_id == new.sensor_id


PARTS = ('level trim', 'gyroscope', 'magnetometer')
"""What a new calibration may carry forward from the file it replaces."""


def carry_forward(cal, old, gyro=None, magnetometer=None, parts=PARTS):
    """
    Put into ``cal`` what the calibration ``old`` it replaces has and this session has not.

    :param cal: the new, accepted Calibration (changed in place).
    :param old: the Calibration of the file being replaced, or None.
    :param gyro: this session's gyroscope SensorOutcome (for the words), or None.
    :param magnetometer: this session's magnetometer SensorOutcome, or None.
    :param parts: which of :data:`PARTS` may be carried forward.
    :return: one line per part carried forward (or left behind: another sensor's file).
    """
    if old is None:
        return []
    held = [name for name, present in (('gyroscope', old.gyro_T is not None),
                                       ('magnetometer', old.magnetometer is not None))
            if present and name in parts]
    if not _same_sensor(old, cal):
        return [f'{part}: not carried forward: the file it replaces was for sensor '
                f'{old.sensor_id}' for part in held]
    lines = []
    since = f' (calibrated {old.created})' if old.created else ''
    if 'level trim' in parts and cal.level_roll_pitch_rad is None and \
            old.level_roll_pitch_rad is not None:
        cal.level_roll_pitch_rad = old.level_roll_pitch_rad
        lines.append('level trim carried forward from the file it replaces')
    if 'gyroscope' in parts and cal.gyro_T is None and old.gyro_T is not None:
        fresh_bias = cal.gyro_bias is not None
        cal.gyro_T = np.array(old.gyro_T, float)
        cal.gyro_predicted_accuracy = old.gyro_predicted_accuracy
        if not fresh_bias:
            cal.gyro_bias = old.gyro_bias
        lines.append('gyroscope: scale and misalignment carried forward from the file it '
                     f'replaces{since}' + _because(gyro)
                     + ("; the bias is this session's" if fresh_bias else ''))
    if 'magnetometer' in parts and cal.magnetometer is None and old.magnetometer is not None:
        cal.magnetometer = old.magnetometer
        lines.append(f'magnetometer: carried forward from the file it replaces{since}'
                     + _because(magnetometer))
    return lines


def _because(outcome):
    if outcome is None:
        return ''
    return f", this session's is {outcome.status}"


def save(outcome, path, carry=PARTS):
    """
    Write an accepted outcome's calibration to ``path`` atomically (its folder is made).

    What the file being replaced carries forward is put into the calibration first
    (:func:`carry_forward`); ``outcome.carried`` and ``outcome.saved_to`` say what happened.

    :param outcome: an accepted :class:`~.accept.Outcome`.
    :param path: the calibration file.
    :param carry: the parts (:data:`PARTS`) the file being replaced may carry forward.
    :raises ValueError: the outcome is not accepted (nothing is written).
    :raises CalibrationError: the calibration holds what no file may (nothing written).
    :raises InputError: the path may not be written (``dataio.atomic.UnsafeOutput``).
    :raises OSError: the file system refused.
    """
    if not outcome.accepted:
        raise ValueError('a refused calibration is never saved')
    from ..dataio.calibration_file import save_calibration
    cal = outcome.calibration
    if carry:
        outcome.carried = carry_forward(cal, previous_calibration(path), outcome.gyro,
                                        outcome.magnetometer, carry)
    save_calibration(cal, path)
    outcome.saved_to = os.fspath(path)
    return outcome


def window_times(t_mid, t_end=None, now=None):
    """
    Return Unix times (s) for windows with mid times ``t_mid``.

    Times that are already Unix times (after 2001) are kept; a device clock or a
    recording that starts at 0 is placed so that its end (``t_end``, default the last
    window) is ``now``.
    """
    t = np.asarray(t_mid, float).reshape(-1)
    if len(t) and np.all(np.isfinite(t) & (t > 1e9)):
        return t
    now = time.time() if now is None else now
    finite = t[np.isfinite(t)]
    end = t_end if t_end is not None else (finite.max() if len(finite) else 0.0)
    out = now - (end - t)
    return np.where(np.isfinite(out), out, now)


def record_history(path, sensor, cal, means, temps, weights, times, gyro=None, windows=None,
                   session_id=None):
    """
    Record an accepted session in the history: its windows and calibration, one transaction.

    :param path: the history database.
    :param sensor: the sensor's id.
    :param cal: the accepted Calibration.
    :param means: (N, 3) this session's window means, m/s²; ``temps`` (N,) °C or None;
        ``weights`` (N,); ``times`` (N,) Unix times, s; ``gyro`` (N, 3) rad/s or None.
    :param windows: the windows the fit used (default ``cal.observations``).
    :param session_id: the session's id (default a new one).
    :return: dict ``db``, ``session``, ``windows_added``.
    :raises InputError, sqlite3.Error, OSError: the history cannot take it (nothing added).
    """
    from ..dataio.history import History, new_session_id
    session_id = session_id or new_session_id()
    temps = None if temps is None else np.asarray(temps, float)
    with History(path) as history:
        added = history.record_session(sensor, session_id, cal, means, temps, weights, times,
                                       gyro, windows=windows)
    return {'db': os.fspath(path), 'session': session_id, 'windows_added': int(added)}
