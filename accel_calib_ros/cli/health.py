"""
``accel-calib health``: is this calibration still good for this sensor? (the field check offline).

The correction node's field monitor (``core.monitor``) run on a recording: the
recording is corrected with the calibration as the node would (level trim included),
cut into blocks, its still periods found, and each rest (a still period of at least
``--min-still-s`` that is a rest in the inertial sense: no lift, vehicle or ship
accelerating, confirmed by the rest after it) checked: the corrected |a| at rest against
the calibration's gravity, with the calibration's own predicted error at that
orientation, the noise of the period's mean (measured from the data's batch means), the
allowance for changes between sessions (the sensor's history, else ``--allowance-mg``)
and, outside the calibrated range, what the temperature could explain, at
``--false-alarm`` per check. Rows with a non-finite time, acceleration or rate are
skipped and counted, as the node does; so are non-finite temperatures. The gyro bias
left at rest is reported too (it is re-estimated in the field; not a verdict).

Exit status: 0 every check passed (a temperature outside the calibrated range that the
data do not contradict is a warning, exit 0); 1 a check says recalibrate (the line names
the size and the likely cause), or the sensor is frozen; 2 bad input, including a
recording with no still period long enough to check, or one slower than the still test
needs (one line).
"""

import itertools
import math
import os

import numpy as np

from .common import add_data_args, ranged, sensor_id, time_unit, to_si, unit_options


def add_arguments(p):
    """Add the options of ``health`` to its parser."""
    p.add_argument('calibration', help='calibration YAML to check')
    add_data_args(p)
    p.add_argument('--json', action='store_true', help='print one JSON object')
    g = p.add_argument_group("the check (defaults: the correction node's)")
    g.add_argument('--false-alarm', type=ranged(1e-9, 0.1), default=1e-4,
                   help='chance that one check says recalibrate on a calibration that is '
                        'fine (default %(default)g)')
    g.add_argument('--allowance-mg', type=ranged(0.0, 100.0), default=1.0,
                   help='bias change per axis between sessions not worth a recalibration, '
                        'mg, when the sensor has no history (default %(default)g)')
    g.add_argument('--min-still-s', type=ranged(0.5, 3600.0), default=2.0,
                   help='shortest still period checked, s (default %(default)g)')
    g.add_argument('--temperature-margin', type=ranged(0.0, 100.0), default=2.0,
                   help='degC outside the calibrated range before it is a warning '
                        '(default %(default)g)')
    h = p.add_argument_group('the sensor history (its session-to-session scatter)')
    h.add_argument('--history', metavar='DB', default=None,
                   help='history database to read (default: history.sqlite beside the '
                        'calibration file, when there is one)')
    h.add_argument('--sensor', type=sensor_id, default=None,
                   help="sensor id in the history (default: the calibration's sensor_id)")


def run(args, out):
    """Run ``accel-calib health``; return the exit status."""
    from ..core.errors import InputError
    from ..core.monitor import corrected_arrays, FieldMonitor, MonitorSettings
    from ..dataio.calibration_file import load_calibration
    cal = load_calibration(args.calibration)
    history, history_words = _history(args, cal)
    settings = MonitorSettings(health_false_alarm=args.false_alarm,
                               health_allowance_mg=args.allowance_mg,
                               health_min_still_s=args.min_still_s,
                               temperature_margin_c=args.temperature_margin,
                               health_memory_s=math.inf, still_timeout_s=math.inf)
    mon = FieldMonitor(cal, settings, history)
    rows = 0
    stream = cal.lag_stream()           # the heating/cooling term's lag, across pieces
    for samples in _pieces(args):
        a, g, m = corrected_arrays(cal, samples.accel, samples.gyro, samples.temp,
                                   samples.mag, samples.t, stream)
        mon.feed(samples.t, a, g, samples.temp, m)
        rows += len(samples)
        if mon.too_slow:
            break
    mon.finish()
    if mon.too_slow:
        raise InputError(f'{mon.too_slow}; record at 25 Hz or more: {args.data}')
    h = mon.health
    fault = mon.faults[0] if mon.faults else None
    first, final = h.first_failure, mon.last_health
    if final is None and fault is None:
        raise InputError(_no_rest(args, mon, rows))
    failures = h.failures
    warning = h.first_warning
    status = 'error' if fault else 'recalibrate' if failures else \
        'warn' if warning is not None else 'ok'
    if fault:
        message, cause = fault['message'], 'the sensor is frozen'
    elif failures:
        message, cause = first.message, first.cause
    else:
        message = final.message if warning is None or final.level == 'warn' \
            else warning.message
        cause = warning.cause if warning is not None else ''
    summary = {'command': 'health', 'calibration': args.calibration, 'data': args.data,
               'status': status, 'healthy': status in ('ok', 'warn'),
               'recalibrate': bool(failures), 'message': message, 'cause': cause,
               'warnings': _warnings(mon, warning),
               'sensor_fault': fault, 'checks': h.periods, 'failed_checks': failures,
               'warned_checks': h.warnings, 'still_periods': mon.periods,
               'still_time_s': mon.still_time_s, 'false_alarm_rate': args.false_alarm,
               'rows': rows, 'rows_skipped_non_finite': mon.skipped_rows,
               'temperatures_non_finite': mon.temps_unknown,
               'rate_hz': mon.cutter.rate_hz, 'block_s': mon.cutter.step_s,
               'clock_steps': mon.cutter.steps,
               'periods_not_rests': dict(mon.rejected),
               'allowance': dict(h.prior.to_dict(), history=history_words),
               'mean_noise': mon.noise.summary(),
               'first_failure': None if first is None else first.to_dict(),
               'final': None if final is None else final.to_dict(),
               'gyro_bias_left': mon.gyro_summary()}
    if args.json:
        out(summary)
    else:
        _print(summary, final, first)
    return 1 if failures or fault else 0


def _warnings(mon, warning):
    out = []
    if warning is not None:
        out.append(warning.warning)
    if mon.skipped_rows:
        out.append(f'{mon.skipped_rows} row(s) with a non-finite time, acceleration or rate '
                   'skipped')
    if mon.cutter.steps:
        out.append(f'the sample clock stepped {mon.cutter.steps} time(s) '
                   f'({mon.cutter.backwards} back): the monitor restarted there')
    if mon.gyro.held_rate:
        out.append(f'gyro: {mon.gyro.vertical}')
    return out


def _no_rest(args, mon, rows):
    """Say why there is nothing to check (one line)."""
    why = ''
    if mon.rejected:
        kinds = ', '.join(f'{v} {k}' for k, v in mon.rejected.most_common(3))
        why = f'; still periods that were not rests: {kinds}'
    return (f'no still period of {args.min_still_s:g} s or more that is a rest '
            f'({mon.still_time_s:.1f} s still in {rows} rows{why}): record the sensor at '
            f'rest, a few poses held for seconds, to check it: {args.data}')


def _history(args, cal):
    """Return (the sensor's calibrations in its history or None, words on where from)."""
    from ..dataio.history import History
    sensor = args.sensor or getattr(cal, 'sensor_id', None)
    path = args.history
    explicit = path is not None
    if path is None:
        path = os.path.join(os.path.dirname(os.path.abspath(args.calibration)),
                            'history.sqlite')
        if not os.path.isfile(path):
            return None, 'none (no history.sqlite beside the calibration)'
    if not sensor:
        if explicit:
            from .common import UsageError
            raise UsageError('accel-calib: health --history needs --sensor NAME (the '
                             'calibration names no sensor_id)')
        return None, 'none (the calibration names no sensor_id)'
    try:
        with History(path, readonly=True) as db:
            rows = db.calibrations(sensor)
    except Exception as err:    # noqa: B902 - a history beside the file is only a help
        if explicit:
            raise
        return None, f'{path} not read ({str(err)[:120]})'
    return rows, f'{path}, sensor {sensor}: {len(rows)} calibration(s)'


def _print(summary, final, first):
    gyro = summary['gyro_bias_left']
    verdict = {'error': 'SENSOR FAULT', 'recalibrate': 'STALE: recalibrate',
               'warn': 'healthy, with a warning', 'ok': 'healthy'}[summary['status']]
    print(f'{verdict} ({summary["checks"]} check(s) over {summary["still_periods"]} still '
          f'period(s), {summary["still_time_s"]:.0f} s at rest; {summary["failed_checks"]} '
          f'failed; false-alarm rate {summary["false_alarm_rate"]:g} per check)')
    if summary['sensor_fault']:
        print(f'sensor fault (t = {summary["sensor_fault"]["time_s"]:.1f} s): '
              f'{summary["sensor_fault"]["message"]}')
    if first is not None:
        print(f'first failure (t = {first.time_s:.1f} s): {first.message}')
        if first.cause:
            print(f'likely cause: {first.cause}')
    if final is not None:
        print(f'at the end: {final.message}')
        for note in final.notes:
            print(f'note: {note}')
    for words in summary['warnings']:
        print(f'warning: {words}')
    if summary['periods_not_rests']:
        print('still periods that were not rests: ' + ', '.join(
            f'{v} ({k})' for k, v in summary['periods_not_rests'].items()))
    est = np.round(gyro['estimate_deg_s'], 4).tolist()
    if gyro['periods_used']:
        print(f'gyro: bias left at rest {est} deg/s (what the correction node would subtract '
              f'after {gyro["periods_used"]} still period(s); {gyro["followed"]}; about '
              f'gravity: {gyro["along_gravity"]})')
    else:
        print(f'gyro: {gyro["state"]}')


def _pieces(args):
    """Yield the recording in pieces, in m/s² (the first piece checked for its unit)."""
    from ..dataio.recording import iter_samples
    unit_options(args)
    pieces = iter_samples(args.data, imu_topic=args.imu_topic, temp_topic=args.temp_topic,
                          mag_topic=getattr(args, 'mag_topic', None), time_unit=time_unit(args),
                          non_finite='keep')
    first = to_si(next(pieces), args)
    return itertools.chain([first], (to_si(piece, args, check=False) for piece in pieces))
