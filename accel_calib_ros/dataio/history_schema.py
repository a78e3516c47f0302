"""
What the history database holds: its tables, their versions, and rows read back checked.

Schema 2 (sessions) is written; schema 1 is read, and migrated when written. A row that
a foreign program, a disk fault or a hand edit has damaged raises :class:`BadRow` with
what is wrong (``History.check`` lists them; a read names the first). Limits: a time is
a Unix time before :data:`MAX_TIME_S`, a stored value is within :data:`MAX_VALUE`, a
window's weight within :data:`MAX_WEIGHT`.
"""

import json
import math

import numpy as np


SCHEMA_VERSION = 2


SCHEMAS = ('1', '2')
"""Schema versions this code reads (1 is migrated to 2 when written)."""


LEGACY_SESSION = 'legacy'
"""Session of the rows of a schema-1 database (written before sessions existed)."""


SCHEMA = """
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
    source TEXT,
    session TEXT
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
    session TEXT,
    UNIQUE (sensor_id, mx, my, mz, weight)
);
CREATE INDEX IF NOT EXISTS windows_sensor ON windows (sensor_id, time_s);
"""


SESSION_INDEXES = """
CREATE INDEX IF NOT EXISTS calibrations_session ON calibrations (sensor_id, session);
CREATE INDEX IF NOT EXISTS windows_session ON windows (sensor_id, session)
"""


COLUMNS = {
    'calibrations': ('id', 'sensor_id', 'time_s', 'created', 'method', 'temp_min_c',
                     'temp_max_c', 'predicted_accuracy', 'residual_rms', 'windows', 'T', 'bias',
                     'gyro_bias', 'source'),
    'windows': ('id', 'sensor_id', 'time_s', 'mx', 'my', 'mz', 'temp_c', 'weight', 'gx', 'gy',
                'gz'),
}


class BadRow(Exception):
    """One damaged value of a stored row (the message names it)."""


MAX_TIME_S = 1e11
"""Latest Unix time a row may hold, s (the year 5138): beyond it a time is damage."""


MAX_VALUE = 1e9
"""Largest magnitude a stored parameter or reading may have (raw counts included)."""


MAX_WEIGHT = 1e12
"""Largest window weight (samples) a row may hold."""


def _real(value, name, optional=False, positive=False, low=-MAX_VALUE, high=MAX_VALUE):
    if value is None and optional:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not math.isfinite(value):
        raise BadRow(f'{name} is {shown(value)}, not a finite number')
    if positive and not value > 0:
        raise BadRow(f'{name} is {value!r}, not positive')
    if not low <= value <= high:
        raise BadRow(f'{name} is {value!r}, outside [{low:g}, {high:g}]')
    return float(value)


def shown(value):
    """Return ``repr(value)`` cut to 30 characters for a message."""
    text = repr(value)
    return text if len(text) <= 30 else text[:29] + '…'


def _numbers(text, name, size, optional=False, limit=MAX_VALUE):
    if text is None and optional:
        return None
    if not isinstance(text, str):
        raise BadRow(f'{name} is {shown(text)}, not JSON text')
    try:
        values = json.loads(text)
    except (ValueError, RecursionError):
        raise BadRow(f'{name} is not valid JSON ({shown(text)})') from None
    if not isinstance(values, list) or len(values) != size:
        raise BadRow(f'{name} holds {shown(values)}, not a list of {size} numbers')
    return [_real(v, name, low=-limit, high=limit) for v in values]


def _text(value, name, optional=True):
    if value is None and optional:
        return None
    if not isinstance(value, str):
        raise BadRow(f'{name} is {shown(value)}, not text')
    return value


def calibration_row(r):
    """Return the dict of one ``calibrations`` row (see :meth:`History.calibrations`)."""
    T = _numbers(r[10], 'T', 9)
    low = _real(r[5], 'temp_min_c', optional=True, low=-1e3, high=1e3)
    high = _real(r[6], 'temp_max_c', optional=True, low=-1e3, high=1e3)
    windows = r[9]
    if windows is not None and (isinstance(windows, bool) or not isinstance(windows, int)
                                or windows < 0):
        raise BadRow(f'windows is {shown(windows)}, not a count')
    return {
        'id': r[0], 'sensor_id': _text(r[1], 'sensor_id', False),
        'time_s': _real(r[2], 'time_s', low=0.0, high=MAX_TIME_S),
        'created': _text(r[3], 'created'),
        'method': _text(r[4], 'method'),
        'temperature_range_c': None if low is None or high is None else [low, high],
        'predicted_accuracy': _real(r[7], 'predicted_accuracy', optional=True, low=0.0),
        'residual_rms': _real(r[8], 'residual_rms', optional=True, low=0.0),
        'windows': windows,
        'T': np.array(T).reshape(3, 3).tolist(), 'bias': _numbers(r[11], 'bias', 3),
        'gyro_bias': _numbers(r[12], 'gyro_bias', 3, optional=True),
        'source': _text(r[13], 'source'), 'session': _text(r[14], 'session')}


def window_row(r):
    """Return one ``windows`` row as 9 floats (NaN for unknown temperature and gyro)."""
    _text(r[1], 'sensor_id', False)
    values = [_real(r[2], 'time_s', low=0.0, high=MAX_TIME_S),
              _real(r[3], 'mx'), _real(r[4], 'my'), _real(r[5], 'mz'),
              _real(r[6], 'temp_c', optional=True, low=-1e3, high=1e3),
              _real(r[7], 'weight', positive=True, high=MAX_WEIGHT),
              _real(r[8], 'gx', optional=True), _real(r[9], 'gy', optional=True),
              _real(r[10], 'gz', optional=True)]
    _text(r[11], 'session')
    return [math.nan if v is None else v for v in values]
