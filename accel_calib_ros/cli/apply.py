"""
``accel-calib apply``: correct a recording with a calibration file, streamed.

The acceleration always; ``gx gy gz`` with the gyro bias and, when the file has a
``gyro`` part, its scale and misalignment (``T⁻¹ (raw - bias)``); ``mx my mz`` with the
``magnetometer`` part when the file has one (else they pass through as recorded).

The unit of ax, ay, az is the one the calibration records (``input_units``: the fit's
``T`` absorbed its counts conversion, so only the same conversion is right): without unit
options ``apply`` uses it, and it refuses (exit 2) options that say another conversion.
"""

import itertools
import os
import sys

import numpy as np

from .common import (add_data_args, check_output, check_suffix, recorded_units, STDOUT,
                     time_unit, to_si, UsageError)
from ..core.errors import InputError
from ..core.samples import Samples


def add_arguments(p):
    """Add the options of ``apply`` to its parser."""
    p.add_argument('calibration', help='calibration YAML from "accel-calib fit"')
    add_data_args(p)
    p.add_argument('-o', '--output', required=True,
                   help='corrected CSV to write ("-": standard output, the summary then goes '
                        'to stderr)')
    p.add_argument('--json', action='store_true', help='print one JSON object')


def run(args, out):
    """Run ``accel-calib apply``; return the exit status."""
    if args.output == STDOUT and args.json:
        raise UsageError('accel-calib: apply -o - writes the CSV to standard output: '
                         'leave out --json')
    check_output(args.output, args.calibration, args.data, stdout=True)
    from .progress import Progress
    from ..dataio.calibration_file import load_calibration
    from ..dataio.recording import csv_writer, iter_samples
    if args.output != STDOUT:
        check_suffix(args.output, ('.csv',), 'apply -o')
    cal = load_calibration(args.calibration)
    used = recorded_units(args, cal)
    is_csv = args.data.lower().endswith('.csv') and os.path.isfile(args.data)
    # Streamed: one piece of the recording in memory at a time, whatever its length.
    with Progress(os.path.getsize(args.data) if is_csv else None, 'apply',
                  'B' if is_csv else 'rows') as bar:
        pieces = iter_samples(args.data, imu_topic=args.imu_topic, temp_topic=args.temp_topic,
                              on_read=bar.update if is_csv else None,
                              mag_topic=getattr(args, 'mag_topic', None),
                              time_unit=time_unit(args))
        first = to_si(next(pieces), args)        # m/s², like every piece after it
        pieces = (to_si(piece, args, check=False) for piece in pieces)
        if cal.thermal is not None and cal.thermal.usable and first.temp is None:
            print('accel-calib: warning: calibration has temperature tables but the data '
                  'have no temperature; applying without drift correction', file=sys.stderr)
        n, sum_before, sum_after = 0, 0.0, 0.0
        range_c = thermal_range(cal)
        seen = Seen(range_c)
        stream = cal.lag_stream()           # the hysteresis term's lag, across pieces
        gyro_subtracted = first.gyro is not None and cal.gyro_bias is not None
        with csv_writer(args.output, first.temp is not None, first.gyro is not None,
                        has_mag=first.mag is not None) as w:
            for samples in itertools.chain([first], pieces):
                seen.add(samples.temp)
                with np.errstate(all='ignore'):
                    corrected = cal.correct(samples.accel, samples.temp, samples.t, stream)
                    gyro = samples.gyro
                    if gyro is not None:
                        gyro = cal.correct_gyro(gyro, samples.temp)
                    mag = None if samples.mag is None else cal.correct_mag(samples.mag)
                bad = ~np.all(np.isfinite(corrected), axis=1)
                if gyro is not None:
                    bad |= ~np.all(np.isfinite(gyro), axis=1)
                if mag is not None:      # rows without a sample stay empty (NaN)
                    bad |= samples.mag_rows & ~np.all(np.isfinite(mag), axis=1)
                if bad.any():       # the atomic writer removes what was written so far
                    raise InputError(
                        f'{int(bad.sum())} rows would be non-finite after correction (first '
                        f't={samples.t[np.argmax(bad)]:.3f} s): the data or the calibration '
                        'are out of range; nothing written')
                w.write(Samples(samples.t, corrected, samples.temp, gyro, mag))
                n += len(samples)
                sum_before += float(np.linalg.norm(samples.accel, axis=1).sum())
                sum_after += float(np.linalg.norm(corrected, axis=1).sum())
                if not is_csv:
                    bar.update(len(samples))
    if seen.outside:
        print(f'accel-calib: warning: {seen.words(cal)}', file=sys.stderr)
    summary = {'output': args.output, 'samples': n, 'calibration': args.calibration,
               'mean_norm_before': sum_before / n, 'mean_norm_after': sum_after / n,
               'gyro_bias_subtracted': gyro_subtracted,
               'gyro_corrected': _gyro_words(cal, first),
               'magnetometer_corrected': first.mag is not None and cal.magnetometer is not None,
               'samples_outside_temperature_range': seen.outside,
               'temperature_range_seen_c': seen.seen_c(),
               'calibrated_range_c': None if range_c is None else list(range_c),
               'hysteresis_applied': stream is not None and first.temp is not None,
               'hysteresis_restarts': 0 if stream is None else stream.restarts,
               'input_units': used}
    if args.json:
        out(summary)
    else:
        print(f'corrected {n} samples -> '
              f'{"standard output" if args.output == STDOUT else args.output} '
              f'(mean |a| {sum_before / n:.4f} -> {sum_after / n:.4f} m/s²'
              + (f', gyro: {summary["gyro_corrected"]}' if summary['gyro_corrected'] else '')
              + (', magnetometer corrected' if summary['magnetometer_corrected'] else
                 ', mx my mz as recorded (no magnetometer calibration)'
                 if first.mag is not None else '') + ')',
              file=sys.stderr if args.output == STDOUT else sys.stdout)
    return 0


RANGE_MARGIN_C = 1.0
"""Temperatures this far beyond the calibrated range are counted as outside it, °C."""


def thermal_range(cal):
    """Return the temperature range the calibration knows, °C (its tables' or its fit's)."""
    if cal.thermal is not None and cal.thermal.range_c is not None:
        return tuple(cal.thermal.range_c)
    return cal.temperature_range_c


class Seen:
    """The temperatures a recording held, and how many lay outside the calibrated range."""

    def __init__(self, range_c):
        self.range_c, self.outside, self.low, self.high = range_c, 0, np.inf, -np.inf

    def add(self, temp):
        if temp is None:
            return
        finite = temp[np.isfinite(temp)]
        if not len(finite):
            return
        self.low, self.high = min(self.low, finite.min()), max(self.high, finite.max())
        if self.range_c is not None:
            lo, hi = self.range_c
            self.outside += int(np.sum((finite < lo - RANGE_MARGIN_C)
                                       | (finite > hi + RANGE_MARGIN_C)))

    def seen_c(self):
        return None if self.low > self.high else [float(self.low), float(self.high)]

    def words(self, cal):
        lo, hi = self.range_c
        beyond = ('the thermal tables are continued linearly there, an extrapolation'
                  if cal.thermal is not None and cal.thermal.extrapolation == 'linear'
                  else 'the correction there is that of the nearest calibrated temperature'
                  if cal.thermal is not None and cal.thermal.usable
                  else 'no thermal tables: the offsets there may have moved')
        return (f'{self.outside} samples lie outside the calibrated temperature range '
                f'{lo:.1f} .. {hi:.1f} °C (the data reach {self.low:.1f} .. {self.high:.1f} °C): '
                f'{beyond}')


def _gyro_words(cal, samples):
    """Say what was done to gx gy gz (None when there are none or nothing was done)."""
    if samples.gyro is None or (cal.gyro_bias is None and cal.gyro_T is None):
        return None
    return 'bias, scale and misalignment' if cal.gyro_T is not None else 'bias subtracted'
