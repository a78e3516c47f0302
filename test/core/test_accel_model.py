"""Static windows, thermal tables, the calibration model and its file; real recordings."""

from accel_calib_ros.core.accelerometer.fit import calibrate, gravity_residuals
from accel_calib_ros.core.accelerometer.thermal import fit_thermal_table
from accel_calib_ros.core.errors import CalibrationError, InputError
from accel_calib_ros.core.windows import detect_static_windows, OnlineStaticDetector
from accel_calib_ros.dataio.calibration_file import load_calibration, save_calibration
from accel_calib_ros.sim.motion import random_directions, simulate_session
from accel_calib_ros.sim.sensor import mpu9250_like
import numpy as np
import peer_data
import pytest

G = 9.80665


def session(seed=0, poses=30, effects=(), temperature=25.0, hold_s=3.0, rate_hz=100.0):
    rng = np.random.default_rng(seed)
    sensor = mpu9250_like(rng, rate_hz, effects)
    return simulate_session(sensor, random_directions(poses, rng), rng, hold_s=hold_s,
                            move_s=1.0, rate_hz=rate_hz, temperature=temperature)


def test_windows_are_the_held_poses_and_nothing_else():
    s = session()
    w = detect_static_windows(s.samples)
    assert len(w) == 30
    for a, b in zip(w.start, w.stop):
        poses = np.unique(s.pose[a:b])
        assert len(poses) == 1 and poses[0] >= 0          # never includes a move
    truth = s.sensor.distort(s.true_accel[(w.start + w.stop) // 2])
    assert np.abs(w.mean - truth).max() < 6 * s.sensor.noise_std.max() / np.sqrt(w.count.min())
    assert np.allclose(w.noise_std, s.sensor.noise_std, rtol=0.1)


def test_online_detector_finds_the_same_windows_with_bounded_memory():
    s = session(hold_s=2.0, rate_hz=200.0)
    det = OnlineStaticDetector(200.0)
    found = [det.update(t, a, temp) for t, a, temp in
             zip(s.samples.t, s.samples.accel, s.samples.temp)]
    found = [f for f in found if f] + [det.flush()]
    assert len(found) == 30                                # a 2 s hold counts
    assert det.retained_samples() <= det.cap + 2 * det.n
    batch = detect_static_windows(s.samples)
    np.testing.assert_allclose([f['mean'] for f in found], batch.mean, atol=0.01)


def test_calibration_model_round_trip_and_inverse(tmp_path):
    s = session(1)
    w = detect_static_windows(s.samples)
    cal = calibrate(w.mean, G, 'ml', w.weights(5, 100), noise_std=w.noise_std)
    raw = cal.distort(G * random_directions(10, np.random.default_rng(2)))
    np.testing.assert_allclose(np.linalg.norm(cal.correct(raw), axis=1), G, atol=1e-12)
    path = tmp_path / 'cal.yaml'
    save_calibration(cal, path)
    back = load_calibration(path)
    np.testing.assert_allclose(back.T, cal.T)
    np.testing.assert_allclose(back.covariance, cal.covariance)
    assert 'bias_m_s2' in path.read_text() and 'version: 1' in path.read_text()
    cov = cal.acceleration_covariance()
    assert np.all(np.linalg.eigvalsh(cov) > 0)


@pytest.mark.parametrize('text', ['', 'format: other\n', 'format: accel_calib_ros/calibration\n'
                                  'version: 1\nT: [[1, 0, 0], [0, 1, 0], [0, 0, 1]]\n', '{{{'])
def test_bad_calibration_files_are_input_errors(tmp_path, text):
    path = tmp_path / 'bad.yaml'
    path.write_text(text)
    with pytest.raises(InputError):
        load_calibration(path)


def test_fresh_poses_are_corrected_to_the_noise_level():
    s = session(3, poses=40)
    w = detect_static_windows(s.samples)
    cal = calibrate(w.mean, G, 'ml', w.weights(5, 100))
    fresh = G * random_directions(100, np.random.default_rng(4))
    err = cal.correct(s.sensor.distort(fresh)) - fresh
    assert np.sqrt(np.mean(err ** 2)) < 0.01
    raw_err = s.sensor.distort(fresh) - fresh
    assert np.sqrt(np.mean(raw_err ** 2)) > 0.1


def test_thermal_tables_remove_temperature_drift():
    s = session(5, poses=120, effects=('temperature_bias', 'temperature_scale'),
                temperature=(10.0, 45.0))
    w = detect_static_windows(s.samples)
    plain = calibrate(w.mean, G, 'ml', w.weights(5, 100), temps=w.temp)
    thermal = calibrate(w.mean, G, 'ml', w.weights(5, 100), temps=w.temp, thermal=True)
    assert [b.status for b in thermal.thermal.bands].count('ok') >= 3
    rng = np.random.default_rng(6)
    fresh, temps = G * random_directions(200, rng), rng.uniform(12, 44, 200)
    raw = s.sensor.distort(fresh, temps)
    err_plain = np.sqrt(np.mean((plain.correct(raw, temps) - fresh) ** 2))
    err_thermal = np.sqrt(np.mean((thermal.correct(raw, temps) - fresh) ** 2))
    assert err_plain > 0.05
    assert err_thermal < 0.01
    # continuous across band edges
    edge = thermal.thermal.usable[1].low_c
    probe = np.array([[1.0, 2.0, 9.5]])
    below = thermal.thermal.drift(probe, edge - 1e-6)
    above = thermal.thermal.drift(probe, edge + 1e-6)
    np.testing.assert_allclose(below, above, atol=1e-6)


def test_sparse_band_is_reported_and_skipped():
    rng = np.random.default_rng(7)
    sensor = mpu9250_like(rng, effects=('temperature_bias',))
    u = random_directions(50, rng)
    temps = np.r_[rng.uniform(20, 29.9, 40), rng.uniform(30, 39.9, 10)]
    y = sensor.distort(G * u, temps)
    table = fit_thermal_table(y, temps, sensor.T, sensor.bias, G)
    status = {b.low_c: b.status for b in table.bands}
    assert status[20.0] == 'ok'
    assert status[30.0].startswith('too few windows') and '10 static windows' in status[30.0]
    np.testing.assert_allclose(table.drift(y[:1], 35.0), table.drift(y[:1], 29.0))


def test_degenerate_sessions_are_refused_with_a_reason():
    s = session(8, poses=3)
    w = detect_static_windows(s.samples)
    with pytest.raises(CalibrationError, match='orientations|observations'):
        calibrate(w.mean, G, 'ml', w.weights())
    same = np.repeat(w.mean[:1], 20, axis=0) + 0.001 * np.arange(60).reshape(20, 3)
    with pytest.raises(CalibrationError, match='distinct orientations'):
        calibrate(same, G, 'gn')


@pytest.mark.skipif(not peer_data.available('imu_tk'), reason='shared/data not present')
def test_imu_tk_scale_factors_agree_with_imu_tk_within_0_05_percent():
    samples = peer_data.imu_tk()
    w = detect_static_windows(samples)
    assert 36 <= len(w) <= 44              # imu_tk's own detector finds 38-42
    cal = calibrate(w.mean, peer_data.IMU_TK_GRAVITY, 'ml', w.weights(5, samples.rate_hz))
    ratio = cal.scale / peer_data.IMU_TK_REFERENCE['inverse_scale'] - 1
    assert np.all(np.abs(ratio) < 5e-4)
    res = gravity_residuals(cal, None, w.mean, peer_data.IMU_TK_GRAVITY)
    assert np.sqrt(np.mean(res ** 2)) < 0.005
