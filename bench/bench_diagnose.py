#!/usr/bin/env python3
"""
Benchmark of the model-gap workflow: detection rate, false alarms, real recordings.

Detection: for each effect of the library, random MPU-9250-like sessions (random
poses, 60 windows of 3.5 s, a temperature that rises 10 -> 45 °C and falls again,
flat for bias_drift) with that one effect hidden at 0.1x, 0.25x, 0.5x and 1x its
datasheet size; a detection is the hidden effect named first. False alarms: null
sessions, flat and varying temperature, in which anything named is false.
Real recordings: what the workflow finds, and the held-out residual with and without
it. Prints figures, asserts nothing.
"""

import argparse
import os
import sys
import zlib

from accel_calib_ros.core.calibration import calibrate, gravity_residuals
from accel_calib_ros.core.diagnose import diagnose
from accel_calib_ros.core.diagnose import diagnose_windows
from accel_calib_ros.core.effects import EFFECTS
from accel_calib_ros.core.simulate import (
    mpu9250_like, random_directions, simulate_static_windows, with_datasheet_effect)
from accel_calib_ros.core.windows import detect_static_windows
import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), '..', 'test'))
import peer_data  # noqa: E402, I100

WINDOWS, HOLD_S = 60, 3.5


def hump(t):
    return 10.0 + 35.0 * np.sin(np.pi * t / (WINDOWS * HOLD_S))


def session(rng, effect=None, scale=1.0, temperature=hump):
    sensor = mpu9250_like(rng)
    baseline = 'gn' if effect == 'nonorthogonality' else 'ml'
    if effect:
        sensor = with_datasheet_effect(sensor, effect, rng, scale)
    elif baseline == 'gn':
        sensor.T = np.diag(np.diag(sensor.T))
    if effect == 'bias_drift':
        temperature = 25.0
    windows = simulate_static_windows(sensor, random_directions(WINDOWS, rng), rng, HOLD_S,
                                      temperature=temperature)
    return windows, baseline


def detection(trials):
    scales = (0.1, 0.25, 0.5, 1.0)
    print(f'\n== Detection rate (hidden effect named first), {trials} sessions per cell, '
          f'{WINDOWS} windows')
    print(f'{"effect":22s}' + ''.join(f'{s:>8g}x' for s in scales))
    for name in EFFECTS:
        row = []
        for scale in scales:
            rng = np.random.default_rng(zlib.crc32(f'{name} {scale}'.encode()))
            hits = 0
            for _ in range(trials):
                windows, baseline = session(rng, name, scale)
                found = diagnose_windows(windows, baseline, rng=rng, replicates=0)
                hits += found.missing_effects[:1] == [name]
            row.append(hits / trials)
        print(f'{name:22s}' + ''.join(f'{r:9.0%}' for r in row))


def false_alarms(trials):
    print(f'\n== False alarms on null sessions ({trials} each; target <= 5 %)')
    for label, temperature, baseline in (('flat temperature, ml', 25.0, 'ml'),
                                         ('varying temperature, ml', hump, 'ml'),
                                         ('varying temperature, gn', hump, 'gn')):
        rng = np.random.default_rng(len(label))
        named = 0
        for _ in range(trials):
            sensor = mpu9250_like(rng)
            if baseline == 'gn':
                sensor.T = np.diag(np.diag(sensor.T))
            windows = simulate_static_windows(sensor, random_directions(WINDOWS, rng), rng,
                                              HOLD_S, temperature=temperature)
            named += bool(diagnose_windows(windows, baseline, rng=rng,
                                           replicates=0).missing_effects)
        print(f'  {label:26s} {named / trials:6.1%} named something')


def real():
    print('\n== Real recordings')
    cases = []
    if peer_data.available('imu_tk'):
        cases.append(('imu_tk Xsens', peer_data.imu_tk(), peer_data.IMU_TK_GRAVITY))
    if peer_data.available('mpu6050_tomisuarez2'):
        cases.append(('MPU-6050', peer_data.mpu6050(), 9.80665))
    if peer_data.available('imucal'):
        cases.append(('imucal Ferraris', peer_data.imucal_ferraris()[0], 9.80665))
    for name, samples, g in cases:
        for baseline in ('gn', 'ml'):
            print(f'\n{name}, baseline {baseline}:')
            try:
                result = diagnose(samples, baseline, g)
            except Exception as err:  # noqa: B902 - report and go on
                print(f'  not diagnosable: {err}')
                continue
            print('  ' + result.text().replace('\n', '\n  '))
            if result.missing_effects == ['nonorthogonality']:
                w = detect_static_windows(samples)
                even = np.arange(len(w)) % 2 == 0
                weights = w.weights(5.0, samples.rate_hz)
                for method in ('gn', 'ml'):
                    cal = calibrate(w.mean[even], g, method, weights[even])
                    res = gravity_residuals(cal, None, w.mean[~even], g)
                    print(f'  held-out residual (fit on half the windows) with {method}: '
                          f'{np.sqrt(np.mean(res ** 2)):.5f} m/s²')


def main():
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('--trials', type=int, default=100)
    args = parser.parse_args()
    detection(max(args.trials // 2, 10))
    false_alarms(args.trials)
    real()


if __name__ == '__main__':
    main()
