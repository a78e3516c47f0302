"""Regressions found by fuzzing the command line with careless-user input."""

from accel_calib_ros.cli import main
import pytest


@pytest.fixture(scope='module')
def faces_csv(tmp_path_factory):
    """Return a short simulated recording of the six faces."""
    path = tmp_path_factory.mktemp('fuzz') / 'faces.csv'
    assert main(['simulate', '-o', str(path), '--poses', 'faces', '--hold', '1.5',
                 '--seed', '3']) == 0
    return path


@pytest.mark.parametrize('option, value', [
    ('--sigma-floor', '1e308'),     # squared: OverflowError (was an internal error)
    ('--gravity', '1e308'),         # overflowed inside the covariance, printed warnings
    ('--gravity', '-0'),
])
def test_advise_out_of_range_options_are_one_line_exit_2(faces_csv, capsys, option, value):
    capsys.readouterr()
    assert main(['advise', str(faces_csv), option, value, '--json']) == 2
    captured = capsys.readouterr()
    assert captured.out == ''
    assert option in captured.err and len(captured.err.strip().splitlines()) == 1


def test_history_listing_leaves_an_empty_file_alone(tmp_path, capsys):
    """``history --db`` on an empty file turned it into an SQLite database."""
    empty = tmp_path / 'empty.csv'
    empty.write_bytes(b'')
    assert main(['history', '--db', str(empty), '--json']) == 2
    captured = capsys.readouterr()
    assert 'not a history database' in captured.err
    assert len(captured.err.strip().splitlines()) == 1
    assert empty.read_bytes() == b''
    assert sorted(p.name for p in tmp_path.iterdir()) == ['empty.csv']


@pytest.mark.parametrize('text', ['t,ax,ay,az\n', 't,ax,ay,az\r\n', '\ufefft,ax,ay,az,temp\n'])
def test_apply_on_a_header_only_csv_is_one_line_exit_2(tmp_path, capsys, faces_csv, text):
    """A header-only CSV made the streaming reader of ``apply`` crash (UnboundLocalError)."""
    cal = tmp_path / 'cal.yaml'
    assert main(['fit', str(faces_csv), '--method', 'gn', '-o', str(cal),
                 '--max-predicted-error', '0.5']) == 0           # six faces: gn
    capsys.readouterr()
    data = tmp_path / 'header.csv'
    data.write_text(text, encoding='utf-8')
    out = tmp_path / 'out.csv'
    assert main(['apply', str(cal), str(data), '-o', str(out), '--json']) == 2
    err = capsys.readouterr().err
    assert 'no data rows' in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_simulate_device_link_never_replaces_a_regular_file(tmp_path, capsys):
    """``simulate-device --link FILE`` replaced FILE by a pty symlink and then removed it."""
    data = tmp_path / 'data.csv'
    data.write_text('t,ax,ay,az\n0,0,0,9.8\n')
    assert main(['simulate-device', '--link', str(data), '--duration', '0.01']) == 2
    err = capsys.readouterr().err
    assert 'not a symlink' in err and len(err.strip().splitlines()) == 1
    assert data.read_text() == 't,ax,ay,az\n0,0,0,9.8\n' and not data.is_symlink()


@pytest.mark.parametrize('name', ['data.csv', 'notes.txt'])
def test_history_plot_must_be_a_png(tmp_path, capsys, faces_csv, name):
    """``history --plot data.csv`` wrote a PNG over the user's CSV."""
    db = tmp_path / 'h.sqlite'
    assert main(['fit', str(faces_csv), '--method', 'gn', '--history', str(db),
                 '--sensor', 's1', '--max-predicted-error', '0.5']) == 0   # six faces: gn
    victim = tmp_path / name
    victim.write_text('keep me\n')
    capsys.readouterr()
    assert main(['history', '--db', str(db), '--plot', str(victim)]) == 2
    err = capsys.readouterr().err
    assert '.png' in err and len(err.strip().splitlines()) == 1
    assert victim.read_text() == 'keep me\n'


def test_calibration_loader_refuses_a_fifo_instead_of_blocking(tmp_path):
    """A FIFO named as the calibration file blocked the loader (and a node) forever."""
    import os
    from accel_calib_ros.core.errors import InputError
    from accel_calib_ros.dataio.calibration_file import load_calibration
    fifo = tmp_path / 'calibration.yaml'
    os.mkfifo(fifo)
    with pytest.raises(InputError, match='not a regular file'):
        load_calibration(fifo)


@pytest.mark.parametrize('with_output', [False, True])
def test_fit_of_data_in_wrong_units_is_refused_with_one_line(
        tmp_path, capsys, faces_csv, with_output):
    """
    Data scaled by 1e-9: refused at the border (exit 2), naming --units; nothing written.

    (It once ran the fit and refused it as implausible only with -o.)
    """
    import numpy as np
    rows = np.loadtxt(faces_csv, delimiter=',', skiprows=1, usecols=(0, 1, 2, 3))
    rows[:, 1:] *= 1e-9
    data = tmp_path / 'tiny.csv'
    np.savetxt(data, rows, delimiter=',', header='t,ax,ay,az', comments='')
    out = tmp_path / 'cal.yaml'
    out.write_text('old: file\n')
    argv = ['fit', str(data), '--method', 'gn', '--json']
    argv += ['-o', str(out)] if with_output else []
    assert main(argv) == 2
    captured = capsys.readouterr()
    assert captured.out == '' and captured.err.count('\n') == 1
    assert '--units' in captured.err and 'median |a|' in captured.err
    assert out.read_text() == 'old: file\n'


def test_allan_refuses_a_stuck_sensor_and_leaves_out_a_constant_gyro(tmp_path, capsys):
    """All-zero accelerometer data gave 'noise density 0' (and log(0) warnings) with exit 0."""
    import json
    import numpy as np
    t = np.arange(3000) * 0.01
    rng = np.random.default_rng(5)
    accel = rng.normal(0, 0.02, (3000, 3)) + [0, 0, 9.8]
    rows = np.column_stack([t, accel, np.zeros((3000, 3))])
    data = tmp_path / 'still.csv'
    np.savetxt(data, rows, delimiter=',', header='t,ax,ay,az,gx,gy,gz', comments='')
    assert main(['allan', str(data), '--json']) == 0
    captured = capsys.readouterr()
    assert json.loads(captured.out)['axes'] == ['ax', 'ay', 'az'] and captured.err == ''
    rows[:, 1:4] = 0.0
    np.savetxt(data, rows, delimiter=',', header='t,ax,ay,az,gx,gy,gz', comments='')
    assert main(['allan', str(data), '--json']) == 1
    err = capsys.readouterr().err
    assert 'never change' in err and len(err.strip().splitlines()) == 1


def test_numpy_runtime_warnings_do_not_reach_the_user(tmp_path, capsys, monkeypatch):
    """The advice on all-zero data printed numpy's 'invalid value in divide' on stderr."""
    import warnings
    import numpy as np
    monkeypatch.delenv('ACCEL_CALIB_DEBUG', raising=False)
    rows = np.column_stack([np.arange(2000) * 0.01, np.zeros((2000, 3))])
    data = tmp_path / 'zeros.csv'
    np.savetxt(data, rows, delimiter=',', header='t,ax,ay,az', comments='')
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        assert main(['advise', str(data), '--json']) == 0
    assert not [w for w in caught if issubclass(w.category, RuntimeWarning)]
    assert capsys.readouterr().err == ''


@pytest.mark.parametrize('argv', [
    ['fit', '{data}', '-o', ''],           # was: exit 0, nothing written, no word said
    ['diagnose', '{data}', '--report', ' '],
    ['allan', '{data}', '--plot', ''],
    ['advise', ''],                        # was: read '' as the current folder
    ['history', '--db', ''],
    ['simulate', '-o', 'x.csv', '--truth', ''],
])
def test_an_empty_file_name_is_a_usage_error(tmp_path, capsys, monkeypatch, faces_csv, argv):
    monkeypatch.chdir(tmp_path)
    assert main([a.format(data=faces_csv) for a in argv]) == 2
    err = capsys.readouterr().err
    assert 'empty name' in err and len(err.strip().splitlines()) == 1
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize('command', ['fit', 'advise', 'diagnose', 'allan'])
def test_a_refusal_with_json_still_prints_one_strict_json_object(tmp_path, capsys, command):
    """diagnose/allan/advise --json printed nothing on stdout when they refused (exit 1)."""
    import json
    data = tmp_path / 'one_row.csv'
    data.write_text('t,ax,ay,az\n0,0.1,0.2,9.8\n')
    assert main([command, str(data), '--json']) == 1
    captured = capsys.readouterr()
    lines = captured.out.strip().splitlines()
    assert len(lines) == 1
    summary = json.loads(lines[0], parse_constant=lambda c: pytest.fail(c))
    assert summary['accepted'] is False and summary['refusal'] in captured.err


def test_history_never_writes_into_a_foreign_sqlite_database(tmp_path, capsys, faces_csv):
    """``history --db bag.db3`` added its tables (and WAL mode) to a rosbag2 database."""
    import sqlite3
    bag = tmp_path / 'bag.db3'
    con = sqlite3.connect(bag)
    con.execute('CREATE TABLE messages (id INTEGER PRIMARY KEY, data BLOB)')
    con.commit()
    con.close()
    before = bag.read_bytes()
    for argv in (['history', '--db', str(bag), '--json'],
                 ['fit', str(faces_csv), '--history', str(bag), '--sensor', 's1']):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert 'not an accel_calib_ros history' in err and len(err.strip().splitlines()) == 1
    assert bag.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ['bag.db3']


@pytest.mark.parametrize('content, words', [
    (b'\xff\xfe\x00x\n', 'not UTF-8'),                   # was an internal error
    (b'1e308,1e308,1e308\n', 'non-zero finite length'),  # was overflow warnings on stderr
])
def test_simulate_device_bad_pose_file_is_one_line_exit_2(tmp_path, capsys, content, words):
    poses = tmp_path / 'poses.txt'
    poses.write_bytes(content)
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter('error')
        assert main(['simulate-device', '--poses', str(poses), '--duration', '0.01']) == 2
    err = capsys.readouterr().err
    assert words in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize('option', ['--truth-out', '--link'])
def test_simulate_device_outputs_never_overwrite_the_pose_file(tmp_path, capsys, option):
    """``--truth-out poses.txt --poses poses.txt`` wrote the truth YAML over the pose file."""
    poses = tmp_path / 'poses.txt'
    poses.write_text('1,0,0\n0,1,0\n0,0,1\n')
    argv = ['simulate-device', '--poses', str(poses), option, str(poses), '--duration', '0.01']
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert 'destroy the input' in err and len(err.strip().splitlines()) == 1
    assert poses.read_text() == '1,0,0\n0,1,0\n0,0,1\n'


@pytest.mark.parametrize('command', ['fit', 'advise', 'allan', 'diagnose'])
def test_repeated_time_stamps_are_bad_input_not_too_few_samples(tmp_path, capsys, command):
    """Unix times with 9 digits: 'fewer than two samples' (fit) or 'lasts 110 s, needs 10'."""
    import numpy as np
    t = np.round(1.7e9 + np.arange(3000) * 0.01, -1)         # 10 s resolution
    rows = np.column_stack([t, np.zeros(3000), np.zeros(3000), np.full(3000, 9.8)])
    data = tmp_path / 'unix.csv'
    np.savetxt(data, rows, delimiter=',', header='t,ax,ay,az', comments='', fmt='%.17g')
    assert main([command, str(data)]) == 2
    err = capsys.readouterr().err
    assert 'share their time stamp' in err and len(err.strip().splitlines()) == 1
