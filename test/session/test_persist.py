"""Persistence (``session.persist``): the file an accepted session writes, and its history."""

import os

from accel_calib_ros.core.calibration import Calibration
from accel_calib_ros.dataio.calibration_file import load_calibration, save_calibration
from accel_calib_ros.dataio.history import History
from accel_calib_ros.session.accept import fit_and_accept, NODE, Settings
from accel_calib_ros.session.persist import record_history, save, window_times
from accel_calib_ros.session.windows import Window, WindowSet
from accel_calib_ros.sim.sensor import mpu9250_like
from accel_calib_ros.sim.session import random_directions, simulate_window_means
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
