"""The accel-calib command-line contract (interface.md §3)."""

import json
import os
import pathlib
import re
import subprocess
import sys

from accel_calib_ros.cli import main
from accel_calib_ros.dataio.calibration_file import load_calibration
from accel_calib_ros.sim.motion import random_directions, simulate_session
from accel_calib_ros.sim.sensor import mpu9250_like
import numpy as np
import peer_data
import pytest
import yaml

G = 9.80665


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope='module')
def session_csv(tmp_path_factory):
    folder = tmp_path_factory.mktemp('cli')
    path = folder / 'session.csv'
    assert main(['simulate', '-o', str(path), '--poses', '30', '--temp', '15', '40',
                 '--seed', '3', '--truth', str(folder / 'truth.yaml')]) == 0
    return path


def test_simulate_fit_apply_round_trip(capsys, session_csv, tmp_path):
    calib = tmp_path / 'calib.yaml'
    code, out, err = run(capsys, 'fit', session_csv, '--method', 'ml', '-o', calib, '--json')
    assert code == 0, err
    summary = json.loads(out)
    for key in ('method', 'T', 'bias', 'residual_rms', 'iterations', 'observations',
                'converged', 'seconds'):
        assert key in summary
    assert summary['observations'] == 30 and summary['converged']
    truth = yaml.safe_load((session_csv.parent / 'truth.yaml').read_text())
    np.testing.assert_allclose(summary['T'], truth['T'], atol=2e-3)
    np.testing.assert_allclose(summary['bias'], truth['bias_m_s2'], atol=0.02)
    assert summary['residual_rms'] < 0.01

    corrected = tmp_path / 'corrected.csv'
    code, out, err = run(capsys, 'apply', calib, session_csv, '-o', corrected)
    assert code == 0, err
    data = np.genfromtxt(corrected, delimiter=',', names=True)
    cal = load_calibration(calib)
    raw = np.genfromtxt(session_csv, delimiter=',', names=True)
    expect = cal.correct(np.column_stack([raw['ax'], raw['ay'], raw['az']]))
    np.testing.assert_allclose(np.column_stack([data['ax'], data['ay'], data['az']]),
                               expect, atol=1e-6)


def test_gn_is_diagonal_and_human_output_is_readable(capsys, session_csv):
    # The sensor has cross-axis terms the 6-parameter model cannot hold: the residual
    # shows it, the predicted accuracy is poor and the fit is refused by default.
    code, out, err = run(capsys, 'fit', session_csv, '--method', 'gn', '--json')
    summary = json.loads(out)
    assert code == 1 and not summary['accepted'] and summary['predicted_accuracy'] > 0.02
    assert 'predicted accuracy' in err and err.count('\n') == 1
    code, out, _ = run(capsys, 'fit', session_csv, '--method', 'gn', '--json',
                       '--max-predicted-error', '1')
    T = np.array(json.loads(out)['T'])
    assert code == 0 and np.all(T == np.diag(np.diag(T)))
    code, out, _ = run(capsys, 'fit', session_csv)
    assert code == 0 and 'residual RMS' in out and out.count('\n') > 4


def test_samples_mode_fits_every_row(capsys, tmp_path):
    rng = np.random.default_rng(1)
    u = random_directions(2000, rng)
    sensor = mpu9250_like(rng)
    raw = sensor.measure(G * u, rng)
    path = tmp_path / 'moving.csv'
    peer_data.to_spec_csv(type('S', (), {'t': np.arange(2000) / 100.0, 'accel': raw, 'temp': None,
                                         'gyro': None}), path)
    code, out, err = run(capsys, 'fit', path, '--mode', 'samples', '--json')
    assert code == 0, err
    summary = json.loads(out)
    assert summary['observations'] == 2000
    np.testing.assert_allclose(summary['T'], sensor.T, atol=3e-3)


def test_rosbag_input(capsys, tmp_path):
    bag = tmp_path / 'session.mcap'
    assert run(capsys, 'simulate', '-o', bag, '--poses', '14', '--hold', '2')[0] == 0
    code, out, err = run(capsys, 'fit', bag, '--json')
    assert code == 0, err
    assert json.loads(out)['observations'] == 14


def _write(path, header, rows):
    with open(path, 'w') as f:
        f.write(header + '\n')
        for row in rows:
            f.write(','.join(f'{v:.6f}' for v in row) + '\n')
    return path


def _text(path, text):
    path.write_text(text)
    return path


def _one_pose(tmp_path):
    rng = np.random.default_rng(2)
    t = np.arange(3000) / 100.0
    acc = np.array([0.1, 0.2, 9.8]) + 0.02 * rng.standard_normal((3000, 3))
    return _write(tmp_path / 'one_pose.csv', 't,ax,ay,az', np.column_stack([t, acc]))


def _motion_only(tmp_path):
    rng = np.random.default_rng(3)
    t = np.arange(3000) / 100.0
    acc = np.cumsum(rng.standard_normal((3000, 3)), axis=0) * 0.5
    return _write(tmp_path / 'motion.csv', 't,ax,ay,az', np.column_stack([t, acc]))


def _few_windows(tmp_path):
    rng = np.random.default_rng(4)
    s = simulate_session(mpu9250_like(rng), random_directions(5, rng), rng)
    return _write(tmp_path / 'few.csv', 't,ax,ay,az', np.column_stack([s.samples.t,
                                                                      s.samples.accel]))


def _nans(tmp_path):
    path = _one_pose(tmp_path)
    lines = path.read_text().splitlines()
    lines[10] = '0.09,nan,0.2,9.8'
    path.write_text('\n'.join(lines) + '\n')
    return path


BAD = {
    'empty': (lambda p: _write(p / 'empty.csv', '', []), 2, 'empty'),
    'header only': (lambda p: _write(p / 'hdr.csv', 't,ax,ay,az', []), 2, 'no data'),
    'missing column': (lambda p: _write(p / 'mc.csv', 't,ax,ay', [[0, 1, 2]]), 2, 'az'),
    'not a number': (lambda p: _text(p / 'nn.csv', 't,ax,ay,az\n0,1,2,x\n'), 2,
                     'line 2.*not a number'),
    'NaN': (_nans, 2, 'NaN'),
    'one pose': (_one_pose, 1, 'observations|orientations|pose'),
    'motion only': (_motion_only, 1, 'static|observations'),
    'too few windows': (_few_windows, 1, 'observations|poses'),
    'missing file': (lambda p: p / 'nothere.csv', 2, 'no such file|not found'),
    'wrong kind': (lambda p: _write(p / 'x.txt', 'hello', []), 2, '.csv'),
}


@pytest.mark.parametrize('case', sorted(BAD))
def test_bad_input_gives_one_line_and_writes_nothing(capsys, tmp_path, case):
    make, expected_code, words = BAD[case]
    data = make(tmp_path)
    out_file = tmp_path / 'calib.yaml'
    code, out, err = run(capsys, 'fit', data, '-o', out_file)
    assert code == expected_code, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and 'Traceback' not in err
    assert re.search(words, lines[0], re.IGNORECASE), lines[0]
    assert not out_file.exists()


def test_failed_fit_leaves_an_existing_calibration_untouched(capsys, tmp_path, session_csv):
    calib = tmp_path / 'calib.yaml'
    assert run(capsys, 'fit', session_csv, '-o', calib)[0] == 0
    before = calib.read_bytes()
    assert run(capsys, 'fit', _one_pose(tmp_path), '-o', calib)[0] == 1
    assert calib.read_bytes() == before


def test_usage_errors_exit_2(capsys, session_csv):
    assert run(capsys, 'fit', session_csv, '--method', 'nope')[0] == 2
    assert run(capsys, 'frobnicate')[0] == 2
    assert run(capsys, 'simulate', '-o', 'x.csv', '--effects', 'warp_drive')[0] == 2
    code, _, err = run(capsys, 'apply', session_csv, session_csv, '-o', 'x.csv')
    assert code == 2 and 'calibration' in err


def test_installed_console_script_runs(tmp_path):
    exe = os.path.join(os.path.dirname(sys.executable), 'accel-calib')
    if not os.path.exists(exe):
        pytest.skip('console script not installed in this environment')
    path = tmp_path / 's.csv'
    proc = subprocess.run([exe, 'simulate', '-o', str(path), '--poses', '12', '--json'],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)['poses'] == 12
    proc = subprocess.run([exe, 'fit', str(tmp_path / 'missing.csv')], capture_output=True,
                          text=True, timeout=60)
    assert proc.returncode == 2 and proc.stderr.count('\n') == 1


def test_six_face_session_gn_is_charged_ml_refuses_and_json_is_strict(capsys, tmp_path):
    data = tmp_path / 'faces.csv'
    truth = tmp_path / 'truth.yaml'
    assert run(capsys, 'simulate', '-o', data, '--poses', 'faces', '--orthogonal',
               '--truth', truth)[0] == 0
    # Six faces cannot show whether the axes are orthogonal: gn is charged the datasheet
    # cross-axis bound and refused at the default limit, saying so (it was
    # accepted with a 0.003 m/s² prediction before, whatever the sensor).
    code, out, err = run(capsys, 'fit', data, '--method', 'gn', '--json')
    summary = json.loads(out, parse_constant=lambda c: pytest.fail(f'{c} in JSON'))
    assert code == 1 and not summary['accepted'] and err.count('\n') == 1
    assert 'orthogonal' in err and 'datasheet' in err and '--method ml' in err
    assert summary['cross_axis_allowance']['terms']['xy']['measured'] is False
    code, out, err = run(capsys, 'fit', data, '--method', 'gn', '--json',
                         '--max-predicted-error', '0.2')
    assert code == 0, err
    summary = json.loads(out, parse_constant=lambda c: pytest.fail(f'{c} in JSON'))
    assert 0.05 < summary['predicted_accuracy'] < 0.2 and 'cross-axis' in err
    true = yaml.safe_load(truth.read_text())
    np.testing.assert_allclose(np.diag(summary['T']), np.diag(true['T']), atol=1e-3)
    np.testing.assert_allclose(summary['bias'], true['bias_m_s2'], atol=0.01)
    assert summary['observations'] == 6
    code, _, err = run(capsys, 'fit', data, '--method', 'ml')
    assert code == 1 and 'orientations' in err


# -- calibrations a user can stand behind ---------------------------------------------------------

def _cap_directions(max_deg, n, rng):
    """Return ``n`` gravity directions within ``max_deg`` of +z (a tilt-only session)."""
    v = rng.normal(size=(n, 3))
    v[:, 2] = 0
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    ang = np.radians(rng.uniform(0, max_deg, n))
    return np.column_stack([v[:, :2] * np.sin(ang)[:, None], np.cos(ang)])


def _session_file(path, directions, seed=0, hold=2.0, **kw):
    rng = np.random.default_rng(seed)
    sensor = mpu9250_like(rng)
    s = simulate_session(sensor, directions, rng, hold_s=hold, **kw)
    peer_data.to_spec_csv(s.samples, path)
    return path, sensor, s


@pytest.mark.parametrize('max_deg', [25, 60])
def test_tilt_only_session_is_refused_naming_the_missing_poses(capsys, tmp_path, session_csv,
                                                               max_deg):
    calib = tmp_path / 'calib.yaml'
    assert run(capsys, 'fit', session_csv, '-o', calib)[0] == 0
    before = calib.read_bytes()
    data, _, _ = _session_file(tmp_path / 'tilt.csv',
                               _cap_directions(max_deg, 30, np.random.default_rng(max_deg)))
    for method in ('ml', 'gn', 'ellipsoid'):
        code, out, err = run(capsys, 'fit', data, '--method', method, '-o', calib, '--json')
        assert code == 1, (method, err)
        assert err.count('\n') == 1 and 'z axis down' in err, err
        assert calib.read_bytes() == before
        summary = json.loads(out)
        assert not summary['accepted'] and 'z axis down' in summary['refusal']


def test_predicted_accuracy_in_json_file_and_summary(capsys, tmp_path, session_csv):
    calib = tmp_path / 'calib.yaml'
    code, out, err = run(capsys, 'fit', session_csv, '-o', calib, '--json')
    assert code == 0, err
    summary = json.loads(out)
    acc = summary['predicted_accuracy']
    assert 0 < acc <= 0.02 and summary['accepted'] and summary['refusal'] is None
    assert load_calibration(calib).predicted_accuracy == pytest.approx(acc)
    truth = yaml.safe_load((session_csv.parent / 'truth.yaml').read_text())
    T, b = np.array(truth['T']), np.array(truth['bias_m_s2'])
    u = random_directions(500, np.random.default_rng(1))
    cal = load_calibration(calib)
    true_err = np.sqrt(np.mean(np.sum((cal.correct(G * u @ T.T + b) - G * u) ** 2, axis=1)))
    assert true_err < 3 * acc                          # the prediction is not optimistic
    code, out, _ = run(capsys, 'fit', session_csv)
    assert 'predicted accuracy' in out
    # A stricter limit than the fit reaches refuses it, naming poses, nothing written.
    strict = tmp_path / 'strict.yaml'
    code, out, err = run(capsys, 'fit', session_csv, '-o', strict, '--json',
                         '--max-predicted-error', str(acc / 3))
    assert code == 1 and not strict.exists() and 'axis' in err
    assert json.loads(out)['accepted'] is False


def test_samples_mode_on_one_pose_is_refused(capsys, tmp_path):
    out_file = tmp_path / 'c.yaml'
    for method in ('ml', 'gn', 'ellipsoid'):
        code, _, err = run(capsys, 'fit', _one_pose(tmp_path), '--mode', 'samples',
                           '--method', method, '-o', out_file)
        assert code == 1 and not out_file.exists(), err


def test_unconverged_fit_is_refused_unless_forced(capsys, tmp_path, session_csv, monkeypatch):
    from accel_calib_ros.core.accelerometer import fit as core_cal
    real = core_cal.fit_ml

    def never_converges(*a, **kw):
        fit = real(*a, **kw)
        fit.converged = False
        return fit
    monkeypatch.setattr(core_cal, 'fit_ml', never_converges)
    calib = tmp_path / 'calib.yaml'
    code, out, err = run(capsys, 'fit', session_csv, '-o', calib, '--json')
    assert code == 1 and not calib.exists() and 'converge' in err
    assert json.loads(out)['converged'] is False
    code, out, err = run(capsys, 'fit', session_csv, '-o', calib, '--json', '--force')
    assert code == 0 and calib.exists() and 'WARNING' in err and 'NOT converge' in err
    assert json.loads(out)['converged'] is False
    assert load_calibration(calib).converged is False


def test_outlier_windows_are_dropped_and_reported(capsys, tmp_path):
    rng = np.random.default_rng(11)
    directions = random_directions(24, rng)
    path, sensor, s = _session_file(tmp_path / 's.csv', directions, seed=11, hold=3.0)
    samples = s.samples
    holds = [np.flatnonzero((s.pose == k) & (np.linalg.norm(s.samples.gyro - sensor.gyro_bias,
                                                            axis=1) < 0.02)) for k in (5, 12)]
    # Hold 5: a sustained push (0.4 m/s²) the accelerometer scatter cannot see.
    a = holds[0][len(holds[0]) // 4: -len(holds[0]) // 4]
    samples.accel[a] += np.array([0.25, -0.2, 0.25])
    # Hold 12: a slow turn the gyro shows (5 °/s about x) over the whole hold.
    b = holds[1]
    samples.gyro[b] += np.array([np.radians(5.0), 0, 0])
    peer_data.to_spec_csv(samples, path)
    code, out, err = run(capsys, 'fit', path, '--json')
    assert code == 0, err
    summary = json.loads(out)
    dropped = summary['dropped_windows']
    starts = [d['t_start'] for d in dropped]
    assert any(samples.t[a[0]] - 1 <= t <= samples.t[a[-1]] for t in starts), dropped
    assert any('rotating' in d['reason'] for d in dropped), dropped
    assert len(dropped) <= 3
    assert summary['predicted_accuracy'] <= 0.02
    code, out, _ = run(capsys, 'fit', path)
    assert code == 0 and 'dropped' in out


def test_gyro_bias_is_estimated_and_apply_subtracts_it(capsys, tmp_path):
    data, truth = tmp_path / 's.csv', tmp_path / 'truth.yaml'
    assert run(capsys, 'simulate', '-o', data, '--poses', '16', '--seed', '4',
               '--truth', truth)[0] == 0
    calib = tmp_path / 'c.yaml'
    code, out, err = run(capsys, 'fit', data, '-o', calib, '--json')
    assert code == 0, err
    true_bias = np.array(yaml.safe_load(truth.read_text())['gyro_bias_rad_s'])
    assert np.abs(true_bias).max() > 1e-3
    np.testing.assert_allclose(json.loads(out)['gyro_bias'], true_bias, atol=3e-4)
    corrected = tmp_path / 'corr.csv'
    assert run(capsys, 'apply', calib, data, '-o', corrected)[0] == 0
    raw = np.genfromtxt(data, delimiter=',', names=True)
    fixed = np.genfromtxt(corrected, delimiter=',', names=True)
    # The gyro's scale and misalignment are fitted too: raw - bias = T fixed.
    gyro_T = json.loads(out)['gyro_T']
    assert gyro_T is not None and np.abs(np.array(gyro_T) - np.eye(3)).max() < 0.01
    raw_rate = np.column_stack([raw[a] for a in ('gx', 'gy', 'gz')])
    fixed_rate = np.column_stack([fixed[a] for a in ('gx', 'gy', 'gz')])
    np.testing.assert_allclose(raw_rate - json.loads(out)['gyro_bias'],
                               fixed_rate @ np.array(gyro_T).T, atol=1e-7)


def test_thermal_fit_reports_band_usability_and_range(capsys, tmp_path, session_csv):
    calib = tmp_path / 'c.yaml'
    code, out, err = run(capsys, 'fit', session_csv, '--thermal', '-o', calib, '--json',
                         '--band-width', '5')
    summary = json.loads(out)
    bands = summary['thermal']['bands']
    assert bands and all('usable' in b and 'why_not' in b for b in bands)
    assert any(not b['usable'] and 'windows' in b['why_not'] for b in bands)
    lo, hi = summary['temperature_range_c']
    assert 14 < lo < hi < 41
    if code == 0:
        assert load_calibration(calib).temperature_range_c == pytest.approx((lo, hi))
    code, out, _ = run(capsys, 'fit', session_csv, '--thermal', '--band-width', '5')
    assert 'not usable' in out and 'temperature range' in out


BAD_ARGS = [
    ['fit', '{data}', '--min-window-s', 'nan'], ['fit', '{data}', '--threshold-factor', 'inf'],
    ['fit', '{data}', '--max-weight-s', '-1'], ['fit', '{data}', '--gravity', '0'],
    ['fit', '{data}', '--gravity', 'nan'], ['fit', '{data}', '--band-width', '1e400'],
    ['fit', '{data}', '--max-predicted-error', 'nan'], ['fit', '{data}', '-o', '{data}'],
    ['fit', '{data}', '-o', '{dir}'], ['fit', '{dir}'], ['fit', '{nonutf8}'], ['fit', '{huge}'],
    ['apply', '{calib}', '{data}', '-o', '{calib}'],
    ['apply', '{calib}', '{data}', '-o', '{data}'],
    ['apply', '{nonutf8}', '{data}', '-o', '{out}'], ['apply', '{dir}', '{data}', '-o', '{out}'],
    ['apply', '{data}', '{data}', '-o', '{out}'], ['apply', '{calib}', '{huge}', '-o', '{out}'],
    ['simulate', '-o', '{out}', '--hold', 'inf'], ['simulate', '-o', '{out}', '--seed', '-1'],
    ['simulate', '-o', '{out}', '--seed', '1.5'], ['simulate', '-o', '{out}', '--temp', 'nan'],
    ['simulate', '-o', '{out}', '--temp', '1', '2', '3'],
    ['simulate', '-o', '{out}', '--poses', 'garbage'],
    ['simulate', '-o', '{out}', '--poses', 'sunxu:'], ['simulate', '-o', '{out}', '--poses', '0'],
    ['simulate', '-o', '{out}', '--poses', '99999', '--rate', '100000'],
    ['simulate', '-o', '{out}', '--rate', '0'], ['simulate', '-o', '{out}', '--gravity', '-9'],
    ['simulate', '-o', '{out}', '--truth', '{out}'], ['simulate', '-o', '{dir}'],
    ['diagnose', '{data}', '--min-window-s', 'nan'], ['diagnose', '{data}', '--gravity', 'inf'],
    ['diagnose', '{data}', '--report', '{data}'],
    ['simulate-device', '--seed', '-1'], ['simulate-device', '--temp', 'nan'],
    ['simulate-device', '--count', '-5', '--poses', 'random'],
    ['simulate-device', '--temp-ramp', 'nan', '3'], ['simulate-device', '--t0-us', '-1'],
    ['simulate-device', '--rate', '1e9']]


@pytest.fixture(scope='module')
def bad_files(tmp_path_factory, session_csv):
    folder = tmp_path_factory.mktemp('bad')
    calib = folder / 'c.yaml'
    assert main(['fit', str(session_csv), '-o', str(calib)]) == 0
    (folder / 'nonutf8.csv').write_bytes(b't,ax,ay,az\n0,\xff\xfe,1,2\n')
    huge = folder / 'huge.csv'
    huge.write_text('t,ax,ay,az\n0,0,0,9.8\n0.01,1e308,0,9.8\n0.02,0,0,9.8\n')
    (folder / 'dir').mkdir()
    return {'data': str(session_csv), 'calib': str(calib), 'nonutf8': str(folder / 'nonutf8.csv'),
            'huge': str(huge), 'dir': str(folder / 'dir'), 'out': str(folder / 'out.csv')}


@pytest.mark.parametrize('argv', BAD_ARGS, ids=lambda a: ' '.join(a))
def test_bad_arguments_exit_2_with_one_line_and_touch_nothing(capsys, bad_files, argv):
    before = {k: pathlib.Path(v).read_bytes() for k, v in bad_files.items() if os.path.isfile(v)}
    code, out, err = run(capsys, *[a.format(**bad_files) for a in argv])
    assert code == 2, err
    assert err.count('\n') == 1 and 'Traceback' not in err and 'internal error' not in err, err
    after = {k: pathlib.Path(v).read_bytes() for k, v in bad_files.items() if os.path.isfile(v)}
    assert after == before
    assert not os.path.exists(bad_files['out'])


def test_apply_refuses_rather_than_writing_non_finite(capsys, tmp_path, bad_files):
    from accel_calib_ros.dataio.calibration_file import calibration_to_dict
    d = calibration_to_dict(load_calibration(bad_files['calib']))
    d['T'] = [[1e6, 0, 0], [0, 1e6, 0], [0, 0, 1e6]]    # valid file, absurd scale: fine
    cal_path = tmp_path / 'big.yaml'
    cal_path.write_text(yaml.safe_dump(d))
    out_file = tmp_path / 'o.csv'
    code, _, err = run(capsys, 'apply', cal_path, bad_files['data'], '-o', out_file)
    if code == 0:
        data = np.genfromtxt(out_file, delimiter=',', names=True)
        assert all(np.all(np.isfinite(data[n])) for n in data.dtype.names)
    else:
        assert code in (1, 2) and not out_file.exists()


def test_gyro_in_the_wrong_unit_does_not_cost_the_calibration(capsys, tmp_path):
    path, _, s = _session_file(tmp_path / 'deg.csv', random_directions(16,
                               np.random.default_rng(6)), seed=6)
    s.samples.gyro = np.degrees(s.samples.gyro) + 200.0          # deg/s with a big offset
    peer_data.to_spec_csv(s.samples, path)
    calib = tmp_path / 'c.yaml'
    code, out, err = run(capsys, 'fit', path, '-o', calib, '--json')
    assert code == 0 and 'rad/s' in err and json.loads(out)['gyro_bias'] is None
    assert load_calibration(calib).gyro_bias is None


def test_apply_uses_the_units_the_fit_recorded_and_refuses_another(capsys, session_csv,
                                                                   tmp_path):
    """T absorbed the fit's counts conversion; only the same one is right."""
    raw = np.genfromtxt(session_csv, delimiter=',', names=True)
    counts = tmp_path / 'counts.csv'
    rows = np.column_stack([raw['t'], np.column_stack([raw['ax'], raw['ay'], raw['az']])
                            / G * 16384.0])
    np.savetxt(counts, rows, delimiter=',', header='t,ax,ay,az', comments='', fmt='%.6f')
    calib = tmp_path / 'c.yaml'
    code, _, err = run(capsys, 'fit', counts, '--counts-per-g', '16384', '-o', calib)
    assert code == 0, err
    assert load_calibration(calib).input_units == {'accel': 'counts', 'counts_per_g': 16384.0,
                                                   'counts_offset': 0.0}
    plain, same = tmp_path / 'plain.csv', tmp_path / 'same.csv'
    code, out, err = run(capsys, 'apply', calib, counts, '-o', plain, '--json')
    assert code == 0, err
    assert json.loads(out)['input_units']['counts_per_g'] == 16384.0
    assert run(capsys, 'apply', calib, counts, '-o', same, '--range', '2')[0] == 0
    assert plain.read_bytes() == same.read_bytes()
    for wrong in (['--counts-per-g', '8192'], ['--units', 'm/s2'], ['--counts-offset', '1']):
        code, _, err = run(capsys, 'apply', calib, counts, '-o', tmp_path / 'x.csv', *wrong)
        assert code == 2 and err.count('\n') == 1, err
        assert 'fitted on readings in counts at 16384 counts per g' in err
        assert not (tmp_path / 'x.csv').exists()


def test_fit_starts_without_numpy_masked_arrays(session_csv):
    """np.median, np.quantile and np.unique import numpy.ma (10 ms of start-up)."""
    code = ('import sys\nimport numpy\nlazy = "numpy.ma" not in sys.modules\n'
            'from accel_calib_ros.cli import main\n'
            f'main(["fit", {str(session_csv)!r}])\n'
            'print(sorted(m for m in ("numpy.ma", "scipy", "shutil", "json") if m in '
            'sys.modules and (lazy or m != "numpy.ma")), file=sys.stderr)')
    done = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stderr.strip().splitlines()[-1] == '[]', done.stderr
