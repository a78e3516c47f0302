#!/usr/bin/env python3
"""
Benchmark of the model-gap workflow: detection rate, false alarms, real recordings.

Detection: for each effect of the library, random MPU-9250-like sessions (random
poses, 60 windows of 3.5 s, a temperature that rises 10 -> 45 °C and falls again,
flat for bias_drift) with that one effect hidden at 0.1x, 0.25x, 0.5x and 1x its
datasheet size; a detection is the hidden effect named first. A plain 10 -> 45 °C
ramp is also run for the temperature effects, where temperature and time move
together: there the result must name the effect *and* say that bias_drift is a rival.
Over-naming: how often a second effect is named besides the hidden one; pairs: two
effects hidden at once.
False alarms: null sessions (window level, flat and varying temperature, ml and gn;
sample level through window detection, with white and with correlated noise), in
which anything named is false. Real recordings: what the workflow finds, the held-out
residual with and without it. Prints figures, asserts nothing.
"""

import argparse
import os
import sys
import time
import zlib

from accel_calib_ros.core.diagnose import diagnose, diagnose_windows, held_out_check
from accel_calib_ros.core.effects import EFFECTS
from accel_calib_ros.core.errors import CalibrationError
from accel_calib_ros.core.simulate import (
    mpu9250_like, random_directions, simulate_session, simulate_static_windows,
    with_datasheet_effect)
from accel_calib_ros.core.windows import detect_static_windows
import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), '..', 'test'))
import peer_data  # noqa: E402, I100

WINDOWS, HOLD_S = 60, 3.5


def hump(t):
    return 10.0 + 35.0 * np.sin(np.pi * t / (WINDOWS * HOLD_S))


def ramp(t):
    return 10.0 + 35.0 * t / (WINDOWS * HOLD_S)


def seeded(text):
    """Return a Generator seeded from ``text`` (crc32: stable across processes)."""
    return np.random.default_rng(zlib.crc32(text.encode()))


def session(rng, effect=None, scale=1.0, temperature=hump):
    sensor = mpu9250_like(rng)
    baseline = 'gn' if effect == 'nonorthogonality' else 'ml'
    if effect:
        sensor = with_datasheet_effect(sensor, effect, rng, scale)
    if effect == 'bias_drift':
        temperature = 25.0
    windows = simulate_static_windows(sensor, random_directions(WINDOWS, rng), rng, HOLD_S,
                                      temperature=temperature)
    return windows, baseline


def detection(trials):
    scales = (0.1, 0.25, 0.5, 1.0)
    print(f'\n== Detection rate (hidden effect named first), {trials} sessions per cell, '
          f'{WINDOWS} windows of {HOLD_S} s, hump temperature 10-45-10 °C (flat for '
          'bias_drift)')
    print(f'{"effect":22s}' + ''.join(f'{s:>8g}x' for s in scales)
          + '   gap_after at 1x (median)')
    for name in EFFECTS:
        row, gaps = [], []
        for scale in scales:
            rng = seeded(f'{name} {scale}')
            hits = 0
            for _ in range(trials):
                windows, baseline = session(rng, name, scale)
                found = diagnose_windows(windows, baseline, rng=rng, replicates=0)
                hits += found.missing_effects[:1] == [name]
                if scale == 1.0:
                    gaps.append(found.gap_after)
            row.append(hits / trials)
        print(f'{name:22s}' + ''.join(f'{r:9.0%}' for r in row)
              + f'   {np.median(gaps):.2f}')


def extras_and_pairs(trials):
    print(f'\n== Over-naming and two hidden effects at 1x ({trials} sessions each)')
    for name in EFFECTS:
        rng = seeded(f'extra {name}')
        extra = 0
        for _ in range(trials):
            windows, baseline = session(rng, name, 1.0)
            found = diagnose_windows(windows, baseline, rng=rng, replicates=0)
            extra += len(found.missing_effects) > 1
        print(f'  {name:20s} alone: something else named too in {extra / trials:5.1%}')
    pairs = (('temperature_bias', 'scale_nonlinearity'), ('temperature_scale', 'temperature_bias'),
             ('bias_drift', 'scale_nonlinearity'), ('temperature_bias', 'bias_drift'))
    for first, second in pairs:
        rng = seeded(f'pair {first} {second}')
        both = 0
        for _ in range(trials):
            sensor = with_datasheet_effect(mpu9250_like(rng), first, rng)
            sensor = with_datasheet_effect(sensor, second, rng)
            windows = simulate_static_windows(sensor, random_directions(WINDOWS, rng), rng,
                                              HOLD_S, temperature=hump)
            found = diagnose_windows(windows, 'ml', rng=rng, replicates=0)
            both += set(found.missing_effects) == {first, second}
        print(f'  {first} + {second} (hump temperature): exactly both named in '
              f'{both / trials:5.0%}')


def ramp_ambiguity(trials):
    print(f'\n== Plain ramp 10 -> 45 °C (temperature and time together), 1x, {trials} each')
    for name in ('temperature_bias', 'temperature_scale'):
        rng = seeded(f'ramp {name}')
        named = flagged = 0
        for _ in range(trials):
            windows, baseline = session(rng, name, 1.0, ramp)
            found = diagnose_windows(windows, baseline, rng=rng, replicates=0)
            named += found.missing_effects[:1] == [name]
            flagged += any('bias_drift' in note for note in found.ambiguities)
        print(f'  {name:20s} named first {named / trials:5.0%}, '
              f'bias_drift flagged as rival {flagged / trials:5.0%}')


def false_alarms(trials):
    print(f'\n== False alarms on null sessions, window level ({trials} each; target <= 5 %)')
    for label, temperature, baseline in (('flat temperature, ml', 25.0, 'ml'),
                                         ('varying temperature, ml', hump, 'ml'),
                                         ('ramp temperature, ml', ramp, 'ml'),
                                         ('varying temperature, gn', hump, 'gn')):
        rng = seeded(label)
        named, unexplained = 0, 0
        for _ in range(trials):
            sensor = mpu9250_like(rng)
            if baseline == 'gn':
                sensor.T = np.diag(np.diag(sensor.T))
            windows = simulate_static_windows(sensor, random_directions(WINDOWS, rng), rng,
                                              HOLD_S, temperature=temperature)
            found = diagnose_windows(windows, baseline, rng=rng, replicates=0)
            named += bool(found.missing_effects)
            unexplained += not found.explained
        print(f'  {label:26s} {named / trials:6.1%} named something, '
              f'{unexplained / trials:6.1%} called "not explained by noise"')


def false_alarms_samples(trials):
    print(f'\n== False alarms, sample level (window detection, measured noise, 20 re-'
          f'simulations; {trials} each)')
    for label, corr in (('white noise, varying temperature', 0.0),
                        ('AR(1) noise 0.1 s, varying temperature', 0.9)):
        rng = seeded(label)
        named, unexplained, inflation = 0, 0, []
        for _ in range(trials):
            sensor = mpu9250_like(rng)
            std = sensor.noise_std.copy()
            if corr:
                sensor.noise_std = np.zeros(3)
            s = simulate_session(sensor, random_directions(40, rng), rng, hold_s=3.0,
                                 move_s=1.0, temperature=lambda t: 10 + 35 * np.sin(t / 50))
            if corr:
                noise = np.zeros_like(s.samples.accel)
                drive = rng.standard_normal(noise.shape) * std * np.sqrt(1 - corr ** 2)
                for k in range(1, len(noise)):
                    noise[k] = corr * noise[k - 1] + drive[k]
                s.samples.accel[:] = s.samples.accel + noise
            found = diagnose(s.samples, 'ml', rng=rng)
            named += bool(found.missing_effects)
            unexplained += not found.explained
            inflation.append(found.noise_inflation)
        print(f'  {label:40s} {named / trials:6.1%} named something, '
              f'{unexplained / trials:6.1%} not explained; inflation median '
              f'{np.median(inflation):.2f}')


def speed():
    rng = seeded('speed')
    sensor = mpu9250_like(rng)
    windows = simulate_static_windows(sensor, random_directions(100, rng), rng, HOLD_S,
                                      temperature=hump)
    for replicates in (0, 20):
        times = []
        for _ in range(5):
            start = time.perf_counter()
            diagnose_windows(windows, 'ml', replicates=replicates)
            times.append(time.perf_counter() - start)
        print(f'  100 windows, {replicates:2d} re-simulations: {1000 * np.median(times):.0f} ms')


def real():
    print('\n== Real recordings')
    cases = []
    if peer_data.available('imu_tk'):
        cases.append(('imu_tk Xsens (raw counts, g = 9.81744)', peer_data.imu_tk(),
                      peer_data.IMU_TK_GRAVITY))
    if peer_data.available('mpu6050_tomisuarez2'):
        cases.append(('MPU-6050', peer_data.mpu6050(), 9.80665))
    if peer_data.available('imucal'):
        cases.append(('imucal Ferraris', peer_data.imucal_ferraris()[0], 9.80665))
    for name, samples, g in cases:
        windows = detect_static_windows(samples)
        for baseline in ('gn', 'ml'):
            print(f'\n{name}, baseline {baseline}:')
            try:
                result = diagnose(samples, baseline, g)
            except CalibrationError as err:
                print(f'  not diagnosable: {err}')
                continue
            print('  ' + result.text().replace('\n', '\n  '))
            noise = result.noise()
            print(f'  noise inflation {noise["inflation"]:.2f}, density '
                  + ', '.join(f'{v:.0f}' for v in noise['density_ug_per_sqrt_hz'])
                  + ' µg/√Hz')
            if result.missing_effects:
                try:
                    check = held_out_check(windows, result)
                except CalibrationError as err:
                    print(f'  held-out check not possible: {err}')
                    continue
                print(f'  held-out |a| - g RMS (fit on {check["fit_windows"]} alternate '
                      f'windows, tested on {check["test_windows"]}): {baseline} '
                      f'{check["baseline_rms"]:.5f} m/s², {baseline} + '
                      f'{" + ".join(check["effects"])} {check["with_effects_rms"]:.5f} m/s²')


def main():
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('--trials', type=int, default=100)
    args = parser.parse_args()
    detection(max(args.trials // 2, 10))
    extras_and_pairs(max(args.trials // 5, 10))
    ramp_ambiguity(max(args.trials // 5, 10))
    false_alarms(args.trials)
    false_alarms_samples(max(args.trials // 5, 10))
    print('\n== Speed (calibration node budget: < 1 s)')
    speed()
    real()


if __name__ == '__main__':
    main()
