"""
Read and write recordings: the spec CSV and rosbag2 (MCAP or SQLite 3) bags.

``load_samples`` accepts

* a ``.csv`` file (interface spec section 2): a header row; required columns ``t``,
  ``ax``, ``ay``, ``az``; optional ``temp`` and ``gx``, ``gy``, ``gz``; other columns are
  ignored; names are matched case-insensitively after stripping spaces;
* a rosbag2 recording of ``sensor_msgs/msg/Imu`` (plus ``sensor_msgs/msg/Temperature`` if
  recorded), given as the bag directory (the one holding ``metadata.yaml``, what
  ``ros2 bag record -o NAME`` creates), as a ``.mcap`` / ``.db3`` storage file inside such
  a directory, or as a bare storage file without ``metadata.yaml`` (rosbags reads the
  metadata embedded in the file).

Bag conventions. ``t`` is the Imu ``header.stamp``; when every stamp of a topic is zero
(a driver that never sets it) the bag's receive time is used instead. Temperature is
interpolated in time onto every Imu sample and held constant before the first and after
the last temperature message; it is interpolated on the receive-time axis when the
temperature stamps are all zero. The gyro is ``angular_velocity`` unless every message
marks it unknown (REP-145: ``angular_velocity_covariance[0] == -1``).

Bag path convention of ``write_bag`` (what a ROS user expects from the name given):

* ``NAME.mcap`` / ``NAME.db3``: one self-contained storage file at exactly that path.
  rosbag2 embeds its metadata in the storage file, so ``ros2 bag info/play NAME.mcap``
  (Humble and later), Foxglove and ``load_samples`` open it without a ``metadata.yaml``.
  It is written in a hidden temporary bag directory next to the target and renamed into
  place, so an existing file is replaced atomically.
* any other name: a rosbag2 bag directory ``NAME/`` holding ``NAME.mcap`` (or
  ``NAME.db3``) and ``metadata.yaml``, like ``ros2 bag record -o NAME``. Like
  ``ros2 bag record`` it refuses to overwrite an existing directory.

Every malformed input raises ``InputError`` with a one-line message that says what is
wrong and where (file, line, topic), so the CLI can print it and exit with status 2.
"""

import contextlib
import csv
import itertools
import os
from pathlib import Path
import warnings

import numpy as np

from .atomic import atomic_path, fsync_directory, replace_into
from ..core.errors import InputError
from ..core.samples import Samples

__all__ = ['csv_writer', 'iter_samples', 'load_samples', 'write_bag', 'write_samples_csv']

IMU_TYPE = 'sensor_msgs/msg/Imu'
TEMP_TYPE = 'sensor_msgs/msg/Temperature'
ACCEPTED = ('a .csv file, a rosbag2 .mcap or .db3 file, '
            'or a rosbag2 bag directory (holding metadata.yaml)')
REQUIRED_COLUMNS = ('t', 'ax', 'ay', 'az')
GYRO_COLUMNS = ('gx', 'gy', 'gz')
STANDARD_COLUMNS = REQUIRED_COLUMNS + ('temp',) + GYRO_COLUMNS
BAG_SUFFIXES = ('.mcap', '.db3')
_STORAGE_SUFFIX = {'mcap': '.mcap', 'sqlite3': '.db3'}
_MAX_LISTED = 5

_typestore = None


PLAUSIBLE_LIMIT = {'time t': 1e12, 'acceleration ax, ay, az': 1e6, 'temperature': 1e3,
                   'gyro gx, gy, gz': 1e6}
"""Largest magnitude a CSV cell may hold per column group (s, m/s² or counts, °C, rad/s)."""


def _rosbags():
    """
    Import rosbags on first use, so CSV work needs nothing beyond numpy.

    On a robot built with colcon, rosbags is not a rosdep key: ``pip install rosbags``.
    """
    try:
        import rosbags.rosbag2
        import rosbags.typesys
    except ImportError:
        raise InputError('reading or writing rosbag2 files needs the rosbags package: '
                         'pip install rosbags') from None
    return rosbags.rosbag2, rosbags.typesys


def _types():
    """Return the ROS 2 Jazzy type store (built once, on first use)."""
    global _typestore
    if _typestore is None:
        typesys = _rosbags()[1]
        _typestore = typesys.get_typestore(typesys.Stores.ROS2_JAZZY)
    return _typestore


def _one_line(exc):
    """Return the first line of an exception's message (or its class name)."""
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def _list(items, limit=_MAX_LISTED):
    """Format numbers or names as 'a, b, c (and N more)'."""
    items = [str(x) for x in items]
    head = ', '.join(items[:limit])
    if len(items) > limit:
        head += f' (and {len(items) - limit} more)'
    return head


# --------------------------------------------------------------------------------------------
# Loading


def load_samples(path, imu_topic=None, temp_topic=None, on_read=None):
    """
    Load a recording as validated ``Samples``.

    :param path: a ``.csv`` file, a ``.mcap`` / ``.db3`` file or a rosbag2 directory.
    :param imu_topic: bags only: the ``sensor_msgs/msg/Imu`` topic (needed if several).
    :param temp_topic: bags only: the ``sensor_msgs/msg/Temperature`` topic (needed if
        several and none shares the Imu topic's namespace).
    :param on_read: CSV only: called with the characters read after each block (progress).
    :return: Samples with t, accel and, when recorded, temp and gyro.
    :raises InputError: the path is missing, of an unknown kind or malformed.
    """
    p = Path(path)
    if not p.exists():
        if p.is_symlink():
            raise InputError(f'{p}: broken symbolic link')
        raise InputError(f'{p}: no such file or directory')
    suffix = p.suffix.lower()
    if p.is_dir():
        samples = _load_bag(p, imu_topic, temp_topic)
    elif suffix == '.csv':
        samples = _load_csv(p, on_read)
    elif suffix in BAG_SUFFIXES:
        samples = _load_bag(p, imu_topic, temp_topic)
    else:
        raise InputError(f'{p}: unsupported data file {suffix or "(no suffix)"}; '
                         f'expected {ACCEPTED}')
    try:
        return samples.validate()
    except InputError as exc:
        raise InputError(f'{p}: {exc}') from None


# ---- CSV


def _open_text(path):
    """Open a CSV file for reading, turning OS errors into InputError."""
    if path.is_dir():
        raise InputError(f'{path}: is a directory, not a CSV file')
    try:
        return open(path, encoding='utf-8-sig', newline='')
    except PermissionError:
        raise InputError(f'{path}: cannot read the file (permission denied)') from None
    except OSError as exc:
        raise InputError(f'{path}: cannot read the file ({exc.strerror or exc})') from None


def _is_data_line(line):
    """Tell whether a CSV line holds data (not blank, not a '#' comment)."""
    stripped = line.strip()
    return bool(stripped) and not stripped.startswith('#')


def _read_header(f, path):
    """
    Read up to and including the header row.

    :return: (column names, lowercased and stripped; 1-based line number of the header).
    """
    lineno = 0
    for line in f:
        lineno += 1
        if _is_data_line(line):
            break
    else:
        raise InputError(f'{path}: the file is empty; expected a header row '
                         f'({", ".join(REQUIRED_COLUMNS)}, ...) and data rows')
    names = [c.strip().lower() for c in next(csv.reader([line]))]
    return names, lineno


def _looks_numeric(text):
    """Tell whether a header cell is a number (the file has no header row)."""
    try:
        float(text)
    except ValueError:
        return False
    return True


def _column_layout(names, path):
    """
    Map the spec columns to their positions in the header.

    :return: dict with 't', 'ax', 'ay', 'az' and, when present, 'temp' and 'gx', 'gy', 'gz'.
    """
    found = ', '.join(repr(n) for n in names)
    missing = [c for c in REQUIRED_COLUMNS if c not in names]
    if missing:
        if names and all(_looks_numeric(n) for n in names if n):
            raise InputError(
                f'{path}: the first line holds numbers, not column names; add a header row '
                f'naming the columns ({", ".join(REQUIRED_COLUMNS)}, optional temp, gx, gy, gz)')
        hint = ''
        if len(names) == 1 and (';' in names[0] or '\t' in names[0]):
            hint = ' (the file must be comma-separated)'
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
    return layout


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
    for key, names in (('accel', ('ax', 'ay', 'az')), ('gyro', GYRO_COLUMNS)):
        if all(n in used for n in names):
            i = used.index(names[0])
            if used[i:i + 3] == list(names):
                out[key] = data[:, i:i + 3]
    return out


def _parse_fast(f, columns):
    """Parse the selected columns with numpy's C reader; raises ValueError on any bad cell."""
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')  # "input contained no data" for a header-only file
        return np.loadtxt(f, delimiter=',', usecols=columns, ndmin=2, dtype=float,
                          comments='#', quotechar='"')


def _parse_careful(path, header_lineno, layout, names):
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
            raise InputError(f'{path}: malformed CSV ({_one_line(exc)})') from None
    empty = {n: [i for i, v in enumerate(cells[n]) if v == ''] for n in used}
    n_rows = len(lines)
    optional_groups = [('temp',), GYRO_COLUMNS]
    for group in optional_groups:
        if all(n in layout for n in group) and all(len(empty[n]) == n_rows for n in group):
            for n in group:  # column present but never filled: not recorded
                del cells[n]
                del empty[n]
    for name, rows in empty.items():
        if rows:
            where = _list(lines[i] for i in rows)
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
                    raise InputError(f'{path}, line {lines[i]}: column {name!r} holds '
                                     f'{v!r}, not a number') from None
            raise  # pragma: no cover - numpy and float() disagree
    return out, np.asarray(lines)


CHUNK_ROWS = 1 << 17
"""CSV rows parsed at a time: reading holds one such block beyond the result."""


def _parse_chunks(f, columns, chunk_rows=CHUNK_ROWS):
    """Yield blocks (rows, len(columns)) of the CSV data lines of ``f``, parsed by numpy."""
    while True:
        lines = list(itertools.islice(f, chunk_rows))
        if not lines:
            return
        block = _parse_fast(lines, columns)
        if block.size:
            yield block, sum(map(len, lines))


def _parse_all(f, columns, size_bytes, on_read=None):
    """
    Parse every data line of ``f`` into one (N, len(columns)) array, block by block.

    The array is allocated once from the file size and the bytes per row of the first
    block (grown if that guess falls short), so the peak resident memory is about the
    result plus one block, not the several copies a whole-file parse makes.
    """
    data, n = None, 0
    for block, nbytes in _parse_chunks(f, columns):
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


def _load_csv(path, on_read=None):
    """Read the spec CSV into (unvalidated but checked) Samples."""
    try:
        f, names, header_lineno, layout = _open_csv(path)
        with f:
            used = list(layout)
            try:
                data = _parse_all(f, [layout[n] for n in used], os.fstat(f.fileno()).st_size,
                                  on_read)
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
    return _checked_samples(path, columns, lines, header_lineno)


def _iter_csv(path, chunk_rows, on_read=None):
    """Yield checked Samples pieces of a CSV file, ``chunk_rows`` data lines at a time."""
    try:
        f, names, header_lineno, layout = _open_csv(path)
        with f:
            used = list(layout)
            offset, t_before, columns = 0, None, {}    # {}: no block at all (header only)
            try:
                for block, nbytes in _parse_chunks(f, [layout[n] for n in used], chunk_rows):
                    if on_read is not None:
                        on_read(nbytes)
                    columns = _columns(block, used)
                    piece = _checked_samples(path, columns, None, header_lineno, offset,
                                             t_before)
                    offset += len(piece)
                    t_before = piece.t[-1]
                    yield piece
            except ValueError:
                if offset:      # a bad cell past the first block: word it, from the start
                    _parse_careful(path, header_lineno, layout, names)
                columns = None
            if offset == 0 and columns is not None:
                raise InputError(f'{path}: the file has a header row but no data rows')
        if columns is None:   # the careful parse decides (e.g. an all-empty temp column)
            columns, lines = _parse_careful(path, header_lineno, layout, names)
            whole = _checked_samples(path, columns, lines, header_lineno)
            for a in range(0, len(whole), chunk_rows):
                yield whole.subset(slice(a, a + chunk_rows))
    except UnicodeDecodeError:
        raise InputError(f'{path}: not a text CSV file (it is not UTF-8 text)') from None
    except OSError as exc:
        raise InputError(f'{path}: cannot read the file ({exc.strerror or exc})') from None


def iter_samples(path, chunk_rows=CHUNK_ROWS, imu_topic=None, temp_topic=None, on_read=None):
    """
    Load a recording piece by piece: a generator of validated ``Samples``.

    A CSV file is read ``chunk_rows`` data lines at a time, so a file of any length is
    handled in bounded memory; problems are reported as by ``load_samples`` (a bad row
    in a later piece raises when that piece is reached). A bag is loaded whole, then
    handed out in pieces.

    :param path: as for ``load_samples``.
    :param chunk_rows: data rows per piece.
    :param imu_topic: bags only, as for ``load_samples``.
    :param temp_topic: bags only, as for ``load_samples``.
    :param on_read: CSV only: called with the characters read for each piece (progress).
    :return: generator of Samples, in time order.
    :raises InputError: as ``load_samples``.
    """
    p = Path(path)
    if p.suffix.lower() == '.csv' and p.is_file():
        for piece in _iter_csv(p, chunk_rows, on_read):
            try:
                yield piece.validate()
            except InputError as exc:
                raise InputError(f'{p}: {exc}') from None
        return
    whole = load_samples(path, imu_topic=imu_topic, temp_topic=temp_topic)
    for a in range(0, len(whole), chunk_rows):
        yield whole.subset(slice(a, a + chunk_rows))


def _checked_samples(path, columns, lines, header_lineno, row_offset=0, t_before=None):
    """
    Check parsed CSV columns (finite values, time order) and return them as Samples.

    :param columns: dict column name -> (N,) array, as parsed.
    :param lines: (N,) file line numbers of the rows, or None (found again when needed).
    :param row_offset: data rows before these ones (a piece of a file read in pieces).
    :param t_before: time of the row just before these ones, s, or None.
    """
    if not columns or len(columns['t']) == 0:
        raise InputError(f'{path}: the file has a header row but no data rows')

    def line_numbers(rows):
        if lines is not None:
            return [int(lines[r]) for r in rows]
        return _data_lines(path, header_lineno, [int(r) + row_offset for r in rows])

    t = columns['t']
    if t_before is not None and t[0] < t_before:
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
    checks = [('time t', t), ('acceleration ax, ay, az', accel)]
    if temp is not None:
        checks.append(('temperature', temp))
    if gyro is not None:
        checks.append(('gyro gx, gy, gz', gyro))
    for what, values in checks:
        with np.errstate(invalid='ignore'):
            finite = np.isfinite(values) & (np.abs(values) <= PLAUSIBLE_LIMIT[what])
        bad = np.nonzero(~(finite if finite.ndim == 1 else finite.all(axis=1)))[0]
        if bad.size:
            where = _list(line_numbers(bad[:_MAX_LISTED]) + ['x'] * (bad.size - _MAX_LISTED))
            raise InputError(f'{path}: NaN or infinite (or beyond {PLAUSIBLE_LIMIT[what]:g}) '
                             f'{what} on {bad.size} row(s), line(s) '
                             f'{where}; clean or drop those rows')
    back = np.nonzero(np.diff(t) < 0)[0]
    if back.size:
        i = int(back[0]) + 1
        line = line_numbers([i])[0]
        raise InputError(
            f'{path}, line {line}: time goes backwards (t={t[i]:.9g} s after {t[i - 1]:.9g} s; '
            f'{back.size} such step(s)); rows must be in increasing time order')
    return Samples(t, accel, temp, gyro)


# ---- rosbag2


def _bag_source(path):
    """
    Return what to hand to the rosbags Reader for ``path``.

    A directory must hold ``metadata.yaml``; a directory without it but with exactly one
    storage file (metadata lost) is read through that file.
    """
    if not path.is_dir():
        return path
    if (path / 'metadata.yaml').is_file():
        return path
    storage = sorted(p for p in path.iterdir() if p.suffix.lower() in BAG_SUFFIXES)
    if len(storage) == 1:
        return storage[0]
    detail = (f'and {len(storage)} storage files' if storage
              else 'and no .mcap or .db3 storage file')
    raise InputError(f'{path}: not a rosbag2 bag directory: no metadata.yaml {detail}; '
                     f'expected {ACCEPTED}')


def _normalize_topic(name):
    """Return a topic name in the absolute form rosbag2 records ('imu' -> '/imu')."""
    name = name.strip()
    return name if name.startswith('/') else '/' + name


def _topic_types(connections):
    """Map each topic to the set of message types recorded on it."""
    types = {}
    for c in connections:
        types.setdefault(c.topic, set()).add(c.msgtype)
    return types


def _pick_topic(types, msgtype, wanted, path, option):
    """
    Return the topic of ``msgtype`` to read: ``wanted`` if given, else the only one.

    :return: the topic name, or None when no topic has the type and none was asked for.
    """
    candidates = sorted(t for t, ts in types.items() if msgtype in ts)
    short = msgtype.replace('/msg/', '/')
    if wanted is not None:
        topic = _normalize_topic(wanted)
        if topic not in types:
            have = _list(candidates) if candidates else 'none'
            raise InputError(f'{path}: topic {topic} is not in the bag ({short} topics: '
                             f'{have})')
        if msgtype not in types[topic]:
            raise InputError(f'{path}: topic {topic} carries '
                             f'{", ".join(sorted(types[topic]))}, not {short}')
        return topic
    if len(candidates) > 1:
        raise InputError(f'{path}: several {short} topics ({", ".join(candidates)}); '
                         f'choose one with {option}')
    return candidates[0] if candidates else None


def _namespace(topic):
    """Return the namespace of a topic ('/imu/data_raw' -> '/imu')."""
    return topic.rsplit('/', 1)[0]


# Imu and Temperature end in a fixed block of float64 after the variable-length frame_id:
# Imu: orientation (4), its covariance (9), angular_velocity (3), covariance (9),
# linear_acceleration (3), covariance (9); Temperature: temperature, variance.
_TAIL_DOUBLES = {IMU_TYPE: 37, TEMP_TYPE: 2}
_IMU_COLUMNS = [25, 26, 27, 13, 14, 15, 16]  # accel xyz, gyro xyz, gyro covariance[0]
_TEMP_COLUMNS = [0]
_CDR_LE = b'\x00\x01'


def _decode_fast(raws, msgtype):
    """
    Decode little-endian CDR messages of one length with numpy, in one go.

    Layout after the 4-byte encapsulation header: stamp sec (int32), nanosec (uint32),
    frame_id length (uint32, with the NUL) and bytes, padding to 8, then the doubles.

    :return: (stamps ns, (N, k) doubles), or None when the batch does not fit the layout.
    """
    size = len(raws[0])
    tail = 8 * _TAIL_DOUBLES[msgtype]
    start = size - tail  # offset of the doubles in the raw message
    if start < 16 or (start - 4) % 8 or any(len(r) != size for r in raws):
        return None
    buf = np.frombuffer(b''.join(raws), dtype=np.uint8).reshape(len(raws), size)
    if np.any(buf[:, 0] != 0) or np.any(buf[:, 1] != 1):
        return None  # not little-endian plain CDR
    head = np.ascontiguousarray(buf[:, 4:16]).view('<u4')
    string_end = 16 + head[:, 2].astype(np.int64)
    if np.any(string_end > start) or np.any(start - string_end >= 8):
        return None  # the frame_id length does not lead to this padding
    stamps = head[:, 0].view('<i4').astype(np.int64) * 1_000_000_000 + head[:, 1]
    doubles = np.ascontiguousarray(buf[:, start:]).view('<f8')
    return stamps, doubles


def _decode_slow(raws, msgtype):
    """Decode messages one by one with rosbags (any layout, any byte order)."""
    deserialize = _types().deserialize_cdr
    stamps, rows = [], []
    for raw in raws:
        msg = deserialize(raw, msgtype)
        stamps.append(msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec)
        if msgtype == IMU_TYPE:
            q, w, a = msg.orientation, msg.angular_velocity, msg.linear_acceleration
            rows.append([q.x, q.y, q.z, q.w, *msg.orientation_covariance,
                         w.x, w.y, w.z, *msg.angular_velocity_covariance,
                         a.x, a.y, a.z, *msg.linear_acceleration_covariance])
        else:
            rows.append([msg.temperature, msg.variance])
    return (np.asarray(stamps, dtype=np.int64),
            np.asarray(rows, dtype=float).reshape(len(rows), _TAIL_DOUBLES[msgtype]))


def _read_topic(reader, topic, msgtype, columns):
    """
    Read every message of one topic.

    :return: (receive times ns, header stamps ns, (N, len(columns)) selected doubles).
    """
    connections = [c for c in reader.connections if c.topic == topic and c.msgtype == msgtype]
    received, raws = [], []
    for _, timestamp, raw in reader.messages(connections=connections):
        received.append(timestamp)
        raws.append(raw)
    received = np.asarray(received, dtype=np.int64)
    if not raws:
        return received, np.zeros(0, dtype=np.int64), np.zeros((0, len(columns)))
    decoded = _decode_fast(raws, msgtype) or _decode_slow(raws, msgtype)
    stamps, doubles = decoded
    return received, stamps, doubles[:, columns]


def _time_axis(received, stamps):
    """Choose header stamps, or receive times when the stamps were never set."""
    use_stamps = bool(np.any(stamps != 0))
    return (stamps if use_stamps else received), use_stamps


def _load_bag(path, imu_topic, temp_topic):
    """Read Imu (and Temperature) messages from a rosbag2 recording into Samples."""
    source = _bag_source(path)
    rosbag2 = _rosbags()[0]
    try:
        reader = rosbag2.Reader(source)
        reader.open()
    except Exception as exc:  # rosbags raises assorted errors on foreign or corrupt files
        raise InputError(f'{path}: not a readable rosbag2 recording ({_one_line(exc)}); '
                         f'expected {ACCEPTED}') from None
    try:
        types = _topic_types(reader.connections)
        imu = _pick_topic(types, IMU_TYPE, imu_topic, path, '--imu-topic')
        if imu is None:
            listing = ', '.join(f'{t} ({"/".join(sorted(ts))})' for t, ts in sorted(types.items()))
            raise InputError(f'{path}: no sensor_msgs/Imu topic in the bag '
                             f'(topics: {listing or "none"})')
        temp = temp_topic
        if temp is None:
            temps = sorted(t for t, ts in types.items() if TEMP_TYPE in ts)
            near = [t for t in temps if _namespace(t) == _namespace(imu)]
            if len(temps) > 1 and len(near) == 1:
                temp = near[0]
        temp = _pick_topic(types, TEMP_TYPE, temp, path, '--temp-topic')

        received, stamps, data = _read_topic(reader, imu, IMU_TYPE, _IMU_COLUMNS)
        if not len(data):
            raise InputError(f'{path}: topic {imu} holds no messages')
        imu_time, _ = _time_axis(received, stamps)
        order = np.argsort(imu_time, kind='stable')
        data = data[order]
        imu_time, received = imu_time[order], received[order]
        t = imu_time * 1e-9
        accel = data[:, 0:3]
        gyro = None if np.all(data[:, 6] == -1.0) else data[:, 3:6]

        temperature = None
        if temp is not None:
            t_received, t_stamps, values = _read_topic(reader, temp, TEMP_TYPE, _TEMP_COLUMNS)
            if not len(values) and temp_topic is not None:
                raise InputError(f'{path}: topic {temp} holds no messages')
            if len(values):
                x, use_stamps = _time_axis(t_received, t_stamps)
                at = imu_time if use_stamps else received
                order = np.argsort(x, kind='stable')
                temperature = np.interp(at.astype(float), x[order].astype(float),
                                        values[order, 0])
    except InputError:
        raise
    except Exception as exc:  # corrupt chunks or messages surface as assorted errors
        raise InputError(f'{path}: cannot read the bag ({_one_line(exc)})') from None
    finally:
        reader.close()
    return Samples(t, accel, temperature, gyro)


# --------------------------------------------------------------------------------------------
# Writing


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


def _csv_names(has_temp, has_gyro, extra_names=()):
    """Return the CSV header names for samples with/without temp and gyro, plus extras."""
    names = list(REQUIRED_COLUMNS)
    if has_temp:
        names.append('temp')
    if has_gyro:
        names.extend(GYRO_COLUMNS)
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
    for values in extra_values:
        data[:, col] = values
        col += 1
    row = '%.9f' + ',%.9g' * (width - 1) + '\n'
    return (row * n) % tuple(data.ravel().tolist())  # one C-level pass: faster than savetxt


class CsvWriter:
    """
    The spec CSV written piece by piece into a temporary file, then renamed into place.

    Use ``csv_writer(path, ...)``; each ``write`` appends rows. Memory stays bounded
    by the pieces given, whatever the length of the file.
    """

    BLOCK_ROWS = 1 << 15
    """Rows formatted at a time (the formatting holds Python floats for a block)."""

    def __init__(self, f, has_temp, has_gyro, extra_names):
        self._f = f
        self.has_temp = has_temp
        self.has_gyro = has_gyro
        self.extra_names = list(extra_names)
        self.names = _csv_names(has_temp, has_gyro, self.extra_names)
        self.rows = 0
        f.write(','.join(self.names) + '\n')

    def write(self, samples, extra=None):
        """
        Append samples (and their extra columns) to the file.

        :param samples: Samples with temp/gyro present exactly when the header has them.
        :param extra: dict name -> (N,) array, the same names as given to ``csv_writer``.
        :raises InputError: the samples or extra columns do not fit the header.
        """
        if (samples.temp is not None) != self.has_temp or \
                (samples.gyro is not None) != self.has_gyro:
            raise InputError('samples written to one CSV must all have (or lack) temp and gyro')
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
def csv_writer(path, has_temp=False, has_gyro=False, extra_names=()):
    """
    Open the spec CSV ``path`` for writing in pieces, atomically.

    The rows go to a temporary file next to ``path``; it replaces ``path`` only when the
    ``with`` block ends normally. On any exception (Ctrl-C included) it is removed and
    an existing ``path`` stays as it was.

    :param path: the CSV file to create or replace.
    :param has_temp: the file has a ``temp`` column.
    :param has_gyro: the file has ``gx, gy, gz`` columns.
    :param extra_names: names of extra columns after the standard ones.
    :return: context manager yielding a ``CsvWriter``.
    :raises InputError: the file cannot be written.
    """
    _check_extra({name: np.zeros(0) for name in extra_names}, 0)
    try:
        with atomic_path(path) as tmp:
            with open(tmp, 'w', encoding='utf-8', newline='') as f:
                yield CsvWriter(f, has_temp, has_gyro, extra_names)
    except OSError as exc:
        raise InputError(f'{path}: cannot write ({exc.strerror or _one_line(exc)})') from None


def write_samples_csv(path, samples, extra=None):
    """
    Write samples as the spec CSV, atomically.

    Columns: ``t, ax, ay, az``, then ``temp`` and ``gx, gy, gz`` when present, then the
    ``extra`` columns in the dict's order. Times are written with nanosecond resolution
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
                    [name for name, _ in checked]) as writer:
        writer.write(first, dict(checked) if checked else None)
        for piece in pieces:
            writer.write(piece)
    return writer.rows


def _storage_for(path, storage):
    """Return the rosbags storage plugin name for ``path`` and an optional explicit choice."""
    suffix = Path(path).suffix.lower()
    implied = {'.db3': 'sqlite3', '.mcap': 'mcap'}.get(suffix)
    if storage is None:
        return implied or 'mcap'
    if storage not in _STORAGE_SUFFIX:
        raise InputError(f'unknown bag storage {storage!r}; use mcap or sqlite3')
    if implied and implied != storage:
        raise InputError(f'{path}: a {suffix} file cannot hold {storage} storage')
    return storage


def _serialized_batch(msgtype, frame_id, ns, doubles):
    """
    Serialize one message per row: a rosbags-made template with stamps and doubles filled in.

    Only the numeric fields at the fixed offsets of ``_decode_fast`` are overwritten, so
    the byte layout (encapsulation header, frame_id string, padding) is rosbags' own.

    :param msgtype: IMU_TYPE or TEMP_TYPE.
    :param frame_id: header.frame_id of every message.
    :param ns: (N,) stamps, integer nanoseconds.
    :param doubles: (N, _TAIL_DOUBLES[msgtype]) values of the float64 tail.
    :return: (N, size) uint8 array, one serialized message per row.
    """
    ts = _types()
    header = ts.types['std_msgs/msg/Header'](
        stamp=ts.types['builtin_interfaces/msg/Time'](sec=0, nanosec=0), frame_id=frame_id)
    if msgtype == IMU_TYPE:
        vector = ts.types['geometry_msgs/msg/Vector3'](x=0.0, y=0.0, z=0.0)
        template = ts.types[IMU_TYPE](
            header=header,
            orientation=ts.types['geometry_msgs/msg/Quaternion'](x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=np.zeros(9), angular_velocity=vector,
            angular_velocity_covariance=np.zeros(9), linear_acceleration=vector,
            linear_acceleration_covariance=np.zeros(9))
    else:
        template = ts.types[TEMP_TYPE](header=header, temperature=0.0, variance=0.0)
    raw = np.frombuffer(bytes(ts.serialize_cdr(template, msgtype)), dtype=np.uint8)
    start = len(raw) - 8 * _TAIL_DOUBLES[msgtype]
    buf = np.tile(raw, (len(ns), 1))
    stamps = np.empty((len(ns), 2), dtype='<u4')
    stamps[:, 0] = ns // 1_000_000_000
    stamps[:, 1] = ns % 1_000_000_000
    buf[:, 4:12] = stamps.view(np.uint8).reshape(len(ns), 8)
    buf[:, start:] = np.ascontiguousarray(doubles, dtype='<f8').view(np.uint8).reshape(
        len(ns), -1)
    return buf


def _bag_batches(samples, frame_id):
    """Serialize one piece of Samples: (stamps ns, Imu messages, Temperature messages)."""
    n = len(samples)
    ns = np.round(samples.t * 1e9).astype(np.int64)
    imu = np.zeros((n, _TAIL_DOUBLES[IMU_TYPE]))
    imu[:, 3] = 1.0  # identity orientation quaternion ...
    imu[:, 4] = -1.0  # ... marked unknown (REP-145: covariance[0] = -1)
    if samples.gyro is None:
        imu[:, 16] = -1.0  # no angular velocity either
    else:
        imu[:, 13:16] = samples.gyro
    imu[:, 25:28] = samples.accel  # its covariance stays all zeros: "unknown"
    imu_raw = _serialized_batch(IMU_TYPE, frame_id, ns, imu)
    temp_raw = None
    if samples.temp is not None:
        temp_raw = _serialized_batch(TEMP_TYPE, frame_id, ns,
                                     np.column_stack([samples.temp, np.zeros(n)]))
    return ns, imu_raw, temp_raw


def _write_bag_dir(bagdir, pieces, imu_topic, temp_topic, frame_id, storage):
    """Write the rosbag2 directory ``bagdir`` (must not exist) from Samples pieces."""
    ts = _types()
    rosbag2 = _rosbags()[0]
    plugins = rosbag2.StoragePlugin
    plugin = plugins.SQLITE3 if storage == 'sqlite3' else plugins.MCAP
    with rosbag2.Writer(bagdir, version=rosbag2.Writer.VERSION_LATEST,
                        storage_plugin=plugin) as writer:
        imu_conn = temp_conn = None
        for samples in pieces:
            ns, imu_raw, temp_raw = _bag_batches(samples, frame_id)
            if imu_conn is None:
                imu_conn = writer.add_connection(imu_topic, IMU_TYPE, typestore=ts)
                if temp_raw is not None:
                    temp_conn = writer.add_connection(temp_topic, TEMP_TYPE, typestore=ts)
            for i, stamp in enumerate(ns.tolist()):
                writer.write(imu_conn, stamp, imu_raw[i].tobytes())
                if temp_conn is not None:
                    writer.write(temp_conn, stamp, temp_raw[i].tobytes())


def _checked_pieces(first, rest):
    """Yield ``first`` then ``rest``: validated, times in order, the same columns in each."""
    yield first
    t_last = first.t[-1]
    for piece in rest:
        piece.validate()
        if (piece.temp is None) != (first.temp is None) or \
                (piece.gyro is None) != (first.gyro is None):
            raise InputError('samples written to one bag must all have (or lack) temp and gyro')
        if piece.t[0] < t_last:
            raise InputError('bag samples must be in increasing time order')
        t_last = piece.t[-1]
        yield piece


def _fsync_tree(directory):
    """Flush every file of a freshly written directory to disk."""
    for entry in os.scandir(directory):
        if entry.is_file():
            fd = os.open(entry.path, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
    fsync_directory(directory)


def write_bag(path, samples, imu_topic='/imu/data_raw', temp_topic='/imu/temperature',
              frame_id='imu_link', storage=None):
    """
    Write samples as a rosbag2 recording of Imu (and Temperature) messages.

    ``path`` ending in ``.mcap`` / ``.db3`` gives one self-contained storage file at that
    path, replaced atomically; any other path gives a bag directory ``path/`` with
    ``metadata.yaml``, as ``ros2 bag record -o path`` would (see the module docstring).
    Header stamps and receive times are both ``t``; orientation is marked unknown and, when
    the samples have no gyro, so is the angular velocity (REP-145). The temperature, when
    present, is published on ``temp_topic`` with the same stamp as each Imu message.

    :param path: output file (``.mcap``/``.db3``) or bag directory.
    :param samples: the Samples to write (t in seconds, t >= 0), or an iterable of Samples
        pieces in time order (written in turn, in bounded memory).
    :param imu_topic: topic of the ``sensor_msgs/msg/Imu`` messages.
    :param temp_topic: topic of the ``sensor_msgs/msg/Temperature`` messages.
    :param frame_id: ``header.frame_id`` of every message.
    :param storage: 'mcap' or 'sqlite3'; default from the suffix (.db3 -> sqlite3, else mcap).
    :return: the Path written (the file or the bag directory).
    :raises InputError: bad samples or arguments, an existing bag directory, or the
        location cannot be written.
    """
    target = Path(path)
    storage = _storage_for(target, storage)
    rest = iter(())
    if not isinstance(samples, Samples):
        rest = iter(samples)
        samples = next(rest, None)
        if samples is None:
            raise InputError('no samples: the recording is empty')
    samples.validate()
    if samples.t[0] < 0:
        raise InputError('bag times must not be negative (t starts at '
                         f'{samples.t[0]:.9g} s); shift t to start at zero or later')
    imu_topic = _normalize_topic(imu_topic)
    temp_topic = _normalize_topic(temp_topic)
    if samples.temp is not None and temp_topic == imu_topic:
        raise InputError(f'the Imu and Temperature topics must differ (both {imu_topic})')
    single_file = target.suffix.lower() in BAG_SUFFIXES
    if not single_file and os.path.lexists(target):
        raise InputError(f'{target} exists already; a rosbag2 directory is never overwritten, '
                         f'choose a new name')
    parent = target.parent
    if not parent.is_dir():
        raise InputError(f'{target}: output directory {parent} does not exist')
    name = target.stem if single_file else target.name
    try:
        import tempfile      # here, not at the top: reading a CSV does not pay for it
        scratch = Path(tempfile.mkdtemp(prefix=f'.{name}.', suffix='.tmp', dir=parent))
    except OSError as exc:
        raise InputError(f'{target}: cannot write ({exc.strerror or _one_line(exc)})') from None
    try:
        bagdir = scratch / name
        _write_bag_dir(bagdir, _checked_pieces(samples, rest), imu_topic, temp_topic,
                       frame_id, storage)
        _fsync_tree(bagdir)
        if single_file:
            replace_into(bagdir / f'{name}{_STORAGE_SUFFIX[storage]}', str(target))
        else:
            os.rename(bagdir, target)
            fsync_directory(str(parent))
    except OSError as exc:
        raise InputError(f'{target}: cannot write ({exc.strerror or _one_line(exc)})') from None
    finally:
        import shutil
        shutil.rmtree(scratch, ignore_errors=True)
    return target
