"""
Readers for the public peer recordings in ../shared/data (tests and benchmarks only).

Each returns Samples in the recording's own units plus what is needed to compare
with the peer's published result. The product reads only the spec's CSV and bags;
``to_spec_csv`` converts a peer recording for the command-line tests.
"""

import json
import os

from accel_calib_ros.core.samples import Samples
import numpy as np

DATA = os.environ.get('ACCEL_CALIB_DATA',
                      os.path.join(os.path.dirname(__file__), '..', '..', 'shared', 'data'))

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


def mpu6050():
    """MPU-6050 multi-position recording (tomisuarez2): m/s² from ±2 g counts, 100 Hz."""
    path = os.path.join(DATA, 'mpu6050_tomisuarez2', 'example_data_calibration.csv')
    table = np.loadtxt(path, delimiter=',', skiprows=5)
    t = np.arange(len(table)) / 100.0
    return Samples(t, table[:, :3] / 16384.0 * 9.80665,
                   gyro=np.radians(table[:, 3:6] / 131.0))


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


def to_spec_csv(samples, path):
    """Write Samples as the spec's CSV (t, ax, ay, az[, temp, gx, gy, gz])."""
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
