"""``accel-calib health CALIB DATA``: 0 healthy, 1 recalibrate (with why), 2 bad input."""

import json

from accel_calib_ros.cli import main
from accel_calib_ros.cli.common import MAX_MESSAGE
from accel_calib_ros.core.samples import Samples
from accel_calib_ros.dataio.calibration_file import save_calibration
from accel_calib_ros.dataio.csv_write import write_samples_csv
from accel_calib_ros.sim import field_stream as F
import numpy as np
import pytest

MG = 9.80665e-3
HOSTILE = {
    'first field 200 KiB': 't' * 200_000 + ',ax,ay,az\n0,0,0,9.8\n',
    'no newline at all': 'x' * 300_000,
    'json pretty': '{\n  "t": [0, 1],\n  "ax": [0, 0]\n}',
    'quote never closed': 't,ax,ay,az\n"0,0,0,9.8\n' + '1,0,0,9.8\n' * 1000,
    'nul bytes': 't,ax,ay,az\n0,0\x00,0,9.8\n',
    'control characters': 't,ax,ay,az\n\x1b[2J\x1b]0;owned\x07,0,0,9.8\n',
}
"""Hostile files (as test/dataio/test_file_inputs.py has them)."""


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def _write(path, rig, rng, events, periods=4, columns='all', units=1.0):
    poses = [F.random_pose(rng, 40) for _ in range(3)]
    segs = [F.move(poses[2], poses[0], 2.0)]
    for k in range(periods):
        segs += [F.still(poses[k % 3], 5.0), F.move(poses[k % 3], poses[(k + 1) % 3], 3.0)]
    ch = list(F.stream(rig, segs, events, rng, chunk_s=30.0))

    def cat(key):
        return np.concatenate([c[key] for c in ch])
    full = columns == 'all'
    write_samples_csv(path, Samples(cat('t'), cat('accel') / units, cat('temp') if full else None,
                                    cat('gyro') if full else None, cat('mag') if full else None))
    return path


@pytest.fixture(scope='module')
def files(tmp_path_factory):
    folder = tmp_path_factory.mktemp('health')
    rng = np.random.default_rng(21)
    rig = F.field_rig(rng)
    cal = folder / 'cal.yaml'
    save_calibration(rig.calibration, cal)
    out = {'cal': cal,
           'ok': _write(folder / 'ok.csv', rig, rng, F.Events(gyro_change=np.radians([.3, 0, 0]))),
           'knock': _write(folder / 'knock.csv', rig, rng,
                           F.Events(knocks=[(10.0, 6 * MG * np.array([1.0, -1.0, 1.0]))])),
           'hot': _write(folder / 'hot.csv', rig, rng, F.Events(temperature=50.0), periods=2),
           'bare': _write(folder / 'bare.csv', rig, rng, F.Events(), columns='accel'),
           'in_g': _write(folder / 'g.csv', rig, rng, F.Events(), units=9.80665)}
    moving = folder / 'moving.csv'
    p, q = F.random_pose(rng, 30), F.random_pose(rng, 30)
    c = next(F.stream(rig, [F.move(p, q, 10.0)], F.Events(), rng, chunk_s=10.0))
    write_samples_csv(moving, Samples(c['t'], c['accel'], c['temp'], c['gyro'], c['mag']))
    out['moving'] = moving
    return out


def test_a_good_calibration_is_healthy_exit_0_one_json_object(capsys, files):
    code, out, err = run(capsys, 'health', files['cal'], files['ok'], '--json')
    assert code == 0, err
    summary = json.loads(out)                    # exactly one object
    assert summary['healthy'] is True and summary['recalibrate'] is False
    assert summary['checks'] >= 3 and summary['failed_checks'] == 0
    assert summary['final']['level'] == 'ok'
    assert summary['gyro_bias_left']['periods_used'] >= 3
    assert abs(summary['gyro_bias_left']['estimate_deg_s'][0] - 0.3) < 0.05


def test_human_words_name_the_verdict(capsys, files):
    code, out, _ = run(capsys, 'health', files['cal'], files['ok'])
    assert code == 0 and out.startswith('healthy') and 'gyro: bias left at rest' in out


def test_a_knock_says_recalibrate_with_size_and_cause_exit_1(capsys, files):
    code, out, err = run(capsys, 'health', files['cal'], files['knock'])
    assert code == 1, err
    assert out.startswith('STALE: recalibrate')
    assert 'likely cause: a bias shift of about' in out and ' mg at ' in out
    code, out, _ = run(capsys, 'health', files['cal'], files['knock'], '--json')
    summary = json.loads(out)
    assert code == 1 and summary['recalibrate'] and summary['first_failure']['time_s'] > 10.0
    assert abs(summary['first_failure']['disagreement_mg']) > 3.0


def test_a_temperature_outside_the_range_is_a_warning_with_its_size(capsys, files):
    # A thermal calibration 15 degC out of range: its own tables' slope says how much the
    # temperature could explain; the data agree within that, so a warning, not stale.
    code, out, _ = run(capsys, 'health', files['cal'], files['hot'], '--json')
    summary = json.loads(out)
    assert code == 0 and summary['status'] == 'warn' and not summary['recalibrate']
    assert summary['cause'].startswith('temperature outside the calibrated range')
    assert summary['final']['temperature_outside_c'] == pytest.approx(15.0, abs=0.1)
    assert max(summary['final']['temperature_explains_mg']) > 10.0
    assert 'thermal tables' in summary['final']['tempco_source']
    code, out, _ = run(capsys, 'health', files['cal'], files['hot'])
    assert out.startswith('healthy, with a warning') and 'could explain up to' in out


def test_acceleration_only_and_other_units(capsys, files):
    code, out, err = run(capsys, 'health', files['cal'], files['bare'], '--json')
    assert code == 0, err
    assert json.loads(out)['gyro_bias_left']['periods_used'] == 0
    code, _, err = run(capsys, 'health', files['cal'], files['in_g'], '--units', 'g')
    assert code == 0, err
    code, _, err = run(capsys, 'health', files['cal'], files['in_g'])
    assert code == 2 and '--units' in err


def test_no_still_period_is_bad_input_in_one_line(capsys, files):
    code, out, err = run(capsys, 'health', files['cal'], files['moving'])
    assert code == 2 and out == ''
    assert err.count('\n') == 1 and 'no still period' in err and 'record the sensor' in err


@pytest.mark.parametrize('argv', [
    ['--false-alarm', 'nan'], ['--false-alarm', '0'], ['--allowance-mg', '-1'],
    ['--min-still-s', 'inf'], ['--temperature-margin', 'x']])
def test_careless_options_are_refused(capsys, files, argv):
    code, _, err = run(capsys, 'health', files['cal'], files['ok'], *argv)
    assert code == 2 and err.count('\n') == 1


def test_bad_calibration_files_are_one_line(capsys, files, tmp_path):
    bad = tmp_path / 'bad.yaml'
    bad.write_text('format: nonsense\n')
    for cal in (bad, tmp_path / 'missing.yaml', files['ok']):
        code, out, err = run(capsys, 'health', cal, files['ok'])
        assert code == 2 and out == '' and err.count('\n') == 1
        assert 'Traceback' not in err and 'internal error' not in err


@pytest.mark.parametrize('content', sorted(HOSTILE))
def test_hostile_recordings_are_one_short_line(tmp_path, capsys, files, content):
    path = tmp_path / 'in.csv'
    path.write_text(HOSTILE[content])
    code, out, err = run(capsys, 'health', files['cal'], path)
    assert code == 2 and out == ''
    assert err.count('\n') == 1 and len(err) <= MAX_MESSAGE + 1
