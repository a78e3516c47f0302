"""``accel-calib simulate``: a calibration session of a simulated MPU-9250, streamed to a file."""

import os

import numpy as np

from .common import (check_output, check_suffix, G0, GRAVITY, MAX_POSES, ranged, SEED,
                     TEMPERATURE, UsageError)


MAX_SIMULATED_SAMPLES = 50_000_000


def add_arguments(p):
    """Add the options of ``simulate`` to its parser."""
    p.add_argument('-o', '--output', required=True,
                   help='CSV, or rosbag2 when it ends in .mcap or .db3')
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
                   help='comma-separated extra effects: scale_nonlinearity, '
                        'temperature_bias, temperature_scale, bias_drift, temperature_lag '
                        '(the offset follows a die temperature 1-5 min behind the recorded '
                        'one), bias_random_walk')
    p.add_argument('--orthogonal', action='store_true',
                   help='no non-orthogonality (diagonal T, the GN model)')
    p.add_argument('--gravity', type=GRAVITY, default=G0, help='gravity, m/s²')
    p.add_argument('--seed', type=SEED, default=0, help='random seed (0 to 2**32-1)')
    p.add_argument('--truth', help='write the true sensor parameters to this YAML')
    p.add_argument('--noise-from', metavar='ALLAN.json',
                   help='per-sample accel (and gyro) noise from "accel-calib allan --json" '
                        '(white_sample_std, kept at its noise density at --rate)')
    p.add_argument('--json', action='store_true', help='print one JSON object')


def run(args, out):
    """Run ``accel-calib simulate``; return the exit status."""
    from ..core import simulate as sim
    from ..dataio.recording import write_bag, write_samples_csv
    from .progress import Progress
    check_output(args.truth, args.output, what='--truth')
    check_output(args.output, args.noise_from)
    check_output(args.truth, args.noise_from, what='--truth')
    if args.output and os.path.isdir(os.path.expanduser(args.output)):
        raise UsageError(f'accel-calib: output {args.output} is a directory')
    check_suffix(args.output, ('.csv', '.mcap', '.db3'), 'simulate -o')
    rng = np.random.default_rng(args.seed)
    effects = [e.strip() for e in args.effects.split(',') if e.strip()]
    known = ('scale_nonlinearity', 'temperature_bias', 'temperature_scale', 'bias_drift',
             'nonorthogonality', 'temperature_lag', 'bias_random_walk')
    for e in effects:
        if e not in known:
            raise UsageError(f'unknown effect {e!r}; choose from {", ".join(known)}')
    sensor = sim.mpu9250_like(rng, args.rate, effects)
    if args.orthogonal:
        sensor.T = np.diag(np.diag(sensor.T))
    if args.noise_from:
        from ..dataio.noise_file import noise_from_allan
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
        from ..dataio.atomic import atomic_write_text
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
            'gyro_noise_std_rad_s': np.asarray(sensor.gyro_noise_std, float).tolist(),
            **({'thermal_lag_s': float(sensor.thermal_lag_s)} if sensor.thermal_lag_s else {}),
            **({'bias_random_walk_m_s2_per_rt_s': sensor.bias_random_walk.tolist()}
               if np.any(sensor.bias_random_walk) else {})}
