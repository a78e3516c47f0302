"""
The gyro bias at rest: re-estimated in still periods, never from motion, never from a turn.

The tracker estimates the *residual* bias of the corrected rate (what is left after the
calibration file's bias): ``published = corrected - estimate``. It starts at zero (the
file is right) with a prior of ``prior`` per axis, and grows its uncertainty by
``walk`` per √s between still periods (power-ups, temperature). Every component stays
within ``limit`` (default 30 °/s: the MPU-9250's zero-rate output moves ±30 °/s over
-40..85 °C besides its ±5 °/s at 25 °C).

In a still period (see :mod:`.still`; the trimmed, lagged blocks only, so the onset
of the next motion is never in it), once it has lasted ``min_still_s``:

- the accelerometer's block means must not tilt: the slope of gravity across itself
  (a turn about a horizontal axis tilts gravity at the same rate) must be below
  ``TEST_Z`` standard errors or ``ESTIMATE_TILT_FLOOR``; a tilting period is dropped whole;
- the two components of the mean rate **across gravity** are then bias: a turn about a
  horizontal axis would have tilted gravity. These are always followed;
- the component **along gravity** is the one a turn in place hides in; it is followed
  only as far as something says the sensor does not turn:

  * a rate about gravity that changes across the period (a turn setting off or
    stopping; ``TEST_Z`` standard errors and ``CHANGE_FLOOR``): held, and said;
  * a magnetometer precise enough (its heading across the whole period, any rate the
    AK8963 offers) that sees no turn: measured, up to ``limit``; one that sees a turn:
    held, and said;
  * else, a rate about gravity at rest (beyond what the estimate explains already:
    other orientations see this component across gravity) of at most
    ``vertical_limit`` (no heading reference), ``stationary_limit`` (an external
    signal says the robot is stationary: its wheels may be still on a turning
    platform) or, in the first still period after a start or a reset that did not
    begin with a change of the rate (a turn setting off), ``powerup_limit`` (the
    power-up change of the zero-rate output), plus 0.24 °/s per °C outside the
    calibrated range, is taken for a bias:
    **a turn in place slower than that is absorbed** (at most that much: once absorbed,
    the rest shows nothing more); a faster one is not absorbed at all (held, and said: a
    turntable, or a bias change that needs a heading reference or a gyro calibration);

- the estimate is a Kalman update of the one committed by the last period with the
  period's mean (per-sample noise over √samples plus ``NOISE_FLOOR``); the published
  estimate follows it only once the period's tilt test is sensitive enough that a tilt
  it has not seen yet could not move it by more than ``PUBLISH_FLOOR`` or a quarter of
  the change (so a period the tilt test rejects later has published nothing), at no
  more than ``SLEW`` or the change over ``SLEW_TIME_S`` per second of still time (never
  while moving). A period that fails a test later is dropped and the estimate returns
  to the committed one; a period that ends (motion) commits its update.
"""

import math

import numpy as np

from .blocks import cross

DEG = math.pi / 180.0
TEST_Z = 3.29
"""Standard errors beyond which a tilt or a turn is real (two-sided 1e-3)."""
ESTIMATE_TILT_FLOOR = 0.005 * DEG
"""Tilt rates below this are ignored, rad/s (slow thermal drift of the corrected mean)."""
HEADING_FLOOR = 0.01 * DEG
"""Turn rates the magnetometer sees below this are ignored, rad/s."""
CHANGE_FLOOR = 0.1 * DEG
"""Changes of the rate about gravity within a period below this are ignored, rad/s
(the gyro's own flicker moves it by hundredths of °/s)."""
NOISE_FLOOR = 0.002 * DEG
"""Error of a period's mean no averaging removes, rad/s (Earth's rate is 0.004 °/s)."""
JUDGE_EVERY_S = 0.3
"""Still time between two evaluations of the period so far, s (the cost stays tiny)."""
SLEW = 1.0 * DEG
"""The published estimate moves at least this fast toward its target, rad/s per s."""
SLEW_TIME_S = 0.3
"""... or covers the distance in this much still time, whichever is faster."""
PUBLISH_FLOOR = 0.02 * DEG
"""A tilt not yet seen may move the published estimate by at most this (or a quarter)."""
TEMPCO = 0.24 * DEG
"""Allowance per °C outside the calibrated range, rad/s (MPU-9250: ±30 °/s over 125 °C)."""


_EYE = np.eye(3)


def _rate_change(line, u, duration):
    """Return how much the rate about ``u`` changed across a period: (change, its std)."""
    slope, noise, sxx = line.slope()
    if sxx <= 0.0:
        return 0.0, math.inf
    return float(u @ slope) * duration, math.sqrt(noise / sxx) * duration


def _basis(u):
    """Return two unit vectors across ``u`` (unit)."""
    a = np.array([1.0, 0.0, 0.0]) if abs(u[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = cross(u, a)
    e1 /= math.sqrt(float(e1 @ e1))
    return e1, cross(u, e1)


class GyroBiasTracker:
    """
    Residual gyro bias, re-estimated in still periods (see the module docstring).

    :param min_still_s: still time before a period updates the estimate, s.
    :param limit: largest residual bias per axis, rad/s.
    :param vertical_limit: largest rate about gravity taken for a bias without a
        magnetometer or a stationary signal, rad/s.
    :param stationary_limit: the same while a stationary signal says stationary, rad/s.
    :param powerup_limit: the same in the first still period after a start or a reset
        (unless it began with a change of the rate), rad/s.
    :param prior: standard deviation of the residual at start and after a reset, rad/s.
    :param walk: growth of its standard deviation between periods, rad/s per √s.
    """

    def __init__(self, min_still_s=1.0, limit=30.0 * DEG, vertical_limit=0.2 * DEG,
                 stationary_limit=1.0 * DEG, powerup_limit=1.0 * DEG, prior=1.0 * DEG,
                 walk=0.5 * DEG / 60.0):
        self.min_still_s = float(min_still_s)
        self.limit = float(limit)
        self.vertical_limit = float(vertical_limit)
        self.stationary_limit = float(stationary_limit)
        self.powerup_limit = float(powerup_limit)
        self.prior, self.walk = float(prior), float(walk)
        self.reset()

    def reset(self, t=None):
        """Forget every update: the file's bias again (residual zero), prior uncertainty."""
        self.committed = np.zeros(3)
        self.P = np.eye(3) * self.prior ** 2
        self.t_commit = t
        self.estimate = np.zeros(3)
        self.updates = 0                    # periods committed
        self.rejected = 0                   # periods dropped (tilt or external motion)
        self.turning = 0                    # periods whose vertical part a turn kept out
        self.state = 'waiting for a still period'
        self.vertical = 'not measured yet'
        self.followed = 'none yet'
        self.held_rate = 0.0                # a rate about gravity not absorbed, rad/s
        self._candidate = None
        self._dropped = False
        self._turned = False
        self._judged = 0.0
        self._held = 0.0
        self._after_turn = False

    # -- one still period ----------------------------------------------------------------
    def begin(self, after_turn=False):
        """
        Start a new still period.

        :param after_turn: it began with a change of the rate (a turn may be setting off).
        """
        self._after_turn = bool(after_turn)
        self._candidate = None
        self._dropped = False
        self._turned = False
        self._judged = 0.0
        self._held = 0.0

    def progress(self, run, dt, stationary=None, outside_c=0.0):
        """
        Update with the still period so far (called once per accepted block).

        :param run: :class:`~.blocks.Run` of the period so far.
        :param dt: still time since the last call, s (for the slew limit).
        :param stationary: True (an external signal says stationary), None (unknown).
        :param outside_c: °C the temperature lies outside the calibrated range (0 inside).
        """
        target = self.committed
        if run.gyro is not None and not self._dropped and run.duration >= self.min_still_s:
            if self._candidate is None or run.duration >= self._judged + JUDGE_EVERY_S:
                self._judged = run.duration
                self._candidate = self._judge(run, stationary, outside_c)
            if self._candidate is not None and self._publishable(run):
                target = self._candidate[0]
        elif run.gyro is not None and not self._dropped:
            self.state = (f'still for {run.duration:.1f} s: updating after '
                          f'{self.min_still_s:g} s')
        gap = target - self.estimate
        step = max(SLEW, float(np.max(np.abs(gap))) / SLEW_TIME_S) * max(dt, 0.0)
        self.estimate = self.estimate + np.clip(gap, -step, step)

    def _publishable(self, run):
        """Tell whether a tilt the period has not shown yet could no longer matter."""
        _, tilt_sd = run.tilt_rate()
        change = float(np.max(np.abs(self._candidate[0] - self.committed)))
        return TEST_Z * tilt_sd <= max(PUBLISH_FLOOR, 0.25 * change)

    def end(self, run):
        """End the still period (motion or a gap): commit its update if it had one."""
        if self._candidate is not None and not self._dropped:
            self.committed, self.P = self._candidate
            self.t_commit = run.t_stop
            self.updates += 1
            self.held_rate = self._held
        self.turning += bool(self._turned or self._held)
        self._candidate = None

    def _judge(self, run, stationary, outside_c):
        """Return the (estimate, P) the period so far gives, or None when it is dropped."""
        tilt, tilt_sd = run.tilt_rate()
        if tilt > max(TEST_Z * tilt_sd, ESTIMATE_TILT_FLOOR):
            self._dropped = True
            self.rejected += 1
            self.state = (f'holding: the last still period tilted at {tilt / DEG:.3f} deg/s '
                          '(not used)')
            return None
        mean = run.accel_mean
        u = mean / math.sqrt(float(mean @ mean))
        e1, e2 = _basis(u)
        rows = [e1, e2]
        along = 'across gravity (gravity shows a turn about a horizontal axis as a tilt)'
        heading = False
        self._held = 0.0
        rate, sd = run.heading_rate()
        bound = self._vertical_bound(outside_c, stationary)
        change, change_sd = _rate_change(run.gyro, u, run.duration)
        if abs(change) > max(TEST_Z * change_sd, CHANGE_FLOOR):
            self._turned = True
            self.vertical = (f'held: the rate about gravity changed by {change / DEG:+.3f} '
                             'deg/s during the period (a turn setting off or stopping)')
        elif math.isfinite(sd) and abs(rate) > max(TEST_Z * sd, HEADING_FLOOR):
            self._turned = True
            self.vertical = (f'held: the magnetometer sees a turn about gravity of '
                             f'{rate / DEG:.3f} deg/s')
        elif math.isfinite(sd) and TEST_Z * sd < bound:
            rows.append(u)
            heading = True
            self.vertical = (f'measured (the magnetometer sees no turn: below '
                             f'{max(TEST_Z * sd, HEADING_FLOOR) / DEG:.3f} deg/s)')
        else:
            residual = float(u @ (run.gyro_mean - self.committed))
            why = ('the stationary signal says the robot is still' if stationary else
                   ('no magnetometer' if not math.isfinite(sd) else
                    f'the magnetometer cannot rule out a turn below {TEST_Z * sd / DEG:.2f} '
                    'deg/s over this period') + ' and no stationary signal'
                   + ('; the first rest since a start: the power-up change'
                      if self._powerup(stationary) else ''))
            if abs(residual) <= bound:
                rows.append(u)
                self.vertical = (f'taken for a bias within ±{bound / DEG:.2f} deg/s ({why}: a '
                                 'turn in place slower than that looks like a bias and is '
                                 'absorbed)')
            else:
                self._held = residual
                self.vertical = (f'held: the rate about gravity at rest is '
                                 f'{residual / DEG:+.3f} deg/s, more than the '
                                 f'±{bound / DEG:.2f} deg/s taken for a bias ({why}): not '
                                 'absorbed (a turn in place or a turntable, or a bias change '
                                 'that needs a magnetometer, a stationary signal or a gyro '
                                 'calibration)')
        self.followed = along + ('; along gravity too' if len(rows) == 3 else
                                 '; not along gravity')
        H = np.array(rows)
        n = max(run.n, 1)
        r = run.gyro_noise ** 2 / n + NOISE_FLOOR ** 2
        grow = 0.0 if self.t_commit is None else max(run.t_stop - self.t_commit, 0.0)
        P = self.P + _EYE * (self.walk ** 2 * grow)
        S = H @ P @ H.T + _EYE[:len(rows), :len(rows)] * r
        K = P @ H.T @ np.linalg.inv(S)
        b = self.committed + K @ (H @ (run.gyro_mean - self.committed))
        P = (_EYE - K @ H) @ P
        if len(rows) == 3 and not heading:
            # Never more than the bound along gravity beyond what was known before.
            along_b = float(u @ (b - self.committed))
            b = b + u * (min(max(along_b, -bound), bound) - along_b)
        b = np.clip(b, -self.limit, self.limit)
        self.state = (f'updating from a still period of {run.duration:.1f} s '
                      f'({len(rows)} components)')
        return b, 0.5 * (P + P.T)

    def _powerup(self, stationary):
        return not stationary and self.updates == 0 and not self._after_turn \
            and self.powerup_limit > self.vertical_limit

    def _vertical_bound(self, outside_c, stationary=None):
        base = self.stationary_limit if stationary else \
            self.powerup_limit if self._powerup(stationary) else self.vertical_limit
        return base + TEMPCO * max(float(outside_c), 0.0)
