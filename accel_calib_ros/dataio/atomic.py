"""
Atomic file replacement: a reader sees the old file or the new one, never half of one.

Every writer here follows the same recipe: create a temporary file in the target's own
directory (so the final rename never crosses a file system), write it, flush it, fsync it,
``os.replace`` it over the target and fsync the directory so the rename itself survives a
power cut. On any failure the temporary file is removed and the previous target, if any,
is left untouched.

Permission bits: a replaced file keeps the mode of the file it replaces; a new file gets
the usual ``0o666`` minus the process umask, as ``open(path, 'w')`` would give it. A
symbolic link at the target is followed, so the link stays and its target is replaced.
"""

import contextlib
import os
import stat

__all__ = ['atomic_path', 'atomic_write_bytes', 'atomic_write_text']


def _resolve(path):
    """Return the real path to write, following a symbolic link at the target."""
    path = os.fspath(path)
    if os.path.islink(path):
        return os.path.realpath(path)
    return path


def _create_temp(target):
    """
    Create an empty, exclusive temporary file next to ``target``.

    The name keeps the target's suffix (libraries such as matplotlib pick the output
    format from it) and starts with a dot so it stays out of the way.

    :param target: the final path.
    :return: (file descriptor open for writing, temporary path).
    """
    directory, name = os.path.split(target)
    stem, suffix = os.path.splitext(name)
    for _ in range(100):
        tmp = os.path.join(directory, f'.{stem}.{os.urandom(4).hex()}.tmp{suffix}')
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        except FileExistsError:
            continue
        return fd, tmp
    raise FileExistsError(f'could not create a temporary file next to {target}')


def _copy_mode(target, tmp):
    """Give ``tmp`` the permission bits of an existing ``target`` (no-op if none)."""
    try:
        mode = stat.S_IMODE(os.stat(target).st_mode)
    except FileNotFoundError:
        return
    os.chmod(tmp, mode)


def fsync_directory(directory):
    """
    Flush a directory entry change (rename, create) to disk.

    Silently does nothing where directories cannot be opened (e.g. Windows).

    :param directory: the directory whose entries changed.
    """
    try:
        fd = os.open(directory or '.', os.O_RDONLY)
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
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _remove_quietly(path):
    """Delete ``path`` if it exists, ignoring errors (clean-up after a failure)."""
    with contextlib.suppress(OSError):
        os.unlink(path)


def replace_into(tmp, target):
    """
    Move a finished temporary file over ``target`` durably.

    Keeps the permission bits of an existing target, renames atomically and fsyncs the
    directory. The caller removes ``tmp`` if this raises.

    :param tmp: a complete file in the same directory as ``target``.
    :param target: the final path.
    """
    _copy_mode(target, tmp)
    os.replace(tmp, target)
    fsync_directory(os.path.dirname(target))


def atomic_write_bytes(path, data):
    """
    Write ``data`` to ``path`` atomically.

    :param path: the file to create or replace.
    :param data: bytes-like content.
    """
    target = _resolve(path)
    fd, tmp = _create_temp(target)
    try:
        with os.fdopen(fd, 'wb') as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        replace_into(tmp, target)
    except BaseException:
        _remove_quietly(tmp)
        raise


def atomic_write_text(path, text, encoding='utf-8'):
    """
    Write ``text`` to ``path`` atomically.

    :param path: the file to create or replace.
    :param text: the content.
    :param encoding: text encoding, UTF-8 by default.
    """
    atomic_write_bytes(path, text.encode(encoding))


@contextlib.contextmanager
def atomic_path(path):
    """
    Yield a temporary path to write; it replaces ``path`` only if the block succeeds.

    For libraries that write by file name (``savefig``, ``np.savetxt``, CSV writers)::

        with atomic_path('report.png') as tmp:
            figure.savefig(tmp)

    The temporary file exists (empty) when the block starts, lives in the target's
    directory and ends with the target's suffix. If the block raises, it is deleted and
    the target is untouched.

    :param path: the file to create or replace.
    :return: a context manager yielding the temporary path as a string.
    """
    target = _resolve(path)
    fd, tmp = _create_temp(target)
    os.close(fd)
    try:
        yield tmp
        _fsync_file(tmp)
        replace_into(tmp, target)
    except BaseException:
        _remove_quietly(tmp)
        raise
