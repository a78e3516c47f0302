"""
The whole IMU beside the accelerometer: file, fit, apply, recordings, advise.

Simulated sessions with gyroscope scale/misalignment errors and an AK8963-like
magnetometer go through the command line; what comes out is compared with the truth the
simulator wrote, within what the fit itself predicts.
"""

import json
import time

from accel_calib_ros.cli import main
from accel_calib_ros.core.calibration import Calibration, MagnetometerPart
from accel_calib_ros.core.collector import ImuCollector
from accel_calib_ros.core.errors import CalibrationError, InputError
from accel_calib_ros.core.magnetometer.fit import canonical
from accel_calib_ros.core.samples import Samples
from accel_calib_ros.dataio.calibration_file import (calibration_from_dict, calibration_to_dict,
                                                     load_calibration, save_calibration)
from accel_calib_ros.dataio.recording import load_samples, write_bag, write_samples_csv
from accel_calib_ros.sim import motion as sim_motion
from accel_calib_ros.sim import sensor as sim
import numpy as np
import pytest
from scipy.spatial.transform import Rotation
import yaml


def run(capsys, *argv):
    """Run accel-calib in-process; return (exit status, stdout, stderr)."""
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def imu_calibration():
    """Return a plausible calibration with a gyroscope and a magnetometer part."""
    R = Rotation.from_rotvec([0.02, -0.01, 0.03]).as_matrix()
    T = np.array([[0.97, 0.01, -0.02], [0.0, 1.02, 0.015], [0.0, 0.0, 1.01]])
    return Calibration(
        T=np.diag([1.01, 0.99, 1.02]), bias=[0.1, -0.2, 0.3], gyro_bias=[0.01, -0.02, 0.03],
        gyro_T=[[1.02, 0.01, -0.015], [0.012, 0.98, 0.004], [-0.02, 0.007, 1.01]],
        gyro_predicted_accuracy=4e-4,
        magnetometer=MagnetometerPart(T=T, hard_iron_uT=[12.0, -25.0, 7.5], R=R,
                                      field_uT=48.0, dip_deg=61.0, predicted_accuracy=0.03,
                                      noise_std_uT=0.4))


# -- the calibration file ---------------------------------------------------------------------

def test_file_round_trip_keeps_both_parts_and_one_gyro_bias(tmp_path):
    cal = imu_calibration()
    path = tmp_path / 'c.yaml'
    save_calibration(cal, path)
    text = yaml.safe_load(path.read_text())
    assert text['gyro']['bias'] == text['gyro_bias_rad_s']            # one bias, twice
    back = load_calibration(path)
    np.testing.assert_array_equal(back.gyro_T, cal.gyro_T)
    np.testing.assert_array_equal(back.gyro_bias, cal.gyro_bias)
    assert back.gyro_predicted_accuracy == cal.gyro_predicted_accuracy
    m, n = back.magnetometer, cal.magnetometer
    for name in ('T', 'hard_iron_uT', 'R'):
        np.testing.assert_array_equal(getattr(m, name), getattr(n, name))
    assert (m.field_uT, m.dip_deg, m.predicted_accuracy, m.noise_std_uT) == \
        (n.field_uT, n.dip_deg, n.predicted_accuracy, n.noise_std_uT)
    # the corrections: T⁻¹ (raw - bias) and Rᵀ T⁻¹ (raw - hard iron), NaN rows kept
    raw = np.array([[0.5, -0.3, 1.2], [0.0, 0.0, 0.0]])
    np.testing.assert_allclose(back.correct_gyro(raw) @ cal.gyro_T.T, raw - cal.gyro_bias,
                               atol=1e-15)
    field = np.array([[20.0, 5.0, -40.0], [np.nan] * 3])
    out = back.correct_mag(field)
    np.testing.assert_allclose(n.T @ n.R @ out[0] + n.hard_iron_uT, field[0], atol=1e-12)
    assert np.all(np.isnan(out[1]))


def test_a_file_without_the_parts_loads_as_before(tmp_path):
    cal = Calibration(T=np.eye(3), bias=np.zeros(3), gyro_bias=[0.01, 0.0, 0.0])
    d = calibration_to_dict(cal)
    assert 'gyro' not in d and 'magnetometer' not in d
    back = calibration_from_dict(d)
    assert back.gyro_T is None and back.magnetometer is None
    np.testing.assert_allclose(back.correct_gyro([[1.0, 1.0, 1.0]]), [[0.99, 1.0, 1.0]])
    np.testing.assert_array_equal(back.correct_mag([[1.0, 2.0, 3.0]]), [[1.0, 2.0, 3.0]])
    # gyro.bias alone is the bias
    d = calibration_to_dict(imu_calibration())
    del d['gyro_bias_rad_s']
    np.testing.assert_array_equal(calibration_from_dict(d).gyro_bias, [0.01, -0.02, 0.03])


def _broken(change):
    d = calibration_to_dict(imu_calibration())
    change(d)
    return d


BAD_PARTS = {
    'two gyro biases': (lambda d: d.update(gyro_bias_rad_s=[0.0, 0.0, 0.0]), 'one gyro bias'),
    'gyro T singular': (lambda d: d['gyro'].update(T=[[1, 0, 0], [1, 0, 0], [0, 0, 1]]),
                        'diagonal|determinant|ill-conditioned'),
    'gyro T scale': (lambda d: d['gyro'].update(T=[[3, 0, 0], [0, 1, 0], [0, 0, 1]]),
                     'diagonal of gyro.T'),
    'gyro cross axis': (lambda d: d['gyro'].update(T=[[1, 0.7, 0], [0, 1, 0], [0, 0, 1]]),
                        'cross-axis'),
    'gyro reflection': (lambda d: d['gyro'].update(T=[[1, 0, 0], [0, 1, 0], [0, 0, -1]]),
                        'diagonal of gyro.T'),
    'gyro T shape': (lambda d: d['gyro'].update(T=[[1, 0], [0, 1]]), 'gyro.T'),
    'gyro bias huge': (lambda d: (d['gyro'].update(bias=[5.0, 0, 0]),
                                  d.pop('gyro_bias_rad_s')), 'gyro.bias'),
    'gyro accuracy': (lambda d: d['gyro'].update(predicted_accuracy=-1.0), 'predicted_acc'),
    'gyro NaN': (lambda d: d['gyro'].update(T=[[float('nan'), 0, 0], [0, 1, 0], [0, 0, 1]]),
                 'finite'),
    'mag R not a rotation': (lambda d: d['magnetometer'].update(
        R=[[1.1, 0, 0], [0, 1, 0], [0, 0, 1]]), 'rotation'),
    'mag R reflection': (lambda d: d['magnetometer'].update(
        R=[[1, 0, 0], [0, 1, 0], [0, 0, -1]]), 'rotation'),
    'mag field': (lambda d: d['magnetometer'].update(field_uT=0.0), 'field_uT'),
    'mag dip': (lambda d: d['magnetometer'].update(dip_deg=120.0), 'dip_deg'),
    'mag hard iron': (lambda d: d['magnetometer'].update(hard_iron_uT=[1e5, 0, 0]),
                      'hard_iron'),
    'mag T': (lambda d: d['magnetometer'].update(T=[[1, 0, 0], [0, 1, 0], [0, 0, 1e-3]]),
              'magnetometer.T'),
    'mag missing key': (lambda d: d['magnetometer'].pop('R'), 'magnetometer.R'),
    'mag not a mapping': (lambda d: d.update(magnetometer=[1, 2]), 'magnetometer'),
}


@pytest.mark.parametrize('case', sorted(BAD_PARTS))
def test_loader_refuses_implausible_parts_with_one_line(case):
    change, words = BAD_PARTS[case]
    with pytest.raises(InputError, match=words) as err:
        calibration_from_dict(_broken(change))
    assert '\n' not in str(err.value)


def test_writer_refuses_what_the_loader_would_and_leaves_the_file(tmp_path):
    path = tmp_path / 'c.yaml'
    save_calibration(imu_calibration(), path)
    before = path.read_bytes()
    cal = imu_calibration()
    cal.magnetometer.R = np.diag([1.0, 1.0, -1.0])
    with pytest.raises(CalibrationError, match='rotation'):
        save_calibration(cal, path)
    assert path.read_bytes() == before


# -- fit, apply, simulate through the command line -------------------------------------------

@pytest.fixture(scope='module')
def imu_session(tmp_path_factory):
    """Simulate a hand-held session with every IMU error, once: return (csv, truth)."""
    folder = tmp_path_factory.mktemp('imu')
    data, truth = folder / 's.csv', folder / 'truth.yaml'
    assert main(['simulate', '-o', str(data), '--poses', '24', '--seed', '5', '--gyro-errors',
                 '--magnetometer', '--tremor', '0.3', '--truth', str(truth)]) == 0
    return data, yaml.safe_load(truth.read_text())


def _rate_error(T_fit, T_true):
    """RMS relative rate error over directions when T_fit corrects a gyro whose T is T_true."""
    A = np.linalg.solve(T_fit, T_true) - np.eye(3)
    return float(np.sqrt(np.sum(A ** 2) / 3.0))


def test_fit_calibrates_all_three_sensors_within_their_predicted_accuracy(
        capsys, tmp_path, imu_session):
    data, truth = imu_session
    calib = tmp_path / 'c.yaml'
    code, out, err = run(capsys, 'fit', data, '-o', calib, '--json')
    assert code == 0, err
    d = json.loads(out)
    assert {s: d['sensors'][s]['status'] for s in d['sensors']} == {
        'accelerometer': 'calibrated', 'gyroscope': 'calibrated', 'magnetometer': 'calibrated'}
    # gyroscope: the relative rate error left, against the predicted one
    T_true = np.array(truth['gyro_T'])
    raw_error = _rate_error(np.eye(3), T_true)
    error = _rate_error(np.array(d['gyro_T']), T_true)
    assert raw_error > 0.01 and error < 3 * d['gyro_predicted_accuracy'] < 0.005
    np.testing.assert_allclose(d['gyro_bias'], truth['gyro_bias_rad_s'], atol=2e-4)
    # magnetometer: in the fit's convention (det T = 1, the field scaled to match)
    m = truth['magnetometer']
    T, R, field_uT = canonical(m['T'], m['R'], truth['earth_field']['field_uT'])
    np.testing.assert_allclose(d['mag_field_uT'], field_uT, rtol=2e-3)
    np.testing.assert_allclose(d['mag_T'], T, atol=3e-3)
    np.testing.assert_allclose(d['mag_hard_iron_uT'], m['hard_iron_uT'], atol=0.1)
    angle = Rotation.from_matrix(np.array(d['mag_R']) @ R.T).magnitude()
    assert np.degrees(angle) < 0.2
    assert abs(d['mag_dip_deg'] - truth['earth_field']['dip_deg']) < 0.1
    assert 0 < d['mag_predicted_accuracy'] < 0.2
    # the file carries both parts; apply uses them
    cal = load_calibration(calib)
    np.testing.assert_allclose(cal.gyro_T, d['gyro_T'])
    np.testing.assert_allclose(cal.magnetometer.R, d['mag_R'])
    corrected = tmp_path / 'corr.csv'
    code, out, err = run(capsys, 'apply', calib, data, '-o', corrected, '--json')
    assert code == 0, err
    summary = json.loads(out)
    assert summary['gyro_corrected'] == 'bias, scale and misalignment'
    assert summary['magnetometer_corrected'] is True
    raw, fixed = load_samples(data), load_samples(corrected)
    np.testing.assert_allclose(fixed.gyro, cal.correct_gyro(raw.gyro), atol=1e-8)
    np.testing.assert_allclose(fixed.mag, cal.correct_mag(raw.mag), atol=1e-6)
    # the corrected field has the fitted magnitude wherever the sensor points
    norm = np.linalg.norm(fixed.mag[fixed.mag_rows], axis=1)
    assert abs(np.median(norm) - d['mag_field_uT']) < 0.1
    # human output: one line per sensor
    code, out, err = run(capsys, 'fit', data)
    assert code == 0
    lines = out.splitlines()
    assert any(x.startswith('accelerometer: calibrated') for x in lines)
    assert any(x.startswith('gyroscope: calibrated, predicted accuracy') for x in lines)
    assert any(x.startswith('magnetometer: calibrated, predicted accuracy') for x in lines)


def test_absent_sensors_are_null_and_the_accelerometer_is_written(capsys, tmp_path):
    data, calib = tmp_path / 's.csv', tmp_path / 'c.yaml'
    rng = np.random.default_rng(3)
    session = sim_motion.simulate_session(sim.mpu9250_like(rng),
                                          sim_motion.random_directions(14, rng), rng)
    s = session.samples
    write_samples_csv(data, Samples(s.t, s.accel, s.temp))            # no gyro, no mag
    code, out, err = run(capsys, 'fit', data, '-o', calib, '--json')
    assert code == 0 and 'warning' not in err, err
    d = json.loads(out)
    for key in ('gyro_T', 'gyro_predicted_accuracy', 'mag_T', 'mag_hard_iron_uT', 'mag_R',
                'mag_field_uT', 'mag_dip_deg', 'mag_predicted_accuracy', 'gyro_bias'):
        assert d[key] is None, key
    assert d['sensors']['gyroscope']['status'] == 'absent'
    assert 'gx gy gz' in d['sensors']['gyroscope']['reason']
    assert d['sensors']['magnetometer']['status'] == 'absent'
    cal = load_calibration(calib)
    assert cal.gyro_T is None and cal.magnetometer is None


def _one_axis_session(seed):
    """Return a session whose poses are reached by turning about x and y only (never z)."""
    rng = np.random.default_rng(seed)
    poses = [Rotation.identity()]
    for k in range(17):
        axis = np.eye(3)[k % 2] * rng.choice([-1.0, 1.0]) * rng.uniform(50, 100)
        poses.append(poses[-1] * Rotation.from_rotvec(np.radians(axis)))
    sensor = sim.with_gyro_errors(sim.mpu9250_like(rng), rng)
    sensor.magnetometer = sim.ak8963_like(rng)
    return sim_motion.simulate_session(sensor, Rotation.concatenate(poses), rng).samples


def test_missing_rotation_axis_and_coverage_are_warnings_not_failures(capsys, tmp_path):
    data, calib = tmp_path / 's.csv', tmp_path / 'c.yaml'
    s = _one_axis_session(8)
    mag = np.full(s.mag.shape, np.nan)                 # the magnetometer saw one direction
    mag[::10] = [20.0, -5.0, 30.0] + np.random.default_rng(1).normal(0, 0.4, mag[::10].shape)
    write_samples_csv(data, Samples(s.t, s.accel, s.temp, s.gyro, mag))
    code, out, err = run(capsys, 'fit', data, '-o', calib, '--json')
    assert code == 0, err
    d = json.loads(out)
    assert d['sensors']['accelerometer']['status'] == 'calibrated'
    gyro = d['sensors']['gyroscope']
    assert gyro['status'] == 'insufficient' and gyro['missing_axes'] == ['z']
    assert 'no turn about the z axis' in gyro['reason'] and 'from x axis up to y axis up' \
        in gyro['reason']
    assert d['gyro_T'] is None and d['gyro_bias'] is not None      # the bias still counts
    mag = d['sensors']['magnetometer']
    assert mag['status'] == 'insufficient' and 'of the sphere' in mag['reason']
    assert d['mag_T'] is None
    assert 'gyroscope not calibrated (insufficient): no turn about the z axis' in err
    cal = load_calibration(calib)
    assert cal.gyro_T is None and cal.magnetometer is None and cal.gyro_bias is not None
    # advise says the same, in its own keys
    code, out, err = run(capsys, 'advise', data, '--json')
    a = json.loads(out)
    assert a['gyroscope']['status'] == 'insufficient' and a['gyroscope']['missing_axes'] == ['z']
    assert 'turn about z: from x axis up to y axis up' in a['gyroscope']['advice']
    assert a['magnetometer']['status'] == 'insufficient' and a['magnetometer']['coverage'] < 0.25


def test_limits_refuse_only_that_sensor(capsys, tmp_path, imu_session):
    data, _ = imu_session
    calib = tmp_path / 'c.yaml'
    code, out, err = run(capsys, 'fit', data, '-o', calib, '--json', '--max-gyro-error', '1e-6',
                         '--max-mag-error', '1e-4')
    assert code == 0, err
    d = json.loads(out)
    assert d['sensors']['gyroscope']['status'] == 'refused'
    assert '--max-gyro-error' in d['sensors']['gyroscope']['reason']
    assert d['sensors']['magnetometer']['status'] == 'refused'
    assert '--max-mag-error' in d['sensors']['magnetometer']['reason']
    assert d['gyro_T'] is None and d['mag_T'] is None and d['accepted']
    cal = load_calibration(calib)
    assert cal.gyro_T is None and cal.magnetometer is None


def test_apply_passes_mx_my_mz_through_without_a_magnetometer_part(capsys, tmp_path,
                                                                   imu_session):
    data, _ = imu_session
    calib, corrected = tmp_path / 'c.yaml', tmp_path / 'corr.csv'
    save_calibration(Calibration(T=np.eye(3), bias=np.zeros(3)), calib)
    code, out, err = run(capsys, 'apply', calib, data, '-o', corrected)
    assert code == 0, err
    assert 'mx my mz as recorded' in out
    raw, fixed = load_samples(data), load_samples(corrected)
    np.testing.assert_array_equal(np.isnan(fixed.mag), np.isnan(raw.mag))
    np.testing.assert_allclose(fixed.mag, raw.mag, atol=1e-6)


def test_simulate_truth_has_the_gyro_and_magnetometer(imu_session):
    _, truth = imu_session
    assert np.abs(np.array(truth['gyro_T']) - np.eye(3)).max() > 1e-3
    assert set(truth['magnetometer']) >= {'T', 'hard_iron_uT', 'R', 'as_fitted'}
    assert truth['earth_field'] == {'field_uT': 48.0, 'dip_deg': 60.0}


# -- recordings: mx my mz ----------------------------------------------------------------------

def _with_mag(n=40, every=3, t0=1.0):
    mag = np.full((n, 3), np.nan)
    mag[::every] = 40.0 + np.arange(3 * len(mag[::every])).reshape(-1, 3)
    return Samples(t0 + 0.01 * np.arange(n), np.tile([0.0, 0.0, 9.8], (n, 1)), np.full(n, 25.0),
                   np.zeros((n, 3)), mag)


def test_csv_mag_columns_round_trip_with_empty_cells(tmp_path):
    s = _with_mag()
    path = tmp_path / 'm.csv'
    write_samples_csv(path, s)
    lines = path.read_text().splitlines()
    assert lines[0] == 't,ax,ay,az,temp,gx,gy,gz,mx,my,mz'
    assert lines[2].endswith(',,,') and not lines[1].endswith(',')
    back = load_samples(path)
    np.testing.assert_array_equal(back.mag_rows, s.mag_rows)
    np.testing.assert_allclose(back.mag, s.mag)


@pytest.mark.parametrize('text, words', [
    ('t,ax,ay,az,mx,my,mz\n0,0,0,9.8,1,,3\n', 'partly empty on line'),
    ('t,ax,ay,az,mx,my\n0,0,0,9.8,1,2\n', 'mx, my, mz or none'),
    ('t,ax,ay,az,mx,my,mz\n0,0,0,9.8,1,2,x\n', "column 'mz' holds 'x'"),
    ('t,ax,ay,az,mx,my,mz\n0,0,0,9.8,1,2,inf\n', 'magnetic field'),
])
def test_csv_mag_problems_are_one_line(tmp_path, text, words):
    path = tmp_path / 'bad.csv'
    path.write_text(text)
    with pytest.raises(InputError, match=words) as err:
        load_samples(path)
    assert '\n' not in str(err.value)


def test_bag_mag_round_trip_in_tesla_and_matching_by_time(tmp_path):
    pytest.importorskip('rosbags')
    s = _with_mag()
    path = tmp_path / 'm.mcap'
    write_bag(path, s)
    back = load_samples(path)
    np.testing.assert_array_equal(back.mag_rows, s.mag_rows)
    np.testing.assert_allclose(back.mag, s.mag, rtol=1e-12)
    # A magnetometer on its own clock: the nearest Imu sample within half a period.
    from accel_calib_ros.dataio.rosbag_io import _match_mag
    imu_ns = (np.arange(10) * 10_000_000).astype(np.int64)          # 100 Hz

    class Reader:
        pass

    import accel_calib_ros.dataio.rosbag_io as rosbag_io
    stamps = np.array([3_000_000, 21_000_000, 18_000_000, 500_000_000], np.int64)
    values = np.array([[1.0, 2, 3], [4, 5, 6], [7, 8, 9], [1, 1, 1]]) * 1e-6
    original = rosbag_io._read_topic
    rosbag_io._read_topic = lambda *a: (stamps, stamps, values)
    try:
        mag = _match_mag(Reader(), '/imu/mag', imu_ns, imu_ns, False, 'x')
    finally:
        rosbag_io._read_topic = original
    np.testing.assert_allclose(mag[0], [1, 2, 3])                    # 3 ms from sample 0
    np.testing.assert_allclose(mag[2], [4, 5, 6])                    # 1 ms beats 2 ms
    assert np.isnan(mag[1]).all() and np.isnan(mag[3:]).all()       # 500 ms: outside


def test_bag_picks_the_mag_topic_or_asks_for_one(tmp_path):
    pytest.importorskip('rosbags')
    s = _with_mag()
    one = tmp_path / 'a.mcap'
    write_bag(one, s, mag_topic='/left/mag')
    assert load_samples(one).mag_rows.sum() == s.mag_rows.sum()
    with pytest.raises(InputError, match='not in the bag'):
        load_samples(one, mag_topic='/right/mag')
    assert load_samples(one, mag_topic='left/mag').mag is not None


# -- the node's buffers --------------------------------------------------------------------

def test_collector_ring_and_decimation_stay_bounded_and_ordered():
    c = ImuCollector(max_samples=100, max_mag_samples=50)
    rows = np.column_stack([np.arange(1000) * 0.01, np.zeros((1000, 3)),
                            np.ones((1000, 3)), np.full(1000, 25.0)])
    for k in range(0, 1000, 7):
        for j in range(k, min(k + 7, 1000), 2):
            c.add_mag(rows[j, 0], [j, 0.0, 1.0])
        c.add_samples(rows[k:k + 7])
    raw = c.raw_samples()
    np.testing.assert_allclose(raw.t, rows[-100:, 0])                # the last 100, in order
    assert len(c.mag) <= 50 and c.stride > 1
    kept = c.mag[:, 1]
    assert np.all(np.diff(kept) > 0) and kept[0] == 0 and kept[-1] > 900   # whole session
    windows = c.windows_in(raw.t, [{'t_start': 9.2, 't_stop': 9.5},
                                   {'t_start': 1.0, 't_stop': 2.0}])     # 2nd: overwritten
    assert list(windows.start) == [20] and list(windows.stop) == [51]
    c.clear()
    assert c.raw_samples() is None and c.mag_samples() is None


def test_guide_session_says_the_turns_and_the_sphere_and_stores_both_parts():
    from accel_calib_ros.cli.guide import _imu_of
    from accel_calib_ros.cli.guide_session import GuideSession
    from accel_calib_ros.cli.guide_sources import SimulatedSource
    source = SimulatedSource(100.0, speed=500.0, seed=1, magnetometer=True)
    session = GuideSession(100.0)
    deadline = time.monotonic() + 60.0
    while not session.enough:
        assert time.monotonic() < deadline, 'the simulated person never got there'
        t, a, temp = source.read(session)
        gyro, mag = _imu_of(source, len(t))
        session.update(t, a, temp, gyro, mag)
    status = session.imu_status
    assert status['gyroscope']['status'] == 'ok' and status['gyroscope']['missing_axes'] == []
    assert status['magnetometer']['coverage'] >= 0.25 and 'of the sphere' in \
        status['magnetometer']['advice']
    from accel_calib_ros.session.settings import DEFAULT_SETTINGS, GUIDE
    outcome = session.finish(DEFAULT_SETTINGS.replace(max_gyro_error=0.01,
                                                      max_mag_error=1.0, words=GUIDE))
    cal, gyro, mag = outcome.calibration, outcome.gyro, outcome.magnetometer
    assert gyro.calibrated and mag.calibrated, (gyro.reason, mag.reason)
    left = np.linalg.solve(cal.gyro_T, source.sensor.gyro_T) - np.eye(3)
    assert np.sqrt(np.sum(left ** 2) / 3) < 3 * cal.gyro_predicted_accuracy
    np.testing.assert_allclose(cal.magnetometer.hard_iron_uT,
                               source.sensor.magnetometer.hard_iron, atol=1.0)


def test_wrong_units_are_named_not_fitted(capsys, tmp_path, imu_session):
    data, _ = imu_session
    s = load_samples(data)
    wrong = tmp_path / 'wrong.csv'
    write_samples_csv(wrong, Samples(s.t, s.accel, s.temp, np.degrees(s.gyro), s.mag * 1000))
    code, out, err = run(capsys, 'fit', wrong, '-o', tmp_path / 'c.yaml', '--json')
    assert code == 0, err
    sensors = json.loads(out)['sensors']
    assert sensors['gyroscope']['status'] == 'refused'
    assert 'are gx gy gz in rad/s?' in sensors['gyroscope']['reason']
    assert sensors['magnetometer']['status'] == 'refused'
    assert 'are mx my mz in µT?' in sensors['magnetometer']['reason']
