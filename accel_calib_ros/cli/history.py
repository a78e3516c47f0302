"""
``accel-calib history``: each sensor's calibrations, drift plot, damage check, forget.

``history [list]`` lists (read-only: the database is never written by listing);
``history check`` looks at every page and row and names the damage (exit 2 when there is
some); ``history forget --sensor S [--session ID]`` removes one session of a sensor (its
windows and calibration), or all of them.
"""

import datetime
import os
import sys

from .common import check_output, check_suffix, sensor_id, UsageError

ACTIONS = ('list', 'check', 'forget')


def add_arguments(p):
    """Add the options of ``history`` to its parser."""
    p.add_argument('action', nargs='?', choices=ACTIONS, default='list',
                   help='list (default): calibrations and sessions per sensor; check: look '
                        'for damage; forget: remove --session of --sensor (or all of its '
                        'sessions)')
    p.add_argument('--db', help="history database (default: the one beside the nodes' "
                                'calibration file of --sensor, or of imu_link: '
                                '$ROS_HOME/accel_calib_ros/<sensor>/history.sqlite)')
    p.add_argument('--sensor', type=sensor_id, help='only this sensor')
    p.add_argument('--session', help='forget: only this session (see the listing)')
    p.add_argument('--plot', metavar='FILE.png', help='plot parameter drift over time')
    p.add_argument('--json', action='store_true', help='print one JSON object')


def _iso(t):
    try:
        return datetime.datetime.fromtimestamp(t, datetime.timezone.utc).isoformat(
            timespec='seconds')
    except (OverflowError, OSError, ValueError):
        return f'{t:g} s'


def _shown(text):
    """Show a sensor id or session escaped (an old database may hold invisible characters)."""
    return ''.join(c if c.isprintable() else c.encode('unicode_escape').decode('ascii')
                   for c in str(text))


def run(args, out):
    """Run ``accel-calib history``; return the exit status."""
    from ..core.errors import InputError
    from ..dataio.history import default_history_path
    from ..dataio.sensor_id import DEFAULT_SENSOR
    path = args.db or default_history_path(args.sensor or DEFAULT_SENSOR)
    if not os.path.exists(path):
        raise InputError(f'no history at {path} (fit --history or guide --history creates it)')
    if args.session is not None and args.action != 'forget':
        raise UsageError('accel-calib: history --session goes with forget')
    if args.plot and args.action != 'list':
        raise UsageError(f'accel-calib: history {args.action} does not plot: leave out --plot')
    if args.action == 'check':
        return _check(path, args, out)
    if args.action == 'forget':
        return _forget(path, args, out)
    return _list(path, args, out)


def _check(path, args, out):
    from ..core.errors import InputError
    from ..dataio.history import History
    with History(path, readonly=True) as h:
        problems = h.check()
        counts = None if problems else (len(h.sensors()), len(h.sessions()),
                                        len(h.calibrations()))
    if args.json:
        out({'db': path, 'ok': not problems, 'problems': problems})
    else:
        for p in problems:
            print(f'damaged: {p}')
        if counts:
            print(f'history {path}: sound ({counts[0]} sensors, {counts[1]} sessions, '
                  f'{counts[2]} calibrations)')
    if problems:
        raise InputError(f'{path}: {len(problems)} problem(s), first: {problems[0]}')
    return 0


def _forget(path, args, out):
    from ..core.errors import InputError
    from ..dataio.history import History
    if not args.sensor:
        raise UsageError('accel-calib: history forget needs --sensor (and --session to forget '
                         'one session only)')
    with History(path) as h:
        windows, cals = h.forget(args.sensor, args.session)
    if not windows and not cals:
        which = f'session {args.session!r} of ' if args.session else ''
        raise InputError(f'{path}: nothing to forget: no {which}sensor {args.sensor!r} '
                         '("accel-calib history" lists sensors and sessions)')
    what = f'session {args.session}' if args.session else 'every session'
    if args.json:
        out({'db': path, 'sensor_id': args.sensor, 'session': args.session,
             'windows_removed': windows, 'calibrations_removed': cals})
    else:
        print(f'history {path}: forgot {what} of sensor {_shown(args.sensor)}: {windows} '
              f'windows, {cals} calibrations')
    return 0


def _list(path, args, out):
    from ..dataio.history import History
    if args.plot:
        check_output(args.plot, path, what='--plot')
        check_suffix(args.plot, ('.png',), 'history --plot')
    with History(path, readonly=True) as h:
        sensors = h.sensors() if args.sensor is None else [args.sensor]
        cals = h.calibrations(args.sensor)
        sessions = h.sessions(args.sensor)
        summary = []
        for s in sensors:
            w = h.windows(s)
            summary.append({'sensor_id': s, 'calibrations': sum(c['sensor_id'] == s
                                                                for c in cals),
                            'windows': len(w['mean']), 'temperature_bands_10c':
                            _bands(w['temp']),
                            'sessions': [x['session'] for x in sessions
                                         if x['sensor_id'] == s]})
    for c in cals:
        c['time'] = _iso(c['time_s'])
    if args.plot:
        plot_drift(cals, args.plot)
    if args.json:
        out({'db': path, 'sensors': summary, 'calibrations': cals, 'sessions': sessions,
             'plot': args.plot})
        return 0
    print(f'history {path}')
    for s in summary:
        print(f'sensor {_shown(s["sensor_id"])}: {s["calibrations"]} calibrations, '
              f'{s["windows"]} windows, 10 °C bands {s["temperature_bands_10c"]}, '
              f'{len(s["sessions"])} sessions')
    for c in cals:
        trange = c['temperature_range_c']
        tr = f'{trange[0]:5.1f}..{trange[1]:5.1f} °C' if trange else '   no temp    '
        acc = c['predicted_accuracy']
        scale = ' '.join(f'{c["T"][i][i]:.5f}' for i in range(3))
        bias = ' '.join(f'{v:+.4f}' for v in c['bias'])
        print(f'  {c["time"]}  {_shown(c["sensor_id"]):<12} {_shown(c["method"]):<4} {tr}  '
              f'accuracy {"   n/a" if acc is None else f"{acc:.4f}"}  scale {scale}  '
              f'bias {bias} m/s²  ({c["windows"]} windows, session {_shown(c["session"])})')
    if args.plot:
        print(f'wrote {args.plot}')
    sys.stdout.flush()
    return 0


def _bands(temps, width=10.0):
    """{band low edge °C: windows} of the finite temperatures."""
    import numpy as np
    t = np.asarray(temps, float)
    t = t[np.isfinite(t)]
    low, counts = np.unique(np.floor(t / width) * width, return_counts=True)
    return {f'{v:g}': int(n) for v, n in zip(low, counts)}


def plot_drift(cals, path):
    """
    Plot scale, bias and predicted accuracy of the calibrations over time (PNG, atomic).

    :param cals: list of dicts from :meth:`History.calibrations`.
    :param path: PNG file to write.
    """
    import warnings
    with warnings.catch_warnings():     # a glyph the font lacks (an emoji id) is not an error
        warnings.filterwarnings('ignore', message='.*(Glyph|missing from|not support)',
                                category=UserWarning)
        _plot_drift(cals, path)


def _label(text):
    """Turn a user's text into a literal matplotlib label, never math text (``$...$``)."""
    text = _shown(text).replace('$', r'\$')
    return text if not text.startswith('_') else ' ' + text    # '_x' would hide the entry


def _plot_drift(cals, path):
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.dates as mdates
    import matplotlib.pyplot as plt
    import numpy as np
    from ..dataio.figures import save_figure
    fig, axes = plt.subplots(3, 1, figsize=(8, 8), sharex=True)
    colours = {'x': 'tab:red', 'y': 'tab:green', 'z': 'tab:blue'}
    for sensor in sorted({c['sensor_id'] for c in cals}):
        mine = [c for c in cals if c['sensor_id'] == sensor]
        when = [datetime.datetime.fromtimestamp(c['time_s'], datetime.timezone.utc)
                for c in mine]
        T = np.array([c['T'] for c in mine]).reshape(-1, 3, 3)
        bias = np.array([c['bias'] for c in mine]).reshape(-1, 3)
        for i, axis in enumerate('xyz'):
            axes[0].plot(when, (T[:, i, i] - 1.0) * 1e3, 'o-', color=colours[axis],
                         label=f'{_label(sensor)} {axis}')
            axes[1].plot(when, bias[:, i], 'o-', color=colours[axis],
                         label=f'{_label(sensor)} {axis}')
        acc = [np.nan if c['predicted_accuracy'] is None else c['predicted_accuracy']
               for c in mine]
        axes[2].plot(when, acc, 'o-', label=_label(sensor))
    axes[0].set_ylabel('scale − 1 [‰]')
    axes[1].set_ylabel('bias [m/s²]')
    axes[2].set_ylabel('predicted accuracy [m/s²]')
    axes[0].set_title('calibration drift per sensor')
    for ax in axes:
        ax.grid(True, alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize='small', ncol=3)
    locator = mdates.AutoDateLocator()
    axes[2].xaxis.set_major_locator(locator)
    axes[2].xaxis.set_major_formatter(mdates.ConciseDateFormatter(locator))
    save_figure(fig, path)
