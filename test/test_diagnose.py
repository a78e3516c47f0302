"""Model-gap workflow: each hidden effect is named, null sessions name nothing."""

import json

from accel_calib_ros.cli import main
from accel_calib_ros.core.diagnose import diagnose, diagnose_windows
from accel_calib_ros.core.effects import EFFECTS
from accel_calib_ros.core.simulate import (
    G0, mpu9250_like, random_directions, simulate_session, simulate_static_windows,
    with_datasheet_effect)
import numpy as np
import pytest

HOLD_S = 3.5
N_WINDOWS = 60
COUNT = 250


def hump(t, low=10.0, high=45.0):
    """Temperature that rises and falls again, so it does not move with time."""
    return low + (high - low) * np.sin(np.pi * t / (N_WINDOWS * HOLD_S))


def hidden(effect, rng, scale=1.0):
    """Return a sensor with one effect at datasheet size and the baseline to use."""
    sensor = with_datasheet_effect(mpu9250_like(rng), effect, rng, scale)
    return sensor, 'gn' if effect == 'nonorthogonality' else 'ml'


def windows_of(sensor, rng, temperature):
    return simulate_static_windows(sensor, random_directions(N_WINDOWS, rng), rng, HOLD_S,
                                   COUNT, temperature=temperature)


@pytest.mark.parametrize('seed', [1, 2])
@pytest.mark.parametrize('effect', sorted(EFFECTS))
def test_each_hidden_effect_is_named_and_the_gap_closes(effect, seed):
    rng = np.random.default_rng(seed)
    sensor, baseline = hidden(effect, rng)
    temperature = 25.0 if effect == 'bias_drift' else hump
    result = diagnose_windows(windows_of(sensor, rng, temperature), baseline, replicates=10)
    assert result.missing_effects[:1] == [effect], result.text()
    assert result.gap_before > 2.0
    assert result.gap_after < 1.5
    assert result.explained


@pytest.mark.parametrize('seed', range(6))
@pytest.mark.parametrize('temperature', [25.0, hump], ids=['flat', 'varying'])
def test_null_sessions_name_nothing(temperature, seed):
    rng = np.random.default_rng(100 + seed)
    sensor = mpu9250_like(rng)
    result = diagnose_windows(windows_of(sensor, rng, temperature), 'ml', replicates=0)
    assert result.missing_effects == [], result.text()
    assert result.gap_before < 1.6


def test_magnitude_is_reported_in_physical_units():
    rng = np.random.default_rng(3)
    sensor, baseline = hidden('temperature_bias', rng)
    result = diagnose_windows(windows_of(sensor, rng, hump), baseline, replicates=0)
    step = result.steps[0]
    fitted = np.array(step['evidence']['params'])
    np.testing.assert_allclose(fitted, sensor.bias_tempco, atol=0.1e-3 * G0)
    assert 'mg/°C' in step['evidence']['magnitude']
    assert step['where'][0]['variable'] in ('temperature', 'time') or \
        'component' in step['where'][0]['variable']


def test_temperature_and_time_together_are_flagged_as_ambiguous():
    rng = np.random.default_rng(4)
    sensor, baseline = hidden('temperature_bias', rng)
    ramp = (lambda t: 10.0 + 35.0 * t / (N_WINDOWS * HOLD_S))
    result = diagnose_windows(windows_of(sensor, rng, ramp), baseline, replicates=0)
    assert result.missing_effects[0] == 'temperature_bias'
    assert any('bias_drift' in note and 'temperature' in note for note in result.ambiguities)


def test_end_to_end_on_samples_and_cli(tmp_path, capsys):
    rng = np.random.default_rng(5)
    sensor = mpu9250_like(rng, effects=('scale_nonlinearity',))
    sensor.nonlinearity = np.array([0.005, -0.005, 0.004])
    session = simulate_session(sensor, random_directions(50, rng), rng, hold_s=2.5,
                               move_s=1.0)
    result = diagnose(session.samples, 'ml', replicates=5)
    assert result.missing_effects == ['scale_nonlinearity'], result.text()

    from accel_calib_ros.dataio.recording import write_samples_csv
    path = tmp_path / 'session.csv'
    write_samples_csv(path, session.samples)
    report = tmp_path / 'report'
    assert main(['diagnose', str(path), '--baseline', 'ml', '--json', '--report',
                 str(report)]) == 0
    summary = json.loads(capsys.readouterr().out)
    for key in ('baseline', 'missing_effects', 'gap_before', 'gap_after', 'steps'):
        assert key in summary
    assert summary['missing_effects'] == ['scale_nonlinearity']
    step = summary['steps'][0]
    for key in ('effect', 'gap_before', 'gap_after', 'evidence', 'where'):
        assert key in step
    assert (report / 'report.md').exists() and (report / 'gap.png').stat().st_size > 1000
