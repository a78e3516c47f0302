"""
``accel-calib health``: is this calibration still good for this sensor? (the field check offline).

The correction node's field monitor (``core.monitor``) run on a recording: the
recording is corrected with the calibration as the node would (level trim included),
cut into 0.1 s blocks, its still periods found, and each still period of at least
``--min-still-s`` checked: the corrected |a| at rest against the calibration's gravity,
with the calibration's own predicted error at that orientation, the noise and
``--allowance-mg`` for power-up changes allowed, at ``--false-alarm`` per check; and the
temperature against the calibrated range (plus ``--temperature-margin``). The gyro bias
left at rest is reported too (it is re-estimated in the field; not a verdict).

Exit status: 0 every check passed; 1 a check failed (stale or inconsistent: the line
names the size, the likely cause and says recalibrate); 2 bad input, including a
recording with no still period long enough to check (one line).
"""

import itertools
import math

import numpy as np

from .common import add_data_args, ranged, time_unit, to_si, unit_options


def add_arguments(p):
    """Add the options of ``health`` to its parser."""
    p.add_argument('calibration', help='calibration YAML to check')
    add_data_args(p)
    p.add_argument('--json', action='store_true', help='print one JSON object')
    g = p.add_argument_group("the check (defaults: the correction node's)")
    g.add_argument('--false-alarm', type=ranged(1e-9, 0.1), default=1e-4,
                   help='chance that one check fails on a calibration that is fine '
                        '(default %(default)g)')
    g.add_argument('--allowance-mg', type=ranged(0.0, 100.0), default=1.0,
                   help='bias change per axis not worth a recalibration, mg '
                        '(default %(default)g)')
    g.add_argument('--min-still-s', type=ranged(0.5, 3600.0), default=2.0,
                   help='shortest still period checked, s (default %(default)g)')
    g.add_argument('--temperature-margin', type=ranged(0.0, 100.0), default=2.0,
                   help='degC outside the calibrated range before it counts '
                        '(default %(default)g)')


def run(args, out):
    """Run ``accel-calib health``; return the exit status."""
    from ..core.errors import InputError
    from ..core.monitor import corrected_arrays, FieldMonitor, MonitorSettings
    from ..dataio.calibration_file import load_calibration
    cal = load_calibration(args.calibration)
    settings = MonitorSettings(health_false_alarm=args.false_alarm,
                               health_allowance_mg=args.allowance_mg,
                               health_min_still_s=args.min_still_s,
                               temperature_margin_c=args.temperature_margin,
                               health_memory_s=math.inf)
    mon = FieldMonitor(cal, settings)
    rows = 0
    for samples in _pieces(args):
        a, g, m = corrected_arrays(cal, samples.accel, samples.gyro, samples.temp, samples.mag)
        mon.feed(samples.t, a, g, samples.temp, m)
        rows += len(samples)
    mon.finish()
    checks, failures = mon.health.periods, mon.health.failures
    first, final = mon.health.first_failure, mon.last_health
    if final is None:
        raise InputError(f'no still period of {args.min_still_s:g} s or more in {args.data} '
                         f'({mon.still_time_s:.1f} s still in {rows} rows): record the sensor '
                         'at rest, a few poses held for seconds, to check it')
    worst = first if first is not None else final
    summary = {'command': 'health', 'calibration': args.calibration, 'data': args.data,
               'healthy': failures == 0, 'recalibrate': failures > 0,
               'message': worst.message if failures else final.message,
               'cause': worst.cause, 'checks': checks, 'failed_checks': failures,
               'still_periods': mon.periods, 'still_time_s': mon.still_time_s,
               'false_alarm_rate': args.false_alarm,
               'first_failure': None if first is None else first.to_dict(),
               'final': final.to_dict(), 'gyro_bias_left': mon.gyro_summary()}
    if args.json:
        out(summary)
    else:
        _print(summary, final, first)
    return 1 if failures else 0


def _print(summary, final, first):
    gyro = summary['gyro_bias_left']
    verdict = ('STALE: recalibrate' if summary['recalibrate'] else 'healthy')
    print(f'{verdict} ({summary["checks"]} check(s) over {summary["still_periods"]} still '
          f'period(s), {summary["still_time_s"]:.0f} s at rest; {summary["failed_checks"]} '
          f'failed; false-alarm rate {summary["false_alarm_rate"]:g} per check)')
    if first is not None:
        print(f'first failure (t = {first.time_s:.1f} s): {first.message}')
        if first.cause:
            print(f'likely cause: {first.cause}')
    print(f'at the end: {final.message}')
    for note in final.notes:
        print(f'note: {note}')
    est = np.round(gyro['estimate_deg_s'], 4).tolist()
    if gyro['periods_used']:
        print(f'gyro: bias left at rest {est} deg/s (what the correction node would subtract '
              f'after {gyro["periods_used"]} still period(s); about gravity: '
              f'{gyro["along_gravity"]})')
    else:
        print(f'gyro: {gyro["state"]}')


def _pieces(args):
    """Yield the recording in pieces, in m/s² (the first piece checked for its unit)."""
    from ..dataio.recording import iter_samples
    unit_options(args)
    pieces = iter_samples(args.data, imu_topic=args.imu_topic, temp_topic=args.temp_topic,
                          mag_topic=getattr(args, 'mag_topic', None), time_unit=time_unit(args))
    first = to_si(next(pieces), args)
    return itertools.chain([first], (to_si(piece, args, check=False) for piece in pieces))
