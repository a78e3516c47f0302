"""
The field monitor: still periods, the gyro bias at rest and the calibration's health.

:class:`FieldMonitor` is what the correction node and ``accel-calib health`` share. It
takes the *corrected* stream (acceleration, the rate before the monitor's own bias is
removed, temperature, the field in µT), in blocks (:class:`~.blocks.Block`, a node
builds one every ``block_s``) or in arrays (:meth:`FieldMonitor.feed`, cut into the same
blocks), and keeps:

- still periods: runs of still blocks (:class:`~.still.StillDetector`), less
  ``trim_s`` at the start and, through a lag of ``trim_s``, at the end (the block that
  holds the onset of a motion is judged before it could be used); a period longer than
  ``max_period_s`` is closed and a new one begun (a parked robot is checked too);
- the gyro bias (:class:`~.gyro_bias.GyroBiasTracker`): updated while a period lasts,
  committed when it ends; ``gyro_bias`` is the residual to subtract;
- the health (:class:`~.health.CalibrationHealth`): one check per period that ends.

An external stationary signal (:meth:`set_stationary`): False ("moving") makes every
block moving for ``stationary_timeout_s``; True ("stationary") lets the gyro tracker
measure the component along gravity; older than the timeout it counts as unknown.
"""

from dataclasses import dataclass, fields
import math

import numpy as np

from .blocks import Block, finite_rows, Run
from .gyro_bias import DEG, GyroBiasTracker
from .health import CalibrationHealth, ErrorModel, MG
from .still import StillDetector


@dataclass
class MonitorSettings:
    """
    The monitor's settings (the node's parameters; docs/parameters.md, docs/ros.md).

    Angles in degrees, rates in °/s, accelerations in mg, times in s, as the node's
    parameters are.
    """

    block_s: float = 0.1
    threshold_factor: float = 3.0
    trim_s: float = 0.3
    max_rotation_deg_s: float = 5.0
    max_period_s: float = 60.0
    stationary_timeout_s: float = 0.5
    gyro_bias_enabled: bool = True
    gyro_min_still_s: float = 1.0
    gyro_bias_limit_deg_s: float = 5.0
    gyro_vertical_limit_deg_s: float = 1.0
    health_enabled: bool = True
    health_min_still_s: float = 2.0
    health_false_alarm: float = 1e-4
    health_allowance_mg: float = 1.0
    health_cluster_deg: float = 10.0
    health_memory_s: float = 3600.0
    temperature_margin_c: float = 2.0

    def replace(self, **changes):
        """Return a copy with some settings changed."""
        values = {f.name: getattr(self, f.name) for f in fields(self)}
        values.update(changes)
        return MonitorSettings(**values)


class FieldMonitor:
    """
    Still periods, gyro bias and calibration health of one calibration in use.

    :param cal: the Calibration applied to the stream (``core.calibration``).
    :param settings: :class:`MonitorSettings`.
    """

    def __init__(self, cal, settings=None):
        self.settings = s = settings or MonitorSettings()
        self.cal = cal
        noise = np.asarray(cal.noise_std, float)
        noise = float(np.sqrt(np.mean(noise ** 2))) if np.all(np.isfinite(noise)) else None
        self.detector = StillDetector(s.threshold_factor, noise,
                                      math.radians(s.max_rotation_deg_s))
        self.gyro = GyroBiasTracker(s.gyro_min_still_s, s.gyro_bias_limit_deg_s * DEG,
                                    s.gyro_vertical_limit_deg_s * DEG)
        self.health = CalibrationHealth(
            ErrorModel(cal), s.health_false_alarm, s.health_allowance_mg * MG,
            s.health_min_still_s, s.health_cluster_deg, s.health_memory_s,
            s.temperature_margin_c)
        self.run = None                 # the still period being accumulated
        self._settle = 0                # still blocks seen since the last motion
        self._pending = []              # still blocks not yet past the lag
        self._last_t = None
        self.blocks = 0
        self.still_blocks = 0
        self.periods = 0                # still periods closed (any length)
        self.still_time_s = 0.0
        self.motion = 'no data yet'     # why the last block was not still ('' still)
        self._stationary = (None, -math.inf)
        self._carry = None              # samples of an unfinished block (feed)
        self.last_health = None         # the newest HealthResult (None: none yet)

    def apply_settings(self, settings):
        """
        Take new settings in place, keeping the state (estimate, periods, orientations).

        ``block_s`` and ``trim_s`` apply from the next block; a changed test level applies
        from the next check.
        """
        s = self.settings = settings
        self.detector.factor = float(s.threshold_factor)
        self.detector.max_rotation = math.radians(s.max_rotation_deg_s)
        tr = self.gyro
        tr.min_still_s = float(s.gyro_min_still_s)
        tr.limit = s.gyro_bias_limit_deg_s * DEG
        tr.vertical_limit = s.gyro_vertical_limit_deg_s * DEG
        h = self.health
        h.false_alarm, h.allowance = float(s.health_false_alarm), s.health_allowance_mg * MG
        h.min_still_s, h.memory_s = float(s.health_min_still_s), float(s.health_memory_s)
        h.cos_cluster = math.cos(math.radians(s.health_cluster_deg))
        h.margin_c = float(s.temperature_margin_c)

    # -- input -----------------------------------------------------------------------------
    @property
    def trim_blocks(self):
        """Return the blocks dropped at the start of a still run and held back at its end."""
        return max(int(round(self.settings.trim_s / self.settings.block_s)), 1)

    @property
    def gyro_bias(self):
        """Return the residual gyro bias to subtract from the corrected rate, rad/s (3,)."""
        return self.gyro.estimate if self.settings.gyro_bias_enabled else np.zeros(3)

    def set_stationary(self, t, value):
        """Say at time ``t`` (s, the stream's clock) whether the robot is stationary."""
        self._stationary = (bool(value), float(t))

    def stationary(self, t):
        """Return the external signal at ``t``: True, False or None (none, or too old)."""
        value, since = self._stationary
        if value is None or not abs(t - since) <= self.settings.stationary_timeout_s:
            return None
        return value

    def add_block(self, block):
        """Judge one block and update the still period, the gyro bias and the health."""
        if block is None:
            return
        self.blocks += 1
        gap = self._last_t is not None and not (
            0.0 < block.t - self._last_t <= 3.0 * max(block.duration, self.settings.block_s))
        self._last_t = block.t
        why = self.detector.judge(block, self.gyro.estimate)
        if not why and self.stationary(block.t) is False:
            why = 'the stationary signal says moving'
        if why or gap:
            self.motion = why or 'gap in the data'
            self._end()
            self._settle = 0 if why else 1
            if why:
                return
        self.motion = ''
        self.still_blocks += 1
        self._settle += 1
        if self._settle <= self.trim_blocks:
            return
        self._pending.append(block)
        if len(self._pending) <= self.trim_blocks:
            return
        ready = self._pending.pop(0)
        if self.run is None:
            self.run = Run(ready)
            self.gyro.begin()
        else:
            self.run.add(ready)
        self.still_time_s += ready.duration
        if self.settings.gyro_bias_enabled:
            self.gyro.progress(self.run, ready.duration, self.stationary(block.t) or None,
                               self.health.model.outside(self.run.temp))
        if self.run.duration >= self.settings.max_period_s:
            self._close()

    def _end(self):
        """Motion or a gap: the blocks still held back are dropped, the period closes."""
        self._pending = []
        self._close()

    def _close(self):
        run, self.run = self.run, None
        if run is None:
            return
        self.periods += 1
        if self.settings.gyro_bias_enabled:
            self.gyro.end(run)
        if self.settings.health_enabled:
            result = self.health.observe(run)
            if result is not None:
                self.last_health = result

    def finish(self):
        """End of the stream: the block being filled is judged, the open period closes."""
        if self._carry is not None:
            self.add_block(self._block(*self._carry))
            self._carry = None
        self._close()

    def reset_gyro_bias(self):
        """Forget the gyro-bias updates: back to the file's bias (the published one jumps)."""
        self.gyro.reset(self._last_t)
        if self.run is not None:
            self.gyro.begin()

    # -- arrays ----------------------------------------------------------------------------
    def feed(self, t, accel, gyro=None, temp=None, mag=None):
        """
        Add samples in time order, cut into blocks of ``block_s`` (rest kept for later).

        :param t: (N,) s. :param accel: (N, 3) corrected m/s². :param gyro: (N, 3) rad/s
            (before :attr:`gyro_bias` is removed) or None. :param temp: (N,) °C or None.
        :param mag: (N, 3) corrected µT, rows of NaN where there is no magnetometer sample,
            or None. Rows with a non-finite time, acceleration or rate are skipped.
        """
        t = np.asarray(t, float).reshape(-1)
        a = np.asarray(accel, float).reshape(-1, 3)
        g = None if gyro is None else np.asarray(gyro, float).reshape(-1, 3)
        temp = None if temp is None else np.asarray(temp, float).reshape(-1)
        m = None if mag is None else np.asarray(mag, float).reshape(-1, 3)
        ok = finite_rows(t, a, g)
        if not ok.all():
            t, a = t[ok], a[ok]
            g = None if g is None else g[ok]
            temp = None if temp is None else temp[ok]
            m = None if m is None else m[ok]
        if self._carry is not None:
            ct, ca, cg, ctemp, cm = self._carry
            if (cg is None) != (g is None) or (ctemp is None) != (temp is None) \
                    or (cm is None) != (m is None):
                self.finish()
            else:
                t, a = np.concatenate([ct, t]), np.concatenate([ca, a])
                g = None if g is None else np.concatenate([cg, g])
                temp = None if temp is None else np.concatenate([ctemp, temp])
                m = None if m is None else np.concatenate([cm, m])
            self._carry = None
        if not len(t):
            return
        step = self.settings.block_s
        index = np.floor(t / step).astype(np.int64)
        cuts = np.flatnonzero(np.diff(index)) + 1
        starts = np.r_[0, cuts]
        stops = np.r_[cuts, len(t)]
        for a0, b0 in zip(starts[:-1], stops[:-1]):
            self.add_block(self._block(t[a0:b0], a[a0:b0], None if g is None else g[a0:b0],
                                       None if temp is None else temp[a0:b0],
                                       None if m is None else m[a0:b0]))
        a0 = starts[-1]
        self._carry = (t[a0:], a[a0:], None if g is None else g[a0:],
                       None if temp is None else temp[a0:], None if m is None else m[a0:])

    @staticmethod
    def _block(t, a, g, temp, m):
        if m is not None:
            m = m[np.all(np.isfinite(m), axis=1)]
        return Block.of(t, a, g, temp, m)

    # -- words -----------------------------------------------------------------------------
    def gyro_summary(self):
        """Return a dict describing the gyro-bias tracker (JSON-ready)."""
        tr = self.gyro
        return {'enabled': self.settings.gyro_bias_enabled,
                'estimate_rad_s': [float(v) for v in self.gyro_bias],
                'estimate_deg_s': [float(math.degrees(v)) for v in self.gyro_bias],
                'state': tr.state if self.settings.gyro_bias_enabled else 'off',
                'along_gravity': tr.vertical, 'periods_used': tr.updates,
                'periods_dropped_tilting': tr.rejected,
                'periods_turning_about_gravity': tr.turning}


def corrected_arrays(cal, accel, gyro=None, temp=None, mag=None):
    """
    Correct arrays as the correction node does (level trim included).

    :param cal: Calibration. :param accel: (N, 3) raw m/s². :param gyro: (N, 3) raw
        rad/s or None. :param temp: (N,) °C or None. :param mag: (N, 3) raw µT or None.
    :return: (accel, gyro or None, mag or None), corrected, in the levelled frame.
    """
    L = np.asarray(cal.level_rotation(), float)
    with np.errstate(all='ignore'):
        a = cal.correct(accel, temp) @ L.T
        g = None if gyro is None else cal.correct_gyro(gyro, temp) @ L.T
        m = None if mag is None or cal.magnetometer is None else cal.correct_mag(mag) @ L.T
        if mag is not None and m is None:
            m = np.asarray(mag, float) @ L.T
    return a, g, m
