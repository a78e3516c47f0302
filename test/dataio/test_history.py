"""Per-sensor history: SQLite store, two writers at once, fit --history, history command."""

import json
import subprocess
import sys

from accel_calib_ros.cli import main
from accel_calib_ros.core.calibration import Calibration
from accel_calib_ros.core.errors import InputError
from accel_calib_ros.dataio.history import History
import numpy as np
import pytest


def _cal(scale=1.01, temps=(20.0, 30.0)):
    return Calibration(T=np.diag([scale, 0.99, 1.0]), bias=[0.1, -0.2, 0.3], method='ml',
                       observations=12, residual_rms=0.002, predicted_accuracy=0.004,
                       temperature_range_c=temps, gyro_bias=np.array([1e-3, -2e-3, 5e-4]))


def test_round_trip_and_a_window_is_kept_once(tmp_path):
    path = tmp_path / 'deep' / 'history.sqlite'
    rng = np.random.default_rng(0)
    means = rng.normal(0, 5, (5, 3))
    with History(path) as h:
        assert h.add_windows('imu0', means, [20, 21, np.nan, 23, 24], 200.0,
                             1.7e9 + np.arange(5), rng.normal(0, 1e-3, (5, 3))) == 5
        assert h.add_windows('imu0', means, 20.0, 200.0, 1.8e9) == 0        # same windows
        h.add_windows('imu1', means[:2], None, [100.0, 150.0], 1.7e9)
        h.add_calibration('imu0', _cal(1.01), time_s=1.7e9)
        h.add_calibration('imu0', _cal(1.02), time_s=1.8e9)
    with History(path) as h:
        assert h.sensors() == ['imu0', 'imu1']
        w = h.windows('imu0')
        np.testing.assert_allclose(w['mean'], means)
        assert np.isnan(w['temp'][2]) and w['temp'][4] == 24
        assert w['gyro_mean'].shape == (5, 3) and np.all(np.isfinite(w['gyro_mean']))
        assert np.all(np.isnan(h.windows('imu1')['gyro_mean']))
        cals = h.calibrations('imu0')
        assert [c['T'][0][0] for c in cals] == [1.01, 1.02]
        assert cals[0]['predicted_accuracy'] == 0.004 and cals[0]['windows'] == 12
        assert cals[0]['temperature_range_c'] == [20.0, 30.0]
        assert cals[0]['gyro_bias'] == [1e-3, -2e-3, 5e-4]
        assert len(h.calibrations()) == 2 and h.calibrations('nobody') == []


@pytest.mark.parametrize('problem', ['garbage', 'directory', 'nan', 'sensor'])
def test_bad_input_is_one_input_error(tmp_path, problem):
    path = tmp_path / 'h.sqlite'
    with pytest.raises(InputError):
        if problem == 'garbage':
            path.write_bytes(b'not a database at all' * 100)
            History(path)
        elif problem == 'directory':
            History(tmp_path)
        else:
            with History(path) as h:
                if problem == 'nan':
                    h.add_windows('imu0', [[np.nan, 0, 9.8]], 20.0, 100.0, 1.7e9)
                else:
                    h.add_windows('', [[0, 0, 9.8]], 20.0, 100.0, 1.7e9)


WRITER = """
import sys
import numpy as np
from accel_calib_ros.core.calibration import Calibration
from accel_calib_ros.dataio.history import History
path, name = sys.argv[1], sys.argv[2]
rng = np.random.default_rng(abs(hash(name)) % 2**32)
for k in range(40):
    with History(path) as h:
        h.add_windows('shared', rng.normal(0, 5, (5, 3)), 25.0, 100.0, 1.7e9 + k)
        h.add_calibration(name, Calibration(T=np.eye(3), bias=np.zeros(3)))
print('done')
"""


def test_two_processes_writing_at_once_lose_nothing(tmp_path):
    path = str(tmp_path / 'h.sqlite')
    History(path).close()
    procs = [subprocess.Popen([sys.executable, '-c', WRITER, path, name],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for name in ('a', 'b')]
    results = [p.communicate(timeout=120) for p in procs]
    for (out, err), p in zip(results, procs):
        assert p.returncode == 0 and out.strip() == 'done', err
    with History(path) as h:
        assert len(h.windows('shared')['mean']) == 2 * 40 * 5
        assert len(h.calibrations('a')) == 40 and len(h.calibrations('b')) == 40


def test_three_sessions_at_three_temperatures_fill_three_bands(tmp_path, capsys):
    db = tmp_path / 'history.sqlite'
    for k, temp in enumerate((15.0, 25.0, 35.0)):
        data = tmp_path / f'session{k}.csv'
        assert main(['simulate', '-o', str(data), '--poses', '13', '--temp', str(temp),
                     '--seed', '11', '--effects', 'temperature_bias']) == 0
        capsys.readouterr()
        code = main(['fit', str(data), '--thermal', '--history', str(db), '--sensor', 'imu0',
                     '--json'])
        out, err = capsys.readouterr()
        assert code == 0, err
        fit = json.loads(out)
        assert fit['observations'] == 13 * (k + 1)
        ok = [b for b in fit['thermal']['bands'] if b['status'] == 'ok']
        assert len(ok) == k + 1
    plot = tmp_path / 'drift.png'
    code = main(['history', '--db', str(db), '--sensor', 'imu0', '--plot', str(plot),
                 '--json'])
    out, err = capsys.readouterr()
    assert code == 0, err
    listing = json.loads(out)
    assert [s['temperature_bands_10c'] for s in listing['sensors']] == \
        [{'10': 13, '20': 13, '30': 13}]
    assert len(listing['calibrations']) == 3
    assert [c['temperature_range_c'][1] for c in listing['calibrations']] == \
        pytest.approx([15.0, 25.0, 35.0], abs=0.1)
    assert plot.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    assert main(['history', '--db', str(db)]) == 0
    assert 'imu0' in capsys.readouterr().out


def test_history_cli_refuses_bad_input(tmp_path, capsys):
    assert main(['history', '--db', str(tmp_path / 'missing.sqlite')]) == 2
    assert 'no history' in capsys.readouterr().err
    data = tmp_path / 's.csv'
    assert main(['simulate', '-o', str(data), '--poses', '12']) == 0
    assert main(['fit', str(data), '--history', str(tmp_path / 'h.sqlite')]) == 2
    assert '--sensor' in capsys.readouterr().err
    assert main(['fit', str(data), '--history', str(data), '--sensor', 'x']) == 2
