"""
``accel-calib advise``: which pose to hold next, and when it is enough (interface §5).

When the data have ``gx gy gz`` it also says which rotation axis the moves between the
windows have not turned about (the gyroscope's scale and misalignment need all three),
and with ``mx my mz`` how much of the sphere of field directions the magnetometer saw.
"""

import math

import numpy as np

from .common import add_data_args, add_window_args, GRAVITY, load_data, positive, ranged
from ..core.advice import advise, DEFAULT_TARGET
from ..core.constants import G0

MAX_SIGMA_FLOOR = 10.0
"""Largest --sigma-floor accepted, m/s² (a floor of about 1 g already means no advice)."""


def add_arguments(p):
    """Add the options of ``advise`` to its parser."""
    add_data_args(p)
    p.add_argument('--method', choices=('ml', 'gn'), default='ml',
                   help='model the advice is for (default ml)')
    p.add_argument('--target', type=positive, default=DEFAULT_TARGET,
                   help='predicted accuracy that is enough, m/s² (default %(default)s)')
    p.add_argument('--gravity', type=GRAVITY, default=G0,
                   help='local gravity magnitude, m/s² (default %(default)s)')
    p.add_argument('--sigma-floor', type=ranged(0.0, MAX_SIGMA_FLOOR), default=None,
                   help='error of a window mean that no averaging removes, m/s² '
                        '(default 0.001)')
    p.add_argument('--json', action='store_true', help='print one JSON object')
    add_window_args(p)


def run(args, out):
    """Run ``accel-calib advise``; return the exit status."""
    from ..core.windows import detect_static_windows
    samples = load_data(args)
    windows = detect_static_windows(samples, min_duration_s=args.min_window_s,
                                    threshold_factor=args.threshold_factor)
    if len(windows):
        weights = windows.weights(args.max_weight_s, samples.rate_hz)
        noise = windows.noise_std
    else:
        weights = np.zeros(0)
        floor = windows.noise_floor
        noise = np.full(3, floor if math.isfinite(floor) else 0.02)
    result = advise(windows.mean, weights, noise, args.gravity, args.method, args.target,
                    args.sigma_floor)
    imu = imu_advice(samples, windows)
    if args.json:
        d = result.to_dict()
        d['samples'] = len(samples)
        d.update(imu)
        out(d)
    else:
        print(result.text())
        for name, part in imu.items():
            if part['status'] != 'absent':
                print(f'{name}: {part["advice"]}')
    return 0


def imu_advice(samples, windows):
    """
    Return the gyroscope and magnetometer advice: ``{'gyroscope': {...}, 'magnetometer': ...}``.

    ``gyroscope``: ``status`` ('absent', 'insufficient' or 'ok'), ``missing_axes``,
    ``excitation_deg``, ``moves_used`` and ``advice`` (the turn to make between poses);
    ``magnetometer``: ``status`` ('absent', 'insufficient' or 'ok'), ``coverage``
    (fraction of the sphere of field directions seen), ``missing_direction`` and ``advice``.
    """
    from ..core.outcomes import field_advice, gyro_advice
    gyro = gyro_advice(samples, windows if len(windows) else None)
    if samples.mag is None or not samples.mag_rows.any():
        mag = {'status': 'absent', 'coverage': None, 'missing_direction': None,
               'advice': 'the data have no mx my mz'}
    else:
        mag = field_advice(samples.mag)
        mag['status'] = 'ok' if mag.pop('enough') else 'insufficient'
    return {'gyroscope': gyro, 'magnetometer': mag}
