"""
The temperature's first-order lag and the heating/cooling hysteresis it carries.

Real MEMS parts read differently at the same reported temperature while heating and while
cooling: the die lags the temperature sensor, and a temperature gradient across the
package adds an offset that follows the rate of temperature change. Both follow the
reported temperature's first-order lag θ_lag with a time constant tau::

    tau dθ_lag/dt = θ - θ_lag

The gradient ``θ - θ_lag`` (°C) is about tau times the rate of temperature change on a
steady ramp (tau dθ/dt): it is the rate smoothed over tau, in °C. :class:`Hysteresis` is
the term a thermal calibration carries to the robot: ``offset_i += k_i (θ - θ_lag)``.

The lag is solved exactly for a temperature that is linear between its samples (no step
size to choose), in a vectorised form for recordings (:func:`lagged_temperature`) and
sample by sample for a live stream (:class:`LagState`); both restart (θ_lag = θ) after a
gap in the temperature longer than ``gap_s``, so fit, ``apply`` and the correction node
compute the same term from the same readings.
"""

from dataclasses import dataclass, field
import math

import numpy as np

LAG_GAP_S = 30.0
"""A temperature gap longer than this restarts the lag, s (the state is then unknown)."""


def lagged_temperature(time, temp, tau_s, gap_s=LAG_GAP_S, start_gradient=0.0):
    """
    Return the first-order lag of a temperature series, same shape as ``temp``.

    Exact for a temperature linear between its samples; in equilibrium (θ_lag = θ) at the
    first sample (or ``start_gradient`` = θ - θ_lag there) and after every gap longer than
    ``gap_s`` (or a step back in time).

    :param time: (N,) s, non-decreasing. :param temp: (N,) °C (finite).
    :param tau_s: time constant, s (> 0).
    :returns: (N,) θ_lag, °C.
    """
    from scipy import signal
    time = np.asarray(time, float).reshape(-1)
    temp = np.asarray(temp, float).reshape(-1)
    out = np.empty_like(temp)
    if not len(temp):
        return out
    dt = np.diff(time)
    breaks = np.flatnonzero(~((dt >= 0) & (dt <= gap_s))) + 1
    for a, b in zip(np.r_[0, breaks], np.r_[breaks, len(temp)]):
        out[a:b] = _lag_piece(time[a:b], temp[a:b], float(tau_s), signal,
                              start_gradient if a == 0 else 0.0)
    return out


def _lag_piece(time, temp, tau, signal, start=0.0):
    """Solve the lag over one stretch without gaps (see ``lagged_temperature``)."""
    n = len(temp)
    if n == 1:
        return temp - start
    dt = np.diff(time)
    # On each linear piece (slope s): y1 = x1 - s tau + (y0 - x0 + s tau) e, e = exp(-dt/tau).
    # With d = y - x: d1 = e d0 + (e - 1) s tau, a first-order recursion with varying e.
    e = np.exp(-dt / tau)
    with np.errstate(divide='ignore', invalid='ignore'):
        slope = np.where(dt > 0, np.diff(temp) / np.where(dt > 0, dt, 1.0), 0.0)
    drive = (e - 1.0) * slope * tau
    # d = lag - temp starts at -start: the drive of the first step carries it.
    drive[0] += e[0] * -start
    if np.allclose(e, e[0], rtol=1e-9, atol=0.0):
        d, _ = signal.lfilter([1.0], [1.0, -e[0]], drive, zi=[0.0])
    else:
        d = _varying_recursion(e, drive, np.cumsum(dt) / tau)
    return temp + np.r_[-start, d]


def _varying_recursion(e, drive, decay):
    """
    Return d with d_k = e_k d_(k-1) + drive_k, d_(-1) = 0, vectorised (e_k = exp(-step_k)).

    d_k = P_k sum_(j<=k) drive_j / P_j with P_k = exp(-decay_k), ``decay`` the cumulative
    steps; taken in stretches over which P falls by at most exp(-500), so nothing
    overflows, the last value carried into the next stretch.
    """
    d = np.empty(len(e))
    carry, start = 0.0, 0
    while start < len(e):
        stop = int(np.searchsorted(decay, decay[start] + 500.0, side='right'))
        stop = max(stop, start + 1)
        rel = decay[start:stop] - decay[start] + (-math.log(e[start]) if e[start] > 0 else 0)
        p = np.exp(-rel)
        d[start:stop] = p * (carry + np.cumsum(drive[start:stop] / p))
        carry, start = d[stop - 1], stop
    return d


class LagState:
    """
    The lag of a live temperature stream, one reading at a time (the correction node).

    :param tau_s: time constant, s. :param gap_s: a longer silence restarts it.
    """

    __slots__ = ('tau_s', 'gap_s', 'time', 'temp', 'lag', 'restarts')

    def __init__(self, tau_s, gap_s=LAG_GAP_S):
        self.tau_s, self.gap_s = float(tau_s), float(gap_s)
        self.time = self.temp = self.lag = None
        self.restarts = 0

    def update(self, time, temp):
        """
        Take one reading (s, °C); return the gradient θ - θ_lag, °C.

        A first reading, one after a gap longer than ``gap_s`` or one back in time starts
        the lag afresh in equilibrium (gradient 0) and counts a restart (but the first).
        """
        if not (math.isfinite(time) and math.isfinite(temp)):
            return self.gradient
        if self.time is None or not 0.0 <= time - self.time <= self.gap_s:
            if self.time is not None:
                self.restarts += 1
            self.time, self.temp, self.lag = time, temp, temp
            return 0.0
        dt = time - self.time
        if dt > 0:
            e = math.exp(-dt / self.tau_s)
            slope_tau = (temp - self.temp) / dt * self.tau_s
            self.lag = temp - slope_tau + (self.lag - self.temp + slope_tau) * e
        self.time, self.temp = time, temp
        return temp - self.lag

    @property
    def gradient(self):
        """Return the last gradient θ - θ_lag, °C (0 before the first reading)."""
        return 0.0 if self.lag is None else self.temp - self.lag


class LagStream:
    """
    The lag of a recording read in pieces (``apply``): :func:`lagged_temperature` carried on.

    Each piece starts where the last one ended (its last time, temperature and lag), unless
    a gap longer than ``gap_s`` lies between them. ``restarts`` counts the gaps.
    """

    def __init__(self, tau_s, gap_s=LAG_GAP_S):
        self.tau_s, self.gap_s = float(tau_s), float(gap_s)
        self.last = None            # (time, temp, lag) of the last finite reading
        self.restarts = 0

    def gradient(self, time, temp):
        """Return θ - θ_lag (N,) °C of the next piece; 0 where the temperature is unknown."""
        time = np.asarray(time, float)
        temp = np.asarray(temp, float)
        out = np.zeros(len(temp))
        ok = np.isfinite(temp) & np.isfinite(time)
        if not ok.any():
            return out
        t, x = time[ok], temp[ok]
        if self.last is not None and 0.0 <= t[0] - self.last[0] <= self.gap_s:
            t0, x0, lag0 = self.last
            lag = lagged_temperature(np.r_[t0, t], np.r_[x0, x], self.tau_s, self.gap_s,
                                     start_gradient=x0 - lag0)[1:]
        else:
            if self.last is not None:
                self.restarts += 1
            lag = lagged_temperature(t, x, self.tau_s, self.gap_s)
        self.restarts += int(np.sum(~((np.diff(t) >= 0) & (np.diff(t) <= self.gap_s))))
        self.last = (float(t[-1]), float(x[-1]), float(lag[-1]))
        out[ok] = x - lag
        return out


@dataclass
class Hysteresis:
    """
    The heating/cooling term of a thermal calibration: ``offset_i += k_i (θ - θ_lag)``.

    :param tau_s: time constant of the lag, s (None before a fit chooses it).
    :param offset_per_c: (3,) k, m/s² per °C of gradient θ - θ_lag (0 on an axis the data
        did not show it on). On a steady ramp at r °C/s the gradient is about tau r, so the
        offset is about k tau r: positive k reads higher while heating.
    :param effect: the library effect it was named as (``temperature_rate``, ...).
    :param gap_s: a silence of the temperature longer than this restarts the lag, s.
    """

    tau_s: float
    offset_per_c: np.ndarray = field(default_factory=lambda: np.zeros(3))
    effect: str = 'temperature_rate'
    gap_s: float = LAG_GAP_S

    def __post_init__(self):
        self.tau_s = None if self.tau_s is None else float(self.tau_s)
        self.offset_per_c = np.asarray(self.offset_per_c, float).reshape(3).copy()

    def offset(self, time, temp):
        """Return what the term adds to the readings, (N, 3) m/s², at ``temp`` and ``time``."""
        return np.outer(self.gradient(time, temp), self.offset_per_c)

    def gradient(self, time, temp):
        """Return θ - θ_lag (N,) °C; 0 where the temperature is unknown."""
        temp = np.asarray(temp, float)
        ok = np.isfinite(temp) & np.isfinite(time)
        out = np.zeros(len(temp))
        if ok.any():
            t, x = np.asarray(time, float)[ok], temp[ok]
            out[ok] = x - lagged_temperature(t, x, self.tau_s, self.gap_s)
        return out

    def per_rate_mg(self, gravity):
        """Return the offset per °C/min of a steady ramp, mg per axis (3,)."""
        return self.offset_per_c * self.tau_s / 60.0 / gravity * 1000.0

    def to_dict(self):
        """Plain YAML-ready mapping."""
        return {'effect': self.effect, 'tau_s': self.tau_s,
                'offset_per_c_m_s2': [float(v) for v in self.offset_per_c],
                'gap_s': self.gap_s,
                'model': 'offset_i += offset_per_c_m_s2[i] (T - T_lag), tau_s dT_lag/dt = '
                         'T - T_lag (restarts when the temperature is silent for gap_s)'}

    @classmethod
    def from_dict(cls, d):
        """Inverse of :meth:`to_dict` (no validation: see dataio.calibration_file)."""
        return cls(float(d['tau_s']), np.asarray(d['offset_per_c_m_s2'], float),
                   str(d.get('effect', 'temperature_rate')), float(d.get('gap_s', LAG_GAP_S)))
