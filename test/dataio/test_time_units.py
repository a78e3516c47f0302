"""Units of time: a t column in ms, us or ns is refused with a hint, or read with --time-unit."""

import json

from accel_calib_ros.cli import main
from accel_calib_ros.core.errors import InputError
from accel_calib_ros.dataio.recording import load_samples
from accel_calib_ros.dataio.time_units import check_time_spacing, PLAUSIBLE_RATE_HZ
import numpy as np
import pytest

SCALE = {'ms': 1e3, 'us': 1e6, 'ns': 1e9}


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope='module')
def session(tmp_path_factory):
    """Write a 24-pose session in seconds, and the same numbers with t in ms, us and ns."""
    folder = tmp_path_factory.mktemp('units')
    seconds = folder / 's.csv'
    assert main(['simulate', '-o', str(seconds), '--poses', '24', '--seed', '7']) == 0
    lines = seconds.read_text().splitlines()
    files = {'s': seconds}
    for unit, scale in SCALE.items():
        rows = []
        for line in lines[1:]:
            t, rest = line.split(',', 1)
            rows.append(f'{round(float(t) * scale)},{rest}')
        files[unit] = folder / f'{unit}.csv'
        files[unit].write_text('\n'.join([lines[0]] + rows) + '\n')
    return files


@pytest.mark.parametrize('unit', ['ms', 'us', 'ns'])
def test_another_unit_under_t_is_refused_with_the_unit_it_looks_like(capsys, session, unit):
    """Milliseconds under ``t`` gave 284 "windows" instead of 24, silently."""
    for command in ('fit', 'advise', 'allan', 'diagnose'):
        code, out, err = run(capsys, command, session[unit])
        assert code == 2 and err.count('\n') == 1, (command, err)
        assert f'--time-unit {unit}' in err and 'Hz' in err, err
    code, _, err = run(capsys, 'apply', session['s'].parent / 'nothing.yaml', session[unit],
                       '-o', session['s'].parent / 'x.csv')
    assert code == 2


@pytest.mark.parametrize('unit', ['ms', 'us', 'ns'])
def test_time_unit_reads_the_same_session(capsys, session, unit, tmp_path):
    code, out, err = run(capsys, 'fit', session['s'], '--json', '-o', tmp_path / 'c.yaml')
    assert code == 0, err
    reference = json.loads(out)
    code, out, err = run(capsys, 'fit', session[unit], '--json', '--time-unit', unit)
    assert code == 0, err
    fit = json.loads(out)
    assert fit['observations'] == reference['observations'] == 24
    np.testing.assert_allclose(fit['T'], reference['T'], atol=1e-4)
    code, _, err = run(capsys, 'apply', tmp_path / 'c.yaml', session[unit], '--time-unit', unit,
                       '-o', tmp_path / 'out.csv')
    assert code == 0, err
    t = np.genfromtxt(tmp_path / 'out.csv', delimiter=',', names=True)['t']
    assert abs(np.median(np.diff(t)) - 0.01) < 1e-6              # written back in seconds


def test_a_wrong_explicit_unit_is_refused_too(capsys, session):
    code, _, err = run(capsys, 'fit', session['s'], '--time-unit', 'ns')
    assert code == 2 and 'not an IMU rate' in err and 'give --time-unit s ' in err, err
    code, _, err = run(capsys, 'fit', session['s'], '--time-unit', 'hours')
    assert code == 2 and 'invalid choice' in err


def test_a_bag_has_its_unit_already(capsys, session, tmp_path):
    bag = tmp_path / 'b.mcap'
    assert run(capsys, 'simulate', '-o', bag, '--poses', '12', '--seed', '2')[0] == 0
    code, _, err = run(capsys, 'fit', bag, '--time-unit', 'ms')
    assert code == 2 and 'CSV files only' in err
    assert run(capsys, 'fit', bag, '--time-unit', 's')[0] == 0


def test_plausible_rates_and_coarse_stamps_pass(tmp_path):
    low, high = PLAUSIBLE_RATE_HZ
    for rate in (low, 10.0, 100.0, 1000.0, high):
        check_time_spacing('x.csv', np.arange(200) / rate)
    t = np.round(1.7e9 + np.arange(3000) * 0.01, -1)        # 10 s stamps, 100 Hz data
    check_time_spacing('x.csv', t)
    gap = np.r_[np.arange(500) * 0.01, 86400 + np.arange(500) * 0.01]   # one long pause
    check_time_spacing('x.csv', gap)
    for rate in (low / 3, high * 3):
        with pytest.raises(InputError, match='not an IMU rate'):
            check_time_spacing('x.csv', np.arange(200) / rate)
    check_time_spacing('x.csv', np.zeros(5))                    # one stamp: other checks say
    check_time_spacing('x.csv', np.array([1.0]))


def test_load_samples_scales_time(session):
    s = load_samples(session['ms'], time_unit='ms')
    reference = load_samples(session['s'])
    np.testing.assert_allclose(s.t, np.round(reference.t * 1e3) * 1e-3, atol=1e-12)
    with pytest.raises(InputError, match='unknown time unit'):
        load_samples(session['s'], time_unit='fortnights')
