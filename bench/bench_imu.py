#!/usr/bin/env python3
"""
Benchmark of the gyroscope (interface.md §9) and magnetometer (interface.md §10) calibrations.

Simulated hand-held sessions (MPU-9250-like accelerometer and gyroscope with ±3 %
scale and ±2 % cross-axis errors, AK8963-like magnetometer with up to ±30 µT hard
iron, ±5 % soft iron and 2° misalignment, 48 µT field at 60° dip, 0.3° hand tremor
during holds): recovered against true parameters, and the predicted accuracy against
the actual one; then the same through the product's own path (``accel-calib simulate
--gyro-errors --magnetometer`` and ``accel-calib fit --json``: the statuses, the stored
parts against the truth file). Then the real recordings in ../shared/data: the MPU-6050
session (its 92° validation turn) and the Xsens gyroscope gains against the factory
values. Prints figures, asserts nothing.
"""

import argparse
import os
import sys
import time

from accel_calib_ros.core.accelerometer.fit import calibrate
from accel_calib_ros.core.gyroscope.fit import fit_gyro
from accel_calib_ros.core.gyroscope.moves import integrate
from accel_calib_ros.core.magnetometer.fit import canonical, correct_field, fit_magnetometer
from accel_calib_ros.core.windows import detect_static_windows
from accel_calib_ros.sim import motion as sim_motion
from accel_calib_ros.sim import sensor as simulate
import numpy as np
from scipy.spatial.transform import Rotation

sys.path.insert(0, os.path.join(os.path.dirname(__file__), '..', 'test'))
import peer_data  # noqa: E402, I100


def session(seed, poses, tremor_deg, full_scale=None, move_s=1.5):
    """Simulate one hand-held session with gyroscope errors and a magnetometer."""
    rng = np.random.default_rng(seed)
    sensor = simulate.with_gyro_errors(simulate.mpu9250_like(rng),
                                       np.random.default_rng(seed + 1000), full_scale)
    sensor.magnetometer = simulate.ak8963_like(np.random.default_rng(seed + 500))
    return sim_motion.simulate_session(sensor, sim_motion.random_poses(poses, rng), rng,
                                       move_s=move_s, tremor_deg=tremor_deg)


def rate_error(T_fit, T_true):
    """RMS relative rate error over the sphere when correcting with T_fit (T_true holds)."""
    A = np.linalg.solve(T_fit, T_true) - np.eye(3)
    return float(np.sqrt(np.sum(A ** 2) / 3.0))


def field_error(correct, sess, n=20000):
    """RMS error of ``correct(raw)`` against the field over directions on the sphere, µT."""
    mag = sess.sensor.magnetometer
    T, R, field_uT = canonical(mag.T, mag.R, sess.earth_field.field_uT)
    u = sim_motion.random_directions(n, np.random.default_rng(1))
    raw = (field_uT * u) @ (T @ R).T + mag.hard_iron
    return float(np.sqrt(np.mean(np.sum((correct(raw) - field_uT * u) ** 2, axis=1))))


def one(seed, poses, tremor_deg):
    """Fit the accelerometer, gyroscope and magnetometer of one session; return figures."""
    sess = session(seed, poses, tremor_deg)
    windows = detect_static_windows(sess.samples)
    accel = calibrate(windows.mean, weights=windows.count, noise_std=windows.noise_std)
    t0 = time.perf_counter()
    gyro = fit_gyro(sess.samples, windows, accel=accel)
    t_gyro = time.perf_counter() - t0
    truth = sess.sensor.gyro_T
    std = np.sqrt(np.diag(gyro.covariance)).reshape(3, 3)
    t0 = time.perf_counter()
    mag = fit_magnetometer(sess.samples, windows, accel=accel)
    t_mag = time.perf_counter() - t0
    m = sess.sensor.magnetometer
    T, R, field_uT = canonical(m.T, m.R, sess.earth_field.field_uT)
    theta = Rotation.from_matrix(mag.R @ R.T).as_rotvec()
    error = np.concatenate([(mag.T * mag.field_uT - T * field_uT)[np.triu_indices(3)],
                            mag.hard_iron_uT - m.hard_iron, theta])
    return {
        'g_T': np.abs(gyro.T - truth).max(), 'g_raw': rate_error(np.eye(3), truth),
        'g_actual': rate_error(gyro.T, truth), 'g_pred': gyro.predicted_accuracy,
        'g_z': np.max(np.abs(gyro.T - truth) / std), 'g_res': gyro.residual_rms_deg,
        'g_bias': np.abs(gyro.bias - sess.sensor.gyro_bias).max(),
        'g_s': t_gyro, 'g_moves': gyro.moves_used,
        'm_hard': np.abs(mag.hard_iron_uT - m.hard_iron).max(),
        'm_T': np.abs(mag.T - T).max(), 'm_R': np.degrees(np.linalg.norm(theta)),
        'm_dip': abs(mag.dip_deg - sess.earth_field.dip_deg),
        'm_field': abs(mag.field_uT - field_uT), 'm_actual': field_error(mag.correct, sess),
        'm_pred': mag.predicted_accuracy, 'm_cov': mag.coverage, 'm_s': t_mag,
        'm_z': np.max(np.r_[np.abs(error) / np.sqrt(np.diag(mag.covariance)),
                            abs(mag.dip_deg - sess.earth_field.dip_deg) / mag.dip_std_deg]),
        'm_raw': field_error(lambda raw: raw, sess),
    }


def table(results, rows):
    """Print median / 95th percentile / max of each named figure over the sessions."""
    print(f'  {"":44s}{"median":>11s}{"95th pct":>11s}{"max":>11s}')
    for key, label, scale in rows:
        v = np.array([r[key] for r in results]) * scale
        print(f'  {label:44s}{np.median(v):11.4g}{np.percentile(v, 95):11.4g}{v.max():11.4g}')


def simulated(args):
    """Print the simulated figures."""
    results = [one(seed, args.poses, args.tremor) for seed in range(args.sessions)]
    print(f'{args.sessions} simulated hand-held sessions, {args.poses} poses, tremor '
          f'{args.tremor:g}° RMS, 100 Hz')
    print('gyroscope (T: 9 parameters from the moves between static windows):')
    table(results, [('g_raw', 'rate error uncalibrated, % RMS over sphere', 100),
                    ('g_actual', 'rate error calibrated (actual), %', 100),
                    ('g_pred', 'predicted accuracy, %', 100),
                    ('g_T', 'max |T - T_true|', 1),
                    ('g_z', 'max |T - T_true| / std (9 entries)', 1),
                    ('g_bias', 'max |bias error|, mrad/s', 1000),
                    ('g_res', 'residual, deg RMS', 1), ('g_s', 'fit time, s', 1)])
    ratio = np.array([r['g_actual'] / r['g_pred'] for r in results])
    print(f'  actual / predicted: RMS {np.sqrt(np.mean(ratio ** 2)):.2f} '
          f'(range {ratio.min():.2f}-{ratio.max():.2f}); 1 = honest')
    print('magnetometer (soft/hard iron by ML, R and dip from the static windows):')
    table(results, [('m_raw', 'field error uncalibrated, µT RMS', 1),
                    ('m_actual', 'field error calibrated (actual), µT RMS', 1),
                    ('m_pred', 'predicted accuracy, µT', 1),
                    ('m_hard', 'max |hard iron error|, µT', 1),
                    ('m_T', 'max |T - T_true| (det 1 form)', 1),
                    ('m_R', 'R error, deg', 1), ('m_dip', 'dip error, deg', 1),
                    ('m_field', 'field magnitude error, µT', 1),
                    ('m_z', 'max error / std (12 parameters + dip)', 1),
                    ('m_cov', 'sphere coverage', 1), ('m_s', 'fit time, s', 1)])
    ratio = np.array([r['m_actual'] / r['m_pred'] for r in results])
    print(f'  actual / predicted: RMS {np.sqrt(np.mean(ratio ** 2)):.2f} '
          f'(range {ratio.min():.2f}-{ratio.max():.2f}); 1 = honest')
    # Clipping: fast moves against a ±250 °/s gyro.
    sess = session(7, 30, args.tremor, np.radians(250.0), move_s=0.5)
    windows = detect_static_windows(sess.samples)
    accel = (sess.sensor.T, sess.sensor.bias)
    dropped = fit_gyro(sess.samples, windows, accel=accel)
    through = fit_gyro(sess.samples, windows, accel=accel, full_scale=np.inf)
    print(f'clipping (±250 °/s, 0.5 s moves, limit found in the data): '
          f'{len(dropped.moves_dropped)} of {len(dropped.moves)} moves dropped; rate error '
          f'{100 * rate_error(dropped.T, sess.sensor.gyro_T):.3f} % (predicted '
          f'{100 * dropped.predicted_accuracy:.3f} %) against '
          f'{100 * rate_error(through.T, sess.sensor.gyro_T):.3f} % integrating through them')


def through_cli(sessions, poses):
    """Print what ``accel-calib fit`` reports and stores on simulated sessions, vs the truth."""
    import contextlib
    import io
    import json
    import tempfile
    from accel_calib_ros.cli import main as cli
    import yaml
    rows, statuses = [], {}
    with tempfile.TemporaryDirectory() as folder:
        for seed in range(sessions):
            data, truth_path = f'{folder}/s{seed}.csv', f'{folder}/t{seed}.yaml'
            out = io.StringIO()
            with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
                cli(['simulate', '-o', data, '--poses', str(poses), '--seed', str(100 + seed),
                     '--gyro-errors', '--magnetometer', '--tremor', '0.3', '--truth',
                     truth_path])
            out = io.StringIO()
            t0 = time.perf_counter()
            with contextlib.redirect_stdout(out), contextlib.redirect_stderr(io.StringIO()):
                cli(['fit', data, '--json'])
            seconds = time.perf_counter() - t0
            d = json.loads(out.getvalue())
            for name, part in d['sensors'].items():
                statuses.setdefault(name, {}).setdefault(part['status'], 0)
                statuses[name][part['status']] += 1
            with open(truth_path, encoding='utf-8') as f:
                truth = yaml.safe_load(f)
            if d['gyro_T'] is None or d['mag_T'] is None:
                continue
            m = truth['magnetometer']
            T, R, field_uT = canonical(m['T'], m['R'], truth['earth_field']['field_uT'])
            u = sim_motion.random_directions(5000, np.random.default_rng(1))
            raw = (field_uT * u) @ (T @ R).T + m['hard_iron_uT']       # the fit's convention
            est = correct_field(raw, d['mag_T'], d['mag_hard_iron_uT'], d['mag_R'])
            rows.append({
                'g_raw': rate_error(np.eye(3), np.array(truth['gyro_T'])),
                'g_actual': rate_error(np.array(d['gyro_T']), np.array(truth['gyro_T'])),
                'g_pred': d['gyro_predicted_accuracy'],
                'g_bias': np.abs(np.array(d['gyro_bias'])
                                 - truth['gyro_bias_rad_s']).max(),
                'm_actual': float(np.sqrt(np.mean(np.sum((est - field_uT * u) ** 2, axis=1)))),
                'm_pred': d['mag_predicted_accuracy'],
                'm_hard': np.abs(np.array(d['mag_hard_iron_uT']) - m['hard_iron_uT']).max(),
                'm_dip': abs(d['mag_dip_deg'] - truth['earth_field']['dip_deg']),
                'seconds': seconds})
    print(f'accel-calib simulate --gyro-errors --magnetometer --tremor 0.3 --poses {poses}, '
          f'then fit --json, {sessions} seeds: statuses {statuses}')
    if not rows:
        return
    table(rows, [('g_raw', 'gyro rate error uncalibrated, %', 100),
                 ('g_actual', 'gyro rate error with the stored T, %', 100),
                 ('g_pred', 'gyro_predicted_accuracy, %', 100),
                 ('g_bias', 'max |gyro_bias error|, mrad/s', 1000),
                 ('m_actual', 'field error with the stored part, µT', 1),
                 ('m_pred', 'mag_predicted_accuracy, µT', 1),
                 ('m_hard', 'max |mag_hard_iron_uT error|, µT', 1),
                 ('m_dip', 'mag_dip_deg error, deg', 1),
                 ('seconds', 'fit wall time (all three), s', 1)])
    for key in ('g', 'm'):
        ratio = np.array([r[f'{key}_actual'] / r[f'{key}_pred'] for r in rows])
        print(f'  {"gyro" if key == "g" else "magnetometer"} actual / predicted: RMS '
              f'{np.sqrt(np.mean(ratio ** 2)):.2f} (range {ratio.min():.2f}-{ratio.max():.2f})')


def angle(u, v):
    """Angle between two vectors, degrees."""
    return float(np.degrees(np.arctan2(np.linalg.norm(np.cross(u, v)), u @ v)))


def real_data():
    """Print the real-data figures."""
    if peer_data.available('mpu6050_tomisuarez2'):
        samples = peer_data.mpu6050()
        windows = detect_static_windows(samples)
        accel = calibrate(windows.mean, method='gn', weights=windows.count,
                          noise_std=windows.noise_std)
        fit = fit_gyro(samples, windows, accel=accel)
        turn = peer_data.mpu6050_turn()
        held = detect_static_windows(turn)
        bias = turn.gyro[held.start[0]:held.stop[0]].mean(axis=0)
        n = 50
        a, b = held.stop[0] - n // 2, held.start[-1] + n // 2
        g0 = accel.correct(turn.accel[held.stop[0] - n:held.stop[0]].mean(axis=0))[0]
        g1 = accel.correct(turn.accel[held.start[-1]:held.start[-1] + n].mean(axis=0))[0]
        g0, g1 = g0 / np.linalg.norm(g0), g1 / np.linalg.norm(g1)
        print(f'MPU-6050 (tomisuarez2): {fit.message}')
        for m in fit.moves_dropped:
            print(f'  dropped move {m.window}->{m.window + 1}: {m.reason}')
        print(f'  T = {np.array2string(fit.T, precision=4, suppress_small=True)}'
              .replace('\n', '\n      '))
        print(f'  validation imu_90_x_rot: accelerometer turn {angle(g0, g1):.2f}°')
        path = os.path.join(peer_data.DATA, 'mpu6050_tomisuarez2', 'params_gyro.csv')
        p = np.loadtxt(path)
        mis, scale = p[:6], p[6:9] / peer_data.MPU6050_GYRO_LSB
        authors = np.linalg.inv(np.array([[1.0, -mis[0], mis[1]], [mis[2], 1.0, -mis[3]],
                                          [-mis[4], mis[5], 1.0]]) @ np.diag(scale))
        for name, T in (('fitted T', fit.T), ('nominal (identity)', np.eye(3)),
                        ("authors' params_gyro", authors)):
            rate = np.linalg.solve(T, (turn.gyro[a:b + 1] - bias).T).T
            end = integrate(rate, turn.t[a:b + 1]).T @ g0
            print(f'  {name:22s} gyro turn {angle(g0, end):7.2f}°, end direction off by '
                  f'{angle(end, g1):.2f}°')
        print('  (measured.md: 0.16° possible without the clipped moves, 1.36° with them)')
    if peer_data.available('imu_tk'):
        gain = 4770.0
        samples = peer_data.imu_tk_imu(gain)
        windows = detect_static_windows(samples)
        accel = calibrate(windows.mean, peer_data.IMU_TK_GRAVITY, weights=windows.count,
                          noise_std=windows.noise_std)
        fit = fit_gyro(samples, windows, accel=accel)
        std = np.sqrt(np.diag(fit.covariance)[[0, 4, 8]]) * gain
        fitted = np.diag(fit.T) * gain
        print(f'imu_tk Xsens MTi: {fit.message}')
        print('  gyro gain counts/(rad/s): fitted '
              + ', '.join(f'{g:.1f} ± {s:.1f}' for g, s in zip(fitted, std))
              + '; factory ' + ', '.join(f'{g:.0f}' for g in peer_data.IMU_TK_GYRO_GAIN)
              + '; difference ' + ', '.join(f'{100 * d:+.3f} %' for d in
                                            fitted / peer_data.IMU_TK_GYRO_GAIN - 1))
        print(f'  off-diagonal T (misalignment to the accelerometer frame): '
              f'{np.array2string(fit.T[~np.eye(3, dtype=bool)], precision=4)}')


def main():
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('--sessions', type=int, default=20)
    parser.add_argument('--poses', type=int, default=24)
    parser.add_argument('--tremor', type=float, default=0.3, help='hand tremor, deg RMS')
    parser.add_argument('--cli-sessions', type=int, default=10,
                        help='sessions through accel-calib simulate and fit (0: none)')
    args = parser.parse_args()
    simulated(args)
    if args.cli_sessions:
        through_cli(args.cli_sessions, args.poses)
    real_data()


if __name__ == '__main__':
    main()
