"""``accel-calib allan``: the Allan deviation of a still recording, and its noise terms."""

from .common import add_data_args, check_output, check_suffix, load_data


def add_arguments(p):
    """Add the options of ``allan`` to its parser."""
    add_data_args(p)
    p.add_argument('--plot', help='write the log-log Allan deviation plot to this PNG')
    p.add_argument('--json', action='store_true', help='print one JSON object')


def run(args, out):
    """Run ``accel-calib allan``; return the exit status."""
    from ..core.allan import allan
    if args.plot:
        check_output(args.plot, args.data, what='--plot')
        check_suffix(args.plot, ('.png',), 'allan --plot')
    result = allan(load_data(args).validate())
    if args.plot:
        write_allan_plot(result, args.plot)
    if args.json:
        out(result.summary())
    else:
        print(result.text())
    return 0


def write_allan_plot(result, path):
    """Write a log-log plot of the Allan deviation per axis with its 95 % band (PNG)."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    import numpy as np
    from ..dataio.figures import save_figure
    groups = [[i for i, a in enumerate(result.axes) if a.startswith('a')],
              [i for i, a in enumerate(result.axes) if a.startswith('g')]]
    groups = [g for g in groups if g]
    fig, axes = plt.subplots(1, len(groups), figsize=(6 * len(groups), 4.2), squeeze=False)
    for ax, group in zip(axes[0], groups):
        for i in group:
            line, = ax.loglog(result.tau, result.adev[i], label=result.axes[i])
            ax.fill_between(result.tau, result.adev_ci[i, :, 0], result.adev_ci[i, :, 1],
                            color=line.get_color(), alpha=0.2)
            ax.loglog(result.tau, result.noise_density[i] / np.sqrt(result.tau), ':',
                      color=line.get_color(), lw=0.8)
        unit = 'm/s²' if result.axes[group[0]].startswith('a') else 'rad/s'
        ax.set_xlabel('cluster time τ, s')
        ax.set_ylabel(f'Allan deviation, {unit}')
        ax.grid(True, which='both', alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle('Allan deviation (dotted: white noise N/√τ; band: 95 %)')
    save_figure(fig, path)
