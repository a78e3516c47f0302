"""The history is transactional, survives damage and foreign files, and can forget."""

import contextlib
import hashlib
import io
import json
import os
import shutil
import sqlite3

from accel_calib_ros.cli import main
from accel_calib_ros.core.calibration import Calibration
from accel_calib_ros.core.errors import InputError
from accel_calib_ros.dataio.history import History, HistoryDamaged
from accel_calib_ros.dataio.sensor_id import normalise_sensor_id
from accel_calib_ros.sim.motion import simulate_session
from accel_calib_ros.sim.sensor import mpu9250_like
from damage_cases import DAMAGE, damage as _damage, EMPTY_IS_NEW
from hypothesis import given, HealthCheck, settings, strategies as st
import numpy as np
import peer_data
import pytest


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def digest(path):
    with open(path, 'rb') as f:
        return hashlib.sha256(f.read()).hexdigest()


@pytest.fixture(scope='module')
def sessions(tmp_path_factory):
    """Simulate a good session (24 poses) and a tilt-only one (every pose near +z)."""
    folder = tmp_path_factory.mktemp('hist16')
    good = folder / 'good.csv'
    assert main(['simulate', '-o', str(good), '--poses', '24', '--seed', '5']) == 0
    rng = np.random.default_rng(2)
    tilt = np.radians(rng.uniform(0, 20, 14))
    az = rng.uniform(0, 2 * np.pi, 14)
    dirs = np.c_[np.sin(tilt) * np.cos(az), np.sin(tilt) * np.sin(az), np.cos(tilt)]
    s = simulate_session(mpu9250_like(np.random.default_rng(5)), dirs, rng, hold_s=2.0)
    bad = folder / 'tilt.csv'
    peer_data.to_spec_csv(s.samples, bad)
    return good, bad


def _good_db(tmp_path, good, capsys, sensor='imu0'):
    db = tmp_path / 'h.sqlite'
    code, out, err = run(capsys, 'fit', good, '--history', db, '--sensor', sensor, '--json')
    assert code == 0, err
    return db, json.loads(out)


def test_a_refused_fit_writes_nothing_and_good_data_still_fits(tmp_path, capsys, sessions):
    """A refused fit --history stored its windows; good data were refused afterwards."""
    good, bad = sessions
    db = tmp_path / 'h.sqlite'
    code, out, err = run(capsys, 'fit', bad, '--history', db, '--sensor', 'imu0', '--json')
    assert code == 1 and not json.loads(out)['accepted']
    assert not db.exists() and os.listdir(tmp_path) == []      # not even created
    code, out, err = run(capsys, 'fit', good, '--history', db, '--sensor', 'imu0', '--json')
    assert code == 0, err
    first = json.loads(out)
    assert first['observations'] == 24 and first['history']['windows_added'] == 24
    before = digest(db)
    code, _, _ = run(capsys, 'fit', bad, '--history', db, '--sensor', 'imu0',
                     '--max-predicted-error', '1e-9')
    assert code == 1 and digest(db) == before                 # refused: byte-identical
    code, _, err = run(capsys, 'fit', good, '--history', db, '--sensor', 'imu0', '-o',
                       tmp_path / 'nowhere' / 'x' / '..' / '..' / 'f' / 'c.yaml')
    with History(db, readonly=True) as h:
        assert len(h.windows('imu0')['mean']) == 24
        assert len(h.calibrations('imu0')) == 1 + (code == 0)
        assert len(h.sessions('imu0')) == 1 + (code == 0)


def test_a_failed_calibration_write_leaves_the_history_alone(tmp_path, capsys, sessions,
                                                             monkeypatch):
    good, _ = sessions
    db, _ = _good_db(tmp_path, good, capsys)
    before = digest(db)
    from accel_calib_ros.dataio import calibration_file

    def broken(cal, path):
        raise OSError(28, 'No space left on device')

    monkeypatch.setattr(calibration_file, 'save_calibration', broken)
    code, _, err = run(capsys, 'fit', good, '--history', db, '--sensor', 'imu0', '-o',
                       tmp_path / 'c.yaml')
    assert code == 2 and 'No space left' in err
    assert digest(db) == before


def test_forget_removes_a_session_or_every_session(tmp_path, capsys, sessions):
    good, _ = sessions
    db, first = _good_db(tmp_path, good, capsys)
    other = tmp_path / 'other.csv'
    assert main(['simulate', '-o', str(other), '--poses', '20', '--seed', '5', '--hold',
                 '2.5']) == 0                            # the same sensor, other poses
    capsys.readouterr()
    code, out, err = run(capsys, 'fit', other, '--history', db, '--sensor', 'imu0', '--json')
    assert code == 0, err
    second = json.loads(out)
    assert second['observations'] == 44
    code, out, _ = run(capsys, 'history', '--db', db, '--json')
    listing = json.loads(out)
    assert [s['session'] for s in listing['sessions']] == [first['history']['session'],
                                                           second['history']['session']]
    code, out, err = run(capsys, 'history', 'forget', '--db', db, '--sensor', 'imu0',
                         '--session', first['history']['session'])
    assert code == 0 and '24 windows, 1 calibrations' in out, err
    with History(db, readonly=True) as h:
        assert len(h.windows('imu0')['mean']) == 20 and len(h.calibrations('imu0')) == 1
    code, _, err = run(capsys, 'history', 'forget', '--db', db, '--sensor', 'imu0',
                       '--session', 'no-such-session')
    assert code == 2 and 'nothing to forget' in err
    code, _, err = run(capsys, 'history', 'forget', '--db', db)
    assert code == 2 and '--sensor' in err
    code, out, _ = run(capsys, 'history', 'forget', '--db', db, '--sensor', ' imu0 ')
    assert code == 0 and '20 windows' in out
    with History(db, readonly=True) as h:
        assert h.sensors() == [] and h.check() == []


V1_SCHEMA = """
CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE calibrations (id INTEGER PRIMARY KEY AUTOINCREMENT, sensor_id TEXT NOT NULL,
    time_s REAL NOT NULL, created TEXT, method TEXT, temp_min_c REAL, temp_max_c REAL,
    predicted_accuracy REAL, residual_rms REAL, windows INTEGER, T TEXT NOT NULL,
    bias TEXT NOT NULL, gyro_bias TEXT, source TEXT);
CREATE INDEX calibrations_sensor ON calibrations (sensor_id, time_s);
CREATE TABLE windows (id INTEGER PRIMARY KEY AUTOINCREMENT, sensor_id TEXT NOT NULL,
    time_s REAL NOT NULL, mx REAL NOT NULL, my REAL NOT NULL, mz REAL NOT NULL, temp_c REAL,
    weight REAL NOT NULL, gx REAL, gy REAL, gz REAL, UNIQUE (sensor_id, mx, my, mz, weight));
CREATE INDEX windows_sensor ON windows (sensor_id, time_s);
INSERT INTO meta VALUES ('schema', '1');
"""


def _v1_database(path, sensor='old'):
    db = sqlite3.connect(path)
    db.executescript(V1_SCHEMA)
    rng = np.random.default_rng(1)
    for k, m in enumerate(rng.normal(0, 5, (4, 3))):
        db.execute('INSERT INTO windows (sensor_id, time_s, mx, my, mz, temp_c, weight) '
                   'VALUES (?, ?, ?, ?, ?, ?, ?)', (sensor, 1.7e9 + k, *m, 25.0, 200.0))
    db.execute('INSERT INTO calibrations (sensor_id, time_s, method, windows, T, bias) '
               'VALUES (?, ?, ?, ?, ?, ?)', (sensor, 1.7e9, 'ml', 4, json.dumps(
                   np.eye(3).ravel().tolist()), json.dumps([0.1, 0.2, 0.3])))
    db.commit()
    db.close()


def test_a_schema_1_database_is_read_as_is_and_migrated_on_write(tmp_path, capsys):
    path = tmp_path / 'v1.sqlite'
    _v1_database(path)
    before = digest(path)
    code, out, err = run(capsys, 'history', '--db', path, '--json')
    assert code == 0, err
    listing = json.loads(out)
    assert listing['sessions'] == [{'sensor_id': 'old', 'session': 'legacy', 'windows': 4,
                                    'calibrations': 1}]
    assert digest(path) == before                      # listing never writes
    code, _, _ = run(capsys, 'history', 'check', '--db', path)
    assert code == 0 and digest(path) == before
    with History(path) as h:                           # opened for writing: migrated
        assert h.version == '2'
        h.add_calibration('old', Calibration(T=np.eye(3), bias=np.zeros(3)), session='s2')
        assert [s['session'] for s in h.sessions('old')] == ['legacy', 's2']
    code, out, _ = run(capsys, 'history', 'forget', '--db', path, '--sensor', 'old',
                       '--session', 'legacy')
    assert code == 0 and '4 windows, 1 calibrations' in out
    with sqlite3.connect(path) as db:
        assert db.execute("SELECT value FROM meta WHERE key = 'schema'").fetchone() == ('2',)


@pytest.fixture(scope='module')
def good_db(tmp_path_factory, sessions):
    folder = tmp_path_factory.mktemp('gooddb')
    db = folder / 'h.sqlite'
    assert main(['fit', str(sessions[0]), '--history', str(db), '--sensor', 'imu0']) == 0
    with sqlite3.connect(db) as c:
        c.execute('PRAGMA wal_checkpoint(TRUNCATE)')
    return db


@pytest.mark.parametrize('how', DAMAGE)
def test_a_damaged_or_foreign_database_is_named_never_an_internal_error(tmp_path, capsys,
                                                                        sessions, good_db,
                                                                        how):
    path = tmp_path / 'h.sqlite'
    shutil.copy(good_db, path)
    _damage(path, how)
    before = digest(path)
    plot = tmp_path / 'p.png'
    for argv in (['history', '--db', path], ['history', '--db', path, '--json'],
                 ['history', '--db', path, '--plot', plot], ['history', 'check', '--db', path],
                 ['fit', sessions[0], '--history', path, '--sensor', 'imu0'],
                 ['history', 'forget', '--db', path, '--sensor', 'imu0', '--session', 'x']):
        if how in EMPTY_IS_NEW and argv[0] == 'fit':
            continue
        code, out, err = run(capsys, *argv)
        assert code == 2, (how, argv, code, err)
        assert err.count('\n') == 1 and 'internal error' not in err, (how, argv, err)
        assert len(err) <= 210
        words = ('damaged', 'not a history', 'something else', 'schema', 'empty', 'problem',
                 'row', 'nothing to forget', 'lacks column', 'meta table')
        assert any(w in err for w in words), (how, argv, err)
        if argv[1] != 'forget':
            assert digest(path) == before, (how, argv)
    assert not plot.exists()


def test_history_check_reports_the_damage(tmp_path, capsys, good_db):
    path = tmp_path / 'h.sqlite'
    shutil.copy(good_db, path)
    code, out, err = run(capsys, 'history', 'check', '--db', path, '--json')
    assert code == 0 and json.loads(out) == {'db': str(path), 'ok': True, 'problems': []}
    _damage(path, 'wrong_size_T')
    db = sqlite3.connect(path)
    db.execute("UPDATE windows SET time_s = 'noon' WHERE id IN (1, 2)")
    db.commit()
    db.close()
    code, out, err = run(capsys, 'history', 'check', '--db', path, '--json')
    report = json.loads(out)
    assert code == 2 and not report['ok'] and len(report['problems']) == 3
    assert any('T holds [1, 2, 3]' in p for p in report['problems'])
    assert sum("time_s is 'noon'" in p for p in report['problems']) == 2
    assert all("session '" in p for p in report['problems'])
    code, out, _ = run(capsys, 'history', 'check', '--db', path)
    assert code == 2 and out.count('damaged:') == 3


def test_writing_into_a_damaged_file_is_refused_and_leaves_it(tmp_path, good_db):
    path = tmp_path / 'h.sqlite'
    shutil.copy(good_db, path)
    _damage(path, 'zero_page_3')
    before = digest(path)
    with pytest.raises(HistoryDamaged):
        with History(path) as h:
            h.add_calibration('imu0', Calibration(T=np.eye(3), bias=np.zeros(3)))
    assert digest(path) == before


def test_sensor_ids_are_normalised_and_checked_at_the_border(tmp_path, capsys, sessions):
    """' padded ' and 'padded' are one sensor; control and bidi characters are refused."""
    assert normalise_sensor_id(' padded ') == 'padded'
    assert normalise_sensor_id('e\u0301') == '\u00e9'            # NFC: one sensor
    for bad in ('', '   ', 'a\x00b', 'imu\n2', 'evil\u202egnp', 'zero\u200bwidth', 'x' * 201,
                'tab\there', 'del\x7f', None, 3):
        with pytest.raises(InputError):
            normalise_sensor_id(bad)
    good, _ = sessions
    db = tmp_path / 'h.sqlite'
    assert run(capsys, 'fit', good, '--history', db, '--sensor', ' padded ')[0] == 0
    code, out, err = run(capsys, 'fit', good, '--history', db, '--sensor', 'padded', '--json')
    assert code == 0 and json.loads(out)['observations'] == 24      # the same 24 windows
    for bad in ('evil\u202egnp', 'a\x1b[2Jb', '   ', 'x' * 300):
        code, _, err = run(capsys, 'fit', good, '--history', db, '--sensor', bad)
        assert code == 2 and err.count('\n') == 1 and '\x1b' not in err and '\u202e' not in err
        code, _, err = run(capsys, 'history', '--db', db, '--sensor', bad)
        assert code == 2
    with History(db, readonly=True) as h:
        assert h.sensors() == ['padded'] and len(h.calibrations(' padded\t')) == 2
    with History(db) as h, pytest.raises(InputError):
        h.add_windows('a\u202eb', [[0, 0, 9.8]], 20.0, 100.0, 1.7e9)


@pytest.mark.parametrize('sensor', ['$\\x$', '$x^2$ and $', '_hidden', 'naïve ☃ 日本',
                                    '\\frac{1}{2}', '$$'])
def test_math_text_in_a_sensor_id_is_drawn_as_text(tmp_path, capsys, sessions, sensor):
    """A sensor id like ``$x^2$`` broke ``history --plot`` (matplotlib math text)."""
    import warnings
    db = tmp_path / 'h.sqlite'
    assert run(capsys, 'fit', sessions[0], '--history', db, '--sensor', sensor)[0] == 0
    plot = tmp_path / 'drift.png'
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        code, out, err = run(capsys, 'history', '--db', db, '--plot', plot)
    assert code == 0, err
    assert plot.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'


def test_listing_a_history_never_writes_it(tmp_path, capsys, good_db):
    path = tmp_path / 'h.sqlite'
    shutil.copy(good_db, path)
    os.chmod(path, 0o444)
    before = digest(path)
    assert run(capsys, 'history', '--db', path)[0] == 0
    assert run(capsys, 'history', 'check', '--db', path)[0] == 0
    assert digest(path) == before and sorted(os.listdir(tmp_path)) in (
        ['h.sqlite'], ['h.sqlite', 'h.sqlite-shm', 'h.sqlite-wal'])
    for how, words in (('directory', 'directory'), ('fifo', 'not a regular file')):
        other = tmp_path / how
        os.mkdir(other) if how == 'directory' else os.mkfifo(other)
        code, _, err = run(capsys, 'history', '--db', other)
        assert code == 2 and words in err, err


def test_sqlite_side_files_follow_the_same_rules(tmp_path, capsys, sessions):
    """Side files (DB-wal, DB-shm, DB-journal) sqlite opens by name: no FIFO, no foreign link."""
    db = tmp_path / 'h.sqlite'
    os.mkfifo(tmp_path / 'h.sqlite-wal')
    code, _, err = run(capsys, 'fit', sessions[0], '--history', db, '--sensor', 'imu0')
    assert code == 2 and 'FIFO' in err, err
    assert not db.exists()


_CELLS = st.one_of(st.none(), st.integers(-2 ** 63, 2 ** 63 - 1), st.floats(allow_nan=False),
                   st.text(max_size=20), st.binary(max_size=20),
                   st.sampled_from(['[1, 2, 3]', '[' + ', '.join(['1e308'] * 9) + ']',
                                    '[1, 0, 0, 0, 1, 0, 0, 0, 1]', '{}', 'null', '[[1]]',
                                    '["a", "b", "c"]', 'NaN', '1e999']))
_COLUMNS = {'calibrations': ['sensor_id', 'time_s', 'created', 'method', 'temp_min_c',
                             'temp_max_c', 'predicted_accuracy', 'residual_rms', 'windows',
                             'T', 'bias', 'gyro_bias', 'source', 'session'],
            'windows': ['sensor_id', 'time_s', 'mx', 'my', 'mz', 'temp_c', 'weight', 'gx', 'gy',
                        'gz', 'session']}


@settings(max_examples=40, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(table=st.sampled_from(sorted(_COLUMNS)), data=st.data(), value=_CELLS)
def test_any_value_in_any_cell_is_read_or_named(tmp_path_factory, good_db, sessions, table,
                                                data, value):
    """Whatever another program wrote into a cell: exit 0, 1 or 2 with one line, no crash."""
    column = data.draw(st.sampled_from(_COLUMNS[table]))
    path = tmp_path_factory.mktemp('cell') / 'h.sqlite'
    shutil.copy(good_db, path)
    db = sqlite3.connect(path)
    try:
        db.execute(f'UPDATE {table} SET {column} = ? WHERE id = 1', (value,))
        db.commit()
    except sqlite3.IntegrityError:          # NOT NULL / UNIQUE: sqlite itself refuses it
        return
    finally:
        db.close()
    for argv in (['history', '--db', path, '--json'], ['history', 'check', '--db', path],
                 ['fit', sessions[0], '--history', path, '--sensor', 'imu0']):
        out, err = io.StringIO(), io.StringIO()
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            code = main([str(a) for a in argv])
        text = err.getvalue()
        assert code in (0, 1, 2) and 'internal error' not in text, (column, value, argv, text)
        if code == 2:
            assert text.count('\n') == 1, text


def test_an_empty_file_becomes_a_history_when_a_fit_is_accepted(tmp_path, capsys, sessions):
    db = tmp_path / 'h.sqlite'
    db.touch()                                            # e.g. made ready by a script
    code, _, err = run(capsys, 'history', '--db', db)
    assert code == 2 and 'empty' in err                   # listing never writes it
    code, out, err = run(capsys, 'fit', sessions[0], '--history', db, '--sensor', 'imu0',
                         '--json')
    assert code == 0 and json.loads(out)['history']['windows_added'] == 24, err
