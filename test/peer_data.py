"""
Readers for the public peer recordings in test/data/peers (tests and benchmarks only).

The three folders (imu_tk, imucal, mpu6050_tomisuarez2) are copies of the recordings
with their licence notes (README.txt in each, README.md above them); the environment
variable ACCEL_CALIB_DATA points at another copy. Each reader returns Samples in the
recording's own units plus what is needed to compare with the peer's published result.
The product reads only the interface's CSV and bags; ``to_spec_csv`` converts a peer
recording for the command-line tests.
"""

import json
import os

from accel_calib_ros.core.samples import Samples
import numpy as np

DATA = os.environ.get('ACCEL_CALIB_DATA',
                      os.path.join(os.path.dirname(os.path.abspath(__file__)), 'data', 'peers'))

IMU_TK_GRAVITY = 9.81744
"""Gravity used by imu_tk's test application, m/s²."""

IMU_TK_REFERENCE = {'inverse_scale': np.array([414.459, 412.010, 414.649]),
                    'bias': np.array([33124.2, 33275.2, 32364.4]), 'residual_rms': 0.0080}
"""imu_tk's own result on xsens_acc.mat: counts/(m/s²), counts, m/s²."""


IMU_TK_GYRO_GAIN = np.array([4778.0, 4758.0, 4766.0])
"""Xsens factory gyroscope gains quoted by imu_tk_matlab, counts/(rad/s) (diagonal)."""

MPU6050_GYRO_LSB = np.radians(1.0 / 131.0)
"""MPU-6050 gyroscope step at ±250 °/s, rad/s per count."""


def available(name):
    """Tell whether the peer data folder ``name`` is present."""
    return os.path.isdir(os.path.join(DATA, name))


def imu_tk():
    """Xsens MTi recording of imu_tk: raw counts, 100 Hz, no temperature."""
    table = np.loadtxt(os.path.join(DATA, 'imu_tk', 'xsens_acc.mat'))
    return Samples(table[:, 0], table[:, 1:4])


MPU6050_REFERENCE = {'misalignment': np.array([1.04386e-05, 2.09845e-06, 2.00599e-06]),
                     'scale': np.array([6.020083e-04, 5.968449e-04, 5.859241e-04]),
                     'bias': np.array([-711.5163, 358.5055, 1840.1285])}
"""The MPU-6050 authors' accelerometer fit (params_acc.csv): (m/s²)/count, counts."""
MPU6050_FILES = {'calibration': 'example_data_calibration.csv',
                 'still': 'example_data_tinit_calc.csv', 'static_test': 'imu_static_test.csv',
                 'rotation_test': 'imu_90_x_rot.csv'}
"""The MPU-6050 recordings: the multi-position session and three other recordings."""


def mpu6050(which='calibration', counts=False):
    """
    Read an MPU-6050 recording (tomisuarez2), 100 Hz, ±2 g and ±250 °/s.

    :param which: a key of MPU6050_FILES.
    :param counts: accelerometer in raw counts (16384 per g) instead of m/s².
    :return: Samples (gyro in rad/s).
    """
    path = os.path.join(DATA, 'mpu6050_tomisuarez2', MPU6050_FILES[which])
    table = np.loadtxt(path, delimiter=',', skiprows=5)
    t = np.arange(len(table)) / 100.0
    accel = table[:, :3] if counts else table[:, :3] / 16384.0 * 9.80665
    return Samples(t, accel, gyro=np.radians(table[:, 3:6] / 131.0))


def imu_tk_imu(gain=4770.0):
    """
    Xsens MTi accelerometer and gyroscope of imu_tk (same session, same time stamps).

    Acceleration in raw counts; gyro as (counts - 32768) / ``gain`` rad/s, so a fitted
    gyroscope T times ``gain`` is the gain in counts/(rad/s).
    """
    acc = np.loadtxt(os.path.join(DATA, 'imu_tk', 'xsens_acc.mat'))
    gyr = np.loadtxt(os.path.join(DATA, 'imu_tk', 'xsens_gyro.mat'))
    return Samples(acc[:, 0], acc[:, 1:4], gyro=(gyr[:, 1:4] - 32768.0) / gain)


def mpu6050_turn():
    """MPU-6050 validation recording imu_90_x_rot.csv: still, one turn, still (as mpu6050)."""
    path = os.path.join(DATA, 'mpu6050_tomisuarez2', 'imu_90_x_rot.csv')
    table = np.loadtxt(path, delimiter=',', skiprows=5)
    return Samples(np.arange(len(table)) / 100.0, table[:, :3] / 16384.0 * 9.80665,
                   gyro=table[:, 3:6] * MPU6050_GYRO_LSB)


def imucal_ferraris():
    """Read imucal's Ferraris session (m/s², 102.4 Hz) and its static section list."""
    path = os.path.join(DATA, 'imucal', 'example_ferraris_session.csv')
    table = np.genfromtxt(path, delimiter=',', names=True)
    t = table['n_samples'] / 102.4
    acc = np.column_stack([table['acc_x'], table['acc_y'], table['acc_z']])
    gyr = np.radians(np.column_stack([table['gyr_x'], table['gyr_y'], table['gyr_z']]))
    with open(os.path.join(DATA, 'imucal', 'example_ferraris_session_list.json')) as f:
        sections = json.load(f)
    return Samples(t, acc, gyro=gyr), sections


IMUCAL_RATE_ANNOTATED = 204.8
"""Sampling rate imucal's tests use for annotated_session.csv, Hz."""


def imucal_annotated():
    """
    Read imucal's annotated session: raw counts (±16 g, ~2048 per g), parts in file order.

    :return: (Samples (accel counts, gyro counts as read), reference dict from
        example_cal.json: K_a diagonal counts/(m/s²), R_a, b_a counts).
    """
    path = os.path.join(DATA, 'imucal', 'annotated_session.csv')
    table = np.genfromtxt(path, delimiter=',', names=True, dtype=None, encoding=None)
    t = np.arange(len(table)) / IMUCAL_RATE_ANNOTATED   # parts in order, moves cut out
    acc = np.column_stack([table['acc_x'], table['acc_y'], table['acc_z']]).astype(float)
    with open(os.path.join(DATA, 'imucal', 'example_cal.json')) as f:
        cal = json.load(f)
    ref = {'K_a': np.diag(cal['K_a']), 'R_a': np.array(cal['R_a']),
           'b_a': np.array(cal['b_a'])}
    return Samples(t, acc), ref


def to_spec_csv(samples, path):
    """Write Samples as the interface's CSV (t, ax, ay, az[, temp, gx, gy, gz])."""
    cols = [samples.t[:, None], samples.accel]
    names = ['t', 'ax', 'ay', 'az']
    if samples.temp is not None:
        cols.append(samples.temp[:, None])
        names.append('temp')
    if samples.gyro is not None:
        cols.append(samples.gyro)
        names += ['gx', 'gy', 'gz']
    np.savetxt(path, np.hstack(cols), delimiter=',', header=','.join(names), comments='',
               fmt='%.9g')
    return path


def held_out(cal, windows, rate_hz, noise_std=None):
    """
    Gravity-norm residual of ``cal`` on static windows it was not fitted to, and its prediction.

    Measured: RMS over the windows of ``|corrected window mean| - gravity``. Predicted:
    the same RMS from the calibration's covariance (``core.accuracy.norm_errors`` at each
    window's direction) plus each window mean's own noise (``core.information`` model,
    inflated as the fit's windows were): what the fit claims a held-out window shows.

    :param cal: Calibration from ``calibrate`` (its ``information`` gives the noise model).
    :param windows: StaticWindows of the held-out data, m/s².
    :param noise_std: per-sample noise of the held-out windows (default: theirs).
    :return: dict with 'windows', 'measured' and 'predicted' (m/s²).
    """
    from accel_calib_ros.core.accuracy import norm_errors
    from accel_calib_ros.core.information import window_variance
    corrected = cal.correct(windows.mean)
    rho = np.linalg.norm(corrected, axis=1) - cal.gravity
    u = corrected / np.linalg.norm(corrected, axis=1, keepdims=True)
    noise = windows.noise_std if noise_std is None else noise_std
    var = window_variance(windows.weights(5.0, rate_hz), noise, len(windows))
    inflation = cal.information.inflation if cal.information is not None else 1.0
    predicted = norm_errors(cal.T, cal.covariance, u, cal.gravity) ** 2 + inflation * var
    return {'windows': len(windows), 'measured': float(np.sqrt(np.mean(rho ** 2))),
            'predicted': float(np.sqrt(np.mean(predicted)))}
