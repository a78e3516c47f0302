"""
A robot in the field: still and moving, turning in place, knocked, warm, for months.

Built on the calibration simulator's sensor (``sim.sensor``: the accelerometer's
T, bias, noise, quantisation and temperature coefficient, the gyroscope's T, bias and
noise, the AK8963's iron and noise) and a calibration fitted to it the way
``accel-calib fit`` would (:func:`field_rig`). A day is a list of segments:

- :func:`still` a pose held for some seconds;
- :func:`turn` the same pose turning about gravity at a constant rate (a robot turning
  in place: the accelerometer reads the same, the gyro and the magnetometer do not);
- :func:`move` a drive to the next pose: a smooth turn between the two, a push of
  ``accel`` m/s² and vibration;
- moving platforms, the pose held while the platform accelerates smoothly (nothing
  vibrates, nothing turns: a block at a time they look still): :func:`lift` (an
  elevator ride: up, cruise, stop), :func:`van` (a vehicle setting off and braking),
  :func:`heave` (a ship's vertical heave);

and events (:class:`Events`): the gyro's power-up bias change, accelerometer bias steps
at given times (knocks), a temperature profile, stretches where the sensor is frozen.
A :class:`Noise` adds what the monitor's own white-noise model does not have: flicker
(a sum of first-order processes from 0.3 s to over an hour), vibration at rest (a
motor), and the gyro's quantisation (the accelerometer's is the sensor's own).

Two ways to run it:

- :func:`stream` gives the samples (as a node would receive them, raw) in chunks;
- :func:`blocks` gives the corrected :class:`~accel_calib_ros.core.monitor.Block` sums
  directly, drawn from their exact distribution for still and turning segments (the
  block mean of white noise is normal with σ/√n, the within-block variance is
  σ² χ²ₙ₋₁ / n): 24 hours in seconds. A move is one block of motion-sized variance
  (the detector's job there is trivial; the still periods are what the checks see).
"""

from dataclasses import dataclass, field, replace
import math

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from .motion import random_directions, simulate_static_windows
from .sensor import ak8963_like, EarthField, mpu9250_like, with_gyro_errors
from ..core.accelerometer.fit import calibrate
from ..core.calibration import MagnetometerPart
from ..core.constants import G0
from ..core.monitor.blocks import Block
from ..core.monitor.field import corrected_arrays

GYRO_DENSITY = math.radians(0.01)
"""MPU-9250 gyro noise density, rad/s/√Hz (0.01 °/s/√Hz)."""
DRIVE_VIBRATION = 0.5
"""Accelerometer vibration while driving, m/s² per sample."""


MPU9250_GYRO_LSB = math.radians(1.0 / 131.0)
"""Gyro ADC step at ±250 °/s, rad/s."""


@dataclass
class Segment:
    """One stretch of a day: still, turn, move or platform, with its pose (body to world)."""

    kind: str
    seconds: float
    pose: Rotation
    rate: float = 0.0               # turn: rad/s about world up
    to: Rotation = None             # move: the pose at the end
    accel: float = 1.5              # move: peak push, m/s²
    push: object = None             # platform: callable(tau (N,)) -> (N, 3) world m/s²


def still(pose, seconds):
    """Hold ``pose`` for ``seconds``."""
    return Segment('still', float(seconds), pose)


def turn(pose, rate, seconds):
    """Turn about gravity at ``rate`` rad/s for ``seconds``, starting at ``pose``."""
    return Segment('turn', float(seconds), pose, rate=float(rate))


def move(pose, to, seconds, accel=1.5):
    """Drive from ``pose`` to ``to`` in ``seconds``."""
    return Segment('move', float(seconds), pose, to=to, accel=float(accel))


def _ramp(tau, start, length):
    """Smooth step 0 -> 1 over [start, start + length] (raised cosine)."""
    x = np.clip((np.asarray(tau, float) - start) / length, 0.0, 1.0)
    return 0.5 - 0.5 * np.cos(np.pi * x)


def _pulse(tau, start, ramp_s, plateau_s):
    """0 -> 1 -> 0: ramps of ``ramp_s`` around a plateau of ``plateau_s``, from ``start``."""
    return _ramp(tau, start, ramp_s) - _ramp(tau, start + ramp_s + plateau_s, ramp_s)


def platform(pose, seconds, push):
    """Hold ``pose`` on a platform whose acceleration (world, m/s²) is ``push(tau)``."""
    return Segment('platform', float(seconds), pose, push=push)


def lift(pose, accel, plateau_s=3.0, cruise_s=8.0, ramp_s=0.6, up=True):
    """Ride an elevator: ``accel`` m/s² for ``plateau_s``, cruise, the same to stop."""
    one = 2.0 * ramp_s + plateau_s
    sign = 1.0 if up else -1.0

    def push(tau):
        a = _pulse(tau, 0.0, ramp_s, plateau_s) - _pulse(tau, one + cruise_s, ramp_s, plateau_s)
        return np.outer(sign * accel * a, [0.0, 0.0, 1.0])
    return platform(pose, 2.0 * one + cruise_s, push)


def van(pose, accel, plateau_s=4.0, cruise_s=10.0, ramp_s=0.8, heading=0.0):
    """Ride a vehicle: set off at ``accel`` m/s², cruise, brake at ``accel`` to a stop."""
    one = 2.0 * ramp_s + plateau_s
    direction = np.array([math.cos(heading), math.sin(heading), 0.0])

    def push(tau):
        a = _pulse(tau, 0.0, ramp_s, plateau_s) - _pulse(tau, one + cruise_s, ramp_s, plateau_s)
        return np.outer(accel * a, direction)
    return platform(pose, 2.0 * one + cruise_s, push)


def heave(pose, amplitude, freq_hz, seconds, phase=0.0):
    """Ride a ship's heave: vertical acceleration ``amplitude`` m/s² at ``freq_hz``."""
    def push(tau):
        a = amplitude * np.sin(2.0 * np.pi * freq_hz * np.asarray(tau, float) + phase)
        return np.outer(a, [0.0, 0.0, 1.0])
    return platform(pose, seconds, push)


@dataclass
class Noise:
    """
    Noise beyond the sensor's white noise (what the monitor does not assume).

    :param flicker: standard deviation of each of the accelerometer's 8 first-order
        processes (time constants 0.3 s x 4^k, up to 5000 s), m/s²: a flicker floor.
    :param gyro_flicker: the same for the gyro, rad/s.
    :param vibration: amplitude of a vibration at rest (a motor at 25-45 Hz), m/s².
    :param gyro_lsb: gyro quantisation step, rad/s (0: none).
    """

    flicker: float = 0.0
    gyro_flicker: float = 0.0
    vibration: float = 0.0
    gyro_lsb: float = 0.0


class _Flicker:
    """A sum of first-order processes per axis, continued from chunk to chunk."""

    TAUS = 0.3 * 4.0 ** np.arange(8)

    def __init__(self, sigma, dt, rng):
        from scipy.signal import lfilter
        self.lfilter = lfilter
        self.phi = np.exp(-dt / self.TAUS)
        self.gain = sigma * np.sqrt(1.0 - self.phi ** 2)
        self.state = rng.standard_normal((len(self.TAUS), 3)) * sigma

    def draw(self, n, rng):
        out = np.zeros((n, 3))
        for k, (phi, gain) in enumerate(zip(self.phi, self.gain)):
            y, zf = self.lfilter([gain], [1.0, -phi], rng.standard_normal((n, 3)), axis=0,
                                 zi=(phi * self.state[k])[None, :])
            self.state[k] = y[-1]
            out += y
        return out


@dataclass
class Events:
    """
    What happens to the sensor in the field.

    :param gyro_change: (3,) gyro bias change since the calibration, rad/s (a power-up).
    :param knocks: list of (time s, (3,) accelerometer bias step m/s²).
    :param temperature: °C, a constant or a callable of time (s).
    :param frozen: list of (start s, stop s): the sensor repeats one reading meanwhile.
    """

    gyro_change: np.ndarray = field(default_factory=lambda: np.zeros(3))
    knocks: list = field(default_factory=list)
    temperature: object = 25.0
    frozen: list = field(default_factory=list)

    def temp(self, t):
        """Return the temperature (N,) at times ``t``."""
        t = np.asarray(t, float)
        if callable(self.temperature):
            return np.asarray(self.temperature(t), float) * np.ones(len(t))
        return np.full(len(t), float(self.temperature))

    def accel_offset(self, t):
        """Return the accelerometer bias steps (N, 3) in force at times ``t``."""
        t = np.asarray(t, float)
        out = np.zeros((len(t), 3))
        for when, step in self.knocks:
            out[t >= when] += np.asarray(step, float)
        return out


@dataclass
class Rig:
    """A simulated sensor and the calibration fitted to it."""

    sensor: object
    calibration: object
    rate_hz: float
    earth: EarthField
    magnetometer: bool


def field_rig(rng, rate_hz=200.0, magnetometer=True, calib_temps=(15.0, 35.0), thermal=True,
              mag_rate_hz=100.0):
    """
    Draw an MPU-9250-like sensor and calibrate it as a user would.

    The accelerometer carries a temperature coefficient (±0.5-1.5 mg/°C); the
    calibration is an ``ml --thermal`` fit (a plain ``ml`` fit without ``thermal``) of
    240 static windows of 3 s held while the temperature ramps over ``calib_temps`` (so
    its range is that ramp). The gyro bias is measured with 0.01 °/s error, its T and
    the magnetometer part (``mag_rate_hz``: 100 Hz, or the AK8963's 8 Hz) are the truth.

    :returns: :class:`Rig`.
    """
    sensor = mpu9250_like(rng, rate_hz, effects=('temperature_bias',))
    sensor = with_gyro_errors(sensor, rng)
    sensor.gyro_noise_std = np.full(3, GYRO_DENSITY * math.sqrt(rate_hz / 2.0))
    if magnetometer:
        sensor.magnetometer = ak8963_like(rng)
        sensor.magnetometer.rate_hz = float(mag_rate_hz)
    n = 240
    lo, hi = calib_temps
    hold = 3.0
    windows = simulate_static_windows(
        sensor, random_directions(n, rng), rng, hold_s=hold, count=int(hold * rate_hz),
        temperature=lambda t: lo + (hi - lo) * t / (n * hold))
    cal = calibrate(windows.mean, G0, 'ml', weights=windows.count, temps=windows.temp,
                    thermal=thermal, noise_std=sensor.noise_std)
    cal.gyro_bias = sensor.gyro_bias + rng.standard_normal(3) * math.radians(0.01)
    cal.gyro_T = sensor.gyro_T.copy()
    cal.gyro_predicted_accuracy = 0.003
    earth = EarthField()
    if magnetometer:
        mag = sensor.magnetometer
        cal.magnetometer = MagnetometerPart(mag.T, mag.hard_iron, mag.R, earth.field_uT,
                                            earth.dip_deg, 0.05, float(mag.noise_std[0]))
    return Rig(sensor, cal, float(rate_hz), earth, magnetometer)


def random_pose(rng, tilt_deg=180.0):
    """Draw a pose with a random heading, tilted from upright by up to ``tilt_deg``."""
    axis = rng.standard_normal(2)
    axis = np.r_[axis / np.linalg.norm(axis), 0.0]
    tilt = math.radians(tilt_deg) * math.sqrt(rng.uniform()) if tilt_deg < 180.0 else None
    yaw = Rotation.from_rotvec([0.0, 0.0, rng.uniform(-math.pi, math.pi)])
    if tilt is None:
        return Rotation.random(random_state=int(rng.integers(2 ** 31)))
    return yaw * Rotation.from_rotvec(axis * tilt)


def _schedule(segments):
    t, out = 0.0, []
    for seg in segments:
        out.append((t, seg))
        t += seg.seconds
    return out


def _truth(seg, tau, rate_hz, g):
    """Body rotations (Rotation of len(tau)), true accel (N, 3), true rate (N, 3) of a segment."""
    up = np.array([0.0, 0.0, g])
    n = len(tau)
    if seg.kind == 'still':
        rot = Rotation.concatenate([seg.pose] * n) if n > 1 else seg.pose * Rotation.identity(1)
        accel = np.tile(seg.pose.inv().apply(up), (n, 1))
        return rot, accel, np.zeros((n, 3))
    if seg.kind == 'turn':
        rot = Rotation.from_rotvec(np.outer(seg.rate * tau, [0.0, 0.0, 1.0])) * seg.pose
        accel = np.tile(seg.pose.inv().apply(up), (n, 1))
        rate = np.tile(seg.pose.inv().apply([0.0, 0.0, seg.rate]), (n, 1))
        return rot, accel, rate
    if seg.kind == 'platform':
        rot = Rotation.concatenate([seg.pose] * n) if n > 1 else seg.pose * Rotation.identity(1)
        return rot, seg.pose.inv().apply(up + seg.push(tau)), np.zeros((n, 3))
    s = np.clip(tau / seg.seconds, 0.0, 1.0)
    slerp = Slerp([0.0, 1.0], Rotation.concatenate([seg.pose, seg.to]))
    rot = slerp(s)
    world_rate = (seg.to * seg.pose.inv()).as_rotvec() / seg.seconds
    push = np.sin(np.pi * s)[:, None] * seg.accel * np.array([1.0, 0.0, 0.0])
    accel = rot.inv().apply(up + push)
    return rot, accel, rot.inv().apply(np.tile(world_rate, (n, 1)))


def stream(rig, segments, events, rng, chunk_s=10.0, noise=None):
    """
    Yield the raw samples of a day in chunks, as the driver would publish them.

    :param noise: :class:`Noise` beyond the white noise, or None.
    :returns: generator of dicts: t (N,), accel (N, 3) m/s², gyro (N, 3) rad/s, temp (N,),
        mag (N, 3) µT with NaN rows between magnetometer samples (None without one),
        true_rate (N, 3) rad/s, kind (the segment kind).
    """
    sensor, dt = rig.sensor, 1.0 / rig.rate_hz
    mag = sensor.magnetometer if rig.magnetometer else None
    field_world = rig.earth.world()
    bias = sensor.gyro_bias + np.asarray(events.gyro_change, float)
    noise = noise or Noise()
    flicker = _Flicker(noise.flicker, dt, rng) if noise.flicker > 0 else None
    gyro_flicker = _Flicker(noise.gyro_flicker, dt, rng) if noise.gyro_flicker > 0 else None
    motor = (rng.uniform(25.0, 45.0, 3), rng.uniform(0.0, 2 * np.pi, 3))
    held = {}
    for start, seg in _schedule(segments):
        total = int(round(seg.seconds * rig.rate_hz))
        for a in range(0, total, int(chunk_s * rig.rate_hz)):
            b = min(total, a + int(chunk_s * rig.rate_hz))
            tau = np.arange(a, b) * dt
            t = start + tau
            rot, accel_true, rate_true = _truth(seg, tau, rig.rate_hz, G0)
            temp = events.temp(t)
            offset = events.accel_offset(t)
            if flicker is not None:
                offset = offset + flicker.draw(len(t), rng)
            if noise.vibration > 0:
                accel_true = accel_true + noise.vibration * np.sin(
                    2 * np.pi * np.outer(t, motor[0]) + motor[1])
            raw = sensor.measure(accel_true, rng, temp, None, offset)
            if seg.kind == 'move':
                raw = raw + rng.standard_normal(raw.shape) * DRIVE_VIBRATION
            gyro = rate_true @ sensor.gyro_T.T + bias \
                + rng.standard_normal((len(t), 3)) * sensor.gyro_noise_std
            if gyro_flicker is not None:
                gyro = gyro + gyro_flicker.draw(len(t), rng)
            if noise.gyro_lsb > 0:
                gyro = np.round(gyro / noise.gyro_lsb) * noise.gyro_lsb
            for k, (t0, t1) in enumerate(events.frozen):
                inside = (t >= t0) & (t < t1)
                if inside.any():
                    first = int(np.argmax(inside))
                    value = held.setdefault(k, (raw[first].copy(), gyro[first].copy()))
                    raw[inside], gyro[inside] = value
            m = None
            if mag is not None:
                body = rot.inv().apply(field_world)
                m = mag.distort(body) + rng.standard_normal(body.shape) * mag.noise_std
                tick = np.floor(t * mag.rate_hz + 1e-9)
                m[tick == np.floor((t - dt) * mag.rate_hz + 1e-9)] = np.nan
            yield {'t': t, 'accel': raw, 'gyro': gyro, 'temp': temp, 'mag': m,
                   'true_rate': rate_true, 'kind': seg.kind}


def recording(rig, segments, events, rng, noise=None):
    """Return a whole simulated recording as raw ``Samples`` (t, accel, temp, gyro, mag)."""
    from ..core.samples import Samples
    chunks = list(stream(rig, segments, events, rng, chunk_s=30.0, noise=noise))

    def cat(key):
        return None if chunks[0][key] is None else np.concatenate([c[key] for c in chunks])
    return Samples(cat('t'), cat('accel'), cat('temp'), cat('gyro'), cat('mag'))


def blocks(rig, segments, events, rng, block_s=0.1):
    """
    Yield corrected Blocks of a day directly (fast; see the module docstring).

    :returns: generator of (Block, kind).
    """
    sensor, cal = rig.sensor, rig.calibration
    n = max(int(round(block_s * rig.rate_hz)), 2)
    mag = sensor.magnetometer if rig.magnetometer else None
    m_n = 0 if mag is None else max(int(round(block_s * mag.rate_hz)), 2)
    field_world = rig.earth.world()
    bias = sensor.gyro_bias + np.asarray(events.gyro_change, float)
    for start, seg in _schedule(segments):
        if seg.kind == 'move':
            t = np.array([start + 0.5 * seg.seconds])
            moving = Block(n, t[0], seg.seconds, np.array([0.0, 0.0, G0]),
                           np.full(3, DRIVE_VIBRATION ** 2), np.zeros(3),
                           np.full(3, 0.1), float(events.temp(t)[0]))
            yield moving, 'move'
            continue
        count = max(int(seg.seconds / block_s), 1)
        tau = (np.arange(count) + 0.5) * block_s
        t = start + tau
        rot, accel_true, rate_true = _truth(seg, tau, rig.rate_hz, G0)
        temp = events.temp(t)
        raw = sensor.distort(accel_true, temp) + events.accel_offset(t)
        raw += rng.standard_normal(raw.shape) * sensor.noise_std / math.sqrt(n)
        gyro = rate_true @ sensor.gyro_T.T + bias \
            + rng.standard_normal(raw.shape) * sensor.gyro_noise_std / math.sqrt(n)
        m = None
        if mag is not None:
            body = rot.inv().apply(field_world)
            m = mag.distort(body) + rng.standard_normal(body.shape) * mag.noise_std \
                / math.sqrt(m_n)
        ca, cg, cm = corrected_arrays(cal, raw, gyro, temp, m)
        a_var = sensor.noise_std ** 2 * rng.chisquare(n - 1, (count, 3)) / n
        g_var = sensor.gyro_noise_std ** 2 * rng.chisquare(n - 1, (count, 3)) / n
        m_var = None if mag is None else \
            mag.noise_std ** 2 * rng.chisquare(m_n - 1, (count, 3)) / m_n
        for k in range(count):
            yield Block(n, t[k], block_s, ca[k], a_var[k], cg[k], g_var[k], temp[k],
                        m_n, None if cm is None else cm[k],
                        None if m_var is None else m_var[k]), seg.kind


def with_gyro_noise(rig, density):
    """Return a copy of ``rig`` whose gyro has another noise density, rad/s/√Hz."""
    sensor = replace(rig.sensor, gyro_noise_std=np.full(3, density
                                                        * math.sqrt(rig.rate_hz / 2.0)))
    return replace(rig, sensor=sensor)
