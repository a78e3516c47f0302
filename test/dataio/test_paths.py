"""Outputs: nothing destroyed, nothing poisoned: the one border of every writer."""

import os
import stat

from accel_calib_ros.cli import main
from accel_calib_ros.core.errors import InputError
from accel_calib_ros.dataio.atomic import (atomic_write_text, output_target, temp_name,
                                           UnsafeOutput)
from accel_calib_ros.dataio.calibration_file import calibration_from_dict
from hypothesis import given, HealthCheck, settings, strategies as st
import path_cases
import pytest
import yaml


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope='module')
def inputs(tmp_path_factory):
    base = tmp_path_factory.mktemp('path_inputs')
    os.chmod(base, 0o755)
    return path_cases.make_inputs(str(base / 'inputs'))


@pytest.fixture
def shared_tmp():
    """Make a folder every user can reach (pytest's own tmp folders are private to root)."""
    import shutil
    import tempfile
    folder = tempfile.mkdtemp(prefix='accel16-')
    os.chmod(folder, 0o755)
    yield folder
    shutil.rmtree(folder, ignore_errors=True)


def _runner_and_other():
    if path_cases.can_chown():
        return os.geteuid(), path_cases.NOBODY
    return os.geteuid(), os.geteuid()          # no foreign owner without root


_FOREIGN = {'foreign_link_to_own', 'foreign_link_to_foreign', 'foreign_dangling_link',
            'foreign_file', 'through_foreign_dir_link', 'char_device'}


@settings(max_examples=60, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(kind=st.sampled_from(path_cases.KINDS), place=st.sampled_from(path_cases.PLACES),
       command=st.sampled_from(('fit', 'apply')))
def test_no_output_path_changes_an_input_or_a_foreign_file(tmp_path_factory, inputs, kind,
                                                           place, command):
    """Any output path: inputs and every other file stay byte-identical, no temp left."""
    runner, other = _runner_and_other()
    if kind in _FOREIGN and runner == other:
        return                                          # needs a second user (root only)
    root = str(tmp_path_factory.mktemp('case'))
    os.chmod(root, 0o755)
    case = path_cases.build_case(os.path.join(root, 'c'), inputs, kind, place, command, runner,
                                 other)
    before = path_cases.snapshot(root)
    code, _, err = path_cases.run_cli(case['argv'])
    problems = path_cases.violations(case, code, err, before, path_cases.snapshot(root))
    assert not problems, (case['kind'], case['place'], case['command'], problems)


@pytest.mark.skipif(not path_cases.can_chown(), reason='switching to another user needs root')
def test_every_kind_of_path_as_root_and_as_an_unprivileged_user(shared_tmp):
    """The whole set, run by root and by nobody (a forked child that dropped root)."""
    made = path_cases.make_inputs(os.path.join(shared_tmp, 'inputs'))
    for runner, other in ((0, path_cases.NOBODY), (path_cases.NOBODY, 0)):
        root = os.path.join(shared_tmp, f'as{runner}')
        cases, bad = path_cases.check_all(root, made, runner, other)
        assert len(cases) > 80
        assert not bad, [(c['kind'], c['place'], c['command'], p) for c, p in bad]


def test_output_inside_a_bag_is_refused_for_every_name(tmp_path, capsys, inputs):
    """``fit BAG -o BAG/metadata.yaml`` destroyed the bag."""
    import shutil
    bag = tmp_path / 'bag'
    shutil.copytree(os.path.join(inputs, 'bag'), bag)
    storage = next(p for p in bag.iterdir() if p.suffix == '.mcap')
    before = {p.name: p.read_bytes() for p in bag.iterdir()}
    for data in (bag, storage):
        for name in ('metadata.yaml', storage.name, 'new.yaml', 'sub/new.yaml'):
            code, _, err = run(capsys, 'fit', data, '-o', bag / name)
            assert code == 2 and err.count('\n') == 1, err
            assert 'inside the input' in err or 'is the input' in err, err
    code, _, err = run(capsys, 'apply', os.path.join(inputs, 'cal.yaml'), bag, '-o',
                       bag / 'corrected.csv')
    assert code == 2 and 'inside the input' in err
    code, _, err = run(capsys, 'diagnose', bag, '--report', bag / 'report')
    assert code == 2 and 'inside the input' in err
    assert {p.name: p.read_bytes() for p in bag.iterdir()} == before


@pytest.fixture
def fifo(tmp_path):
    path = tmp_path / 'target.csv'
    os.mkfifo(path)
    return path


def _writers(inputs, target, tmp_path):
    data, cal = os.path.join(inputs, 'data.csv'), os.path.join(inputs, 'cal.yaml')
    png = target.with_suffix('.png')
    return {
        'fit -o': ['fit', data, '-o', target],
        'fit --history': ['fit', data, '--history', target, '--sensor', 'imu'],
        'apply -o': ['apply', cal, data, '-o', target],
        'simulate -o': ['simulate', '-o', target, '--poses', '3', '--hold', '0.2'],
        'simulate --truth': ['simulate', '-o', tmp_path / 's.csv', '--poses', '3', '--hold',
                             '0.2', '--truth', target],
        'allan --plot': ['allan', data, '--plot', png],
        'history --plot': ['history', '--db', tmp_path / 'h.sqlite', '--plot', png],
        'diagnose --report': ['diagnose', data, '--report', target],
        'guide -o': ['guide', '--simulate', '-o', target, '--timeout', '1'],
        'guide --record': ['guide', '--simulate', '-o', tmp_path / 'g.yaml', '--record',
                           target, '--timeout', '1'],
        'guide --history': ['guide', '--simulate', '-o', tmp_path / 'g.yaml', '--history',
                            target, '--timeout', '1'],
        'simulate-device --link': ['simulate-device', '--link', target, '--duration', '0.01'],
        'simulate-device --truth-out': ['simulate-device', '--truth-out', target,
                                        '--duration', '0.01'],
    }


@pytest.mark.parametrize('writer', ['fit -o', 'fit --history', 'apply -o', 'simulate -o',
                                    'simulate --truth', 'allan --plot', 'history --plot',
                                    'diagnose --report', 'guide -o', 'guide --record',
                                    'guide --history', 'simulate-device --link',
                                    'simulate-device --truth-out'])
def test_every_writer_refuses_a_fifo_and_a_foreign_link(tmp_path, capsys, inputs, writer):
    """The same border for every option that writes: a FIFO or another user's link."""
    if writer == 'history --plot':
        assert main(['fit', os.path.join(inputs, 'data.csv'), '--history',
                     tmp_path / 'h.sqlite', '--sensor', 'imu']) == 0
        capsys.readouterr()
    target = tmp_path / 'target.csv'
    png = target.with_suffix('.png')
    for path in (target, png):
        os.mkfifo(path)
    argv = _writers(inputs, target, tmp_path)[writer]
    code, _, err = run(capsys, *argv)
    assert code == 2 and err.count('\n') == 1, err
    assert 'FIFO' in err or 'not a folder' in err or 'not a symlink' in err, err
    assert stat.S_ISFIFO(os.lstat(target).st_mode) and stat.S_ISFIFO(os.lstat(png).st_mode)
    if not path_cases.can_chown():
        return
    shared = tmp_path / 'shared'
    shared.mkdir()
    shared.chmod(0o1777)
    victim = tmp_path / 'victim.csv'
    victim.write_text('t,ax,ay,az\n')
    for name in ('target.csv', 'target.png', 'target'):
        os.symlink(victim, shared / name)
        os.chown(shared / name, path_cases.NOBODY, path_cases.NOBODY, follow_symlinks=False)
    argv = _writers(inputs, shared / 'target.csv', tmp_path)[writer]
    code, _, err = run(capsys, *argv)
    assert code == 2 and err.count('\n') == 1, err
    assert victim.read_text() == 't,ax,ay,az\n'
    assert all(os.path.islink(shared / n) for n in ('target.csv', 'target.png', 'target'))


@pytest.mark.skipif(not path_cases.can_chown(), reason='mknod needs root')
def test_a_device_is_never_replaced(tmp_path, capsys, inputs):
    """``fit --json -o /dev/null`` as root replaced the device by a 0666 regular file."""
    dev = tmp_path / 'null'
    os.mknod(dev, stat.S_IFCHR | 0o666, os.makedev(1, 3))
    for argv in (['fit', os.path.join(inputs, 'data.csv'), '--json', '-o', dev],
                 ['apply', os.path.join(inputs, 'cal.yaml'), os.path.join(inputs, 'data.csv'),
                  '-o', dev],
                 ['fit', os.path.join(inputs, 'data.csv'), '-o', '/dev/null']):
        code, _, err = run(capsys, *argv)
        assert code == 2 and 'character device' in err, err
    assert stat.S_ISCHR(os.lstat(dev).st_mode) and stat.S_ISCHR(os.lstat('/dev/null').st_mode)


def test_temp_names_fit_in_name_max():
    """Legal 242..255-byte names were refused: the temp name added its suffix."""
    for name in ('n' * 251 + '.csv', 'é' * 125 + '.csv', '日' * 84 + '.png', 'x' * 255,
                 'a.' + 'b' * 253, '.hidden'):
        tmp = temp_name('/tmp', name, 'abcd1234')
        assert len(os.fsencode(tmp)) <= 255 and tmp.startswith('.'), (name, tmp)
        tmp.encode('utf-8')                              # no half character
        if name.endswith(('.csv', '.png')):
            assert tmp.endswith(name[-4:])


def test_names_of_255_bytes_are_written(tmp_path, capsys, inputs):
    data = os.path.join(inputs, 'data.csv')
    for argv, name in ((['fit', data, '-o'], 'f' * 250 + '.yaml'),
                       (['apply', os.path.join(inputs, 'cal.yaml'), data, '-o'],
                        'é' * 125 + '.csv'),
                       (['simulate', '--poses', '3', '--hold', '0.2', '-o'], 'b' * 250 + '.mcap'),
                       (['allan', data, '--plot'], 'p' * 251 + '.png')):
        code, _, err = run(capsys, *argv, tmp_path / name)
        assert code == 0, err
        assert (tmp_path / name).is_file()
    assert all(not n.startswith('.') for n in os.listdir(tmp_path))


def test_a_failed_write_removes_the_folders_it_made(tmp_path, capsys, inputs, monkeypatch):
    data = os.path.join(inputs, 'data.csv')
    code, _, err = run(capsys, 'fit', data, '-o', tmp_path / 'new' / 'deep' / ('x' * 300))
    assert code == 2 and err.count('\n') == 1
    assert not (tmp_path / 'new').exists()
    from accel_calib_ros.dataio import atomic

    def full(src, dst):
        raise OSError(28, 'No space left on device')

    monkeypatch.setattr(atomic.os, 'replace', full)
    with pytest.raises(OSError):
        atomic_write_text(tmp_path / 'a' / 'b' / 'c.txt', 'x', make_dirs=True)
    code, _, err = run(capsys, 'fit', data, '-o', tmp_path / 'n2' / 'c.yaml')
    assert code == 2 and 'No space left' in err
    assert os.listdir(tmp_path) == []


def test_dash_is_standard_output_where_text_makes_sense(tmp_path, capsys, inputs, monkeypatch):
    monkeypatch.chdir(tmp_path)
    data, cal = os.path.join(inputs, 'data.csv'), os.path.join(inputs, 'cal.yaml')
    code, out, err = run(capsys, 'fit', data, '-o', '-')
    assert code == 0, err
    calibration_from_dict(yaml.safe_load(out))          # stdout holds exactly the YAML
    assert 'predicted accuracy' in err                 # the summary went to stderr
    code, out, err = run(capsys, 'apply', cal, data, '-o', '-')
    assert code == 0 and out.startswith('t,ax,ay,az') and 'corrected' in err
    with open(data) as f:
        assert len(out.splitlines()) == len(f.read().splitlines())
    code, out, err = run(capsys, 'simulate', '-o', '-', '--poses', '3', '--hold', '0.2')
    assert code == 0 and out.startswith('t,ax,ay,az') and 'simulated' in err
    for argv in (['fit', data, '-o', '-', '--json'], ['apply', cal, data, '-o', '-', '--json'],
                 ['allan', data, '--plot', '-'], ['diagnose', data, '--report', '-'],
                 ['simulate', '-o', 's.csv', '--truth', '-'],
                 ['fit', data, '--history', '-', '--sensor', 'x'],
                 ['guide', '--simulate', '-o', '-', '--timeout', '1'],
                 ['simulate-device', '--truth-out', '-', '--duration', '0.01'],
                 ['history', '--db', data, '--plot', '-']):
        code, out, err = run(capsys, *argv)
        assert code == 2 and err.count('\n') == 1 and 'Traceback' not in err, (argv, err)
        assert not out
    assert not os.path.exists(tmp_path / '-')


def test_tilde_user_is_expanded_or_refused(tmp_path, capsys, inputs, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv('HOME', str(tmp_path / 'home'))
    (tmp_path / 'home').mkdir()
    data = os.path.join(inputs, 'data.csv')
    code, _, err = run(capsys, 'fit', data, '-o', '~nouser_16/cal.yaml')
    assert code == 2 and "no user 'nouser_16'" in err
    assert os.listdir(tmp_path) == ['home']              # no literal '~nouser_16' folder
    code, _, err = run(capsys, 'fit', data, '-o', '~/cal.yaml')
    assert code == 0, err
    assert (tmp_path / 'home' / 'cal.yaml').is_file()
    code, _, err = run(capsys, 'apply', '~nouser_16/c.yaml', data, '-o', 'x.csv')
    assert code == 2 and 'nouser_16' in err


def test_output_target_rules_directly(tmp_path):
    """The writer itself refuses (a node or a library call has no CLI border)."""
    os.mkfifo(tmp_path / 'fifo')
    (tmp_path / 'dir').mkdir()
    (tmp_path / 'file').write_text('x')
    with pytest.raises(UnsafeOutput, match='FIFO'):
        atomic_write_text(tmp_path / 'fifo', 'x')
    with pytest.raises(UnsafeOutput, match='directory'):
        atomic_write_text(tmp_path / 'dir', 'x')
    with pytest.raises(UnsafeOutput, match='not a folder'):
        atomic_write_text(tmp_path / 'file' / 'x', 'x')
    assert isinstance(UnsafeOutput('x'), InputError)
    os.symlink(tmp_path / 'real', tmp_path / 'own')
    assert output_target(tmp_path / 'own') == str(tmp_path / 'real')
    atomic_write_text(tmp_path / 'own', 'through my own link')
    assert (tmp_path / 'real').read_text() == 'through my own link'
    assert os.path.islink(tmp_path / 'own')
    if path_cases.can_chown():
        os.symlink(tmp_path / 'file', tmp_path / 'theirs')
        os.chown(tmp_path / 'theirs', path_cases.NOBODY, path_cases.NOBODY,
                 follow_symlinks=False)
        with pytest.raises(UnsafeOutput, match='another user'):
            atomic_write_text(tmp_path / 'theirs', 'y')
        assert (tmp_path / 'file').read_text() == 'x'
    assert sorted(os.listdir(tmp_path)) == sorted(
        n for n in ('fifo', 'dir', 'file', 'own', 'real', 'theirs')
        if os.path.lexists(tmp_path / n))


@pytest.mark.skipif(not path_cases.can_chown(), reason='another owner needs root')
def test_replacing_a_users_file_as_root_keeps_its_owner(tmp_path):
    path = tmp_path / 'cal.yaml'
    path.write_text('old')
    os.chown(path, path_cases.NOBODY, path_cases.NOBODY)
    atomic_write_text(path, 'new')
    st = os.stat(path)
    assert path.read_text() == 'new' and (st.st_uid, st.st_gid) == (path_cases.NOBODY,) * 2


def test_simulate_device_link_rules(tmp_path, capsys):
    """The device re-points its own link; another user's link in a shared folder is theirs."""
    if not path_cases.can_chown():
        pytest.skip('another owner needs root')
    shared = tmp_path / 'shared'
    shared.mkdir()
    shared.chmod(0o1777)
    os.symlink('/dev/null', shared / 'imu0')
    os.chown(shared / 'imu0', path_cases.NOBODY, path_cases.NOBODY, follow_symlinks=False)
    code, _, err = run(capsys, 'simulate-device', '--link', shared / 'imu0', '--duration',
                       '0.01')
    assert code == 2 and 'another user' in err
    assert os.readlink(shared / 'imu0') == '/dev/null'


def test_a_temp_file_swapped_under_the_writer_replaces_nothing(tmp_path):
    """In a world-writable folder someone may rename the temp away: nothing is replaced."""
    from accel_calib_ros.dataio.atomic import atomic_file, atomic_path
    target = tmp_path / 'cal.yaml'
    target.write_text('old')
    with pytest.raises(UnsafeOutput, match='swapped'):
        with atomic_path(target) as tmp:
            os.remove(tmp)
            with open(tmp, 'w') as f:
                f.write('planted')
    assert target.read_text() == 'old'
    planted = [n for n in os.listdir(tmp_path) if n != 'cal.yaml']
    assert len(planted) == 1                 # not ours: left where the other user put it
    with atomic_file(target, 'w', encoding='utf-8') as f:       # written through its own fd
        f.write('new')
    assert target.read_text() == 'new'
    assert sorted(os.listdir(tmp_path)) == sorted(['cal.yaml'] + planted)


def test_a_second_output_that_cannot_be_written_stops_before_the_first(tmp_path, capsys):
    """``simulate -o A --truth missing/B`` wrote A, then failed: refused before A now."""
    code, _, err = run(capsys, 'simulate', '-o', tmp_path / 'a.csv', '--truth',
                       tmp_path / 'missing' / 'b.yaml')
    assert code == 2 and 'does not exist' in err
    code, _, err = run(capsys, 'guide', '--simulate', '-o', tmp_path / 'c.yaml', '--record',
                       tmp_path / 'missing' / 'r.csv', '--timeout', '1')
    assert code == 2 and 'does not exist' in err
    assert os.listdir(tmp_path) == []
