"""
``accel-calib simulate-device``: a virtual MPU-9250 streaming serial frames on a pty.

The options and the device live in ``sim.device``; this module checks what that parser
takes loosely (ranges, outputs that are inputs) and runs it.
"""

import os

import numpy as np

from .common import check_link_output, check_output, MAX_POSES, UsageError


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
    poses = poses if poses and os.path.isfile(poses) else None
    link = getattr(args, 'link', None)
    check_output(getattr(args, 'truth_out', None), link, poses,
                 getattr(args, 'noise_from', None), what='--truth-out')
    check_link_output(link, poses, getattr(args, 'noise_from', None), what='--link')


def add_arguments(p):
    """Add the options of ``simulate-device`` (``sim.device``) to its parser."""
    from ..sim import device
    device.add_arguments(p)


def run(args, out):
    """Run ``accel-calib simulate-device``; return the exit status."""
    from ..sim import device
    _check_device_args(args)
    return device.run(args)
