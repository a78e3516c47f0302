"""
The unit of the accelerometer columns of a recording, and its conversion to m/s².

Everything past the reader works in SI units (REP-103), and every file the package
writes holds m/s². A recording may hold the acceleration in

* ``m/s2`` (the interface's CSV and ``sensor_msgs/Imu``; the default),
* ``g`` (standard gravity, 9.80665 m/s², whatever the local gravity), or
* ``counts``: raw ADC codes, ``a = (counts - counts_offset) / counts_per_g * 9.80665``.
  ``counts_per_g`` is the sensor's nominal sensitivity (16384 for an MPU-9250 at ±2 g;
  for a signed 16-bit sensor at range ±R g it is 32768 / R); ``counts_offset`` is the
  code of zero acceleration: 0 for signed (two's complement) codes, 32768 for unsigned
  16-bit codes such as imu_tk's Xsens recording. The offset is never guessed: a wrong
  guess would hide in the fitted bias, so it is asked for when the data look unsigned.

The calibration fitted on converted readings is relative to the nominal sensitivity
(``T`` near identity, bias in m/s²); ``apply`` must be given the same conversion.

A recording whose median acceleration magnitude is far from 1 g after conversion is
in another unit than the one declared: :func:`check_magnitude` refuses it with one line
that names the option to give. Only the accelerometer columns are converted (gyro in
rad/s, temperature in °C as interface.md says).
"""

import numpy as np

from ..core.constants import G0
from ..core.errors import InputError
from ..core.samples import Samples
from ..core.stats import median

UNITS = ('m/s2', 'g', 'counts')
"""Units the accelerometer columns may be declared in (``--units``)."""
PLAUSIBLE_G = (0.25, 4.0)
"""Median acceleration magnitude believed for a recording on Earth, in g."""
MAX_CHECKED_ROWS = 1_000_000
"""The magnitude test looks at most at this many rows (evenly spaced)."""


def scale_and_offset(units='m/s2', counts_per_g=None, counts_offset=0.0):
    """
    Return (factor, offset) with ``a_m_s2 = (reading - offset) * factor``.

    :param units: one of :data:`UNITS`.
    :param counts_per_g: nominal counts per g (``counts`` only, required there).
    :param counts_offset: code of zero acceleration (``counts`` only).
    :raises InputError: unknown unit, or counts without their sensitivity.
    """
    if units in (None, 'm/s2'):
        return 1.0, 0.0
    if units == 'g':
        return G0, 0.0
    if units != 'counts':
        raise InputError(f'unknown unit {units!r}; choose one of {", ".join(UNITS)}')
    if counts_per_g is None:
        raise InputError(COUNTS_NEED_SENSITIVITY)
    if not (np.isfinite(counts_per_g) and counts_per_g > 0):
        raise InputError(f'counts per g must be a positive number, got {counts_per_g!r}')
    return G0 / float(counts_per_g), float(counts_offset or 0.0)


COUNTS_NEED_SENSITIVITY = ('--units counts needs the sensitivity: --counts-per-g N '
                           '(e.g. 16384 for an MPU-9250 at ±2 g) or --range G (a signed '
                           '16-bit sensor at ±G g: 32768/G counts per g)')
"""The one refusal of raw counts without their sensitivity."""


def to_si(samples, units='m/s2', counts_per_g=None, counts_offset=0.0):
    """
    Return ``samples`` with the acceleration in m/s² (the same object when already SI).

    :param samples: Samples as read (accel in ``units``).
    :return: Samples with accel in m/s² (t, temp, gyro and mag unchanged).
    :raises InputError: as :func:`scale_and_offset`.
    """
    factor, offset = scale_and_offset(units, counts_per_g, counts_offset)
    if factor == 1.0 and offset == 0.0:
        return samples
    return Samples(samples.t, (samples.accel - offset) * factor, samples.temp, samples.gyro,
                   samples.mag)


def median_magnitude(accel):
    """Median of |a| over the rows of ``accel`` (N, 3) (at most MAX_CHECKED_ROWS looked at)."""
    a = np.asarray(accel, float).reshape(-1, 3)
    if len(a) > MAX_CHECKED_ROWS:
        a = a[::len(a) // MAX_CHECKED_ROWS + 1]
    return median(np.linalg.norm(a, axis=1)) if len(a) else float('nan')


def check_magnitude(si_accel, raw_accel=None, units='m/s2', counts_per_g=None,
                    counts_offset=0.0):
    """
    Refuse a recording whose median |a| is not about 1 g after conversion.

    :param si_accel: (N, 3) converted acceleration, m/s².
    :param raw_accel: (N, 3) the readings as in the file (for the hint), or None.
    :param units: the declared unit (for the message).
    :raises InputError: one line saying what the data look like and which option to give.
    """
    median = median_magnitude(si_accel)
    low, high = PLAUSIBLE_G
    if not np.isfinite(median) or median == 0.0 or low * G0 <= median <= high * G0:
        return              # exactly 0: a stuck sensor, which the commands name as such
    raw = si_accel if raw_accel is None else raw_accel
    raw_median = median_magnitude(raw)
    expected = f'not about {G0:.2f} m/s² (1 g)'
    if units == 'counts':
        hint = ('check --counts-per-g / --range' + _offset_hint(raw, counts_offset))
        raise InputError(f'with --units counts ({counts_per_g:g} counts per g, offset '
                         f'{counts_offset:g}) the median |a| is {median:.4g} m/s², {expected}: '
                         f'{hint}')
    if units != 'g' and low <= raw_median <= high:
        hint = 'the data are in g: add --units g'
    elif units == 'g' and low * G0 <= raw_median <= high * G0:
        hint = 'the data are in m/s²: give --units m/s2'
    elif raw_median > high * G0:
        hint = ('raw counts? add --units counts with --counts-per-g N or --range G'
                + _offset_hint(raw, 0.0))
    else:
        hint = 'give their unit with --units (m/s2, g or counts)'
    declared = f'{raw_median:.4g} g ({median:.4g} m/s²)' if units == 'g' else f'{median:.4g} m/s²'
    raise InputError(f'the median |a| is {declared}, {expected}: {hint}')


def _offset_hint(raw, offset):
    """Suggest --counts-offset 32768 when the codes look unsigned 16-bit and it is not set."""
    a = np.asarray(raw, float).reshape(-1, 3)
    if offset or not len(a):
        return ''
    centre = np.median(a, axis=0)
    if np.all(a.min(axis=0) >= 0) and np.all(np.abs(centre - 32768.0) < 16384.0):
        return '; codes centre near 32768 (unsigned): add --counts-offset 32768'
    return ''


# -- the record of a conversion (a calibration file's ``input_units``) ------------------

def input_units(units='m/s2', counts_per_g=None, counts_offset=0.0):
    """
    Return the ``input_units`` record of a conversion to m/s² (:func:`to_si`'s options).

    :param units: 'm/s2', 'g' or 'counts'; ``counts_per_g``, ``counts_offset``: for counts.
    """
    if units != 'counts':
        return {'accel': units or 'm/s2'}
    return {'accel': 'counts', 'counts_per_g': float(counts_per_g),
            'counts_offset': float(counts_offset or 0.0)}


def same_conversion(a, b):
    """Whether two ``input_units`` records convert alike (m/s2 and g are both exact)."""
    if 'counts' not in (a['accel'], b['accel']):
        return True
    if a['accel'] != b['accel']:
        return False
    return (abs(a['counts_per_g'] - b['counts_per_g']) <= 1e-9 * b['counts_per_g']
            and abs((a.get('counts_offset') or 0.0) - (b.get('counts_offset') or 0.0)) <= 1e-9)


def conversion_words(units):
    """Say an ``input_units`` record in words (``counts at 16384 counts per g, offset 0``)."""
    if units['accel'] != 'counts':
        return units['accel']
    return (f'counts at {units["counts_per_g"]:g} counts per g, offset '
            f'{units.get("counts_offset") or 0.0:g}')
