"""
Read the interface's CSV (section 2): in blocks, validated (writing: ``csv_write``).

A header row names the columns; required ``t``, ``ax``, ``ay``, ``az``; optional
``temp``, ``gx``, ``gy``, ``gz`` and ``mx``, ``my``, ``mz`` (µT, accelerometer frame; all
three cells empty in a row without a magnetometer sample, as the magnetometer runs
slower than the accelerometer); other columns are ignored; names are matched
case-insensitively after stripping spaces. Rows are parsed in blocks of
``PARSE_CHUNK_ROWS`` (fast path), and a file that the fast path refuses is read again line
by line to say which line and which cell are wrong. Cells must be finite and within
``PLAUSIBLE_LIMIT``; time must increase.
"""

import csv
import itertools
import math
import os
import warnings

import numpy as np

from .atomic import regular_opener
from .formats import (GYRO_COLUMNS, listed, MAG_COLUMNS, MAX_LISTED, one_line, REQUIRED_COLUMNS,
                      STANDARD_COLUMNS)
from .time_units import check_time_spacing, seconds
from ..core.errors import InputError
from ..core.samples import Samples


PLAUSIBLE_LIMIT = {'time t': 1e12, 'acceleration ax, ay, az': 1e6, 'temperature': 1e3,
                   'gyro gx, gy, gz': 1e6, 'magnetic field mx, my, mz': 1e6}
"""Largest magnitude a CSV cell may hold per column group (s, m/s² or counts, °C, rad/s, µT)."""


def _open_text(path):
    """Open a CSV file for reading, turning OS errors into InputError."""
    if path.is_dir():
        raise InputError(f'{path}: is a directory, not a CSV file')
    try:
        return open(path, encoding='utf-8-sig', newline='', opener=regular_opener)
    except PermissionError:
        raise InputError(f'{path}: cannot read the file (permission denied)') from None
    except OSError as exc:
        raise InputError(f'{path}: cannot read the file ({exc.strerror or exc})') from None


def _is_data_line(line):
    """Tell whether a CSV line holds data (not blank, not a '#' comment)."""
    stripped = line.strip()
    return bool(stripped) and not stripped.startswith('#')


MAX_HEADER_CHARS = 1 << 16
"""Longest header (or comment) line read, characters: a longer one is not a CSV header."""


def _read_header(f, path):
    """
    Read up to and including the header row.

    A line is read at most ``MAX_HEADER_CHARS`` at a time, so a file with no line break
    (a JSON file, a binary blob) is refused without being read whole.

    :return: (column names, lowercased and stripped; 1-based line number of the header).
    """
    lineno = 0
    while True:
        line = f.readline(MAX_HEADER_CHARS + 1)
        if not line:
            raise InputError(f'{path}: the file is empty; expected a header row '
                             f'({", ".join(REQUIRED_COLUMNS)}, ...) and data rows')
        lineno += 1
        if len(line) > MAX_HEADER_CHARS:
            raise InputError(f'{path}, line {lineno}: no line break in the first '
                             f'{MAX_HEADER_CHARS} characters{_looks_like(line)}; expected a '
                             f'CSV header row ({", ".join(REQUIRED_COLUMNS)}, ...)')
        if _is_data_line(line):
            break
    try:
        names = [c.strip().lower() for c in next(csv.reader([line]))]
    except (csv.Error, StopIteration) as exc:
        raise InputError(f'{path}, line {lineno}: malformed CSV header ({one_line(exc)})') \
            from None
    return names, lineno


def _looks_like(text):
    """Hint at what a file that is not a CSV is (from its first characters)."""
    head = text.lstrip('\ufeff \t\r\n')[:1]
    return {'{': ' (it looks like JSON)', '[': ' (it looks like JSON)',
            '<': ' (it looks like XML or HTML)'}.get(head, '')


def _shown_names(names, limit=8, width=30):
    """Show header names in a message: at most ``limit`` of them, each cut to ``width``."""
    shown = [repr(n if len(n) <= width else n[:width] + '…') for n in names[:limit]]
    if len(names) > limit:
        shown.append(f'and {len(names) - limit} more')
    return ', '.join(shown)


def _looks_numeric(text):
    """Tell whether a header cell is a number (the file has no header row)."""
    try:
        float(text)
    except ValueError:
        return False
    return True


def _column_layout(names, path):
    """
    Map the interface's columns to their positions in the header.

    :return: dict with 't', 'ax', 'ay', 'az' and, when present, 'temp' and 'gx', 'gy', 'gz'.
    """
    found = _shown_names(names)
    missing = [c for c in REQUIRED_COLUMNS if c not in names]
    if missing:
        if names and all(_looks_numeric(n) for n in names if n):
            raise InputError(
                f'{path}: the first line holds numbers, not column names; add a header row '
                f'naming the columns ({", ".join(REQUIRED_COLUMNS)}, optional temp, gx, gy, gz)')
        hint = ''
        if len(names) == 1 and (';' in names[0] or '\t' in names[0]):
            hint = ' (the file must be comma-separated)'
        hint = hint or _looks_like(names[0] if names else '')
        raise InputError(f'{path}: missing required column(s) {", ".join(missing)}; '
                         f'found columns: {found}{hint}')
    layout = {}
    for name in STANDARD_COLUMNS:
        positions = [i for i, n in enumerate(names) if n == name]
        if len(positions) > 1:
            raise InputError(f'{path}: column {name!r} appears {len(positions)} times '
                             f'in the header (columns {found})')
        if positions:
            layout[name] = positions[0]
    gyro = [c for c in GYRO_COLUMNS if c in layout]
    if gyro and len(gyro) < 3:
        missing = [c for c in GYRO_COLUMNS if c not in layout]
        raise InputError(f'{path}: gyro columns incomplete: found {", ".join(gyro)} but not '
                         f'{", ".join(missing)}; give all of gx, gy, gz or none')
    _check_mag_layout(layout, path)
    return layout


def _check_mag_layout(layout, path):
    """Refuse a header with some but not all of mx, my, mz."""
    mag = [c for c in MAG_COLUMNS if c in layout]
    if mag and len(mag) < 3:
        missing = [c for c in MAG_COLUMNS if c not in layout]
        raise InputError(f'{path}: magnetometer columns incomplete: found {", ".join(mag)} but '
                         f'not {", ".join(missing)}; give all of mx, my, mz or none')


def _mag_positions(layout):
    """File column indices of mx, my, mz (empty cells allowed there), or ()."""
    return tuple(layout[c] for c in MAG_COLUMNS if c in layout)


def _empty_is_nan(text):
    """Parse a magnetometer cell: an empty one is NaN (a row without a sample)."""
    return float(text) if text.strip() else math.nan


def _data_lines(path, header_lineno, rows):
    """
    Translate data-row indexes (0-based, as parsed) into 1-based file line numbers.

    Only called to word an error message, so a second pass over the file is fine.
    """
    wanted = sorted({int(r) for r in rows})
    out = {}
    with _open_text(path) as f:
        index = -1
        k = 0
        for lineno, line in enumerate(f, start=1):
            if lineno <= header_lineno or not _is_data_line(line):
                continue
            index += 1
            if index == wanted[k]:
                out[index] = lineno
                k += 1
                if k == len(wanted):
                    break
    return [out.get(int(r), int(r) + header_lineno + 1) for r in rows]


def _columns(data, used):
    """
    Name the columns of a parsed block: views, no copies.

    Besides one (N,) view per column, ``accel`` (and ``gyro``) are (N, 3) views of the
    three side-by-side columns (the reader parses them in STANDARD_COLUMNS order).
    """
    out = {n: data[:, i] for i, n in enumerate(used)}
    for key, names in (('accel', ('ax', 'ay', 'az')), ('gyro', GYRO_COLUMNS),
                       ('mag', MAG_COLUMNS)):
        if all(n in used for n in names):
            i = used.index(names[0])
            if used[i:i + 3] == list(names):
                out[key] = data[:, i:i + 3]
    return out


def _parse_fast(f, columns, empty_ok=()):
    """
    Parse the selected columns with numpy's C reader; raises ValueError on any bad cell.

    :param empty_ok: file column indices whose empty cells are NaN (the magnetometer's).
    """
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')  # "input contained no data" for a header-only file
        return np.loadtxt(f, delimiter=',', usecols=columns, ndmin=2, dtype=float,
                          comments='#', quotechar='"',
                          converters=dict.fromkeys(empty_ok, _empty_is_nan) or None)


def _parse_careful(path, header_lineno, layout, names, non_finite='refuse'):
    """
    Parse the used columns cell by cell, to find and word the problem the fast path hit.

    Also the place where an entirely empty optional column (``temp``, or all of the gyro
    columns) is taken to mean "not recorded".

    :return: dict column name -> float array, for the columns kept.
    """
    used = list(layout)
    cells = {name: [] for name in used}
    lines = []
    with _open_text(path) as f:
        try:
            for lineno, row in enumerate(csv.reader(f), start=1):
                if lineno <= header_lineno:
                    continue
                if not row or not _is_data_line(','.join(row)):
                    continue
                needed = max(layout[n] for n in used) + 1
                if len(row) < needed:
                    short = [n for n in used if layout[n] >= len(row)]
                    raise InputError(
                        f'{path}, line {lineno}: {len(row)} fields but the header names '
                        f'{len(names)} columns (no value for {", ".join(short)})')
                lines.append(lineno)
                for name in used:
                    cells[name].append(row[layout[name]].strip())
        except csv.Error as exc:
            raise InputError(f'{path}: malformed CSV ({one_line(exc)})') from None
    empty = {n: [i for i, v in enumerate(cells[n]) if v == ''] for n in used}
    n_rows = len(lines)
    optional_groups = [('temp',), GYRO_COLUMNS, MAG_COLUMNS]
    for group in optional_groups:
        if all(n in layout for n in group) and all(len(empty[n]) == n_rows for n in group):
            for n in group:  # column present but never filled: not recorded
                del cells[n]
                del empty[n]
    _mag_rows_without_sample(path, cells, empty, lines)
    if non_finite == 'keep':        # a missing value is as good as NaN
        for name, rows in empty.items():
            for i in rows:
                cells[name][i] = 'nan'
            empty[name] = []
    for name, rows in empty.items():
        if rows:
            where = listed(lines[i] for i in rows)
            what = 'temperature' if name == 'temp' else f'column {name!r}'
            raise InputError(f'{path}: {what} is empty on line(s) {where}; fill every row '
                             f'or leave the whole column empty')
    out = {}
    for name, values in cells.items():
        try:
            out[name] = np.array(values, dtype=float)
        except ValueError:
            for i, v in enumerate(values):
                try:
                    float(v)
                except ValueError:
                    shown = v if len(v) <= 40 else v[:40] + '…'
                    raise InputError(f'{path}, line {lines[i]}: column {name!r} holds '
                                     f'{shown!r}, not a number') from None
            raise  # pragma: no cover - numpy and float() disagree
    return out, np.asarray(lines)


def _mag_rows_without_sample(path, cells, empty, lines):
    """
    Accept rows whose three magnetometer cells are all empty (NaN: no sample there).

    Changes ``cells`` and ``empty`` in place; a row with one or two of them empty is an
    InputError naming its lines.
    """
    if not all(n in cells for n in MAG_COLUMNS):
        return
    counts = {}
    for name in MAG_COLUMNS:
        for i in empty[name]:
            counts[i] = counts.get(i, 0) + 1
    partial = sorted(i for i, k in counts.items() if k < len(MAG_COLUMNS))
    if partial:
        raise InputError(f'{path}: magnetometer cells partly empty on line(s) '
                         f'{listed(lines[i] for i in partial)}; a row without a magnetometer '
                         'sample leaves all of mx, my, mz empty')
    for name in MAG_COLUMNS:
        for i in empty[name]:
            cells[name][i] = 'nan'
        empty[name] = []


PARSE_CHUNK_ROWS = 1 << 17
"""CSV rows parsed at a time: reading holds one such block beyond the result."""


def _parse_chunks(f, columns, chunk_rows=PARSE_CHUNK_ROWS, empty_ok=()):
    """Yield blocks (rows, len(columns)) of the CSV data lines of ``f``, parsed by numpy."""
    while True:
        lines = list(itertools.islice(f, chunk_rows))
        if not lines:
            return
        block = _parse_fast(lines, columns, empty_ok)
        if block.size:
            yield block, sum(map(len, lines))


def _parse_all(f, columns, size_bytes, on_read=None, empty_ok=()):
    """
    Parse every data line of ``f`` into one (N, len(columns)) array, block by block.

    The array is allocated once from the file size and the bytes per row of the first
    block (grown if that guess falls short), so the peak resident memory is about the
    result plus one block, not the several copies a whole-file parse makes.
    """
    data, n = None, 0
    for block, nbytes in _parse_chunks(f, columns, empty_ok=empty_ok):
        if on_read is not None:
            on_read(nbytes)
        if data is None:
            # Generous: pages never written are never resident, so over-guessing is free.
            guess = int(size_bytes / max(nbytes / len(block), 1.0) * 1.25) + len(block)
            data = np.empty((max(guess, len(block)), len(columns)))
        if n + len(block) > len(data):
            grown = np.empty((int((n + len(block)) * 1.25), len(columns)))
            grown[:n] = data[:n]
            data = grown
        data[n:n + len(block)] = block
        n += len(block)
    if data is None:
        return np.empty((0, len(columns)))
    return data[:n]


def _open_csv(path):
    """Open the CSV, read its header; return (file, names, header line number, layout)."""
    f = _open_text(path)
    try:
        names, header_lineno = _read_header(f, path)
        layout = _column_layout(names, path)
    except BaseException:
        f.close()
        raise
    return f, names, header_lineno, layout


def load_csv(path, on_read=None, time_unit='s'):
    """
    Read the interface's CSV into (unvalidated but checked) Samples.

    :param time_unit: unit of the ``t`` column ('s', 'ms', 'us' or 'ns'; see
        :func:`check_time_spacing`).
    """
    try:
        f, names, header_lineno, layout = _open_csv(path)
        with f:
            used = list(layout)
            try:
                data = _parse_all(f, [layout[n] for n in used], os.fstat(f.fileno()).st_size,
                                  on_read, _mag_positions(layout))
                # Views into the one array: no copies of a big file.
                columns = _columns(data, used) if data.size else {}
                lines = None
            except ValueError:
                columns = None
        if columns is None:
            columns, lines = _parse_careful(path, header_lineno, layout, names)
    except UnicodeDecodeError:
        raise InputError(f'{path}: not a text CSV file (it is not UTF-8 text)') from None
    except OSError as exc:
        raise InputError(f'{path}: cannot read the file ({exc.strerror or exc})') from None
    samples = _checked_samples(path, seconds(columns, time_unit), lines, header_lineno)
    check_time_spacing(path, samples.t, time_unit, samples.temp)
    return samples


def iter_csv(path, chunk_rows, on_read=None, time_unit='s', non_finite='refuse'):
    """
    Yield checked Samples pieces of a CSV file, ``chunk_rows`` data lines at a time.

    :param non_finite: 'refuse' (a NaN, an infinite or an empty cell is an InputError) or
        'keep' (such cells are NaN in the samples, for a reader that skips them itself).
    """
    try:
        f, names, header_lineno, layout = _open_csv(path)
        with f:
            used = list(layout)
            offset, t_before, columns = 0, None, {}    # {}: no block at all (header only)
            try:
                for block, nbytes in _parse_chunks(f, [layout[n] for n in used], chunk_rows,
                                                   _mag_positions(layout)):
                    if on_read is not None:
                        on_read(nbytes)
                    columns = seconds(_columns(block, used), time_unit)
                    piece = _checked_samples(path, columns, None, header_lineno, offset,
                                             t_before, non_finite)
                    if offset == 0:
                        check_time_spacing(path, piece.t, time_unit, piece.temp)
                    offset += len(piece)
                    t_before = _last_time(piece.t, t_before)
                    yield piece
            except ValueError:
                if offset:      # a bad cell past the first block: word it, from the start
                    _parse_careful(path, header_lineno, layout, names)
                columns = None
            if offset == 0 and columns is not None:
                raise InputError(f'{path}: the file has a header row but no data rows')
        if columns is None:   # the careful parse decides (e.g. an all-empty temp column)
            columns, lines = _parse_careful(path, header_lineno, layout, names, non_finite)
            whole = _checked_samples(path, seconds(columns, time_unit), lines, header_lineno,
                                     non_finite=non_finite)
            check_time_spacing(path, whole.t, time_unit, whole.temp)
            for a in range(0, len(whole), chunk_rows):
                yield whole.subset(slice(a, a + chunk_rows))
    except UnicodeDecodeError:
        raise InputError(f'{path}: not a text CSV file (it is not UTF-8 text)') from None
    except OSError as exc:
        raise InputError(f'{path}: cannot read the file ({exc.strerror or exc})') from None


def _last_time(t, before):
    """Return the last finite time of ``t`` (else ``before``)."""
    finite = t[np.isfinite(t)]
    return float(finite[-1]) if len(finite) else before


def _checked_samples(path, columns, lines, header_lineno, row_offset=0, t_before=None,
                     non_finite='refuse'):
    """
    Check parsed CSV columns (finite values, time order) and return them as Samples.

    :param columns: dict column name -> (N,) array, as parsed.
    :param lines: (N,) file line numbers of the rows, or None (found again when needed).
    :param row_offset: data rows before these ones (a piece of a file read in pieces).
    :param t_before: time of the row just before these ones, s, or None.
    :param non_finite: 'refuse', or 'keep' (NaN and infinite cells, and values beyond
        the plausible limits, are kept as NaN: the reader skips them; the times of the
        rows that have one must still increase).
    """
    if not columns or len(columns['t']) == 0:
        raise InputError(f'{path}: the file has a header row but no data rows')

    def line_numbers(rows):
        if lines is not None:
            return [int(lines[r]) for r in rows]
        return _data_lines(path, header_lineno, [int(r) + row_offset for r in rows])

    t = columns['t']
    keep = non_finite == 'keep'
    timed = np.flatnonzero(np.isfinite(t)) if keep else np.arange(len(t))
    if t_before is not None and len(timed) and t[timed[0]] < t_before:
        line = line_numbers([0])[0]
        raise InputError(f'{path}, line {line}: time goes backwards (t={t[0]:.9g} s after '
                         f'{t_before:.9g} s); rows must be in increasing time order')
    accel = columns.get('accel')
    if accel is None:
        accel = np.column_stack([columns['ax'], columns['ay'], columns['az']])
    temp = columns.get('temp')
    gyro = None
    if all(n in columns for n in GYRO_COLUMNS):
        gyro = columns.get('gyro')
        if gyro is None:
            gyro = np.column_stack([columns[n] for n in GYRO_COLUMNS])
    mag = _mag_column(columns)
    checks = [('time t', t), ('acceleration ax, ay, az', accel)]
    if temp is not None:
        checks.append(('temperature', temp))
    if gyro is not None:
        checks.append(('gyro gx, gy, gz', gyro))
    if mag is not None:
        checks.append(('magnetic field mx, my, mz', mag))
        gaps = np.isnan(mag)
        partial = np.nonzero(gaps.any(axis=1) & ~gaps.all(axis=1))[0]
        if partial.size:
            where = listed(line_numbers(partial[:MAX_LISTED])
                           + ['x'] * (partial.size - MAX_LISTED))
            raise InputError(f'{path}: magnetometer cells partly empty on line(s) {where}; a '
                             'row without a magnetometer sample leaves all of mx, my, mz empty')
    for what, values in checks:
        with np.errstate(invalid='ignore'):
            finite = np.isfinite(values) & (np.abs(values) <= PLAUSIBLE_LIMIT[what])
        if keep:
            if values is not mag and not finite.all():
                values[~finite] = np.nan        # implausible: as good as missing
            continue
        if values is mag:           # a row without a magnetometer sample is all NaN
            finite |= np.all(np.isnan(values), axis=1)[:, None]
        bad = np.nonzero(~(finite if finite.ndim == 1 else finite.all(axis=1)))[0]
        if bad.size:
            where = listed(line_numbers(bad[:MAX_LISTED]) + ['x'] * (bad.size - MAX_LISTED))
            raise InputError(f'{path}: NaN or infinite (or beyond {PLAUSIBLE_LIMIT[what]:g}) '
                             f'{what} on {bad.size} row(s), line(s) '
                             f'{where}; clean or drop those rows')
    back = np.nonzero(np.diff(t[timed]) < 0)[0]
    if back.size:
        i = int(timed[back[0] + 1])
        line = line_numbers([i])[0]
        raise InputError(
            f'{path}, line {line}: time goes backwards (t={t[i]:.9g} s after {t[i - 1]:.9g} s; '
            f'{back.size} such step(s)); rows must be in increasing time order')
    return Samples(t, accel, temp, gyro, mag)


def _mag_column(columns):
    """Return the (N, 3) magnetometer columns (a view when side by side), or None."""
    if not all(n in columns for n in MAG_COLUMNS):
        return None
    mag = columns.get('mag')
    return np.column_stack([columns[n] for n in MAG_COLUMNS]) if mag is None else mag
