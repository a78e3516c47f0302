"""
``accel-calib``: the calibration science offline, on CSV or rosbag2 recordings.

One module per command (``fit``, ``apply``, ``simulate``, ``diagnose``, ``allan``,
``advise``, ``guide``, ``history``, ``health``, ``simulate_device``), each with
``add_arguments(p)`` and ``run(args, out)``; ``common`` holds what they share. Only the
module of the command that runs is imported, so a command pays only for its own imports.

Exit status: 0 success, 2 bad usage or bad input, 1 a calibration that cannot be
solved, 128 + N when stopped by signal N (130 SIGINT, 143 SIGTERM, 129 SIGHUP: every
one cleans up the same way, no partial output left). Human summary on stdout by
default, exactly one JSON object with --json; diagnostics on stderr, one line of at
most ``common.MAX_MESSAGE`` characters (a refusal: ``MAX_REFUSAL``); never a traceback
for a user mistake.
"""

import importlib
import os
import signal
import sys

from .common import (check_not_empty, expand_paths, MAX_MESSAGE, MAX_REFUSAL, message_line, Parser,
                     plain, UsageError)

COMMANDS = {
    'fit': ('fit', 'fit a calibration to a recording'),
    'apply': ('apply', 'correct a recording with a calibration file'),
    'simulate': ('simulate', 'simulate a calibration session of an MPU9250'),
    'diagnose': ('diagnose', 'find the physical effect the model is missing'),
    'allan': ('allan', 'Allan deviation of a still recording (noise terms)'),
    'simulate-device': ('simulate_device',
                        'stream MPU9250 serial frames of a virtual sensor on a pty'),
    'advise': ('advise', 'which pose to hold next, and when it is enough'),
    'guide': ('guide', 'live guided calibration in the terminal'),
    'history': ('history', 'list calibrations per sensor and plot their drift'),
    'health': ('health', 'check a calibration against a recording at rest: still good, or '
                         'recalibrate?'),
}
"""Command name: (module in this package, one-line help)."""


def command_module(name):
    """Import and return the module of command ``name``."""
    return importlib.import_module(f'.{COMMANDS[name][0]}', __name__)


def build_parser(command=None):
    """
    Build the argparse parser of ``accel-calib``.

    :param command: the command about to run: only its module is imported and only its
        parser is made (None or '': every command's, for the top-level help and errors).
    """
    parser = Parser(prog='accel-calib', description='the calibration science offline, on '
                    'CSV or rosbag2 recordings')
    sub = parser.add_subparsers(dest='command', required=True, parser_class=Parser)
    for name, (_, text) in COMMANDS.items():
        if command and name != command:
            continue            # (each parser costs its help strings' translation look-ups)
        p = sub.add_parser(name, help=text, description=text)
        if command is None or name == command:
            command_module(name).add_arguments(p)
    return parser


class Interrupted(KeyboardInterrupt):
    """A stopping signal (SIGINT, SIGTERM, SIGHUP) raised where the program is."""

    def __init__(self, signum):
        super().__init__(signum)
        self.signum = signum


STOP_SIGNALS = ('SIGINT', 'SIGTERM', 'SIGHUP')
"""Signals that stop a command the way Ctrl-C does (partial output removed)."""


def _on_stop_signal(signum, frame):
    """Raise Interrupted; later stop signals are ignored so the clean-up runs to its end."""
    for name in STOP_SIGNALS:
        if hasattr(signal, name):
            signal.signal(getattr(signal, name), signal.SIG_IGN)
    raise Interrupted(signum)


def _stop_signals_raise():
    """Install :func:`_on_stop_signal` (main thread only); return the handlers replaced."""
    import threading
    if threading.current_thread() is not threading.main_thread():
        return {}
    old = {}
    for name in STOP_SIGNALS:
        sig = getattr(signal, name, None)
        if sig is None:
            continue
        previous = signal.getsignal(sig)
        if previous is signal.SIG_IGN and name != 'SIGINT':   # nohup: keep ignoring it
            continue
        old[sig] = previous
        signal.signal(sig, _on_stop_signal)
    return old


def main(argv=None):
    """Entry point of the ``accel-calib`` console script; returns the exit status."""
    import warnings
    old = _stop_signals_raise()
    try:
        with warnings.catch_warnings():
            if not os.environ.get('ACCEL_CALIB_DEBUG'):  # numpy's 0/0 notes are not for users
                warnings.simplefilter('ignore', RuntimeWarning)
            return _main(argv)
    except KeyboardInterrupt as err:     # a signal between _main's handlers and here
        return 128 + getattr(err, 'signum', signal.SIGINT)
    finally:
        for sig, handler in old.items():
            if handler is None or (argv is None and handler is signal.default_int_handler):
                handler = signal.SIG_DFL      # the process ends now: no KeyboardInterrupt
            signal.signal(sig, handler)       # traceback from a Ctrl-C while it exits


def _error(text, limit=MAX_MESSAGE):
    """Print one error line (capped, escaped) on stderr."""
    print(message_line(text, limit), file=sys.stderr)


def _main(argv):
    from ..core.errors import CalibrationError, InputError
    printed = []

    def out(obj):
        import json
        print(json.dumps(plain(obj), allow_nan=False))
        printed.append(True)

    args = None
    try:
        argv = sys.argv[1:] if argv is None else [os.fspath(a) if isinstance(a, os.PathLike)
                                                  else a for a in argv]
        command = argv[0] if argv and argv[0] in COMMANDS else None
        args = build_parser(command or '').parse_args(argv)
        check_not_empty(args)
        expand_paths(args)
        return command_module(args.command).run(args, out)
    except UsageError as err:
        _error(f'{err}')
        return 2
    except InputError as err:
        _error(f'accel-calib: error: {err}')
        return 2
    except CalibrationError as err:
        if getattr(args, 'json', False) and not printed:   # --json: still one object
            out({'command': args.command, 'accepted': False, 'refusal': str(err)})
        _error(f'accel-calib: cannot calibrate: {err}', MAX_REFUSAL)
        return 1
    except KeyboardInterrupt as err:
        signum = getattr(err, 'signum', signal.SIGINT)
        how = 'interrupted' if signum == signal.SIGINT else \
            f'stopped by {signal.Signals(signum).name}'
        _error(f'accel-calib: {how} (partial output removed)')
        return 128 + signum
    except BrokenPipeError:
        return 0
    except OSError as err:
        _error(f'accel-calib: error: {err.strerror or err}: {err.filename or ""}'.rstrip(': '))
        return 2
    except SystemExit as err:   # argparse --help
        return err.code if isinstance(err.code, int) else 0
    except Exception as err:    # noqa: B902 - a bug must still not dump a traceback on users
        if os.environ.get('ACCEL_CALIB_DEBUG'):
            raise
        _error(f'accel-calib: internal error: {type(err).__name__}: {err} '
               '(set ACCEL_CALIB_DEBUG=1 for the traceback)')
        return 1


if __name__ == '__main__':
    sys.exit(main())
