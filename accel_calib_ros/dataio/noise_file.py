"""
Read the sensor noise of an ``accel-calib allan --json`` result for the simulators.

The Allan result (interface.md §8) carries ``white_sample_std``: per axis, the std of
one sample of the white part of the noise at the recording's rate ``rate_hz``
(``noise_density * sqrt(rate_hz)``). A simulator at another rate keeps the noise
density, so the per-sample std it draws is ``white_sample_std * sqrt(rate / rate_hz)``.
Every problem raises :class:`core.errors.InputError` with a one-line message.
"""

import json
import math
import os

import numpy as np

from .atomic import open_regular
from ..core.errors import InputError

MAX_BYTES = 20_000_000
"""An Allan JSON is a few hundred kB at most; refuse anything far bigger."""
ACCEL_AXES = ['ax', 'ay', 'az']
GYRO_AXES = ['gx', 'gy', 'gz']
MAX_ACCEL_STD = 100.0
"""Largest plausible accelerometer sample std, m/s² (about 10 g)."""
MAX_GYRO_STD = 10.0
"""Largest plausible gyro sample std, rad/s."""


def _read(path):
    what = f'--noise-from {path}'
    if os.path.isdir(path):
        raise InputError(f'{what} is a directory')
    try:
        with open_regular(path) as f:
            data = f.read(MAX_BYTES + 1)
        if len(data) > MAX_BYTES:
            raise InputError(f'{what} is larger than {MAX_BYTES // 1_000_000} MB: '
                             'not an allan --json result')
        text = data.decode('utf-8')
    except FileNotFoundError:
        raise InputError(f'{what}: no such file') from None
    except UnicodeDecodeError:
        raise InputError(f'{what} is not UTF-8 text (expected allan --json output)') from None
    except OSError as err:
        raise InputError(f'{what}: {err.strerror or err}') from None
    try:
        data = json.loads(text, parse_constant=lambda name: math.nan,
                          object_pairs_hook=_unique_keys)
    except _DuplicateKey as err:
        raise InputError(f'{what}: {err}') from None
    except (ValueError, RecursionError) as err:
        raise InputError(f'{what} is not JSON ({str(err).splitlines()[0][:80]})') from None
    if not isinstance(data, dict):
        raise InputError(f'{what}: expected the JSON object of "accel-calib allan --json"')
    return data, what


class _DuplicateKey(ValueError):
    """Internal: a JSON object gives a key twice."""


def _unique_keys(pairs):
    """JSON object hook: refuse a key given twice (no silent last-win)."""
    seen = set()
    for key, _ in pairs:
        if key in seen:
            shown = repr(key) if len(repr(key)) <= 40 else repr(key)[:39] + '…'
            raise _DuplicateKey(f'duplicate key {shown}: say it once')
        seen.add(key)
    return dict(pairs)


def _number(value):
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return math.nan
    return float(value)


def noise_from_allan(path, rate_hz):
    """
    Per-sample white noise for a simulator at ``rate_hz``, from an allan JSON file.

    :param path: file written from ``accel-calib allan DATA --json``.
    :param rate_hz: sample rate of the simulation, Hz.
    :return: (accel std (3,) m/s², gyro std (3,) rad/s or None when the file has no gyro).
    :raises InputError: unreadable file, missing keys, wrong lengths, non-finite,
        negative or implausible values.
    """
    data, what = _read(os.path.expanduser(os.fspath(path)))
    for key in ('axes', 'white_sample_std', 'rate_hz'):
        if key not in data:
            raise InputError(f'{what}: missing key {key!r} (expected allan --json output)')
    axes, std = data['axes'], data['white_sample_std']
    if axes not in (ACCEL_AXES, ACCEL_AXES + GYRO_AXES):
        raise InputError(f'{what}: "axes" must be {ACCEL_AXES} or '
                         f'{ACCEL_AXES + GYRO_AXES}, got {str(axes)[:60]}')
    if not isinstance(std, list) or len(std) != len(axes):
        raise InputError(f'{what}: "white_sample_std" must be a list of {len(axes)} numbers '
                         f'(one per axis), got {str(std)[:60]}')
    values = np.array([_number(v) for v in std])
    recorded = _number(data['rate_hz'])
    if not (math.isfinite(recorded) and 0 < recorded <= 1e6):
        raise InputError(f'{what}: "rate_hz" must be a finite rate in (0, 1e6] Hz, '
                         f'got {str(data["rate_hz"])[:40]}')
    if not np.all(np.isfinite(values)):
        raise InputError(f'{what}: "white_sample_std" has a non-finite or non-number value')
    if np.any(values < 0):
        raise InputError(f'{what}: "white_sample_std" has a negative value')
    if np.any(values[:3] > MAX_ACCEL_STD) or np.any(values[3:] > MAX_GYRO_STD):
        raise InputError(f'{what}: "white_sample_std" is implausibly large (accel at most '
                         f'{MAX_ACCEL_STD:g} m/s², gyro at most {MAX_GYRO_STD:g} rad/s)')
    values = values * math.sqrt(rate_hz / recorded)
    return values[:3], (values[3:] if len(values) == 6 else None)
