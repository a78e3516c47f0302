#!/usr/bin/env python3
"""
Benchmark of the thermal fit of one still pose on simulated chamber cycles.

A unit held still in a chamber that cools, heats and cools again (-18 .. 74 °C, ramps of
1-8 °C/min drawn per leg, the board 1-4 min behind the air), with MPU-9250-like offsets
against temperature (16, 15 and 55 mg over the range, along a curve with bumps no cubic
holds) and a heating/cooling hysteresis of 0 (null), 5, 10 or 15 mg on its worst axis (a
temperature gradient across the package, smoothed over 30-60 s). ``fit --thermal
--calibration`` (``session.temperature.fit_thermal``) on the heating leg and on the second
cooling leg; the other legs corrected and compared with a cubic in the reported temperature
fitted on the same leg (PX4's model): held-out RMS per axis, mg, after a constant per leg
(the fitted leg's level). Also how often the hysteresis term is carried (on nulls: false).
Prints figures, asserts nothing.
"""

import argparse
import time

from accel_calib_ros.core.calibration import Calibration
from accel_calib_ros.core.samples import Samples
from accel_calib_ros.session.temperature import fit_thermal
from accel_calib_ros.sim.chamber import ChamberProgramme, simulate_still, thermal_unit
import numpy as np

G = 9.80665


def session(seed, hysteresis_mg, rate_hz):
    rng = np.random.default_rng(seed)
    rates = rng.uniform(1.0, 8.0, 3)
    programme = ChamberProgramme(rates_c_min=rates, hold_s=rng.uniform(300.0, 900.0),
                                 board_tau_s=rng.uniform(60.0, 240.0))
    sensor = thermal_unit(rng, hysteresis_mg=hysteresis_mg, rate_c_min=float(np.mean(rates)),
                          gradient_tau_s=rng.uniform(30.0, 60.0), bumps=0.08,
                          noise_mg=rng.uniform(0.3, 0.5), rate_hz=rate_hz)
    s = simulate_still(sensor, [0.0, 0.0, 1.0], rng, programme.duration_s, rate_hz=rate_hz,
                       temperature=programme).samples
    return s, programme.leg_of(s.t), sensor


def held_out(s, leg, k, sensor):
    sel = leg == k
    ref = Calibration(T=sensor.T, bias=sensor.bias, temperature_range_c=(24.0, 26.0))
    started = time.perf_counter()
    out = fit_thermal(Samples(s.t[sel], s.accel[sel], s.temp[sel]), ref)
    seconds = time.perf_counter() - started
    if out.calibration is None:
        return None
    fixed = out.calibration.correct(s.accel, s.temp, s.t)
    ours = fixed[~sel] - fixed[sel].mean(axis=0)
    X = np.vander(s.temp - 25.0, 4)
    coef = np.linalg.lstsq(X[sel], s.accel[sel], rcond=None)[0]
    cubic = s.accel[~sel] - X[~sel] @ coef
    rms = [1000.0 * np.sqrt(np.mean(e ** 2, axis=0)) / G for e in (ours, cubic)]
    return rms + [out.calibration.thermal.hysteresis is not None, seconds]


def main():
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('--sessions', type=int, default=10)
    parser.add_argument('--rate', type=float, default=10.0, help='sample rate, Hz')
    parser.add_argument('--hysteresis', type=float, nargs='+', default=[0.0, 5.0, 10.0, 15.0])
    args = parser.parse_args()
    print(f'{args.sessions} chamber cycles per row at {args.rate:g} Hz; fitted on the heating '
          'leg and on the last cooling leg, the other legs held out; RMS mg (median over '
          'sessions and splits)')
    print(f'{"hysteresis":>10s} {"carried":>8s} {"axis":>5s} {"ours":>7s} {"cubic":>7s} '
          f'{"ratio":>6s} {"worst ratio":>11s} {"s/fit":>6s}')
    for h in args.hysteresis:
        rows = []
        for seed in range(args.sessions):
            s, leg, sensor = session(1000 * int(h) + seed, h, args.rate)
            worst = int(np.argmax(np.abs(sensor.bias_gradient))) if h else 2
            for k in (1, 2):
                r = held_out(s, leg, k, sensor)
                if r is not None:
                    rows.append((r[0], r[1], r[2], r[3], worst))
        carried = np.mean([r[2] for r in rows])
        for name, pick in (('worst', lambda r: r[4]), ('other', None)):
            if pick is None:
                ours = np.concatenate([np.delete(r[0], r[4]) for r in rows])
                cubic = np.concatenate([np.delete(r[1], r[4]) for r in rows])
            else:
                ours = np.array([r[0][pick(r)] for r in rows])
                cubic = np.array([r[1][pick(r)] for r in rows])
            ratio = ours / cubic
            print(f'{h:10.0f} {carried:8.0%} {name:>5s} {np.median(ours):7.2f} '
                  f'{np.median(cubic):7.2f} {np.median(ratio):6.2f} {ratio.max():11.2f} '
                  f'{np.median([r[3] for r in rows]):6.1f}')


if __name__ == '__main__':
    main()
