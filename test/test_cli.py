"""The accel-calib command-line contract (spec section 3)."""

import json
import os
import re
import subprocess
import sys

from accel_calib_ros.cli import main
from accel_calib_ros.core.simulate import mpu9250_like, random_directions, simulate_session
from accel_calib_ros.dataio.calibration_file import load_calibration
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
    code, out, _ = run(capsys, 'fit', session_csv, '--method', 'gn', '--json')
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


def test_six_face_session_gn_fits_ml_refuses_and_json_is_strict(capsys, tmp_path):
    data = tmp_path / 'faces.csv'
    truth = tmp_path / 'truth.yaml'
    assert run(capsys, 'simulate', '-o', data, '--poses', 'faces', '--orthogonal',
               '--truth', truth)[0] == 0
    code, out, err = run(capsys, 'fit', data, '--method', 'gn', '--json')
    assert code == 0, err
    summary = json.loads(out, parse_constant=lambda c: pytest.fail(f'{c} in JSON'))
    true = yaml.safe_load(truth.read_text())
    np.testing.assert_allclose(np.diag(summary['T']), np.diag(true['T']), atol=1e-3)
    np.testing.assert_allclose(summary['bias'], true['bias_m_s2'], atol=0.01)
    assert summary['observations'] == 6
    code, _, err = run(capsys, 'fit', data, '--method', 'ml')
    assert code == 1 and 'orientations' in err
