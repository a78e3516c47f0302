"""
Adversarial output paths for the CLI, and the invariant they must keep.

Shared by test/dataio/test_paths.py (Hypothesis as root, a fixed set as an unprivileged user)
and bench/bench_reliability.py (the "paths" row). A case is an output path of one kind
(a FIFO, a device, a link another user owns, a path inside an input bag, ...) in a
private or a shared (sticky, world-writable) folder, handed to ``fit -o``, ``apply -o`` or
``fit BAG -o``. The invariant: whatever the exit status, no input and no file other than
the one output allowed changes (every entry of the tree is hashed before and after), no
temporary file is left, a refusal is one line with exit status 2 and nothing crashes.

The tree is built by root (it needs ``chown`` and ``mknod``); the commands then run as the
"runner" (root itself, or an unprivileged user in a forked child, see :func:`run_as`).
"""

import contextlib
import hashlib
import io
import os
import pickle
import shutil
import signal
import socket
import stat
import sys
import time
import traceback
import warnings

KINDS = ('missing', 'own_file', 'fifo', 'socket', 'directory', 'char_device',
         'own_link_to_own', 'own_link_to_input', 'own_dangling_link', 'foreign_link_to_own',
         'foreign_link_to_foreign', 'foreign_dangling_link', 'link_loop', 'foreign_file',
         'readonly_own_file', 'input', 'hard_link_to_input', 'inside_bag_existing',
         'inside_bag_new', 'inside_bag_dotdot', 'through_own_dir_link',
         'through_foreign_dir_link', 'long_name', 'utf8_long_name', 'trailing_slash')
"""Every kind of output path a case may be."""
PLACES = ('private', 'shared')
COMMANDS = ('fit', 'apply', 'fit_bag')
NOBODY = 65534
"""The unprivileged user (nobody) the runner switches to when the tests run as root."""
_BAG_KINDS = ('inside_bag_existing', 'inside_bag_new', 'inside_bag_dotdot')


def can_chown():
    """Whether this process can build trees with other users' files (it is root)."""
    return hasattr(os, 'geteuid') and os.geteuid() == 0


def make_inputs(folder):
    """Write the inputs every case copies: a small session CSV, its calibration, its bag."""
    from accel_calib_ros.cli import main
    from accel_calib_ros.dataio.recording import load_samples, write_bag
    os.makedirs(folder, exist_ok=True)
    data = os.path.join(folder, 'data.csv')
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        assert main(['simulate', '-o', data, '--poses', '12', '--hold', '1.6', '--move', '0.5',
                     '--rate', '50', '--seed', '4']) == 0
        assert main(['fit', data, '-o', os.path.join(folder, 'cal.yaml')]) == 0
    write_bag(os.path.join(folder, 'bag'), load_samples(data))
    return folder


def _own(path, uid, follow=False):
    os.chown(path, uid, uid, follow_symlinks=follow)


def build_case(root, inputs, kind, place, command, runner_uid, other_uid):
    """
    Build one case under the new folder ``root``; return its description.

    :param root: a new folder for this case (made here).
    :param inputs: the folder of :func:`make_inputs`.
    :param kind: one of KINDS.
    :param place: 'private' (the runner's own folder) or 'shared' (sticky, world-writable).
    :param command: one of COMMANDS.
    :param runner_uid: who runs the command.
    :param other_uid: another user ("foreign" files and links belong to them).
    :return: dict argv, target (as given), expect ('refuse' or 'write'), allowed (the real
        path the command may create or change, or None).
    """
    os.makedirs(root)
    os.chmod(root, 0o755)
    inp = os.path.join(root, 'in')
    shutil.copytree(inputs, inp)
    for folder, dirs, files in os.walk(inp):
        for name in dirs + files:
            os.chmod(os.path.join(folder, name), 0o755 if name in dirs else 0o644)
    private = os.path.join(root, 'private')
    shared = os.path.join(root, 'shared')
    elsewhere = os.path.join(root, 'elsewhere')          # the other user's own folder
    for folder, mode in ((private, 0o755), (shared, 0o1777), (elsewhere, 0o755)):
        os.mkdir(folder)
        os.chmod(folder, mode)
    _own(private, runner_uid)
    _own(elsewhere, other_uid)
    victim = os.path.join(elsewhere, 'victim.csv')
    with open(victim, 'w') as f:
        f.write('t,ax,ay,az\n0,0,0,9.8\n')
    _own(victim, other_uid)
    mine = os.path.join(private, 'mine.csv')
    with open(mine, 'w') as f:
        f.write('my own file\n')
    _own(mine, runner_uid)
    here = private if place == 'private' else shared
    name = 'out.csv'
    target = os.path.join(here, name)
    refuse, allowed = False, target

    def link(dest, path, uid):
        os.symlink(dest, path)
        _own(path, uid)

    trusted_other = other_uid == 0 and place == 'private'      # root's link, not shared
    if kind == 'missing':
        pass
    elif kind == 'own_file':
        with open(target, 'w') as f:
            f.write('old\n')
        _own(target, runner_uid)
    elif kind == 'readonly_own_file':
        with open(target, 'w') as f:
            f.write('old\n')
        _own(target, runner_uid)
        os.chmod(target, 0o444)
        refuse = runner_uid != 0                          # root may write anything
    elif kind == 'fifo':
        os.mkfifo(target)
        refuse = True
    elif kind == 'socket':
        s = socket.socket(socket.AF_UNIX)
        try:
            s.bind(target)
        except OSError:                                   # path too long for AF_UNIX
            os.mkfifo(target)
        s.close()
        refuse = True
    elif kind == 'directory':
        os.mkdir(target)
        refuse = True
    elif kind == 'char_device':
        os.mknod(target, stat.S_IFCHR | 0o666, os.makedev(1, 3))     # a /dev/null twin
        refuse = True
    elif kind == 'own_link_to_own':
        link(mine, target, runner_uid)
        allowed = mine
    elif kind == 'own_link_to_input':
        link(os.path.join(inp, 'data.csv'), target, runner_uid)
        refuse = True
    elif kind == 'own_dangling_link':
        allowed = os.path.join(private, 'created.csv')
        link(allowed, target, runner_uid)
    elif kind == 'foreign_link_to_own':
        link(mine, target, other_uid)
        refuse, allowed = not trusted_other, mine
    elif kind == 'foreign_link_to_foreign':
        link(victim, target, other_uid)
        # even a trusted (root's) link leads to a file the unprivileged runner may not write
        refuse, allowed = not trusted_other or runner_uid != 0, victim
    elif kind == 'foreign_dangling_link':
        allowed = os.path.join(elsewhere, 'planted.csv')
        link(allowed, target, other_uid)
        refuse = not trusted_other or runner_uid != 0     # elsewhere is not the runner's
    elif kind == 'link_loop':
        link(os.path.join(here, 'loop2'), target, runner_uid)
        link(target, os.path.join(here, 'loop2'), runner_uid)
        refuse = True
    elif kind == 'foreign_file':
        with open(target, 'w') as f:
            f.write('theirs\n')
        _own(target, other_uid)
        # shared: protected_regular; private: writable only by root (0644)
        refuse = place == 'shared' or runner_uid != 0
    elif kind == 'input':
        target = os.path.join(inp, 'data.csv')
        refuse = True
    elif kind == 'hard_link_to_input':
        os.link(os.path.join(inp, 'data.csv'), target)
        refuse = True
    elif kind in _BAG_KINDS:
        command = 'fit_bag'
        target = {'inside_bag_existing': os.path.join(inp, 'bag', 'metadata.yaml'),
                  'inside_bag_new': os.path.join(inp, 'bag', 'new.csv'),
                  'inside_bag_dotdot': os.path.join(here, '..', 'in', 'bag', 'x.csv')}[kind]
        refuse = True
    elif kind == 'through_own_dir_link':
        sub = os.path.join(private, 'sub')
        os.mkdir(sub)
        _own(sub, runner_uid)
        link(sub, os.path.join(here, 'dlink'), runner_uid)
        target = os.path.join(here, 'dlink', name)
        allowed = os.path.join(sub, name)
    elif kind == 'through_foreign_dir_link':
        link(elsewhere, os.path.join(here, 'dlink'), other_uid)
        target = os.path.join(here, 'dlink', name)
        allowed = os.path.join(elsewhere, name)
        refuse = not trusted_other or runner_uid != 0
    elif kind == 'long_name':
        target = os.path.join(here, 'n' * 251 + '.csv')
        allowed = target
    elif kind == 'utf8_long_name':
        target = os.path.join(here, 'é' * 125 + '.csv')      # 254 bytes
        allowed = target
    elif kind == 'trailing_slash':
        target = os.path.join(here, 'newdir') + os.sep
        refuse = True
    else:
        raise ValueError(kind)
    data = os.path.join(inp, 'data.csv')
    argv = {'fit': ['fit', data, '-o', target],
            'apply': ['apply', os.path.join(inp, 'cal.yaml'), data, '-o', target],
            'fit_bag': ['fit', os.path.join(inp, 'bag'), '-o', target]}[command]
    return {'argv': argv, 'target': target, 'kind': kind, 'place': place, 'root': root,
            'command': command, 'expect': 'refuse' if refuse else 'write',
            'allowed': None if refuse else os.path.realpath(allowed)}


def snapshot(root):
    """
    Hash every entry under ``root`` (not following links): path -> what it is.

    Regular files by content, links by target, devices by number; type, mode and owner of
    every entry. Run as root (it reads every file).
    """
    out = {}
    for folder, dirs, files in os.walk(root):
        for name in dirs + files:
            path = os.path.join(folder, name)
            st = os.lstat(path)
            what = (stat.S_IFMT(st.st_mode), stat.S_IMODE(st.st_mode), st.st_uid, st.st_nlink)
            if stat.S_ISREG(st.st_mode):
                with open(path, 'rb') as f:
                    what += (hashlib.sha256(f.read()).hexdigest(),)
            elif stat.S_ISLNK(st.st_mode):
                what += (os.readlink(path),)
            elif stat.S_ISCHR(st.st_mode) or stat.S_ISBLK(st.st_mode):
                what += (st.st_rdev,)
            out[path] = what
    return out


def run_cli(argv):
    """Run ``accel-calib`` in-process: (exit status, stdout, stderr); a crash is status -1."""
    from accel_calib_ros.cli import main
    out, err = io.StringIO(), io.StringIO()
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            code = main([str(a) for a in argv])
    except BaseException:   # noqa: B902 - anything escaping main is a crash
        code = -1
        err.write(traceback.format_exc())
    return code, out.getvalue(), err.getvalue()


def violations(case, code, err, before, after):
    """
    Return what broke the invariant in one case (empty list: it held).

    :param case: from :func:`build_case`.
    :param code: the exit status.
    :param err: the standard error text.
    :param before: :func:`snapshot` before the command.
    :param after: :func:`snapshot` after it.
    """
    problems = []
    if code not in (0, 1, 2) or 'Traceback' in err or 'internal error' in err:
        problems.append(f'crash: status {code}: {err.strip()[-300:]}')
    if code == 2 and err.count('\n') != 1:
        problems.append(f'refusal not one line: {err!r}')
    if case['expect'] == 'refuse' and code != 2:
        problems.append(f'expected a refusal (2), got {code}')
    if case['expect'] == 'write' and code != 0:
        problems.append(f'expected a write (0), got {code}: {err.strip()}')
    allowed = case['allowed'] if code == 0 else None
    for path in sorted(set(before) | set(after)):
        if path == allowed:
            continue
        if before.get(path) != after.get(path):
            what = ('created' if path not in before else 'removed' if path not in after
                    else 'changed')
            problems.append(f'{what}: {path}')
    if allowed is not None:
        st = after.get(allowed)
        if st is None or not stat.S_ISREG(st[0]):
            problems.append(f'the output {allowed} was not written as a regular file')
    return problems


def run_cases(cases):
    """Run the cases' commands here (as whoever this process is); return [(code, err)]."""
    return [run_cli(case['argv'])[::2] for case in cases]


def warm_up(inputs):
    """Import what the commands import (a child that switched user may not read the stdlib)."""
    import csv  # noqa: F401
    import sqlite3  # noqa: F401
    import unicodedata  # noqa: F401
    import urllib.parse  # noqa: F401
    scratch = os.path.join(inputs, '..', 'warm')
    os.makedirs(scratch, exist_ok=True)
    run_cli(['fit', os.path.join(inputs, 'data.csv'), '-o', os.path.join(scratch, 'c.yaml')])
    run_cli(['fit', os.path.join(inputs, 'bag'), '-o', os.path.join(scratch, 'b.yaml')])
    run_cli(['apply', os.path.join(inputs, 'cal.yaml'), os.path.join(inputs, 'data.csv'), '-o',
             os.path.join(scratch, 'a.csv')])
    run_cli(['fit', os.path.join(inputs, 'data.csv'), '-o', '/dev/null'])
    shutil.rmtree(scratch, ignore_errors=True)


def run_as(uid, function, *args, timeout=600.0):
    """
    Call ``function(*args)`` in a forked child running as user ``uid``; return its result.

    The child inherits what this process imported (so it needs no access to the Python
    installation); its result comes back pickled. An exception in the child is raised
    here as a RuntimeError with its traceback.
    """
    read, write = os.pipe()
    with warnings.catch_warnings():
        warnings.simplefilter('ignore', DeprecationWarning)   # fork with threads (3.12)
        pid = os.fork()
    if pid == 0:                                              # the child
        code = 0
        try:
            os.close(read)
            os.setgroups([])
            os.setgid(uid)
            os.setuid(uid)
            result = ('ok', function(*args))
        except BaseException:   # noqa: B902 - everything goes back to the parent
            result = ('error', traceback.format_exc())
            code = 1
        try:
            data = pickle.dumps(result)
            view = memoryview(data)
            while view:
                view = view[os.write(write, view):]
        finally:
            os._exit(code)
    os.close(write)
    chunks, deadline = [], time.monotonic() + timeout
    with os.fdopen(read, 'rb') as f:
        while True:
            if time.monotonic() > deadline:
                os.kill(pid, signal.SIGKILL)
                os.waitpid(pid, 0)
                raise TimeoutError(f'the child running as uid {uid} took over {timeout} s')
            chunk = f.read(1 << 16)
            if not chunk:
                break
            chunks.append(chunk)
    os.waitpid(pid, 0)
    status, value = pickle.loads(b''.join(chunks))
    if status != 'ok':
        raise RuntimeError(f'in the child (uid {uid}):\n{value}')
    return value


def all_cases(root, inputs, runner_uid, other_uid, commands=('fit', 'apply')):
    """Build every kind x place x command (bag kinds once per place); return the cases."""
    cases = []
    k = 0
    for kind in KINDS:
        if kind == 'char_device' and not can_chown():
            continue
        for place in PLACES:
            for command in (('fit_bag',) if kind in _BAG_KINDS else commands):
                k += 1
                cases.append(build_case(os.path.join(root, f'case{k}'), inputs, kind, place,
                                        command, runner_uid, other_uid))
    return cases


def check_all(root, inputs, runner_uid, other_uid):
    """
    Build every case, run them as ``runner_uid`` (forked when it is not this process's).

    :return: (cases, list of (case, problems) that broke the invariant).
    """
    cases = all_cases(root, inputs, runner_uid, other_uid)
    before = snapshot(root)
    if runner_uid == os.geteuid():
        results = run_cases(cases)
    else:
        warm_up(inputs)
        results = run_as(runner_uid, run_cases, cases)
    after = snapshot(root)
    bad = []
    for case, (code, err) in zip(cases, results):
        mine = {p: v for p, v in before.items() if p.startswith(case['root'] + os.sep)}
        now = {p: v for p, v in after.items() if p.startswith(case['root'] + os.sep)}
        problems = violations(case, code, err, mine, now)
        if problems:
            bad.append((case, problems))
    return cases, bad


if __name__ == '__main__':          # a quick look: python test/path_cases.py
    import tempfile
    base = tempfile.mkdtemp()
    os.chmod(base, 0o755)
    made = make_inputs(os.path.join(base, 'inputs'))
    for uid, other in ((0, NOBODY), (NOBODY, 0)):
        found, broken = check_all(os.path.join(base, f'as{uid}'), made, uid, other)
        print(f'as uid {uid}: {len(found)} cases, {len(broken)} broke the invariant')
        for c, p in broken:
            print(' ', c['kind'], c['place'], c['command'], p)
    shutil.rmtree(base)
    sys.exit(0)
