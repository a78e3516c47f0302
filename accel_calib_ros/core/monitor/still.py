"""
Still blocks: the calibration's detector family, one block at a time, on the corrected stream.

A block is quiet when (as :class:`~accel_calib_ros.core.windows.OnlineStaticDetector`
judges a moving window):

- the sensor is alive: a block whose samples all repeat (no variance on every axis),
  many of whose samples equal the one before on every axis (``FROZEN_REPEATS``: a few
  codes repeating), or whose acceleration scatters less than
  ``FROZEN_FRACTION`` of the calibration's own noise, is *frozen* (a stuck sensor or a
  driver repeating its last frame): never still, and the monitor reports it;
- the within-block standard deviation of the acceleration is below ``factor`` x its
  noise floor, and so is the angular rate's (a vibrating or hand-held sensor is not
  still); the floor is a low quantile (``FLOOR_QUANTILE``) of the block deviations seen
  (the streaming detector's log histogram, old values fading), never above ``cap``
  (``CAP_FACTOR`` times the calibration's own per-sample noise, when the file has it: a
  robot that is rarely still cannot raise its floor to the level of its motion) nor
  below 10 µg;
- the mean rate differs by less than ``max_rotation`` from the gyro's *zero*: the median
  rate of the recent quiet, steady blocks (:attr:`StillDetector.zero`), measured here from
  the data alone. The still test never depends on the gyro-bias estimate it feeds, so a
  zero-rate change of any size within the chip's range (±30 °/s over temperature) is
  found: the first second of rest teaches it;
- the block mean has not jumped from the last block's by more than ``JUMP_SIGMA`` of
  their noise plus ``JUMP_FLOOR`` (a tilt or a bump between blocks), nor the mean rate
  by more than ``JUMP_SIGMA`` of its noise plus ``GYRO_JUMP_FLOOR`` (a turn setting off:
  the period before it must not be averaged with it).

A constant turn about gravity passes all of these: the accelerometer cannot see it.
That is the gyro-bias tracker's problem (:mod:`.gyro_bias`). A smooth sustained
acceleration (a lift, a vehicle, a ship) passes them too: that is judged per still
period (:mod:`.inertial`).
"""

from collections import deque
import math

import numpy as np

from ..windows.streaming import FloorHistogram

FLOOR_QUANTILE = 0.05
"""Quantile of the block deviations taken as the noise floor."""
FLOOR_MEMORY = 3000
"""Blocks after which the floor histogram's old counts are halved (5 min of 0.1 s blocks)."""
FLOOR_EVERY = 50
"""The floor is recomputed every this many blocks."""
JUMP_SIGMA = 6.0
"""A block mean further than this many standard errors from the last one has moved."""
JUMP_FLOOR = 0.01
"""... plus this much, m/s² (1 mg: vibration makes block means scatter beyond white noise)."""
GYRO_JUMP_FLOOR = math.radians(0.05)
"""... and the mean rate by this much, rad/s."""
CAP_FACTOR = 3.0
"""The floor never exceeds this many times the calibration's per-sample noise."""
MIN_ACCEL_FLOOR = 1e-4
"""Lowest accelerometer floor believed, m/s² (10 µg)."""
GYRO_CAP = 0.02
"""Highest gyro floor believed, rad/s per sample (1.1 °/s; an MPU-9250 at 1 kHz: 0.22 °/s)."""
MIN_GYRO_FLOOR = 1e-5
"""Lowest gyro floor believed, rad/s."""
FROZEN_REPEATS = 0.4
"""A block of which this fraction of samples repeat the one before exactly on every axis
is frozen (a live MPU-9250 at ±2 g scatters over tens of codes: a few per cent)."""
FROZEN_FRACTION = 0.05
"""... or whose acceleration scatters less than this fraction of the calibration's noise."""
ZERO_MEMORY = 600
"""Quiet blocks the gyro's zero is the median of (a minute of rest)."""
ZERO_MIN = 5
"""Quiet blocks needed before the zero is believed (until then: the file's bias)."""
ZERO_RANGE = math.radians(35.0)
"""Largest zero believed, rad/s (MPU-9250: ±5 °/s at 25 °C, ±30 °/s more over -40..85 °C)."""


class _Floor:
    """A running low quantile of a positive quantity (a fading log histogram), capped."""

    def __init__(self, cap, low):
        self.cap, self.low = cap, low
        self.hist = FloorHistogram()
        self.value = cap
        self._since = 0
        self._added = 0

    def add(self, x):
        if not (math.isfinite(x) and x > 0):
            return
        self.hist.add([x])
        self._added += 1
        self._since += 1
        if self._added % FLOOR_MEMORY == 0:
            self.hist.decay(0.5)
        if self._since >= FLOOR_EVERY or self._added <= FLOOR_EVERY:
            self._since = 0
            q = self.hist.quantile(FLOOR_QUANTILE)
            self.value = max(self.low, q if self.cap is None else min(q, self.cap))

    def ready(self):
        return self.cap is not None or self._added >= 10


def frozen_words(block, accel_noise=None):
    """Return '' for a live block, else a few words on how it is frozen."""
    n = max(block.n - 1, 1)
    if not np.any(block.a_var > 0.0) or block.a_repeats >= FROZEN_REPEATS * n:
        return f'the accelerometer repeats its output ({block.a_repeats + 1} of {block.n} ' \
               'samples identical)'
    if accel_noise is not None and block.a_std < FROZEN_FRACTION * accel_noise:
        return (f'the accelerometer has almost no noise ({block.a_std * 1e3:.3f} mm/s2 '
                f'against {accel_noise * 1e3:.1f} in the calibration)')
    if block.g_var is not None and np.any(block.g_mean != 0.0) and (
            not np.any(block.g_var > 0.0) or block.g_repeats >= FROZEN_REPEATS * n):
        return f'the gyro repeats its output ({block.g_repeats + 1} of {block.n} samples ' \
               'identical)'
    return ''


class StillDetector:
    """
    Judge blocks still or moving (see the module docstring).

    :param factor: still when a deviation is below factor x its floor.
    :param accel_noise: the calibration's per-sample accelerometer noise, m/s², or None.
    :param max_rotation: largest mean rate (less the gyro's zero) of a still block, rad/s.
    """

    def __init__(self, factor=3.0, accel_noise=None, max_rotation=math.radians(5.0)):
        self.factor = float(factor)
        self.max_rotation = float(max_rotation)
        self.accel_noise = accel_noise
        cap = None if accel_noise is None or not accel_noise > 0 \
            else CAP_FACTOR * float(accel_noise)
        self.accel_floor = _Floor(cap, MIN_ACCEL_FLOOR)
        self.gyro_floor = _Floor(GYRO_CAP, MIN_GYRO_FLOOR)
        self._quiet_rates = deque(maxlen=ZERO_MEMORY)
        self.zero = np.zeros(3)
        self.zero_known = False
        self._last = None
        self.frozen = ''                # why the last block was frozen ('' alive)

    def restart(self):
        """Forget the last block (a clock step: the next block is not its neighbour)."""
        self._last = None

    def judge(self, block):
        """
        Return '' when ``block`` is still, else a few words why not.

        :param block: :class:`~.blocks.Block`.
        """
        last, self._last = self._last, block
        self.frozen = frozen_words(block, self.accel_noise)
        if self.frozen:
            return 'frozen: ' + self.frozen
        a_std = block.a_std
        self.accel_floor.add(a_std)
        g_std = block.g_std
        if block.g_mean is not None:
            self.gyro_floor.add(g_std)
        if not self.accel_floor.ready():
            return 'learning the noise floor'
        if a_std > self.factor * self.accel_floor.value:
            return 'accelerating or vibrating'
        jumped = turned = False
        if last is not None and 0.0 < block.t - last.t < 4.0 * max(block.duration, 1e-3):
            step = np.abs(block.a_mean - last.a_mean)
            noise = np.sqrt(block.a_var / block.n + last.a_var / last.n)
            jumped = bool(np.any(step > JUMP_SIGMA * noise + JUMP_FLOOR))
            if block.g_mean is not None and last.g_mean is not None:
                step = np.abs(block.g_mean - last.g_mean)
                noise = np.sqrt(block.g_var / block.n + last.g_var / last.n)
                turned = bool(np.any(step > JUMP_SIGMA * noise + GYRO_JUMP_FLOOR))
        if block.g_mean is not None:
            if g_std > self.factor * self.gyro_floor.value:
                return 'rotation rate changing'
            if not (jumped or turned):
                self._learn_zero(block.g_mean)
            rate = block.g_mean - self.zero
            if float(rate @ rate) > self.max_rotation ** 2:
                return 'rotating'
        if jumped:
            return 'moved between blocks'
        if turned:
            return 'the rotation rate changed between blocks'
        return ''

    def _learn_zero(self, rate):
        """Add a quiet, steady block's mean rate to the zero (median of the recent ones)."""
        self._quiet_rates.append(rate)
        count = len(self._quiet_rates)
        if count >= ZERO_MIN and (count < 50 or count % 10 == 0):
            zero = np.median(np.array(self._quiet_rates), axis=0)
            self.zero = np.clip(zero, -ZERO_RANGE, ZERO_RANGE)
            self.zero_known = True
