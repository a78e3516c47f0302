"""The one validating calibration-file loader, the atomic writer and the model data class."""

import math
import os
import subprocess
import sys

from accel_calib_ros.core.accelerometer.thermal import ThermalBand, ThermalTable
from accel_calib_ros.core.accuracy import direction_errors, predicted_accuracy, worst_faces
from accel_calib_ros.core.calibration import Calibration
from accel_calib_ros.core.errors import CalibrationError, InputError
from accel_calib_ros.dataio.calibration_file import (calibration_from_dict, calibration_to_dict,
                                                     calibration_to_yaml, load_calibration,
                                                     MAX_BANDS, MAX_NESTING, nesting_depth,
                                                     save_calibration)
from hypothesis import given, HealthCheck, settings, strategies as st
import numpy as np
import pytest
import yaml

G = 9.80665


def full_calibration():
    """Return a calibration with every optional attribute set."""
    T = np.array([[1.02, 0.01, -0.005], [0.0, 0.98, 0.012], [0.0, 0.0, 1.01]])
    bands = [ThermalBand(10.0, 20.0, 15.0, np.full(3, 1e-4), np.full(3, 1e-3),
                         np.array([0.01, -0.02, 0.03]), 14, gyro_bias=np.array([1e-3, 0, 0])),
             ThermalBand(20.0, 30.0, 25.0, np.zeros(3), np.zeros(3), np.zeros(3), 3,
                         'too few windows: 3 static windows in 20..30 °C, needs 12')]
    cov = np.diag(np.r_[np.full(6, 1e-8), np.full(3, 1e-6)])
    return Calibration(T=T, bias=[0.2, -0.1, 0.3], covariance=cov, noise_std=[0.03, 0.03, 0.04],
                       predicted_accuracy=0.004, gyro_bias=[0.01, -0.02, 0.005],
                       temperature_range_c=(12.0, 27.5), level_roll_pitch_rad=(0.01, -0.02),
                       sensor_id='imu0', thermal=ThermalTable(10.0, bands), residual_rms=0.003,
                       observations=30, iterations=7)


def test_round_trip_keeps_every_attribute(tmp_path):
    cal = full_calibration()
    path = tmp_path / 'deep' / 'er' / 'cal.yaml'          # parent directories are created
    save_calibration(cal, path)
    back = load_calibration(path)
    np.testing.assert_array_equal(back.T, cal.T)
    np.testing.assert_array_equal(back.covariance, cal.covariance)
    np.testing.assert_array_equal(back.gyro_bias, cal.gyro_bias)
    assert back.predicted_accuracy == cal.predicted_accuracy
    assert back.temperature_range_c == cal.temperature_range_c
    assert back.level_roll_pitch_rad == cal.level_roll_pitch_rad
    assert back.sensor_id == 'imu0' and back.observations == 30
    np.testing.assert_array_equal(back.thermal.bands[0].gyro_bias, [1e-3, 0, 0])
    raw = np.array([[0.1, 0.2, 9.9], [9.7, 0.0, 0.3]])
    np.testing.assert_array_equal(back.correct(raw, [14.0, 22.0]), cal.correct(raw, [14.0, 22.0]))


def test_unknown_values_are_written_as_null_not_nan(tmp_path):
    cal = Calibration(T=np.eye(3), bias=np.zeros(3))           # noise and residual unknown
    path = tmp_path / 'cal.yaml'
    save_calibration(cal, path)
    text = path.read_text()
    assert 'nan' not in text.lower() and 'inf' not in text.lower()
    back = load_calibration(path)
    assert np.all(np.isnan(back.noise_std)) and back.gyro_bias is None


@pytest.mark.parametrize('field,value', [
    ('T', np.diag([np.nan, 1, 1])), ('T', np.eye(3) * 1e-300), ('bias', [np.inf, 0, 0]),
    ('covariance', np.full((9, 9), np.nan)), ('gyro_bias', [np.nan, 0, 0]),
    ('predicted_accuracy', float('inf')), ('gravity', float('nan'))])
def test_save_refuses_non_finite_and_keeps_the_old_file(tmp_path, field, value):
    path = tmp_path / 'cal.yaml'
    save_calibration(full_calibration(), path)
    before = path.read_bytes()
    bad = full_calibration()
    setattr(bad, field, np.asarray(value, float) if field != 'gravity' else value)
    with pytest.raises(CalibrationError):
        save_calibration(bad, path)
    assert path.read_bytes() == before
    assert os.listdir(tmp_path) == ['cal.yaml']              # no temporary file left behind


def _valid():
    return calibration_to_dict(full_calibration())


def _set(d, keys, value):
    target = d
    for k in keys[:-1]:
        target = target[k]
    target[keys[-1]] = value
    return d


BAD_EDITS = [
    (('fit',), 'hello'), (('T',), 'eye'), (('T',), [[1, 0, 0], [0, 1, 0]]),
    (('T',), [[1, 0, 0], [0.5, 1, 0], [0, 0, 1]]),
    (('T',), [[1e-300, 0, 0], [0, 1, 0], [0, 0, 1]]),
    (('T',), [[1, 0, 0], [0, 1, 0], [0, 0, 100]]), (('T',), [[True, 0, 0], [0, 1, 0], [0, 0, 1]]),
    (('T',), [[float('nan'), 0, 0], [0, 1, 0], [0, 0, 1]]), (('bias_m_s2',), [1e308, 0, 0]),
    (('bias_m_s2',), [50.0, 0, 0]), (('bias_m_s2',), '0 0 0'), (('gravity_m_s2',), 0),
    (('gravity_m_s2',), float('nan')), (('method',), 'magic'), (('version',), 2),
    (('version',), True), (('format',), 'other'), (('gyro_bias_rad_s',), [5.0, 0, 0]),
    (('temperature_range_c',), [30.0, 10.0]), (('level_roll_pitch_rad',), [0.0, 2.0]),
    (('covariance', 'matrix'), [[1.0] * 9] * 8), (('fit', 'converged'), 'yes'),
    (('fit', 'observations'), -3), (('fit', 'observations'), 2.5),
    (('thermal', 'bands', 0, 'offset_m_s2'), [float('nan'), 0, 0]),
    (('thermal', 'bands', 0, 'linear'), [1e30, 0, 0]), (('thermal', 'bands', 0, 'low_c'), 40.0),
    (('thermal', 'bands', 1, 'low_c'), 12.0), (('thermal', 'bands'), {'a': 1}),
    (('thermal', 'band_width_c'), -1), (('sensor_id',), ['a'])]


@pytest.mark.parametrize('keys,value', BAD_EDITS)
def test_bad_values_are_one_line_input_errors(keys, value):
    d = _set(_valid(), keys, value)
    with pytest.raises(InputError) as err:
        calibration_from_dict(d)
    assert '\n' not in str(err.value)


def _write(tmp_path, data):
    path = tmp_path / 'cal.yaml'
    path.write_bytes(data if isinstance(data, bytes) else data.encode())
    return path


@pytest.mark.parametrize('data', [
    b'', b'fit: hello\n', b'\xff\xfe\x00garbage', ('[' * 5000 + ']' * 5000).encode(),
    b'{{{', b'- 1\n- 2\n', b'a: &a [1]\nb: *a\n', b'!!python/object:os.system {}\n',
    'format: accel_calib_ros/calibration\nversion: 1\nT: [[1, 0, 0], [0, 1, 0], [0, 0, 1]]\n'
    .encode(), b'x' * (2 << 20)])
def test_bad_files_are_input_errors(tmp_path, data):
    with pytest.raises(InputError) as err:
        load_calibration(_write(tmp_path, data))
    assert '\n' not in str(err.value)


def test_truncated_files_directories_and_missing_files(tmp_path):
    cal = full_calibration()
    text = calibration_to_yaml(cal)
    refused = 0
    for cut in range(0, len(text), max(len(text) // 40, 1)):
        try:
            back = load_calibration(_write(tmp_path, text[:cut]))
        except InputError:
            refused += 1
            continue
        np.testing.assert_array_equal(back.T, cal.T)   # a cut in the optional tail only
        np.testing.assert_array_equal(back.bias, cal.bias)
    assert refused >= 5
    with pytest.raises(InputError, match='directory'):
        load_calibration(tmp_path)
    with pytest.raises(InputError, match='not found'):
        load_calibration(tmp_path / 'nope.yaml')


@pytest.mark.parametrize('text', [
    'a: ' + '[' * 20000 + ']' * 20000 + '\n',                       # 40 kB of brackets
    'a: ' + '{b: ' * 40 + '1' + '}' * 40 + '\n',
    'a:\n' + ''.join(' ' * k + '- \n' for k in range(1, 60)),      # block nesting
    '- ' * 60 + 'x\n',                                            # compact sequences
])
def test_deeply_nested_files_are_refused_before_parsing(tmp_path, text):
    """A file of nested brackets is refused by its shape (it stalled a reload 1.7 s)."""
    assert nesting_depth(text) > MAX_NESTING
    with pytest.raises(InputError, match='nested too deeply'):
        load_calibration(_write(tmp_path, text))


def test_the_largest_real_file_loads_and_is_shallow(tmp_path):
    """MAX_BANDS thermal bands with gyro biases: under the size cap, 5 levels deep."""
    cal = full_calibration()
    bands = [ThermalBand(-40 + 0.5 * k, -39.5 + 0.5 * k, -39.75 + 0.5 * k, np.full(3, 1e-5),
                         np.full(3, -1e-3), np.full(3, 0.01), 20, gyro_bias=np.full(3, 1e-3))
             for k in range(MAX_BANDS)]
    cal.thermal = ThermalTable(0.5, bands)
    cal.temperature_range_c = (-40.0, 60.0)
    text = calibration_to_yaml(cal)
    assert nesting_depth(text) <= 6 and '[[[' not in text
    assert nesting_depth('a: "[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[" # [[[[[[[[[[[[\n') == 0
    back = load_calibration(_write(tmp_path, text))
    assert len(back.thermal.bands) == MAX_BANDS


def test_loader_imports_no_scipy():
    code = ('import sys, accel_calib_ros.dataio.calibration_file, '
            'accel_calib_ros.core.calibration, accel_calib_ros.core.accuracy; '
            'print(any(m.startswith("scipy") for m in sys.modules))')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == 'False'


_scalars = st.one_of(st.none(), st.booleans(), st.integers(-10 ** 30, 10 ** 30),
                     st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=8))
_trees = st.recursive(_scalars, lambda inner: st.one_of(
    st.lists(inner, max_size=10), st.dictionaries(st.text(max_size=8), inner, max_size=6)),
    max_leaves=40)
_PATHS = [('T',), ('T', 0), ('T', 1, 1), ('bias_m_s2',), ('bias_m_s2', 2), ('gravity_m_s2',),
          ('fit',), ('fit', 'noise_std_m_s2'), ('covariance',), ('covariance', 'matrix', 3, 3),
          ('thermal',), ('thermal', 'bands', 0), ('thermal', 'bands', 0, 'quadratic_per_m_s2'),
          ('thermal', 'bands', 1, 'temp_c'), ('gyro_bias_rad_s',), ('temperature_range_c',),
          ('level_roll_pitch_rad', 1), ('method',), ('version',), ('created',)]


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.tuples(st.sampled_from(_PATHS), _trees), min_size=1, max_size=3))
def test_property_mutated_files_load_or_raise_input_error(edits):
    d = _valid()
    for keys, value in edits:
        try:
            _set(d, keys, value)
        except (TypeError, IndexError, KeyError):
            pass
    try:
        cal = calibration_from_dict(d)
    except InputError as err:
        assert '\n' not in str(err)
        return
    raw = np.array([[0.0, 0.0, G], [G, 0.0, 0.0], [-3.0, 4.0, -8.0]])
    assert np.all(np.isfinite(cal.correct(raw, [15.0, 25.0, float('nan')])))
    assert np.all(np.isfinite(cal.correct_gyro(np.ones((3, 3)), [15.0, 25.0, float('nan')])))
    calibration_from_dict(yaml.safe_load(calibration_to_yaml(cal)))   # and it saves back


@settings(max_examples=150, deadline=None)
@given(st.one_of(_trees, st.binary(max_size=200)))
def test_property_any_text_loads_or_raises_input_error(tmp_path_factory, data):
    path = tmp_path_factory.mktemp('fuzz') / 'cal.yaml'
    path.write_bytes(data if isinstance(data, bytes) else
                     yaml.safe_dump(data, allow_unicode=True).encode('utf-8', 'replace'))
    try:
        load_calibration(path)
    except InputError as err:
        assert '\n' not in str(err)


# -- predicted accuracy ---------------------------------------------------------------------------

def test_predicted_accuracy_matches_monte_carlo_over_the_sphere():
    rng = np.random.default_rng(3)
    T = np.triu(rng.normal(0, 0.01, (3, 3))) + np.eye(3)
    A = rng.normal(size=(9, 9)) * np.r_[np.full(6, 1e-3), np.full(3, 1e-2)]
    C = A @ A.T
    u = rng.normal(size=(20000, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    mc = np.sqrt(np.mean(direction_errors(T, C, u, G) ** 2))
    assert predicted_accuracy(T, C, G) == pytest.approx(mc, rel=0.02)
    # Direct simulation of parameter errors at one direction.
    p = rng.multivariate_normal(np.zeros(9), C, size=20000)
    a0 = G * np.array([0.0, 0.6, 0.8])
    dT = np.zeros((len(p), 3, 3))
    dT[:, 0, 0], dT[:, 0, 1], dT[:, 0, 2], dT[:, 1, 1], dT[:, 1, 2], dT[:, 2, 2] = p[:, :6].T
    da = -np.linalg.solve(T, (dT @ a0 + p[:, 6:]).T).T
    rms = np.sqrt(np.mean(np.sum(da ** 2, axis=1)))
    assert direction_errors(T, C, [[0, 0.6, 0.8]], G)[0] == pytest.approx(rms, rel=0.03)


def test_bias_only_uncertainty_names_the_axis():
    C = np.zeros((9, 9))
    C[8, 8] = 0.5 ** 2                                     # b_z unknown
    assert predicted_accuracy(np.eye(3), C) == pytest.approx(0.5)
    C = np.zeros((9, 9))
    C[5, 5] = 0.01 ** 2                                    # T_zz unknown: z up/down suffer
    faces = worst_faces(np.eye(3), C, G, limit=0.01)
    assert sorted(name for name, _, _ in faces) == ['z axis down', 'z axis up']
    assert math.isnan(predicted_accuracy(np.eye(3), np.full((9, 9), np.nan)))


def test_level_rotation_maps_the_resting_reading_to_base_z():
    a = np.array([0.3, -0.5, 9.7])
    roll, pitch = math.atan2(a[1], a[2]), math.atan2(-a[0], math.hypot(a[1], a[2]))
    cal = Calibration(T=np.eye(3), bias=np.zeros(3), level_roll_pitch_rad=(roll, pitch))
    np.testing.assert_allclose(cal.level_rotation() @ a, [0, 0, np.linalg.norm(a)], atol=1e-12)
    np.testing.assert_array_equal(Calibration(T=np.eye(3), bias=np.zeros(3)).level_rotation(),
                                  np.eye(3))


def test_gyro_bias_per_band_and_fallback():
    cal = full_calibration()
    gyro = np.zeros((3, 3))
    out = cal.correct_gyro(gyro, [15.0, 40.0, float('nan')])
    np.testing.assert_allclose(out[0], [-1e-3, 0, 0])       # the band's own value
    np.testing.assert_allclose(out[1], [-1e-3, 0, 0])       # held beyond the last band
    np.testing.assert_allclose(out[2], -cal.gyro_bias)      # no temperature: global value
    cal.thermal = None
    np.testing.assert_allclose(cal.correct_gyro(gyro), -np.tile(cal.gyro_bias, (3, 1)))


def test_the_file_records_the_units_the_fit_was_given():
    """input_units (the counts conversion T absorbed) round-trips and is checked."""
    cal = full_calibration()
    for units in ({'accel': 'm/s2'}, {'accel': 'g'},
                  {'accel': 'counts', 'counts_per_g': 16384.0, 'counts_offset': 32768.0}):
        cal.input_units = units
        assert calibration_from_dict(calibration_to_dict(cal)).input_units == units
    d = calibration_to_dict(cal)
    assert d['input_units'] == {'accel': 'counts', 'counts_per_g': 16384.0,
                                'counts_offset': 32768.0}
    for bad, words in (({'accel': 'furlongs'}, 'input_units.accel must be one of'),
                       ({'accel': 'counts'}, 'input_units.counts_per_g must be a number'),
                       ({'accel': 'counts', 'counts_per_g': -5.0}, 'counts_per_g'),
                       ({'accel': 'm/s2', 'counts_per_g': 16384.0}, 'belong to counts'),
                       ('m/s2', 'input_units must be a mapping')):
        d['input_units'] = bad
        with pytest.raises(InputError, match=words):
            calibration_from_dict(d)
    del d['input_units']                                   # older files: not recorded
    assert calibration_from_dict(d).input_units is None
