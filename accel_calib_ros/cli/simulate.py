"""``accel-calib simulate``: a calibration session of a simulated MPU-9250, streamed to a file."""

import os
import sys

import numpy as np

from .common import (check_output, check_suffix, GRAVITY, MAX_POSES, mode_options, ranged,
                     SEED, STDOUT, TEMPERATURE, UsageError)
from ..core.constants import G0


MAX_SIMULATED_SAMPLES = 50_000_000
CHAMBER_OPTIONS = {'--chamber-rate': [3.0], '--chamber-hold': 900.0, '--board-tau': 180.0,
                   '--hysteresis': 0.0, '--up': 'z'}
"""The options of ``--chamber`` only, with their defaults there."""


def add_arguments(p):
    """Add the options of ``simulate`` to its parser."""
    p.add_argument('-o', '--output', required=True,
                   help='CSV, or rosbag2 when it ends in .mcap or .db3 ("-": CSV on standard '
                        'output, the summary then goes to stderr)')
    p.add_argument('--poses', default='24',
                   help='number of random poses, "faces" (six faces) or "sunxu:N" '
                        '(Sun & Xu Euler-angle poses) (default 24)')
    p.add_argument('--hold', type=ranged(0.01, 1e6), default=3.0, help='seconds per pose')
    p.add_argument('--move', type=ranged(0.01, 3600.0), default=1.5, help='seconds per move')
    p.add_argument('--rate', type=ranged(1.0, 100000.0), default=100.0,
                   help='sample rate, Hz')
    p.add_argument('--temp', type=TEMPERATURE, nargs='+', default=[25.0], metavar='C',
                   help='temperature, °C: one value, or START END for a ramp')
    p.add_argument('--effects', default='',
                   help='comma-separated extra effects: ' + ', '.join(
                       name + (f' ({effect.sim_note})' if effect.sim_note else '')
                       for name, effect in _switchable().items()))
    p.add_argument('--orthogonal', action='store_true',
                   help='no non-orthogonality (diagonal T, the GN model)')
    p.add_argument('--gravity', type=GRAVITY, default=G0, help='gravity, m/s²')
    p.add_argument('--seed', type=SEED, default=0, help='random seed (0 to 2**32-1)')
    p.add_argument('--truth', help='write the true sensor parameters to this YAML')
    p.add_argument('--noise-from', metavar='ALLAN.json',
                   help='per-sample accel (and gyro) noise from "accel-calib allan --json" '
                        '(white_sample_std, kept at its noise density at --rate)')
    g = p.add_argument_group('gyroscope and magnetometer (off by default)')
    g.add_argument('--gyro-errors', action='store_true',
                   help='gyroscope scale ±3 %% and cross-axis ±2 %% errors (MPU-9250 '
                        'datasheet); the rates still integrate to the simulated turns')
    g.add_argument('--gyro-range', type=ranged(1.0, 10000.0), default=None, metavar='DPS',
                   help='gyroscope full scale, °/s: readings clip there (default: none)')
    g.add_argument('--magnetometer', action='store_true',
                   help='an AK8963-like magnetometer (±30 µT hard iron, ±5 %% soft iron, 2° '
                        'misalignment, 0.4 µT noise, 100 Hz): columns mx my mz, µT')
    g.add_argument('--field', type=ranged(1.0, 1000.0), default=48.0, metavar='UT',
                   help='Earth field magnitude the magnetometer sees, µT (default %(default)s)')
    g.add_argument('--dip', type=ranged(-90.0, 90.0), default=60.0, metavar='DEG',
                   help='field inclination below the horizontal, degrees (default '
                        '%(default)s)')
    g.add_argument('--tremor', type=ranged(0.0, 10.0), default=0.0, metavar='DEG',
                   help='RMS angle a trembling hand turns the sensor while it holds a pose, '
                        'degrees (default 0: perfectly still)')
    g = p.add_argument_group('a climate chamber: one still pose while the temperature cycles '
                             '(the recording of a thermal calibration)')
    g.add_argument('--chamber', type=TEMPERATURE, nargs='+', metavar='C',
                   help='set points the chamber air goes to in turn, °C, starting from --temp '
                        '(e.g. -18 74 -18: cool, heat, cool again); the sensor, with '
                        'MPU-9250-like offsets against temperature (16, 15 and 55 mg over '
                        '-18..74 °C), is held still in one pose (--up)')
    g.add_argument('--chamber-rate', type=ranged(0.01, 100.0), nargs='+', default=None,
                   metavar='C_PER_MIN', help='ramp rate to each set point, °C/min (one value '
                                             'or one per set point; default 3)')
    g.add_argument('--chamber-hold', type=ranged(0.0, 1e5), default=None, metavar='S',
                   help='hold at each set point, s (default 900)')
    g.add_argument('--board-tau', type=ranged(0.0, 1e5), default=None, metavar='S',
                   help="the board's time constant behind the chamber air, s (default 180)")
    g.add_argument('--hysteresis', type=ranged(0.0, 1000.0), default=None, metavar='MG',
                   help='heating minus cooling at the same temperature on the worst axis at '
                        'the ramp rate, mg (a temperature gradient across the package; '
                        'default 0)')
    g.add_argument('--up', choices=('x', '-x', 'y', '-y', 'z', '-z'), default=None,
                   help='the axis that points up in the chamber (default z)')
    p.add_argument('--json', action='store_true', help='print one JSON object')


def _chamber(args, rng):
    """Return (sensor, programme, direction) of a chamber recording (``--chamber``)."""
    from ..sim.chamber import ChamberProgramme, thermal_unit
    if len(args.chamber_rate) not in (1, len(args.chamber)):
        raise UsageError('accel-calib: --chamber-rate takes one rate or one per set point')
    if len(args.temp) != 1:
        raise UsageError('accel-calib: --chamber starts at one --temp (the room), not a ramp')
    programme = ChamberProgramme(args.chamber, args.chamber_rate, args.chamber_hold,
                                 args.temp[0], args.board_tau)
    temps = [args.temp[0], *args.chamber]
    sensor = thermal_unit(rng, span_c=(min(temps), max(temps)),
                          hysteresis_mg=args.hysteresis, rate_c_min=float(args.chamber_rate[0]),
                          temp_ref=args.temp[0], rate_hz=args.rate)
    axis = 'xyz'.index(args.up[-1])
    direction = np.zeros(3)
    direction[axis] = -1.0 if args.up.startswith('-') else 1.0
    return sensor, programme, direction


def _switchable():
    """Return the library effects a simulated sensor gets by name: {name: Effect}."""
    from ..modelgap.effects import EFFECTS
    return {name: effect for name, effect in EFFECTS.items()
            if effect.sensor_range is not None}


def _known():
    """Return the library effects ``--effects`` takes (also those always on, such as T's)."""
    from ..modelgap.effects import EFFECTS
    return [name for name, effect in EFFECTS.items() if effect.datasheet is not None]


def _imu_sensor(sensor, args):
    """
    Add the gyroscope errors and the magnetometer asked for (their own random streams).

    The draws come from generators of their own (seeded from ``--seed``), so that the
    accelerometer, the poses and the noise are those of the session without them.
    """
    if args.gyro_errors or args.gyro_range:
        from ..sim.sensor import with_gyro_errors
        rng = np.random.default_rng([args.seed, 19, 1])
        full_scale = None if args.gyro_range is None else np.radians(args.gyro_range)
        gyro = with_gyro_errors(sensor, rng, full_scale)
        if not args.gyro_errors:            # clipping only
            gyro.gyro_T = np.eye(3)
        sensor = gyro
    if args.magnetometer:
        from ..sim.sensor import ak8963_like
        sensor.magnetometer = ak8963_like(np.random.default_rng([args.seed, 19, 2]))
    return sensor


def imu_truth(sensor, earth_field):
    """Return the true gyroscope and magnetometer parameters (YAML-ready), or {}."""
    d = {'gyro_T': np.asarray(sensor.gyro_T, float).tolist()}
    if np.isfinite(sensor.gyro_full_scale):
        d['gyro_full_scale_rad_s'] = float(sensor.gyro_full_scale)
    mag = sensor.magnetometer
    if mag is not None:
        from ..core.magnetometer.fit import canonical
        T, R, field_uT = canonical(mag.T, mag.R, earth_field.field_uT)
        d['magnetometer'] = {
            'T': mag.T.tolist(), 'hard_iron_uT': mag.hard_iron.tolist(), 'R': mag.R.tolist(),
            'noise_std_uT': mag.noise_std.tolist(), 'lsb_uT': float(mag.lsb),
            'rate_hz': float(mag.rate_hz),
            'as_fitted': {'T': T.tolist(), 'R': R.tolist(), 'field_uT': field_uT,
                          'note': 'the same model in the convention of the fit (T upper '
                                  'triangular, det 1, field scaled to match)'}}
        d['earth_field'] = {'field_uT': float(earth_field.field_uT),
                            'dip_deg': float(earth_field.dip_deg)}
    return d


def run(args, out):
    """Run ``accel-calib simulate``; return the exit status."""
    from ..sim import motion as sim_motion
    from ..sim import sensor as sim
    if args.output == STDOUT and args.json:
        raise UsageError('accel-calib: simulate -o - writes the CSV to standard output: '
                         'leave out --json')
    check_output(args.truth, args.output, args.noise_from, what='--truth')
    if args.truth and not os.path.isdir(os.path.dirname(os.path.abspath(args.truth))):
        raise UsageError(f'accel-calib: --truth {args.truth}: its folder does not exist (the '
                         'recording would be written and the truth lost)')
    check_output(args.output, args.noise_from, stdout=True)
    if args.output != STDOUT:
        check_suffix(args.output, ('.csv', '.mcap', '.db3'), 'simulate -o')
    mode_options(args, CHAMBER_OPTIONS, '--chamber', bool(args.chamber))
    rng = np.random.default_rng(args.seed)
    if args.chamber:
        return _run_chamber(args, out, rng)
    effects = [e.strip() for e in args.effects.split(',') if e.strip()]
    known = _known()
    for e in effects:
        if e not in known:
            raise UsageError(f'unknown effect {e!r}; choose from {", ".join(known)}')
    sensor = sim.mpu9250_like(rng, args.rate, effects)
    if args.orthogonal:
        sensor.T = np.diag(np.diag(sensor.T))
    sensor = _imu_sensor(sensor, args)
    imu = args.gyro_errors or args.gyro_range or args.magnetometer or args.tremor > 0
    if args.noise_from:
        from ..dataio.noise_file import noise_from_allan
        sensor.noise_std, gyro_noise = noise_from_allan(args.noise_from, args.rate)
        if gyro_noise is not None:
            sensor.gyro_noise_std = gyro_noise
    if args.poses == 'faces':
        directions = sim_motion.face_directions()
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
        directions = (sim_motion.sun_xu_directions(count, rng) if sunxu
                      else sim_motion.random_poses(count, rng) if imu      # headings fixed too
                      else sim_motion.random_directions(count, rng))
    if len(args.temp) not in (1, 2):
        raise UsageError('accel-calib: --temp takes one value or START END')
    total = len(directions) * (args.hold + args.move) * args.rate + args.hold * args.rate
    if total > MAX_SIMULATED_SAMPLES:
        raise UsageError(f'accel-calib: that session would have {total:.3g} samples; the '
                         f'limit is {MAX_SIMULATED_SAMPLES:.3g} (fewer poses, shorter holds '
                         'or a lower --rate)')
    temperature = args.temp[0] if len(args.temp) == 1 else tuple(args.temp)
    earth_field = sim.EarthField(args.field, args.dip)
    kwargs = {'hold_s': args.hold, 'move_s': args.move, 'rate_hz': args.rate}
    total = sim_motion.session_length(directions, **kwargs)
    last_t = _write(args.output, total, sim_motion.iter_session(
        sensor, directions, rng, gravity=args.gravity, temperature=temperature,
        earth_field=earth_field, tremor_deg=args.tremor, **kwargs))
    truth = sensor_to_dict(sensor, args.gravity)
    if imu:
        truth.update(imu_truth(sensor, earth_field))
    if args.truth:
        import yaml
        from ..dataio.atomic import atomic_write_text
        atomic_write_text(args.truth, yaml.safe_dump(truth, sort_keys=False))
    summary = {'output': args.output, 'samples': total, 'poses': len(directions),
               'magnetometer': sensor.magnetometer is not None,
               'seconds': last_t[0], 'truth': truth}
    if args.json:
        out(summary)
    else:
        print(f'simulated {len(directions)} poses, {total} samples ({last_t[0]:.1f} s) -> '
              f'{"standard output" if args.output == STDOUT else args.output}',
              file=sys.stderr if args.output == STDOUT else sys.stdout)
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
            'gyro_noise_std_rad_s': np.asarray(sensor.gyro_noise_std, float).tolist(),
            **({'thermal_lag_s': float(sensor.thermal_lag_s)} if sensor.thermal_lag_s else {}),
            **({'bias_random_walk_m_s2_per_rt_s': sensor.bias_random_walk.tolist()}
               if np.any(sensor.bias_random_walk) else {}),
            **({'bias_tempco_quadratic_m_s2_per_c2': sensor.bias_tempco_quadratic.tolist(),
                'bias_tempco_cubic_m_s2_per_c3': sensor.bias_tempco_cubic.tolist()}
               if np.any(sensor.bias_tempco_quadratic) or np.any(sensor.bias_tempco_cubic)
               else {}),
            **({'bias_gradient_m_s2_per_c': sensor.bias_gradient.tolist(),
                'gradient_tau_s': float(sensor.gradient_tau_s)}
               if np.any(sensor.bias_gradient) else {}),
            **({'gyro_bias_tempco_rad_s_per_c': sensor.gyro_bias_tempco.tolist()}
               if np.any(sensor.gyro_bias_tempco) else {}),
            **({'library_effects': {effect.name: {'params': np.asarray(params, float).tolist(),
                                                  'param_names': list(effect.param_names),
                                                  'unit': effect.unit}
                                    for effect, params in sensor.library_effects}}
               if sensor.library_effects else {})}


def _run_chamber(args, out, rng):
    """Simulate one still pose in a chamber cycle (``--chamber``), streamed to the output."""
    from ..sim import motion as sim_motion
    sensor, programme, direction = _chamber(args, rng)
    total = int(round(programme.duration_s * args.rate))
    if total > MAX_SIMULATED_SAMPLES:
        raise UsageError(f'accel-calib: that chamber cycle would have {total:.3g} samples; the '
                         f'limit is {MAX_SIMULATED_SAMPLES:.3g} (a lower --rate, shorter holds '
                         'or faster ramps)')
    last_t = _write(args.output, total, sim_motion.iter_session(
        sensor, direction[None, :], rng, hold_s=programme.duration_s, rate_hz=args.rate,
        gravity=args.gravity, temperature=programme, lead_s=0.0))
    truth = sensor_to_dict(sensor, args.gravity)
    truth['chamber'] = {'set_points_c': list(args.chamber), 'start_c': args.temp[0],
                        'rates_c_per_min': list(args.chamber_rate),
                        'hold_s': args.chamber_hold, 'board_tau_s': args.board_tau,
                        'legs': [{'direction': kind, 't_start_s': float(a), 't_stop_s': float(b)}
                                 for kind, a, b in programme.legs],
                        'up': args.up}
    if args.truth:
        import yaml
        from ..dataio.atomic import atomic_write_text
        atomic_write_text(args.truth, yaml.safe_dump(truth, sort_keys=False))
    summary = {'output': args.output, 'samples': total, 'poses': 1, 'seconds': last_t[0],
               'chamber': truth['chamber'], 'truth': truth}
    if args.json:
        out(summary)
    else:
        print(f'simulated a chamber cycle of {last_t[0] / 60:.0f} min, one still pose ({args.up} '
              f'up), {total} samples -> '
              f'{"standard output" if args.output == STDOUT else args.output}',
              file=sys.stderr if args.output == STDOUT else sys.stdout)
    return 0


def _write(output, total, pieces):
    """
    Stream simulated session pieces to ``output`` (CSV, or a bag by its suffix), with a bar.

    One piece in memory at a time; return [the last sample's time, s].
    """
    from .progress import Progress
    from ..dataio.recording import write_bag, write_samples_csv
    last_t = []

    def samples(bar):
        for piece in pieces:
            bar.update(len(piece.samples))
            last_t[:] = [float(piece.samples.t[-1])]
            yield piece.samples

    with Progress(total, 'simulate') as bar:
        if output.lower().endswith(('.mcap', '.db3')):
            write_bag(output, samples(bar))
        else:
            write_samples_csv(output, samples(bar))
    return last_t
