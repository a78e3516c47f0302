"""
Thermal calibration of one still pose through the command line: fit, apply, diagnose.

A simulated chamber cycle (cool, heat, cool) of one unit held still: ``fit --thermal
--calibration`` on one leg, ``apply`` on the whole run, the error of the other legs against
a cubic in the reported temperature fitted on the same leg (PX4's model); the refusals with
what to record; ``diagnose --calibration`` naming the heating/cooling effect.
"""

import json
import os

from accel_calib_ros.cli import main
from accel_calib_ros.core.calibration import Calibration
from accel_calib_ros.dataio.calibration_file import load_calibration, save_calibration
from accel_calib_ros.dataio.recording import load_samples, write_samples_csv
from accel_calib_ros.sim.chamber import ChamberProgramme, simulate_still, thermal_unit
import numpy as np
import pytest

G = 9.80665


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def _write_cycle(folder, name, hysteresis_mg, seed, rate_hz=5.0):
    rng = np.random.default_rng(seed)
    programme = ChamberProgramme(rates_c_min=3.0, hold_s=600.0)
    sensor = thermal_unit(rng, hysteresis_mg=hysteresis_mg)
    s = simulate_still(sensor, [0.0, 0.0, 1.0], rng, programme.duration_s, rate_hz=rate_hz,
                       temperature=programme).samples
    leg = programme.leg_of(s.t)
    write_samples_csv(str(folder / f'{name}.csv'), s)
    for k in range(3):
        sel = leg == k
        write_samples_csv(str(folder / f'{name}_leg{k}.csv'),
                          type(s)(s.t[sel], s.accel[sel], s.temp[sel], s.gyro[sel]))
    save_calibration(Calibration(T=sensor.T, bias=sensor.bias, temperature_range_c=(24.0, 26.0),
                                 gyro_bias=sensor.gyro_bias), str(folder / f'{name}_cal.yaml'))
    return sensor, leg


@pytest.fixture(scope='module')
def cycles(tmp_path_factory):
    folder = tmp_path_factory.mktemp('thermal')
    return folder, {'hyst': _write_cycle(folder, 'hyst', 10.0, 21),
                    'null': _write_cycle(folder, 'null', 0.0, 22)}


def _held_out(folder, name, leg, k, out_yaml, capsys):
    """Return (ours, cubic) held-out RMS per axis, mg, of the legs other than ``k``."""
    corrected = folder / f'{name}_corr{k}.csv'
    code, _, err = run(capsys, 'apply', out_yaml, folder / f'{name}.csv', '-o', corrected)
    assert code == 0, err
    raw, fixed = load_samples(str(folder / f'{name}.csv')), load_samples(str(corrected))
    fit = leg == k
    ours = fixed.accel[~fit] - fixed.accel[fit].mean(axis=0)
    X = np.vander(raw.temp - 25.0, 4)
    coef = np.linalg.lstsq(X[fit], raw.accel[fit], rcond=None)[0]
    cubic = raw.accel[~fit] - X[~fit] @ coef
    rms = [1000.0 * np.sqrt(np.mean(e ** 2, axis=0)) / G for e in (ours, cubic)]
    return rms


@pytest.mark.parametrize('k', [1, 2])
def test_one_leg_predicts_the_others_better_than_a_cubic(capsys, cycles, tmp_path, k):
    folder, sims = cycles
    sensor, leg = sims['hyst']
    out_yaml = tmp_path / 'out.yaml'
    code, out, err = run(capsys, 'fit', folder / f'hyst_leg{k}.csv', '--thermal',
                         '--calibration', folder / 'hyst_cal.yaml', '-o', out_yaml, '--json')
    assert code == 0, err
    summary = json.loads(out)
    assert summary['accepted'] and summary['hysteresis'] is not None
    assert 'temperature_rate' in summary['model_gap']['missing_effects']
    assert summary['hysteresis']['tau_s'] == pytest.approx(sensor.gradient_tau_s, rel=0.3)
    for row in summary['predicted_accuracy_by_temperature']:
        assert row['total_m_s2'] >= row['thermal_m_s2'] > 0
    ours, cubic = _held_out(folder, 'hyst', leg, k, out_yaml, capsys)
    assert np.all(ours <= 1.05 * cubic + 0.02), (ours, cubic)
    worst = int(np.argmax(np.abs(sensor.bias_gradient)))
    assert ours[worst] <= 0.8 * cubic[worst], (ours, cubic)
    cal = load_calibration(out_yaml)
    assert cal.thermal.hysteresis is not None and cal.thermal.source == 'still'
    np.testing.assert_array_equal(cal.T, load_calibration(folder / 'hyst_cal.yaml').T)


def test_a_null_leg_names_nothing_and_is_no_worse_than_a_cubic(capsys, cycles, tmp_path):
    folder, sims = cycles
    _, leg = sims['null']
    out_yaml = tmp_path / 'out.yaml'
    code, out, err = run(capsys, 'fit', folder / 'null_leg1.csv', '--thermal',
                         '--calibration', folder / 'null_cal.yaml', '-o', out_yaml, '--json')
    assert code == 0, err
    summary = json.loads(out)
    assert summary['hysteresis'] is None
    assert not set(summary['model_gap']['missing_effects']) & {'temperature_rate',
                                                               'temperature_lag'}
    ours, cubic = _held_out(folder, 'null', leg, 1, out_yaml, capsys)
    assert np.all(ours <= 1.05 * cubic + 0.02), (ours, cubic)


def test_output_may_replace_the_calibration_a_refusal_leaves_it_untouched(capsys, cycles,
                                                                          tmp_path):
    folder, _ = cycles
    calib = tmp_path / 'calib.yaml'
    calib.write_bytes((folder / 'hyst_cal.yaml').read_bytes())
    before = calib.read_bytes()
    short = tmp_path / 'short.csv'
    s = load_samples(str(folder / 'hyst_leg1.csv'))
    sel = s.t < s.t[0] + 60.0
    write_samples_csv(str(short), type(s)(s.t[sel], s.accel[sel], s.temp[sel], s.gyro[sel]))
    code, _, err = run(capsys, 'fit', short, '--thermal', '--calibration', calib, '-o', calib)
    assert code == 1 and 'spans only' in err and 'warms up' in err
    assert calib.read_bytes() == before
    code, _, err = run(capsys, 'fit', folder / 'hyst_leg1.csv', '--thermal', '--calibration',
                       calib, '-o', calib)
    assert code == 0, err
    assert load_calibration(calib).thermal is not None
    code, _, err = run(capsys, 'fit', folder / 'hyst_leg1.csv', '--thermal', '--calibration',
                       calib, '-o', folder / 'hyst_leg1.csv')
    assert code == 2 and 'destroy the input' in err
    assert len(err.strip().splitlines()) == 1


def test_without_a_temperature_column_or_a_calibration(capsys, cycles, tmp_path):
    folder, _ = cycles
    s = load_samples(str(folder / 'hyst_leg1.csv'))
    bare = tmp_path / 'bare.csv'
    write_samples_csv(str(bare), type(s)(s.t, s.accel))
    code, _, err = run(capsys, 'fit', bare, '--thermal', '--calibration',
                       folder / 'hyst_cal.yaml', '-o', tmp_path / 'o.yaml')
    assert code == 1 and 'no temperature column' in err
    code, _, err = run(capsys, 'fit', folder / 'hyst_leg1.csv', '--thermal')
    assert code == 1 and 'add --calibration' in err
    code, _, err = run(capsys, 'fit', folder / 'hyst_leg1.csv', '--calibration',
                       folder / 'hyst_cal.yaml')
    assert code == 2 and '--thermal' in err


@pytest.mark.parametrize('argv', [
    ('fit', '{data}', '--min-span', '3', '-o', '{out}.yaml'),
    ('fit', '{data}', '--thermal', '--hysteresis', 'off', '-o', '{out}.yaml'),
    ('simulate', '--hysteresis', '5', '-o', '{out}.csv'),
    ('simulate', '--board-tau', '30', '-o', '{out}.csv'),
    ('simulate', '--up', 'x', '-o', '{out}.csv')])
def test_an_option_of_the_other_mode_is_refused_not_ignored(capsys, cycles, tmp_path, argv):
    """A chamber or one-pose option outside its mode would do nothing: one line, exit 2."""
    folder, _ = cycles
    out = tmp_path / 'o'
    code, _, err = run(capsys, *(a.format(data=folder / 'hyst_leg1.csv', out=out) for a in argv))
    flag = next(a for a in argv if a.startswith('--') and a != '--thermal')
    assert code == 2 and err.count('\n') == 1 and f'{flag} acts only with' in err
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize('every', [5, 10])
def test_a_logger_s_averaged_output_at_one_hertz_and_slower(capsys, cycles, tmp_path, every):
    folder, sims = cycles
    s = load_samples(str(folder / 'hyst_leg2.csv'))
    n = len(s.t) // every * every

    def mean(x):
        return x[:n].reshape(-1, every, *x.shape[1:]).mean(axis=1)
    logger = tmp_path / 'logger.csv'
    write_samples_csv(str(logger), type(s)(mean(s.t), mean(s.accel), mean(s.temp)))
    code, out, err = run(capsys, 'fit', logger, '--thermal', '--calibration',
                         folder / 'hyst_cal.yaml', '-o', tmp_path / 'o.yaml', '--json')
    assert code == 0, err
    summary = json.loads(out)
    assert summary['rate_hz'] == pytest.approx(5.0 / every, rel=0.01)
    assert summary['hysteresis'] is not None
    # Without its temperature, a recording slower than 1 Hz is taken for milliseconds.
    bare = tmp_path / 'bare.csv'
    write_samples_csv(str(bare), type(s)(mean(s.t), mean(s.accel)))
    code, _, err = run(capsys, 'fit', bare)
    assert (code == 2 and 'not an IMU rate' in err) if every == 10 else code != 2


def test_health_corrects_with_the_hysteresis_term_as_the_node_does(capsys, tmp_path):
    """Regression: ``health`` left the heating/cooling term out: 'recalibrate' on a cycle."""
    _write_cycle(tmp_path, 'fast', 10.0, 21, rate_hz=25.0)
    cal = tmp_path / 'fast_cal.yaml'
    verdicts = {}
    for mode in ('auto', 'off'):
        out = tmp_path / f'{mode}.yaml'
        code, _, err = run(capsys, 'fit', tmp_path / 'fast.csv', '--thermal', '--calibration',
                           cal, '--hysteresis', mode, '-o', out)
        assert code == 0, err
        code, text, err = run(capsys, 'health', out, tmp_path / 'fast.csv', '--json')
        verdicts[mode] = (code, json.loads(text))
    code, body = verdicts['auto']
    assert code == 0 and body['status'] == 'ok' and body['checks'] >= 20
    code, body = verdicts['off']                      # the term is what makes it fit
    assert code == 1 and body['failed_checks'] > body['checks'] // 4


def test_apply_says_when_the_data_leave_the_calibrated_range(capsys, cycles, tmp_path):
    folder, _ = cycles
    out_yaml = tmp_path / 'out.yaml'
    code, _, err = run(capsys, 'fit', folder / 'hyst_leg0.csv', '--thermal', '--calibration',
                       folder / 'hyst_cal.yaml', '-o', out_yaml)
    assert code == 0, err
    code, out, err = run(capsys, 'apply', out_yaml, folder / 'hyst.csv', '-o',
                         tmp_path / 'c.csv', '--json')
    assert code == 0
    summary = json.loads(out)
    assert summary['samples_outside_temperature_range'] > 0
    assert 'outside the calibrated temperature range' in err and 'extrapolation' in err
    assert summary['hysteresis_applied'] is True
    low, high = summary['calibrated_range_c']
    assert high < 30.0 and summary['temperature_range_seen_c'][1] > 70.0


def test_diagnose_names_the_heating_cooling_effect_and_reports_it(capsys, cycles, tmp_path):
    folder, _ = cycles
    report = tmp_path / 'report'
    code, out, err = run(capsys, 'diagnose', folder / 'hyst.csv', '--calibration',
                         folder / 'hyst_cal.yaml', '--json', '--report', report)
    assert code == 0, err
    summary = json.loads(out)
    assert summary['missing_effects'][:1] == ['temperature_rate']
    assert summary['hysteresis_named'] == ['temperature_rate']
    held = summary['held_out_legs']['heating_to_cooling']
    assert held['with_effects']['gap'] < 0.5 * held['baseline']['gap']
    assert sorted(os.listdir(report)) == ['held_out.png', 'hysteresis.png', 'offsets.png',
                                          'report.md']
    code, out, err = run(capsys, 'diagnose', folder / 'null.csv', '--calibration',
                         folder / 'null_cal.yaml', '--json')
    assert code == 0, err
    assert json.loads(out)['missing_effects'] == []
