"""
A climate chamber: temperature programmes and a still sensor whose offsets move with them.

Thermal calibration the way flight stacks do it (PX4, ArduPilot's INS_TCAL) records one
still pose while the temperature sweeps: a warm-up after power-on, or a chamber cycle that
cools, heats and cools again. :class:`ChamberProgramme` is such a cycle: the chamber air
ramps at a set rate between set points and holds there, and the board's temperature sensor
follows the air with a first-order lag (the board's own heat capacity), so its rate rises
from zero at the start of a ramp, peaks, and settles at each hold, as on a real chamber.
:func:`thermal_unit` draws a sensor whose offsets move with temperature along a smooth
curve (a cubic) and, optionally, with a heating/cooling hysteresis (a temperature gradient
across the package: ``SensorModel.bias_gradient``). :func:`simulate_still` records it in
one pose.
"""

import numpy as np

from .motion import simulate_session
from .sensor import MPU9250_LSB, SensorModel
from ..core.constants import G0

MPU9250_TEMP_LSB = 1.0 / 333.87
"""The MPU-9250's temperature step, °C per count."""


class ChamberProgramme:
    """
    A chamber cycle as the board's temperature sensor sees it: a callable of time (s) -> °C.

    :param set_points: temperatures the chamber air goes to in turn, °C; the air starts at
        ``start_c``.
    :param rates_c_min: ramp rate of the air towards each set point, °C/min (one value, or
        one per set point).
    :param hold_s: time the air holds each set point, s (one value or one per set point).
    :param start_c: the air's (and board's) temperature at t = 0, °C.
    :param board_tau_s: time constant of the board behind the air, s (0: none).
    :param lead_s: still time at ``start_c`` before the first ramp, s.
    """

    def __init__(self, set_points=(-18.0, 74.0, -18.0), rates_c_min=3.0, hold_s=900.0,
                 start_c=25.0, board_tau_s=180.0, lead_s=120.0):
        set_points = [float(v) for v in np.atleast_1d(set_points)]
        rates = np.broadcast_to(np.asarray(rates_c_min, float), (len(set_points),))
        holds = np.broadcast_to(np.asarray(hold_s, float), (len(set_points),))
        times, temps = [0.0, float(lead_s)], [float(start_c), float(start_c)]
        self.legs = []
        for target, rate, hold in zip(set_points, rates, holds):
            start = times[-1]
            ramp = abs(target - temps[-1]) / (rate / 60.0)
            times += [start + ramp, start + ramp + hold]
            temps += [target, target]
            self.legs.append(('heating' if target > temps[-3] else 'cooling', start,
                              start + ramp + hold))
        self.duration_s = times[-1]
        self._air = (np.array(times), np.array(temps))
        self.board_tau_s = float(board_tau_s)
        self._grid = np.arange(0.0, self.duration_s + 1.0, 1.0)
        air = np.interp(self._grid, *self._air)
        if self.board_tau_s > 0:
            a = np.exp(-1.0 / self.board_tau_s)
            from scipy import signal
            air, _ = signal.lfilter([1.0 - a], [1.0, -a], air, zi=[a * air[0]])
        self._board = air

    def __call__(self, t):
        """Return the board temperature (°C) at times ``t`` (s)."""
        return np.interp(np.asarray(t, float), self._grid, self._board)

    def air(self, t):
        """Return the chamber air temperature (°C) at times ``t`` (s)."""
        return np.interp(np.asarray(t, float), *self._air)

    def leg_of(self, t):
        """Return the index of the leg (ramp and its hold) each time ``t`` lies in, (N,)."""
        t = np.asarray(t, float)
        ends = np.array([end for _, _, end in self.legs])
        return np.minimum(np.searchsorted(ends, t, side='right'), len(ends) - 1)


def thermal_unit(rng, offsets_mg=(16.0, 15.0, 55.0), span_c=(-18.0, 74.0),
                 hysteresis_mg=0.0, rate_c_min=3.0, gradient_tau_s=45.0, temp_ref=25.0,
                 noise_mg=0.4, rate_hz=100.0, gyro_tempco_dps_c=0.02, curvature=0.3,
                 bumps=0.0):
    """
    Draw a sensor whose offsets move along a smooth curve over a temperature span.

    Each axis moves by ``offsets_mg`` over ``span_c`` (sign random), along a cubic whose
    departure from the straight line is ``curvature`` of the total; with ``hysteresis_mg``
    the heating and cooling legs of a ramp at ``rate_c_min`` differ by that much at the
    same reported temperature on the axis with the largest offsets (about half of it on
    another axis, none on the third), from a temperature gradient across the package
    (``bias_gradient``, ``gradient_tau_s``). Calibration errors (T, bias) are those of
    ``mpu9250_like``-sized drawn values; the gyro bias moves ``gyro_tempco_dps_c`` °/s per
    °C at most per axis.

    :param noise_mg: per-sample noise, mg (the chamber recordings: 0.3-0.5 mg).
    :param bumps: with it, three smooth bumps per axis (widths 10-25 °C) of up to ``bumps``
        of the total each are added: a curve no cubic holds (``SensorModel.bias_curve``).
    :returns: SensorModel (its ``temp_ref`` is ``temp_ref``).
    """
    low, high = span_c
    centre, half = 0.5 * (low + high) - temp_ref, 0.5 * (high - low)
    total = np.asarray(offsets_mg, float) * 1e-3 * G0 * rng.choice([-1.0, 1.0], 3)
    # offset(u) = total/2 (u + c (u³ - u)) over u in [-1, 1]: its ends differ by ``total``,
    # the cubic bows it by up to about 0.38 c of the total from the straight line.
    bend = curvature * rng.uniform(0.5, 1.0, 3) * rng.choice([-1.0, 1.0], 3)
    a1 = total / 2.0 * (1.0 - bend) / half
    a3 = total / 2.0 * bend / half ** 3
    # In powers of (theta - temp_ref): u half = theta - temp_ref - centre.
    lin = a1 + 3.0 * a3 * centre ** 2
    quad = -3.0 * a3 * centre
    cub = a3
    # Heating minus cooling at +-rate: 2 k tau rate.
    rate = rate_c_min / 60.0
    order = np.argsort(-np.abs(total))
    share = np.zeros(3)
    share[order[0]], share[order[1 + rng.integers(2)]] = 1.0, 0.5
    k = hysteresis_mg * 1e-3 * G0 * share / (2.0 * gradient_tau_s * rate) \
        * rng.choice([-1.0, 1.0], 3)
    T = np.diag(1.0 + rng.uniform(-1, 1, 3) * 0.03)
    T[np.triu_indices(3, 1)] = rng.uniform(-1, 1, 3) * 0.02
    bias = np.array([0.06, 0.06, 0.08]) * G0 * rng.uniform(-1, 1, 3)
    curve = None
    if bumps > 0:
        grid = np.linspace(low - 30.0, high + 30.0, 400)
        centres = rng.uniform(low, high, (3, 3))
        widths = rng.uniform(10.0, 25.0, (3, 3))
        sizes = rng.uniform(-1.0, 1.0, (3, 3)) * bumps * np.abs(total)[:, None]
        shape = np.exp(-0.5 * ((grid[None, None, :] - centres[..., None])
                               / widths[..., None]) ** 2)
        offsets = np.einsum('ab,abn->na', sizes, shape)
        ref = np.array([np.interp(temp_ref, grid, offsets[:, i]) for i in range(3)])
        curve = (grid, offsets - ref)
    return SensorModel(
        T=T, bias=bias, bias_curve=curve, noise_std=np.full(3, noise_mg * 1e-3 * G0),
        lsb=MPU9250_LSB,
        bias_tempco=lin, bias_tempco_quadratic=quad, bias_tempco_cubic=cub,
        bias_gradient=k, gradient_tau_s=gradient_tau_s, temp_ref=temp_ref,
        gyro_bias=np.radians(rng.uniform(-3.0, 3.0, 3)),
        gyro_bias_tempco=np.radians(gyro_tempco_dps_c) * rng.uniform(-1.0, 1.0, 3),
        gyro_noise_std=np.full(3, np.radians(0.01) * np.sqrt(rate_hz / 2.0)),
        temp_lsb=MPU9250_TEMP_LSB)


def simulate_still(sensor, direction, rng, duration_s, rate_hz=100.0, temperature=25.0,
                   gravity=G0):
    """
    Record ``sensor`` held still in one pose for ``duration_s`` while ``temperature`` runs.

    :param direction: (3,) gravity direction in the body frame (the axis that points up).
    :param temperature: °C, a constant or a callable of time (a ``ChamberProgramme``).
    :returns: sim.motion.Session (one pose, no moves).
    """
    d = np.asarray(direction, float).reshape(1, 3)
    return simulate_session(sensor, d, rng, hold_s=float(duration_s), rate_hz=rate_hz,
                            gravity=gravity, temperature=temperature, lead_s=0.0)
