"""
``accel-calib fit DATA --thermal --calibration CALIB``: the thermal part from one still pose.

DATA is a still recording whose temperature sweeps (a warm-up after power-on, a chamber
cycle), at anything from a logger's 1 Hz to 1 kHz; CALIB an existing calibration (its T
and bias). The fit (``session.temperature.fit_thermal``) adds offset tables against
temperature, the gyroscope bias against temperature and, when the model-gap selection
names it, the heating/cooling hysteresis; the output is CALIB plus that part, written
atomically (``-o`` may be CALIB itself: it is replaced only by an accepted fit).
"""

import os
import sys

import numpy as np

from .common import check_output, load_data, recorded_units, STDOUT, UsageError
from ..core.errors import CalibrationError


def _settings(args, source):
    from ..session.temperature import STILL_BAND_WIDTH_C, ThermalSettings
    return ThermalSettings(band_width_c=args.band_width or STILL_BAND_WIDTH_C,
                           min_span_c=args.min_span, hysteresis=args.hysteresis,
                           gravity=args.gravity, source=source)


def _accuracy_rows(outcome):
    """Return the predicted accuracy per temperature: the thermal part and with CALIB's."""
    base = outcome.calibration.predicted_accuracy or 0.0
    rows = []
    for a in outcome.fit.accuracy:
        thermal = a['predicted_accuracy_m_s2']
        rows.append({'temp_c': a['temp_c'], 'thermal_m_s2': thermal,
                     'total_m_s2': float(np.hypot(thermal, base)),
                     'offset_se_m_s2': a['offset_se_m_s2'], 'misfit_m_s2': a['misfit_m_s2']})
    return rows


def _summary(args, samples, outcome, used):
    rec, fit, cal = outcome.recording, outcome.fit, outcome.calibration
    table = cal.thermal
    h = table.hysteresis
    gap = outcome.diagnosis
    return {
        'method': 'thermal-still', 'accepted': True, 'refusal': None,
        'calibration': args.calibration, 'output': args.output,
        'reference_c': outcome.reference_c, 'reference_note': outcome.reference_note,
        'calibrated_range_c': list(table.range_c), 'band_width_c': table.band_width_c,
        'samples': len(samples), 'rate_hz': rec.rate_hz, 'bins': len(rec.bins),
        'bin_s': float(np.median(np.diff(rec.bins.t_mid))) if len(rec.bins) > 1 else None,
        'poses': int(rec.pose.max()) + 1, 'moves_s': rec.moves,
        'dropped_bins': rec.dropped, 'skipped_rows': rec.skipped_rows,
        'thermal': table.to_dict(),
        'hysteresis': None if h is None else {
            **h.to_dict(), 'offset_per_c_min_mg': h.per_rate_mg(cal.gravity).tolist(),
            'standard_error_m_s2': None if fit.hysteresis_se is None
            else fit.hysteresis_se.tolist()},
        'model_gap': None if gap is None else gap.brief(),
        'predicted_accuracy_by_temperature': _accuracy_rows(outcome),
        'residual_rms_m_s2': np.sqrt(np.mean(fit.residuals ** 2, axis=0)).tolist(),
        'legs': fit.legs, 'accuracy_covers': _covers(fit.legs),
        'T': cal.T.tolist(), 'bias': cal.bias.tolist(),
        'gyro_bias_by_band': [None if b.gyro_bias is None else b.gyro_bias.tolist()
                              for b in table.bands],
        'input_units': used, 'warnings': outcome.warnings}


def _covers(legs):
    """Say which directions of the temperature's change the predicted accuracy covers."""
    heating, cooling = legs.get('heating_bins', 0) >= 10, legs.get('cooling_bins', 0) >= 10
    return ('heating and cooling' if heating and cooling else 'heating' if heating
            else 'cooling' if cooling else 'a steady temperature')


def _print(summary, outcome):
    rec = outcome.recording
    lo, hi = summary['calibrated_range_c']
    print(f'thermal fit of one still pose: {summary["bins"]} bins of {summary["bin_s"]:.0f} s '
          f'from {summary["samples"]} samples ({summary["rate_hz"]:.3g} Hz), '
          f'{summary["poses"]} pose(s), {lo:.1f} .. {hi:.1f} °C')
    print(f'reference temperature {outcome.reference_c:.1f} °C ({outcome.reference_note}): '
          'the calibration is unchanged there')
    g = outcome.calibration.gravity
    for band in outcome.calibration.thermal.bands:
        print(f'  {band.temp_c:6.1f} °C: offset [mg] '
              + ' '.join(f'{1000 * v / g:+7.2f}' for v in band.offset)
              + ('' if band.gyro_bias is None else '   gyro bias [°/s] ' + ' '.join(
                  f'{np.degrees(v):+.3f}' for v in band.gyro_bias)))
    h = summary['hysteresis']
    if h is None:
        print('heating/cooling hysteresis: none carried'
              + (f' ({summary["model_gap"]["verdict"]})' if summary['model_gap'] else ''))
    else:
        print(f'heating/cooling hysteresis ({h["effect"]}): '
              + ', '.join(f'{a} {v:+.2f}' for a, v in zip('xyz', h['offset_per_c_min_mg']))
              + f' mg per °C/min of heating (the rate smoothed over {h["tau_s"]:.0f} s)')
    for row in summary['predicted_accuracy_by_temperature']:
        print(f'  predicted accuracy at {row["temp_c"]:6.1f} °C: {row["thermal_m_s2"]:.4f} '
              f'm/s² (thermal part), {row["total_m_s2"]:.4f} m/s² with the calibration\'s own')
    held = summary['legs'].get('held_out_rms_m_s2')
    if held:
        for name, rms in held.items():
            print(f'  {name.replace("_", " ")}: held-out RMS [mg] '
                  + ' '.join(f'{1000 * v / g:.2f}' for v in rms))
    if rec.dropped:
        print(f'left out {len(rec.dropped)} bin(s) that moved')
    if rec.skipped_rows:
        print(f'skipped {rec.skipped_rows} row(s) without a finite reading or temperature')
    if summary['output'] and summary['output'] != STDOUT:
        print(f'wrote {summary["output"]}')


def run(args, out):
    """Run the one-pose thermal fit; return the exit status."""
    from ..dataio.calibration_file import calibration_yaml, load_calibration, save_calibration
    from ..session.temperature import fit_thermal
    if args.output == STDOUT and args.json:
        raise UsageError('accel-calib: fit -o - writes the YAML to standard output: leave out '
                         '--json')
    if args.mode != 'windows':
        raise UsageError('accel-calib: fit --thermal --calibration fits a still recording: '
                         'leave out --mode samples')
    if getattr(args, 'history', None) is not None:
        raise UsageError('accel-calib: fit --thermal --calibration keeps no windows: leave out '
                         '--history')
    check_output(args.output, args.data, stdout=True)     # -o may be the calibration itself
    reference = load_calibration(args.calibration)
    used = recorded_units(args, reference, 'fit --thermal')
    samples = load_data(args)
    outcome = fit_thermal(samples, reference, _settings(args, os.path.basename(args.data)))
    if outcome.refusal is not None:
        if args.json:
            out({'method': 'thermal-still', 'accepted': False, 'refusal': outcome.refusal,
                 'calibration': args.calibration, 'output': None, 'samples': len(samples)})
        raise CalibrationError(outcome.refusal)
    summary = _summary(args, samples, outcome, used)
    for warning in outcome.warnings:
        print(f'accel-calib: warning: {warning}', file=sys.stderr)
    worst = max(row['total_m_s2'] for row in summary['predicted_accuracy_by_temperature'])
    if worst > args.max_predicted_error:
        print(f'accel-calib: warning: the predicted accuracy reaches {worst:.4f} m/s² within '
              f'the calibrated range (limit {args.max_predicted_error:g} m/s²): the offsets '
              'there follow the temperature less closely than the limit asks', file=sys.stderr)
    if args.output == STDOUT:
        sys.stdout.write(calibration_yaml(outcome.calibration))
        sys.stdout.flush()
    elif args.output:
        save_calibration(outcome.calibration, args.output)
    if args.json:
        out(summary)
    else:
        import contextlib
        with contextlib.redirect_stdout(sys.stderr if args.output == STDOUT else sys.stdout):
            _print(summary, outcome)
    return 0


def one_pose_hint(args, samples):
    """
    Return words for a multi-pose ``--thermal`` refusal on what looks like one still pose.

    '' unless the recording spans at least the thermal minimum in temperature and holds
    nearly one direction: then the one-pose fit is the way (it needs ``--calibration``).
    """
    if samples.temp is None or getattr(args, 'calibration', None):
        return ''
    temp = samples.temp[np.isfinite(samples.temp)]
    if not len(temp) or np.ptp(temp) < args.min_span:
        return ''
    a = samples.accel / np.maximum(np.linalg.norm(samples.accel, axis=1, keepdims=True),
                                   1e-300)
    spread = np.degrees(np.arccos(np.clip(a @ np.mean(a, axis=0) / np.linalg.norm(
        np.mean(a, axis=0)), -1.0, 1.0)))
    if np.percentile(spread, 90) > 10.0:
        return ''
    return (f'; this looks like one still pose while the temperature spans {np.ptp(temp):.1f} '
            '°C: a one-pose thermal fit extends an existing calibration: add --calibration '
            'CALIB (its T and bias at its own temperature)')
