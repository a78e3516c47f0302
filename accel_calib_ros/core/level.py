"""
Level trim: the sensor's roll and pitch on the robot, from gravity at rest.

With the robot resting level, the corrected accelerometer reads the specific force
``f = g (−sin θ, sin φ cos θ, cos φ cos θ)`` in the sensor frame, where (φ, θ) are the
roll and pitch (ZYX Euler angles, yaw unobservable and taken as 0) of the sensor
relative to the robot base. Then ``roll = atan2(f_y, f_z)`` and
``pitch = atan2(−f_x, hypot(f_y, f_z))``, and ``Ry(θ) Rx(φ) f = (0, 0, |f|)``: the
rotation :meth:`core.calibration.Calibration.level_rotation` applies (ArduPilot's
"level" / AHRS_TRIM). numpy only.
"""

import math

import numpy as np

from .constants import G0
from .errors import CalibrationError

MAX_TILT_DEG = 25.0
"""Largest mounting tilt accepted: beyond it the robot is probably not level."""
MAX_MOTION = 0.3
"""Largest RMS deviation of the samples from their mean, m/s²: beyond it the robot moves."""
MAX_NORM_ERROR = 0.05
"""Largest relative deviation of |mean| from gravity (the calibration must be applied)."""


def roll_pitch(mean_accel):
    """
    Roll and pitch (rad) of the sensor relative to level, from the mean specific force.

    :param mean_accel: (3,) corrected acceleration at rest, m/s² (points up).
    :return: (roll, pitch), rad; pitch in [-π/2, π/2].
    """
    fx, fy, fz = (float(v) for v in np.asarray(mean_accel, float).reshape(3))
    return math.atan2(fy, fz), math.atan2(-fx, math.hypot(fy, fz))


def level_trim(accel, gravity=G0, max_tilt_deg=MAX_TILT_DEG, max_motion=MAX_MOTION):
    """
    Measure the level trim from corrected samples taken while the robot rests level.

    :param accel: (N, 3) corrected acceleration samples, m/s².
    :param gravity: local gravity, m/s².
    :param max_tilt_deg: refuse a larger tilt (robot not level, or sensor upside down).
    :param max_motion: refuse when the samples scatter more than this RMS, m/s².
    :return: dict with ``roll_rad``, ``pitch_rad``, ``tilt_deg``, ``samples``,
        ``motion_rms`` (m/s²) and ``norm`` (|mean|, m/s²).
    :raises CalibrationError: too few or non-finite samples, motion, a norm far from
        gravity, or a tilt beyond ``max_tilt_deg`` (the reason says which).
    """
    a = np.asarray(accel, float).reshape(-1, 3)
    a = a[np.all(np.isfinite(a), axis=1)]
    if len(a) < 10:
        raise CalibrationError(f'only {len(a)} samples: keep the robot still a little longer')
    mean = a.mean(axis=0)
    motion = float(np.sqrt(np.mean(np.sum((a - mean) ** 2, axis=1))))
    if motion > max_motion:
        raise CalibrationError(f'the robot is moving (scatter {motion:.3f} m/s2 > '
                               f'{max_motion:g}): let it rest')
    norm = float(np.linalg.norm(mean))
    if abs(norm / gravity - 1.0) > MAX_NORM_ERROR:
        raise CalibrationError(f'|a| = {norm:.3f} m/s2 is not gravity ({gravity:g}): '
                               'calibrate the accelerometer first, or the robot accelerates')
    tilt = math.degrees(math.acos(min(1.0, max(-1.0, mean[2] / norm))))
    if tilt > max_tilt_deg:
        raise CalibrationError(f'the sensor is tilted {tilt:.1f} deg from level (limit '
                               f'{max_tilt_deg:g}): is the robot resting level, sensor z up?')
    roll, pitch = roll_pitch(mean)
    return {'roll_rad': roll, 'pitch_rad': pitch, 'tilt_deg': tilt, 'samples': len(a),
            'motion_rms': motion, 'norm': norm}
