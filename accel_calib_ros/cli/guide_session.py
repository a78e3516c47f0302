"""
The state of a guided session: holds, windows, advice, and the fit at the end.

:class:`HoldTracker` decides sample by sample when a pose is held still and for how long;
:class:`GuideSession` keeps the windows, the advice (``core.advice``) and the pose to ask
for next, and ends the session when it is enough (``session.finish.finish_session``: the
fit, acceptance, file and history of ``fit`` and the node). When the source gives the
angular rate and the magnetic field, the session also keeps them (``core.collector``) and
says after each window which rotation axis the moves have not turned about yet and how
much of the sphere of field directions the magnetometer has seen (``core.outcomes``).
"""

from collections import deque
import math

import numpy as np

from ..core.advice import advise, coverage, DEFAULT_TARGET
from ..core.collector import ImuCollector
from ..core.constants import G0
from ..session.settings import DEFAULT_SETTINGS
from ..session.windows import Window, WindowSet


class HoldTracker:
    """
    Decide, sample by sample, when a pose is being held still and for how long.

    Still means the moving standard deviation of the acceleration over ``window_s``
    is below ``factor`` x the noise floor (the smallest moving standard deviation seen
    lately, never below ``min_floor``). After ``settle_s`` of stillness the hold starts;
    after ``hold_s`` more the window is captured and the tracker waits for the next
    movement, so a pose gives one window however long it is held.

    :param rate_hz: nominal sample rate, Hz.
    """

    def __init__(self, rate_hz, hold_s=2.0, window_s=0.25, factor=3.0, settle_s=0.3,
                 min_floor=0.005, floor_memory_s=60.0):
        self.n = max(int(round(window_s * rate_hz)), 3)
        self.hold_s = hold_s
        self.settle_s = settle_s
        self.factor = factor
        self.min_floor = min_floor
        self._ring = deque(maxlen=self.n)
        self._sum = [0.0, 0.0, 0.0]
        self._sum2 = [0.0, 0.0, 0.0]
        self._block = max(int(round(floor_memory_s * rate_hz / 6)), 1)
        self._floors = deque(maxlen=6)
        self._block_min, self._block_count = math.inf, 0
        self.state = 'moving'
        self._t0 = 0.0
        self._acc = None
        self.progress = 0.0
        self.last = np.array([0.0, 0.0, G0])

    @property
    def noise_floor(self):
        """Return the noise floor now, m/s²."""
        return max(min(list(self._floors) + [self._block_min]), self.min_floor)

    def update(self, t, a, temp=math.nan, gyro=None):
        """
        Add one sample; return a captured window (dict) or None.

        :param t: time, s.
        :param a: (3,) acceleration, m/s².
        :param temp: °C or NaN.
        :param gyro: (3,) angular rate, rad/s, or None (the window's mean rate: the gyro bias).
        """
        a = [float(a[0]), float(a[1]), float(a[2])]
        if len(self._ring) == self.n:
            old = self._ring[0]
            for i in range(3):
                self._sum[i] -= old[i]
                self._sum2[i] -= old[i] * old[i]
        self._ring.append(a)
        for i in range(3):
            self._sum[i] += a[i]
            self._sum2[i] += a[i] * a[i]
        m = len(self._ring)
        var = sum(max(self._sum2[i] / m - (self._sum[i] / m) ** 2, 0.0) for i in range(3)) / 3
        std = math.sqrt(var)
        if m < self.n:
            return None
        self._block_min = min(self._block_min, std)
        self._block_count += 1
        if self._block_count >= self._block:
            self._floors.append(self._block_min)
            self._block_min, self._block_count = math.inf, 0
        if std > self.factor * self.noise_floor:
            self.state, self.progress, self._acc = 'moving', 0.0, None
            return None
        if self.state == 'moving':
            self.state, self._t0 = 'settling', t
        if self.state == 'settling':
            if t - self._t0 < self.settle_s:
                return None
            self.state, self._t0 = 'holding', t
            self._acc = {'n': 0, 's': np.zeros(3), 's2': np.zeros(3), 'temp': [], 't0': t,
                         'g': np.zeros(3), 'g_n': 0}
        if self.state == 'holding':
            acc = self._acc
            v = np.array(a)
            acc['n'] += 1
            acc['s'] += v
            acc['s2'] += v * v
            if math.isfinite(temp):
                acc['temp'].append(temp)
            if gyro is not None and np.all(np.isfinite(gyro)):
                acc['g'] += gyro
                acc['g_n'] += 1
            self.progress = min((t - self._t0) / self.hold_s, 1.0)
            if self.progress >= 1.0 and acc['n'] >= 3:
                self.state = 'captured'
                n = acc['n']
                mean = acc['s'] / n
                scatter = np.sqrt(np.maximum(acc['s2'] - n * mean ** 2, 0.0) / (n - 1))
                return {'mean': mean, 'scatter': scatter, 'count': n,
                        'temp': float(np.mean(acc['temp'])) if acc['temp'] else math.nan,
                        't_start': acc['t0'], 't_stop': t, 't_mid': 0.5 * (acc['t0'] + t),
                        'rate_hz': (n - 1) / max(t - acc['t0'], 1e-9),
                        'gyro_mean': acc['g'] / n if acc['g_n'] == n else None}
        return None

    def current(self):
        """Mean acceleration over the last ``window_s``, m/s² (3,)."""
        m = len(self._ring)
        if m:
            self.last = np.array(self._sum) / m
        return self.last


class GuideSession:
    """
    The logic of a guided session, without any terminal: windows, advice, fit.

    :param method: 'ml' or 'gn'.
    :param target: predicted accuracy that is enough, m/s².
    """

    def __init__(self, rate_hz, method=DEFAULT_SETTINGS.method, target=DEFAULT_TARGET, gravity=G0,
                 hold_s=2.0, max_weight_s=DEFAULT_SETTINGS.max_weight_s):
        self.method = method
        self.target = target
        self.gravity = gravity
        self.max_weight_s = max_weight_s
        self.tracker = HoldTracker(rate_hz, hold_s)
        self.windows = []
        self.samples = 0
        self.advice = advise(np.zeros((0, 3)), np.zeros(0), 0.02, gravity, method, target)
        self.imu = ImuCollector(max_mag_samples=5000)
        self.imu_status = {}        # 'gyroscope' / 'magnetometer' advice, when they come

    @property
    def enough(self):
        """Return True once the advice says the target is reached."""
        return self.advice.enough

    @property
    def target_direction(self):
        """Gravity direction (3,) of the pose asked for, or None when enough."""
        pose = self.advice.next_pose
        return None if pose is None else pose.gravity_direction

    def window_set(self):
        """Return the windows captured so far as a WindowSet."""
        return WindowSet.from_windows(self.windows)

    def update(self, t, accel, temp, gyro=None, mag=None):
        """
        Feed samples; return the windows captured among them.

        :param t: (N,) s; ``accel`` (N, 3) m/s²; ``temp`` (N,) °C (NaN when unknown).
        :param gyro: (N, 3) rad/s, or None when the source has no gyro.
        :param mag: (times (M,) s, field (M, 3) µT) of the magnetometer samples, or None.
        """
        self._feed_imu(t, accel, temp, gyro, mag)
        new = []
        for k in range(len(t)):
            window = self.tracker.update(t[k], accel[k], temp[k],
                                         None if gyro is None else gyro[k])
            if window is not None:
                window = Window.from_detector(window)
                self.windows.append(window)
                new.append(window)
        self.samples += len(t)
        if new:
            obs = self.observations()
            self.advice = advise(obs.readings, obs.weights, obs.noise, self.gravity,
                                 self.method, self.target)
            self._imu_advice()
        return new

    def _feed_imu(self, t, accel, temp, gyro, mag):
        """Keep the rates and the field for the gyroscope and magnetometer advice."""
        if mag is not None:
            for tm, field in zip(*mag):
                self.imu.add_mag(tm, field)
        if gyro is not None or mag is not None:
            g = np.full((len(t), 3), np.nan) if gyro is None else np.asarray(gyro, float)
            self.imu.add_samples(np.column_stack([t, accel, g, temp]))

    def _imu_advice(self):
        """Recompute the gyroscope and magnetometer advice (after a window)."""
        from ..core.outcomes import field_advice, gyro_advice
        raw = self.imu.raw_samples()
        if raw is not None and raw.gyro is not None and len(self.windows) >= 2:
            self.imu_status['gyroscope'] = gyro_advice(
                raw, self.imu.windows_in(raw.t, self.windows))
        if len(self.imu.mag) >= 10:
            step = max(1, len(self.imu.mag) // 2000)
            self.imu_status['magnetometer'] = field_advice(self.imu.mag[::step, 1:4])

    def status(self):
        """Return what the screen shows, as a dict."""
        now = self.tracker.current()
        norm = float(np.linalg.norm(now))
        direction = now / norm if norm > 0 else np.array([0.0, 0.0, 1.0])
        target = self.target_direction
        angle = None
        if target is not None:
            angle = float(np.degrees(np.arccos(np.clip(direction @ target, -1, 1))))
        means = self.window_set().mean
        distinct = coverage(means / np.linalg.norm(means, axis=1, keepdims=True))[1] \
            if len(means) else 0
        return {'direction': direction, 'norm_g': norm / self.gravity, 'angle_deg': angle,
                'state': self.tracker.state, 'progress': self.tracker.progress,
                'windows': len(self.windows), 'distinct': distinct, 'advice': self.advice}

    def observations(self):
        """Return the session's Observations (the tracker's noise floor before any window)."""
        obs = self.window_set().observations(self.max_weight_s)
        if obs.noise is None:
            obs.noise = np.full(3, self.tracker.noise_floor)
        return obs

    def finish(self, settings, output=None, history=None):
        """
        End the session as every front door does (``session.finish.finish_session``).

        :param settings: ``session.settings.Settings`` (method, gravity and the weight cap
            are the session's).
        :param output: the calibration file to write, or None.
        :param history: a ``session.finish.HistoryTarget``, or None.
        :return: ``session.accept.Outcome``.
        """
        from ..session.accept import CollectedImu
        from ..session.finish import finish_session
        settings = settings.replace(method=self.method, gravity=self.gravity,
                                    max_weight_s=self.max_weight_s)
        windows = self.window_set()
        return finish_session(windows, settings, CollectedImu(self.imu, windows),
                              obs=self.observations(), output=output, history=history)
