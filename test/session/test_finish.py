"""
After the windows (``session.finish``): one session through every front door ends alike.

The same recorded session (an accelerometer and a gyroscope, held in 14 poses, stamped in
Unix time) goes through the calibration node's job function (no DDS: the worker's
function with the node's own settings), ``accel-calib fit`` and ``accel-calib guide``'s
ending. Each gives the same outcome, the same calibration file and the same history rows,
apart from wording (and the file's ``source`` and ``created``).
"""

import contextlib
import io
import json
from types import SimpleNamespace

from accel_calib_ros.cli import build_parser, main
from accel_calib_ros.core.collector import ImuCollector
from accel_calib_ros.core.samples import Samples
from accel_calib_ros.dataio.calibration_file import load_calibration
from accel_calib_ros.dataio.history import History
from accel_calib_ros.dataio.recording import load_samples, write_samples_csv
from accel_calib_ros.session.accept import CollectedImu, fit_and_accept, refused
from accel_calib_ros.session.finish import finish_session, HistoryTarget
from accel_calib_ros.session.settings import DEFAULT_SETTINGS as S, FIT, GUIDE, NODE, Words
from accel_calib_ros.session.windows import WindowSet
from accel_calib_ros.sim.motion import random_directions, simulate_session
from accel_calib_ros.sim.sensor import mpu9250_like, with_gyro_errors
import numpy as np
import pytest

SENSOR = 'imu_test'
T0 = 1.7e9
"""The recording's first stamp, Unix time s: every door keeps the windows' own times."""


@pytest.fixture(scope='module')
def recording(tmp_path_factory):
    """Return (CSV path, samples, the windows ``fit`` finds in it)."""
    rng = np.random.default_rng(21)
    sensor = with_gyro_errors(mpu9250_like(rng), np.random.default_rng(22))
    directions = random_directions(14, np.random.default_rng(23))
    s = simulate_session(sensor, directions, rng, hold_s=3.0, move_s=1.5).samples
    path = tmp_path_factory.mktemp('doors') / 'session.csv'
    write_samples_csv(path, Samples(s.t + T0, s.accel, s.temp, s.gyro))
    samples = load_samples(str(path))
    from accel_calib_ros.cli.fit import _observations
    args = build_parser('fit').parse_args(['fit', str(path)])
    found = _observations(samples, args)
    assert not found.dropped
    return path, samples, WindowSet.from_static(found.kept, samples.t)


def collector_of(samples):
    """Return an ImuCollector that took in the whole recording, as a live door does."""
    c = ImuCollector()
    c.add_samples(np.column_stack([samples.t, samples.accel, samples.gyro, samples.temp]))
    return c


def node_door(path, samples, windows, out, db):
    rclpy = pytest.importorskip('rclpy')
    assert rclpy            # the node's module imports it; no context, no DDS
    from accel_calib_ros.nodes.calibration import CalibrationNode
    from accel_calib_ros.nodes.calibration_job import Job, run_job
    from accel_calib_ros.nodes.calibration_params import PARAMS
    params = {p.name: p.default for p in PARAMS}
    params.update(sensor_id=SENSOR, thermal='off')
    node = SimpleNamespace(params=params, frame_id='imu_link', sensor=SENSOR,
                           get_fully_qualified_name=lambda: '/accel_calibration')
    job = Job(windows=windows, rate_hz=samples.rate_hz,
              settings=CalibrationNode.settings(node),
              imu=CollectedImu(collector_of(samples).snapshot(), windows), path=str(out),
              history=str(db), now=T0)
    outcome, notes = run_job(job)
    assert notes == []
    return outcome


def fit_door(path, samples, windows, out, db):
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        code = main(['fit', str(path), '-o', str(out), '--history', str(db), '--sensor',
                     SENSOR, '--json'])
    assert code == 0
    return json.loads(stdout.getvalue())


def guide_door(path, samples, windows, out, db):
    from rich.console import Console
    from accel_calib_ros.cli.guide import _finish
    from accel_calib_ros.cli.guide_session import GuideSession
    session = GuideSession(samples.rate_hz)
    session.windows = windows.windows()
    session.imu = collector_of(samples)
    console = Console(file=io.StringIO(), width=200)
    assert _finish(session, str(out), 'a test', console, str(db), SENSOR) == 0
    return console.file.getvalue()


DOORS = {'node': node_door, 'fit': fit_door, 'guide': guide_door}


@pytest.fixture(scope='module')
def ended(recording, tmp_path_factory):
    """Return {door: (what it said, the file it wrote, the history it kept)}."""
    path, samples, windows = recording
    done = {}
    for name, door in DOORS.items():
        folder = tmp_path_factory.mktemp(name)
        out, db = folder / 'calibration.yaml', folder / 'history.sqlite'
        said = door(path, samples, windows, out, db)
        with History(db, readonly=True) as h:
            rows, cals = h.windows(SENSOR), h.calibrations(SENSOR)
        done[name] = said, load_calibration(out), rows, cals
    return done


@pytest.mark.parametrize('door', ['node', 'guide'])
def test_the_same_session_ends_alike_through_every_door(ended, door):
    _, fit_cal, fit_rows, fit_cals = ended['fit']
    said, cal, rows, cals = ended[door]
    # The same calibration file: the accelerometer, the gyroscope, the units, the sensor.
    for field in ('T', 'bias'):
        np.testing.assert_allclose(getattr(cal, field), getattr(fit_cal, field), rtol=1e-9,
                                   err_msg=field)
    # A live door keeps the raw rates as float32 (core.collector): the gyroscope's fit on
    # them agrees to that precision.
    for field in ('gyro_bias', 'gyro_T'):
        np.testing.assert_allclose(getattr(cal, field), getattr(fit_cal, field), atol=1e-6,
                                   err_msg=field)
    assert cal.predicted_accuracy == pytest.approx(fit_cal.predicted_accuracy, rel=1e-6)
    assert cal.gyro_predicted_accuracy == pytest.approx(fit_cal.gyro_predicted_accuracy,
                                                        rel=1e-3)
    assert (cal.method, cal.observations, cal.sensor_id, cal.input_units) == \
        (fit_cal.method, fit_cal.observations, SENSOR, {'accel': 'm/s2'})
    # The same history rows: window means, temperatures, weights, times and gyro means.
    assert set(rows) == set(fit_rows)
    for key in ('mean', 'temp', 'weight', 'time_s', 'gyro_mean'):
        np.testing.assert_allclose(rows[key], fit_rows[key], rtol=1e-12, err_msg=key)
    assert np.isfinite(rows['gyro_mean']).all() and len(rows['mean']) == 14
    assert len(cals) == len(fit_cals) == 1
    assert cals[0]['predicted_accuracy'] == pytest.approx(fit_cals[0]['predicted_accuracy'],
                                                          rel=1e-6)


def test_each_door_says_so_in_its_own_words(ended):
    node, fit, guide = (ended[d][0] for d in ('node', 'fit', 'guide'))
    assert node.accepted and node.gyro.calibrated and node.magnetometer.status == 'absent'
    assert node.magnetometer.reason == NODE.no_mag and node.saved_to
    assert fit['accepted'] and fit['sensors']['gyroscope']['status'] == 'calibrated'
    assert fit['sensors']['magnetometer']['reason'] == FIT.no_mag
    assert fit['history']['windows_added'] == 14
    assert 'wrote calibration' in guide and 'gyroscope: calibrated' in guide
    assert '14 windows and the calibration kept' in guide


def options_of(command):
    """Return the option strings of an ``accel-calib`` command."""
    parser = build_parser(command)
    sub = next(a for a in parser._actions if a.choices and command in a.choices)
    return {s for a in sub.choices[command]._actions for s in a.option_strings}


@pytest.mark.parametrize('command, words', [('fit', FIT), ('guide', GUIDE)])
def test_a_door_names_only_options_it_has(command, words):
    import re
    have = options_of(command)
    named = {m for text in words if text for m in re.findall(r'--[a-z][a-z-]*', text)}
    # Other commands a door points to are named with their command (accel-calib fit ...).
    elsewhere = {m for text in words if text
                 for m in re.findall(r'accel-calib fit (--[a-z][a-z-]*)', text)}
    assert named - elsewhere <= have, sorted(named - elsewhere - have)


def test_the_defaults_of_every_door_are_the_settings():
    fit = build_parser('fit').parse_args(['fit', 'x.csv'])
    guide = build_parser('guide').parse_args(['guide', '--simulate'])
    for args in (fit, guide):
        assert args.max_predicted_error == S.max_predicted_error
        assert args.method == S.method and args.gravity == S.gravity
    # --band-width's default depends on the recording (poses: the settings'; one still pose:
    # the thermal settings'): the value fit uses is the settings' one.
    from accel_calib_ros.cli.fit import settings
    fit.data = 'x.csv'
    assert (fit.max_residual_ratio, fit.max_weight_s, settings(fit).band_width_c) == \
        (S.max_residual_ratio, S.max_weight_s, S.band_width_c)
    assert (fit.max_gyro_error, fit.max_mag_error) == \
        (S.max_gyro_error, S.max_mag_error)


def test_a_failed_save_is_a_refusal_and_the_old_file_stays(recording, tmp_path):
    _, samples, windows = recording
    blocked = tmp_path / 'file'
    blocked.write_text('not a folder\n')
    outcome = finish_session(windows, S.replace(words=NODE), rate_hz=samples.rate_hz,
                             output=blocked / 'calibration.yaml',
                             history=HistoryTarget(tmp_path / 'h.sqlite', SENSOR))
    assert not outcome.accepted and outcome.refusal.startswith(f'cannot write {blocked}')
    assert outcome.cause == 'output'
    assert outcome.history is None and not (tmp_path / 'h.sqlite').exists()
    assert blocked.read_text() == 'not a folder\n'
    assert outcome.message().startswith('refused: cannot write')


def test_a_failed_history_is_a_note_not_a_lost_calibration(recording, tmp_path):
    _, samples, windows = recording
    (tmp_path / 'h.sqlite').write_bytes(b'this is not a database' * 100)
    outcome = finish_session(windows, S, rate_hz=samples.rate_hz,
                             output=tmp_path / 'c.yaml',
                             history=HistoryTarget(tmp_path / 'h.sqlite', SENSOR))
    assert outcome.accepted and outcome.saved_to and outcome.history is None
    assert len(outcome.notes) == 1 and outcome.notes[0].startswith('history not recorded')
    assert outcome.cause == 'output'
    assert load_calibration(tmp_path / 'c.yaml').observations == 14


def test_an_input_that_cannot_be_fitted_is_a_refusal_of_the_input(recording):
    _, samples, windows = recording
    outcome = finish_session(windows, S.replace(method='nonsense'),
                             rate_hz=samples.rate_hz)
    assert outcome.cause == 'input' and not outcome.accepted and 'nonsense' in outcome.refusal
    with pytest.raises(Exception):
        fit_and_accept(windows.observations(), S.replace(method='nonsense'))


def test_one_refused_outcome_for_every_door():
    for words in (NODE, FIT, GUIDE):
        out = refused('no', words=words, observations=3)
        assert (out.refusal, out.observations, out.accepted) == ('no', 3, False)
        assert out.gyro.reason == words.no_gyro and out.magnetometer.reason == words.no_mag
    assert isinstance(GUIDE, Words)


def test_a_door_may_stop_the_session_right_before_its_save(recording, tmp_path):
    _, samples, windows = recording
    asked = []
    outcome = finish_session(windows, S.replace(words=NODE), rate_hz=samples.rate_hz,
                             output=tmp_path / 'c.yaml', may_save=lambda: asked.append(1))
    assert asked == [1] and outcome.refusal == NODE.stopping and outcome.cause is None
    assert not (tmp_path / 'c.yaml').exists()
