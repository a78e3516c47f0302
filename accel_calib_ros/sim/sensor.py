"""
Simulated MEMS sensor physics: the accelerometer, gyroscope and magnetometer models.

The forward model, for true specific force ``a`` (m/s², body frame), temperature
``theta`` (°C) and time ``t`` (s)::

    s      = diag(1 + scale_tempco * (theta - temp_ref)) @ T @ a
    raw_i  = s_i + nonlinearity_i * s_i**2 / g0
             + bias_i + bias_tempco_i * (theta - temp_ref) + bias_drift_i * t
             + sum over library_effects (columns(a, theta - temp_ref, t) @ params)_i
             + w_i(t) + noise, then quantised to the ADC step.

``theta`` is the die temperature: the reported temperature itself, or, with
``thermal_lag_s`` > 0, its first-order lag (the die warms up minutes behind the
temperature sensor). The offset may bend with temperature beyond the straight line
(``bias_tempco_quadratic``, ``bias_tempco_cubic``: terms in (theta - temp_ref)² and ³).
``w(t)`` is a random walk of the offset (``bias_random_walk``, m/s² per √s), zero unless
switched on. A temperature gradient across the package adds an offset that follows the
rate of temperature change (``bias_gradient``, m/s² per °C of gradient, the gradient being
the reported temperature minus its first-order lag with ``gradient_tau_s``: about
``gradient_tau_s`` x the heating rate): heating and cooling then read differently at the
same reported temperature (hysteresis). These need the session's history, so they act in
``sim.motion`` (``iter_session``, ``simulate_session``, ``simulate_static_windows``), not
in ``distort``. The reported temperature itself may carry noise (``temp_noise_std``) and
the sensor's step (``temp_lsb``).

``T`` is upper triangular (scale times non-orthogonality, Sun & Xu eq. 1-4).
Each physical effect has its own field and is off when that field is zero, so
effects can be switched on one at a time (the model-gap workflow relies on it).
An effect of the model-gap library without a field of its own acts through its own
design columns (``library_effects``: the fit's definition is the simulator's). Which
field holds which library effect, its datasheet size and how a random sensor draws it
are the effect's own declarations (``modelgap.effect.Effect``): ``with_datasheet_effect``
and ``mpu9250_like`` loop over the library.

The gyroscope and the magnetometer (interface.md §9 and §10), for the true body rate
``w`` (rad/s) and the local Earth field ``f`` in the body (accelerometer) frame (µT)::

    raw_gyro = clip(gyro_T @ w + gyro_bias + noise, ±gyro_full_scale)
    raw_mag  = mag.T @ mag.R @ f + mag.hard_iron + noise     (at the magnetometer's rate)

Both are off (identity, no clipping, no magnetometer) by default, and then a session
is bit for bit the one this module gave before they existed: their random numbers
come from a generator spawned from the session's, only when they are switched on.
"""

from dataclasses import dataclass, field, replace
from typing import Optional

import numpy as np
from scipy.spatial.transform import Rotation

from ..core.constants import G0
from ..dataio.wire.chips import AK8963, DEFAULT_CHIP
from ..modelgap.effects import EFFECTS


MPU9250_LSB = G0 / DEFAULT_CHIP.accel_lsb_per_g[2]
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
    :param bias_tempco_quadratic: (3,) offset curvature, m/s² per °C².
    :param bias_tempco_cubic: (3,) offset third-order term, m/s² per °C³.
    :param bias_gradient: (3,) offset per °C of temperature gradient across the package,
        m/s² per °C (the gradient: reported temperature minus its lag ``gradient_tau_s``).
    :param gradient_tau_s: time constant of that gradient, s.
    :param gyro_bias_tempco: (3,) gyroscope offset drift, rad/s per °C of die temperature.
    :param temp_noise_std: noise of the reported temperature, °C (0: none).
    :param temp_lsb: step of the reported temperature, °C (0: none; MPU-9250 1/333.87).
    :param bias_curve: (temps (M,) °C, offsets (M, 3) m/s²): an offset against the die
        temperature beyond the polynomial terms, linear between its points (a curve no
        polynomial holds), or None.
    :param library_effects: ((Effect, params), ...): model-gap library effects without a
        field here, each adding ``Effect.apply(params, a, theta - temp_ref, t)`` (empty: none).
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
    bias_tempco_quadratic: np.ndarray = field(default_factory=lambda: np.zeros(3))
    bias_tempco_cubic: np.ndarray = field(default_factory=lambda: np.zeros(3))
    bias_gradient: np.ndarray = field(default_factory=lambda: np.zeros(3))
    gradient_tau_s: float = 60.0
    gyro_bias_tempco: np.ndarray = field(default_factory=lambda: np.zeros(3))
    temp_noise_std: float = 0.0
    temp_lsb: float = 0.0
    bias_curve: Optional[tuple] = None
    library_effects: tuple = ()

    def __post_init__(self):
        self.T = np.asarray(self.T, dtype=float).reshape(3, 3)
        self.gyro_T = np.asarray(self.gyro_T, dtype=float).reshape(3, 3)
        for name in ('bias', 'noise_std', 'nonlinearity', 'bias_tempco',
                     'scale_tempco', 'bias_drift', 'gyro_noise_std', 'bias_random_walk',
                     'bias_tempco_quadratic', 'bias_tempco_cubic', 'bias_gradient',
                     'gyro_bias_tempco'):
            setattr(self, name, _vec3(getattr(self, name)))
        self.thermal_lag_s = float(self.thermal_lag_s)
        self.gradient_tau_s = float(self.gradient_tau_s)
        self.library_effects = tuple(self.library_effects)

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
        if np.any(self.bias_tempco_quadratic) or np.any(self.bias_tempco_cubic):
            raw = raw + (dtheta[:, None] ** 2 * self.bias_tempco_quadratic
                         + dtheta[:, None] ** 3 * self.bias_tempco_cubic)
        if self.bias_curve is not None:
            temps, offsets = self.bias_curve
            theta = dtheta + self.temp_ref
            raw = raw + np.column_stack([np.interp(theta, temps, offsets[:, i])
                                         for i in range(3)])
        raw = raw + time[:, None] * self.bias_drift
        for effect, params in self.library_effects:
            raw = raw + effect.apply(params, a, dtheta, time, G0)
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
    quantisation. The model-gap library's effects beyond the calibration model are off
    unless named in ``effects``: each then gets a random size per axis in its
    ``Effect.sensor_range`` with random signs (``scale_nonlinearity`` 0.2-0.5 %,
    ``temperature_bias`` 0.5-1.5 mg/°C, ``temperature_scale`` 0.001-0.026 %/°C,
    ``bias_drift`` 0.5-2 mg/min, ``temperature_lag`` the offset's 0.5-1.5 mg/°C driven by a
    die temperature 1-5 minutes behind the reported one, ``bias_random_walk``
    0.05-0.2 mg/√s). ``nonorthogonality`` is always on (it is part of T); pass
    ``orthogonal=True`` semantics by zeroing it yourself.

    The random draws: the library's first effects (``Effect.drawn_always``) are drawn in
    every call, asked for or not, then the others asked for, in library order; so a
    seeded sensor stays the same when effects are added to the library.

    :returns: SensorModel.
    """
    def pm(scale):
        return rng.uniform(-1, 1, 3) * scale

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
    asked = [EFFECTS[name] for name in effects]
    drawn = [(effect, effect.draw(rng)) for effect in EFFECTS.values() if effect.drawn_always]
    for effect, size in drawn:
        if effect in asked:
            effect.hide_in(model, size)
    # Drawn only when asked, after the others: seeded sessions without them keep their draws.
    for effect in EFFECTS.values():
        if effect in asked and effect.sensor_range is not None and not effect.drawn_always:
            effect.draw_into(model, rng, asked)
    return model


AK8963_LSB_UT = AK8963.ut_per_count[16]
"""AK8963 16-bit output step, µT per count."""


@dataclass
class MagnetometerModel:
    """
    True error parameters of a simulated magnetometer (AK8963-like, interface.md §10).

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


def with_datasheet_effect(sensor, effect, rng, scale=1.0):
    """
    Return a copy of ``sensor`` with one library effect at ``scale`` x its datasheet size.

    The three axes get random signs and sizes of (1, 0.75, 0.5) x the magnitude
    (``Effect.datasheet``; ``Effect.hide_in`` puts it in the copy). For
    ``nonorthogonality`` T becomes diagonal plus the hidden off-diagonal terms, so a
    6-parameter (gn) baseline lacks exactly that effect. ``temperature_lag`` is the
    offset's temperature coefficient driven by a die temperature 120 s behind the reported
    one (set ``thermal_lag_s`` for another lag).

    :param effect: a library name (``modelgap.effects.EFFECTS``).
    """
    library = EFFECTS[effect]
    if library.datasheet is None:
        raise ValueError(f'the simulator cannot show {effect}: it has no datasheet size')
    size = (scale * library.to_si(library.datasheet) * rng.choice([-1.0, 1.0], 3)
            * np.array([1.0, 0.75, 0.5]))
    out = replace(sensor, T=sensor.T.copy())
    library.hide_in(out, size)
    return out
