"""
What every ``accel-calib`` command shares: argument types, data options, border checks.

Standard library only at import (``accel-calib --help`` starts fast). A command module
imports from here, from ``core``, ``dataio``, ``modelgap`` and ``sim``, never from another
command.
"""

import argparse
import math
import os
import stat
import sys

from ..dataio.formats import MAX_MESSAGE, message_line  # noqa: F401 - one line, capped


MAX_POSES = 100_000
"""Most poses a simulated session may have."""


class UsageError(Exception):
    """Bad command-line usage (exit status 2)."""


def _help_formatter(prog):
    """
    Return argparse's HelpFormatter for the terminal's width, as argparse finds it.

    argparse asks ``shutil.get_terminal_size`` for it, and importing shutil imports zlib,
    bz2 and lzma (about 2 ms of every command's start-up) for the width alone.
    """
    try:
        columns = int(os.environ['COLUMNS'])
    except (KeyError, ValueError):
        columns = 0
    if columns <= 0:
        try:
            columns = os.get_terminal_size(sys.__stdout__.fileno()).columns
        except (AttributeError, ValueError, OSError):
            columns = 0
    return argparse.HelpFormatter(prog, width=(columns or 80) - 2)


class Parser(argparse.ArgumentParser):
    """An argparse parser whose errors are a UsageError (one line, exit status 2)."""

    def __init__(self, *args, **kwargs):
        kwargs.setdefault('formatter_class', _help_formatter)
        super().__init__(*args, **kwargs)

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
    add_time_unit_arg(p)


def add_unit_args(p):
    """Add ``--units`` and the raw-count options (``dataio.units`` converts)."""
    from ..dataio.units import UNITS
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


def mode_options(args, options, mode, active):
    """
    Fill in the options that act in one mode only; refuse them given outside it.

    Such an option has the argparse default None, so that a value given by the user is
    told from none (one the mode would then ignore in silence).

    :param options: {option flag: its default in the mode}, e.g. ``{'--min-span': 5.0}``.
    :param mode: the words that name the mode, e.g. ``'--chamber'``.
    :param active: whether the mode is on.
    :raises UsageError: an option was given and the mode is off.
    """
    for flag, default in options.items():
        dest = flag.lstrip('-').replace('-', '_')
        if getattr(args, dest) is None:
            setattr(args, dest, default)
        elif not active:
            raise UsageError(f'accel-calib: {flag} acts only with {mode}; add it or leave '
                             f'{flag} out')


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
    from ..session.settings import DEFAULT_SETTINGS
    g = p.add_argument_group('static windows')
    g.add_argument('--min-window-s', type=ranged(0.01, 3600.0),
                   default=DEFAULTS['min_duration_s'],
                   help='shortest static window kept after trimming its ends, s '
                        '(default %(default)s: poses held about 1 s or longer)')
    g.add_argument('--threshold-factor', type=ranged(1.0, 1e3),
                   default=DEFAULTS['threshold_factor'],
                   help='still when moving std < factor x noise floor (default %(default)s)')
    g.add_argument('--max-weight-s', type=ranged(1e-3, 1e6), default=DEFAULT_SETTINGS.max_weight_s,
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
    from .progress import Progress
    from ..dataio.recording import load_samples
    unit_options(args)                          # a usage mistake before a long read
    size = os.path.getsize(args.data) if os.path.isfile(args.data) else None
    with Progress(size, 'read', 'B') as bar:     # shown only for a long read on a terminal
        samples = load_samples(args.data, imu_topic=args.imu_topic,
                               temp_topic=args.temp_topic, on_read=bar.update,
                               mag_topic=getattr(args, 'mag_topic', None),
                               time_unit=time_unit(args))
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


def check_output(output, *inputs, what='output', stdout=False, folder=False):
    """
    Refuse (UsageError, exit 2) an output that would destroy an input or a foreign file.

    See :func:`check_output_path`; ``stdout`` allows ``-`` (standard output), ``folder``
    an output folder.
    """
    return check_output_path(output, *inputs, what=what, stdout=stdout, folder=folder)


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


# -- the output border ----------------------------------------------------------------------

MAX_REFUSAL = 500
"""Longest refusal line (``cannot calibrate: ...``): its own words, the poses to add."""
EXPANDED_PATHS = ('data', 'calibration', 'output', 'truth', 'report', 'plot', 'record', 'db',
                  'truth_out', 'link', 'port', 'history', 'noise_from', 'poses')
"""File-name arguments whose leading ``~`` / ``~user`` is expanded (or refused)."""
STDOUT = '-'
"""The output name meaning standard output (where a command writes text)."""


def expand_user(text, option):
    """
    Expand a leading ``~`` or ``~user`` of a file name; refuse an unknown user.

    :param text: the name as given (returned unchanged unless it starts with ``~``).
    :param option: the option's name, for the message.
    :raises UsageError: ``~user`` names no user (a folder literally named ``~user`` is
        never created).
    """
    if not isinstance(text, str) or not text.startswith('~'):
        return text
    expanded = os.path.expanduser(text)
    if expanded.startswith('~'):
        user = text[1:].split(os.sep, 1)[0]
        who = f'no user {user!r}' if user else 'no home folder'
        raise UsageError(f'accel-calib: {option} {text}: there is {who} to expand '
                         f'~{user} to (write ./{text.split(os.sep, 1)[0]} for a folder of '
                         'that name)')
    return expanded


def expand_paths(args):
    """Expand ``~`` in every file-name argument of ``args`` (in place), or refuse."""
    options = dict(PATH_OPTIONS, history='--history', noise_from='--noise-from',
                   poses='--poses')
    for name in EXPANDED_PATHS:
        value = getattr(args, name, None)
        if isinstance(value, str) and value:
            setattr(args, name, expand_user(value, options.get(name, name)))


def input_folders(path):
    """
    Return the folders an input ``path`` owns: a bag directory, or the bag of a storage file.

    Nothing may be written inside them (``fit BAG -o BAG/metadata.yaml`` would destroy it).
    """
    if not path or path == STDOUT:
        return []
    path = os.fspath(path)
    if os.path.isdir(path):
        return [os.path.realpath(path)]
    folder = os.path.dirname(os.path.realpath(path))
    if path.lower().endswith(('.mcap', '.db3')) and \
            os.path.isfile(os.path.join(folder, 'metadata.yaml')):
        return [folder]
    return []


def _inside(target, folder):
    try:
        return os.path.commonpath([target, folder]) == folder
    except ValueError:
        return False


def check_output_path(output, *inputs, what='output', stdout=False, folder=False):
    """
    Check the border of every file a command writes (exit status 2, one line).

    Refuses an output that is an input, lies inside an input folder or bag, exists but
    is not a regular file (device, FIFO, socket, directory), or is reached through a
    symbolic link another user owns (the rules of :func:`dataio.atomic.output_target`).

    :param output: the output name as given (``~`` expanded), or None (nothing to check).
    :param inputs: the command's inputs (files or folders; None entries are skipped).
    :param what: the option, for the message (``-o``, ``--plot``, ...).
    :param stdout: ``-`` means standard output here (else it is a usage error).
    :param folder: the output is a folder (``diagnose --report``): it may exist as one.
    :return: the real path that will be written (``-`` for standard output), or None.
    :raises UsageError: the output must not be written.
    """
    if output is None:
        return None
    output = os.fspath(output)
    if output == STDOUT:
        if stdout:
            return STDOUT
        raise UsageError(f'accel-calib: {what} -: this output cannot go to standard output; '
                         'give a file name')
    from ..dataio.atomic import output_target, UnsafeOutput
    try:
        target = output_target(output, folder=folder)
    except UnsafeOutput as err:
        raise UsageError(f'accel-calib: {what} {err}') from None
    except OSError as err:
        raise UsageError(f'accel-calib: {what} {output}: {err.strerror or err}') from None
    for path in inputs:
        if not path or path == STDOUT:
            continue
        if same_file(output, path) or same_file(target, path):
            raise UsageError(f'accel-calib: {what} {output} is the input {path}; '
                             'writing it would destroy the input: choose another name')
        for inside in input_folders(path):
            if _inside(target, inside):
                raise UsageError(f'accel-calib: {what} {output} lies inside the input {inside}'
                                 '; writing there could destroy it: choose a path outside it')
    return target


def sensor_id(text):
    """Argparse type: a sensor id, normalised (stripped, NFC) and checked (printable)."""
    from ..core.errors import InputError
    from ..dataio.sensor_id import normalise_sensor_id
    try:
        return normalise_sensor_id(text)
    except InputError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


def add_time_unit_arg(p):
    """Add ``--time-unit`` (the unit of a CSV's ``t`` column) to parser ``p``."""
    from ..dataio.time_units import TIME_UNITS        # numpy-free: --help stays light
    p.add_argument('--time-unit', choices=tuple(TIME_UNITS), default=None,
                   help='unit of the t column of a CSV (default s; a spacing no '
                        'IMU has, 1 Hz .. 100 kHz, is refused with the unit it looks like)')


def time_unit(args):
    """Return the CSV time unit of ``args`` ('s' unless --time-unit says otherwise)."""
    return getattr(args, 'time_unit', None) or 's'


def check_link_output(link, *inputs, what='--link'):
    """
    Check the border of a symbolic link a command maintains (``simulate-device --link``).

    The link itself is replaced (never what it points to), so: no input may be it or lie
    under it, an existing entry must be a link, and a link in a shared folder must be the
    user's own; the folders on the way follow the rules of :func:`check_output_path`.

    :raises UsageError: the link must not be made or replaced there.
    """
    if link is None:
        return
    for path in inputs:
        if path and same_file(link, path):
            raise UsageError(f'accel-calib: {what} {link} is the input {path}; '
                             'writing it would destroy the input: choose another name')
    from ..dataio.atomic import output_target, UnsafeOutput
    parent = os.path.dirname(os.path.abspath(link))
    try:
        folder = output_target(parent, folder=True)
        st = os.lstat(link) if os.path.lexists(link) else None
    except UnsafeOutput as err:
        raise UsageError(f'accel-calib: {what} {err}') from None
    except OSError as err:
        raise UsageError(f'accel-calib: {what} {link}: {err.strerror or err}') from None
    if st is not None and not stat.S_ISLNK(st.st_mode):
        raise UsageError(f'accel-calib: {what} {link} exists and is not a symlink: replacing '
                         'it would destroy it (choose a new name)')
    if st is not None and st.st_uid != os.geteuid() and \
            os.stat(folder).st_mode & (stat.S_ISVTX | stat.S_IWOTH):
        raise UsageError(f'accel-calib: {what} {link}: the link belongs to another user '
                         f'(uid {st.st_uid}) in the shared folder {folder}; choose a new name')
    target = os.path.join(folder, os.path.basename(link))
    for path in inputs:
        for inside in input_folders(path):
            if _inside(target, inside):
                raise UsageError(f'accel-calib: {what} {link} lies inside the input {inside}; '
                                 'writing there could destroy it: choose a path outside it')


UNIT_OPTIONS = ('units', 'counts_per_g', 'range_g')


def recorded_units(args, cal, command='apply'):
    """
    Set the unit options of ``args`` to the calibration's ``input_units`` (or check them).

    Without unit options the recorded conversion is used; options that say another one
    are refused (counts options without a sensitivity take the recorded one). A
    calibration that records none leaves the options as they are.

    :return: the conversion used (``input_units`` form).
    :raises UsageError: the options say another conversion than the fit's.
    """
    from ..dataio.units import conversion_words, input_units, same_conversion
    given = any(getattr(args, k, None) is not None for k in UNIT_OPTIONS) or \
        bool(getattr(args, 'counts_offset', 0.0))
    recorded = cal.input_units
    sensitivity = getattr(args, 'counts_per_g', None), getattr(args, 'range_g', None)
    if recorded is not None and recorded['accel'] == 'counts' and sensitivity == (None, None) \
            and getattr(args, 'units', None) in (None, 'counts'):
        args.counts_per_g = recorded['counts_per_g']     # counts without their sensitivity
    options = unit_options(args)
    stated = input_units(options['units'], options['counts_per_g'], options['counts_offset'])
    if recorded is None:
        return stated
    if not given:
        args.units = recorded['accel']
        args.counts_per_g = recorded.get('counts_per_g')
        args.range_g = None
        args.counts_offset = recorded.get('counts_offset') or 0.0
        return dict(recorded)
    if not same_conversion(stated, recorded):
        raise UsageError(f'accel-calib: {command}: the calibration was fitted on readings in '
                         f'{conversion_words(recorded)}, and its T absorbed that conversion; '
                         f'the unit options say {conversion_words(stated)}: give the same '
                         'conversion (or no unit option: apply then uses the recorded one), '
                         'or fit again on data converted this way')
    return stated
