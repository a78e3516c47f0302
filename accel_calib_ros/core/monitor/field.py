"""
The field monitor: still periods, the gyro bias at rest and the calibration's health.

:class:`FieldMonitor` is what the correction node and ``accel-calib health`` share. It
takes the *corrected* stream (acceleration, the rate before the monitor's own bias is
removed, temperature, the field in µT) in arrival order (:meth:`FieldMonitor.feed`),
cuts it into blocks one way (:class:`~.blocks.BlockCutter`: ``block_s`` of stream time,
longer below 80 Hz; a step of the sample clock either way restarts every time-ordered
state) and keeps:

- still periods: runs of still blocks (:class:`~.still.StillDetector`), less
  ``trim_s`` at the start and, through a lag of ``trim_s``, at the end (the block that
  holds the onset of a motion is judged before it could be used); a period longer than
  ``max_period_s`` is closed and a new one begun (a parked robot is checked too);
- the gyro bias (:class:`~.gyro_bias.GyroBiasTracker`): updated while a period lasts,
  committed when it ends; ``gyro_bias`` is the residual to subtract;
- the health (:class:`~.health.CalibrationHealth`): a period that is a rest in the
  inertial sense (:mod:`.inertial`) and that the next rest confirms is one check;
- a frozen sensor: ``FROZEN_S`` of frozen blocks is a fault (:attr:`FieldMonitor.fault`);
- how long since the last still block, and why none came (:meth:`FieldMonitor.idle_words`).

An external stationary signal (:meth:`set_stationary`): False ("moving") makes every
block moving for ``stationary_timeout_s``; True ("stationary") lets the gyro tracker take
a rate about gravity up to ``gyro_stationary_limit_deg_s`` for a bias; older than the
timeout it counts as unknown.
"""

from collections import Counter
from dataclasses import dataclass, fields
import math

import numpy as np

from .blocks import BlockCutter, finite_rows, Run, STILL_MIN_RATE_HZ
from .gyro_bias import DEG, GyroBiasTracker
from .health import CalibrationHealth, ErrorModel, MG
from .inertial import Neighbours, period_words
from .mean_noise import MeanNoise
from .prior import sensor_prior
from .still import StillDetector

FROZEN_S = 1.0
"""Frozen blocks in a row, s, before the sensor is reported frozen."""
ZERO_DOUBT = 0.05 * DEG
"""Least doubt of the gyro's zero when carrying a direction through motion, rad/s."""


@dataclass
class MonitorSettings:
    """
    The monitor's settings (the node's parameters; docs/parameters.md, docs/field_monitor.md).

    Angles in degrees, rates in °/s, accelerations in mg, times in s, as the node's
    parameters are.
    """

    block_s: float = 0.1
    threshold_factor: float = 3.0
    trim_s: float = 0.3
    max_rotation_deg_s: float = 5.0
    max_period_s: float = 60.0
    stationary_timeout_s: float = 0.5
    still_timeout_s: float = 300.0
    gyro_bias_enabled: bool = True
    gyro_min_still_s: float = 1.0
    gyro_bias_limit_deg_s: float = 30.0
    gyro_vertical_limit_deg_s: float = 0.2
    gyro_stationary_limit_deg_s: float = 1.0
    gyro_powerup_limit_deg_s: float = 1.0
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
    :param history: the calibrations of this sensor in its history (dicts as
        ``dataio.history.History.calibrations`` gives them), or None.
    """

    def __init__(self, cal, settings=None, history=None):
        self.settings = s = settings or MonitorSettings()
        self.cal = cal
        noise = np.asarray(cal.noise_std, float)
        noise = float(np.sqrt(np.mean(noise ** 2))) if np.all(np.isfinite(noise)) else None
        self.detector = StillDetector(s.threshold_factor, noise,
                                      math.radians(s.max_rotation_deg_s))
        self.gyro = GyroBiasTracker(s.gyro_min_still_s, s.gyro_bias_limit_deg_s * DEG,
                                    s.gyro_vertical_limit_deg_s * DEG,
                                    s.gyro_stationary_limit_deg_s * DEG,
                                    s.gyro_powerup_limit_deg_s * DEG)
        self.health = CalibrationHealth(
            ErrorModel(cal), s.health_false_alarm, s.health_allowance_mg * MG,
            s.health_min_still_s, s.health_cluster_deg, s.health_memory_s,
            s.temperature_margin_c)
        self.history = history
        self.health.prior = sensor_prior(s.health_allowance_mg * MG, history,
                                         getattr(cal, 'sensor_id', None) or '')
        self.neighbours = Neighbours(self.health.explained)
        self.noise = MeanNoise()
        self.cutter = BlockCutter(s.block_s)
        self.run = None                 # the still period being accumulated
        self._settle = 0                # still blocks seen since the last motion
        self._pending = []              # still blocks not yet past the lag
        self.blocks = 0
        self.still_blocks = 0
        self.periods = 0                # still periods closed (any length)
        self.still_time_s = 0.0
        self.motion = 'no data yet'     # why the last block was not still ('' still)
        self.rejected = Counter()       # still periods that were not rests, by kind
        self.last_rejection = ''
        self.skipped_rows = 0           # rows with a non-finite time, acceleration or rate
        self.temps_unknown = 0          # rows with a non-finite temperature
        self.fault = None               # the sensor fault in force (dict) or None
        self.faults = []                # every fault seen (dicts, at most 20)
        self._frozen_s = 0.0
        self._t = None                  # the newest block time
        self._since = None              # stream time of the last still block (or the start)
        self._why = Counter()           # why the blocks since then were not still
        self._turn_step = False         # the moves since the last rest began turning from rest
        self._was_still = False
        self._stationary = (None, -math.inf)
        self.last_health = None         # the newest HealthResult (None: none yet)

    def apply_settings(self, settings):
        """
        Take new settings in place, keeping the state (estimate, periods, orientations).

        ``trim_s`` applies from the next block; a changed test level from the next check;
        ``block_s`` only to a new monitor.
        """
        s = self.settings = settings
        self.detector.factor = float(s.threshold_factor)
        self.detector.max_rotation = math.radians(s.max_rotation_deg_s)
        tr = self.gyro
        tr.min_still_s = float(s.gyro_min_still_s)
        tr.limit = s.gyro_bias_limit_deg_s * DEG
        tr.vertical_limit = s.gyro_vertical_limit_deg_s * DEG
        tr.stationary_limit = s.gyro_stationary_limit_deg_s * DEG
        tr.powerup_limit = s.gyro_powerup_limit_deg_s * DEG
        h = self.health
        h.false_alarm = float(s.health_false_alarm)
        h.min_still_s, h.memory_s = float(s.health_min_still_s), float(s.health_memory_s)
        h.cos_cluster = math.cos(math.radians(s.health_cluster_deg))
        h.margin_c = float(s.temperature_margin_c)
        h.prior = sensor_prior(s.health_allowance_mg * MG, self.history,
                               getattr(self.cal, 'sensor_id', None) or '')

    # -- input -----------------------------------------------------------------------------
    @property
    def trim_blocks(self):
        """Return the blocks dropped at the start of a still run and held back at its end."""
        step = self.cutter.step_s or self.settings.block_s
        return max(int(round(self.settings.trim_s / step)), 1)

    @property
    def gyro_bias(self):
        """Return the residual gyro bias to subtract from the corrected rate, rad/s (3,)."""
        return self.gyro.estimate if self.settings.gyro_bias_enabled else np.zeros(3)

    @property
    def too_slow(self):
        """Return words when the stream is too slow for the still test, else ''."""
        if not self.cutter.too_slow:
            return ''
        return (f'the stream runs at {self.cutter.rate_hz:.1f} Hz: the still test needs at '
                f'least {STILL_MIN_RATE_HZ:g} Hz')

    def set_stationary(self, t, value):
        """Say at time ``t`` (s, the stream's clock) whether the robot is stationary."""
        self._stationary = (bool(value), float(t))

    def stationary(self, t):
        """Return the external signal at ``t``: True, False or None (none, or too old)."""
        value, since = self._stationary
        if value is None or not abs(t - since) <= self.settings.stationary_timeout_s:
            return None
        return value

    def feed(self, t, accel, gyro=None, temp=None, mag=None, mag_t=None):
        """
        Add samples in arrival order (cut into blocks; the rest kept for later).

        :param t: (N,) s. :param accel: (N, 3) corrected m/s². :param gyro: (N, 3) rad/s
            (before :attr:`gyro_bias` is removed) or None. :param temp: (N,) °C or None.
        :param mag: corrected µT: with ``mag_t`` (K,) s, (K, 3) samples at those times;
            without, (N, 3) rows beside the others, NaN where there is no sample; or None.
            Rows with a non-finite time, acceleration or rate are skipped (counted).
        """
        t = np.asarray(t, float).reshape(-1)
        a = np.asarray(accel, float).reshape(-1, 3)
        g = None if gyro is None else np.asarray(gyro, float).reshape(-1, 3)
        temp = None if temp is None else np.asarray(temp, float).reshape(-1)
        m = None if mag is None else np.asarray(mag, float).reshape(-1, 3)
        if m is not None and mag_t is None:
            has = np.all(np.isfinite(m), axis=1) & np.isfinite(t)
            m, mag_t = m[has], t[has]
        elif m is not None:
            mag_t = np.asarray(mag_t, float).reshape(-1)
            has = np.all(np.isfinite(m), axis=1) & np.isfinite(mag_t)
            m, mag_t = m[has], mag_t[has]
        ok = finite_rows(t, a, g)
        if not ok.all():
            self.skipped_rows += int(np.count_nonzero(~ok))
            t, a = t[ok], a[ok]
            g = None if g is None else g[ok]
            temp = None if temp is None else temp[ok]
        if temp is not None:
            self.temps_unknown += int(np.count_nonzero(~np.isfinite(temp)))
        self._events(self.cutter.cut(t, a, g, temp, m, mag_t))

    def finish(self):
        """End of the stream: the block being filled is judged, every period closes."""
        self._events(self.cutter.finish())
        self._end()
        self._confirm(self.neighbours.expire(None))

    def _events(self, events):
        for kind, value in events:
            if kind == 'block':
                self.add_block(value)
            else:
                self.restart(value)

    def restart(self, words='the sample clock stepped'):
        """End the period and restart the time-ordered state (a step of the sample clock)."""
        self._end()
        self._confirm(self.neighbours.expire(None))
        self.detector.restart()
        self.neighbours.lose_direction()
        self._settle = 0
        self.motion = words
        self._t = None
        self._since = None

    def add_block(self, block):
        """Judge one block and update the still period, the gyro bias and the health."""
        if block is None or self.cutter.too_slow:
            return
        self.blocks += 1
        self._t = block.t
        if self._since is None:
            self._since = block.t
        why = self.detector.judge(block)
        self._frozen(block)
        if not why and self.stationary(block.t) is False:
            why = 'the stationary signal says moving'
        doubt = max(ZERO_DOUBT, float(np.max(np.abs(self.detector.zero - self.gyro.estimate))))
        self.neighbours.carry(block, self.detector.zero, doubt)
        self._confirm(self.neighbours.expire(block.t))
        if why:
            # A change of the rate right after rest: a turn in place may be setting off.
            if why.startswith('the rotation rate changed'):
                self._turn_step = self._was_still
            elif not why.startswith('rotating'):
                self._turn_step = False
            self._was_still = False
            self.motion = why
            self._why[why.split(':')[0]] += 1
            self._end()
            self._settle = 0
            return
        self.motion = ''
        self._was_still = True
        self._since = block.t
        self._why.clear()
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
            self.gyro.begin(after_turn=self._turn_step)
            if self.settings.health_enabled:
                self._confirm(self.neighbours.arrive(ready.a_mean, ready.temp, ready.t))
        else:
            self.run.add(ready)
        self.still_time_s += ready.duration
        self.run.inflation = self.noise.ratio(len(self.run.blocks))
        if self.settings.gyro_bias_enabled:
            self.gyro.progress(self.run, ready.duration, self.stationary(block.t) or None,
                               self.health.model.outside(self.run.temp))
        if self.run.duration >= self.settings.max_period_s:
            self._close()

    def _frozen(self, block):
        if not self.detector.frozen:
            self._frozen_s = 0.0
            if self.fault is not None:
                self.fault = None
            return
        self._frozen_s += block.duration
        if self._frozen_s >= FROZEN_S and self.fault is None:
            self.fault = {'kind': 'frozen', 'time_s': float(block.t),
                          'message': f'the sensor is frozen: {self.detector.frozen} for '
                                     f'{self._frozen_s:.1f} s (a stuck sensor, or a driver '
                                     'repeating its last frame)'}
            if len(self.faults) < 20:
                self.faults.append(self.fault)

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
        if not self.settings.health_enabled or run.duration < self.health.min_still_s:
            return
        words = period_words(run)
        if words:
            self.rejected[words.split(' (')[0].split(' at ')[0]] += 1
            self.last_rejection = words
            return
        self.noise.add(run)
        obs = self.health.observation(run, self.noise.ratio(len(run.blocks)))
        if obs is not None:
            self.neighbours.close(run, obs)

    def _confirm(self, results):
        for result in results:
            if result[0] == 'confirm':
                self.last_health = self.health.observe(result[1])
            else:
                self.rejected['between rests that disagree with it'] += 1
                self.last_rejection = result[2]

    def reset_gyro_bias(self):
        """Forget the gyro-bias updates: back to the file's bias (the published one jumps)."""
        self.gyro.reset(self._t)
        if self.run is not None:
            self.gyro.begin()

    # -- words -----------------------------------------------------------------------------
    def idle_s(self):
        """Return the stream time since the last still block, s (0 before any data)."""
        if self._t is None or self._since is None:
            return 0.0
        return max(self._t - self._since, 0.0)

    def idle_words(self):
        """Return '' when a still block came within ``still_timeout_s``, else why none came."""
        idle = self.idle_s()
        if idle < self.settings.still_timeout_s:
            return ''
        total = sum(self._why.values()) or 1
        why = ', '.join(f'{k} {100.0 * v / total:.0f} %' for k, v in self._why.most_common(3))
        return (f'no still period for {idle:.0f} s (the blocks: {why}): the gyro bias and '
                'the calibration are not being checked')

    def gyro_summary(self):
        """Return a dict describing the gyro-bias tracker (JSON-ready)."""
        tr = self.gyro
        return {'enabled': self.settings.gyro_bias_enabled,
                'estimate_rad_s': [float(v) for v in self.gyro_bias],
                'estimate_deg_s': [float(math.degrees(v)) for v in self.gyro_bias],
                'state': tr.state if self.settings.gyro_bias_enabled else 'off',
                'followed': tr.followed, 'along_gravity': tr.vertical,
                'held_about_gravity_deg_s': float(math.degrees(tr.held_rate)),
                'zero_deg_s': [float(math.degrees(v)) for v in self.detector.zero],
                'periods_used': tr.updates, 'periods_dropped_tilting': tr.rejected,
                'periods_turning_about_gravity': tr.turning}


def corrected_arrays(cal, accel, gyro=None, temp=None, mag=None, time=None, stream=None):
    """
    Correct arrays as the correction node does (level trim and hysteresis term included).

    :param cal: Calibration. :param accel: (N, 3) raw m/s². :param gyro: (N, 3) raw
        rad/s or None. :param temp: (N,) °C or None. :param mag: (N, 3) raw µT or None.
    :param time: (N,) s, or None (no heating/cooling term). :param stream: the
        calibration's ``lag_stream()`` carried from piece to piece of one recording.
    :return: (accel, gyro or None, mag or None), corrected, in the levelled frame.
    """
    L = np.asarray(cal.level_rotation(), float)
    with np.errstate(all='ignore'):
        a = cal.correct(accel, temp, time, stream) @ L.T
        g = None if gyro is None else cal.correct_gyro(gyro, temp) @ L.T
        m = None if mag is None or cal.magnetometer is None else cal.correct_mag(mag) @ L.T
        if mag is not None and m is None:
            m = np.asarray(mag, float) @ L.T
    return a, g, m
