"""
``accel-calib fit``: a calibration from a recording's static windows (or its samples).

The recording's windows are found here (``core.windows``, outliers dropped; with
``--history`` joined to the sensor's kept windows); everything after them (the fit, its
acceptance, the file, the history) is the session floor's ``finish_session``, as for the
node and ``guide``; a file that cannot be written is an error of the arguments (exit 2).
"""

import os
import sys
import time

import numpy as np

from .common import (add_data_args, add_window_args, check_output, GRAVITY, load_data,
                     mode_options, ranged, sensor_id, STDOUT, UsageError)
from ..core.accelerometer.fit import METHODS
from ..core.errors import CalibrationError
from ..core.windows import DEFAULTS, detect_static_windows


def add_arguments(p):
    """Add the options of ``fit`` to its parser."""
    from ..session.settings import DEFAULT_SETTINGS as S
    add_data_args(p)
    p.add_argument('--method', choices=METHODS, default=S.method,
                   help='ml: maximum likelihood (Sun & Xu); ml-bc: ML with bootstrap bias '
                        'correction; gn: 6-parameter Gauss-Newton (Gui Yi); ellipsoid: '
                        'algebraic LS (default ml)')
    p.add_argument('--mode', choices=('windows', 'samples'), default='windows',
                   help='windows: one observation per detected static window; samples: '
                        'every row is one observation (default windows)')
    p.add_argument('--thermal', action='store_true',
                   help='also fit temperature-band drift tables (needs temp); with '
                        '--calibration: the thermal part from one still pose')
    p.add_argument('--band-width', type=ranged(0.1, 1000.0), default=None,
                   help='temperature band width, °C (default 10, or 5 for one still pose)')
    g = p.add_argument_group('thermal calibration from one still pose (--thermal '
                             '--calibration: a warm-up or chamber cycle, as PX4 and '
                             'ArduPilot record it)')
    g.add_argument('--calibration', metavar='CALIB',
                   help='the calibration to extend (its T and bias at its own temperature): '
                        'DATA is then one still pose while the temperature sweeps; the '
                        'output is CALIB plus offset tables against temperature (-o may be '
                        'CALIB itself)')
    g.add_argument('--min-span', type=ranged(0.5, 200.0), default=None, metavar='C',
                   help='smallest temperature span taken, °C (default 5)')
    g.add_argument('--hysteresis', choices=('auto', 'off'), default=None,
                   help='auto: carry the heating/cooling hysteresis term when the model-gap '
                        'selection names it (default); off: never')
    p.add_argument('--gravity', type=GRAVITY, default=S.gravity,
                   help='local gravity magnitude, m/s² (default %(default)s)')
    p.add_argument('--max-predicted-error', type=ranged(1e-9, 1e3),
                   default=S.max_predicted_error, metavar='M_S2',
                   help='refuse a fit whose predicted accuracy (RMS error at 1 g over all '
                        'orientations) is worse than this, m/s² (default %(default)s)')
    p.add_argument('--max-residual-ratio', type=ranged(1.0, 1e6),
                   default=S.max_residual_ratio, metavar='RATIO',
                   help='refuse a fit whose gravity-norm residual RMS exceeds this many times '
                        'the error expected of a window mean from its noise (the sensor moved, '
                        'or the model does not fit it; default %(default)s, as the node)')
    add_imu_arguments(p)
    p.add_argument('--force', action='store_true',
                   help='write the calibration even if the fit did not converge (loud '
                        'warning; JSON still says converged false)')
    p.add_argument('-o', '--output', help='write the calibration YAML here (atomically; "-": '
                                          'standard output, the summary then goes to stderr)')
    p.add_argument('--json', action='store_true', help='print one JSON object')
    add_window_args(p)
    g = p.add_argument_group('per-sensor history')
    g.add_argument('--history', nargs='?', const='', default=None, metavar='DB',
                   help='fit on all windows of --sensor kept in this SQLite history (default: '
                        "the one beside the nodes' calibration file of --sensor); an accepted "
                        'fit adds its windows and calibration as one session, a refused one '
                        'adds nothing')
    g.add_argument('--sensor', type=sensor_id,
                   help='sensor id in the history (firmware id, port or name; surrounding '
                        'spaces are dropped)')


def add_imu_arguments(p):
    """Add the options of the gyroscope and magnetometer parts (interface.md §9, §10)."""
    from ..session.settings import DEFAULT_SETTINGS as S
    g = p.add_argument_group('gyroscope and magnetometer (fitted whenever the data have '
                             'gx gy gz / mx my mz)')
    g.add_argument('--max-gyro-error', type=ranged(1e-9, 1.0), default=S.max_gyro_error,
                   metavar='FRACTION',
                   help='store the gyroscope scale/misalignment only when its predicted '
                        'accuracy (RMS relative rate error over all directions) is at most '
                        'this (default %(default)s = 1 %%); otherwise only that part is '
                        'left out')
    g.add_argument('--max-mag-error', type=ranged(1e-9, 1e3), default=S.max_mag_error,
                   metavar='UT',
                   help='store the magnetometer calibration only when its predicted accuracy '
                        '(RMS field error over all directions) is at most this, µT (default '
                        '%(default)s); otherwise only that part is left out')
    g.add_argument('--field', type=ranged(1.0, 1000.0), default=None, metavar='UT',
                   help='known local field magnitude, µT (e.g. from a geomagnetic model); '
                        'default: fitted, trusting the magnetometer sensitivity on average')


def warn_imu(outcomes):
    """Warn on stderr about each sensor that is there but not calibrated."""
    for outcome in outcomes:
        if outcome.status in ('insufficient', 'refused'):
            print(f'accel-calib: warning: {outcome.sensor} not calibrated ({outcome.status}): '
                  f'{outcome.reason}', file=sys.stderr)


def _history_path(args):
    from ..dataio.history import default_history_path
    return args.history or default_history_path(args.sensor)


def history_observations(args, samples, obs):
    """
    Return the observations of this recording's windows joined to the sensor's history.

    Nothing is written here: the history gets this session only if the fit is accepted
    (``session.finish.finish_session``), so a refused or failed fit leaves it as it was.

    :param args: parsed ``fit`` arguments (``history`` not None).
    :param samples: the loaded recording.
    :param obs: this recording's observations (static windows, outliers already dropped:
        see ``_observations``); changed in place.
    :return: (``obs`` with readings (N, 3), weights (N,), temps (N,), count N and gyro means
        (N, 3) rad/s (NaN rows where a session had no gyro) over every kept window of the
        sensor and this recording's (a window kept already counts once), the
        ``session.finish.HistoryTarget`` that records this recording's windows).
    """
    if args.mode != 'windows':
        raise UsageError('accel-calib: fit --history works on static windows (--mode windows)')
    if not args.sensor:
        raise UsageError('accel-calib: fit --history needs --sensor NAME (whose history it '
                         'is)')
    from ..dataio.history import History
    from ..session.finish import HistoryTarget
    from ..session.persist import window_times
    path = _history_path(args)
    check_output(path, args.data, args.output, what='--history')
    t = samples.t
    target = HistoryTarget(path, args.sensor, now=time.time(),
                           clock_end=float(t[-1]) if len(t) else None)
    when = window_times(obs.t_mid, t_end=target.clock_end, now=target.now)
    gyro = np.full((obs.count, 3), np.nan) if obs.gyro is None else obs.gyro
    temps = np.full(obs.count, np.nan) if obs.temps is None else obs.temps
    new = {'mean': obs.readings, 'temp': temps, 'weight': obs.weights, 'time_s': when,
           'gyro_mean': gyro}
    kept = {'mean': np.zeros((0, 3)), 'temp': np.zeros(0), 'weight': np.zeros(0),
            'time_s': np.zeros(0), 'gyro_mean': np.zeros((0, 3))}
    if os.path.exists(path) and not (os.path.isfile(path) and os.path.getsize(path) == 0):
        with History(path, readonly=True) as h:
            kept = h.windows(args.sensor)
            h.calibrations(args.sensor)         # damage is named now, before any fit
    old = set(zip(*(kept['mean'].T), kept['weight']))
    fresh = np.array([(tuple(m) + (w,)) not in old for m, w in zip(new['mean'], new['weight'])],
                     bool).reshape(-1)
    union = {k: np.concatenate([kept[k], new[k][fresh]]) for k in new}
    order = np.argsort(union['time_s'], kind='stable')
    print(f'accel-calib: history {path}: {obs.count} windows from this recording, '
          f'{len(kept["mean"])} kept for sensor {args.sensor}, {len(order)} fitted',
          file=sys.stderr)
    obs.readings, obs.weights = union['mean'][order], union['weight'][order]
    obs.temps, obs.gyro = union['temp'][order], union['gyro_mean'][order]
    obs.count = len(order)
    return obs, target


def report_history(done, sensor):
    """Say on stderr what the history recorded (``done``: ``Outcome.history``)."""
    print(f'accel-calib: history {done["db"]}: session {done["session"]} recorded for sensor '
          f'{sensor} ({done["windows_added"]} new windows and the calibration)',
          file=sys.stderr)


class _Observations:
    """Observations for the fit, with what was left out (mode, windows, reasons)."""

    def __init__(self, **kw):
        self.__dict__.update(kw)


def _observations(samples, args):
    """Return the observations for the chosen mode, outlier windows dropped."""
    if getattr(args, 'mode', 'windows') == 'samples':
        return _Observations(readings=samples.accel, weights=None, temps=samples.temp,
                             noise=None, count=len(samples), gyro=None, dropped=[],
                             mean_count=1.0, low_passed=False, windows=None, kept=None)
    windows = detect_static_windows(samples, min_duration_s=args.min_window_s,
                                    threshold_factor=args.threshold_factor)
    if len(windows) == 0:
        raise CalibrationError(
            'no static windows found: hold each pose still for at least '
            f'{args.min_window_s + 2 * DEFAULTS["trim_s"] + DEFAULTS["window_s"]:g} s '
            '(or use --mode samples for a moving recording)'
            + (f'; {len(windows.dropped)} still stretches were dropped because the gyro '
               'shows rotation' if windows.dropped else ''))
    weights = windows.weights(args.max_weight_s, samples.rate_hz)
    dropped = list(windows.dropped)
    from ..core.accelerometer.fit import find_outlier_windows
    keep, outliers = find_outlier_windows(
        windows.mean, weights, windows.count, windows.noise_std, args.gravity,
        windows.temp, getattr(args, 'thermal', False), getattr(args, 'band_width', None) or 10.0,
        getattr(args, 'method', 'ml'))
    for k, reason in outliers:
        dropped.append({'t_start': float(samples.t[windows.start[k]]),
                        't_stop': float(samples.t[windows.stop[k] - 1]), 'reason': reason})
    detected = windows
    windows = windows.select(keep)
    dropped.sort(key=lambda d: d['t_start'])
    return _Observations(readings=windows.mean, weights=weights[keep], temps=windows.temp,
                         noise=windows.noise_std, count=len(windows),
                         gyro=windows.gyro_mean, dropped=dropped, t_mid=windows.t_mid,
                         mean_count=float(np.mean(windows.count)) if len(windows) else 1.0,
                         low_passed=windows.low_passed, windows=detected, kept=windows)


def _band_dict(band):
    d = band.to_dict()
    d['usable'] = band.status == 'ok'
    d['why_not'] = None if band.status == 'ok' else band.status
    return d


def _fit_summary(cal, extra):
    d = {'method': cal.method, 'T': cal.T.tolist(), 'bias': cal.bias.tolist(),
         'residual_rms': cal.residual_rms, 'iterations': cal.iterations,
         'observations': cal.observations, 'converged': cal.converged, 'seconds': cal.seconds,
         'gravity': cal.gravity, 'scale': cal.scale.tolist(),
         'nonorthogonality_deg': cal.nonorthogonality_deg.tolist(),
         'noise_std': [None if not np.isfinite(v) else float(v) for v in cal.noise_std],
         'predicted_accuracy': cal.predicted_accuracy,
         'gyro_bias': None if cal.gyro_bias is None else cal.gyro_bias.tolist(),
         'temperature_range_c': (None if cal.temperature_range_c is None
                                 else list(cal.temperature_range_c))}
    if cal.covariance is not None:
        d['stddev'] = np.sqrt(np.maximum(np.diag(cal.covariance), 0)).tolist()
    if cal.cross_axis is not None:      # gn: what the terms it holds at zero cost
        d['cross_axis_allowance'] = cal.cross_axis.to_dict()
    if cal.thermal is not None:
        d['thermal'] = cal.thermal.to_dict()
        d['thermal']['bands'] = [_band_dict(b) for b in cal.thermal.bands]
    d.update(extra)
    return d


def _print_fit(cal, summary, n_obs, mode, samples, dropped, out_path):
    print(f'{cal.method} fit of {n_obs} {"windows" if mode == "windows" else "samples"} '
          f'({samples} samples): {"converged" if cal.converged else "NOT converged"} '
          f'in {cal.iterations} iterations, {cal.seconds * 1e3:.1f} ms')
    with np.printoptions(precision=6, suppress=True):
        print(f'T (raw = T·true + bias):\n{cal.T}')
        print(f'bias [m/s²]: {cal.bias}')
        print(f'scale: {cal.scale}   non-orthogonality [deg] xy xz yz: '
              f'{cal.nonorthogonality_deg}')
        if cal.gyro_bias is not None:
            print(f'gyro bias [rad/s]: {cal.gyro_bias}')
    print(f'gravity-norm residual RMS: {cal.residual_rms:.5f} m/s² '
          f'(uncalibrated {summary["residual_rms_uncalibrated"]:.5f} m/s²)')
    acc = cal.predicted_accuracy
    print(f'predicted accuracy: {acc:.5f} m/s² RMS at 1 g over all orientations '
          f'(limit {summary["max_predicted_error"]:g} m/s²)' if acc is not None
          and np.isfinite(acc) else 'predicted accuracy: unknown (the poses do not '
          'determine the calibration)')
    if cal.cross_axis is not None:
        print(f'  of which {cal.cross_axis.accuracy:.5f} m/s² for the cross-axis terms gn '
              f'leaves out ({cal.cross_axis.source})')
    if summary.get('windows_low_passed'):
        print('windows found on a 5 Hz low-passed copy: vibration hid the holds from the '
              'plain detector (the calibration node has only the plain one)')
    if dropped:
        print(f'dropped {len(dropped)} window(s):')
        for d in dropped:
            print(f'  {d["t_start"]:9.2f} .. {d["t_stop"]:9.2f} s: {d["reason"]}')
    if cal.temperature_range_c is not None:
        print(f'temperature range: {cal.temperature_range_c[0]:.1f} .. '
              f'{cal.temperature_range_c[1]:.1f} °C')
    if cal.thermal is not None:
        for band in cal.thermal.bands:
            print(f'  band {band.low_c:5.1f}..{band.high_c:5.1f} °C: {band.windows:3d} windows,'
                  f' {"usable" if band.status == "ok" else "not usable: " + band.status}')
    for line in summary.get('sensor_lines', ()):
        print(line)
    if out_path:
        print(f'wrote {out_path}')


def _imu_summary(outcome):
    """Return the ``gyro_*`` / ``mag_*`` keys, the per-sensor statuses, a line per sensor."""
    d = outcome.json_keys()
    del d['gyro_bias']          # the fit's own key (interface.md §6), the same vector when fitted
    d['sensors'] = outcome.sensors()
    d['sensor_lines'] = outcome.sensor_lines()
    if outcome.calibration is None:        # no fit at all: the accelerometer is insufficient
        d['sensors']['accelerometer']['status'] = 'insufficient'
        d['sensor_lines'][0] = f'accelerometer: insufficient: {outcome.refusal}'
    return d


def settings(args):
    """Return the session settings of the ``fit`` options."""
    from .common import unit_options
    from ..dataio.units import input_units
    from ..session.settings import DEFAULT_SETTINGS as S, FIT
    units = unit_options(args)
    return S.replace(
        method=args.method, gravity=args.gravity, thermal='on' if args.thermal else 'off',
        band_width_c=args.band_width or S.band_width_c,
        max_predicted_error=args.max_predicted_error,
        max_residual_ratio=getattr(args, 'max_residual_ratio', S.max_residual_ratio),
        max_weight_s=getattr(args, 'max_weight_s', S.max_weight_s),
        allow_unconverged=args.force, max_gyro_error=args.max_gyro_error,
        max_mag_error=args.max_mag_error, field_uT=args.field,
        sensor_id=getattr(args, 'sensor', None),
        input_units=input_units(units['units'], units['counts_per_g'], units['counts_offset']),
        source=os.path.basename(args.data), words=FIT)


def run(args, out):
    """Run ``accel-calib fit``; return the exit status."""
    from ..core.errors import InputError
    from ..session.accept import RecordingImu, refused
    from ..session.finish import finish_session
    from ..session.settings import FIT
    from ..session.windows import Observations, WindowSet
    mode_options(args, {'--min-span': 5.0, '--hysteresis': 'auto'},
                 '--thermal --calibration CALIB (one still pose)',
                 args.calibration is not None)
    if args.calibration is not None:
        if not args.thermal:
            raise UsageError('accel-calib: fit --calibration is the calibration a thermal fit '
                             'extends: add --thermal (DATA: one still pose while the '
                             'temperature sweeps)')
        from .fit_thermal import run as run_thermal
        return run_thermal(args, out)
    if args.output == STDOUT and args.json:
        raise UsageError('accel-calib: fit -o - writes the YAML to standard output: leave out '
                         '--json')
    check_output(args.output, args.data, stdout=True)
    samples = load_data(args)
    obs = None
    imu = RecordingImu(samples)
    try:
        obs = _observations(samples, args)
        target = None
        if getattr(args, 'history', None) is not None:     # per-sensor history
            obs, target = history_observations(args, samples, obs)
    except CalibrationError as err:
        outcome = refused(str(err), imu, words=FIT, limit=args.max_predicted_error)
    else:
        imu.windows = obs.windows
        outcome = finish_session(
            None if obs.kept is None else WindowSet.from_static(obs.kept, samples.t),
            settings(args), imu,
            obs=Observations(obs.readings, obs.weights, obs.temps, obs.noise, obs.gyro),
            rate_hz=samples.rate_hz, history=target,
            output=args.output if args.output != STDOUT else None)
    if outcome.cause is not None and not outcome.accepted:  # the arguments', not the data's
        raise InputError(outcome.refusal)
    if outcome.refusal is not None and not outcome.accepted and args.thermal:
        from .fit_thermal import one_pose_hint
        outcome.refusal += one_pose_hint(args, samples)
    cal = outcome.calibration
    if cal is None:
        if args.json:       # still exactly one JSON object, saying why
            imu_keys = _imu_summary(outcome)
            imu_keys.pop('sensor_lines')
            out({'method': args.method, 'mode': args.mode, 'samples': len(samples),
                 'observations': 0 if obs is None else obs.count, 'accepted': False,
                 'refusal': outcome.refusal, 'converged': False, 'predicted_accuracy': None,
                 'max_predicted_error': args.max_predicted_error,
                 'dropped_windows': [] if obs is None else obs.dropped, 'output': None,
                 **imu_keys})
        raise CalibrationError(outcome.refusal)
    raw_resid = np.sqrt(np.mean((np.linalg.norm(obs.readings, axis=1) - args.gravity) ** 2))
    refusal = outcome.refusal
    verdict = outcome.verdict
    extra = {'mode': args.mode, 'samples': len(samples), 'residual_rms_uncalibrated': raw_resid,
             'max_predicted_error': args.max_predicted_error, 'accepted': refusal is None,
             'refusal': refusal, 'dropped_windows': obs.dropped,
             'output': args.output if refusal is None else None,
             'windows_low_passed': obs.low_passed,
             'next_poses': [{'name': name, 'predicted_accuracy_after': after}
                            for name, after in verdict.poses]}
    if refusal is None and not cal.converged:
        print(f'accel-calib: WARNING: the {cal.method} fit did NOT converge in '
              f'{cal.iterations} iterations; writing it only because of --force. Do not '
              'trust this calibration.', file=sys.stderr)
    for warning in outcome.warnings:
        print(f'accel-calib: warning: {warning}', file=sys.stderr)
    if refusal is None:
        warn_imu((outcome.gyro, outcome.magnetometer))
    if outcome.notes:           # saved, but the history could not take it
        raise InputError('; '.join(outcome.notes))
    if refusal is None and args.output == STDOUT:
        from ..dataio.calibration_file import calibration_yaml
        sys.stdout.write(calibration_yaml(cal))
        sys.stdout.flush()
    if outcome.history is not None:
        extra['history'] = outcome.history
        report_history(outcome.history, args.sensor)
    summary = _fit_summary(cal, extra)
    summary.update(_imu_summary(outcome))
    if args.json:
        summary.pop('sensor_lines')
        out(summary)
    else:
        import contextlib
        with contextlib.redirect_stdout(sys.stderr if args.output == STDOUT else sys.stdout):
            _print_fit(cal, summary, obs.count, args.mode, len(samples), obs.dropped,
                       args.output if refusal is None and args.output != STDOUT else None)
    if refusal is not None:
        raise CalibrationError(refusal)
    return 0
