"""
Guided calibration on the command line: ``accel-calib advise`` and ``accel-calib guide``.

``advise`` reads a recording (or a session still being recorded) and says how good the
calibration would be now, whether that is enough and which pose to hold next
(interface §5). ``guide`` walks a person through a calibration live, from a serial
port (§1 frames), a ROS topic or a simulated sensor held by a simulated person: it
shows where gravity points now against the pose asked for, how long to keep holding,
the windows collected and the predicted accuracy against the target, draws the board
in the next pose, says "enough", fits and writes the calibration atomically.

Only the standard library and numpy are imported here at module level (``accel-calib``
starts fast); rich, pyserial and rclpy are imported when a command needs them.
"""

from collections import deque
import math
import os
import sys
import time

import numpy as np

from .core.advice import advise, coverage, DEFAULT_TARGET, MIN_WINDOWS, pose_name
from .core.errors import CalibrationError, InputError

G0 = 9.80665
MAX_SIGMA_FLOOR = 10.0
"""Largest --sigma-floor accepted, m/s² (a floor of about 1 g already means no advice)."""


# -- arguments ------------------------------------------------------------------------------

def _non_negative(text):
    import argparse
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f'not a number: {text!r}') from None
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f'must be >= 0, got {text}')
    return value


def _positive_upto(high):
    """Argparse type: a positive finite number no larger than ``high``."""
    import argparse
    from . import cli

    def parse(text):
        value = cli._positive(text)
        if value > high:
            raise argparse.ArgumentTypeError(f'must be at most {high:g}, got {text}')
        return value
    parse.__name__ = 'number'
    return parse


def add_parsers(sub):
    """
    Register ``advise`` and ``guide`` on the ``accel-calib`` subparsers.

    :param sub: the subparsers object of :func:`accel_calib_ros.cli.build_parser`.
    """
    from . import cli
    p = sub.add_parser('advise', help='which pose to hold next, and when it is enough')
    cli._add_data_args(p)
    p.add_argument('--method', choices=('ml', 'gn'), default='ml',
                   help='model the advice is for (default ml)')
    p.add_argument('--target', type=cli._positive, default=DEFAULT_TARGET,
                   help='predicted accuracy that is enough, m/s² (default %(default)s)')
    p.add_argument('--gravity', type=cli.GRAVITY, default=G0,
                   help='local gravity magnitude, m/s² (default %(default)s)')
    p.add_argument('--sigma-floor', type=cli._ranged(0.0, MAX_SIGMA_FLOOR), default=None,
                   help='error of a window mean that no averaging removes, m/s² '
                        '(default 0.001)')
    p.add_argument('--json', action='store_true', help='print one JSON object')
    cli._add_window_args(p)

    p = sub.add_parser('guide', help='live guided calibration in the terminal')
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument('--port', help='serial port of the MPU9250 board (interface §1 frames)')
    src.add_argument('--topic', help='sensor_msgs/Imu topic to listen to (ROS 2)')
    src.add_argument('--simulate', action='store_true',
                     help='a simulated sensor held by a simulated person who follows the '
                          'advice')
    p.add_argument('-o', '--output', help='calibration YAML to write (default: the file of '
                                          'the nodes, $ROS_HOME/accel_calib_ros/'
                                          'calibration.yaml)')
    p.add_argument('--method', choices=('ml', 'gn'), default='ml')
    p.add_argument('--target', type=cli._positive, default=DEFAULT_TARGET,
                   help='predicted accuracy that is enough, m/s² (default %(default)s)')
    p.add_argument('--gravity', type=cli.GRAVITY, default=G0)
    p.add_argument('--max-predicted-error', type=cli._ranged(1e-9, 1e3), default=0.02,
                   metavar='M_S2',
                   help='refuse to write a calibration whose predicted accuracy is worse '
                        'than this, m/s² (default %(default)s, as fit and the node)')
    p.add_argument('--hold', type=cli._positive, default=2.0,
                   help='seconds to hold each pose still (default %(default)s)')
    p.add_argument('--record', help='also write the raw samples to this CSV')
    p.add_argument('--history', nargs='?', const='', default=None, metavar='DB',
                   help='keep the windows and the calibration in this per-sensor history '
                        '(default next to the calibration file)')
    p.add_argument('--sensor', help='sensor id in the history (default: the port, the topic '
                                    'or "simulated-SEED")')
    p.add_argument('--timeout', type=cli._positive, default=None,
                   help='give up after this many wall-clock seconds')
    g = p.add_argument_group('serial port')
    g.add_argument('--baud', type=int, default=1000000)
    g.add_argument('--ascii', action='store_true', help='ASCII line format instead of frames')
    g.add_argument('--accel-range', type=int, default=2, choices=(2, 4, 8, 16))
    g.add_argument('--gyro-range', type=int, default=250, choices=(250, 500, 1000, 2000))
    g = p.add_argument_group('ROS topic')
    g.add_argument('--temp-topic', help='sensor_msgs/Temperature topic (optional)')
    g = p.add_argument_group('simulation')
    g.add_argument('--speed', type=_positive_upto(1e4), default=1.0,
                   help='simulated seconds per wall-clock second (default %(default)s)')
    g.add_argument('--seed', type=cli.SEED, default=0)
    g.add_argument('--pose-error', type=_non_negative, default=3.0,
                   help='how far off the simulated person holds each pose, degrees')
    g.add_argument('--turn', type=cli._positive, default=2.0,
                   help='seconds the simulated person takes to turn (default %(default)s)')
    g.add_argument('--temp', type=cli.TEMPERATURE, default=25.0,
                   help='simulated temperature, °C')
    g.add_argument('--rate', type=cli._ranged(1.0, 100000.0), default=100.0,
                   help='simulated rate, Hz')
    return {'advise': cmd_advise, 'guide': cmd_guide}


# -- advise -----------------------------------------------------------------------------------

def cmd_advise(args, out):
    """Run ``accel-calib advise``; return the exit status."""
    from . import cli
    from .core.windows import detect_static_windows
    samples = cli._load(args)
    windows = detect_static_windows(samples, min_duration_s=args.min_window_s,
                                    threshold_factor=args.threshold_factor)
    if len(windows):
        weights = windows.weights(args.max_weight_s, samples.rate_hz)
        noise = windows.noise_std
    else:
        weights = np.zeros(0)
        floor = windows.noise_floor
        noise = np.full(3, floor if math.isfinite(floor) else 0.02)
    result = advise(windows.mean, weights, noise, args.gravity, args.method, args.target,
                    args.sigma_floor)
    if args.json:
        d = result.to_dict()
        d['samples'] = len(samples)
        out(d)
    else:
        print(result.text())
    return 0


# -- live session -----------------------------------------------------------------------------

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

    def update(self, t, a, temp=math.nan):
        """
        Add one sample; return a captured window (dict) or None.

        :param t: time, s.
        :param a: (3,) acceleration, m/s².
        :param temp: °C or NaN.
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
            self._acc = {'n': 0, 's': np.zeros(3), 's2': np.zeros(3), 'temp': [], 't0': t}
        if self.state == 'holding':
            acc = self._acc
            v = np.array(a)
            acc['n'] += 1
            acc['s'] += v
            acc['s2'] += v * v
            if math.isfinite(temp):
                acc['temp'].append(temp)
            self.progress = min((t - self._t0) / self.hold_s, 1.0)
            if self.progress >= 1.0 and acc['n'] >= 3:
                self.state = 'captured'
                n = acc['n']
                mean = acc['s'] / n
                scatter = np.sqrt(np.maximum(acc['s2'] - n * mean ** 2, 0.0) / (n - 1))
                return {'mean': mean, 'scatter': scatter, 'count': n,
                        'temp': float(np.mean(acc['temp'])) if acc['temp'] else math.nan,
                        't_start': acc['t0'], 't_stop': t, 't_mid': 0.5 * (acc['t0'] + t),
                        'rate_hz': (n - 1) / max(t - acc['t0'], 1e-9)}
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

    def __init__(self, rate_hz, method='ml', target=DEFAULT_TARGET, gravity=G0, hold_s=2.0,
                 max_weight_s=5.0):
        self.method = method
        self.target = target
        self.gravity = gravity
        self.max_weight_s = max_weight_s
        self.tracker = HoldTracker(rate_hz, hold_s)
        self.windows = []
        self.samples = 0
        self.advice = advise(np.zeros((0, 3)), np.zeros(0), 0.02, gravity, method, target)

    @property
    def enough(self):
        """Return True once the advice says the target is reached."""
        return self.advice.enough

    @property
    def target_direction(self):
        """Gravity direction (3,) of the pose asked for, or None when enough."""
        pose = self.advice.next_pose
        return None if pose is None else pose.gravity_direction

    def arrays(self):
        """Return (means (N, 3), weights (N,), temps (N,), noise (3,)) of the windows."""
        w = self.windows
        means = np.array([x['mean'] for x in w]).reshape(-1, 3)
        counts = np.array([x['count'] for x in w], float)
        rates = np.array([x['rate_hz'] for x in w], float)
        weights = np.minimum(counts, self.max_weight_s * rates)
        temps = np.array([x['temp'] for x in w], float)
        scatter = np.array([x['scatter'] for x in w]).reshape(-1, 3)
        dof = np.maximum(counts - 1, 0)
        noise = np.sqrt(np.sum(dof[:, None] * scatter ** 2, axis=0) / max(dof.sum(), 1.0)) \
            if len(w) else np.full(3, self.tracker.noise_floor)
        return means, weights, temps, noise

    def update(self, t, accel, temp):
        """
        Feed samples; return the windows captured among them.

        :param t: (N,) s; ``accel`` (N, 3) m/s²; ``temp`` (N,) °C (NaN when unknown).
        """
        new = []
        for k in range(len(t)):
            window = self.tracker.update(t[k], accel[k], temp[k])
            if window is not None:
                self.windows.append(window)
                new.append(window)
        self.samples += len(t)
        if new:
            means, weights, _, noise = self.arrays()
            self.advice = advise(means, weights, noise, self.gravity, self.method, self.target)
        return new

    def status(self):
        """Return what the screen shows, as a dict."""
        now = self.tracker.current()
        norm = float(np.linalg.norm(now))
        direction = now / norm if norm > 0 else np.array([0.0, 0.0, 1.0])
        target = self.target_direction
        angle = None
        if target is not None:
            angle = float(np.degrees(np.arccos(np.clip(direction @ target, -1, 1))))
        means = self.arrays()[0]
        distinct = coverage(means / np.linalg.norm(means, axis=1, keepdims=True))[1] \
            if len(means) else 0
        return {'direction': direction, 'norm_g': norm / self.gravity, 'angle_deg': angle,
                'state': self.tracker.state, 'progress': self.tracker.progress,
                'windows': len(self.windows), 'distinct': distinct, 'advice': self.advice}

    def fit(self, source=''):
        """Fit the calibration to the windows; CalibrationError when it cannot."""
        from .core.calibration import calibrate
        means, weights, temps, noise = self.arrays()
        return calibrate(means, gravity=self.gravity, method=self.method, weights=weights,
                         temps=temps, noise_std=noise, source=source)


# -- drawing ----------------------------------------------------------------------------------

_FACE_ART = {
    'z': ('      ▲ up',
          '  ┌─────────┐',
          '  │ ▪▪ chip │  lying flat, chip side up',
          '  └─────────┘',
          ' ▔▔▔▔▔▔▔▔▔▔▔▔▔'),
    '-z': ('      ▲ up',
           '  ┌─────────┐',
           '  │  bottom │  lying flat, upside down',
           '  └─────────┘',
           ' ▔▔▔▔▔▔▔▔▔▔▔▔▔'),
}


def _axis_arrow(component):
    """Arrow for how far an axis points up: component of the up direction on it."""
    deg = math.degrees(math.asin(max(-1.0, min(1.0, component))))
    if deg > 60:
        return '↑', f'{deg:+.0f}° up'
    if deg > 15:
        return '↗', f'{deg:+.0f}° up'
    if deg >= -15:
        return '→', 'level'
    if deg >= -60:
        return '↘', f'{-deg:.0f}° down'
    return '↓', f'{-deg:.0f}° down'


def board_drawing(direction):
    """
    Return a small text drawing of the board held in the pose ``direction``.

    A side view of the board for the two flat poses; for the others the board stands on
    an edge or a corner, drawn standing, with the side that faces up named. Below it,
    for each sensor axis, an arrow and the angle its + end makes with the horizontal.

    :param direction: (3,) gravity direction of the pose (the sensor axis pointing up).
    :return: multi-line string.
    """
    d = np.asarray(direction, float)
    d = d / np.linalg.norm(d)
    up = [('+' if d[i] > 0 else '-') + 'xyz'[i] for i in range(3) if abs(d[i]) > 0.3]
    if abs(d[2]) > 0.95:
        lines = list(_FACE_ART['z' if d[2] > 0 else '-z'])
    else:
        side = ' '.join(up)
        stand = ' on its edge' if abs(d[2]) < 0.3 else ', leaning'
        how = {2: '  tilted 45°', 3: '  on a corner'}.get(len(up), '')
        lines = ['      ▲ up',
                 f'    ┌──┐  {side} side{"s" if len(up) > 1 else ""} up',
                 '    │▪▪│  board standing' + stand,
                 '    │  │' + how,
                 '    └──┘',
                 ' ▔▔▔▔▔▔▔▔▔▔▔▔▔']
    for i, axis in enumerate('xyz'):
        arrow, words = _axis_arrow(d[i])
        lines.append(f'  {axis} axis {arrow} {words}')
    return '\n'.join(lines)


# -- sample sources -------------------------------------------------------------------------

def _slerp(a, b, s):
    """Point a fraction ``s`` of the way along the great circle from unit ``a`` to ``b``."""
    dot = float(np.clip(a @ b, -1.0, 1.0))
    if dot < -0.999:            # opposite: turn over a perpendicular axis
        p = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
        p /= np.linalg.norm(p)
        return _slerp(a, p, 2 * s) if s < 0.5 else _slerp(p, b, 2 * s - 1)
    omega = math.acos(dot)
    if omega < 1e-9:
        return b.copy()
    v = (math.sin((1 - s) * omega) * a + math.sin(s * omega) * b) / math.sin(omega)
    return v / np.linalg.norm(v)


class SimulatedSource:
    """
    A simulated MPU9250 held by a simulated person who follows the guide.

    The person holds a pose until the guide has captured it, waits a reaction time,
    turns to the pose the guide asks for (off by a few degrees) in ``turn_s`` with the
    hand's acceleration, and holds again. Time runs ``speed`` times faster than the wall
    clock, so a test of a whole session takes seconds.
    """

    label = 'simulated sensor and person'

    def __init__(self, rate_hz=100.0, speed=1.0, seed=0, error_deg=3.0, turn_s=2.0,
                 temp=25.0, gravity=G0, tremor=0.02, reaction_s=0.5):
        from .core.simulate import mpu9250_like
        self.rng = np.random.default_rng(seed)
        self.sensor = mpu9250_like(self.rng, rate_hz)
        self.rate = rate_hz
        self.speed = speed
        self.error_deg = error_deg
        self.turn_s = turn_s
        self.temp = temp
        self.gravity = gravity
        self.tremor = tremor
        self.reaction_s = reaction_s
        self.t = 0.0
        self._wall0 = None
        self.direction = np.array([0.0, 0.0, 1.0])
        self.state, self._since, self._from, self._to = 'holding', 0.0, None, None
        self._axis = np.array([1.0, 0.0, 0.0])

    def _person(self, session, t):
        if self.state == 'holding':
            if session is not None and session.tracker.state == 'captured' \
                    and not session.enough:
                if self._since is None:
                    self._since = t
                if t - self._since >= self.reaction_s:
                    from .core.person import tilt
                    self._from = self.direction.copy()
                    self._to = tilt(session.target_direction, abs(self.rng.normal(
                        0.0, self.error_deg)), self.rng)
                    self.state, self._since = 'turning', t
                    axis = np.cross(self._from, self.rng.standard_normal(3))
                    self._axis = axis / np.linalg.norm(axis)
            else:
                self._since = None
        elif self.state == 'turning':
            s = (t - self._since) / self.turn_s
            if s >= 1.0:
                self.direction = self._to
                self.state, self._since = 'holding', None
                return np.zeros(3)
            smooth = s * s * (3 - 2 * s)
            self.direction = _slerp(self._from, self._to, smooth)
            return 1.5 * math.sin(math.pi * s) * self._axis
        return np.zeros(3)

    def read(self, session):
        """Return the samples (t, accel, temp) due by now; sleeps a little."""
        time.sleep(0.02)
        now = time.monotonic()
        if self._wall0 is None:
            self._wall0 = now - 0.02
        due = (now - self._wall0) * self.speed
        n = min(int((due - self.t) * self.rate), int(5 * self.rate))
        if n <= 0:
            return np.zeros(0), np.zeros((0, 3)), np.zeros(0)
        t = self.t + np.arange(n) / self.rate
        true = np.empty((n, 3))
        for k in range(n):
            motion = self._person(session, t[k])
            true[k] = self.gravity * self.direction + motion
        self.t = t[-1] + 1.0 / self.rate
        temp = np.full(n, float(self.temp))
        raw = self.sensor.measure(true, self.rng, temp)
        raw = raw + self.rng.standard_normal(raw.shape) * self.tremor
        return t, raw, temp

    def close(self):
        """Nothing to release."""


class SerialSource:
    """MPU9250 frames (interface §1) or ASCII lines from a serial port."""

    def __init__(self, port, baud=1000000, ascii_lines=False, accel_range=2, gyro_range=250):
        try:
            import serial
        except ImportError:
            raise InputError('pyserial is not installed (pip install pyserial)') from None
        from .dataio.wire import AsciiLineParser, Converter, FrameParser
        self.label = f'serial {port} at {baud} baud'
        try:
            self.port = serial.Serial(port, baud, timeout=0.05)
        except (serial.SerialException, OSError, ValueError) as err:
            raise InputError(f'cannot open {port}: {err}') from None
        self.parser = AsciiLineParser() if ascii_lines else FrameParser()
        self.converter = Converter(accel_range, gyro_range)
        self._last_us, self._t = None, 0.0

    def read(self, session):
        """Return the samples (t, accel, temp) received since the last call."""
        import serial
        try:
            data = self.port.read(max(1, self.port.in_waiting))
        except (serial.SerialException, OSError) as err:
            raise InputError(f'serial port: {err}') from None
        t, acc, temp = [], [], []
        for frame in self.parser.feed(data):
            a, c, _ = self.converter.to_si(frame.counts)
            if frame.t_us is None:
                self._t = time.monotonic()
            else:
                if self._last_us is not None:
                    self._t += ((frame.t_us - self._last_us) % 2 ** 32) * 1e-6
                self._last_us = frame.t_us
            t.append(self._t)
            acc.append(a)
            temp.append(c)
        return np.array(t), np.array(acc).reshape(-1, 3), np.array(temp)

    def close(self):
        """Close the port."""
        self.port.close()


class RosSource:
    """sensor_msgs/Imu (and Temperature) from ROS 2 topics; rclpy is imported here."""

    def __init__(self, topic, temp_topic=None):
        try:
            import rclpy
            from rclpy.qos import qos_profile_sensor_data
            from sensor_msgs.msg import Imu, Temperature
        except ImportError as err:
            raise InputError(f'ROS 2 (rclpy) is not available: {err}') from None
        from rclpy.executors import SingleThreadedExecutor
        self.label = f'ROS topic {topic}'
        self.rclpy = rclpy
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node('accel_calib_guide', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.buffer = []
        self.temp = math.nan
        self.node.create_subscription(Imu, topic, self._on_imu, qos_profile_sensor_data)
        if temp_topic:
            self.node.create_subscription(Temperature, temp_topic, self._on_temp,
                                          qos_profile_sensor_data)

    def _on_imu(self, msg):
        a = msg.linear_acceleration
        stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        if stamp <= 0:
            stamp = time.monotonic()
        self.buffer.append((stamp, (a.x, a.y, a.z), self.temp))

    def _on_temp(self, msg):
        self.temp = float(msg.temperature)

    def read(self, session):
        """Spin briefly; return the samples (t, accel, temp) received."""
        deadline = time.monotonic() + 0.05
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.01)
        got, self.buffer = self.buffer, []
        got = [g for g in got if all(map(math.isfinite, g[1]))]
        return (np.array([g[0] for g in got]), np.array([g[1] for g in got]).reshape(-1, 3),
                np.array([g[2] for g in got], float))

    def close(self):
        """Leave the ROS graph."""
        self.executor.shutdown()
        self.node.destroy_node()
        self.rclpy.try_shutdown(context=self.context)


# -- the screen -------------------------------------------------------------------------------

def render(session, source_label, message=''):
    """
    Build the rich renderable of the guide screen.

    :param session: GuideSession.
    :param source_label: where the samples come from.
    :param message: a status line.
    """
    from rich.console import Group
    from rich.panel import Panel
    from rich.progress_bar import ProgressBar
    from rich.table import Table
    from rich.text import Text

    st = session.status()
    adv = st['advice']
    grid = Table.grid(padding=(0, 2))
    grid.add_column(justify='right', style='bold')
    grid.add_column()
    d = st['direction']
    grid.add_row('gravity now', f'({d[0]:+.2f}, {d[1]:+.2f}, {d[2]:+.2f})  '
                                f'{pose_name(d)}')
    if st['angle_deg'] is not None:
        on = st['angle_deg'] < 12.0
        grid.add_row('pose asked', Text(f'{st["angle_deg"]:.0f}° from it'
                                        + ('  ✓ on target' if on else ''),
                                        style='green' if on else 'yellow'))
    state = {'moving': 'moving', 'settling': 'settling…', 'holding': 'hold still…',
             'captured': 'captured ✓ — turn to the next pose'}[st['state']]
    if adv.enough:
        state = 'captured ✓ — done'
    bar = Table.grid(padding=(0, 1))
    bar.add_row(ProgressBar(total=1.0, completed=st['progress'], width=30),
                f'{st["progress"] * 100:3.0f} %  {state}')
    grid.add_row('hold', bar)
    grid.add_row('windows', f'{st["windows"]} collected, {st["distinct"]} distinct directions'
                            f' ({session.method} needs {MIN_WINDOWS[session.method]})')
    if adv.predicted_accuracy is None:
        acc = Text(f'— (not solvable yet)  target {adv.target:.4f} m/s²', style='dim')
    else:
        good = adv.predicted_accuracy <= adv.target
        acc = Text(f'{adv.predicted_accuracy:.4f} m/s²  target {adv.target:.4f} m/s²',
                   style='bold green' if good else 'bold yellow')
    grid.add_row('predicted accuracy', acc)
    parts = [grid]
    if adv.enough:
        parts.append(Panel(Text('ENOUGH — the calibration meets the target', style='bold green'),
                           border_style='green'))
    elif adv.next_pose is not None:
        after = adv.next_pose.predicted_accuracy_after
        title = f'next pose: {adv.next_pose.name}'
        if after is not None:
            title += f'  (then {after:.4f} m/s²)'
        parts.append(Panel(Text(board_drawing(adv.next_pose.gravity_direction)),
                           title=title, title_align='left', border_style='cyan'))
    if message:
        parts.append(Text(message))
    if not adv.enough:
        parts.append(Text('q: stop without writing', style='dim'))
    return Panel(Group(*parts), title=f'accel-calib guide — {source_label}',
                 title_align='left')


class _Keys:
    """Single key presses from a terminal, without waiting for Enter (no-op otherwise)."""

    def __init__(self):
        self.fd = None
        if sys.stdin is not None and sys.stdin.isatty():
            import termios
            import tty
            self.fd = sys.stdin.fileno()
            self.saved = termios.tcgetattr(self.fd)
            tty.setcbreak(self.fd)

    def get(self):
        """Return the keys pressed since the last call ('' if none)."""
        if self.fd is None:
            return ''
        import select
        keys = ''
        while select.select([self.fd], [], [], 0)[0]:
            chunk = os.read(self.fd, 32)
            if not chunk:
                break
            keys += chunk.decode(errors='replace')
        return keys

    def close(self):
        """Restore the terminal."""
        if self.fd is not None:
            import termios
            termios.tcsetattr(self.fd, termios.TCSADRAIN, self.saved)
            self.fd = None


def cmd_guide(args, out):
    """Run ``accel-calib guide``; return the exit status."""
    from . import cli
    from .dataio.calibration_file import default_calibration_path
    output = args.output or default_calibration_path()
    cli._check_output(output, args.port, what='-o')
    cli._check_output(args.record, args.port, what='--record')
    if cli._same_file(args.record, output):
        raise cli.UsageError('accel-calib guide: --record and -o must be different files')
    history = None
    if args.history is not None:
        from .dataio.history import default_history_path
        history = args.history or default_history_path()
        if any(cli._same_file(history, f) for f in (output, args.record)):
            raise cli.UsageError('accel-calib guide: the history must not be the output or '
                                 'the record file')
        args.sensor = args.sensor or args.port or args.topic or f'simulated-{args.seed}'
    try:
        from rich.console import Console
        from rich.live import Live
        from rich.text import Text
    except ImportError:
        raise InputError('the guide needs the rich package (pip install rich)') from None
    if args.simulate:
        source = SimulatedSource(args.rate, args.speed, args.seed, args.pose_error, args.turn,
                                 args.temp, args.gravity)
        rate = args.rate
    elif args.port:
        source = SerialSource(args.port, args.baud, args.ascii, args.accel_range,
                              args.gyro_range)
        rate = None
    else:
        source = RosSource(args.topic, args.temp_topic)
        rate = None
    console = Console()
    session, recorded, keys = None, [], _Keys()
    if rate:
        session = GuideSession(rate, args.method, args.target, args.gravity, args.hold)
    start = time.monotonic()
    status, message = 1, ''
    try:
        pending = []
        with Live(console=console, auto_refresh=False, transient=False) as live:
            last_draw = 0.0
            while True:
                t, a, temp = source.read(session)
                if session is None:
                    pending.append((t, a, temp))
                    rate = rate or _rate([p[0] for p in pending])
                    if rate is None:
                        live.update(Text('waiting for samples from ' + source.label),
                                    refresh=True)
                        continue
                    session = GuideSession(rate, args.method, args.target, args.gravity,
                                           args.hold)
                    t, a, temp = (np.concatenate([p[i] for p in pending]) for i in range(3))
                    a = a.reshape(-1, 3)
                    pending = None
                keep = np.all(np.isfinite(a), axis=1)
                t, a, temp = t[keep], a[keep], temp[keep]
                if args.record:
                    recorded.append((t, a, temp))
                session.update(t, a, temp)
                if session.enough:
                    live.update(render(session, source.label, 'fitting…'), refresh=True)
                    break
                pressed = keys.get()
                if 'q' in pressed.lower():
                    message = 'stopped: nothing written'
                    live.update(render(session, source.label, message), refresh=True)
                    break
                if args.timeout and time.monotonic() - start > args.timeout:
                    message = f'timed out after {args.timeout:g} s: nothing written'
                    live.update(render(session, source.label, message), refresh=True)
                    break
                now = time.monotonic()
                if now - last_draw > 0.1:
                    live.update(render(session, source.label), refresh=True)
                    last_draw = now
        if session is not None and session.enough:
            status = _finish(session, output, source.label, console, history, args.sensor,
                             args.max_predicted_error)
        else:
            console.print(message or 'stopped: nothing written')
    except KeyboardInterrupt:
        console.print('interrupted: nothing written')
        status = 130
    finally:
        keys.close()
        source.close()
        if args.record and recorded:
            _write_record(args.record, recorded)
    return status


def _rate(stamp_lists):
    t = np.concatenate(stamp_lists) if stamp_lists else np.zeros(0)
    if len(t) < 50:
        return None
    dt = np.diff(t)
    dt = dt[dt > 0]
    if len(dt) < 25:
        return None
    return 1.0 / float(np.median(dt))


def _finish(session, output, label, console, history=None, sensor=None,
            max_predicted_error=0.02):
    """
    Fit, review (the same acceptance rule as ``fit``) and write the calibration.

    :return: the exit status (1 when the fit is refused: nothing written).
    """
    try:
        cal = session.fit(source=f'accel-calib guide ({label})')
    except CalibrationError as err:
        console.print(f'cannot calibrate: {err}')
        return 1
    from .core.acceptance import review
    from .dataio.calibration_file import save_calibration
    adv = session.advice
    if cal.predicted_accuracy is None:
        cal.predicted_accuracy = adv.predicted_accuracy
    verdict = review(cal, max_predicted_error, refuse_unphysical=True,
                     limit_name='--max-predicted-error')
    if verdict.refusal:
        console.print(f'cannot calibrate: {verdict.refusal}; nothing written')
        return 1
    temps = session.arrays()[2]
    temps = temps[np.isfinite(temps)]
    if cal.temperature_range_c is None and len(temps):
        cal.temperature_range_c = (float(temps.min()), float(temps.max()))
    save_calibration(cal, output)
    console.print(f'enough: predicted accuracy {adv.predicted_accuracy:.4f} m/s² ≤ target '
                  f'{adv.target:.4f} m/s² after {len(session.windows)} poses')
    console.print(f'wrote calibration {output}')
    if history:
        from .dataio.history import History
        means, weights, temps, _ = session.arrays()
        t_mid = np.array([w['t_mid'] for w in session.windows])
        now = time.time()
        with History(history) as h:
            h.add_windows(sensor, means, temps, weights, now - (t_mid.max() - t_mid))
            h.add_calibration(sensor, cal, windows=len(means))
        console.print(f'history {history}: {len(means)} windows and the calibration kept '
                      f'for sensor {sensor}')
    return 0


def _write_record(path, recorded):
    from .core.samples import Samples
    from .dataio.recording import write_samples_csv
    t = np.concatenate([r[0] for r in recorded])
    if len(t) < 2:
        return
    a = np.concatenate([r[1] for r in recorded]).reshape(-1, 3)
    temp = np.concatenate([r[2] for r in recorded])
    write_samples_csv(path, Samples(t, a, temp if np.all(np.isfinite(temp)) else None, None))
