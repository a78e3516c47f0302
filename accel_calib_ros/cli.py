"""
``accel-calib``: the calibration science offline, on CSV or rosbag2 recordings.

Exit status: 0 success, 2 bad usage or bad input, 1 a calibration that cannot be
solved. Human summary on stdout by default, exactly one JSON object with --json;
diagnostics on stderr; never a traceback for a user mistake.
"""

import argparse
import json
import os
import sys

import numpy as np

from .core.calibration import calibrate, METHODS
from .core.errors import CalibrationError, InputError
from .core.samples import Samples
from .core.windows import DEFAULTS, detect_static_windows

G0 = 9.80665
MAX_WEIGHT_S = 5.0
"""Window weights are capped at this many seconds of samples (see StaticWindows.weights)."""


class UsageError(Exception):
    """Bad command-line usage (exit status 2)."""


class _Parser(argparse.ArgumentParser):
    def error(self, message):
        raise UsageError(f'{self.prog}: {message}')


def _add_data_args(p):
    p.add_argument('data', help='CSV file (t, ax, ay, az[, temp, gx, gy, gz]) or rosbag2 '
                                '(.mcap, .db3 or bag directory)')
    p.add_argument('--imu-topic', help='sensor_msgs/Imu topic in a bag (default: the only one)')
    p.add_argument('--temp-topic', help='sensor_msgs/Temperature topic in a bag')


def _add_window_args(p):
    g = p.add_argument_group('static windows')
    g.add_argument('--min-window-s', type=float, default=DEFAULTS['min_duration_s'],
                   help='shortest static window kept after trimming its ends, s '
                        '(default %(default)s: poses held about 1.5 s or longer)')
    g.add_argument('--threshold-factor', type=float, default=DEFAULTS['threshold_factor'],
                   help='still when moving std < factor x noise floor (default %(default)s)')
    g.add_argument('--max-weight-s', type=float, default=MAX_WEIGHT_S,
                   help='cap of a window weight, seconds of samples (default %(default)s)')


def _positive(text):
    value = float(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f'must be positive, got {text}')
    return value


def build_parser():
    """Build the argparse parser of ``accel-calib``."""
    parser = _Parser(prog='accel-calib', description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest='command', required=True, parser_class=_Parser)

    p = sub.add_parser('fit', help='fit a calibration to a recording')
    _add_data_args(p)
    p.add_argument('--method', choices=METHODS, default='ml',
                   help='ml: maximum likelihood (Sun & Xu); ml-bc: ML with bootstrap bias '
                        'correction; gn: 6-parameter Gauss-Newton (Gui Yi); ellipsoid: '
                        'algebraic LS (default ml)')
    p.add_argument('--mode', choices=('windows', 'samples'), default='windows',
                   help='windows: one observation per detected static window; samples: '
                        'every row is one observation (default windows)')
    p.add_argument('--thermal', action='store_true',
                   help='also fit temperature-band drift tables (needs temp)')
    p.add_argument('--band-width', type=_positive, default=10.0,
                   help='temperature band width, °C (default %(default)s)')
    p.add_argument('--gravity', type=_positive, default=G0,
                   help='local gravity magnitude, m/s² (default %(default)s)')
    p.add_argument('-o', '--output', help='write the calibration YAML here (atomically)')
    p.add_argument('--json', action='store_true', help='print one JSON object')
    _add_window_args(p)

    p = sub.add_parser('apply', help='correct a recording with a calibration file')
    p.add_argument('calibration', help='calibration YAML from "accel-calib fit"')
    _add_data_args(p)
    p.add_argument('-o', '--output', required=True, help='corrected CSV to write')
    p.add_argument('--json', action='store_true', help='print one JSON object')

    p = sub.add_parser('simulate', help='simulate a calibration session of an MPU9250')
    p.add_argument('-o', '--output', required=True,
                   help='CSV, or rosbag2 when it ends in .mcap or .db3')
    p.add_argument('--poses', default='24',
                   help='number of random poses, "faces" (six faces) or "sunxu:N" '
                        '(Sun & Xu Euler-angle poses) (default 24)')
    p.add_argument('--hold', type=_positive, default=3.0, help='seconds per pose')
    p.add_argument('--move', type=_positive, default=1.5, help='seconds per move')
    p.add_argument('--rate', type=_positive, default=100.0, help='sample rate, Hz')
    p.add_argument('--temp', type=float, nargs='+', default=[25.0], metavar='C',
                   help='temperature, °C: one value, or START END for a ramp')
    p.add_argument('--effects', default='',
                   help='comma-separated extra effects: scale_nonlinearity, '
                        'temperature_bias, temperature_scale, bias_drift')
    p.add_argument('--orthogonal', action='store_true',
                   help='no non-orthogonality (diagonal T, the GN model)')
    p.add_argument('--gravity', type=_positive, default=G0, help='gravity, m/s²')
    p.add_argument('--seed', type=int, default=0, help='random seed')
    p.add_argument('--truth', help='write the true sensor parameters to this YAML')
    p.add_argument('--json', action='store_true', help='print one JSON object')

    p = sub.add_parser('diagnose', help='find the physical effect the model is missing')
    _add_data_args(p)
    p.add_argument('--baseline', choices=('gn', 'ml'), default='ml')
    p.add_argument('--report', help='folder for PNG plots and a Markdown summary')
    p.add_argument('--min-effect-mg', type=_positive, default=None,
                   help='name an effect only when its worst-case error in corrected '
                        'acceleration exceeds this, mg (default: the predicted accuracy '
                        'of the fit, at least 1 mg)')
    p.add_argument('--gravity', type=_positive, default=G0, help='gravity, m/s²')
    p.add_argument('--json', action='store_true', help='print one JSON object')
    _add_window_args(p)

    _add_allan_parser(sub)

    p = sub.add_parser('simulate-device',
                       help='stream MPU9250 serial frames of a virtual sensor on a pty')
    try:
        from . import device
        device.add_arguments(p)
        p.set_defaults(run_device=device.run)
    except ImportError as err:      # pragma: no cover - only while device.py is missing
        p.set_defaults(run_device=None, device_error=str(err))
    return parser


# -- commands ----------------------------------------------------------------------------

def _load(args):
    from .dataio.recording import load_samples
    return load_samples(args.data, imu_topic=args.imu_topic, temp_topic=args.temp_topic)


def _observations(samples, args):
    """Return readings, weights, temperatures and noise for the chosen mode."""
    if getattr(args, 'mode', 'windows') == 'samples':
        return samples.accel, None, samples.temp, None, len(samples)
    windows = detect_static_windows(samples, min_duration_s=args.min_window_s,
                                    threshold_factor=args.threshold_factor)
    if len(windows) == 0:
        raise CalibrationError(
            'no static windows found: hold each pose still for at least '
            f'{args.min_window_s + 2 * DEFAULTS["trim_s"] + DEFAULTS["window_s"]:g} s '
            '(or use --mode samples for a moving recording)')
    weights = windows.weights(args.max_weight_s, samples.rate_hz)
    return windows.mean, weights, windows.temp, windows.noise_std, len(windows)


def _fit_summary(cal, extra):
    d = {'method': cal.method, 'T': cal.T.tolist(), 'bias': cal.bias.tolist(),
         'residual_rms': cal.residual_rms, 'iterations': cal.iterations,
         'observations': cal.observations, 'converged': cal.converged, 'seconds': cal.seconds,
         'gravity': cal.gravity, 'scale': cal.scale.tolist(),
         'nonorthogonality_deg': cal.nonorthogonality_deg.tolist(),
         'noise_std': [None if not np.isfinite(v) else float(v) for v in cal.noise_std]}
    if cal.covariance is not None:
        d['stddev'] = np.sqrt(np.maximum(np.diag(cal.covariance), 0)).tolist()
    if cal.thermal is not None:
        d['thermal'] = cal.thermal.to_dict()
    d.update(extra)
    return d


def cmd_fit(args, out):
    samples = _load(args)
    readings, weights, temps, noise, n_obs = _observations(samples, args)
    cal = calibrate(readings, gravity=args.gravity, method=args.method, weights=weights,
                    temps=temps, thermal=args.thermal, band_width_c=args.band_width,
                    noise_std=noise, source=os.path.basename(args.data))
    raw_resid = np.sqrt(np.mean((np.linalg.norm(readings, axis=1) - args.gravity) ** 2))
    extra = {'mode': args.mode, 'samples': len(samples), 'residual_rms_uncalibrated': raw_resid,
             'output': args.output}
    if args.output:
        from .dataio.calibration_file import save_calibration
        save_calibration(cal, args.output)
    for problem in cal.physical_problems():
        print(f'accel-calib: warning: {problem} (are the data in m/s²?)', file=sys.stderr)
    summary = _fit_summary(cal, extra)
    if args.json:
        out(summary)
        return 0
    print(f'{cal.method} fit of {n_obs} {"windows" if args.mode == "windows" else "samples"} '
          f'({len(samples)} samples): {"converged" if cal.converged else "NOT converged"} '
          f'in {cal.iterations} iterations, {cal.seconds * 1e3:.1f} ms')
    with np.printoptions(precision=6, suppress=True):
        print(f'T (raw = T·true + bias):\n{cal.T}')
        print(f'bias [m/s²]: {cal.bias}')
        print(f'scale: {cal.scale}   non-orthogonality [deg] xy xz yz: '
              f'{cal.nonorthogonality_deg}')
    print(f'gravity-norm residual RMS: {cal.residual_rms:.5f} m/s² '
          f'(uncalibrated {raw_resid:.5f} m/s²)')
    if cal.thermal is not None:
        for band in cal.thermal.bands:
            print(f'  band {band.low_c:5.1f}..{band.high_c:5.1f} °C: {band.windows:3d} windows,'
                  f' {band.status}')
    if args.output:
        print(f'wrote {args.output}')
    return 0


def cmd_apply(args, out):
    from .dataio.recording import write_samples_csv
    from .dataio.calibration_file import load_calibration
    cal = load_calibration(args.calibration)
    samples = _load(args)
    if cal.thermal is not None and cal.thermal.usable and samples.temp is None:
        print('accel-calib: warning: calibration has temperature tables but the data have '
              'no temperature; applying without drift correction', file=sys.stderr)
    corrected = cal.correct(samples.accel, samples.temp)
    write_samples_csv(args.output, Samples(samples.t, corrected, samples.temp, samples.gyro))
    norm_before = np.linalg.norm(samples.accel, axis=1)
    norm_after = np.linalg.norm(corrected, axis=1)
    summary = {'output': args.output, 'samples': len(samples), 'calibration': args.calibration,
               'mean_norm_before': float(norm_before.mean()),
               'mean_norm_after': float(norm_after.mean())}
    if args.json:
        out(summary)
    else:
        print(f'corrected {len(samples)} samples -> {args.output} '
              f'(mean |a| {norm_before.mean():.4f} -> {norm_after.mean():.4f} m/s²)')
    return 0


def cmd_simulate(args, out):
    from .core import simulate as sim
    from .dataio.recording import write_bag, write_samples_csv
    rng = np.random.default_rng(args.seed)
    effects = [e.strip() for e in args.effects.split(',') if e.strip()]
    known = ('scale_nonlinearity', 'temperature_bias', 'temperature_scale', 'bias_drift',
             'nonorthogonality')
    for e in effects:
        if e not in known:
            raise UsageError(f'unknown effect {e!r}; choose from {", ".join(known)}')
    sensor = sim.mpu9250_like(rng, args.rate, effects)
    if args.orthogonal:
        sensor.T = np.diag(np.diag(sensor.T))
    if args.poses == 'faces':
        directions = sim.face_directions()
    elif args.poses.startswith('sunxu:'):
        directions = sim.sun_xu_directions(int(args.poses[6:]), rng)
    else:
        try:
            count = int(args.poses)
        except ValueError:
            raise UsageError(f'--poses takes a number, "faces" or "sunxu:N", '
                             f'not {args.poses!r}') from None
        if count < 1:
            raise UsageError('--poses must be at least 1')
        directions = sim.random_directions(count, rng)
    if len(args.temp) not in (1, 2):
        raise UsageError('--temp takes one value or START END')
    temperature = args.temp[0] if len(args.temp) == 1 else tuple(args.temp)
    session = sim.simulate_session(sensor, directions, rng, hold_s=args.hold, move_s=args.move,
                                   rate_hz=args.rate, gravity=args.gravity,
                                   temperature=temperature)
    if args.output.endswith(('.mcap', '.db3')):
        write_bag(args.output, session.samples)
    else:
        write_samples_csv(args.output, session.samples)
    truth = sensor_to_dict(sensor, args.gravity)
    if args.truth:
        import yaml
        from .dataio.atomic import atomic_write_text
        atomic_write_text(args.truth, yaml.safe_dump(truth, sort_keys=False))
    summary = {'output': args.output, 'samples': len(session.samples), 'poses': len(directions),
               'seconds': float(session.samples.t[-1]), 'truth': truth}
    if args.json:
        out(summary)
    else:
        print(f'simulated {len(directions)} poses, {len(session.samples)} samples '
              f'({session.samples.t[-1]:.1f} s) -> {args.output}')
    return 0


def sensor_to_dict(sensor, gravity):
    """Return the true parameters of a simulated sensor as a mapping (m/s², °C, s)."""
    return {'T': sensor.T.tolist(), 'bias_m_s2': sensor.bias.tolist(),
            'noise_std_m_s2': sensor.noise_std.tolist(), 'lsb_m_s2': float(sensor.lsb),
            'nonlinearity': sensor.nonlinearity.tolist(),
            'bias_tempco_m_s2_per_c': sensor.bias_tempco.tolist(),
            'scale_tempco_per_c': sensor.scale_tempco.tolist(),
            'bias_drift_m_s2_per_s': sensor.bias_drift.tolist(),
            'temp_ref_c': float(sensor.temp_ref), 'gravity_m_s2': float(gravity)}


def cmd_diagnose(args, out):
    from .core.diagnose import diagnose
    samples = _load(args)
    result = diagnose(samples, baseline=args.baseline, gravity=args.gravity,
                      min_duration_s=args.min_window_s,
                      threshold_factor=args.threshold_factor,
                      max_weight_s=args.max_weight_s, min_effect_mg=args.min_effect_mg)
    if args.report:
        from .report import write_report
        write_report(result, args.report)
    if args.json:
        out(result.summary())
    else:
        print(result.text())
        if args.report:
            print(f'report: {os.path.join(args.report, "report.md")}')
    return 0


def _add_allan_parser(sub):
    p = sub.add_parser('allan', help='Allan deviation of a still recording (noise terms)')
    _add_data_args(p)
    p.add_argument('--plot', help='write the log-log Allan deviation plot to this PNG')
    p.add_argument('--json', action='store_true', help='print one JSON object')


def cmd_allan(args, out):
    from .core.allan import allan
    if args.plot and os.path.abspath(args.plot) == os.path.abspath(args.data):
        raise UsageError('accel-calib allan: --plot must not overwrite the data file')
    result = allan(_load(args).validate())
    if args.plot:
        from .report import write_allan_plot
        write_allan_plot(result, args.plot)
    if args.json:
        out(result.summary())
    else:
        print(result.text())
    return 0


def cmd_simulate_device(args, out):
    if args.run_device is None:
        raise UsageError(f'simulate-device is not available: {args.device_error}')
    return args.run_device(args)


COMMANDS = {'fit': cmd_fit, 'apply': cmd_apply, 'simulate': cmd_simulate, 'diagnose': cmd_diagnose}
COMMANDS['simulate-device'] = cmd_simulate_device
COMMANDS['allan'] = cmd_allan


def _plain(value):
    """Return ``value`` as strict-JSON data: lists, floats, None for NaN or infinity."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value


def main(argv=None):
    """Entry point of the ``accel-calib`` console script; returns the exit status."""
    def out(obj):
        print(json.dumps(_plain(obj), allow_nan=False))

    try:
        args = build_parser().parse_args(argv)
        return COMMANDS[args.command](args, out)
    except UsageError as err:
        print(f'{err}', file=sys.stderr)
        return 2
    except InputError as err:
        print(f'accel-calib: error: {err}', file=sys.stderr)
        return 2
    except CalibrationError as err:
        print(f'accel-calib: cannot calibrate: {err}', file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:
        return 0
    except OSError as err:
        print(f'accel-calib: error: {err.strerror or err}: {err.filename or ""}'.rstrip(': '),
              file=sys.stderr)
        return 2
    except SystemExit as err:   # argparse --help
        return err.code if isinstance(err.code, int) else 0
    except Exception as err:    # noqa: B902 - a bug must still not dump a traceback on users
        if os.environ.get('ACCEL_CALIB_DEBUG'):
            raise
        print(f'accel-calib: internal error: {type(err).__name__}: {err} '
              '(set ACCEL_CALIB_DEBUG=1 for the traceback)', file=sys.stderr)
        return 1


if __name__ == '__main__':
    sys.exit(main())
