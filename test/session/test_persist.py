"""Persistence (``session.persist``): the file an accepted session writes, and its history."""

import os

from accel_calib_ros.core.calibration import Calibration
from accel_calib_ros.dataio.calibration_file import load_calibration, save_calibration
from accel_calib_ros.dataio.history import History
from accel_calib_ros.session.accept import fit_and_accept, NODE, Settings
from accel_calib_ros.session.persist import record_history, save, window_times
from accel_calib_ros.session.windows import Window, WindowSet
from accel_calib_ros.sim.motion import random_directions, simulate_window_means
from accel_calib_ros.sim.sensor import mpu9250_like
import numpy as np
import pytest


def accepted(n=20, seed=3, sensor_id=None):
    rng = np.random.default_rng(seed)
    means = simulate_window_means(mpu9250_like(rng, rate_hz=200.0),
                                  random_directions(n, np.random.default_rng(seed)), 300, rng)
    windows = WindowSet.from_windows([
        Window(mean=m, scatter=np.full(3, 0.02), count=300, t_start=k, t_stop=k + 1.5,
               temp=25.0) for k, m in enumerate(means)])
    outcome = fit_and_accept(windows.observations(5.0, 200.0),
                             Settings(words=NODE, sensor_id=sensor_id))
    assert outcome.accepted, outcome.refusal
    return outcome, windows


def test_save_keeps_the_level_trim_and_never_writes_a_refusal(tmp_path):
    path = tmp_path / 'calibration.yaml'
    save_calibration(Calibration(T=np.eye(3), bias=np.zeros(3),
                                 level_roll_pitch_rad=(0.01, -0.02)), path)
    outcome, _ = accepted()
    save(outcome, path, carry=('level trim',))
    assert load_calibration(path).level_roll_pitch_rad == (0.01, -0.02)
    assert outcome.saved_to == str(path) and 'level trim' in outcome.carried[0]
    assert 'level trim carried forward' in outcome.message()
    before = path.read_bytes()
    refused = outcome.refuse('no')
    with pytest.raises(ValueError):
        save(refused, path)
    assert path.read_bytes() == before


def test_history_records_one_session(tmp_path):
    outcome, windows = accepted()
    times = window_times(windows.t_mid, now=1.7e9)
    assert times[-1] == 1.7e9 and np.all(np.diff(times) > 0)
    unix = np.array([1.6e9, 1.6e9 + 2])
    np.testing.assert_array_equal(window_times(unix), unix)
    done = record_history(tmp_path / 'h.sqlite', 'imu_link', outcome.calibration, windows.mean,
                          windows.temp, windows.weights(5.0, 200.0), times,
                          windows=len(windows))
    assert done['windows_added'] == 20 and os.path.exists(done['db'])
    with History(tmp_path / 'h.sqlite', readonly=True) as h:
        (row,) = h.calibrations('imu_link')
        assert abs(row['predicted_accuracy'] - outcome.predicted_accuracy) < 1e-12


def imu_file(path, sensor_id=None):
    """Save a calibration with a level trim, a gyroscope T and a magnetometer part."""
    from accel_calib_ros.core.calibration import MagnetometerPart
    mag = MagnetometerPart(T=np.diag([0.97, 1.02, 1.01]), hard_iron_uT=[12.0, -25.0, 7.5],
                           R=np.eye(3), field_uT=48.0, dip_deg=61.0, predicted_accuracy=0.05)
    save_calibration(Calibration(T=np.eye(3), bias=np.zeros(3), gyro_bias=[0.01, 0.0, 0.0],
                                 gyro_T=np.diag([1.02, 0.98, 1.01]),
                                 gyro_predicted_accuracy=4e-3, magnetometer=mag,
                                 level_roll_pitch_rad=(0.01, -0.02), sensor_id=sensor_id),
                     path)


def test_what_this_session_could_not_calibrate_is_carried_forward_and_said(tmp_path):
    path = tmp_path / 'calibration.yaml'
    imu_file(path, 'imu_link')
    outcome, _ = accepted(sensor_id='imu_link')           # accelerometer only
    save(outcome, path)
    cal = load_calibration(path)
    np.testing.assert_allclose(cal.gyro_T, np.diag([1.02, 0.98, 1.01]))
    np.testing.assert_allclose(cal.gyro_bias, [0.01, 0.0, 0.0])
    assert cal.magnetometer is not None and cal.magnetometer.field_uT == 48.0
    assert cal.level_roll_pitch_rad == (0.01, -0.02)
    assert np.allclose(cal.T, outcome.calibration.T)        # the new accelerometer
    said = ' | '.join(outcome.carried)
    assert 'gyroscope: scale and misalignment carried forward' in said
    assert 'magnetometer: carried forward' in said and 'level trim' in said
    assert "this session's is absent" in said
    message = outcome.message()
    assert 'gyroscope: absent' in message and 'carried forward' in message


def test_another_sensors_parts_are_not_carried_forward(tmp_path):
    path = tmp_path / 'calibration.yaml'
    imu_file(path, 'other_imu')
    outcome, _ = accepted(sensor_id='imu_link')
    save(outcome, path)
    cal = load_calibration(path)
    assert cal.gyro_T is None and cal.magnetometer is None and cal.level_roll_pitch_rad is None
    assert all('not carried forward: the file it replaces was for sensor other_imu' in line
               for line in outcome.carried) and len(outcome.carried) == 2
    # Nothing to carry: no file, or an unreadable one.
    fresh, _ = accepted()
    save(fresh, tmp_path / 'new' / 'c.yaml')
    assert fresh.carried == [] and (tmp_path / 'new' / 'c.yaml').exists()
    (tmp_path / 'bad.yaml').write_text('not: [a calibration')
    again, _ = accepted()
    save(again, tmp_path / 'bad.yaml')
    assert again.carried == [] and load_calibration(tmp_path / 'bad.yaml').T is not None
