"""
Calibration files: the one validating loader and the atomic writer.

A calibration file is versioned, human-readable YAML with units in the key names
(see :func:`calibration_to_dict`). :func:`load_calibration` is the only way the
product reads one: it checks the schema, the types, that every number is finite
and in a plausible range (a well-conditioned upper-triangular ``T``, a bias smaller
than gravity, ordered non-overlapping temperature bands with bounded drift
coefficients) and turns every problem - a missing file, a directory, a huge or
non-UTF-8 file, broken or deeply nested YAML - into one
:class:`~accel_calib_ros.core.errors.InputError` with a one-line message.
:func:`save_calibration` refuses to write anything that the loader would refuse and
replaces the file atomically, creating its directory. Imports yaml, numpy and the
scipy-free ``core.calibration`` only.

The optional IMU parts (interface.md §9, §10) are validated the same way: ``gyro: {T, bias,
predicted_accuracy}`` (T well-conditioned, near identity; bias as ``gyro_bias_rad_s``)
and ``magnetometer: {T, hard_iron_uT, R, field_uT, dip_deg, predicted_accuracy}`` (T
well-conditioned, R a rotation, plausible field and dip). ``input_units: {accel, counts_per_g,
counts_offset}`` records how the fitted readings were turned into m/s² (``dataio.units``;
``apply`` uses it and refuses another conversion). One gyro bias per file: the
writer puts the same vector in ``gyro_bias_rad_s`` and ``gyro.bias``; the loader takes
``gyro.bias`` when only it is given and refuses a file whose two differ (by more than
``SAME_GYRO_BIAS_RAD_S``), so neither silently wins over the other.
"""

import math
import os

import numpy as np
import yaml

from .thermal_file import thermal_table
from .units import UNITS
from .yaml_schema import (_found, _mapping, _matrix, _number, _optional, _string,  # noqa: F401
                          _vector, Bad as _Bad, load_yaml, nesting_depth, UniqueKeyLoader)
from ..core.calibration import (Calibration, FIELD_RANGE_UT, gyro_problems, magnetometer_problems,
                                MagnetometerPart, MAX_CONDITION, MAX_GYRO_BIAS, MAX_HARD_IRON_UT,
                                METHODS, PARAMETER_NAMES)
from ..core.errors import CalibrationError, InputError
from ..core.finite import finite_or_none

FORMAT = 'accel_calib_ros/calibration'
VERSION = 1
MAX_FILE_BYTES = 1 << 18
"""Largest calibration file read, bytes (a real one is a few kB; 200 thermal bands with
gyro biases, the most the loader takes, under 100 kB)."""
MAX_NESTING = 32
"""Deepest nesting of a calibration file's YAML, as :func:`nesting_depth` bounds it (the
writer's files reach 5): checked before parsing, so a file of nested brackets is
refused at once instead of after a long parse."""
MAX_BANDS = 200
GRAVITY_RANGE = (0.1, 100.0)
"""Gravity magnitudes accepted, m/s² (1.0 allows data in units of g)."""
T_DIAGONAL_RANGE = (1e-6, 1e6)
"""Diagonal of T accepted (readings per true unit; raw counts are about 1.7e3)."""
TEMPERATURE_RANGE = (-100.0, 200.0)
"""Temperatures accepted, °C."""
MAX_RELATIVE_ACCURACY = 1.0
"""Largest gyroscope predicted accuracy accepted (relative: 1 = 100 % of the rate)."""
SAME_GYRO_BIAS_RAD_S = 1e-9
"""``gyro.bias`` and ``gyro_bias_rad_s`` must agree to this, rad/s (one bias per file)."""


def default_calibration_path(sensor=None):
    """
    Where the calibration is kept unless told otherwise: one folder per sensor.

    ``$ROS_HOME/accel_calib_ros/<sensor>/calibration.yaml`` (``$ROS_HOME`` defaults to
    ``~/.ros``); the sensor id's ``/``-separated parts are folders (``robot1/imu_link``),
    empty, ``.`` and ``..`` parts are left out. Without a sensor: the package's folder.

    :param sensor: the sensor id (the nodes: namespace and frame_id), or None.
    """
    root = os.environ.get('ROS_HOME', os.path.join(os.path.expanduser('~'), '.ros'))
    parts = [p for p in str(sensor or '').split('/') if p not in ('', '.', '..')]
    return os.path.join(root, 'accel_calib_ros', *parts, 'calibration.yaml')


# -- writing ---------------------------------------------------------------------------

def _floats(values):
    return [float(v) for v in np.asarray(values, float).reshape(-1)]


def calibration_to_dict(cal):
    """
    Versioned, YAML-ready mapping with units in the key names.

    Unknown noise and residual (NaN) are written as null; any other non-finite value
    is kept, so that :func:`calibration_from_dict` refuses it.
    """
    with np.errstate(all='ignore'):
        return _to_dict(cal)


def _to_dict(cal):
    d = {
        'format': FORMAT, 'version': VERSION, 'created': str(cal.created),
        'source': str(cal.source),
        'model': 'raw = T @ true + bias + drift(raw, temp); '
        'true = inv(T) @ (raw - bias - drift(raw, temp))',
        'method': cal.method, 'gravity_m_s2': float(cal.gravity),
        'T': [_floats(row) for row in cal.T],
        'bias_m_s2': _floats(cal.bias),
        'scale': _floats(cal.scale),
        'nonorthogonality_deg': dict(zip(('xy', 'xz', 'yz'),
                                         _floats(cal.nonorthogonality_deg))),
        'fit': {'observations': int(cal.observations), 'iterations': int(cal.iterations),
                'converged': bool(cal.converged), 'seconds': float(cal.seconds),
                'residual_rms_m_s2': finite_or_none(cal.residual_rms),
                'noise_std_m_s2': [finite_or_none(v) for v in cal.noise_std]},
    }
    if cal.predicted_accuracy is not None:
        d['predicted_accuracy_m_s2'] = float(cal.predicted_accuracy)
    if cal.sensor_id is not None:
        d['sensor_id'] = str(cal.sensor_id)
    if cal.temperature_range_c is not None:
        d['temperature_range_c'] = _floats(cal.temperature_range_c)
    if cal.gyro_bias is not None:
        d['gyro_bias_rad_s'] = _floats(cal.gyro_bias)
    if cal.level_roll_pitch_rad is not None:
        d['level_roll_pitch_rad'] = _floats(cal.level_roll_pitch_rad)
    if cal.covariance is not None:
        d['covariance'] = {
            'order': list(PARAMETER_NAMES), 'units': 'T dimensionless, b in m/s2',
            'matrix': [_floats(row) for row in cal.covariance]}
    if cal.thermal is not None:
        d['thermal'] = cal.thermal.to_dict()
    if cal.input_units is not None:
        d['input_units'] = _units_to_dict(cal.input_units)
    d.update(_imu_parts_to_dict(cal))
    return d


def _units_to_dict(units):
    """Return the ``input_units`` block: the unit, and the counts conversion for counts."""
    d = {'accel': str(units.get('accel'))}
    if d['accel'] == 'counts':
        for key in ('counts_per_g', 'counts_offset'):
            value = units.get(key, 0.0 if key == 'counts_offset' else None)
            d[key] = None if value is None else float(value)   # None: the loader refuses
    return d


def _imu_parts_to_dict(cal):
    """
    Return the optional ``gyro`` and ``magnetometer`` blocks (interface.md §9, §10).

    ``gyro.bias`` is the same vector as ``gyro_bias_rad_s`` (written for readers that know
    only interface.md §6): one bias per file.
    """
    d = {}
    if cal.gyro_T is not None:
        bias = np.zeros(3) if cal.gyro_bias is None else cal.gyro_bias
        d['gyro'] = {'model': 'raw = T @ true + bias; true = inv(T) @ (raw - bias)',
                     'units': 'T dimensionless, bias rad/s, predicted_accuracy relative RMS '
                              'over rate directions',
                     'T': [_floats(row) for row in cal.gyro_T], 'bias': _floats(bias),
                     'predicted_accuracy': finite_or_none(cal.gyro_predicted_accuracy)}
    mag = cal.magnetometer
    if mag is not None:
        d['magnetometer'] = {
            'model': 'raw = T @ R @ field + hard_iron; field = R.T @ inv(T) @ (raw - hard_iron)',
            'frame': 'field in the accelerometer frame; R rotates it into the magnetometer frame',
            'T': [_floats(row) for row in mag.T], 'hard_iron_uT': _floats(mag.hard_iron_uT),
            'R': [_floats(row) for row in mag.R], 'field_uT': float(mag.field_uT),
            'dip_deg': float(mag.dip_deg),
            'predicted_accuracy': finite_or_none(mag.predicted_accuracy)}
        if mag.noise_std_uT is not None:
            d['magnetometer']['noise_std_uT'] = float(mag.noise_std_uT)
    return d


def calibration_to_yaml(cal):
    """YAML text of :func:`calibration_to_dict`."""
    return yaml.safe_dump(calibration_to_dict(cal), sort_keys=False,
                          default_flow_style=None, width=100, allow_unicode=True)


def calibration_yaml(cal):
    """
    Return the YAML text :func:`save_calibration` writes (checked by the loader first).

    :raises CalibrationError: the calibration holds non-finite or implausible values.
    """
    d = calibration_to_dict(cal)
    try:
        calibration_from_dict(d)
    except InputError as err:
        raise CalibrationError(f'refusing to write the calibration: {err}') from None
    return yaml.safe_dump(d, sort_keys=False, default_flow_style=None, width=100,
                          allow_unicode=True)


def save_calibration(cal, path):
    """
    Write ``cal`` to ``path`` atomically, creating the directory.

    Folders it creates are removed again when the write fails. The target must be a
    regular file or missing, reached through no other user's link
    (:func:`dataio.atomic.output_target`).

    :raises CalibrationError: the calibration holds non-finite or implausible values
        (nothing is written; an existing file is left as it was).
    :raises UnsafeOutput: the path may not be written (an InputError).
    :raises OSError: the file system refused.
    """
    text = calibration_yaml(cal)
    from .atomic import atomic_write_text
    atomic_write_text(path, text, make_dirs=True)


# -- reading ---------------------------------------------------------------------------

def _validate_T(T):
    if np.any(np.tril(T, -1) != 0):
        raise _Bad('T must be upper triangular (raw = T @ true + bias)')
    diag = np.diag(T)
    low, high = T_DIAGONAL_RANGE
    if np.any(diag < low) or np.any(diag > high):
        raise _Bad(f'the diagonal of T must lie in [{low:g}, {high:g}], got '
                   f'{np.array2string(diag, precision=4)}')
    cond = np.linalg.cond(T)
    if not cond <= MAX_CONDITION:
        raise _Bad(f'T is ill-conditioned (condition number {cond:.3g} > {MAX_CONDITION:g})')


def _gyro_part(value, gyro_bias):
    """Parse the ``gyro`` block; return (T, bias, predicted accuracy)."""
    g = _mapping(value, 'gyro')
    T = _matrix(g.get('T'), 'gyro.T', 3, 3)
    for problem in gyro_problems(T):
        raise _Bad(problem)
    bias = _vector(g.get('bias'), 'gyro.bias', 3, -MAX_GYRO_BIAS, MAX_GYRO_BIAS)
    if gyro_bias is not None and np.max(np.abs(gyro_bias - bias)) > SAME_GYRO_BIAS_RAD_S:
        raise _Bad('gyro.bias differs from gyro_bias_rad_s: a file carries one gyro bias '
                   '(give both the same value, or only one of them)')
    accuracy = _optional(g, 'predicted_accuracy', lambda v: _number(
        v, 'gyro.predicted_accuracy', 0.0, MAX_RELATIVE_ACCURACY))
    return T, bias, accuracy


def _magnetometer_part(value):
    """Parse the ``magnetometer`` block into a MagnetometerPart."""
    m = _mapping(value, 'magnetometer')
    T = _matrix(m.get('T'), 'magnetometer.T', 3, 3)
    hard_iron = _vector(m.get('hard_iron_uT'), 'magnetometer.hard_iron_uT', 3,
                        -MAX_HARD_IRON_UT, MAX_HARD_IRON_UT)
    R = _matrix(m.get('R'), 'magnetometer.R', 3, 3)
    field_uT = _number(m.get('field_uT'), 'magnetometer.field_uT', *FIELD_RANGE_UT)
    dip_deg = _number(m.get('dip_deg'), 'magnetometer.dip_deg', -90.0, 90.0)
    for problem in magnetometer_problems(T, hard_iron, R, field_uT, dip_deg):
        raise _Bad(problem)
    return MagnetometerPart(
        T=T, hard_iron_uT=hard_iron, R=R, field_uT=field_uT, dip_deg=dip_deg,
        predicted_accuracy=_optional(m, 'predicted_accuracy', lambda v: _number(
            v, 'magnetometer.predicted_accuracy', 0.0, FIELD_RANGE_UT[1])),
        noise_std_uT=_optional(m, 'noise_std_uT', lambda v: _number(
            v, 'magnetometer.noise_std_uT', 0.0, FIELD_RANGE_UT[1])))


def _input_units(value):
    """Parse the ``input_units`` block into a dict (``accel``; counts: their conversion)."""
    u = _mapping(value, 'input_units')
    unit = _string(u.get('accel'), 'input_units.accel', 10)
    if unit not in UNITS:
        raise _Bad(f'input_units.accel must be one of {", ".join(UNITS)}, found '
                   f'{_found(u.get("accel"))}')
    if unit != 'counts':
        if u.get('counts_per_g') is not None or u.get('counts_offset') not in (None, 0, 0.0):
            raise _Bad(f'input_units: counts_per_g and counts_offset belong to counts, not '
                       f'{unit}')
        return {'accel': unit}
    return {'accel': unit,
            'counts_per_g': _number(u.get('counts_per_g'), 'input_units.counts_per_g', 1e-3,
                                    1e9),
            'counts_offset': _number(u.get('counts_offset', 0.0) or 0.0,
                                     'input_units.counts_offset', -1e9, 1e9)}


def _calibration(d):
    d = _mapping(d, 'the file')
    if d.get('format') != FORMAT:
        raise _Bad(f'not an accel_calib_ros calibration file (format is not {FORMAT})')
    version = d.get('version')
    if version != VERSION or isinstance(version, bool) or not isinstance(version, int):
        raise _Bad(f'version must be the integer {VERSION}, found {_found(version)}')
    method = _string(d.get('method'), 'method', 40)
    if method not in METHODS:
        raise _Bad(f'method {method!r} is not one of {", ".join(METHODS)}')
    gravity = _number(d.get('gravity_m_s2'), 'gravity_m_s2', *GRAVITY_RANGE)
    T = _matrix(d.get('T'), 'T', 3, 3)
    _validate_T(T)
    gravity_raw = gravity * float(np.max(np.diag(T)))
    bias = _vector(d.get('bias_m_s2'), 'bias_m_s2', 3, -gravity_raw, gravity_raw)
    fit = _mapping(d.get('fit', {}) or {}, 'fit')
    noise = fit.get('noise_std_m_s2')
    if noise is None:
        noise = np.full(3, np.nan)
    else:
        if not isinstance(noise, list) or len(noise) != 3:
            raise _Bad('fit.noise_std_m_s2 must be a list of 3 numbers')
        noise = np.array([np.nan if v is None else _number(v, 'fit.noise_std_m_s2', 0.0)
                          for v in noise])
    converged = fit.get('converged', True)
    if not isinstance(converged, bool):
        raise _Bad('fit.converged must be true or false')
    cov = None
    if d.get('covariance') is not None:
        cov = _matrix(_mapping(d['covariance'], 'covariance').get('matrix'),
                      'covariance.matrix', 9, 9)
        if np.any(np.diag(cov) < 0) or not np.allclose(cov, cov.T, rtol=1e-6,
                                                       atol=1e-12 * np.abs(cov).max()):
            raise _Bad('covariance.matrix must be symmetric with a non-negative diagonal')
    lo_t, hi_t = TEMPERATURE_RANGE
    temp_range = _optional(d, 'temperature_range_c',
                           lambda v: _vector(v, 'temperature_range_c', 2, lo_t, hi_t))
    if temp_range is not None and temp_range[0] > temp_range[1]:
        raise _Bad('temperature_range_c must be [min, max]')
    level = _optional(d, 'level_roll_pitch_rad',
                      lambda v: _vector(v, 'level_roll_pitch_rad', 2, -math.pi, math.pi))
    if level is not None and abs(level[1]) > math.pi / 2:
        raise _Bad('level_roll_pitch_rad: pitch must lie in [-pi/2, pi/2]')
    gyro_bias = _optional(d, 'gyro_bias_rad_s', lambda v: _vector(
        v, 'gyro_bias_rad_s', 3, -MAX_GYRO_BIAS, MAX_GYRO_BIAS))
    gyro_T = gyro_accuracy = None
    if d.get('gyro') is not None:
        gyro_T, gyro_bias, gyro_accuracy = _gyro_part(d['gyro'], gyro_bias)
    return Calibration(
        T=T, bias=bias, gravity=gravity, method=method, covariance=cov,
        residual_rms=float('nan') if fit.get('residual_rms_m_s2') is None else _number(
            fit['residual_rms_m_s2'], 'fit.residual_rms_m_s2', 0.0),
        noise_std=noise,
        observations=_number(fit.get('observations', 0), 'fit.observations', 0, 1e15,
                             integer=True),
        iterations=_number(fit.get('iterations', 0), 'fit.iterations', 0, 1e9, integer=True),
        converged=converged,
        seconds=0.0 if fit.get('seconds') is None else _number(fit['seconds'],
                                                               'fit.seconds', 0.0),
        thermal=_optional(d, 'thermal', lambda v: thermal_table(v, gravity_raw, MAX_BANDS,
                                                                TEMPERATURE_RANGE)),
        created=_string(d.get('created'), 'created', 100),
        source=_string(d.get('source'), 'source'),
        predicted_accuracy=_optional(d, 'predicted_accuracy_m_s2', lambda v: _number(
            v, 'predicted_accuracy_m_s2', 0.0)),
        gyro_bias=gyro_bias,
        temperature_range_c=None if temp_range is None else tuple(temp_range),
        level_roll_pitch_rad=None if level is None else tuple(level),
        sensor_id=_optional(d, 'sensor_id', lambda v: _string(v, 'sensor_id', 200)),
        gyro_T=gyro_T, gyro_predicted_accuracy=gyro_accuracy,
        magnetometer=_optional(d, 'magnetometer', _magnetometer_part),
        input_units=_optional(d, 'input_units', _input_units))


def calibration_from_dict(d):
    """
    Validate a parsed calibration mapping and build the Calibration (no I/O).

    :raises InputError: with a one-line reason, for anything malformed or implausible.
    """
    try:
        return _calibration(d)
    except _Bad as err:
        raise InputError(f'calibration: {err}') from None
    except RecursionError:
        raise InputError('calibration: nested too deeply') from None
    except (TypeError, ValueError, AttributeError, KeyError, OverflowError, IndexError,
            np.linalg.LinAlgError) as err:
        raise InputError(f'calibration is malformed: {type(err).__name__}: '
                         f'{str(err).splitlines()[0] if str(err) else ""}') from None


def load_calibration(path):
    """
    Read and validate a calibration file.

    :param path: file path (``~`` is expanded).
    :returns: Calibration.
    :raises InputError: one-line reason for any problem; nothing else escapes.
    """
    try:
        return _load(path)
    except InputError:
        raise
    except MemoryError:
        raise InputError(f'calibration file {path} is too large to read') from None
    except Exception as err:   # noqa: B902 - the one loader must never let anything else out
        raise InputError(f'cannot read calibration file {path}: {type(err).__name__}') \
            from None


def _load(path):
    path = os.path.expanduser(os.fspath(path))
    try:
        if os.path.isdir(path):
            raise InputError(f'calibration file {path} is a directory')
        # a FIFO or a terminal would block the reader (and a node) forever
        from .atomic import open_regular
        with open_regular(path) as f:
            data = f.read(MAX_FILE_BYTES + 1)
    except FileNotFoundError:
        raise InputError(f'calibration file not found: {path}') from None
    except OSError as err:
        raise InputError(f'cannot read calibration file {path}: '
                         f'{err.strerror or err}') from None
    if len(data) > MAX_FILE_BYTES:
        raise InputError(f'calibration file {path} is larger than {MAX_FILE_BYTES} bytes')
    try:
        text = data.decode('utf-8')
    except UnicodeDecodeError as err:
        raise InputError(f'calibration file {path} is not UTF-8 text (byte {err.start})') \
            from None
    if nesting_depth(text) > MAX_NESTING:
        raise InputError(f'calibration file {path} is nested too deeply (more than '
                         f'{MAX_NESTING} levels): not a calibration file')
    try:
        parsed = load_yaml(text)
    except yaml.YAMLError as err:
        first = str(err).splitlines()[0] if str(err) else 'syntax error'
        raise InputError(f'calibration file {path} is not valid YAML: {first}') from None
    except RecursionError:
        raise InputError(f'calibration file {path} is nested too deeply') from None
    try:
        return calibration_from_dict(parsed)
    except InputError as err:
        raise InputError(f'{path}: {err}') from None
