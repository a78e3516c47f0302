"""
Per-sensor calibration history: a small SQLite database next to the calibration file.

Two tables, keyed by a sensor id (an id from the firmware, the port, or a name the user
gives; normalised by :func:`dataio.sensor_id.normalise_sensor_id`):

- ``calibrations``: one row per fit with its time, the temperature range of its data,
  the method, the predicted accuracy (interface §5), the residual and the parameters
  (T, bias, gyro bias), so parameter drift over months can be read back and plotted.
- ``windows``: every static window ever kept (mean reading, temperature, weight, time,
  gyro mean), so temperature bands fill across sessions on different days and a
  thermal fit can use all of them. Adding the same window twice keeps one copy.

Sessions (schema 2): every row carries the ``session`` that wrote it, one id per
``fit --history`` run, ``guide --history`` run or saved calibration of the node
(:func:`new_session_id`). A session is written whole or not at all
(:meth:`History.record_session`: its windows and its calibration in one transaction, only
once the calibration was accepted), and :meth:`History.forget` removes a session (or
every session of a sensor). A schema-1 database is migrated when first opened for
writing: its rows join the session ``legacy``; read-only it is read as it is.

Safe for several processes at once: WAL journal, a busy timeout, and every write in
one ``BEGIN IMMEDIATE`` transaction (a writer waits for the other instead of failing).
Damage (a zeroed page, a row of the wrong shape, text where a number belongs, a
foreign database) is an :class:`HistoryDamaged` naming it; :meth:`History.check` lists
all of it. Standard library only (sqlite3, json) plus numpy.
"""

import json
import os
import sqlite3
import stat
import time

import numpy as np

from .atomic import make_parents, output_target, remove_made
from .history_schema import (BadRow, calibration_row, COLUMNS, LEGACY_SESSION, MAX_TIME_S,
                             MAX_VALUE, SCHEMA, SCHEMA_VERSION, SCHEMAS, SESSION_INDEXES, shown,
                             window_row)
from .sensor_id import MAX_SENSOR_ID, normalise_sensor_id
from ..core.errors import InputError
from ..core.finite import finite_or_none

BUSY_TIMEOUT_S = 30.0
MAX_PROBLEMS = 50
"""Problems :meth:`History.check` lists at most."""

__all__ = ['History', 'HistoryDamaged', 'MAX_SENSOR_ID', 'new_session_id']


class HistoryDamaged(InputError):
    """The history database is damaged or not a history (one line naming the damage)."""


def default_history_path(sensor=None):
    """``history.sqlite`` beside the default calibration file (of ``sensor``, if given)."""
    from .calibration_file import default_calibration_path
    return os.path.join(os.path.dirname(default_calibration_path(sensor)), 'history.sqlite')


def new_session_id():
    """Return a new session id: UTC time, 6 random hex digits (``20250101T120000Z-1a2b3c``)."""
    return time.strftime('%Y%m%dT%H%M%SZ', time.gmtime()) + '-' + os.urandom(3).hex()


def _sensor(sensor_id):
    return normalise_sensor_id(sensor_id)


def _session(session):
    if not isinstance(session, str) or not session.strip() or len(session) > 100 \
            or not session.isprintable():
        raise InputError('a session id must be printable text of at most 100 characters')
    return session.strip()


def _vector_json(value, size):
    if value is None:
        return None
    v = np.asarray(value, float).reshape(-1)
    if v.size != size or not np.all(np.isfinite(v)):
        return None
    return json.dumps([float(x) for x in v])


class History:
    """
    The history database of one calibration directory.

    :param path: SQLite file (created with its directory when missing, unless
        ``readonly``).
    :param readonly: only read: nothing is created, migrated or written.
    :raises InputError: the file is not a usable history database (:class:`HistoryDamaged`
        when it is damaged or foreign; ``UnsafeOutput`` when it may not be written: a
        device, a FIFO, a link of another user).
    """

    def __init__(self, path, readonly=False):
        self.path = os.fspath(path)
        self.readonly = readonly
        self.db = None
        made = []
        try:
            if readonly:
                self._check_readable()
                from urllib.parse import quote
                uri = 'file:' + quote(os.path.abspath(self.path)) + '?mode=ro'
                self.db = sqlite3.connect(uri, uri=True, timeout=BUSY_TIMEOUT_S,
                                          isolation_level=None)
            else:
                real = output_target(self.path)
                if os.path.isdir(real):
                    raise InputError(f'{self.path}: is a directory, not a history database')
                for suffix in ('-wal', '-shm', '-journal'):    # sqlite opens these by name
                    if os.path.lexists(real + suffix):
                        output_target(real + suffix)
                made = make_parents(os.path.dirname(real))
                self.db = sqlite3.connect(real, timeout=BUSY_TIMEOUT_S, isolation_level=None)
        except (OSError, sqlite3.Error) as err:
            remove_made(made)
            raise InputError(f'cannot open history {self.path}: {err}') from None
        except BaseException:
            remove_made(made)
            raise
        try:
            self.db.execute(f'PRAGMA busy_timeout = {int(BUSY_TIMEOUT_S * 1000)}')
            self.version = self._open_schema()
            self.has_session = self.version != '1'
        except sqlite3.DatabaseError as err:
            self.db.close()
            remove_made(made)
            raise HistoryDamaged(f'{self.path}: damaged, or not a history database ({err})') \
                from None
        except BaseException:
            self.db.close()
            remove_made(made)
            raise

    def _check_readable(self):
        try:
            st = os.stat(self.path)
        except FileNotFoundError:
            raise InputError(f'no history at {self.path}') from None
        if stat.S_ISDIR(st.st_mode):
            raise InputError(f'{self.path}: is a directory, not a history database')
        if not stat.S_ISREG(st.st_mode):
            raise InputError(f'{self.path}: is not a regular file, not a history database')
        if st.st_size == 0:
            raise InputError(f'{self.path}: is an empty file, not a history database')

    def _tables(self):
        return {row[0] for row in self.db.execute(
            "SELECT name FROM sqlite_master WHERE type = 'table'")}

    def _schema_row(self):
        try:
            row = self.db.execute("SELECT value FROM meta WHERE key = 'schema'").fetchone()
        except sqlite3.OperationalError as err:
            raise HistoryDamaged(f"{self.path}: its meta table is not a history's ({err})") \
                from None
        return None if row is None else str(row[0])

    def _foreign(self):
        return HistoryDamaged(f'{self.path}: an SQLite database of something else (not an '
                              'accel_calib_ros history); choose another file')

    def _open_schema(self):
        """Check (and, for writing, create or migrate) the schema; return its version."""
        tables = self._tables()
        if tables and 'meta' not in tables:     # e.g. a rosbag2 .db3: leave it alone
            raise self._foreign()
        version = None
        if tables:
            version = self._schema_row()
            self._check_version(version)
            self._check_tables(version)
        elif self.readonly:
            raise HistoryDamaged(f'{self.path}: an empty database, not a history')
        if self.readonly:
            return version
        if tables:                  # never write into a damaged file (it would spread)
            bad = [r[0] for r in self.db.execute('PRAGMA quick_check').fetchall() if r[0] != 'ok']
            if bad:
                raise HistoryDamaged(f'{self.path}: the database is damaged ({bad[0]}); '
                                     '"accel-calib history check" lists the damage')
        self.db.execute('PRAGMA journal_mode = WAL')
        self.db.execute('PRAGMA synchronous = NORMAL')
        with self._write():
            tables = self._tables()             # again, now that we hold the lock
            if not tables:
                for statement in (SCHEMA + ';' + SESSION_INDEXES).split(';'):
                    if statement.strip():
                        self.db.execute(statement)
                self.db.execute("INSERT INTO meta VALUES ('schema', ?)", (str(SCHEMA_VERSION),))
                return str(SCHEMA_VERSION)
            version = self._schema_row()
            self._check_version(version)
            self._check_tables(version)
            if version == '1':
                self._migrate_1_to_2()
            return str(SCHEMA_VERSION)

    def _check_version(self, version):
        if version is None:
            raise self._foreign()
        if version not in SCHEMAS:
            raise HistoryDamaged(f'{self.path}: history schema {version[:20]!r} is not one this '
                                 f'version reads ({", ".join(SCHEMAS)}); a newer accel_calib_ros '
                                 'wrote it')

    def _check_tables(self, version):
        for table, columns in COLUMNS.items():
            have = {row[1] for row in self.db.execute(f'PRAGMA table_info({table})')}
            wanted = set(columns) | ({'session'} if version != '1' else set())
            if not wanted <= have:
                missing = ', '.join(sorted(wanted - have))
                raise HistoryDamaged(f'{self.path}: table {table} lacks column(s) {missing} '
                                     '(damaged, or not an accel_calib_ros history)')

    def _migrate_1_to_2(self):
        """Migrate schema 1 to 2 (in the caller's transaction): rows join the legacy session."""
        for table in ('calibrations', 'windows'):
            self.db.execute(f'ALTER TABLE {table} ADD COLUMN session TEXT')
            self.db.execute(f'UPDATE {table} SET session = ?', (LEGACY_SESSION,))
        for statement in SESSION_INDEXES.split(';'):
            if statement.strip():
                self.db.execute(statement)
        self.db.execute("UPDATE meta SET value = ? WHERE key = 'schema'", (str(SCHEMA_VERSION),))

    # -- plumbing ---------------------------------------------------------------------------
    def _write(self):
        if self.readonly:
            raise InputError(f'history {self.path} was opened read-only')
        return _Transaction(self.db, self.path)

    def _rows(self, sql, args=()):
        """Run a query; a damaged database is a HistoryDamaged naming the damage."""
        try:
            return self.db.execute(sql, args).fetchall()
        except sqlite3.DatabaseError as err:
            raise HistoryDamaged(f'{self.path}: the database is damaged ({err}); '
                                 '"accel-calib history check" lists the damage') from None

    def _damaged(self, table, row_id, err):
        return HistoryDamaged(f'{self.path}: {table} row {row_id}: {err}; "accel-calib history '
                              'check" lists the damage, "history forget" removes a session')

    def _session_sql(self):
        return f"COALESCE(session, '{LEGACY_SESSION}')" if self.has_session \
            else f"'{LEGACY_SESSION}'"

    def close(self):
        """Close the connection."""
        if self.db is not None:
            self.db.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # -- writing ----------------------------------------------------------------------------
    def add_calibration(self, sensor_id, cal, windows=None, time_s=None, session=None):
        """
        Record a fitted calibration (a session of its own unless ``session`` is given).

        :param sensor_id: the sensor's name.
        :param cal: core.calibration.Calibration.
        :param windows: windows the fit used (default ``cal.observations``).
        :param time_s: when, Unix time s (default now).
        :param session: session id (default a new one).
        :return: the row id.
        """
        row = self._calibration_values(sensor_id, cal, windows, time_s, session)
        with self._write():
            return self._insert_calibration(row)

    def add_windows(self, sensor_id, means, temps, weights, time_s, gyro_means=None,
                    session=None):
        """
        Keep static windows of a session; a window already kept is not added again.

        :param means: (N, 3) mean raw acceleration, m/s².
        :param temps: (N,) °C (NaN when unknown).
        :param weights: (N,) samples (capped) of each window.
        :param time_s: (N,) Unix time of each window, s.
        :param gyro_means: (N, 3) mean angular rate, rad/s, or None.
        :param session: session id (default a new one).
        :return: number of windows added.
        """
        rows = self._window_values(sensor_id, means, temps, weights, time_s, gyro_means,
                                   session)
        with self._write():
            return self._insert_windows(rows)

    def record_session(self, sensor_id, session, cal, means, temps, weights, time_s,
                       gyro_means=None, windows=None):
        """
        Record one accepted session whole: its windows and its calibration, one transaction.

        Called only once the calibration was accepted (and written), so a refused or
        failed fit leaves the history as it was.

        :param sensor_id: the sensor's name.
        :param session: the session id (:func:`new_session_id`).
        :param cal: the accepted Calibration.
        :param means: (N, 3) this session's window means, m/s² (see :meth:`add_windows`).
        :param temps: (N,) °C or None.
        :param weights: (N,) window weights.
        :param time_s: (N,) Unix times of the windows, s.
        :param gyro_means: (N, 3) rad/s or None.
        :param windows: windows the fit used (default ``cal.observations``).
        :return: number of windows added (those not kept already).
        """
        session = _session(session)
        rows = self._window_values(sensor_id, means, temps, weights, time_s, gyro_means,
                                   session)
        row = self._calibration_values(sensor_id, cal, windows, None, session)
        with self._write():
            added = self._insert_windows(rows)
            self._insert_calibration(row)
        return added

    def forget(self, sensor_id, session=None):
        """
        Remove a session of a sensor (or all of its sessions) in one transaction.

        :param sensor_id: the sensor.
        :param session: the session id, or None for every session of the sensor.
        :return: (windows removed, calibrations removed).
        """
        sensor_id = _sensor(sensor_id)
        where, args = 'sensor_id = ?', (sensor_id,)
        if session is not None:
            where += f' AND {self._session_sql()} = ?'
            args += (_session(session),)
        with self._write():
            try:
                windows = self.db.execute(f'DELETE FROM windows WHERE {where}', args).rowcount
                cals = self.db.execute(f'DELETE FROM calibrations WHERE {where}', args).rowcount
            except sqlite3.DatabaseError as err:
                raise HistoryDamaged(f'{self.path}: the database is damaged ({err}); '
                                     '"accel-calib history check" lists the damage') from None
        return windows, cals

    def _calibration_values(self, sensor_id, cal, windows, time_s, session):
        sensor_id = _sensor(sensor_id)
        T = np.asarray(cal.T, float)
        bias = np.asarray(cal.bias, float)
        if not (np.all(np.isfinite(T)) and np.all(np.isfinite(bias))):
            raise InputError('a calibration with non-finite parameters is not recorded')
        if max(np.abs(T).max(), np.abs(bias).max()) > MAX_VALUE:
            raise InputError(f'a calibration with parameters beyond {MAX_VALUE:g} is not '
                             'recorded')
        trange = getattr(cal, 'temperature_range_c', None) or (None, None)
        time_s = float(time.time() if time_s is None else time_s)
        if not 0.0 <= time_s <= MAX_TIME_S:
            raise InputError(f'a calibration time must be a Unix time in [0, {MAX_TIME_S:g}] s')
        return (sensor_id, time_s,
                str(getattr(cal, 'created', '') or ''), str(cal.method),
                finite_or_none(trange[0]), finite_or_none(trange[1]),
                finite_or_none(getattr(cal, 'predicted_accuracy', None)),
                finite_or_none(cal.residual_rms),
                int(cal.observations if windows is None else windows),
                json.dumps(T.reshape(-1).tolist()), json.dumps(bias.tolist()),
                _vector_json(getattr(cal, 'gyro_bias', None), 3),
                str(getattr(cal, 'source', '') or ''),
                new_session_id() if session is None else _session(session))

    def _insert_calibration(self, row):
        cur = self.db.execute(
            'INSERT INTO calibrations (sensor_id, time_s, created, method, temp_min_c, '
            'temp_max_c, predicted_accuracy, residual_rms, windows, T, bias, gyro_bias, '
            'source, session) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)', row)
        return cur.lastrowid

    def _window_values(self, sensor_id, means, temps, weights, time_s, gyro_means, session):
        sensor_id = _sensor(sensor_id)
        session = new_session_id() if session is None else _session(session)
        means = np.asarray(means, float).reshape(-1, 3)
        n = len(means)
        temps = np.broadcast_to(np.asarray(np.nan if temps is None else temps, float), (n,))
        weights = np.broadcast_to(np.asarray(weights, float), (n,))
        times = np.broadcast_to(np.asarray(time_s, float), (n,))
        gyro = np.full((n, 3), np.nan) if gyro_means is None else \
            np.asarray(gyro_means, float).reshape(n, 3)
        if not (np.all(np.isfinite(means)) and np.all(np.isfinite(times))):
            raise InputError('window means and times must be finite')
        if np.any(times < 0) or np.any(times > MAX_TIME_S):
            raise InputError(f'window times must be Unix times in [0, {MAX_TIME_S:g}] s')
        if not (np.all(np.isfinite(weights)) and np.all(weights > 0)):
            raise InputError('window weights must be finite and positive')
        return [(sensor_id, float(times[k]), *map(float, means[k]), finite_or_none(temps[k]),
                 float(weights[k]), *map(finite_or_none, gyro[k]), session) for k in range(n)]

    def _insert_windows(self, rows):
        before = self.db.total_changes
        self.db.executemany(
            'INSERT OR IGNORE INTO windows (sensor_id, time_s, mx, my, mz, temp_c, weight, '
            'gx, gy, gz, session) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)', rows)
        return self.db.total_changes - before

    # -- reading ----------------------------------------------------------------------------
    def sensors(self):
        """Return the sensor ids with calibrations or windows, sorted."""
        rows = self._rows('SELECT sensor_id FROM calibrations UNION '
                          'SELECT sensor_id FROM windows ORDER BY 1')
        return [str(r[0]) for r in rows]

    def windows(self, sensor_id):
        """
        Return all windows kept for a sensor, oldest first.

        :return: dict of arrays: ``mean`` (N, 3) m/s², ``temp`` (N,) °C (NaN unknown),
            ``weight`` (N,), ``time_s`` (N,) Unix s, ``gyro_mean`` (N, 3) rad/s (NaN
            unknown), and ``session`` (N,) object array of session ids.
        :raises HistoryDamaged: a row holds something no window has.
        """
        rows = self._rows(
            'SELECT id, sensor_id, time_s, mx, my, mz, temp_c, weight, gx, gy, gz, '
            f'{self._session_sql()} FROM windows WHERE sensor_id = ? ORDER BY time_s, id',
            (_sensor(sensor_id),))
        values = []
        for r in rows:
            try:
                values.append(window_row(r))
            except BadRow as err:
                raise self._damaged('windows', r[0], err) from None
        a = np.array(values, float).reshape(-1, 9)
        return {'mean': a[:, 1:4], 'temp': a[:, 4], 'weight': a[:, 5], 'time_s': a[:, 0],
                'gyro_mean': a[:, 6:9], 'session': np.array([r[11] for r in rows], object)}

    def calibrations(self, sensor_id=None):
        """
        Return the recorded calibrations, oldest first (of one sensor, or of all).

        :return: list of dicts: id, sensor_id, time_s, created, method,
            temperature_range_c, predicted_accuracy, residual_rms, windows, T (3x3 lists),
            bias, gyro_bias (or None), source, session.
        :raises HistoryDamaged: a row holds something no calibration has.
        """
        sql = ('SELECT id, sensor_id, time_s, created, method, temp_min_c, temp_max_c, '
               'predicted_accuracy, residual_rms, windows, T, bias, gyro_bias, source, '
               f'{self._session_sql()} FROM calibrations')
        args = ()
        if sensor_id is not None:
            sql += ' WHERE sensor_id = ?'
            args = (_sensor(sensor_id),)
        out = []
        for r in self._rows(sql + ' ORDER BY time_s, id', args):
            try:
                out.append(calibration_row(r))
            except BadRow as err:
                raise self._damaged('calibrations', r[0], err) from None
        out.sort(key=lambda c: (c['time_s'], c['id']))   # a text time_s sorts apart in SQL
        return out

    def sessions(self, sensor_id=None):
        """
        Return the sessions, oldest first: dicts sensor_id, session, windows, calibrations.

        :param sensor_id: only this sensor's (None: every sensor's).
        """
        where, args = '', ()
        if sensor_id is not None:
            where, args = 'WHERE sensor_id = ?', (_sensor(sensor_id),)
        col = self._session_sql()
        rows = self._rows(
            f'SELECT sensor_id, s, SUM(w), SUM(c), MIN(t) FROM ('
            f'SELECT sensor_id, {col} AS s, 1 AS w, 0 AS c, time_s AS t FROM windows {where} '
            f'UNION ALL SELECT sensor_id, {col}, 0, 1, time_s FROM calibrations {where}) '
            'GROUP BY sensor_id, s ORDER BY MIN(t), s', args + args)
        return [{'sensor_id': str(r[0]), 'session': str(r[1]), 'windows': int(r[2]),
                 'calibrations': int(r[3])} for r in rows]

    def check(self):
        """
        Look for damage: the file's pages, the schema, every row.

        :return: list of one-line problems (empty when the history is sound), at most
            ``MAX_PROBLEMS`` (the last one then says how many more there were).
        """
        problems = []
        try:
            rows = self.db.execute('PRAGMA quick_check').fetchall()
            problems += [f'page damage: {r[0]}' for r in rows if r[0] != 'ok']
        except sqlite3.DatabaseError as err:
            return [f'the file is damaged: {err}']
        scans = (('calibrations', 'SELECT id, sensor_id, time_s, created, method, temp_min_c, '
                  'temp_max_c, predicted_accuracy, residual_rms, windows, T, bias, gyro_bias, '
                  f'source, {self._session_sql()} FROM calibrations ORDER BY id',
                  calibration_row),
                 ('windows', 'SELECT id, sensor_id, time_s, mx, my, mz, temp_c, weight, gx, gy, '
                  f'gz, {self._session_sql()} FROM windows ORDER BY id', window_row))
        more = 0
        for table, sql, parse in scans:
            try:
                rows = self.db.execute(sql).fetchall()
            except sqlite3.DatabaseError as err:
                problems.append(f'table {table} cannot be read: {err}')
                continue
            for r in rows:
                try:
                    parse(r)
                    normalise_sensor_id(r[1])
                except (BadRow, InputError) as err:
                    if len(problems) < MAX_PROBLEMS:
                        problems.append(f'{table} row {r[0]} (sensor {shown(r[1])}, '
                                        f'session {shown(r[-1])}): {err}')
                    else:
                        more += 1
        if more:
            problems.append(f'and {more} more damaged rows')
        return problems


class _Transaction:
    """``BEGIN IMMEDIATE`` ... ``COMMIT`` (rollback on error); sqlite errors as InputError."""

    def __init__(self, db, path):
        self.db = db
        self.path = path

    def __enter__(self):
        try:
            self.db.execute('BEGIN IMMEDIATE')
        except sqlite3.OperationalError as err:
            raise InputError(f'history {self.path} is busy or read-only: {err}') from None
        except sqlite3.DatabaseError as err:
            raise HistoryDamaged(f'{self.path}: the database is damaged ({err}); '
                                 '"accel-calib history check" lists the damage') from None
        return self.db

    def _rollback(self):
        try:
            self.db.execute('ROLLBACK')
        except sqlite3.Error:
            pass

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            try:
                self.db.execute('COMMIT')
            except sqlite3.Error as err:
                self._rollback()
                raise InputError(f'cannot write history {self.path}: {err}') from None
            return False
        self._rollback()
        if issubclass(exc_type, sqlite3.DatabaseError):
            raise HistoryDamaged(f'cannot write history {self.path}: {exc} (damaged? '
                                 '"accel-calib history check" lists the damage)') from None
        if issubclass(exc_type, sqlite3.Error):
            raise InputError(f'cannot write history {self.path}: {exc}') from None
        return False
