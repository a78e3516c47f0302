"""
Damaged and foreign history databases, as users hit them.

Shared by test/dataio/test_history_integrity.py and bench/bench_reliability.py (the "history"
row): :func:`damage` turns a copy of a good history database into one of ``DAMAGE``.
"""

import os
import sqlite3


def damage(path, how):
    """Damage a copy of a good history database in one of the ways users hit."""
    db = sqlite3.connect(path)
    db.execute('PRAGMA wal_checkpoint(TRUNCATE)')
    db.execute('PRAGMA journal_mode = DELETE')
    statements = {
        'bad_json': "UPDATE calibrations SET T = '[1, 2'",
        'wrong_size_T': "UPDATE calibrations SET T = '[1, 2, 3]'",
        'text_time': "UPDATE calibrations SET time_s = 'yesterday'",
        'huge_time': 'UPDATE calibrations SET time_s = 1e300',
        'text_window': "UPDATE windows SET mx = 'abc' WHERE id = 3",
        'null_weight_text': "UPDATE windows SET weight = 'heavy' WHERE id = 2",
        'bias_object': 'UPDATE calibrations SET bias = \'{"x": 1}\'',
        'newer_schema': "UPDATE meta SET value = '9' WHERE key = 'schema'",
        'no_schema_row': 'DELETE FROM meta',
        'dropped_column': 'ALTER TABLE windows DROP COLUMN gz',
    }
    if how in statements:
        db.execute(statements[how])
        db.commit()
    db.close()
    if how.startswith('zero_page_'):
        with open(path, 'rb') as f:
            data = bytearray(f.read())
        size = int.from_bytes(data[16:18], 'big')
        page = int(how.rsplit('_', 1)[1])
        data[page * size:(page + 1) * size] = bytes(size)
        with open(path, 'wb') as f:
            f.write(bytes(data))
    elif how == 'foreign':
        os.remove(path)
        with sqlite3.connect(path) as db:
            db.execute('CREATE TABLE meta (k TEXT, v TEXT)')
            db.execute('CREATE TABLE other (x)')
    elif how == 'rosbag_like':
        os.remove(path)
        with sqlite3.connect(path) as db:
            db.execute('CREATE TABLE topics (id INTEGER, name TEXT)')
    elif how == 'text':
        with open(path, 'w') as f:
            f.write('{"not": "a database"}\n')
    elif how == 'empty':
        with open(path, 'w'):
            pass


DAMAGE = ['bad_json', 'wrong_size_T', 'text_time', 'huge_time', 'text_window',
          'null_weight_text', 'bias_object', 'newer_schema', 'no_schema_row', 'dropped_column',
          'zero_page_0', 'zero_page_1', 'zero_page_2', 'zero_page_3', 'foreign',
          'rosbag_like', 'text', 'empty']
EMPTY_IS_NEW = ('empty',)
"""Damage that is no damage to a writer: ``fit --history`` starts a history in an empty file."""
