"""
Time columns in any unit: ``--time-unit {s,ms,us,ns}``, and the check for the wrong one.

A time spacing that no IMU has (a rate outside 1 Hz .. 100 kHz) is refused with the
unit that would make it plausible; a temperature logger's averaged output down to 0.1 Hz is
taken when its own temperature says it is one (``slow_logger``).
"""

from ..core.errors import InputError


TIME_UNITS = {'s': 1.0, 'ms': 1e-3, 'us': 1e-6, 'ns': 1e-9}
"""Units the ``t`` column may be given in: seconds per unit."""


TIME_UNIT_NAMES = {'s': 'seconds', 'ms': 'milliseconds', 'us': 'microseconds',
                   'ns': 'nanoseconds'}


PLAUSIBLE_RATE_HZ = (1.0, 100_000.0)
"""Sample rates an IMU recording may have, Hz: a ``t`` spacing outside them is refused."""


_TYPICAL_RATE_HZ = 200.0

SLOW_LOGGER_HZ = 0.1
"""Slowest rate taken from a temperature logger (``slow_logger``), Hz."""

MIN_LOGGER_SPAN_C = 2.0
"""A slow logger's temperature must move this much, °C, to vouch for its time unit."""

IMPOSSIBLE_HEATING_C_MIN = 100.0
"""No IMU's temperature changes this fast, °C/min: a time unit that says so is wrong."""


def seconds(columns, unit):
    """
    Convert the time column of parsed CSV columns from ``unit`` to seconds, in place.

    :param columns: dict column name -> array, as parsed (or None / empty).
    :param unit: 's', 'ms', 'us' or 'ns'.
    :return: ``columns``.
    :raises InputError: an unknown unit.
    """
    if unit not in TIME_UNITS:
        raise InputError(f'unknown time unit {str(unit)[:20]!r}; use one of '
                         f'{", ".join(TIME_UNITS)}')
    if columns and unit != 's' and 't' in columns:
        columns['t'] *= TIME_UNITS[unit]
    return columns


def slow_logger(t, temp):
    """
    Tell whether a recording slower than 1 Hz is a temperature logger's, by its temperature.

    A fast IMU stamped in milliseconds and read as seconds also looks slower than 1 Hz; but
    a temperature that moves by ``MIN_LOGGER_SPAN_C`` or more would then have moved faster
    than ``IMPOSSIBLE_HEATING_C_MIN`` in the recording's true (1000 times shorter) time:
    only seconds make it plausible.

    :param t: (N,) times in seconds. :param temp: (N,) °C or None.
    """
    import numpy as np
    if temp is None:
        return False
    finite = np.isfinite(temp)
    if finite.sum() < 2 or t[-1] <= t[0]:
        return False
    span = float(np.ptp(temp[finite]))
    as_milliseconds = span / ((t[-1] - t[0]) * 1e-3) * 60.0
    return span >= MIN_LOGGER_SPAN_C and as_milliseconds > IMPOSSIBLE_HEATING_C_MIN


def check_time_spacing(path, t, unit='s', temp=None):
    """
    Refuse a time column whose spacing no IMU has: it is in another unit than said.

    The median step between distinct times gives the sample rate, and so does the number
    of samples over the duration; when neither lies in ``PLAUSIBLE_RATE_HZ`` the file is
    refused, naming the unit that would make the rate plausible (milliseconds under ``t``
    would otherwise give hundreds of false windows). Either one in range is enough: coarse
    stamps (many samples per stamp) or one long gap do not make a file implausible.

    :param path: the file, for the message.
    :param t: (N,) times in seconds (already converted from ``unit``), increasing.
    :param unit: the unit the file's numbers were read in.
    :param temp: (N,) the temperature column, °C, or None: a logger between
        ``SLOW_LOGGER_HZ`` and 1 Hz is taken when it vouches for its unit (``slow_logger``).
    :raises InputError: the rate is not an IMU's.
    """
    import numpy as np
    from ..core.stats import median
    step = np.diff(t)
    step = step[step > 0]
    if not len(step):
        return
    low, high = PLAUSIBLE_RATE_HZ
    mean_rate = (len(t) - 1) / (t[-1] - t[0])
    step = median(step)
    rate = 1.0 / step
    if low <= rate <= high or low <= mean_rate <= high:    # coarse stamps, or a long gap
        return
    if SLOW_LOGGER_HZ <= rate < low and slow_logger(t, temp):   # a temperature logger
        return
    given = step / TIME_UNITS[unit]           # the step in the file's own numbers
    fits = [(abs(np.log10(1.0 / (given * scale) / _TYPICAL_RATE_HZ)), u)
            for u, scale in TIME_UNITS.items()
            if u != unit and low <= 1.0 / (given * scale) <= high]
    hint = 'check the t column'
    if fits:
        best = min(fits)[1]
        hint = (f'if t is in {TIME_UNIT_NAMES[best]}, give --time-unit {best} (then '
                f'{1.0 / (given * TIME_UNITS[best]):.4g} Hz)')
    raise InputError(f'{path}: t steps by {given:.4g} (median): {rate:.4g} Hz in '
                     f'{TIME_UNIT_NAMES[unit]}, not an IMU rate ({low:g} Hz .. '
                     f'{high / 1e3:g} kHz); {hint}')
