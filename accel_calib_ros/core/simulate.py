"""
Simulated MEMS accelerometer and calibration sessions.

The forward model, for true specific force ``a`` (m/s², body frame), temperature
``theta`` (°C) and time ``t`` (s)::

    s      = diag(1 + scale_tempco * (theta - temp_ref)) @ T @ a
    raw_i  = s_i + nonlinearity_i * s_i**2 / g0
             + bias_i + bias_tempco_i * (theta - temp_ref) + bias_drift_i * t
             + w_i(t) + noise, then quantised to the ADC step.

``theta`` is the die temperature: the reported temperature itself, or, with
``thermal_lag_s`` > 0, its first-order lag (the die warms up minutes behind the
temperature sensor). ``w(t)`` is a random walk of the offset (``bias_random_walk``,
m/s² per √s), zero unless switched on. Both need the session's history, so they act
in ``iter_session``/``simulate_session`` and ``simulate_static_windows``, not in
``distort``.

``T`` is upper triangular (scale times non-orthogonality, Sun & Xu eq. 1-4).
Each physical effect has its own field and is off when that field is zero, so
effects can be switched on one at a time (the model-gap workflow relies on it).
"""

from dataclasses import dataclass, field, replace
import warnings

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from .samples import Samples

G0 = 9.80665
"""Standard gravity, m/s²."""

MPU9250_LSB = G0 / 16384.0
"""Accelerometer ADC step at ±2 g, m/s² per count."""


def _vec3(value):
    return np.broadcast_to(np.asarray(value, dtype=float), (3,)).copy()


@dataclass
class SensorModel:
    """
    True error parameters of a simulated accelerometer.

    :param T: (3, 3) upper-triangular scale x non-orthogonality, raw = T @ true + bias.
    :param bias: (3,) zero-g offset at ``temp_ref``, m/s².
    :param noise_std: (3,) white noise per sample, m/s².
    :param lsb: ADC quantisation step, m/s² (0 disables quantisation).
    :param nonlinearity: (3,) quadratic scale term, fraction of reading per g (0.005 = 0.5 %).
    :param bias_tempco: (3,) offset drift, m/s² per °C.
    :param scale_tempco: (3,) scale drift, 1 per °C.
    :param bias_drift: (3,) offset change with time, m/s² per s.
    :param temp_ref: reference temperature of ``T`` and ``bias``, °C.
    :param gyro_bias: (3,) gyroscope offset, rad/s (raw rate = true + gyro_bias).
    :param gyro_noise_std: (3,) gyroscope white noise per sample, rad/s.
    :param thermal_lag_s: time constant of the die temperature behind the reported one,
        s (0: none): the temperature effects follow the lagged temperature.
    :param bias_random_walk: (3,) random walk of the offset, m/s² per √s (0: none).
    """

    T: np.ndarray = field(default_factory=lambda: np.eye(3))
    bias: np.ndarray = field(default_factory=lambda: np.zeros(3))
    noise_std: np.ndarray = field(default_factory=lambda: np.full(3, 0.02))
    lsb: float = 0.0
    nonlinearity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    bias_tempco: np.ndarray = field(default_factory=lambda: np.zeros(3))
    scale_tempco: np.ndarray = field(default_factory=lambda: np.zeros(3))
    bias_drift: np.ndarray = field(default_factory=lambda: np.zeros(3))
    temp_ref: float = 25.0
    gyro_bias: np.ndarray = field(default_factory=lambda: np.zeros(3))
    gyro_noise_std: np.ndarray = field(default_factory=lambda: np.full(3, 0.002))
    thermal_lag_s: float = 0.0
    bias_random_walk: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self):
        self.T = np.asarray(self.T, dtype=float).reshape(3, 3)
        for name in ('bias', 'noise_std', 'nonlinearity', 'bias_tempco',
                     'scale_tempco', 'bias_drift', 'gyro_noise_std', 'bias_random_walk'):
            setattr(self, name, _vec3(getattr(self, name)))
        self.thermal_lag_s = float(self.thermal_lag_s)

    def with_effects(self, **fields):
        """Return a copy with some fields replaced (switch effects on or off)."""
        return replace(self, **fields)

    def distort(self, true_accel, temp=None, t=None):
        """
        Noise-free raw reading for true specific force.

        :param true_accel: (N, 3) true specific force, m/s².
        :param temp: (N,) temperature, °C (default ``temp_ref``).
        :param t: (N,) time, s (default 0).
        :returns: (N, 3) raw reading, m/s².
        """
        a = np.atleast_2d(np.asarray(true_accel, dtype=float))
        n = len(a)
        dtheta = np.zeros(n) if temp is None else np.asarray(temp, float) - self.temp_ref
        time = np.zeros(n) if t is None else np.asarray(t, float)
        s = a @ self.T.T
        s = s * (1.0 + dtheta[:, None] * self.scale_tempco)
        raw = s + self.nonlinearity * s ** 2 / G0
        raw = raw + self.bias + dtheta[:, None] * self.bias_tempco
        raw = raw + time[:, None] * self.bias_drift
        return raw

    def measure(self, true_accel, rng, temp=None, t=None, offset=None):
        """
        Noisy, quantised raw reading (as ``distort`` plus noise and ADC step).

        :param offset: (N, 3) extra offset before the noise (the random walk), m/s².
        """
        raw = self.distort(true_accel, temp, t)
        if offset is not None:
            raw = raw + offset
        raw = raw + rng.standard_normal(raw.shape) * self.noise_std
        if self.lsb > 0:
            raw = np.round(raw / self.lsb) * self.lsb
        return raw


def mpu9250_like(rng, rate_hz=100.0, effects=()):
    """
    Draw a sensor with MPU-9250 datasheet error magnitudes.

    Scale ±3 %, cross-axis ±2 %, zero-g offset ±60 mg (x, y) / ±80 mg (z), noise
    300 µg/√Hz over a bandwidth of rate/2, ±2 g quantisation. Effects beyond the
    calibration model are off unless named in ``effects``: ``scale_nonlinearity``
    (±0.5 %), ``temperature_bias`` (±1.5 mg/°C), ``temperature_scale``
    (±0.026 %/°C), ``bias_drift`` (±0.2 mg/min), ``temperature_lag`` (the offset's
    ±1.5 mg/°C driven by a die temperature 1-5 minutes behind the reported one),
    ``bias_random_walk`` (±0.05-0.2 mg/√s). ``nonorthogonality`` is always on (it is part
    of T); pass ``orthogonal=True`` semantics by zeroing it yourself.

    :returns: SensorModel.
    """
    def pm(scale):
        return rng.uniform(-1, 1, 3) * scale

    def signed(low, high):
        return rng.uniform(low, high, 3) * rng.choice([-1.0, 1.0], 3)

    T = np.diag(1.0 + pm(0.03))
    T[np.triu_indices(3, 1)] = pm(0.02)
    model = SensorModel(
        T=T,
        bias=np.array([0.06, 0.06, 0.08]) * G0 * rng.uniform(-1, 1, 3),
        noise_std=np.full(3, 300e-6 * G0 * np.sqrt(rate_hz / 2.0)),
        lsb=MPU9250_LSB)
    # Gyro zero-rate offset up to ±3 °/s, drawn without consuming ``rng`` (seeded sessions
    # keep their accelerometer draws).
    model.gyro_bias = np.random.default_rng(
        int(abs(model.bias[0]) * 1e12) % (2 ** 32)).uniform(-1, 1, 3) * np.radians(3.0)
    magnitudes = {
        'scale_nonlinearity': ('nonlinearity', signed(0.002, 0.005)),
        'temperature_bias': ('bias_tempco', signed(0.5e-3, 1.5e-3) * G0),
        'temperature_scale': ('scale_tempco', signed(0.1e-4, 2.6e-4)),
        'bias_drift': ('bias_drift', signed(0.5e-3, 2e-3) * G0 / 60.0),
    }
    for name in effects:
        if name in ('nonorthogonality', 'temperature_lag', 'bias_random_walk'):
            continue
        attr, value = magnitudes[name]
        setattr(model, attr, value)
    # Drawn only when asked, after the others: seeded sessions without them keep their draws.
    if 'temperature_lag' in effects:
        if 'temperature_bias' not in effects:
            model.bias_tempco = signed(0.5e-3, 1.5e-3) * G0
        model.thermal_lag_s = float(rng.uniform(60.0, 300.0))
    if 'bias_random_walk' in effects:
        model.bias_random_walk = signed(0.05e-3, 0.2e-3) * G0
    return model


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

    ``pose`` is the index of the held pose for each sample, -1 while moving.
    """

    samples: Samples
    true_accel: np.ndarray
    pose: np.ndarray
    directions: np.ndarray
    sensor: SensorModel
    gravity: float


def _segments(n_pose, holds, move_s, rate_hz):
    """Return the session script: (pose index, move?, samples) per segment, in order."""
    out = []
    for k in range(n_pose):
        if k > 0:
            out.append((k, True, max(int(round(move_s * rate_hz)), 2)))
        out.append((k, False, max(int(round(holds[k] * rate_hz)), 1)))
    return out


def session_length(directions, hold_s=3.0, move_s=1.5, rate_hz=100.0):
    """Return the number of samples ``simulate_session`` gives for these arguments."""
    n_pose = len(np.asarray(directions, float).reshape(-1, 3))
    holds = np.broadcast_to(np.asarray(hold_s, float), (n_pose,))
    return sum(n for _, _, n in _segments(n_pose, holds, move_s, rate_hz))


def iter_session(sensor, directions, rng, hold_s=3.0, move_s=1.5, rate_hz=100.0,
                 gravity=G0, temperature=25.0, motion_accel=1.5, lead_s=None,
                 chunk_rows=CHUNK_ROWS):
    """
    Simulate a session piece by piece, in bounded memory (see ``simulate_session``).

    Same arguments as ``simulate_session``. Yields ``Session`` objects of at most
    about ``chunk_rows`` samples each, in time order; their concatenation is the
    session ``simulate_session`` returns for the same random generator state. The
    draws do not depend on ``chunk_rows`` (only on the fixed ``CHUNK_ROWS``).

    :returns: generator of Session.
    """
    directions = np.asarray(directions, float).reshape(-1, 3)
    directions = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    n_pose = len(directions)
    holds = np.broadcast_to(np.asarray(hold_s, float), (n_pose,))
    dt = 1.0 / rate_hz
    rots = _rotation_to(directions)
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
    gyro_bias = np.asarray(getattr(sensor, 'gyro_bias', np.zeros(3)), float)  # raw = true + b
    gyro_noise = np.asarray(getattr(sensor, 'gyro_noise_std', 0.002), float)  # rad/s
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
            elif index + 1 < len(segments):     # the first rotation of the next segment
                k_next, move_next, n_next = segments[index + 1]
                after = rots[k_next]
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
            else:                               # held still: one rotation, no turn rate
                inverse = rots[k].inv()
                true_accel = np.tile(inverse.apply(up), (m, 1))
                last = rots[k]
            if after is not None:
                gyro_world[-1] = (after * last.inv()).as_rotvec() / dt
            elif b == n and index + 1 == len(segments):  # the very last sample
                gyro_world[-1] = gyro_world[-2] if m > 1 else gyro_world_last
            gyro_world_last = gyro_world[-1]
            gyro = inverse.apply(gyro_world) + rng.standard_normal((m, 3)) * gyro_noise
            gyro += gyro_bias
            temp = temp_at(t)
            raw = sensor.measure(true_accel, rng, die(temp), t, walk(m, rng))
            pose = np.full(m, -1 if moving else k)
            pieces.append((t, raw, temp, gyro, true_accel, pose))
            rows += m
            if rows >= chunk_rows:
                yield _join(pieces, directions, sensor, gravity)
                pieces, rows = [], 0
        first += n
    if pieces:
        yield _join(pieces, directions, sensor, gravity)


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


def _join(pieces, directions, sensor, gravity):
    """Concatenate (t, raw, temp, gyro, true_accel, pose) pieces into one Session."""
    t, raw, temp, gyro, true_accel, pose = (
        np.concatenate(column) if len(pieces) > 1 else column[0] for column in zip(*pieces))
    return Session(Samples(t, raw, temp, gyro), true_accel, pose, directions, sensor, gravity)


def simulate_session(sensor, directions, rng, hold_s=3.0, move_s=1.5, rate_hz=100.0,
                     gravity=G0, temperature=25.0, motion_accel=1.5, lead_s=None):
    """
    Simulate someone turning the sensor through a sequence of held poses.

    The whole session in memory; ``iter_session`` gives the same in pieces.

    :param sensor: SensorModel that produces the raw readings.
    :param directions: (P, 3) unit gravity directions in the body frame, one per pose.
    :param rng: numpy Generator.
    :param hold_s: seconds each pose is held still (scalar or (P,) array).
    :param move_s: seconds each move between poses takes.
    :param rate_hz: sample rate, Hz.
    :param gravity: local gravity magnitude, m/s².
    :param temperature: °C; a constant, a (start, end) pair for a linear ramp over
        the session, or a callable of time in seconds.
    :param motion_accel: peak hand acceleration during a move, m/s².
    :param lead_s: still time before the first pose is reached (default ``hold_s``).
    :returns: Session.
    """
    parts = list(iter_session(sensor, directions, rng, hold_s, move_s, rate_hz, gravity,
                              temperature, motion_accel, lead_s, chunk_rows=1 << 62))
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


DATASHEET = {
    'nonorthogonality': 0.02,              # cross-axis sensitivity, fraction
    'scale_nonlinearity': 0.005,           # fraction of reading at 1 g
    'temperature_bias': 1.5e-3 * G0,       # m/s² per °C
    'temperature_scale': 2.6e-4,           # 1 per °C
    'bias_drift': 1e-3 * G0 / 60.0,        # m/s² per s (1 mg/min; not in the datasheet)
    'temperature_lag': 1.5e-3 * G0,        # m/s² per °C of the die temperature
    'bias_random_walk': 0.1e-3 * G0,       # m/s² per √s (not in the datasheet)
}
"""MPU-9250 datasheet magnitude of each effect of the model-gap library."""

THERMAL_LAG_S = 120.0
"""Die temperature lag of ``with_datasheet_effect(..., 'temperature_lag')``, s."""


def with_datasheet_effect(sensor, effect, rng, scale=1.0):
    """
    Return a copy of ``sensor`` with one effect at ``scale`` x its datasheet size.

    The three axes get random signs and sizes of (1, 0.75, 0.5) x the magnitude. For
    ``nonorthogonality`` T becomes diagonal plus the hidden off-diagonal terms, so a
    6-parameter (gn) baseline lacks exactly that effect. ``temperature_lag`` is the
    offset's temperature coefficient driven by a die temperature ``THERMAL_LAG_S`` behind
    the reported one (set ``thermal_lag_s`` for another lag).
    """
    size = scale * DATASHEET[effect] * rng.choice([-1.0, 1.0], 3) * np.array([1.0, 0.75, 0.5])
    out = replace(sensor, T=sensor.T.copy())
    if effect == 'nonorthogonality':
        out.T = np.diag(np.diag(sensor.T))
        out.T[np.triu_indices(3, 1)] = size
    else:
        attr = {'scale_nonlinearity': 'nonlinearity', 'temperature_bias': 'bias_tempco',
                'temperature_scale': 'scale_tempco', 'bias_drift': 'bias_drift',
                'temperature_lag': 'bias_tempco', 'bias_random_walk': 'bias_random_walk'}[effect]
        setattr(out, attr, size)
        if effect == 'temperature_lag':
            out.thermal_lag_s = THERMAL_LAG_S
    return out


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
    from .windows import StaticWindows
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
    mean = simulate_window_means(sensor, directions, counts, rng, gravity, die, t, offset)
    return StaticWindows(np.zeros(n, int), counts, mean, np.tile(sensor.noise_std, (n, 1)),
                         counts, t, temp)
