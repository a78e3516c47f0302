"""
The calibration node's thermal part: ``~/calibrate_thermal`` while the robot sits and warms up.

Every sample the node takes in also goes to a :class:`~accel_calib_ros.core.accelerometer.
thermal_still.StillBinner` (10 s bins: a few hundred bytes a minute, at most
``thermal_max_hours`` kept). ``~/calibrate_thermal`` fits the thermal part of one still
pose to them as ``accel-calib fit --thermal --calibration`` does (``session.temperature``:
the offsets and the gyro bias against temperature, and the heating/cooling hysteresis when
the model-gap selection names it) on top of the calibration in force (the node's
``calibration_file``: its T and bias), in the worker thread, and saves it atomically; a
refusal (no calibration in force, too small a span, a sensor that moved, a temperature
that jumps) leaves the file as it was and says what to record. ``~/reset`` forgets the
bins too.
"""

from dataclasses import dataclass
from typing import Optional

from .parameters import Param

THERMAL_PARAMS = [
    Param('thermal_bin_s', 10.0, 'bin length of the thermal intake (one still pose while '
          'the temperature sweeps), s; read-only', low=1.0, high=600.0, read_only=True),
    Param('thermal_max_hours', 24.0, 'hours of thermal bins kept (the oldest go first); '
          'read-only', low=0.1, high=720.0, read_only=True),
    Param('thermal_min_span_c', 5.0, '~/calibrate_thermal: smallest temperature span taken, '
          'degC', low=0.5, high=200.0),
    Param('thermal_band_width_c', 5.0, '~/calibrate_thermal: band width of the offset '
          'tables, degC', low=0.5, high=100.0),
    Param('thermal_hysteresis', 'auto', '~/calibrate_thermal: auto (carry the heating/'
          'cooling term when the model-gap selection names it) or off',
          choices=('auto', 'off')),
]


def new_binner(params):
    """Return the node's thermal intake for its parameters."""
    from ..core.accelerometer.thermal_still import StillBinner
    bin_s = params['thermal_bin_s']
    return StillBinner(bin_s, max_bins=int(params['thermal_max_hours'] * 3600.0 / bin_s))


@dataclass
class ThermalJob:
    """
    What ``~/calibrate_thermal`` needs, taken when it was called.

    :param raw: the bins collected (``RawBins``). :param min_span_c: the span limit.
    :param reference: the calibration in force (Calibration). :param path: its file.
    :param settings: ``session.temperature.ThermalSettings``.
    :param history: the history database, or None. :param sensor: the sensor id.
    """

    raw: object
    min_span_c: float
    reference: object
    path: str
    settings: object
    history: Optional[str]
    sensor: str


def thermal_job(node):
    """
    Return the ThermalJob of a call, or the reason it cannot run (str).

    The calibration in force must exist, load and be this sensor's; some bins must be there.
    """
    from ..core.errors import InputError
    from ..dataio.calibration_file import load_calibration
    from ..session.temperature import ThermalSettings
    p = node.params
    raw = node.thermal.raw()
    if raw is None or len(raw.bins) < 2:
        return ('no thermal data collected yet: keep the robot still while it warms up '
                '(30-60 min from a cold start), then call ~/calibrate_thermal')
    try:
        reference = load_calibration(node.path)
    except InputError as err:
        return (f'no calibration in force to extend ({err}): ~/calibrate first (its T and bias '
                'are what the thermal part is added to)')
    if reference.sensor_id is not None and reference.sensor_id != node.sensor:
        return (f'the calibration in force ({node.path}) was made for sensor '
                f'{reference.sensor_id!r}, not {node.sensor!r}')
    settings = ThermalSettings(band_width_c=p['thermal_band_width_c'],
                               min_span_c=p['thermal_min_span_c'],
                               hysteresis=p['thermal_hysteresis'], gravity=p['gravity'],
                               source=f'ros node {node.get_fully_qualified_name()}')
    return ThermalJob(raw, p['thermal_min_span_c'], reference, node.path, settings,
                      node.history if p['history'] else None, node.sensor)


def run_thermal(job, may_save=None):
    """
    Fit, save and record the thermal part in the worker thread.

    :param may_save: callable -> bool asked right before the save (False: nothing written).
    :return: (success, message, notes).
    """
    from ..core.accelerometer.thermal_still import still_recording
    from ..core.errors import CalibrationError, InputError
    from ..dataio.calibration_file import save_calibration
    from ..session.temperature import fit_thermal_recording
    try:
        rec = still_recording(job.raw, job.min_span_c)
    except CalibrationError as err:
        return False, f'refused: {err}', []
    outcome = fit_thermal_recording(rec, job.reference, job.settings)
    if outcome.refusal is not None:
        return False, f'refused: {outcome.refusal}', []
    cal = outcome.calibration
    if may_save is not None and not may_save():
        return False, 'refused: the node is shutting down: nothing was saved', []
    try:
        save_calibration(cal, job.path)
    except (OSError, InputError, CalibrationError) as err:
        return False, f'refused: cannot write {job.path}: {err}', []
    notes = list(outcome.warnings)
    if job.history:
        notes += _record(job, cal)
    return True, summary(outcome, job.path), notes


def _record(job, cal):
    """Record the thermal calibration in the history (no windows); return why not."""
    import sqlite3

    import numpy as np

    from ..session.persist import record_history
    try:
        record_history(job.history, job.sensor, cal, np.zeros((0, 3)), np.zeros(0),
                       np.zeros(0), np.zeros(0), windows=0)
    except (sqlite3.Error, OSError, ValueError) as err:
        return [f'history not recorded: {err}']
    return []


def summary(outcome, path):
    """Return the words of an accepted thermal fit (the service's message)."""
    rec, fit, cal = outcome.recording, outcome.fit, outcome.calibration
    low, high = cal.thermal.range_c
    h = cal.thermal.hysteresis
    worst = max(a['predicted_accuracy_m_s2'] for a in fit.accuracy) if fit.accuracy else None
    words = (f'thermal part saved to {path}: {len(rec.bins)} bins of one still pose, '
             f'{low:.1f} .. {high:.1f} degC, zero at {outcome.reference_c:.1f} degC; '
             + ('hysteresis: none carried' if h is None else
                f'hysteresis ({h.effect}): '
                + ', '.join(f'{a} {v:+.2f}' for a, v in zip('xyz', h.per_rate_mg(cal.gravity)))
                + f' mg per degC/min of heating (tau {h.tau_s:.0f} s)'))
    if worst is not None:
        words += f'; predicted accuracy of the thermal part up to {worst:.4f} m/s2'
    return words


def thermal_status(node):
    """Return the thermal intake's state for ``~/status`` (JSON-ready)."""
    raw = node.thermal.raw()
    if raw is None:
        return {'bins': 0, 'span_c': 0.0, 'enough': False}
    span = float(raw.bins.temp.max() - raw.bins.temp.min())
    return {'bins': len(raw.bins), 'span_c': span,
            'range_c': [float(raw.bins.temp.min()), float(raw.bins.temp.max())],
            'enough': span >= node.params['thermal_min_span_c']}
