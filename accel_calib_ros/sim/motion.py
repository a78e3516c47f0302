"""
Simulated calibration sessions: poses, holds and moves of a simulated sensor.

A session holds the sensor still in a sequence of orientations (``directions``: the
gravity direction in the body frame, i.e. the axis pointing up) for ``hold_s`` and
turns it between them over ``move_s`` (a smooth rotation with a little hand wobble),
sampling every channel of the sensor model (``sensor``) on the way: ``iter_session``
streams it in chunks, ``simulate_session`` returns it whole, and
``simulate_window_means`` / ``simulate_static_windows`` skip the samples and give the
window means directly (the model-gap benchmarks). The die temperature's lag and the
offset's random walk need the session's history, so they act here.
"""

from dataclasses import dataclass
from typing import Optional
import warnings

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from .sensor import EarthField, measure_mag, SensorModel
from ..core.constants import G0
from ..core.samples import Samples


def random_directions(n, rng):
    """``n`` unit vectors uniformly distributed on the sphere, shape (n, 3)."""
    v = rng.standard_normal((n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def face_directions():
    """Return the six-face session directions: ±x, ±y, ±z up, shape (6, 3)."""
    return np.vstack([np.eye(3), -np.eye(3)])[[0, 3, 1, 4, 2, 5]]


def sun_xu_directions(n, rng, amplitude_deg=(120.0, 120.0, 80.0)):
    """
    Gravity directions of Sun & Xu's simulation (Euler angles x U(-1, 1)).

    Pitch, roll and heading amplitudes 120°, 120°, 80°, each multiplied by a uniform
    random number; gravity (0, 0, 1) in the navigation frame rotated into the body.

    :returns: (n, 3) unit vectors.
    """
    angles = rng.uniform(-1, 1, (n, 3)) * np.asarray(amplitude_deg)
    rot = Rotation.from_euler('yxz', angles, degrees=True)
    return rot.inv().apply([0.0, 0.0, 1.0])


def _rotation_to(direction):
    """Rotation R (body to world) with R^T e_z = direction, for each row."""
    d = np.atleast_2d(direction)
    rots, _ = zip(*[_align_z(row) for row in d])
    return Rotation.concatenate(rots)


def _align_z(direction):
    """Return ``Rotation.align_vectors`` of e_z onto one direction, quietly (one pair)."""
    with warnings.catch_warnings():
        # scipy < 1.12 warns that one vector pair leaves the rotation about it undefined:
        # any such rotation serves here (the pose is defined by its gravity direction).
        warnings.simplefilter('ignore', UserWarning)
        return Rotation.align_vectors([[0.0, 0.0, 1.0]], [direction])


CHUNK_ROWS = 1 << 16
"""Rows generated at a time by ``iter_session`` (bounds its memory; fixes its draws)."""


@dataclass
class Session:
    """
    A simulated calibration session: samples plus the truth behind them.

    ``pose`` is the index of the held pose for each sample, -1 while moving. The
    truth: ``sensor`` (accelerometer, gyroscope and magnetometer errors), ``gravity``
    (m/s²), ``true_accel`` (N, 3) specific force (m/s²), ``true_rate`` (N, 3) body rate
    (rad/s, held from each sample to the next: integrating it sample by sample gives
    the simulated orientations exactly), ``earth_field`` and ``true_field`` (N, 3) the
    field in the body frame, µT (None without a magnetometer).
    """

    samples: Samples
    true_accel: np.ndarray
    pose: np.ndarray
    directions: np.ndarray
    sensor: SensorModel
    gravity: float
    true_rate: Optional[np.ndarray] = None
    earth_field: Optional[EarthField] = None
    true_field: Optional[np.ndarray] = None


def _segments(n_pose, holds, move_s, rate_hz):
    """Return the session script: (pose index, move?, samples) per segment, in order."""
    out = []
    for k in range(n_pose):
        if k > 0:
            out.append((k, True, max(int(round(move_s * rate_hz)), 2)))
        out.append((k, False, max(int(round(holds[k] * rate_hz)), 1)))
    return out


def _poses(directions):
    """Return ``directions`` as a stack of Rotations when it holds poses, else None."""
    if not isinstance(directions, Rotation):
        return None
    return directions if not directions.single else Rotation.concatenate([directions])


def random_poses(n, rng):
    """
    ``n`` orientations (body to world) uniformly distributed over all rotations.

    Poses for ``simulate_session`` that fix the heading too, so that sessions do not
    depend on how scipy's ``align_vectors`` picks the rotation about gravity.

    :returns: Rotation of length n.
    """
    return Rotation.from_quat(rng.standard_normal((n, 4)))


def session_length(directions, hold_s=3.0, move_s=1.5, rate_hz=100.0):
    """Return the number of samples ``simulate_session`` gives for these arguments."""
    poses = _poses(directions)
    n_pose = len(poses) if poses is not None else len(
        np.asarray(directions, float).reshape(-1, 3))
    holds = np.broadcast_to(np.asarray(hold_s, float), (n_pose,))
    return sum(n for _, _, n in _segments(n_pose, holds, move_s, rate_hz))


def iter_session(sensor, directions, rng, hold_s=3.0, move_s=1.5, rate_hz=100.0,
                 gravity=G0, temperature=25.0, motion_accel=1.5, lead_s=None,
                 chunk_rows=CHUNK_ROWS, earth_field=None, tremor_deg=0.0):
    """
    Simulate a session piece by piece, in bounded memory (see ``simulate_session``).

    Same arguments as ``simulate_session``. Yields ``Session`` objects of at most
    about ``chunk_rows`` samples each, in time order; their concatenation is the
    session ``simulate_session`` returns for the same random generator state. The
    draws do not depend on ``chunk_rows`` (only on the fixed ``CHUNK_ROWS``).

    :returns: generator of Session.
    """
    poses = _poses(directions)
    if poses is not None:                   # full orientations, body to world
        directions = poses.inv().apply([0.0, 0.0, 1.0]).reshape(-1, 3)
    directions = np.asarray(directions, float).reshape(-1, 3)
    directions = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    n_pose = len(directions)
    holds = np.broadcast_to(np.asarray(hold_s, float), (n_pose,))
    dt = 1.0 / rate_hz
    rots = _rotation_to(directions) if poses is None else poses
    segments = _segments(n_pose, holds, move_s, rate_hz)
    total = sum(n for _, _, n in segments)
    if callable(temperature):
        def temp_at(t):
            return np.asarray(temperature(t), float) * np.ones(len(t))
    elif np.ndim(temperature) == 0:
        def temp_at(t):
            return np.full(len(t), float(temperature))
    else:
        start, end = temperature

        def temp_at(t):
            return start + (end - start) * t / max((total - 1) * dt, dt)
    up = np.array([0.0, 0.0, gravity])
    die = _DieTemperature(getattr(sensor, 'thermal_lag_s', 0.0), dt)
    walk = _RandomWalk(getattr(sensor, 'bias_random_walk', np.zeros(3)), dt)
    gradient = _Gradient(sensor, dt)
    gyro_tempco = np.asarray(getattr(sensor, 'gyro_bias_tempco', np.zeros(3)), float)
    gyro_bias = np.asarray(getattr(sensor, 'gyro_bias', np.zeros(3)), float)  # raw = true + b
    gyro_noise = np.asarray(getattr(sensor, 'gyro_noise_std', 0.002), float)  # rad/s
    gyro_T = np.asarray(getattr(sensor, 'gyro_T', np.eye(3)), float)
    scaled = not np.array_equal(gyro_T, np.eye(3))
    full_scale = float(getattr(sensor, 'gyro_full_scale', float('inf')))
    gyro_lsb = float(getattr(sensor, 'gyro_lsb', 0.0))
    mag = getattr(sensor, 'magnetometer', None)
    if mag is not None and earth_field is None:
        earth_field = EarthField()
    # The new effects draw from their own generator, spawned only when they are on, so
    # that switching them off leaves every other draw (and the session) unchanged.
    extra = _spawn(rng) if (mag is not None or tremor_deg > 0) else None
    reported = _ReportedTemperature(sensor, rng)
    wobble = _Wobble(segments, tremor_deg, extra) if tremor_deg > 0 else None

    def hold_rotation(index, k, i):
        """Rotation of held pose ``k`` (segment ``index``) at its sample indices ``i``."""
        return rots[k] * Rotation.from_rotvec(wobble(index, i))

    pieces, rows = [], 0
    first = 0
    gyro_world_last = np.zeros(3)
    for index, (k, moving, n) in enumerate(segments):
        if moving:
            s = (np.arange(n) + 1) / (n + 1)
            slerp = Slerp([0.0, 1.0], Rotation.concatenate([rots[k - 1], rots[k]]))
            axis = rng.standard_normal(3)
            axis = motion_accel * axis / np.linalg.norm(axis)
        for a in range(0, n, CHUNK_ROWS):
            b = min(a + CHUNK_ROWS, n)
            m = b - a
            t = (first + np.arange(a, b)) * dt
            if b < n:
                after = slerp(s[b]) if moving else None
                if wobble is not None and not moving:
                    after = hold_rotation(index, k, np.array([b]))[0]
            elif index + 1 < len(segments):     # the first rotation of the next segment
                k_next, move_next, n_next = segments[index + 1]
                after = rots[k_next]
                if wobble is not None and not move_next:
                    after = hold_rotation(index + 1, k_next, np.array([0]))[0]
                if move_next:
                    pair = Rotation.concatenate([rots[k_next - 1], rots[k_next]])
                    after = Slerp([0.0, 1.0], pair)(1.0 / (n_next + 1))
            else:
                after = None
            gyro_world = np.zeros((m, 3))
            if moving:
                rot = slerp(s[a:b])
                inverse = rot.inv()
                world = up + np.sin(np.pi * s[a:b])[:, None] * axis
                true_accel = inverse.apply(world)
                if m > 1:
                    gyro_world[:-1] = (rot[1:] * inverse[:-1]).as_rotvec() / dt
                last = rot[-1]
            elif wobble is not None:            # held by a trembling hand
                rot = hold_rotation(index, k, np.arange(a, b))
                inverse = rot.inv()
                true_accel = inverse.apply(up)
                if m > 1:
                    gyro_world[:-1] = (rot[1:] * inverse[:-1]).as_rotvec() / dt
                last = rot[-1]
            else:                               # held still: one rotation, no turn rate
                inverse = rots[k].inv()
                true_accel = np.tile(inverse.apply(up), (m, 1))
                last = rots[k]
            if after is not None:
                gyro_world[-1] = (after * last.inv()).as_rotvec() / dt
            elif b == n and index + 1 == len(segments):  # the very last sample
                gyro_world[-1] = gyro_world[-2] if m > 1 else gyro_world_last
            gyro_world_last = gyro_world[-1]
            true_rate = inverse.apply(gyro_world)
            gyro = (true_rate @ gyro_T.T if scaled else true_rate) \
                + rng.standard_normal((m, 3)) * gyro_noise
            gyro += gyro_bias
            temp = temp_at(t)
            theta = die(temp)
            if np.any(gyro_tempco):
                gyro += (theta - sensor.temp_ref)[:, None] * gyro_tempco
            if gyro_lsb > 0:
                gyro = np.round(gyro / gyro_lsb) * gyro_lsb
            if np.isfinite(full_scale):
                np.clip(gyro, -full_scale, full_scale, out=gyro)
            raw = sensor.measure(true_accel, rng, theta, t, gradient(temp, walk(m, rng)))
            temp = reported(temp)
            pose = np.full(m, -1 if moving else k)
            field_body = raw_mag = None
            if mag is not None:
                field_body = np.broadcast_to(inverse.apply(earth_field.world()), (m, 3))
                raw_mag = measure_mag(mag, field_body, t, dt, extra)
            pieces.append((t, raw, temp, gyro, true_accel, pose, true_rate, field_body,
                           raw_mag))
            rows += m
            if rows >= chunk_rows:
                yield _join(pieces, directions, sensor, gravity, earth_field)
                pieces, rows = [], 0
        first += n
    if pieces:
        yield _join(pieces, directions, sensor, gravity, earth_field)


class _DieTemperature:
    """First-order lag of the reported temperature, sample by sample, across chunks."""

    def __init__(self, tau, dt):
        self.decay = float(np.exp(-dt / tau)) if tau > 0 else 0.0
        self.state = None

    def __call__(self, temp):
        """Return the die temperature for the next samples of the reported one."""
        if self.decay == 0.0:
            return temp
        from scipy import signal
        if self.state is None:                 # in equilibrium at the start
            self.state = float(temp[0])
        a = self.decay
        out, _ = signal.lfilter([1.0 - a], [1.0, -a], temp, zi=[a * self.state])
        self.state = float(out[-1])
        return out


class _Gradient:
    """
    The offset of a temperature gradient across the package, across chunks.

    The gradient is the reported temperature minus its first-order lag (``gradient_tau_s``):
    about tau times the rate of temperature change, positive while heating; the offset is
    ``bias_gradient`` times it (0 at the start: in equilibrium).
    """

    def __init__(self, sensor, dt):
        self.k = np.asarray(getattr(sensor, 'bias_gradient', np.zeros(3)), float)
        self.lag = _DieTemperature(float(getattr(sensor, 'gradient_tau_s', 60.0)), dt) \
            if np.any(self.k) else None

    def __call__(self, temp, offset=None):
        """Return ``offset`` (m, 3) or None, plus the gradient's offset for ``temp`` (m,)."""
        if self.lag is None:
            return offset
        extra = (temp - self.lag(temp))[:, None] * self.k
        return extra if offset is None else offset + extra


class _ReportedTemperature:
    """The temperature as the sensor reports it: noise and its step (own random stream)."""

    def __init__(self, sensor, rng):
        self.std = float(getattr(sensor, 'temp_noise_std', 0.0))
        self.lsb = float(getattr(sensor, 'temp_lsb', 0.0))
        self.rng = _spawn(rng) if self.std > 0 else None

    def __call__(self, temp):
        if self.rng is not None:
            temp = temp + self.rng.standard_normal(len(temp)) * self.std
        if self.lsb > 0:
            temp = np.round(temp / self.lsb) * self.lsb
        return temp


class _RandomWalk:
    """Random walk of the offset, sample by sample, across chunks (0 at the start)."""

    def __init__(self, k, dt):
        self.step = np.asarray(k, float) * np.sqrt(dt)
        self.state = np.zeros(3)

    def __call__(self, m, rng):
        """Return the offset (m, 3) for the next m samples, or None when switched off."""
        if not np.any(self.step):
            return None
        path = self.state + np.cumsum(rng.standard_normal((m, 3)) * self.step, axis=0)
        self.state = path[-1]
        return path


def _join(pieces, directions, sensor, gravity, earth_field=None):
    """Concatenate (t, raw, temp, gyro, true_accel, pose, ...) pieces into one Session."""
    (t, raw, temp, gyro, true_accel, pose, true_rate, field_body, raw_mag) = (
        None if column[0] is None else np.concatenate(column) if len(pieces) > 1
        else column[0] for column in zip(*pieces))
    return Session(Samples(t, raw, temp, gyro, raw_mag), true_accel, pose, directions,
                   sensor, gravity, true_rate, earth_field,
                   None if field_body is None else np.array(field_body))


def _spawn(rng):
    """Return a child generator of ``rng`` that leaves ``rng``'s own stream untouched."""
    try:
        return rng.spawn(1)[0]
    except (AttributeError, TypeError, ValueError):     # numpy < 1.25 or no SeedSequence
        return np.random.default_rng(rng.bit_generator.random_raw())


class _Wobble:
    """
    Hand tremor during holds: a small smooth rotation that vanishes at both ends.

    For hold segment ``index`` of n samples, the wobble rotation vector (body frame)
    at sample i is ``sum_j c_j sin(pi j s)`` with ``s = (i + 1) / (n + 1)``, j = 1..3,
    ``c_j`` ~ N(0, (amp / j)²) per axis; ``amp`` makes the RMS wobble angle
    ``tremor_deg``. All coefficients are drawn up front (chunk-independent).
    """

    MODES = 3

    def __init__(self, segments, tremor_deg, rng):
        self.n = [n for _, _, n in segments]
        j = np.arange(1, self.MODES + 1)
        amp = np.radians(tremor_deg) / np.sqrt(1.5 * np.sum(1.0 / j ** 2))
        self.coef = rng.standard_normal((len(segments), self.MODES, 3)) \
            * (amp / j)[None, :, None]
        self.j = j

    def __call__(self, index, i):
        s = (np.asarray(i, float) + 1.0) / (self.n[index] + 1.0)
        return np.sin(np.pi * np.outer(s, self.j)) @ self.coef[index]


def simulate_session(sensor, directions, rng, hold_s=3.0, move_s=1.5, rate_hz=100.0,
                     gravity=G0, temperature=25.0, motion_accel=1.5, lead_s=None,
                     earth_field=None, tremor_deg=0.0):
    """
    Simulate someone turning the sensor through a sequence of held poses.

    The whole session in memory; ``iter_session`` gives the same in pieces.

    :param sensor: SensorModel that produces the raw readings.
    :param directions: (P, 3) unit gravity directions in the body frame, one per pose
        (the rotation about gravity is scipy's choice), or a Rotation of P poses (body
        to world, world z up) that fixes it (e.g. ``random_poses``).
    :param rng: numpy Generator.
    :param hold_s: seconds each pose is held still (scalar or (P,) array).
    :param move_s: seconds each move between poses takes.
    :param rate_hz: sample rate, Hz.
    :param gravity: local gravity magnitude, m/s².
    :param temperature: °C; a constant, a (start, end) pair for a linear ramp over
        the session, or a callable of time in seconds.
    :param motion_accel: peak hand acceleration during a move, m/s².
    :param lead_s: still time before the first pose is reached (default ``hold_s``).
    :param earth_field: EarthField the magnetometer sees (default ``EarthField()``,
        48 µT at 60° dip); used only when ``sensor.magnetometer`` is set.
    :param tremor_deg: RMS angle by which a trembling hand turns the sensor while it
        holds a pose, degrees (0: held perfectly still). The wobble vanishes at the
        ends of each hold; accelerometer and gyroscope see it consistently.
    :returns: Session.
    """
    parts = list(iter_session(sensor, directions, rng, hold_s, move_s, rate_hz, gravity,
                              temperature, motion_accel, lead_s, chunk_rows=1 << 62,
                              earth_field=earth_field, tremor_deg=tremor_deg))
    return parts[0]


def simulate_window_means(sensor, directions, n_samples, rng, gravity=G0, temp=None, t=None,
                          offset=None):
    """
    Window means of static poses directly, without simulating every sample.

    :param directions: (N, 3) unit gravity directions.
    :param n_samples: (N,) samples averaged in each window.
    :param temp: (N,) window (die) temperatures, °C; ``t``: (N,) window mid times, s.
    :param offset: (N, 3) extra offset of each window (a random walk), m/s², or None.
    :returns: (N, 3) mean raw readings, m/s² (noise std / sqrt(n); no quantisation).
    """
    directions = np.asarray(directions, float).reshape(-1, 3)
    raw = sensor.distort(gravity * directions, temp, t)
    if offset is not None:
        raw = raw + offset
    n = np.broadcast_to(np.asarray(n_samples, float), (len(directions),))
    return raw + rng.standard_normal(raw.shape) * sensor.noise_std / np.sqrt(n)[:, None]


def simulate_static_windows(sensor, directions, rng, hold_s=3.5, count=250, gravity=G0,
                            temperature=25.0):
    """
    Simulate the static windows of a session directly (no sample stream): fast.

    :param directions: (N, 3) unit gravity directions, one window each, held in turn.
    :param hold_s: time per pose, s (window mid times are (k + 0.5) x hold_s).
    :param count: samples averaged per window.
    :param temperature: °C, a constant or a callable of time in seconds.
    :returns: StaticWindows with the sensor's noise as the within-window scatter.
    """
    from ..core.windows import StaticWindows
    n = len(directions)
    t = (np.arange(n) + 0.5) * hold_s
    temp = np.asarray(temperature(t), float) if callable(temperature) \
        else np.full(n, float(temperature))
    counts = np.full(n, int(count))
    die = temp
    lag = float(getattr(sensor, 'thermal_lag_s', 0.0))
    if lag > 0 and callable(temperature):
        # The die temperature: the reported one lagged, on a grid fine against tau.
        dt = min(hold_s / 10.0, lag / 20.0)
        fine = np.arange(0.0, t[-1] + dt, dt)
        die = np.interp(t, fine, _DieTemperature(lag, dt)(
            np.asarray(temperature(fine), float) * np.ones(len(fine))))
    offset = None
    k = np.asarray(getattr(sensor, 'bias_random_walk', np.zeros(3)), float)
    if np.any(k):
        steps = rng.standard_normal((n, 3)) * k * np.sqrt(np.diff(t, prepend=0.0))[:, None]
        offset = np.cumsum(steps, axis=0)
    if np.any(getattr(sensor, 'bias_gradient', 0.0)) and callable(temperature):
        tau = float(sensor.gradient_tau_s)
        dt = min(hold_s / 10.0, tau / 20.0)
        fine = np.arange(0.0, t[-1] + dt, dt)
        reported = np.asarray(temperature(fine), float) * np.ones(len(fine))
        lagged = np.interp(t, fine, _DieTemperature(tau, dt)(reported))
        extra = (temp - lagged)[:, None] * sensor.bias_gradient
        offset = extra if offset is None else offset + extra
    mean = simulate_window_means(sensor, directions, counts, rng, gravity, die, t, offset)
    return StaticWindows(np.zeros(n, int), counts, mean, np.tile(sensor.noise_std, (n, 1)),
                         counts, t, temp)
