"""
Real recordings of three public projects (test/data/peers, with their licence notes).

imu_tk's Xsens MTi session (raw unsigned counts), the MPU-6050 session of tomisuarez2
(raw ±2 g counts, plus three other recordings of the same sensor) and imucal's Ferraris
sessions (m/s², and raw ±16 g counts): the fits agree with each peer's own published
numbers, every refusal names only what is missing (or the term the method cannot
model), and the predictions are compared with held-out data honestly: held-out windows
of the same session where it can be split, other recordings where it cannot. The
figures of the "Real recordings" table (docs/benchmarks.md) are printed by bench/bench_peers.py.
"""

import json
import re

from accel_calib_ros.cli import main
from accel_calib_ros.core.accelerometer.fit import calibrate
from accel_calib_ros.core.errors import CalibrationError
from accel_calib_ros.core.poses import CANDIDATE_POSES
from accel_calib_ros.core.windows import detect_static_windows
from accel_calib_ros.dataio.calibration_file import load_calibration
from accel_calib_ros.dataio.units import to_si
import numpy as np
import peer_data
import pytest

pytestmark = pytest.mark.skipif(
    not all(peer_data.available(n) for n in ('imu_tk', 'imucal', 'mpu6050_tomisuarez2')),
    reason='peer recordings not present')

G0 = 9.80665
IMU_TK = ['--counts-per-g', '4065', '--counts-offset', '32768', '--gravity', '9.81744']
"""imu_tk's Xsens counts: about 414 counts per m/s² (nominal), unsigned, imu_tk's g."""
MPU = ['--range', '2']
IMUCAL_RAW = ['--range', '16', '--gravity', '9.81']
FACE = re.compile(r'\b[xyz] axis (up|down)\b(?!, tilted)')


@pytest.fixture(scope='module')
def data(tmp_path_factory):
    """Spec CSVs of the recordings, in their own units (counts stay counts)."""
    folder = tmp_path_factory.mktemp('peers')
    paths = {'imu_tk': peer_data.to_spec_csv(peer_data.imu_tk(), folder / 'imu_tk.csv'),
             'mpu': peer_data.to_spec_csv(peer_data.mpu6050(counts=True), folder / 'mpu.csv'),
             'imucal': peer_data.to_spec_csv(peer_data.imucal_ferraris()[0],
                                             folder / 'imucal.csv'),
             'imucal_raw': peer_data.to_spec_csv(peer_data.imucal_annotated()[0],
                                                 folder / 'imucal_raw.csv')}
    return {k: str(v) for k, v in paths.items()}


def cli(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def named_poses(text):
    """Return the candidate poses a message names, as (name, direction), in order."""
    found = []
    for d, name in sorted(CANDIDATE_POSES, key=lambda p: -len(p[1])):
        while name in text:               # 'x axis up' is also in 'x axis up, tilted ...'
            found.append((text.index(name), name, d))
            text = text.replace(name, '#' * len(name), 1)
    return [(name, d) for _, name, d in sorted(found, key=lambda f: f[0])]


def held_directions(samples):
    w = detect_static_windows(samples)
    return w.mean / np.linalg.norm(w.mean, axis=1, keepdims=True)


def nearest_held_deg(direction, held):
    return float(np.degrees(np.arccos(np.clip(np.max(held @ direction), -1, 1))))


# -- imu_tk: Xsens MTi, raw unsigned counts ----------------------------------------------------

def test_imu_tk_ml_matches_imu_tk_and_the_file_holds_si_units(data, capsys, tmp_path):
    out_file = tmp_path / 'cal.yaml'
    code, out, err = cli(capsys, 'fit', data['imu_tk'], *IMU_TK, '--json', '-o', out_file)
    assert code == 0, err
    summary = json.loads(out)
    k = G0 / 4065.0                                          # m/s² per count, nominal
    ref = peer_data.IMU_TK_REFERENCE
    inverse_scale = np.array(summary['scale']) / k           # counts per m/s²
    np.testing.assert_allclose(inverse_scale, ref['inverse_scale'], rtol=5e-4)
    np.testing.assert_allclose(32768 + np.array(summary['bias']) / k, ref['bias'], atol=1.0)
    cal = load_calibration(out_file)
    assert np.all(np.abs(cal.bias) < 0.25 * G0) and np.allclose(np.diag(cal.T), 1.0, atol=0.01)
    # imu_tk's own residual: RMS |g|-residual over the static samples, 0.0080 m/s².
    samples = to_si(peer_data.imu_tk(), 'counts', 4065.0, 32768.0)
    w = detect_static_windows(samples)
    rho = np.concatenate([np.linalg.norm(cal.correct(samples.accel[a:b]), axis=1)
                          - peer_data.IMU_TK_GRAVITY for a, b in zip(w.start, w.stop)])
    assert np.sqrt(np.mean(rho ** 2)) == pytest.approx(ref['residual_rms'], abs=5e-4)


def test_imu_tk_counts_are_refused_without_their_unit(data, capsys):
    code, _, err = cli(capsys, 'fit', data['imu_tk'])
    assert code == 2 and err.count('\n') == 1
    assert '--units counts' in err and '--counts-offset 32768' in err
    code, _, err = cli(capsys, 'advise', data['imu_tk'], '--units', 'counts')
    assert code == 2 and '--counts-per-g' in err and err.count('\n') == 1
    code, _, err = cli(capsys, 'allan', data['imu_tk'], '--range', '8')     # offset missing
    assert code == 2 and '--counts-offset 32768' in err and err.count('\n') == 1


def test_imu_tk_gn_refusal_names_the_cross_axis_terms_not_poses(data, capsys):
    code, out, err = cli(capsys, 'fit', data['imu_tk'], *IMU_TK, '--method', 'gn', '--json')
    assert code == 1 and err.count('\n') == 1
    assert 'orthogonal' in err and '--method ml' in err and '°' in err, err
    assert not FACE.search(err) and not named_poses(err), err
    assert json.loads(out)['cross_axis_allowance']['terms']['yz']['measured'] is True


def test_imu_tk_held_out_windows_stay_within_the_prediction():
    """Fit on every other window, test on the rest (and the other way round)."""
    samples = to_si(peer_data.imu_tk(), 'counts', 4065.0, 32768.0)
    w = detect_static_windows(samples)
    even = np.arange(len(w)) % 2 == 0
    for train in (even, ~even):
        part = w.select(train)
        cal = calibrate(part.mean, peer_data.IMU_TK_GRAVITY, 'ml',
                        part.weights(5.0, samples.rate_hz), noise_std=part.noise_std)
        result = peer_data.held_out(cal, w.select(~train), samples.rate_hz)
        print(f'imu_tk held-out {result}')
        assert result['measured'] < 1.5 * result['predicted']


# -- MPU-6050 (tomisuarez2): raw ±2 g counts -------------------------------------------------

def test_mpu6050_refusal_asks_for_the_missing_tilt_not_for_held_faces(data, capsys):
    code, _, err = cli(capsys, 'fit', data['mpu'])
    assert code == 2 and '--units counts' in err and '--range' in err
    code, out, err = cli(capsys, 'fit', data['mpu'], *MPU, '--json')
    assert code == 1 and err.count('\n') == 1
    # The session holds all six faces; what it lacks is a pose tilted in x-y.
    held = held_directions(peer_data.mpu6050())
    named = named_poses(err)
    assert named and named[0][0] == 'y axis up, tilted 45° toward -x', err
    assert not FACE.search(err), err
    assert all(nearest_held_deg(d, held) >= 25.0 for _, d in named)
    nxt = json.loads(out)['next_poses']
    assert nxt[0]['predicted_accuracy_after'] < 0.02          # that pose alone is enough
    # advise (same windows, same accuracy model) names the same pose.
    code, out, _ = cli(capsys, 'advise', data['mpu'], *MPU, '--json')
    assert code == 0 and json.loads(out)['next_pose']['name'] == named[0][0]


def test_mpu6050_agrees_with_the_authors_fit(data, capsys):
    code, out, err = cli(capsys, 'fit', data['mpu'], *MPU, '--json', '--max-predicted-error', '1')
    assert code == 0, err
    summary = json.loads(out)
    k = G0 / 16384.0
    ref = peer_data.MPU6050_REFERENCE
    np.testing.assert_allclose(k / np.array(summary['scale']), ref['scale'], rtol=1e-3)
    bias_counts = np.array(summary['bias']) / k
    # Their bias enters with the other sign (a = T K (raw + b)). y, z agree within 0.5 %;
    # x differs by ~12 counts: it trades off against the x-y cross-axis term, which these
    # poses do not determine (the reason the fit is refused by default).
    np.testing.assert_allclose(-bias_counts[1:], ref['bias'][1:], rtol=5e-3)
    assert abs(-bias_counts[0] - ref['bias'][0]) < 20.0


def test_mpu6050_gn_is_never_more_confident_with_fewer_orientations():
    """
    Every 7-window subset: predicted at least the whole session's, refused, held-out within.

    (A 7-window subset predicted 0.007 m/s² and was once accepted, while its
    held-out error reached 6x that.)
    """
    import itertools
    samples = peer_data.mpu6050()
    w = detect_static_windows(samples)
    weights = w.weights(5.0, samples.rate_hz)
    whole = calibrate(w.mean, G0, 'gn', weights, noise_std=w.noise_std)
    fitted = 0
    for comb in itertools.combinations(range(len(w)), 7):
        sel = np.zeros(len(w), bool)
        sel[list(comb)] = True
        try:
            cal = calibrate(w.mean[sel], G0, 'gn', weights[sel], noise_std=w.noise_std)
        except CalibrationError:
            continue
        fitted += 1
        assert cal.predicted_accuracy >= whole.predicted_accuracy > 0.02
        result = peer_data.held_out(cal, w.select(~sel), samples.rate_hz)
        assert result['measured'] <= result['predicted'], (comb, result)
    assert fitted > 100


def test_mpu6050_held_out_recordings():
    """
    The session fits, forced; three other recordings of the sensor are the held-out data.

    Their windows lie near held poses (z up, y up), so they test the radial error only;
    they were recorded at other power-ups, and the sensor's bias moved by about 1 mg
    between them, which no single session can show: the measured residual exceeds the
    within-session prediction by about that much, and stays below the acceptance limit.
    """
    samples = peer_data.mpu6050()
    w = detect_static_windows(samples)
    cal = calibrate(w.mean, G0, 'ml', w.weights(5.0, samples.rate_hz), noise_std=w.noise_std)
    for which in ('still', 'static_test', 'rotation_test'):
        other = peer_data.mpu6050(which)
        result = peer_data.held_out(cal, detect_static_windows(other), other.rate_hz)
        print(f'MPU-6050 held-out {which}: {result}')
        assert result['measured'] < 0.02
        assert result['measured'] < result['predicted'] + 0.015


# -- imucal: Ferraris sessions (m/s², and raw ±16 g counts) ----------------------------------

def test_imucal_refusals_name_tilted_poses_not_the_faces_it_holds(data, capsys):
    code, _, err = cli(capsys, 'fit', data['imucal'])
    assert code == 1 and err.count('\n') == 1
    assert 'all six faces are held' in err and not FACE.search(err), err
    named = named_poses(err)
    held = held_directions(peer_data.imucal_ferraris()[0])
    assert len(named) == 3 and all(nearest_held_deg(d, held) >= 25.0 for _, d in named)
    code, out, err = cli(capsys, 'fit', data['imucal'], '--method', 'gn', '--json')
    assert code == 1 and 'datasheet' in err and 'tilted' in err and not FACE.search(err)
    summary = json.loads(out)
    assert summary['predicted_accuracy'] > 0.1           # was 0.0033, accepted
    assert not any(t['measured'] for t in summary['cross_axis_allowance']['terms'].values())


def test_imucal_agrees_with_imucal_on_its_annotated_session(data, capsys):
    code, out, err = cli(capsys, 'fit', data['imucal_raw'], *IMUCAL_RAW, '--method', 'gn',
                         '--json', '--max-predicted-error', '1')
    assert code == 0, err
    summary = json.loads(out)
    k = G0 / 2048.0
    _, ref = peer_data.imucal_annotated()
    np.testing.assert_allclose(np.array(summary['scale']) / k, ref['K_a'], rtol=5e-4)
    np.testing.assert_allclose(np.array(summary['bias']) / k, ref['b_a'], atol=1.0)


def test_imucal_held_out_is_the_later_phase_of_the_ferraris_session():
    """
    The Ferraris session holds the six faces, then x, y and z up again around rotations.

    gn fitted to the six-face phase (forced: its cross-axis terms are charged at the
    datasheet bound) is tested on the windows of the later phase. Those faces came back
    about 0.5 mg off in norm, more than the 0.1 mg floor the prediction assumes and more
    than one spare window can show: the held-out residual is printed beside the
    prediction. The annotated session (8 windows) cannot be split at all: each half
    lacks faces.
    """
    samples = peer_data.imucal_ferraris()[0]
    w = detect_static_windows(samples)
    first = w.t_mid < np.median(w.t_mid)
    weights = w.weights(5.0, samples.rate_hz)
    cal = calibrate(w.mean[first], 9.81, 'gn', weights[first], noise_std=w.noise_std)
    result = peer_data.held_out(cal, w.select(~first), samples.rate_hz)
    print(f'imucal held-out (later phase): {result}')
    assert result['windows'] == 7 and result['measured'] < 0.01
    with pytest.raises(CalibrationError, match='orientations'):
        calibrate(w.mean[~first], 9.81, 'gn', weights[~first])
    raw = to_si(peer_data.imucal_annotated()[0], 'counts', 2048.0)
    w = detect_static_windows(raw)
    first = w.t_mid < np.median(w.t_mid)
    for half in (first, ~first):
        with pytest.raises(CalibrationError, match='observations'):
            calibrate(w.mean[half], 9.81, 'gn', w.weights(5.0, raw.rate_hz)[half])


# -- one detector, one accuracy, one noise convention ---------------------------------------

@pytest.mark.parametrize('name, options, method', [
    ('imu_tk', IMU_TK, 'ml'), ('imu_tk', IMU_TK, 'gn'), ('mpu', MPU, 'gn'),
    ('imucal', [], 'gn')])
def test_fit_advise_and_diagnose_see_the_same_windows_and_accuracy(
        data, capsys, name, options, method):
    limit = ['--max-predicted-error', '1']
    code, out, err = cli(capsys, 'fit', data[name], *options, '--method', method, '--json',
                         *limit)
    fit = json.loads(out)
    outliers = [d for d in fit['dropped_windows'] if 'moved' in d['reason']]
    code, out, _ = cli(capsys, 'advise', data[name], *options, '--method', method, '--json')
    advice = json.loads(out)
    code, out, err = cli(capsys, 'diagnose', data[name], *options, '--baseline', method,
                         '--json')
    assert code == 0, err
    gap = json.loads(out)
    assert advice['windows'] == fit['observations'] + len(outliers)
    assert gap['windows'] + gap['dropped_windows'] == advice['windows']
    if not outliers:
        assert advice['predicted_accuracy'] == pytest.approx(fit['predicted_accuracy'],
                                                             rel=1e-9)
    # diagnose reports fit's accuracy; for gn without the cross-axis share it looks for.
    share = fit['cross_axis_allowance']['accuracy_m_s2'] if method == 'gn' else 0.0
    estimation = np.sqrt(fit['predicted_accuracy'] ** 2 - share ** 2)
    if not outliers and not gap['dropped_windows']:
        assert gap['predicted_accuracy_mg'] * G0 / 1000 == pytest.approx(estimation, rel=1e-6)


def test_allan_and_diagnose_agree_on_the_mpu6050_noise_density(data, capsys, tmp_path):
    still = peer_data.to_spec_csv(peer_data.mpu6050('still', counts=True),
                                  tmp_path / 'still.csv')
    code, out, err = cli(capsys, 'allan', still, *MPU, '--json')
    assert code == 0, err
    allan = json.loads(out)
    code, out, err = cli(capsys, 'diagnose', data['mpu'], *MPU, '--baseline', 'gn', '--json')
    assert code == 0, err
    noise = json.loads(out)['noise']
    assert noise['noise_density_convention'] == allan['noise_density_convention']
    print(f"MPU-6050 noise density µg/√Hz: allan {allan['noise_density_ug_rthz'][:3]}, "
          f"diagnose {noise['noise_density_ug_rthz']}")
    # Different recordings of one sensor (a 7.5 min table-still run, the session's
    # windows): the same convention gives the same number within 25 % (x: 325 and 368).
    np.testing.assert_allclose(noise['noise_density_ug_rthz'][:2],
                               allan['noise_density_ug_rthz'][:2], rtol=0.25)
