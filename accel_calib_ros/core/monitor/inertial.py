"""
Rest in the inertial sense: a lift, a vehicle or a ship is not a rest, though it looks still.

The still test (:mod:`.still`) sees a block at a time: a smooth sustained acceleration
(an elevator's 0.5-1.2 m/s² plateau, a van braking at 1-2 m/s², a ship's 0.3 m/s² heave
at 0.2-0.5 Hz) passes it, since nothing vibrates and nothing turns. What tells it from
rest is physics across the period and between periods:

1. **Within a period** (:func:`period_words`): at rest the block means scatter about a
   straight line as the within-block noise says (``WANDER_LIMIT``: a ship's heave makes
   them scatter hundreds of times more); ``|a|`` does not ramp (a lift starting or
   stopping, ``RAMP_Z`` standard errors and ``RAMP_FLOOR``); the direction of ``a`` does
   not tilt (a vehicle braking tilts it without any rotation, ``TILT_Z`` and
   ``REST_TILT_FLOOR``).
2. **Between periods** (:class:`Neighbours`): a plateau is a bounded stretch between
   rests. The direction of each period's mean acceleration is carried through the
   motion that follows by the gyro (with its doubt: the zero's uncertainty times the
   time, plus ``SCALE_DOUBT`` of the angle turned), and compared with the next rest: a
   rest *agrees* with a period when ``|a|`` differs by less than ``MAG_GATE`` (plus what
   the calibration's error can change between their orientations and temperatures)
   and the direction by less than ``DIR_GATE`` plus three times the carried doubt.
   A period is *confirmed* (it goes to the health check) when a later rest that begins
   at least ``CONFIRM_S`` after it began agrees with it: a bias shift persists, so the
   rests after a knock agree with each other, while the two halves of one plateau (a
   lift's lasts seconds) confirm nothing.
   It is *dropped* as motion when a later rest disagrees with it but agrees with the
   confirmed rest before it: the elevator's plateau between two rests on the floor, the
   van's braking between cruising and standing. A period no rest has answered after
   ``HOLD_S`` (or at the end of a recording, or at a clock step) is confirmed, unless
   it disagrees with the last confirmed rest or, with no
   confirmed rest at all, from gravity by more than ``GROSS`` (a departure of that size
   that no second rest repeats is motion, not a bias: the MPU-9250's zero-g offset is
   ±60-80 mg before any calibration).

The health check therefore hears of a period one rest later (or at the end of a
recording); a bias shift of any size is still found, since every rest after it agrees
with the one before.
"""

import math

import numpy as np

from ..constants import G0

WANDER_LIMIT = 20.0
"""Block-mean scatter over within-block variance above which a period wanders."""
RAMP_Z = 5.0
"""Standard errors beyond which |a| ramps within a period."""
RAMP_FLOOR = 0.01
"""... and at least this, m/s³ (1 mg/s: a warming sensor drifts far slower)."""
TILT_Z = 5.0
"""Standard errors beyond which the direction of a tilts within a period."""
REST_TILT_FLOOR = math.radians(0.01)
"""... and at least this, rad/s."""
MAG_GATE = 0.01 * G0
"""|a| of two rests that agree differs by less than this, m/s² (10 mg), plus the calibration."""
DIR_GATE = math.radians(1.0)
"""Their directions, carried by the gyro, differ by less than this, rad (0.17 m/s² across)."""
SCALE_DOUBT = 0.03
"""Doubt of an angle the gyro turned, fraction (MPU-9250 scale ±3 %)."""
CONFIRM_S = 10.0
"""A rest confirms a period only when it begins this long after the period began, s."""
HOLD_S = 120.0
"""A period no rest answers within this is judged alone, s."""
GROSS = 0.03 * G0
"""Alone, with no confirmed rest to compare with, a |a| - g beyond this is not a bias, m/s²."""


def period_words(run):
    """Return '' when a still period is a rest in the inertial sense, else why not."""
    if len(run.blocks) >= 5:
        wander = run.wander()
        if wander > WANDER_LIMIT:
            return (f'the acceleration wanders ({wander:.0f}x the noise: a moving platform, '
                    'a ship)')
    rate, sd = run.magnitude_rate()
    if abs(rate) > max(RAMP_Z * sd, RAMP_FLOOR):
        return f'|a| changes at {rate:+.3f} m/s3 (a lift or a vehicle speeding up)'
    tilt, sd = run.tilt_rate()
    if tilt > max(TILT_Z * sd, REST_TILT_FLOOR):
        return f'the acceleration tilts at {math.degrees(tilt):.3f} deg/s'
    return ''


def rotate(v, angle):
    """Return ``v`` rotated by the rotation vector ``angle`` (rad), Rodrigues."""
    theta = math.sqrt(float(angle @ angle))
    if theta < 1e-12:
        return v
    k = angle / theta
    c, s = math.cos(theta), math.sin(theta)
    kv = k[1] * v[2] - k[2] * v[1], k[2] * v[0] - k[0] * v[2], k[0] * v[1] - k[1] * v[0]
    return v * c + np.array(kv) * s + k * float(k @ v) * (1.0 - c)


class _Rest:
    """A period's mean acceleration, carried through the motion after it."""

    __slots__ = ('a', 'sigma', 'temp', 't', 't_start', 'obs')

    def __init__(self, a, temp, t, t_start, obs=None):
        self.a = np.array(a, float)
        self.sigma = 0.0            # doubt of its direction, rad
        self.temp, self.t, self.t_start, self.obs = float(temp), float(t), float(t_start), obs

    def carry(self, angle, doubt):
        self.a = rotate(self.a, -angle)
        self.sigma += doubt


class Neighbours:
    """
    Periods waiting for the next rest to say whether they were rests (module docstring).

    :param explained: callable(u1, u2, temp1, temp2) -> m/s²: how much |a| may differ
        between two rests at these directions and temperatures on a calibration that is
        fine (its error, the allowance, the temperature's share).
    """

    def __init__(self, explained=None):
        self.explained = explained or (lambda u1, u2, t1, t2: 0.0)
        self.ref = None             # the last confirmed rest (_Rest)
        self.pending = []           # periods not yet answered (_Rest with obs)
        self.dropped = 0            # periods dropped as motion
        self.last_drop = ''

    def carry(self, block, zero, rate_doubt):
        """Carry every direction through one block the sensor may have turned in."""
        if block.g_mean is None:
            angle, doubt = None, math.inf
        else:
            angle = (block.g_mean - zero) * block.duration
            doubt = rate_doubt * block.duration + SCALE_DOUBT * math.sqrt(float(angle @ angle))
        for rest in ([self.ref] if self.ref is not None else []) + self.pending:
            if angle is None:
                rest.sigma = math.inf
            else:
                rest.carry(angle, doubt)

    def lose_direction(self):
        """Forget every direction (a clock step: they cannot be carried across it)."""
        for rest in ([self.ref] if self.ref is not None else []) + self.pending:
            rest.sigma = math.inf

    def agree(self, rest, a, temp):
        """Tell whether a rest of mean ``a`` (m/s²) at ``temp`` agrees with ``rest``."""
        na, nr = math.sqrt(float(a @ a)), math.sqrt(float(rest.a @ rest.a))
        gate = MAG_GATE + self.explained(rest.a / nr, a / na, rest.temp, temp)
        if abs(na - nr) > gate:
            return False
        if not math.isfinite(rest.sigma):
            return True
        cos = float(a @ rest.a) / (na * nr)
        angle = math.acos(min(max(cos, -1.0), 1.0))
        return angle <= DIR_GATE + 3.0 * rest.sigma + gate / G0

    def arrive(self, a, temp, t):
        """
        Answer the periods waiting: a new rest begins at ``t`` (s) with mean ``a``.

        :return: list of ('confirm', obs) and ('drop', obs, words), in order.
        """
        out = []
        keep = []
        for rest in self.pending:
            if self.agree(rest, a, temp):
                if t - rest.t_start < CONFIRM_S:
                    keep.append(rest)
                    continue
                out.append(('confirm', rest.obs))
                self.ref = rest
            elif self.ref is not None and self.agree(self.ref, a, temp):
                out.append(('drop', rest.obs, self._drop('the rests before and after it agree '
                                                         'with each other, not with it: '
                                                         'motion (a lift, a vehicle)')))
            else:
                keep.append(rest)
        self.pending = keep
        return out

    def close(self, run, obs):
        """Hold a still period that ended, with its observation ``obs``, for the next rest."""
        self.pending.append(_Rest(run.accel_mean, run.temp, run.t_stop, run.t_start, obs))

    def expire(self, t=None):
        """
        Judge alone the periods no rest answered by ``t`` - ``HOLD_S`` (all when None).

        :return: as :meth:`arrive`.
        """
        out, keep = [], []
        for rest in self.pending:
            if t is not None and t - rest.t < HOLD_S:
                keep.append(rest)
                continue
            if self.ref is not None:
                gone = not self.agree(self.ref, rest.a, rest.temp)
            else:
                gone = abs(rest.obs['d']) > GROSS
            if gone:
                out.append(('drop', rest.obs, self._drop(
                    f'|a| departs by {rest.obs["d"] / G0 * 1e3:+.0f} mg and no later rest '
                    'repeats it: motion, not a bias')))
            else:
                out.append(('confirm', rest.obs))
                self.ref = rest
        self.pending = keep
        return out

    def _drop(self, words):
        self.dropped += 1
        self.last_drop = words
        return words
