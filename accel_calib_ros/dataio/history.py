"""
Per-sensor calibration history: a small SQLite database next to the calibration file.

Two tables, keyed by a sensor id (an id from the firmware, the port, or a name the user
gives):

- ``calibrations``: one row per fit with its time, the temperature range of its data,
  the method, the predicted accuracy (interface §5), the residual and the parameters
  (T, bias, gyro bias), so parameter drift over months can be read back and plotted.
- ``windows``: every static window ever kept (mean reading, temperature, weight, time,
  gyro mean), so temperature bands fill across sessions on different days and a
  thermal fit can use all of them. Adding the same window twice keeps one copy.

Safe for several processes at once: WAL journal, a busy timeout, and every write in
one ``BEGIN IMMEDIATE`` transaction (a writer waits for the other instead of failing).
Standard library only (sqlite3, json) plus numpy.
"""

import json
import math
import os
import sqlite3
import time

import numpy as np

from ..core.errors import InputError

SCHEMA_VERSION = 1
BUSY_TIMEOUT_S = 30.0
MAX_SENSOR_ID = 200

_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS calibrations (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    sensor_id TEXT NOT NULL,
    time_s REAL NOT NULL,
    created TEXT,
    method TEXT,
    temp_min_c REAL,
    temp_max_c REAL,
    predicted_accuracy REAL,
    residual_rms REAL,
    windows INTEGER,
    T TEXT NOT NULL,
    bias TEXT NOT NULL,
    gyro_bias TEXT,
    source TEXT
);
CREATE INDEX IF NOT EXISTS calibrations_sensor ON calibrations (sensor_id, time_s);
CREATE TABLE IF NOT EXISTS windows (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    sensor_id TEXT NOT NULL,
    time_s REAL NOT NULL,
    mx REAL NOT NULL, my REAL NOT NULL, mz REAL NOT NULL,
    temp_c REAL,
    weight REAL NOT NULL,
    gx REAL, gy REAL, gz REAL,
    UNIQUE (sensor_id, mx, my, mz, weight)
);
CREATE INDEX IF NOT EXISTS windows_sensor ON windows (sensor_id, time_s);
"""


def default_history_path():
    """``history.sqlite`` in the directory of the default calibration file."""
    from .calibration_file import default_calibration_path
    return os.path.join(os.path.dirname(default_calibration_path()), 'history.sqlite')


def _sensor(sensor_id):
    if not isinstance(sensor_id, str) or not sensor_id.strip():
        raise InputError('a sensor id must be a non-empty string')
    if len(sensor_id) > MAX_SENSOR_ID or any(ord(c) < 32 for c in sensor_id):
        raise InputError(f'a sensor id is at most {MAX_SENSOR_ID} printable characters')
    return sensor_id.strip()


def _opt(value):
    """Finite float or None (SQL NULL)."""
    if value is None:
        return None
    value = float(value)
    return value if math.isfinite(value) else None


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

    :param path: SQLite file (created with its directory when missing).
    :raises InputError: the file is not a usable history database.
    """

    def __init__(self, path):
        self.path = os.fspath(path)
        if os.path.isdir(self.path):
            raise InputError(f'{self.path}: is a directory, not a history database')
        directory = os.path.dirname(os.path.abspath(self.path))
        try:
            os.makedirs(directory, exist_ok=True)
            self.db = sqlite3.connect(self.path, timeout=BUSY_TIMEOUT_S, isolation_level=None)
        except (OSError, sqlite3.Error) as err:
            raise InputError(f'cannot open history {self.path}: {err}') from None
        try:
            self.db.execute(f'PRAGMA busy_timeout = {int(BUSY_TIMEOUT_S * 1000)}')
            tables = {row[0] for row in self.db.execute(
                "SELECT name FROM sqlite_master WHERE type = 'table'")}
            if tables and 'meta' not in tables:     # e.g. a rosbag2 .db3: leave it alone
                raise InputError(f'{self.path}: an SQLite database of something else '
                                 '(not an accel_calib_ros history); choose another file')
            self.db.execute('PRAGMA journal_mode = WAL')
            self.db.execute('PRAGMA synchronous = NORMAL')
            with self._write():
                for statement in _SCHEMA.split(';'):
                    if statement.strip():
                        self.db.execute(statement)
                row = self.db.execute("SELECT value FROM meta WHERE key = 'schema'").fetchone()
                if row is None:
                    self.db.execute("INSERT INTO meta VALUES ('schema', ?)",
                                    (str(SCHEMA_VERSION),))
                elif row[0] != str(SCHEMA_VERSION):
                    raise InputError(f'{self.path}: history schema {row[0]} is not supported')
        except sqlite3.DatabaseError as err:
            self.db.close()
            raise InputError(f'{self.path}: not a history database ({err})') from None
        except InputError:
            self.db.close()
            raise

    # -- plumbing ---------------------------------------------------------------------------
    def _write(self):
        return _Transaction(self.db, self.path)

    def close(self):
        """Close the connection."""
        self.db.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # -- writing ----------------------------------------------------------------------------
    def add_calibration(self, sensor_id, cal, windows=None, time_s=None):
        """
        Record a fitted calibration.

        :param sensor_id: the sensor's name.
        :param cal: core.model.Calibration.
        :param windows: windows the fit used (default ``cal.observations``).
        :param time_s: when, Unix time s (default now).
        :return: the row id.
        """
        sensor_id = _sensor(sensor_id)
        T = np.asarray(cal.T, float)
        bias = np.asarray(cal.bias, float)
        if not (np.all(np.isfinite(T)) and np.all(np.isfinite(bias))):
            raise InputError('a calibration with non-finite parameters is not recorded')
        trange = getattr(cal, 'temperature_range_c', None) or (None, None)
        row = (sensor_id, float(time.time() if time_s is None else time_s),
               str(getattr(cal, 'created', '') or ''), str(cal.method),
               _opt(trange[0]), _opt(trange[1]),
               _opt(getattr(cal, 'predicted_accuracy', None)), _opt(cal.residual_rms),
               int(cal.observations if windows is None else windows),
               json.dumps(T.reshape(-1).tolist()), json.dumps(bias.tolist()),
               _vector_json(getattr(cal, 'gyro_bias', None), 3),
               str(getattr(cal, 'source', '') or ''))
        with self._write():
            cur = self.db.execute(
                'INSERT INTO calibrations (sensor_id, time_s, created, method, temp_min_c, '
                'temp_max_c, predicted_accuracy, residual_rms, windows, T, bias, gyro_bias, '
                'source) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)', row)
            return cur.lastrowid

    def add_windows(self, sensor_id, means, temps, weights, time_s, gyro_means=None):
        """
        Keep static windows of a session; a window already kept is not added again.

        :param means: (N, 3) mean raw acceleration, m/s².
        :param temps: (N,) °C (NaN when unknown).
        :param weights: (N,) samples (capped) of each window.
        :param time_s: (N,) Unix time of each window, s.
        :param gyro_means: (N, 3) mean angular rate, rad/s, or None.
        :return: number of windows added.
        """
        sensor_id = _sensor(sensor_id)
        means = np.asarray(means, float).reshape(-1, 3)
        n = len(means)
        temps = np.broadcast_to(np.asarray(np.nan if temps is None else temps, float), (n,))
        weights = np.broadcast_to(np.asarray(weights, float), (n,))
        times = np.broadcast_to(np.asarray(time_s, float), (n,))
        gyro = np.full((n, 3), np.nan) if gyro_means is None else \
            np.asarray(gyro_means, float).reshape(n, 3)
        if not (np.all(np.isfinite(means)) and np.all(np.isfinite(times))):
            raise InputError('window means and times must be finite')
        if not (np.all(np.isfinite(weights)) and np.all(weights > 0)):
            raise InputError('window weights must be finite and positive')
        rows = [(sensor_id, float(times[k]), *map(float, means[k]), _opt(temps[k]),
                 float(weights[k]), *map(_opt, gyro[k])) for k in range(n)]
        with self._write():
            before = self.db.total_changes
            self.db.executemany(
                'INSERT OR IGNORE INTO windows (sensor_id, time_s, mx, my, mz, temp_c, weight, '
                'gx, gy, gz) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?)', rows)
            return self.db.total_changes - before

    # -- reading ----------------------------------------------------------------------------
    def sensors(self):
        """Return the sensor ids with calibrations or windows, sorted."""
        rows = self.db.execute('SELECT sensor_id FROM calibrations UNION '
                               'SELECT sensor_id FROM windows ORDER BY 1').fetchall()
        return [r[0] for r in rows]

    def windows(self, sensor_id):
        """
        Return all windows kept for a sensor, oldest first.

        :return: dict of arrays: ``mean`` (N, 3) m/s², ``temp`` (N,) °C (NaN unknown),
            ``weight`` (N,), ``time_s`` (N,) Unix s, ``gyro_mean`` (N, 3) rad/s (NaN unknown).
        """
        rows = self.db.execute(
            'SELECT mx, my, mz, temp_c, weight, time_s, gx, gy, gz FROM windows '
            'WHERE sensor_id = ? ORDER BY time_s, id', (_sensor(sensor_id),)).fetchall()
        a = np.array([[np.nan if v is None else v for v in r] for r in rows],
                     float).reshape(-1, 9)
        return {'mean': a[:, 0:3], 'temp': a[:, 3], 'weight': a[:, 4], 'time_s': a[:, 5],
                'gyro_mean': a[:, 6:9]}

    def calibrations(self, sensor_id=None):
        """
        Return the recorded calibrations, oldest first (of one sensor, or of all).

        :return: list of dicts: id, sensor_id, time_s, created, method,
            temperature_range_c, predicted_accuracy, residual_rms, windows, T (3x3 lists),
            bias, gyro_bias (or None), source.
        """
        sql = ('SELECT id, sensor_id, time_s, created, method, temp_min_c, temp_max_c, '
               'predicted_accuracy, residual_rms, windows, T, bias, gyro_bias, source '
               'FROM calibrations')
        args = ()
        if sensor_id is not None:
            sql += ' WHERE sensor_id = ?'
            args = (_sensor(sensor_id),)
        out = []
        for r in self.db.execute(sql + ' ORDER BY time_s, id', args).fetchall():
            T = np.array(json.loads(r[10]), float).reshape(3, 3)
            out.append({
                'id': r[0], 'sensor_id': r[1], 'time_s': r[2], 'created': r[3],
                'method': r[4],
                'temperature_range_c': None if r[5] is None else [r[5], r[6]],
                'predicted_accuracy': r[7], 'residual_rms': r[8], 'windows': r[9],
                'T': T.tolist(), 'bias': json.loads(r[11]),
                'gyro_bias': None if r[12] is None else json.loads(r[12]),
                'source': r[13]})
        return out


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
        return self.db

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            try:
                self.db.execute('COMMIT')
            except sqlite3.Error as err:
                self.db.execute('ROLLBACK')
                raise InputError(f'cannot write history {self.path}: {err}') from None
        else:
            try:
                self.db.execute('ROLLBACK')
            except sqlite3.Error:
                pass
        return False
