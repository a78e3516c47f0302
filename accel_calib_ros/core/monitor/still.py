"""
Still blocks: the calibration's detector family, one block at a time, on the corrected stream.

A block is quiet when (as :class:`~accel_calib_ros.core.windows.OnlineStaticDetector`
judges a moving window):

- the within-block standard deviation of the acceleration is below ``factor`` x its
  noise floor, and so is the angular rate's (a vibrating or hand-held sensor is not
  still);
- the floor is a low quantile (``FLOOR_QUANTILE``) of the block deviations seen so far,
  never above ``cap`` (``CAP_FACTOR`` times the calibration's own per-sample noise, when
  the file has it: a robot that is rarely still cannot raise its floor to the level of
  its motion; a stream up to about seven times noisier than the calibration's, another
  rate or filter, still finds rest below the threshold of ``factor`` x the cap)
  nor below 10 µg;
- the mean rate differs from the current bias estimate by less than ``max_rotation``;
- the block mean has not jumped from the last block's by more than ``JUMP_SIGMA`` of
  their noise plus ``JUMP_FLOOR`` (a tilt or a bump between blocks).

A constant turn about gravity passes all of these: the accelerometer cannot see it.
That is the gyro-bias tracker's problem (:mod:`.gyro_bias`), not this one's.
"""

from collections import deque
import math

import numpy as np

FLOOR_QUANTILE = 0.05
"""Quantile of the block deviations taken as the noise floor."""
FLOOR_MEMORY = 3000
"""Block deviations remembered for the floor (5 minutes of 0.1 s blocks)."""
FLOOR_EVERY = 50
"""The floor is recomputed every this many blocks."""
JUMP_SIGMA = 6.0
"""A block mean further than this many standard errors from the last one has moved."""
JUMP_FLOOR = 0.01
"""... plus this much, m/s² (1 mg: vibration makes block means scatter beyond white noise)."""
CAP_FACTOR = 3.0
"""The floor never exceeds this many times the calibration's per-sample noise."""
MIN_ACCEL_FLOOR = 1e-4
"""Lowest accelerometer floor believed, m/s² (10 µg)."""
GYRO_CAP = 0.02
"""Highest gyro floor believed, rad/s per sample (1.1 °/s; an MPU-9250 at 1 kHz: 0.22 °/s)."""
MIN_GYRO_FLOOR = 1e-5
"""Lowest gyro floor believed, rad/s."""


class _Floor:
    """A running low quantile of a positive quantity, bounded memory, capped."""

    def __init__(self, cap, low):
        self.cap, self.low = cap, low
        self.values = deque(maxlen=FLOOR_MEMORY)
        self.value = cap
        self._since = 0

    def add(self, x):
        if not math.isfinite(x):
            return
        self.values.append(x)
        self._since += 1
        if self._since >= FLOOR_EVERY or len(self.values) <= FLOOR_EVERY:
            self._since = 0
            q = float(np.quantile(np.fromiter(self.values, float), FLOOR_QUANTILE))
            self.value = max(self.low, q if self.cap is None else min(q, self.cap))

    def ready(self):
        return self.cap is not None or len(self.values) >= 10


class StillDetector:
    """
    Judge blocks still or moving (see the module docstring).

    :param factor: still when a deviation is below factor x its floor.
    :param accel_noise: the calibration's per-sample accelerometer noise, m/s², or None.
    :param max_rotation: largest mean rate (less the bias estimate) of a still block, rad/s.
    """

    def __init__(self, factor=3.0, accel_noise=None, max_rotation=math.radians(5.0)):
        self.factor = float(factor)
        self.max_rotation = float(max_rotation)
        cap = None if accel_noise is None or not accel_noise > 0 \
            else CAP_FACTOR * float(accel_noise)
        self.accel_floor = _Floor(cap, MIN_ACCEL_FLOOR)
        self.gyro_floor = _Floor(GYRO_CAP, MIN_GYRO_FLOOR)
        self._last = None

    def judge(self, block, gyro_bias=None):
        """
        Return '' when ``block`` is still, else a few words why not.

        :param block: :class:`~.blocks.Block`.
        :param gyro_bias: (3,) current bias estimate, rad/s, or None.
        """
        a_std = block.a_std
        self.accel_floor.add(a_std)
        g_std = block.g_std
        if block.g_mean is not None:
            self.gyro_floor.add(g_std)
        last, self._last = self._last, block
        if not self.accel_floor.ready():
            return 'learning the noise floor'
        if a_std > self.factor * self.accel_floor.value:
            return 'accelerating or vibrating'
        if block.g_mean is not None:
            if g_std > self.factor * self.gyro_floor.value:
                return 'rotation rate changing'
            rate = block.g_mean if gyro_bias is None else block.g_mean - gyro_bias
            if float(rate @ rate) > self.max_rotation ** 2:
                return 'rotating'
        if last is not None and 0.0 < block.t - last.t < 4.0 * max(block.duration, 1e-3):
            step = np.abs(block.a_mean - last.a_mean)
            noise = np.sqrt(block.a_var / block.n + last.a_var / last.n)
            if np.any(step > JUMP_SIGMA * noise + JUMP_FLOOR):
                return 'moved between blocks'
        return ''
