"""
``accel-calib``: the calibration science offline, on CSV or rosbag2 recordings.

Exit status: 0 success, 2 bad usage or bad input, 1 a calibration that cannot be
solved. Human summary on stdout by default, exactly one JSON object with --json;
diagnostics on stderr; never a traceback for a user mistake.
"""

import argparse
import itertools
import json
import os
import sys

import numpy as np

from .core.accel.calibration import calibrate, METHODS
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
    g.add_argument('--min-window-s', type=_ranged(0.01, 3600.0),
                   default=DEFAULTS['min_duration_s'],
                   help='shortest static window kept after trimming its ends, s '
                        '(default %(default)s: poses held about 1 s or longer)')
    g.add_argument('--threshold-factor', type=_ranged(1.0, 1e3),
                   default=DEFAULTS['threshold_factor'],
                   help='still when moving std < factor x noise floor (default %(default)s)')
    g.add_argument('--max-weight-s', type=_ranged(1e-3, 1e6), default=MAX_WEIGHT_S,
                   help='cap of a window weight, seconds of samples (default %(default)s)')


def _number(text):
    try:
        value = float(text)
    except (TypeError, ValueError):
        raise argparse.ArgumentTypeError(f'not a number: {text!r}') from None
    if not np.isfinite(value):
        raise argparse.ArgumentTypeError(f'must be a finite number, got {text!r}')
    return value


def _positive(text):
    value = _number(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f'must be positive, got {text}')
    return value


def _ranged(low, high, integer=False):
    """Argparse type: a finite number (an integer with ``integer``) in [low, high]."""
    def parse(text):
        if integer:
            try:
                value = int(text, 10)
            except (TypeError, ValueError):
                raise argparse.ArgumentTypeError(f'not an integer: {text!r}') from None
        else:
            value = _number(text)
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f'must lie in [{low:g}, {high:g}], got {text}')
        return value
    parse.__name__ = 'integer' if integer else 'number'
    return parse


GRAVITY = _ranged(0.1, 100.0)
"""Local gravity accepted, m/s² (1.0 allows data in units of g)."""
TEMPERATURE = _ranged(-100.0, 200.0)
SEED = _ranged(0, 2 ** 32 - 1, integer=True)
MAX_SIMULATED_SAMPLES = 50_000_000
MAX_POSES = 100_000


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
    p.add_argument('--band-width', type=_ranged(0.1, 1000.0), default=10.0,
                   help='temperature band width, °C (default %(default)s)')
    p.add_argument('--gravity', type=GRAVITY, default=G0,
                   help='local gravity magnitude, m/s² (default %(default)s)')
    p.add_argument('--max-predicted-error', type=_ranged(1e-9, 1e3), default=0.02,
                   metavar='M_S2',
                   help='refuse a fit whose predicted accuracy (RMS error at 1 g over all '
                        'orientations) is worse than this, m/s² (default %(default)s)')
    p.add_argument('--force', action='store_true',
                   help='write the calibration even if the fit did not converge (loud '
                        'warning; JSON still says converged false)')
    p.add_argument('-o', '--output', help='write the calibration YAML here (atomically)')
    p.add_argument('--json', action='store_true', help='print one JSON object')
    _add_window_args(p)
    from .history_cli import add_fit_arguments
    add_fit_arguments(p)

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
    p.add_argument('--hold', type=_ranged(0.01, 1e6), default=3.0, help='seconds per pose')
    p.add_argument('--move', type=_ranged(0.01, 3600.0), default=1.5, help='seconds per move')
    p.add_argument('--rate', type=_ranged(1.0, 100000.0), default=100.0,
                   help='sample rate, Hz')
    p.add_argument('--temp', type=TEMPERATURE, nargs='+', default=[25.0], metavar='C',
                   help='temperature, °C: one value, or START END for a ramp')
    p.add_argument('--effects', default='',
                   help='comma-separated extra effects: scale_nonlinearity, '
                        'temperature_bias, temperature_scale, bias_drift')
    p.add_argument('--orthogonal', action='store_true',
                   help='no non-orthogonality (diagonal T, the GN model)')
    p.add_argument('--gravity', type=GRAVITY, default=G0, help='gravity, m/s²')
    p.add_argument('--seed', type=SEED, default=0, help='random seed (0 to 2**32-1)')
    p.add_argument('--truth', help='write the true sensor parameters to this YAML')
    p.add_argument('--noise-from', metavar='ALLAN.json',
                   help='per-sample accel (and gyro) noise from "accel-calib allan --json" '
                        '(white_sample_std, kept at its noise density at --rate)')
    p.add_argument('--json', action='store_true', help='print one JSON object')

    p = sub.add_parser('diagnose', help='find the physical effect the model is missing')
    _add_data_args(p)
    p.add_argument('--baseline', choices=('gn', 'ml'), default='ml')
    p.add_argument('--report', help='folder for PNG plots and a Markdown summary')
    p.add_argument('--min-effect-mg', type=_ranged(1e-6, 1e4), default=None,
                   help='name an effect only when its worst-case error in corrected '
                        'acceleration exceeds this, mg (default: the predicted accuracy '
                        'of the fit, at least 1 mg)')
    p.add_argument('--gravity', type=GRAVITY, default=G0, help='gravity, m/s²')
    p.add_argument('--json', action='store_true', help='print one JSON object')
    _add_window_args(p)

    _add_allan_parser(sub)

    # Its options live in device.py, loaded only when the command runs (see main).
    sub.add_parser('simulate-device', add_help=False,
                   help='stream MPU9250 serial frames of a virtual sensor on a pty')
    from . import guide, history_cli
    COMMANDS.update(guide.add_parsers(sub))
    COMMANDS.update(history_cli.add_parsers(sub))
    return parser


def _device_parser():
    """Return the parser of ``accel-calib simulate-device`` (imports device.py)."""
    parser = _Parser(prog='accel-calib simulate-device',
                     description='stream MPU9250 serial frames of a virtual sensor on a pty')
    try:
        from . import device
        device.add_arguments(parser)
        parser.set_defaults(command='simulate-device', run_device=device.run)
    except ImportError as err:      # pragma: no cover - only while device.py is missing
        parser.set_defaults(command='simulate-device', run_device=None, device_error=str(err))
    return parser


# -- commands ----------------------------------------------------------------------------

def _load(args):
    from .dataio.recording import load_samples
    from .progress import Progress
    size = os.path.getsize(args.data) if os.path.isfile(args.data) else None
    with Progress(size, 'read', 'B') as bar:     # shown only for a long read on a terminal
        return load_samples(args.data, imu_topic=args.imu_topic, temp_topic=args.temp_topic,
                            on_read=bar.update)


def _same_file(a, b):
    """Return True when paths ``a`` and ``b`` name the same file (or would; not if empty)."""
    if not a or not b:
        return False
    a, b = os.path.expanduser(os.fspath(a)), os.path.expanduser(os.fspath(b))
    try:
        if os.path.exists(a) and os.path.exists(b):
            return os.path.samefile(a, b)
    except OSError:
        pass
    return os.path.realpath(a) == os.path.realpath(b)


def _check_output(output, *inputs, what='output'):
    """Raise UsageError when ``output`` is one of ``inputs`` (it would destroy it)."""
    if not output:
        return
    if os.path.isdir(os.path.expanduser(output)):
        raise UsageError(f'accel-calib: {what} {output} is a directory')
    for path in inputs:
        if path and _same_file(output, path):
            raise UsageError(f'accel-calib: {what} {output} is the input {path}; '
                             'writing it would destroy the input: choose another name')


class _Observations:
    """Observations for the fit, with what was left out (mode, windows, reasons)."""

    def __init__(self, **kw):
        self.__dict__.update(kw)


def _observations(samples, args):
    """Return the observations for the chosen mode, outlier windows dropped."""
    if getattr(args, 'mode', 'windows') == 'samples':
        return _Observations(readings=samples.accel, weights=None, temps=samples.temp,
                             noise=None, count=len(samples), gyro=None, dropped=[],
                             mean_count=1.0)
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
    from .core.accel.calibration import find_outlier_windows
    keep, outliers = find_outlier_windows(
        windows.mean, weights, windows.count, windows.noise_std, args.gravity,
        windows.temp, getattr(args, 'thermal', False), getattr(args, 'band_width', 10.0),
        getattr(args, 'method', 'ml'))
    for k, reason in outliers:
        dropped.append({'t_start': float(samples.t[windows.start[k]]),
                        't_stop': float(samples.t[windows.stop[k] - 1]), 'reason': reason})
    windows = windows.select(keep)
    dropped.sort(key=lambda d: d['t_start'])
    return _Observations(readings=windows.mean, weights=weights[keep], temps=windows.temp,
                         noise=windows.noise_std, count=len(windows),
                         gyro=windows.gyro_mean, dropped=dropped, t_mid=windows.t_mid,
                         mean_count=float(np.mean(windows.count)) if len(windows) else 1.0)


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
    if out_path:
        print(f'wrote {out_path}')


def _unstorable(cal):
    """Reason the calibration file loader would refuse ``cal`` (None when it accepts it)."""
    from .dataio.calibration_file import calibration_from_dict, calibration_to_dict
    try:
        calibration_from_dict(calibration_to_dict(cal))
    except InputError as err:
        return f'the fitted calibration is implausible ({err}); are the data in m/s²?'
    return None


def _drop_implausible_gyro_bias(cal):
    """Leave out a gyro bias no rad/s gyro has (the accelerometer fit still counts)."""
    from .dataio.calibration_file import MAX_GYRO_BIAS
    biases = [cal.gyro_bias] + ([b.gyro_bias for b in cal.thermal.bands]
                                if cal.thermal is not None else [])
    if all(b is None or np.all(np.abs(b) <= MAX_GYRO_BIAS) for b in biases):
        return
    print(f'accel-calib: warning: gyro bias {np.round(cal.gyro_bias, 3).tolist()} exceeds '
          f'{MAX_GYRO_BIAS:g} rad/s (are gx gy gz in rad/s?); not stored', file=sys.stderr)
    cal.gyro_bias = None
    if cal.thermal is not None:
        for band in cal.thermal.bands:
            band.gyro_bias = None


def cmd_fit(args, out):
    _check_output(args.output, args.data)
    samples = _load(args)
    obs = None
    try:
        obs = _observations(samples, args)
        if getattr(args, 'history', None) is not None:     # per-sensor history
            from .history_cli import history_observations
            obs = history_observations(args, samples, obs)
        cal = calibrate(obs.readings, gravity=args.gravity, method=args.method,
                        weights=obs.weights, temps=obs.temps, thermal=args.thermal,
                        band_width_c=args.band_width, noise_std=obs.noise,
                        source=os.path.basename(args.data), gyro_means=obs.gyro,
                        mean_count=obs.mean_count)
    except CalibrationError as err:
        if args.json:       # still exactly one JSON object, saying why
            out({'method': args.method, 'mode': args.mode, 'samples': len(samples),
                 'observations': 0 if obs is None else obs.count, 'accepted': False,
                 'refusal': str(err), 'converged': False, 'predicted_accuracy': None,
                 'max_predicted_error': args.max_predicted_error,
                 'dropped_windows': [] if obs is None else obs.dropped, 'output': None})
        raise
    raw_resid = np.sqrt(np.mean((np.linalg.norm(obs.readings, axis=1) - args.gravity) ** 2))
    _drop_implausible_gyro_bias(cal)
    from .core.acceptance import review
    verdict = review(cal, args.max_predicted_error, allow_unconverged=args.force,
                     limit_name='--max-predicted-error')
    refusal = verdict.refusal
    if not verdict.converged and refusal is not None:
        refusal += '; nothing written (--force writes it anyway)'
    refusal = refusal or _unstorable(cal)
    extra = {'mode': args.mode, 'samples': len(samples), 'residual_rms_uncalibrated': raw_resid,
             'max_predicted_error': args.max_predicted_error, 'accepted': refusal is None,
             'refusal': refusal, 'dropped_windows': obs.dropped,
             'output': args.output if refusal is None else None}
    if refusal is None and not cal.converged:
        print(f'accel-calib: WARNING: the {cal.method} fit did NOT converge in '
              f'{cal.iterations} iterations; writing it only because of --force. Do not '
              'trust this calibration.', file=sys.stderr)
    for warning in verdict.warnings if refusal is None else []:
        print(f'accel-calib: warning: {warning}', file=sys.stderr)
    if refusal is None and args.output:
        from .dataio.calibration_file import save_calibration
        save_calibration(cal, args.output)
    if refusal is None and getattr(args, 'history', None) is not None:
        from .history_cli import record_fit
        record_fit(args, cal, obs.temps)
    summary = _fit_summary(cal, extra)
    if args.json:
        out(summary)
    else:
        _print_fit(cal, summary, obs.count, args.mode, len(samples), obs.dropped,
                   args.output if refusal is None else None)
    if refusal is not None:
        raise CalibrationError(refusal)
    return 0


def _check_suffix(path, suffixes, what):
    """Refuse an output name whose suffix says no format this command writes (exit 2)."""
    if not path.lower().endswith(suffixes):
        names = ' or '.join(suffixes)
        raise UsageError(f'accel-calib: error: {what} {path}: the name must end in {names} '
                         '(the suffix picks the file format)')


def cmd_apply(args, out):
    _check_output(args.output, args.calibration, args.data)
    from .dataio.calibration_file import load_calibration
    from .dataio.recording import csv_writer, iter_samples
    from .progress import Progress
    _check_suffix(args.output, ('.csv',), 'apply -o')
    cal = load_calibration(args.calibration)
    is_csv = args.data.lower().endswith('.csv') and os.path.isfile(args.data)
    # Streamed: one piece of the recording in memory at a time, whatever its length.
    with Progress(os.path.getsize(args.data) if is_csv else None, 'apply',
                  'B' if is_csv else 'rows') as bar:
        pieces = iter_samples(args.data, imu_topic=args.imu_topic, temp_topic=args.temp_topic,
                              on_read=bar.update if is_csv else None)
        first = next(pieces)
        if cal.thermal is not None and cal.thermal.usable and first.temp is None:
            print('accel-calib: warning: calibration has temperature tables but the data '
                  'have no temperature; applying without drift correction', file=sys.stderr)
        n, outside, sum_before, sum_after = 0, 0, 0.0, 0.0
        gyro_subtracted = first.gyro is not None and cal.gyro_bias is not None
        with csv_writer(args.output, first.temp is not None, first.gyro is not None) as w:
            for samples in itertools.chain([first], pieces):
                if cal.temperature_range_c is not None and samples.temp is not None:
                    lo, hi = cal.temperature_range_c
                    outside += int(np.sum((samples.temp < lo - 1.0) | (samples.temp > hi + 1.0)))
                with np.errstate(all='ignore'):
                    corrected = cal.correct(samples.accel, samples.temp)
                    gyro = samples.gyro
                    if gyro is not None:
                        gyro = cal.correct_gyro(gyro, samples.temp)
                bad = ~np.all(np.isfinite(corrected), axis=1)
                if gyro is not None:
                    bad |= ~np.all(np.isfinite(gyro), axis=1)
                if bad.any():       # the atomic writer removes what was written so far
                    raise InputError(
                        f'{int(bad.sum())} rows would be non-finite after correction (first '
                        f't={samples.t[np.argmax(bad)]:.3f} s): the data or the calibration '
                        'are out of range; nothing written')
                w.write(Samples(samples.t, corrected, samples.temp, gyro))
                n += len(samples)
                sum_before += float(np.linalg.norm(samples.accel, axis=1).sum())
                sum_after += float(np.linalg.norm(corrected, axis=1).sum())
                if not is_csv:
                    bar.update(len(samples))
    if outside:
        lo, hi = cal.temperature_range_c
        print(f'accel-calib: warning: {outside} samples lie outside the calibrated '
              f'temperature range {lo:.1f} .. {hi:.1f} °C', file=sys.stderr)
    summary = {'output': args.output, 'samples': n, 'calibration': args.calibration,
               'mean_norm_before': sum_before / n, 'mean_norm_after': sum_after / n,
               'gyro_bias_subtracted': gyro_subtracted,
               'samples_outside_temperature_range': outside}
    if args.json:
        out(summary)
    else:
        print(f'corrected {n} samples -> {args.output} '
              f'(mean |a| {sum_before / n:.4f} -> {sum_after / n:.4f} m/s²'
              + (', gyro bias subtracted' if gyro_subtracted else '') + ')')
    return 0


def cmd_simulate(args, out):
    from .core import simulate as sim
    from .dataio.recording import write_bag, write_samples_csv
    from .progress import Progress
    _check_output(args.truth, args.output, what='--truth')
    _check_output(args.output, args.noise_from)
    _check_output(args.truth, args.noise_from, what='--truth')
    if args.output and os.path.isdir(os.path.expanduser(args.output)):
        raise UsageError(f'accel-calib: output {args.output} is a directory')
    _check_suffix(args.output, ('.csv', '.mcap', '.db3'), 'simulate -o')
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
    if args.noise_from:
        from .dataio.noise_file import noise_from_allan
        sensor.noise_std, gyro_noise = noise_from_allan(args.noise_from, args.rate)
        if gyro_noise is not None:
            sensor.gyro_noise_std = gyro_noise
    if args.poses == 'faces':
        directions = sim.face_directions()
    else:
        sunxu = args.poses.startswith('sunxu:')
        text = args.poses[6:] if sunxu else args.poses
        try:
            count = int(text, 10)
        except ValueError:
            raise UsageError(f'accel-calib: --poses takes a number, "faces" or "sunxu:N", '
                             f'not {args.poses[:40]!r}') from None
        if not 1 <= count <= MAX_POSES:
            raise UsageError(f'accel-calib: --poses must lie in [1, {MAX_POSES}], got {count}')
        directions = (sim.sun_xu_directions(count, rng) if sunxu
                      else sim.random_directions(count, rng))
    if len(args.temp) not in (1, 2):
        raise UsageError('accel-calib: --temp takes one value or START END')
    total = len(directions) * (args.hold + args.move) * args.rate + args.hold * args.rate
    if total > MAX_SIMULATED_SAMPLES:
        raise UsageError(f'accel-calib: that session would have {total:.3g} samples; the '
                         f'limit is {MAX_SIMULATED_SAMPLES:.3g} (fewer poses, shorter holds '
                         'or a lower --rate)')
    temperature = args.temp[0] if len(args.temp) == 1 else tuple(args.temp)
    kwargs = {'hold_s': args.hold, 'move_s': args.move, 'rate_hz': args.rate}
    total = sim.session_length(directions, **kwargs)
    last_t = []

    def pieces(bar):        # streamed: one piece of the session in memory at a time
        for piece in sim.iter_session(sensor, directions, rng, gravity=args.gravity,
                                      temperature=temperature, **kwargs):
            bar.update(len(piece.samples))
            last_t[:] = [float(piece.samples.t[-1])]
            yield piece.samples

    with Progress(total, 'simulate') as bar:
        if args.output.lower().endswith(('.mcap', '.db3')):
            write_bag(args.output, pieces(bar))
        else:
            write_samples_csv(args.output, pieces(bar))
    truth = sensor_to_dict(sensor, args.gravity)
    if args.truth:
        import yaml
        from .dataio.atomic import atomic_write_text
        atomic_write_text(args.truth, yaml.safe_dump(truth, sort_keys=False))
    summary = {'output': args.output, 'samples': total, 'poses': len(directions),
               'seconds': last_t[0], 'truth': truth}
    if args.json:
        out(summary)
    else:
        print(f'simulated {len(directions)} poses, {total} samples '
              f'({last_t[0]:.1f} s) -> {args.output}')
    return 0


def sensor_to_dict(sensor, gravity):
    """Return the true parameters of a simulated sensor as a mapping (m/s², °C, s)."""
    return {'T': sensor.T.tolist(), 'bias_m_s2': sensor.bias.tolist(),
            'noise_std_m_s2': sensor.noise_std.tolist(), 'lsb_m_s2': float(sensor.lsb),
            'nonlinearity': sensor.nonlinearity.tolist(),
            'bias_tempco_m_s2_per_c': sensor.bias_tempco.tolist(),
            'scale_tempco_per_c': sensor.scale_tempco.tolist(),
            'bias_drift_m_s2_per_s': sensor.bias_drift.tolist(),
            'temp_ref_c': float(sensor.temp_ref), 'gravity_m_s2': float(gravity),
            'gyro_bias_rad_s': np.asarray(getattr(sensor, 'gyro_bias', np.zeros(3)),
                                          float).tolist(),
            'gyro_noise_std_rad_s': np.asarray(sensor.gyro_noise_std, float).tolist()}


def cmd_diagnose(args, out):
    from .modelgap import diagnose
    if args.report:
        _check_output(os.path.join(args.report, 'report.md'), args.data, what='report')
        if os.path.exists(args.report) and not os.path.isdir(args.report):
            raise UsageError(f'accel-calib: --report {args.report} exists and is not a folder')
    samples = _load(args)
    result = diagnose(samples, baseline=args.baseline, gravity=args.gravity,
                      min_duration_s=args.min_window_s,
                      threshold_factor=args.threshold_factor,
                      max_weight_s=args.max_weight_s, min_effect_mg=args.min_effect_mg)
    if args.report:
        from .modelgap.report import write_report
        write_report(result, args.report)
    if args.json:
        out(result.summary())
    else:
        print(result.text())
        if args.report:
            print(f'report: {os.path.join(args.report, "report.md")}')
    return 0


def _check_device_args(args):
    """Validate the simulate-device options the device module parses loosely."""
    def need(ok, message):
        if not ok:
            raise UsageError(f'accel-calib simulate-device: {message}')

    def finite(name, low, high):
        value = getattr(args, name, None)
        if value is None:
            return
        for v in np.atleast_1d(value):
            need(np.isfinite(v) and low <= v <= high,
                 f'--{name.replace("_", "-")} must lie in [{low:g}, {high:g}], got {v}')

    finite('seed', 0, 2 ** 32 - 1)
    finite('rate', 1.0, 100000.0)
    finite('hold', 0.01, 1e6)
    finite('move', 0.01, 3600.0)
    finite('temp', -100.0, 200.0)
    finite('temp_ramp', -100.0, 200.0)
    finite('gravity', 0.1, 100.0)
    finite('count', 1, MAX_POSES)
    finite('t0_us', 0, 2 ** 32 - 1)
    finite('duration', 1e-3, 1e7)
    finite('unplug_s', 0.0, 3600.0)
    poses = getattr(args, 'poses', None)            # a pose file is an input too
    _check_output(getattr(args, 'truth_out', None), getattr(args, 'link', None),
                  poses if poses and os.path.isfile(poses) else None,
                  getattr(args, 'noise_from', None), what='--truth-out')
    _check_output(getattr(args, 'link', None), poses if poses and os.path.isfile(poses)
                  else None, getattr(args, 'noise_from', None), what='--link')


def _add_allan_parser(sub):
    p = sub.add_parser('allan', help='Allan deviation of a still recording (noise terms)')
    _add_data_args(p)
    p.add_argument('--plot', help='write the log-log Allan deviation plot to this PNG')
    p.add_argument('--json', action='store_true', help='print one JSON object')


def cmd_allan(args, out):
    from .core.allan import allan
    if args.plot:
        _check_output(args.plot, args.data, what='--plot')
        _check_suffix(args.plot, ('.png',), 'allan --plot')
    result = allan(_load(args).validate())
    if args.plot:
        write_allan_plot(result, args.plot)
    if args.json:
        out(result.summary())
    else:
        print(result.text())
    return 0


def write_allan_plot(result, path):
    """Write a log-log plot of the Allan deviation per axis with its 95 % band (PNG)."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    from .dataio.figures import save_figure
    groups = [[i for i, a in enumerate(result.axes) if a.startswith('a')],
              [i for i, a in enumerate(result.axes) if a.startswith('g')]]
    groups = [g for g in groups if g]
    fig, axes = plt.subplots(1, len(groups), figsize=(6 * len(groups), 4.2), squeeze=False)
    for ax, group in zip(axes[0], groups):
        for i in group:
            line, = ax.loglog(result.tau, result.adev[i], label=result.axes[i])
            ax.fill_between(result.tau, result.adev_ci[i, :, 0], result.adev_ci[i, :, 1],
                            color=line.get_color(), alpha=0.2)
            ax.loglog(result.tau, result.noise_density[i] / np.sqrt(result.tau), ':',
                      color=line.get_color(), lw=0.8)
        unit = 'm/s²' if result.axes[group[0]].startswith('a') else 'rad/s'
        ax.set_xlabel('cluster time τ, s')
        ax.set_ylabel(f'Allan deviation, {unit}')
        ax.grid(True, which='both', alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle('Allan deviation (dotted: white noise N/√τ; band: 95 %)')
    save_figure(fig, path)


def cmd_simulate_device(args, out):
    if args.run_device is None:
        raise UsageError(f'simulate-device is not available: {args.device_error}')
    _check_device_args(args)
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


PATH_OPTIONS = {'data': 'DATA', 'calibration': 'the calibration file', 'output': '-o',
                'truth': '--truth', 'report': '--report', 'plot': '--plot',
                'record': '--record', 'db': '--db', 'truth_out': '--truth-out',
                'link': '--link', 'port': '--port', 'topic': '--topic'}
"""File-name (and port/topic) arguments that an empty string must not silently drop."""


def _check_not_empty(args):
    """Refuse an empty file name (``-o "$UNSET"`` silently wrote nothing before)."""
    for name, option in PATH_OPTIONS.items():
        value = getattr(args, name, None)
        if isinstance(value, str) and not value.strip():
            raise UsageError(f'accel-calib: {option} is an empty name; give a file name')


def main(argv=None):
    """Entry point of the ``accel-calib`` console script; returns the exit status."""
    import warnings
    with warnings.catch_warnings():
        if not os.environ.get('ACCEL_CALIB_DEBUG'):    # numpy's 0/0 notes are not for users
            warnings.simplefilter('ignore', RuntimeWarning)
        return _main(argv)


def _main(argv):
    printed = []

    def out(obj):
        print(json.dumps(_plain(obj), allow_nan=False))
        printed.append(True)

    args = None
    try:
        argv = sys.argv[1:] if argv is None else list(argv)
        if argv[:1] == ['simulate-device']:
            args = _device_parser().parse_args(argv[1:])
        else:
            args = build_parser().parse_args(argv)
        _check_not_empty(args)
        return COMMANDS[args.command](args, out)
    except UsageError as err:
        print(f'{err}', file=sys.stderr)
        return 2
    except InputError as err:
        print(f'accel-calib: error: {err}', file=sys.stderr)
        return 2
    except CalibrationError as err:
        if getattr(args, 'json', False) and not printed:   # --json: still one object
            out({'command': args.command, 'accepted': False, 'refusal': str(err)})
        print(f'accel-calib: cannot calibrate: {err}', file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print('accel-calib: interrupted (partial output removed)', file=sys.stderr)
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
