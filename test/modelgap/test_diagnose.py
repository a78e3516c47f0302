"""Model-gap workflow: each hidden effect is named, null sessions name nothing."""

import json
import pathlib

from accel_calib_ros.cli import main
from accel_calib_ros.core.errors import CalibrationError
from accel_calib_ros.modelgap import diagnose, diagnose_windows, held_out_check
from accel_calib_ros.sim.motion import (face_directions, random_directions, simulate_session,
                                        simulate_static_windows)
from accel_calib_ros.sim.sensor import G0, mpu9250_like, with_datasheet_effect
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


ROUND_ONE = ('bias_drift', 'nonorthogonality', 'scale_nonlinearity', 'temperature_bias',
             'temperature_scale')


@pytest.mark.parametrize('seed', [1, 2])
@pytest.mark.parametrize('effect', ROUND_ONE)
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
    assert (report / 'probes.png').stat().st_size > 1000
    # The practical threshold is a parameter: above the effect's size nothing is named.
    worst = step['evidence']['worst_case_mg']
    assert main(['diagnose', str(path), '--json', '--min-effect-mg', f'{2 * worst}']) == 0
    high = json.loads(capsys.readouterr().out)
    assert high['missing_effects'] == [] and high['threshold_mg'] == pytest.approx(2 * worst)
    assert 'scale_nonlinearity' in [c['effect'] for c in high['below_threshold']]
    assert main(['diagnose', str(path), '--min-effect-mg', '-1']) == 2


def test_summary_is_strict_json_with_parameters_noise_and_null():
    rng = np.random.default_rng(6)
    sensor, baseline = hidden('temperature_scale', rng)
    result = diagnose_windows(windows_of(sensor, rng, hump), baseline, rate_hz=100.0,
                              replicates=10)
    summary = json.loads(json.dumps(result.summary(), allow_nan=False))
    assert summary['missing_effects'] == ['temperature_scale']
    effect = summary['parameters']['effects']['temperature_scale']
    assert '%/°C' in effect['magnitude'] and len(effect['values']) == 3
    np.testing.assert_allclose(effect['values'], sensor.scale_tempco, atol=0.3e-4)
    assert summary['null']['replicates'] == 10 and 0 < summary['null']['p_value'] <= 1
    # MPU-9250-like noise: the datasheet's 300 µg/√Hz is one-sided, Allan N = 300/√2.
    np.testing.assert_allclose(summary['noise']['noise_density_ug_rthz'], 300 / np.sqrt(2),
                               rtol=0.1)
    assert 'temperature_scale' in result.text()


def test_held_out_residual_drops_with_the_found_effect():
    rng = np.random.default_rng(7)
    sensor, baseline = hidden('temperature_bias', rng)
    windows = windows_of(sensor, rng, hump)
    result = diagnose_windows(windows, baseline, replicates=0)
    check = held_out_check(windows, result)
    assert check['effects'] == ['temperature_bias']
    assert check['with_effects_rms'] < 0.3 * check['baseline_rms']
    assert check['fit_windows'] + check['test_windows'] == N_WINDOWS


def test_a_long_null_session_names_nothing():
    # The calibration node's case (windows only, noise level given); its speed is measured
    # in bench/bench_diagnose.py (section speed).
    rng = np.random.default_rng(8)
    sensor = mpu9250_like(rng)
    windows = simulate_static_windows(sensor, random_directions(100, rng), rng, HOLD_S,
                                      COUNT, temperature=hump)
    result = diagnose_windows(windows, 'ml', 9.80665, replicates=20)
    assert result.missing_effects == [] and result.outcome == 'explained', result.text()


def test_too_few_windows_is_a_calibration_error_and_gn_needs_fewer():
    rng = np.random.default_rng(9)
    sensor = mpu9250_like(rng)
    sensor.T = np.diag(np.diag(sensor.T))
    windows = windows_of(sensor, rng, 25.0).select(np.arange(10))
    with pytest.raises(CalibrationError):
        diagnose_windows(windows, 'ml')
    result = diagnose_windows(windows, 'gn', replicates=0)
    assert result.missing_effects == []
    assert 'nonorthogonality' in result.skipped      # 10 windows: too few to test


def test_correlated_noise_is_not_taken_for_a_model_error():
    rng = np.random.default_rng(10)
    sensor = mpu9250_like(rng)
    sensor.noise_std = np.zeros(3)
    session = simulate_session(sensor, random_directions(40, rng), rng, hold_s=3.0,
                               move_s=1.0)
    # AR(1) noise with a 0.1 s correlation time: a window mean is ~4x noisier than
    # white noise of the same per-sample scatter would make it.
    phi, noise = 0.9, np.zeros((len(session.samples.t), 3))
    drive = rng.standard_normal(noise.shape) * 0.02 * np.sqrt(1 - phi ** 2)
    for k in range(1, len(noise)):
        noise[k] = phi * noise[k - 1] + drive[k]
    session.samples.accel[:] = session.samples.accel + noise
    result = diagnose(session.samples, 'ml', replicates=10)
    assert result.noise_inflation > 5.0
    assert result.missing_effects == [], result.text()
    assert not result.outside_library, result.text()
    # Window means about 4x noisier: the verdict is noise, or "cannot tell" when the naming
    # simulated on this design would miss an effect of twice the practical threshold.
    assert result.outcome in ('explained', 'cannot tell'), result.text()
    assert (result.outcome == 'cannot tell') == bool(result.weak_effects())


def test_cli_simulate_then_diagnose(tmp_path, capsys):
    path = str(tmp_path / 'x.csv')
    assert main(['simulate', '-o', path, '--effects', 'temperature_bias', '--temp', '10',
                 '45', '--poses', '60', '--hold', '2.5', '--move', '1.0']) == 0
    capsys.readouterr()
    assert main(['diagnose', path, '--json']) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary['missing_effects'][:1] == ['temperature_bias']
    # A plain ramp: temperature and time cannot be told apart, and the result says so.
    assert any('bias_drift' in note for note in summary['ambiguities'])


def test_six_faces_cannot_show_cross_axis_or_quadratic_terms():
    rng = np.random.default_rng(11)
    sensor, baseline = hidden('nonorthogonality', rng)
    windows = simulate_static_windows(sensor, np.tile(face_directions(), (3, 1)), rng,
                                      HOLD_S, COUNT)
    result = diagnose_windows(windows, baseline, replicates=0)
    assert result.missing_effects == []
    for name in ('nonorthogonality', 'scale_nonlinearity'):
        assert 'cannot show' in result.skipped[name]
    assert 'bias_drift' not in result.skipped


def test_report_has_a_residual_plot_per_step(tmp_path):
    from accel_calib_ros.modelgap.report import write_report
    rng = np.random.default_rng(12)
    sensor, baseline = hidden('temperature_bias', rng)
    result = diagnose_windows(windows_of(sensor, rng, hump), baseline, replicates=5)
    path = write_report(result, str(tmp_path / 'r'))
    text = pathlib.Path(path).read_text(encoding='utf-8')
    assert 'temperature_bias' in text and 'mg/°C' in text
    for name in ('gap.png', 'residuals_step0.png', 'residuals_step1.png'):
        assert name in text and (tmp_path / 'r' / name).stat().st_size > 1000
    assert not [f for f in (tmp_path / 'r').iterdir() if f.name.startswith('.')]


# -- round two: practical size, outside the library, vibration, 1 kHz, stable null ---------

def test_detectable_but_tiny_drift_is_not_named_unless_the_threshold_is_lowered():
    rng = np.random.default_rng(21)
    sensor = mpu9250_like(rng)
    span = 24 * 1200.0                                  # 24 poses, 20-minute pauses
    sensor.bias_drift = np.array([1.0, -1.0, 1.0]) * 0.6e-3 * G0 / span
    windows = simulate_static_windows(sensor, random_directions(24, rng), rng, 1200.0,
                                      30000, temperature=25.0)
    result = diagnose_windows(windows, 'ml')
    assert result.missing_effects == [], result.text()
    drift = [c for c in result.candidates if c['effect'] == 'bias_drift'][0]
    assert drift['significant'] and drift['worst_case_mg'] < 1.0
    assert result.below_threshold and result.explained
    lowered = diagnose_windows(windows, 'ml', min_effect_mg=0.1)
    assert lowered.missing_effects == ['bias_drift']
    assert 0.3 < lowered.steps[0]['evidence']['worst_case_mg'] < 1.0


def _outside(term, seed):
    rng = np.random.default_rng(seed)
    directions = random_directions(N_WINDOWS, rng)
    windows = windows_of(mpu9250_like(rng), rng, hump)
    windows = simulate_static_windows(mpu9250_like(rng), directions, rng, HOLD_S, COUNT,
                                      temperature=hump)
    windows.mean[:] = windows.mean + term(directions, windows.t_mid) * G0 / 1000.0
    return diagnose_windows(windows, 'ml')


def test_a_cause_outside_the_library_is_said_and_located():
    def orientation(d, t):
        return np.column_stack([d[:, 1] * d[:, 2], d[:, 0] * d[:, 2] ** 2,
                                d[:, 0] * d[:, 1] * d[:, 2]]) * np.array([8.0, -6.0, 9.0])
    result = _outside(orientation, 31)
    assert result.missing_effects == [] and result.outside_library, result.text()
    assert 'outside the effect library' in result.text()
    assert result.probes['direction']['significant']
    assert not result.probes['temperature']['significant']
    summary = json.loads(json.dumps(result.summary(), allow_nan=False))
    assert summary['outside_library'] and summary['probes']['direction']['p'] < 1e-3


def test_a_bias_step_is_not_passed_off_as_a_linear_drift():
    def step(d, t):
        return np.outer(t > np.median(t), [3.0, 2.0, -2.5])
    result = _outside(step, 32)
    assert result.missing_effects == [], result.text()
    # Withdrawn as a projection of a step, or not named because a single jump explains it.
    withdrawn = [p['effect'] for p in result.partial] + [v['effect'] for v in result.vetoed]
    assert 'bias_drift' in withdrawn or 'bias_random_walk' in withdrawn, result.text()
    assert result.outside_library and result.probes['time']['significant']


def _samples(rng, rate, dlpf_hz=None, vibration=0.0, effect=None, poses=24, hold_s=2.5):
    from scipy import signal
    sensor = mpu9250_like(rng, rate_hz=rate)
    if effect:
        sensor = with_datasheet_effect(sensor, effect, rng)
    s = simulate_session(sensor, random_directions(poses, rng), rng, hold_s=hold_s,
                         move_s=1.0, rate_hz=rate, temperature=lambda t: 25 + 12 * np.sin(t / 20))
    accel = s.samples.accel
    if vibration:
        b, a = signal.butter(2, [15 / (rate / 2), 45 / (rate / 2)], 'bandpass')
        shake = signal.lfilter(b, a, rng.standard_normal(accel.shape), axis=0)
        accel += shake / shake.std(axis=0) * vibration
    if dlpf_hz:
        b, a = signal.butter(2, dlpf_hz / (rate / 2))
        accel[:] = signal.lfilter(b, a, accel, axis=0, zi=signal.lfilter_zi(b, a)[:, None]
                                  * accel[:1])[0]
    return s.samples


def test_1khz_dlpf_clean_session_is_no_false_alarm():
    result = diagnose(_samples(np.random.default_rng(41), 1000.0, dlpf_hz=41.0), 'ml')
    assert result.missing_effects == [] and result.statistically_explained, result.text()
    assert result.noise_inflation > 4.0         # a DLPF correlates neighbouring samples
    assert 0.5 < result.gap_after < 1.6


def test_vibration_neither_hides_an_effect_nor_raises_an_alarm():
    null = diagnose(_samples(np.random.default_rng(42), 100.0, vibration=0.5), 'ml')
    assert null.missing_effects == [] and null.statistically_explained, null.text()
    assert null.gap_after > 0.5 and 'vibration' in null.noise()['model']
    found = diagnose(_samples(np.random.default_rng(43), 100.0, vibration=0.5,
                              effect='temperature_bias'), 'ml')
    assert found.missing_effects[:1] == ['temperature_bias'], found.text()


def test_null_verdict_does_not_depend_on_the_random_draws():
    rng = np.random.default_rng(51)
    windows = windows_of(mpu9250_like(rng), rng, hump)
    first = diagnose_windows(windows, 'ml', rng=np.random.default_rng(1), replicates=5)
    second = diagnose_windows(windows, 'ml', rng=np.random.default_rng(2), replicates=5)
    assert first.null_limit == second.null_limit and first.explained == second.explained
    # A noise level measured with few degrees of freedom widens the limit.
    from accel_calib_ros.modelgap.noise import null_gap_limit
    assert null_gap_limit(50, 30) > null_gap_limit(50, 3000) > null_gap_limit(50, np.inf)


def test_no_temperature_column_is_said_so():
    rng = np.random.default_rng(61)
    windows = windows_of(mpu9250_like(rng), rng, 25.0)
    windows.temp[:] = np.nan
    result = diagnose_windows(windows, 'ml')
    assert result.skipped['temperature_bias'] == 'no temperature column'
    assert 'spans only' not in result.text()


def test_six_face_session_gets_no_off_target_ambiguity_note():
    rng = np.random.default_rng(12)
    sensor, _ = hidden('temperature_bias', rng)
    directions = np.tile(face_directions(), (10, 1))         # 60 windows: the hump rises and falls
    windows = simulate_static_windows(sensor, directions, rng, HOLD_S, COUNT, temperature=hump)
    result = diagnose_windows(windows, 'gn')        # six faces: the gn model
    assert result.missing_effects[:1] == ['temperature_bias'], result.text()
    assert result.ambiguities == [], result.ambiguities
