"""
``accel-calib history`` and the ``fit --history DB --sensor NAME`` hook.

``fit --history`` keeps this session's static windows in the sensor's history and fits
on all of that sensor's windows, so temperature bands fill across sessions recorded on
different days (``--thermal`` then uses them all); the calibration is recorded too.
``history`` lists the calibrations of each sensor and plots the parameter drift over
time. Standard library only at module level (``accel-calib`` starts fast).
"""

import datetime
import math
import os
import sys
import time


def _usage(message):
    from .cli import UsageError
    return UsageError(f'accel-calib: {message}')


def add_fit_arguments(p):
    """
    Add ``--history`` and ``--sensor`` to the ``fit`` parser.

    :param p: the ``fit`` subparser.
    """
    g = p.add_argument_group('per-sensor history')
    g.add_argument('--history', nargs='?', const='', default=None, metavar='DB',
                   help='keep the windows in this SQLite history (default next to the '
                        'calibration file of the nodes) and fit on all windows of --sensor')
    g.add_argument('--sensor', help='sensor id in the history (firmware id, port or name)')


def _history_path(args):
    from .dataio.history import default_history_path
    path = args.history or getattr(args, 'db', None) or default_history_path()
    return path


def history_observations(args, samples, obs):
    """
    Add this recording's windows to the history; return the observations of all of them.

    :param args: parsed ``fit`` arguments (``history`` not None).
    :param samples: the loaded recording.
    :param obs: this recording's observations (static windows, outliers already dropped:
        see ``cli._observations``); changed in place.
    :return: ``obs`` with readings (N, 3), weights (N,), temps (N,), count N and gyro means
        (N, 3) rad/s (NaN rows where a session had no gyro) over every kept window of the
        sensor.
    """
    if args.mode != 'windows':
        raise _usage('fit --history works on static windows (--mode windows)')
    if not args.sensor:
        raise _usage('fit --history needs --sensor NAME (whose history it is)')
    from .cli import _same_file
    from .dataio.history import History
    path = _history_path(args)
    if _same_file(path, args.data) or _same_file(path, args.output):
        raise _usage('the history database must not be the data or the output file')
    t = samples.t
    if len(t) and t[0] > 1e9:            # stamps are already Unix times (a rosbag)
        when = obs.t_mid
    else:                                # a CSV from 0: assume it was just recorded
        when = time.time() - (t[-1] - obs.t_mid) if len(t) else obs.t_mid
    with History(path) as h:
        if obs.count:
            h.add_windows(args.sensor, obs.readings, obs.temps, obs.weights, when, obs.gyro)
        kept = h.windows(args.sensor)
    print(f'accel-calib: history {path}: {obs.count} windows from this recording, '
          f'{len(kept["mean"])} kept for sensor {args.sensor}', file=sys.stderr)
    obs.readings, obs.weights, obs.temps = kept['mean'], kept['weight'], kept['temp']
    obs.gyro, obs.count = kept['gyro_mean'], len(kept['mean'])
    return obs


def record_fit(args, cal, temps=None):
    """
    Record a fitted calibration in the sensor's history.

    :param args: parsed ``fit`` arguments.
    :param cal: the Calibration.
    :param temps: temperatures of the windows it used, °C (for its temperature range).
    """
    import numpy as np
    from .dataio.history import History
    if getattr(cal, 'temperature_range_c', None) is None and temps is not None:
        finite = np.asarray(temps, float)
        finite = finite[np.isfinite(finite)]
        if len(finite):
            cal.temperature_range_c = (float(finite.min()), float(finite.max()))
    if getattr(cal, 'predicted_accuracy', None) is None and cal.covariance is not None:
        from .core.accuracy import predicted_accuracy
        value = predicted_accuracy(cal.T, cal.covariance, cal.gravity)
        if math.isfinite(value):
            cal.predicted_accuracy = value
    with History(_history_path(args)) as h:
        h.add_calibration(args.sensor, cal)


def add_parsers(sub):
    """
    Register ``history`` on the ``accel-calib`` subparsers.

    :return: {'history': cmd_history}.
    """
    p = sub.add_parser('history', help='list calibrations per sensor and plot their drift')
    p.add_argument('--db', help='history database (default next to the calibration file of '
                                'the nodes: $ROS_HOME/accel_calib_ros/history.sqlite)')
    p.add_argument('--sensor', help='only this sensor')
    p.add_argument('--plot', metavar='FILE.png', help='plot parameter drift over time')
    p.add_argument('--json', action='store_true', help='print one JSON object')
    return {'history': cmd_history}


def _iso(t):
    return datetime.datetime.fromtimestamp(t, datetime.timezone.utc).isoformat(
        timespec='seconds')


def cmd_history(args, out):
    """Run ``accel-calib history``; return the exit status."""
    from .cli import _same_file
    from .core.errors import InputError
    from .dataio.history import default_history_path, History
    path = args.db or default_history_path()
    if not os.path.exists(path):
        raise InputError(f'no history at {path} (fit --history or guide --history creates it)')
    if os.path.isfile(path) and os.path.getsize(path) == 0:     # listing must not write it
        raise InputError(f'{path}: is an empty file, not a history database')
    if _same_file(args.plot, path):
        raise _usage('the plot must not overwrite the history database')
    if args.plot:
        from .cli import _check_output, _check_suffix
        _check_output(args.plot, what='--plot')
        _check_suffix(args.plot, ('.png',), 'history --plot')
    with History(path) as h:
        sensors = h.sensors() if args.sensor is None else [args.sensor]
        cals = h.calibrations(args.sensor)
        summary = []
        for s in sensors:
            w = h.windows(s)
            summary.append({'sensor_id': s, 'calibrations': sum(c['sensor_id'] == s
                                                                for c in cals),
                            'windows': len(w['mean']), 'temperature_bands_10c':
                            _bands(w['temp'])})
    for c in cals:
        c['time'] = _iso(c['time_s'])
    if args.plot:
        plot_drift(cals, args.plot)
    if args.json:
        out({'db': path, 'sensors': summary, 'calibrations': cals, 'plot': args.plot})
        return 0
    print(f'history {path}')
    for s in summary:
        print(f'sensor {s["sensor_id"]}: {s["calibrations"]} calibrations, {s["windows"]} '
              f'windows, 10 °C bands {s["temperature_bands_10c"]}')
    for c in cals:
        trange = c['temperature_range_c']
        tr = f'{trange[0]:5.1f}..{trange[1]:5.1f} °C' if trange else '   no temp    '
        acc = c['predicted_accuracy']
        scale = ' '.join(f'{c["T"][i][i]:.5f}' for i in range(3))
        bias = ' '.join(f'{v:+.4f}' for v in c['bias'])
        print(f'  {c["time"]}  {c["sensor_id"]:<12} {c["method"]:<4} {tr}  '
              f'accuracy {"   n/a" if acc is None else f"{acc:.4f}"}  scale {scale}  '
              f'bias {bias} m/s²  ({c["windows"]} windows)')
    if args.plot:
        print(f'wrote {args.plot}')
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
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.dates as mdates
    import matplotlib.pyplot as plt
    import numpy as np
    from .dataio.figures import save_figure
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
                         label=f'{sensor} {axis}')
            axes[1].plot(when, bias[:, i], 'o-', color=colours[axis],
                         label=f'{sensor} {axis}')
        acc = [np.nan if c['predicted_accuracy'] is None else c['predicted_accuracy']
               for c in mine]
        axes[2].plot(when, acc, 'o-', label=sensor)
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
