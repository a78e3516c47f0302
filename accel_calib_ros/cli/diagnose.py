"""``accel-calib diagnose``: which physical effect the model is missing (model-gap workflow)."""

import os

from .common import (add_data_args, add_window_args, check_output, GRAVITY, load_data, ranged,
                     UsageError)
from ..core.constants import G0

REPORT_FILES = ('report.md', 'gap.png', 'probes.png')
MAX_STILL_BINS = 1500
"""A longer still recording is cut into longer bins for ``--calibration`` (about 1 GB of
naming simulation at most; 10 s bins hold 4 hours)."""
"""Files ``--report`` writes (plus one ``residuals_stepK.png`` per model step)."""


def report_files(folder, still=False):
    """Return the names the report would write in ``folder`` that may exist already."""
    if still:
        from ..modelgap.still_pose_report import STILL_REPORT_FILES as STILL_FILES
        return list(STILL_FILES)
    names = list(REPORT_FILES)
    if os.path.isdir(folder):
        names += sorted(n for n in os.listdir(folder)
                        if n.startswith('residuals_step') and n.endswith('.png'))
    return names


def _write_report(result, folder, still=False):
    """Write the report; a folder made for it goes again when writing fails."""
    from ..dataio.atomic import make_parents
    if still:
        from ..modelgap.still_pose_report import write_still_report as write_report
    else:
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
    g = p.add_argument_group('one still pose while the temperature sweeps (a warm-up or a '
                             'chamber cycle): heating against cooling')
    g.add_argument('--calibration', metavar='CALIB',
                   help='the calibration of the sensor (its T and bias): DATA is then one '
                        'still pose whose temperature sweeps; the baseline is the offset '
                        'against the reported temperature, and the workflow looks for what '
                        'heating and cooling show beyond it (a die lag, a gradient)')
    g.add_argument('--band-width', type=ranged(0.1, 1000.0), default=None, metavar='C',
                   help="the offset tables' band width, °C (default 5)")
    g.add_argument('--min-span', type=ranged(0.5, 200.0), default=5.0, metavar='C',
                   help='smallest temperature span taken, °C (default %(default)s)')
    add_window_args(p)


def run(args, out):
    """Run ``accel-calib diagnose``; return the exit status."""
    from ..modelgap import diagnose
    still = args.calibration is not None
    if args.report:
        if os.path.lexists(args.report) and not os.path.isdir(args.report):
            raise UsageError(f'accel-calib: --report {args.report} exists and is not a folder')
        check_output(args.report, args.data, args.calibration, what='--report', folder=True)
        for name in report_files(args.report, still):
            check_output(os.path.join(args.report, name), args.data, args.calibration,
                         what='--report')
    if still:
        result = _diagnose_still(args)
    else:
        samples = load_data(args)
        result = diagnose(samples, baseline=args.baseline, gravity=args.gravity,
                          min_duration_s=args.min_window_s,
                          threshold_factor=args.threshold_factor,
                          max_weight_s=args.max_weight_s, min_effect_mg=args.min_effect_mg)
    if args.report:
        _write_report(result, args.report, still)
    if args.json:
        out(result.summary())
    else:
        print(result.text())
        if args.report:
            print(f'report: {os.path.join(args.report, "report.md")}')
    return 0


def _diagnose_still(args):
    """Run the workflow on one still pose against a calibration (``modelgap.still_pose``)."""
    from .common import recorded_units
    from ..core.accelerometer.thermal_still import still_bins
    from ..dataio.calibration_file import load_calibration
    from ..modelgap.still_pose_run import diagnose_still
    from ..session.temperature import reference_temperature, STILL_BAND_WIDTH_C
    cal = load_calibration(args.calibration)
    recorded_units(args, cal, 'diagnose --calibration')
    samples = load_data(args)
    rec = still_bins(samples, min_span_c=args.min_span)
    if len(rec.bins) > MAX_STILL_BINS:       # the naming simulation grows with the bins
        duration = float(rec.bins.t_mid[-1] - rec.bins.t_mid[0])
        rec = still_bins(samples, bin_s=duration / MAX_STILL_BINS, min_span_c=args.min_span)
    reference_c, _ = reference_temperature(cal, rec)
    return diagnose_still(rec, cal, reference_c, args.band_width or STILL_BAND_WIDTH_C,
                          args.gravity, min_effect_mg=args.min_effect_mg, samples=samples)
