"""
Write the interface's CSV (section 2) atomically: whole recordings or block by block.

The header is ``t ax ay az`` plus ``temp``, ``gx gy gz`` and ``mx my mz`` when the
samples carry them, then any extra columns; a row without a magnetometer sample leaves
its three cells empty. ``csv_writer`` streams blocks into one atomic file (nothing is
left behind on an error); ``write_samples_csv`` writes a whole recording.
"""

import contextlib
import os

import numpy as np

from .atomic import atomic_file
from .formats import GYRO_COLUMNS, MAG_COLUMNS, one_line, REQUIRED_COLUMNS, STANDARD_COLUMNS
from ..core.errors import InputError
from ..core.samples import Samples


def _csv_names(has_temp, has_gyro, extra_names=(), has_mag=False):
    """Return the CSV header names for samples with/without temp, gyro, mag, plus extras."""
    names = list(REQUIRED_COLUMNS)
    if has_temp:
        names.append('temp')
    if has_gyro:
        names.extend(GYRO_COLUMNS)
    if has_mag:
        names.extend(MAG_COLUMNS)
    return names + list(extra_names)


def _csv_block(samples, extra_values, width):
    """Format Samples (plus extra columns) as CSV text lines, ``%.9f`` t, ``%.9g`` others."""
    n = len(samples)
    data = np.empty((n, width))
    data[:, 0] = samples.t
    data[:, 1:4] = samples.accel
    col = 4
    if samples.temp is not None:
        data[:, col] = samples.temp
        col += 1
    if samples.gyro is not None:
        data[:, col:col + 3] = samples.gyro
        col += 3
    mag_col = col
    if samples.mag is not None:
        data[:, col:col + 3] = samples.mag
        col += 3
    for values in extra_values:
        data[:, col] = values
        col += 1
    row = '%.9f' + ',%.9g' * (width - 1) + '\n'
    if samples.mag is None or samples.mag_rows.all():
        return (row * n) % tuple(data.ravel().tolist())  # one C-level pass: faster than savetxt
    return _csv_block_mag_gaps(data, samples.mag_rows, mag_col, width)


def _csv_block_mag_gaps(data, mag_rows, mag_col, width):
    """Format rows whose magnetometer cells are empty where ``mag_rows`` (N,) is False."""
    full = '%.9f' + ',%.9g' * (width - 1) + '\n'
    gap = '%.9f' + ',%.9g' * (mag_col - 1) + ',,,' + ',%.9g' * (width - mag_col - 3) + '\n'
    keep = np.ones(data.shape, bool)
    keep[~mag_rows, mag_col:mag_col + 3] = False
    formats = np.where(mag_rows, full, gap)
    return ''.join(formats.tolist()) % tuple(data[keep].tolist())


class CsvWriter:
    """
    The interface CSV written piece by piece into a temporary file, then renamed into place.

    Use ``csv_writer(path, ...)``; each ``write`` appends rows. Memory stays bounded
    by the pieces given, whatever the length of the file.
    """

    BLOCK_ROWS = 1 << 15
    """Rows formatted at a time (the formatting holds Python floats for a block)."""

    def __init__(self, f, has_temp, has_gyro, extra_names, has_mag=False):
        self._f = f
        self.has_temp = has_temp
        self.has_gyro = has_gyro
        self.has_mag = has_mag
        self.extra_names = list(extra_names)
        self.names = _csv_names(has_temp, has_gyro, self.extra_names, has_mag)
        self.rows = 0
        f.write(','.join(self.names) + '\n')

    def write(self, samples, extra=None):
        """
        Append samples (and their extra columns) to the file.

        :param samples: Samples with temp/gyro/mag present exactly when the header has them.
        :param extra: dict name -> (N,) array, the same names as given to ``csv_writer``.
        :raises InputError: the samples or extra columns do not fit the header.
        """
        if (samples.temp is not None) != self.has_temp or \
                (samples.gyro is not None) != self.has_gyro:
            raise InputError('samples written to one CSV must all have (or lack) temp and gyro')
        if (samples.mag is not None) != self.has_mag:
            raise InputError('samples written to one CSV must all have (or lack) mx my mz')
        checked = _check_extra(extra, len(samples))
        if [name for name, _ in checked] != self.extra_names:
            raise InputError(f'extra columns {[n for n, _ in checked]} differ from those '
                             f'of the header {self.extra_names}')
        for a in range(0, len(samples), self.BLOCK_ROWS):
            part = slice(a, a + self.BLOCK_ROWS)
            self._f.write(_csv_block(samples.subset(part), [v[part] for _, v in checked],
                                     len(self.names)))
        self.rows += len(samples)


@contextlib.contextmanager
def csv_writer(path, has_temp=False, has_gyro=False, extra_names=(), has_mag=False):
    """
    Open the interface's CSV ``path`` for writing in pieces, atomically.

    The rows go to a temporary file next to ``path``; it replaces ``path`` only when the
    ``with`` block ends normally. On any exception (Ctrl-C included) it is removed and
    an existing ``path`` stays as it was.

    :param path: the CSV file to create or replace; ``-`` writes to standard output
        (not atomic: a pipe has no old content to keep).
    :param has_temp: the file has a ``temp`` column.
    :param has_gyro: the file has ``gx, gy, gz`` columns.
    :param extra_names: names of extra columns after the standard ones.
    :param has_mag: the file has ``mx, my, mz`` columns (empty cells for NaN rows).
    :return: context manager yielding a ``CsvWriter``.
    :raises InputError: the file cannot be written.
    """
    _check_extra({name: np.zeros(0) for name in extra_names}, 0)
    if os.fspath(path) == '-':
        import sys
        yield CsvWriter(sys.stdout, has_temp, has_gyro, extra_names, has_mag)
        sys.stdout.flush()
        return
    try:
        with atomic_file(path, 'w', encoding='utf-8', newline='') as f:
            yield CsvWriter(f, has_temp, has_gyro, extra_names, has_mag)
    except OSError as exc:
        raise InputError(f'{path}: cannot write ({exc.strerror or one_line(exc)})') from None


def write_samples_csv(path, samples, extra=None):
    """
    Write samples as the interface's CSV, atomically.

    Columns: ``t, ax, ay, az``, then ``temp``, ``gx, gy, gz`` and ``mx, my, mz`` when
    present (empty magnetometer cells in rows without a sample), then the ``extra``
    columns in the dict's order. Times are written with nanosecond resolution
    (``%.9f``, so absolute ROS times keep their fraction), other values with ``%.9g``.

    :param path: the CSV file to create or replace.
    :param samples: the Samples to write, or an iterable of Samples pieces (written in
        turn, in bounded memory; every piece with the same optional columns).
    :param extra: optional dict column name -> (N,) array of extra columns (one Samples
        only).
    :return: the number of rows written.
    :raises InputError: an extra column is misnamed or of the wrong length, or the file
        cannot be written.
    """
    if isinstance(samples, Samples):
        checked = _check_extra(extra, len(samples))
        pieces = iter(())
        first = samples
    else:
        checked = []
        pieces = iter(samples)
        first = next(pieces, None)
        if first is None:
            first = Samples(np.zeros(0), np.zeros((0, 3)))
    with csv_writer(path, first.temp is not None, first.gyro is not None,
                    [name for name, _ in checked], first.mag is not None) as writer:
        writer.write(first, dict(checked) if checked else None)
        for piece in pieces:
            writer.write(piece)
    return writer.rows


def _check_extra(extra, n):
    """Validate extra CSV columns: name -> (N,) array, names new and CSV-safe."""
    out = []
    seen = set(STANDARD_COLUMNS)
    for name, values in (extra or {}).items():
        key = str(name).strip().lower()
        if not key or any(ch in str(name) for ch in ',"\r\n'):
            raise InputError(f'extra column name {name!r} is not usable in a CSV header')
        if key in seen:
            raise InputError(f'extra column {name!r} clashes with another column')
        seen.add(key)
        values = np.asarray(values, dtype=float).reshape(-1)
        if len(values) != n:
            raise InputError(f'extra column {name!r} has {len(values)} values for {n} samples')
        out.append((str(name).strip(), values))
    return out
