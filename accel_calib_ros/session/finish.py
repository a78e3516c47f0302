"""
After the windows: the one function every front door calls to end a session.

:func:`finish_session` takes the session's windows and the door's settings and does
everything that follows, the same way for the calibration node, ``accel-calib fit`` and
``accel-calib guide``:

1. fit and accept (:func:`.accept.fit_and_accept`); an input that cannot be fitted as
   given (an unknown method, temperature tables without temperatures) is a refusal with
   ``cause`` 'input';
2. save an accepted calibration atomically (:func:`.persist.save`, with what the file it
   replaces carries forward); a save that fails is a refusal that names the file and the
   reason, with ``cause`` 'output', and the old file stays as it was;
3. record the session in the history (:func:`.persist.record_history`): this session's
   windows (their means, temperatures, weights capped at ``Settings.max_weight_s``, gyro
   means, NaN where there were none) and the calibration, one transaction. The windows'
   times follow one rule (:func:`.persist.window_times`): Unix times are kept, a device
   clock or a recording from 0 is placed so that the session's end is now. The history
   failing does not undo the saved calibration: the outcome says so in ``notes``, with
   ``cause`` 'output'.

A refused outcome is made in one place (:func:`.accept.refused`). The door only says
what happened, in its words: the node answers and logs (a refusal, a warning for a note),
a command line reports a ``cause`` as an error of its arguments (exit status 2).
"""

from typing import NamedTuple, Optional

import numpy as np

from .accept import fit_and_accept, refused
from ..core.errors import CalibrationError, InputError


class HistoryTarget(NamedTuple):
    """
    Where and under which name a session is recorded.

    :param path: the history database.
    :param sensor: the sensor's id (None: the calibration's ``sensor_id``, else 'imu').
    :param session_id: the session's id (None: a new one).
    :param now: Unix time of the session's end, s (None: when it is recorded).
    :param clock_end: the session's end in the windows' clock, s (None: the last window's
        end): what :data:`now` is, for windows timed by a device clock or from 0.
    """

    path: str
    sensor: Optional[str] = None
    session_id: Optional[str] = None
    now: Optional[float] = None
    clock_end: Optional[float] = None


def finish_session(windows, settings, imu=None, obs=None, rate_hz=None, output=None,
                   history=None, may_save=None):
    """
    Fit, accept, save and record one session.

    :param windows: this session's :class:`~.windows.WindowSet` (what the history records),
        or None (``fit --mode samples``: no windows, no history).
    :param settings: the door's :class:`~.settings.Settings`.
    :param imu: the gyroscope and magnetometer (:class:`~.accept.RecordingImu`,
        :class:`~.accept.CollectedImu`), or None.
    :param obs: what is fitted (default the windows' :class:`~.windows.Observations`, their
        weights capped at ``settings.max_weight_s``); ``fit --history`` fits more windows
        than it records.
    :param rate_hz: the sample rate, Hz, for the weight cap of windows without their own.
    :param output: the calibration file to write (None: nothing written).
    :param history: a :class:`HistoryTarget` (None: not recorded).
    :param may_save: callable asked right before the save (a node shutting down): False
        refuses the outcome with the door's ``Words.stopping`` and nothing is written.
    :return: :class:`~.accept.Outcome`; ``saved_to``, ``carried``, ``history`` and
        ``notes`` say what was written.
    """
    words = settings.words
    if obs is None:
        obs = windows.observations(settings.max_weight_s, rate_hz)
    try:
        outcome = fit_and_accept(obs, settings, imu)
    except InputError as err:
        return refused(str(err), imu, words=words, observations=len(obs),
                       limit=settings.max_predicted_error, cause='input')
    if not outcome.accepted:
        return outcome
    if may_save is not None and not may_save():
        return refused(words.stopping, outcome=outcome)
    if output is not None:
        from .persist import save
        try:
            save(outcome, output)
        except (OSError, InputError, CalibrationError) as err:
            return refused(f'cannot write {output}: {_why(err)}', outcome=outcome,
                           cause='output')
    if history is not None and windows is not None:
        _record(history, windows, outcome, settings, rate_hz)
    return outcome


def _why(err):
    if isinstance(err, OSError) and err.strerror:
        return err.strerror
    return str(err)


def _record(target, windows, outcome, settings, rate_hz):
    """Record the session in the history; a failure becomes a note of the outcome."""
    import sqlite3
    from ..dataio.sensor_id import normalise_sensor_id
    from .persist import record_history, window_times
    cal = outcome.calibration
    try:
        sensor = target.sensor or normalise_sensor_id(cal.sensor_id or 'imu')
        n = len(windows)
        gyro = windows.gyro_mean if windows.gyro_mean is not None else np.full((n, 3), np.nan)
        end = target.clock_end if target.clock_end is not None else \
            (float(np.nanmax(windows.t_stop)) if n else None)
        times = window_times(windows.t_mid, t_end=end, now=target.now)
        outcome.history = record_history(
            target.path, sensor, cal, windows.mean, windows.temp,
            windows.weights(settings.max_weight_s, rate_hz), times, gyro,
            windows=outcome.observations, session_id=target.session_id)
    except (InputError, sqlite3.Error, OSError, ValueError) as err:
        outcome.notes.append(f'history not recorded: {err}')
        outcome.cause = 'output'
