"""
Atomic, safe file replacement: a reader sees the old file or the new one, never half of one.

Every writer here follows the same recipe: decide what may be written (:func:`output_target`),
create a temporary file in the target's own directory (so the final rename never crosses
a file system), write it, flush it, fsync it, ``os.replace`` it over the target and fsync
the directory so the rename itself survives a power cut. On any failure (a signal
included) the temporary file and the directories made for it are removed and the
previous target, if any, is left untouched.

What may be written (the same rules for every command and node that writes a file):

- an existing target must be a regular file: a directory, a device (``/dev/null``), a
  FIFO or a socket is refused, never replaced by a regular file;
- a symbolic link on the way (the target or a folder above it) is followed only when it
  belongs to the user running this (or, outside shared folders, to root): a link owned by
  someone else is refused, so nobody can make this process replace a file on their behalf;
- in a shared folder (sticky or world-writable, like ``/tmp``) an existing file owned by
  another user is refused (the kernel's ``protected_symlinks`` and ``protected_regular``
  rules, applied here whatever the system's settings), and so is any existing file this
  user may not write (a rename would bypass its permissions).

Temporary names fit in NAME_MAX (a 255-byte final name works), are created with
``O_EXCL | O_NOFOLLOW`` (never through a link) and start with a dot so they stay out of
the way. Permission bits: a replaced file keeps its mode (and, when run as root, its
owner); a new file gets the usual ``0o666`` minus the process umask.
"""

import contextlib
import os
import signal
import stat

from ..core.errors import InputError

__all__ = ['atomic_file', 'atomic_path', 'atomic_write_bytes', 'atomic_write_text',
           'output_target', 'UnsafeOutput']

MAX_LINKS = 40
"""Symbolic links followed on one path at most (the kernel's own limit)."""
_HELD_SIGNALS = {getattr(signal, name) for name in ('SIGINT', 'SIGTERM', 'SIGHUP')
                 if hasattr(signal, name)}


def _euid():
    """Return the effective user id (-1 where there is none, e.g. Windows)."""
    return os.geteuid() if hasattr(os, 'geteuid') else -1


class UnsafeOutput(InputError):
    """An output path this process must not write (one line; exit status 2 in the CLI)."""


def _kind(mode):
    """Name the kind of a file that is not a regular file."""
    for test, name in ((stat.S_ISDIR, 'a directory'), (stat.S_ISCHR, 'a character device'),
                       (stat.S_ISBLK, 'a block device'), (stat.S_ISFIFO, 'a FIFO (named pipe)'),
                       (stat.S_ISSOCK, 'a socket'), (stat.S_ISLNK, 'a symbolic link')):
        if test(mode):
            return name
    return 'not a regular file'


def _shared(dir_stat):
    """Whether a folder lets other users add or swap entries (sticky or world-writable)."""
    return bool(dir_stat.st_mode & (stat.S_ISVTX | stat.S_IWOTH))


def _check_link(shown, link, link_stat, folder):
    """Refuse to follow ``link`` (in ``folder``) unless its owner is to be trusted."""
    me = _euid()
    if link_stat.st_uid == me:
        return
    shared = _shared(os.stat(folder))
    if link_stat.st_uid == 0 and not shared:
        return
    which = '' if link == os.path.abspath(shown) else f' {link}'
    where = ' in a shared folder' if shared else ''
    raise UnsafeOutput(f'{shown}: the symbolic link{which}{where} belongs to another user '
                       f'(uid {link_stat.st_uid}): following it could replace their file; '
                       'write to the real path')


def output_target(path, folder=False):
    """
    Return the real file (or folder) to write for ``path``, or refuse with the reason.

    Symbolic links are resolved one by one (each checked, see the module docstring); the
    part of the path that does not exist yet is kept as given.

    :param path: the output path as the user gave it (``~`` already expanded).
    :param folder: the output is a folder to write files into: it may exist as one.
    :return: absolute path of the file to create or replace (no link in it).
    :raises UnsafeOutput: a link owned by someone else, a target that is not a regular
        file, a foreign file in a shared folder, or a link loop.
    """
    shown = os.fspath(path)
    if not shown:
        raise UnsafeOutput('an empty output name')
    if '\0' in shown:
        raise UnsafeOutput('an output name must not hold a NUL character')
    if shown.endswith(os.sep) and not folder:
        raise UnsafeOutput(f'{shown} names a folder, not a file')
    pending = list(reversed(shown.split(os.sep)))
    current = os.sep if os.path.isabs(shown) else os.getcwd()
    links = 0
    missing = False
    while pending:
        name = pending.pop()
        if name in ('', '.'):
            continue
        if name == '..' and not missing:
            current = os.path.dirname(current)
            continue
        candidate = os.path.join(current, name)
        if missing:                       # below a missing folder: nothing to check
            current = candidate
            continue
        try:
            st = os.lstat(candidate)
        except FileNotFoundError:
            missing = True
            current = candidate
            continue
        except NotADirectoryError:
            raise UnsafeOutput(f'{shown}: {current} is not a folder') from None
        if stat.S_ISLNK(st.st_mode):
            links += 1
            if links > MAX_LINKS:
                raise UnsafeOutput(f'{shown}: too many levels of symbolic links')
            _check_link(shown, candidate, st, current)
            target = os.readlink(candidate)
            if os.path.isabs(target):
                current = os.sep
            pending.extend(reversed(target.split(os.sep)))
            continue
        if pending and not stat.S_ISDIR(st.st_mode) and any(p not in ('', '.') for p in pending):
            raise UnsafeOutput(f'{shown}: {candidate} is {_kind(st.st_mode)}, not a folder')
        current = candidate
    if not missing:
        try:
            st = os.lstat(current)
        except FileNotFoundError:
            return current
        if folder:
            if not stat.S_ISDIR(st.st_mode):
                raise UnsafeOutput(f'{shown} is {_kind(st.st_mode)}, not a folder')
            return current
        if not stat.S_ISREG(st.st_mode):
            raise UnsafeOutput(f'{shown} is {_kind(st.st_mode)}, not a regular file; '
                               'refusing to replace it (choose a file name)')
        folder = os.path.dirname(current)
        dir_stat = os.stat(folder)
        if _shared(dir_stat) and st.st_uid not in (_euid(), dir_stat.st_uid):
            raise UnsafeOutput(f'{shown}: the file belongs to another user (uid {st.st_uid}) '
                               'in a shared folder; refusing to replace it')
        if not _writable(current):
            raise UnsafeOutput(f'{shown}: the file is read-only for this user; refusing to '
                               'write it')
    return current


def _writable(path):
    """Whether this process may write the existing file ``path`` (effective ids)."""
    try:
        if os.access in os.supports_effective_ids:
            return os.access(path, os.W_OK, effective_ids=True, follow_symlinks=False)
        return os.access(path, os.W_OK)
    except (OSError, NotImplementedError):
        return True


def _name_max(directory):
    try:
        return os.pathconf(directory or '.', 'PC_NAME_MAX')
    except (OSError, ValueError):
        return 255


def temp_name(directory, name, tag):
    """
    Return a hidden temporary name for ``name`` that fits in the folder's NAME_MAX.

    The name keeps the target's suffix when it is short (libraries such as matplotlib
    pick the output format from it) and shortens the stem as needed.

    :param directory: the folder the name is for.
    :param name: the final file name.
    :param tag: what makes the name unique (e.g. random hex), ASCII.
    :return: ``.STEM.TAG.tmpSUFFIX``.
    """
    stem, suffix = os.path.splitext(name)
    if len(os.fsencode(suffix)) > 16:
        stem, suffix = name, ''
    room = max(_name_max(directory) - len(f'..{tag}.tmp') - len(os.fsencode(suffix)), 1)
    short = os.fsencode(stem)[:room]
    while short:                      # do not cut a UTF-8 character in half
        try:
            short.decode('utf-8')
            break
        except UnicodeDecodeError as err:
            if err.start < len(short) - 4:
                break                 # not UTF-8 anyway: bytes are bytes
            short = short[:-1]
    return f'.{os.fsdecode(short)}.{tag}.tmp{suffix}'


def _create_temp(target):
    """
    Create an empty, exclusive temporary file next to ``target`` (never through a link).

    :param target: the final path (from :func:`output_target`).
    :return: (file descriptor open for writing, temporary path).
    """
    directory, name = os.path.split(target)
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, 'O_NOFOLLOW', 0) \
        | getattr(os, 'O_CLOEXEC', 0)
    for _ in range(100):
        tmp = os.path.join(directory, temp_name(directory, name, os.urandom(4).hex()))
        try:
            fd = os.open(tmp, flags, 0o666)
        except FileExistsError:
            continue
        return fd, tmp
    raise FileExistsError(f'could not create a temporary file next to {target}')


def _copy_mode(target, tmp):
    """Give ``tmp`` the permission bits (and, as root, the owner) of an existing ``target``."""
    try:
        st = os.lstat(target)
    except FileNotFoundError:
        return
    if not stat.S_ISREG(st.st_mode):
        return
    os.chmod(tmp, stat.S_IMODE(st.st_mode))
    if _euid() == 0 and (st.st_uid, st.st_gid) != (0, 0):
        with contextlib.suppress(OSError):
            os.chown(tmp, st.st_uid, st.st_gid, follow_symlinks=False)


def fsync_directory(directory):
    """
    Flush a directory entry change (rename, create) to disk.

    Silently does nothing where directories cannot be opened (e.g. Windows).

    :param directory: the directory whose entries changed.
    """
    try:
        fd = os.open(directory or '.', os.O_RDONLY | getattr(os, 'O_DIRECTORY', 0))
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _fsync_file(path):
    """Flush a file written by someone else (e.g. a library writing by name) to disk."""
    fd = os.open(path, os.O_RDONLY | getattr(os, 'O_NOFOLLOW', 0))
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _remove_quietly(path):
    """Delete ``path`` if it exists, ignoring errors (clean-up after a failure)."""
    if path:
        with contextlib.suppress(OSError):
            os.unlink(path)


@contextlib.contextmanager
def signals_held():
    """Hold SIGINT, SIGTERM and SIGHUP for a few statements (delivered when it ends)."""
    try:
        old = signal.pthread_sigmask(signal.SIG_BLOCK, _HELD_SIGNALS)
    except (AttributeError, OSError, ValueError):
        old = None
    try:
        yield
    finally:
        if old is not None:
            signal.pthread_sigmask(signal.SIG_SETMASK, old)


def make_parents(directory):
    """
    Create ``directory`` and its missing parents; return the folders made, outermost first.

    :param directory: folder that must exist.
    :return: list of the folders this call created (for :func:`remove_made`).
    """
    made = []
    missing = []
    folder = os.path.abspath(directory or '.')
    while not os.path.lexists(folder):
        missing.append(folder)
        parent = os.path.dirname(folder)
        if parent == folder:
            break
        folder = parent
    try:
        for folder in reversed(missing):
            os.mkdir(folder)
            made.append(folder)
    except BaseException:
        remove_made(made)
        raise
    return made


def remove_made(made):
    """Remove the (empty) folders :func:`make_parents` made, innermost first."""
    for folder in reversed(made):
        with contextlib.suppress(OSError):
            os.rmdir(folder)


def replace_into(tmp, target):
    """
    Move a finished temporary file over ``target`` durably.

    Keeps the permission bits of an existing target, renames atomically and fsyncs the
    directory. The caller removes ``tmp`` if this raises.

    :param tmp: a complete file in the same directory as ``target``.
    :param target: the final path (from :func:`output_target`).
    """
    _copy_mode(target, tmp)
    os.replace(tmp, target)
    fsync_directory(os.path.dirname(target))


def atomic_write_bytes(path, data, make_dirs=False):
    """
    Write ``data`` to ``path`` atomically.

    :param path: the file to create or replace.
    :param data: bytes-like content.
    :param make_dirs: create missing folders (removed again when the write fails).
    :raises UnsafeOutput: the path may not be written (see the module docstring).
    """
    with atomic_file(path, make_dirs=make_dirs) as f:
        f.write(data)


def atomic_write_text(path, text, encoding='utf-8', make_dirs=False):
    """
    Write ``text`` to ``path`` atomically.

    :param path: the file to create or replace.
    :param text: the content.
    :param encoding: text encoding, UTF-8 by default.
    :param make_dirs: create missing folders (removed again when the write fails).
    """
    atomic_write_bytes(path, text.encode(encoding), make_dirs)


@contextlib.contextmanager
def _temporary(path, make_dirs):
    """Yield (fd, temp path, target); replace the target on success, clean up on failure."""
    target = output_target(path)
    made, tmp, fd = [], None, None
    try:
        with signals_held():
            if make_dirs:
                made = make_parents(os.path.dirname(target))
            fd, tmp = _create_temp(target)
        mine = os.fstat(fd)
        yield fd, tmp, target
        st = os.lstat(tmp)
        if (st.st_dev, st.st_ino) != (mine.st_dev, mine.st_ino):
            tmp = None                         # not ours any more: leave it, replace nothing
            raise UnsafeOutput(f'{path}: the temporary file was swapped by someone else; '
                               'nothing written')
        replace_into(tmp, target)
    except BaseException:
        _remove_quietly(tmp)
        remove_made(made)
        raise
    finally:
        if fd is not None:
            with contextlib.suppress(OSError):
                os.close(fd)


@contextlib.contextmanager
def atomic_file(path, mode='wb', encoding=None, newline=None, make_dirs=False):
    """
    Yield a file object to write; it replaces ``path`` only if the block succeeds.

    The file is the temporary file's own descriptor (``O_EXCL | O_NOFOLLOW``), never
    opened again by name, so nobody can slip a link under it.

    :param path: the file to create or replace.
    :param mode: 'wb' or 'w' (text: give ``encoding``; ``newline`` as for :func:`open`).
    :param make_dirs: create missing folders (removed again when the write fails).
    :raises UnsafeOutput: the path may not be written (see the module docstring).
    """
    with _temporary(path, make_dirs) as (fd, tmp, target):
        with open(os.dup(fd), mode, encoding=encoding, newline=newline) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())


@contextlib.contextmanager
def atomic_path(path, make_dirs=False):
    """
    Yield a temporary path to write; it replaces ``path`` only if the block succeeds.

    For libraries that can only write by file name (prefer :func:`atomic_file`)::

        with atomic_path('report.png') as tmp:
            figure.savefig(tmp)

    The temporary file exists (empty) when the block starts, lives in the target's
    directory and ends with the target's suffix. If the block raises (a signal too), it
    is deleted, folders made for it are removed and the target is untouched.

    :param path: the file to create or replace.
    :param make_dirs: create missing folders (removed again when the write fails).
    :return: a context manager yielding the temporary path as a string.
    :raises UnsafeOutput: the path may not be written (see the module docstring).
    """
    with _temporary(path, make_dirs) as (fd, tmp, target):
        yield tmp
        _fsync_file(tmp)


def regular_opener(path, flags):
    """
    ``open(..., opener=regular_opener)``: open only a regular file, never blocking on a FIFO.

    The open is non-blocking and the check is made on what was opened, so a FIFO, a
    device such as ``/dev/zero`` or a terminal is refused instead of hanging or reading
    forever.

    :raises InputError: not a regular file (OSError for the file system's refusals).
    """
    fd = os.open(path, flags | getattr(os, 'O_NONBLOCK', 0) | getattr(os, 'O_CLOEXEC', 0))
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            raise InputError(f'{path}: is {_kind(mode)}, not a regular file')
        if hasattr(os, 'set_blocking'):
            os.set_blocking(fd, True)
    except BaseException:
        os.close(fd)
        raise
    return fd


def open_regular(path, **kwargs):
    """
    Open an input for reading only if it is a regular file (see :func:`regular_opener`).

    :param path: the input file.
    :param kwargs: passed to :func:`open` (``encoding``, ``newline``); binary without.
    :return: the open file object (text mode when ``encoding`` is given, else binary).
    """
    return open(path, 'r' if 'encoding' in kwargs else 'rb', opener=regular_opener, **kwargs)
