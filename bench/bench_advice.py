#!/usr/bin/env python3
"""
Benchmark of the pose advice: poses a simulated person needs to reach the target.

A simulated person (poses off by about 3°, hand tremor 0.02 m/s² per sample, 150
samples per window) calibrates an MPU-9250-like sensor (datasheet scale, cross-axis and
offset errors) until the advice says "enough" (predicted accuracy ≤ target), holding
either the advised poses, random poses (uniform on the sphere) or a fixed plan (the six
faces, then the eight corners, then the twelve edges). For each policy it prints how
many poses were needed, the predicted and the true accuracy at the stop (RMS error of
the corrected vector at 1 g over the sphere, against the simulated truth) and how
often the true accuracy met the target. Then the same loop through the command line:
a recording grows pose by pose and ``accel-calib advise --json`` picks the next one.
Prints figures, asserts nothing.
"""

import argparse
from contextlib import redirect_stdout
import io
import json
import math
import os
import tempfile

from accel_calib_ros.core.advice import advise, CANDIDATE_DIRECTIONS
from accel_calib_ros.sim.motion import simulate_session
from accel_calib_ros.sim.person import closed_loop, Person, tilt
from accel_calib_ros.sim.sensor import mpu9250_like
import numpy as np

PLAN = CANDIDATE_DIRECTIONS[[0, 1, 2, 3, 4, 5] + list(range(18, 26)) + list(range(6, 18))]


def run_policy(policy, seeds, target, person):
    poses, true, predicted, met = [], [], [], 0
    for seed in range(seeds):
        rng = np.random.default_rng(1000 + seed)
        sensor = mpu9250_like(rng)
        start = PLAN if policy == 'plan' else None
        if start is not None:
            result = _plan_loop(sensor, rng, person, target)
        else:
            result = closed_loop(sensor, rng, policy, person, target=target, max_poses=40)
        n = result.poses_to_enough
        poses.append(n if n is not None else math.inf)
        if n is not None:
            true.append(result.true_at_enough)
            predicted.append(result.predicted_at_enough)
            met += result.true_at_enough <= target
    return np.array(poses), np.array(true), np.array(predicted), met


def _plan_loop(sensor, rng, person, target):
    """Hold the fixed plan in order until the advice says enough."""
    from accel_calib_ros.core.accelerometer.fit import calibrate
    from accel_calib_ros.core.advice import true_accuracy
    from accel_calib_ros.sim.person import LoopResult
    means, result = [], LoopResult()
    noise = sensor.noise_std
    for k in range(len(PLAN) + 1):
        m = np.array(means).reshape(-1, 3)
        w = np.full(len(m), float(person.samples))
        adv = advise(m, w, noise, target=target)
        if adv.enough:
            cal = calibrate(m, method='ml', weights=w)
            result.poses_to_enough = len(m)
            result.predicted_at_enough = adv.predicted_accuracy
            result.true_at_enough = true_accuracy(cal.T, cal.bias, sensor.T, sensor.bias)
            return result
        if k == len(PLAN):
            return result
        _, mean, noise = person.hold(sensor, PLAN[k], rng)
        means.append(mean)
    return result


def describe(name, poses, true, predicted, met, seeds, target):
    finite = poses[np.isfinite(poses)]
    values, counts = np.unique(finite, return_counts=True)
    hist = ', '.join(f'{int(v)}: {int(c)}' for v, c in zip(values, counts))
    print(f'  {name:8s} poses median {np.median(poses):4.1f}  mean {np.mean(finite):5.2f}  '
          f'max {np.max(poses):4.0f}  never {int(np.sum(~np.isfinite(poses)))}/{seeds}   '
          f'predicted at stop median {np.median(predicted):.4f}  true median '
          f'{np.median(true):.4f} max {np.max(true):.4f}  true <= target {met}/{seeds}')
    print(f'           poses histogram {{{hist}}}')


def cli_loop(seed, target, max_poses=20):
    """Grow a CSV pose by pose; ask ``accel-calib advise --json`` which pose comes next."""
    from accel_calib_ros.cli import main
    from accel_calib_ros.core.advice import true_accuracy
    rng = np.random.default_rng(seed)
    sensor = mpu9250_like(rng)
    held = []
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, 'session.csv')
        advice = {'next_pose': {'gravity_direction': [0.0, 0.0, 1.0]}, 'enough': False}
        while not advice['enough'] and len(held) < max_poses:
            held.append(tilt(advice['next_pose']['gravity_direction'], 3.0, rng))
            session = simulate_session(sensor, np.array(held), np.random.default_rng(seed),
                                       hold_s=2.5, move_s=1.5)
            from accel_calib_ros.dataio.recording import write_samples_csv
            write_samples_csv(path, session.samples)
            buf = io.StringIO()
            with redirect_stdout(buf):
                code = main(['advise', path, '--json', '--target', str(target)])
            assert code == 0
            advice = json.loads(buf.getvalue())
        buf = io.StringIO()
        with redirect_stdout(buf):
            main(['fit', path, '--json'])
        fit = json.loads(buf.getvalue())
    true = true_accuracy(np.array(fit['T']), np.array(fit['bias']), sensor.T, sensor.bias)
    return len(held), advice, true


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--seeds', type=int, default=100)
    parser.add_argument('--cli-seeds', type=int, default=5)
    args = parser.parse_args()
    person = Person()
    print(f'simulated person: pose error {person.error_deg}°, tremor {person.tremor_std} m/s², '
          f'{person.samples} samples per window; {args.seeds} sensors per policy')
    for target in (0.01, 0.005, 0.003):
        print(f'target {target} m/s²:')
        for policy in ('advised', 'random', 'plan'):
            describe(policy, *run_policy(policy, args.seeds, target, person), args.seeds,
                     target)
    rng = np.random.default_rng(7)
    sensor = mpu9250_like(rng)
    angles = []
    for trial in range(20):
        start = [tilt([0, 0, 1], a, rng) for a in rng.uniform(0, 25, 10)]
        means = sensor.distort(9.80665 * np.array(start))
        means = means + rng.normal(0, 0.002, means.shape)
        adv = advise(means, np.full(10, 150.0), 0.02)
        angles.append(np.degrees(np.arccos(adv.next_pose.gravity_direction @ [0, 0, 1])))
    print(f'tilt-only start (10 poses within 25° of +z): advice {min(angles):.0f}°..'
          f'{max(angles):.0f}° away from +z over 20 trials')
    print('through the command line (simulate -> advise --json -> ... -> fit --json):')
    for seed in range(args.cli_seeds):
        n, advice, true = cli_loop(50 + seed, 0.01)
        print(f'  seed {50 + seed}: {n} poses, enough={advice["enough"]}, predicted '
              f'{advice["predicted_accuracy"]:.4f}, true {true:.4f} m/s²')


if __name__ == '__main__':
    main()
