"""``accel-calib history``: each sensor's calibrations over time, and their drift as a plot."""

import datetime
import os

from .common import check_output, check_suffix, same_file, UsageError


def add_arguments(p):
    """Add the options of ``history`` to its parser."""
    p.add_argument('--db', help='history database (default next to the calibration file of '
                                'the nodes: $ROS_HOME/accel_calib_ros/history.sqlite)')
    p.add_argument('--sensor', help='only this sensor')
    p.add_argument('--plot', metavar='FILE.png', help='plot parameter drift over time')
    p.add_argument('--json', action='store_true', help='print one JSON object')


def _iso(t):
    return datetime.datetime.fromtimestamp(t, datetime.timezone.utc).isoformat(
        timespec='seconds')


def run(args, out):
    """Run ``accel-calib history``; return the exit status."""
    from ..core.errors import InputError
    from ..dataio.history import default_history_path, History
    path = args.db or default_history_path()
    if not os.path.exists(path):
        raise InputError(f'no history at {path} (fit --history or guide --history creates it)')
    if os.path.isfile(path) and os.path.getsize(path) == 0:     # listing must not write it
        raise InputError(f'{path}: is an empty file, not a history database')
    if same_file(args.plot, path):
        raise UsageError('accel-calib: the plot must not overwrite the history database')
    if args.plot:
        check_output(args.plot, what='--plot')
        check_suffix(args.plot, ('.png',), 'history --plot')
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
