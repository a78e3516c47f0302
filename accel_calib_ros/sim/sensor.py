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

The gyroscope and the magnetometer (spec sections 9 and 10), for the true body rate
``w`` (rad/s) and the local Earth field ``f`` in the body (accelerometer) frame (µT)::

    raw_gyro = clip(gyro_T @ w + gyro_bias + noise, ±gyro_full_scale)
    raw_mag  = mag.T @ mag.R @ f + mag.hard_iron + noise     (at the magnetometer's rate)

Both are off (identity, no clipping, no magnetometer) by default, and then a session
is bit for bit the one this module gave before they existed: their random numbers
come from a generator spawned from the session's, only when they are switched on.
"""

from dataclasses import dataclass, field, replace
from typing import Optional
import warnings

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from ..core.constants import G0
from ..core.samples import Samples


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
    :param gyro_T: (3, 3) gyroscope scale x misalignment, raw rate = gyro_T @ true + bias.
    :param gyro_full_scale: the gyroscope's range, rad/s: readings clip at ± this
        (inf: no clipping).
    :param gyro_lsb: gyroscope ADC step, rad/s (0 disables quantisation).
    :param magnetometer: MagnetometerModel, or None for a sensor without one.
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
    gyro_T: np.ndarray = field(default_factory=lambda: np.eye(3))
    gyro_full_scale: float = float('inf')
    gyro_lsb: float = 0.0
    magnetometer: Optional['MagnetometerModel'] = None
    thermal_lag_s: float = 0.0
    bias_random_walk: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self):
        self.T = np.asarray(self.T, dtype=float).reshape(3, 3)
        self.gyro_T = np.asarray(self.gyro_T, dtype=float).reshape(3, 3)
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
    300 µg/√Hz (the datasheet's one-sided density) over a bandwidth of rate/2, i.e.
    sample std 300 µg·√(rate/2) and Allan N = 212 µg/√Hz (``core.allan``), ±2 g
    quantisation. Effects beyond the
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


AK8963_LSB_UT = 0.15
"""AK8963 16-bit output step, µT per count."""


@dataclass
class MagnetometerModel:
    """
    True error parameters of a simulated magnetometer (AK8963-like, spec section 10).

    ``raw = T @ R @ field_body + hard_iron + noise``, sampled at ``rate_hz``.

    :param T: (3, 3) soft iron, dimensionless (any matrix: symmetric for a physical
        soft-iron effect; the fit reports the equivalent upper-triangular form, see
        ``core.magnetometer.fit.canonical``).
    :param hard_iron: (3,) offset, µT.
    :param R: (3, 3) rotation from the accelerometer frame to the magnetometer's.
    :param noise_std: (3,) white noise per sample, µT.
    :param lsb: ADC step, µT (0 disables quantisation).
    :param rate_hz: magnetometer sample rate, Hz; rows between its samples are NaN.
    """

    T: np.ndarray = field(default_factory=lambda: np.eye(3))
    hard_iron: np.ndarray = field(default_factory=lambda: np.zeros(3))
    R: np.ndarray = field(default_factory=lambda: np.eye(3))
    noise_std: np.ndarray = field(default_factory=lambda: np.full(3, 0.4))
    lsb: float = 0.0
    rate_hz: float = 100.0

    def __post_init__(self):
        self.T = np.asarray(self.T, dtype=float).reshape(3, 3)
        self.R = np.asarray(self.R, dtype=float).reshape(3, 3)
        self.hard_iron = _vec3(self.hard_iron)
        self.noise_std = _vec3(self.noise_std)

    def distort(self, field_body):
        """
        Noise-free raw reading for the field in the body frame.

        :param field_body: (N, 3) µT, accelerometer frame.
        :returns: (N, 3) µT, magnetometer frame.
        """
        return np.atleast_2d(field_body) @ (self.T @ self.R).T + self.hard_iron


@dataclass
class EarthField:
    """
    The local geomagnetic field of a simulated session.

    World frame: x north (magnetic), z up (the frame in which gravity reads +g).

    :param field_uT: magnitude, µT.
    :param dip_deg: inclination below the horizontal, degrees (positive: the field
        points down, northern hemisphere); the accelerometer's up direction and the
        field then satisfy ``up · field / |field| = -sin(dip)``.
    """

    field_uT: float = 48.0
    dip_deg: float = 60.0

    def world(self):
        """Field vector (3,) in the world frame, µT."""
        dip = np.radians(self.dip_deg)
        return self.field_uT * np.array([np.cos(dip), 0.0, -np.sin(dip)])


def _small_rotation(rng, angle_deg):
    """Return a rotation matrix about a random axis by ``angle_deg`` x U(-1, 1)."""
    axis = rng.standard_normal(3)
    axis *= np.radians(angle_deg) * rng.uniform(-1, 1) / np.linalg.norm(axis)
    return Rotation.from_rotvec(axis).as_matrix()


def with_gyro_errors(sensor, rng, full_scale=None, lsb=0.0):
    """
    Return a copy of ``sensor`` with a datasheet-sized gyroscope scale and misalignment.

    MPU-9250 gyroscope: sensitivity tolerance ±3 % (diagonal of ``gyro_T``) and
    cross-axis sensitivity ±2 % (its six off-diagonal terms), each uniform.

    :param rng: numpy Generator (only it is drawn from).
    :param full_scale: range in rad/s at which readings clip (None: no clipping), e.g.
        ``np.radians(250)`` for the MPU's ±250 °/s setting.
    :param lsb: ADC step in rad/s (0: none), e.g. ``np.radians(1 / 131)``.
    :returns: SensorModel.
    """
    gyro_T = np.diag(1.0 + rng.uniform(-1, 1, 3) * 0.03)
    off = ~np.eye(3, dtype=bool)
    gyro_T[off] = rng.uniform(-1, 1, 6) * 0.02
    return replace(sensor, gyro_T=gyro_T,
                   gyro_full_scale=float('inf') if full_scale is None else float(full_scale),
                   gyro_lsb=float(lsb))


def ak8963_like(rng, hard_iron_uT=30.0, soft_iron=0.05, misalignment_deg=2.0):
    """
    Draw an AK8963-like magnetometer mounted on a robot.

    Hard iron up to ±``hard_iron_uT`` per axis (board and robot magnetisation), a
    symmetric soft iron with ±``soft_iron`` on the diagonal and half that off it, a
    residual misalignment to the accelerometer of up to ``misalignment_deg`` about a
    random axis (after the driver's axis swap), noise 0.4 µT, 0.15 µT steps, 100 Hz.

    :param rng: numpy Generator (only it is drawn from).
    :returns: MagnetometerModel.
    """
    T = np.diag(1.0 + rng.uniform(-1, 1, 3) * soft_iron)
    upper = np.triu_indices(3, 1)
    T[upper] = rng.uniform(-1, 1, 3) * soft_iron / 2.0
    T.T[upper] = T[upper]
    return MagnetometerModel(T=T, hard_iron=rng.uniform(-1, 1, 3) * hard_iron_uT,
                             R=_small_rotation(rng, misalignment_deg), lsb=AK8963_LSB_UT)


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
            if gyro_lsb > 0:
                gyro = np.round(gyro / gyro_lsb) * gyro_lsb
            if np.isfinite(full_scale):
                np.clip(gyro, -full_scale, full_scale, out=gyro)
            temp = temp_at(t)
            raw = sensor.measure(true_accel, rng, die(temp), t, walk(m, rng))
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


def measure_mag(mag, field_body, t, dt, rng):
    """
    Raw magnetometer rows (m, 3) µT for the body field, NaN where it takes no sample.

    A row holds a sample when it is the first since the magnetometer's clock ticked
    (``floor(t x rate_hz)`` changed), so the pattern depends only on time.
    """
    raw = mag.distort(field_body) + rng.standard_normal(field_body.shape) * mag.noise_std
    if mag.lsb > 0:
        raw = np.round(raw / mag.lsb) * mag.lsb
    tick = np.floor(np.round(t * mag.rate_hz, 6))
    before = np.floor(np.round((t - dt) * mag.rate_hz, 6))
    raw[(tick == before) & (t > 0)] = np.nan
    return raw


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
    mean = simulate_window_means(sensor, directions, counts, rng, gravity, die, t, offset)
    return StaticWindows(np.zeros(n, int), counts, mean, np.tile(sensor.noise_std, (n, 1)),
                         counts, t, temp)
