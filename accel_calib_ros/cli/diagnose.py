"""``accel-calib diagnose``: which physical effect the model is missing (model-gap workflow)."""

import os

from .common import (add_data_args, add_window_args, check_output, GRAVITY, load_data, ranged,
                     UsageError)
from ..core.constants import G0

REPORT_FILES = ('report.md', 'gap.png', 'probes.png')
"""Files ``--report`` writes (plus one ``residuals_stepK.png`` per model step)."""


def report_files(folder):
    """Return the names the report would write in ``folder`` that may exist already."""
    names = list(REPORT_FILES)
    if os.path.isdir(folder):
        names += sorted(n for n in os.listdir(folder)
                        if n.startswith('residuals_step') and n.endswith('.png'))
    return names


def _write_report(result, folder):
    """Write the report; a folder made for it goes again when writing fails."""
    from ..dataio.atomic import make_parents
    from ..modelgap.report import write_report
    made = make_parents(folder)
    try:
        write_report(result, folder)
    except BaseException:
        if made:                    # ours alone: take out what was written in it
            import shutil
            shutil.rmtree(made[0], ignore_errors=True)
        raise


def add_arguments(p):
    """Add the options of ``diagnose`` to its parser."""
    add_data_args(p)
    p.add_argument('--baseline', choices=('gn', 'ml'), default='ml')
    p.add_argument('--report', help='folder for PNG plots and a Markdown summary')
    p.add_argument('--min-effect-mg', type=ranged(1e-6, 1e4), default=None,
                   help='name an effect only when its worst-case error in corrected '
                        'acceleration exceeds this, mg (default: the predicted accuracy '
                        'of the fit, at least 1 mg)')
    p.add_argument('--gravity', type=GRAVITY, default=G0, help='gravity, m/s²')
    p.add_argument('--json', action='store_true', help='print one JSON object')
    add_window_args(p)


def run(args, out):
    """Run ``accel-calib diagnose``; return the exit status."""
    from ..modelgap import diagnose
    if args.report:
        if os.path.lexists(args.report) and not os.path.isdir(args.report):
            raise UsageError(f'accel-calib: --report {args.report} exists and is not a folder')
        check_output(args.report, args.data, what='--report', folder=True)
        for name in report_files(args.report):
            check_output(os.path.join(args.report, name), args.data, what='--report')
    samples = load_data(args)
    result = diagnose(samples, baseline=args.baseline, gravity=args.gravity,
                      min_duration_s=args.min_window_s,
                      threshold_factor=args.threshold_factor,
                      max_weight_s=args.max_weight_s, min_effect_mg=args.min_effect_mg)
    if args.report:
        _write_report(result, args.report)
    if args.json:
        out(result.summary())
    else:
        print(result.text())
        if args.report:
            print(f'report: {os.path.join(args.report, "report.md")}')
    return 0
