"""
What every ``accel-calib`` command shares: argument types, data options, border checks.

Standard library only at import (``accel-calib --help`` starts fast). A command module
imports from here, from ``core``, ``dataio``, ``modelgap`` and ``sim``, never from another
command.
"""

import argparse
import math
import os


G0 = 9.80665
"""Standard gravity, m/s² (the default of --gravity)."""
MAX_WEIGHT_S = 5.0
"""Window weights are capped at this many seconds of samples (see StaticWindows.weights)."""
MAX_POSES = 100_000
"""Most poses a simulated session may have."""


class UsageError(Exception):
    """Bad command-line usage (exit status 2)."""


class Parser(argparse.ArgumentParser):
    """An argparse parser whose errors are a UsageError (one line, exit status 2)."""

    def error(self, message):
        raise UsageError(f'{self.prog}: {message}')


def add_data_args(p):
    """Add the recording argument, the bag topic and the unit options to parser ``p``."""
    p.add_argument('data', help='CSV file (t, ax, ay, az[, temp, gx, gy, gz, mx, my, mz]) or '
                                'rosbag2 (.mcap, .db3 or bag directory)')
    p.add_argument('--imu-topic', help='sensor_msgs/Imu topic in a bag (default: the only one)')
    p.add_argument('--temp-topic', help='sensor_msgs/Temperature topic in a bag')
    p.add_argument('--mag-topic', help='sensor_msgs/MagneticField topic in a bag (tesla; '
                                       'default: the only one)')
    add_unit_args(p)


UNITS = ('m/s2', 'g', 'counts')
"""Units of ax, ay, az a recording may be in (as ``dataio.units.UNITS``)."""


def add_unit_args(p):
    """Add ``--units`` and the raw-count options (``dataio.units`` converts)."""
    g = p.add_argument_group('unit of ax, ay, az (files written hold m/s²)')
    g.add_argument('--units', choices=UNITS, default=None,
                   help='m/s2 (default), g (standard gravity) or counts (raw ADC codes: '
                        'give --counts-per-g or --range); gyro stays rad/s')
    scale = g.add_mutually_exclusive_group()
    scale.add_argument('--counts-per-g', type=ranged(1e-3, 1e9), metavar='N',
                       help='nominal counts per g of --units counts (MPU-9250 at ±2 g: 16384)')
    scale.add_argument('--range', type=ranged(1e-3, 1e6), dest='range_g', metavar='G',
                       help='--units counts of a signed 16-bit sensor at ±G g '
                            '(32768/G counts per g)')
    g.add_argument('--counts-offset', type=number, default=0.0, metavar='CODE',
                   help='code of zero acceleration for --units counts: 0 for signed codes '
                        '(default), 32768 for unsigned 16-bit codes')


def unit_options(args):
    """
    Return the declared unit of ax, ay, az as keyword arguments of ``dataio.units.to_si``.

    The count options imply ``--units counts``; with another unit they are refused.
    """
    counts_per_g = getattr(args, 'counts_per_g', None)
    if getattr(args, 'range_g', None) is not None:
        counts_per_g = 32768.0 / args.range_g
    offset = getattr(args, 'counts_offset', 0.0) or 0.0
    units = getattr(args, 'units', None)
    counting = counts_per_g is not None or offset != 0.0
    if units is None:
        units = 'counts' if counting else 'm/s2'
    elif counting and units != 'counts':
        raise UsageError(f'accel-calib: --counts-per-g, --range and --counts-offset are for '
                         f'--units counts, not --units {units}')
    if units == 'counts' and counts_per_g is None:
        from ..dataio.units import COUNTS_NEED_SENSITIVITY
        raise UsageError(f'accel-calib: {COUNTS_NEED_SENSITIVITY}')
    return {'units': units, 'counts_per_g': counts_per_g, 'counts_offset': offset}


def to_si(samples, args, check=True):
    """Convert ``samples`` to m/s² as the unit options say (one refusal when implausible)."""
    from ..dataio.units import check_magnitude, to_si as convert
    options = unit_options(args)
    si = convert(samples, **options)
    if check:
        check_magnitude(si.accel, samples.accel, **options)
    return si


def add_window_args(p):
    """Add the static-window detector options to parser ``p``."""
    from ..core.windows import DEFAULTS
    g = p.add_argument_group('static windows')
    g.add_argument('--min-window-s', type=ranged(0.01, 3600.0),
                   default=DEFAULTS['min_duration_s'],
                   help='shortest static window kept after trimming its ends, s '
                        '(default %(default)s: poses held about 1 s or longer)')
    g.add_argument('--threshold-factor', type=ranged(1.0, 1e3),
                   default=DEFAULTS['threshold_factor'],
                   help='still when moving std < factor x noise floor (default %(default)s)')
    g.add_argument('--max-weight-s', type=ranged(1e-3, 1e6), default=MAX_WEIGHT_S,
                   help='cap of a window weight, seconds of samples (default %(default)s)')


def number(text):
    """Argparse type: a finite number."""
    try:
        value = float(text)
    except (TypeError, ValueError):
        raise argparse.ArgumentTypeError(f'not a number: {text!r}') from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f'must be a finite number, got {text!r}')
    return value


def positive(text):
    """Argparse type: a positive finite number."""
    value = number(text)
    if not value > 0:
        raise argparse.ArgumentTypeError(f'must be positive, got {text}')
    return value


def non_negative(text):
    """Argparse type: a finite number >= 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'not a number: {text!r}') from None
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f'must be >= 0, got {text}')
    return value


def positive_upto(high):
    """Argparse type: a positive finite number no larger than ``high``."""

    def parse(text):
        value = positive(text)
        if value > high:
            raise argparse.ArgumentTypeError(f'must be at most {high:g}, got {text}')
        return value
    parse.__name__ = 'number'
    return parse


def ranged(low, high, integer=False):
    """Argparse type: a finite number (an integer with ``integer``) in [low, high]."""
    def parse(text):
        if integer:
            try:
                value = int(text, 10)
            except (TypeError, ValueError):
                raise argparse.ArgumentTypeError(f'not an integer: {text!r}') from None
        else:
            value = number(text)
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f'must lie in [{low:g}, {high:g}], got {text}')
        return value
    parse.__name__ = 'integer' if integer else 'number'
    return parse


GRAVITY = ranged(0.1, 100.0)
"""Local gravity accepted, m/s² (1.0 allows data in units of g)."""
TEMPERATURE = ranged(-100.0, 200.0)
"""Temperature accepted, °C."""
SEED = ranged(0, 2 ** 32 - 1, integer=True)
"""Random seed accepted."""


def load_data(args):
    """Load the recording ``args.data`` in m/s² (with a progress bar on a long read)."""
    from ..dataio.recording import load_samples
    from .progress import Progress
    unit_options(args)                          # a usage mistake before a long read
    size = os.path.getsize(args.data) if os.path.isfile(args.data) else None
    with Progress(size, 'read', 'B') as bar:     # shown only for a long read on a terminal
        samples = load_samples(args.data, imu_topic=args.imu_topic,
                               temp_topic=args.temp_topic, on_read=bar.update,
                               mag_topic=getattr(args, 'mag_topic', None))
    return to_si(samples, args)


def same_file(a, b):
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


def check_output(output, *inputs, what='output'):
    """Raise UsageError when ``output`` is one of ``inputs`` (it would destroy it)."""
    if not output:
        return
    if os.path.isdir(os.path.expanduser(output)):
        raise UsageError(f'accel-calib: {what} {output} is a directory')
    for path in inputs:
        if path and same_file(output, path):
            raise UsageError(f'accel-calib: {what} {output} is the input {path}; '
                             'writing it would destroy the input: choose another name')


def check_suffix(path, suffixes, what):
    """Refuse an output name whose suffix says no format this command writes (exit 2)."""
    if not path.lower().endswith(suffixes):
        names = ' or '.join(suffixes)
        raise UsageError(f'accel-calib: error: {what} {path}: the name must end in {names} '
                         '(the suffix picks the file format)')


def plain(value):
    """Return ``value`` as strict-JSON data: lists, floats, None for NaN or infinity."""
    import numpy as np
    if isinstance(value, dict):
        return {str(k): plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return [plain(v) for v in value]
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


def check_not_empty(args):
    """Refuse an empty file name (``-o "$UNSET"`` silently wrote nothing before)."""
    for name, option in PATH_OPTIONS.items():
        value = getattr(args, name, None)
        if isinstance(value, str) and not value.strip():
            raise UsageError(f'accel-calib: {option} is an empty name; give a file name')
