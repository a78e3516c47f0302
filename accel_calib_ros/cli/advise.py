"""``accel-calib advise``: which pose to hold next, and when it is enough (interface §5)."""

import math

import numpy as np

from .common import add_data_args, add_window_args, G0, GRAVITY, load_data, positive, ranged
from ..core.advice import advise, DEFAULT_TARGET

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
    if args.json:
        d = result.to_dict()
        d['samples'] = len(samples)
        out(d)
    else:
        print(result.text())
    return 0
