"""
The library of physical effects the model-gap workflow can add to a calibration.

An effect is one small class (``effect.Effect``): its name (the interface's vocabulary),
what it is physically, its parameters with units, when a session can see it, and its
design-matrix columns: the change of the raw reading per unit parameter, evaluated at the
true acceleration, the temperature and the time. The same columns drive the fit
(``diagnose``) and the simulation (``Effect.apply``), so both always agree. Everything
else the workflow and the simulator ask of an effect (its family, what contradicts it,
how its replicates are drawn, what separates it from another, its datasheet size) is an
attribute or a method of that class, with a default that suits most effects.

Adding an effect is adding one subclass to ``EFFECTS``, for example an offset that moves
with the square of the temperature::

    class TemperatureBiasQuadratic(PerAxisEffect):
        name = 'temperature_bias_quadratic'
        description = 'the zero-g offset bends with temperature'
        param_names = ('c2_x', 'c2_y', 'c2_z')
        unit = 'm/s² per °C²'
        label = 'offset curvature'
        variable = 'temperature'
        applicable = TemperatureBias.applicable
        datasheet_unit = 'g per °C²'
        datasheet = 0.05e-3
        sensor_range = (0.02e-3, 0.05e-3)

        def columns(self, accel, temp, time, gravity=G0):
            return _per_axis(np.repeat(temp[:, None] ** 2, 3, axis=1))

        def axis_text(self, value, gravity):
            return f'{1000 * value / gravity:+.4f} mg/°C²'

        def to_si(self, value):
            return value * G0

and listing ``TemperatureBiasQuadratic()`` at the end of ``EFFECTS`` (a test sets
``EFFECTS[effect.name] = effect``). The fit, the search and the F-test, the ambiguity
notes with what to record to separate it from a rival (by its family, ``variable``), the
visibility check, the naming power, the null simulation, the report and the JSON then pick
it up; so do the simulator (``sim.sensor.with_datasheet_effect`` and ``mpu9250_like``, by
its own columns since it names no sensor field), ``accel-calib simulate --effects`` and the
virtual device.
"""

import numpy as np

from .effect import _per_axis, Effect, PerAxisEffect, still_time_reason
from .walk import BiasRandomWalk
from ..core.constants import G0


class Nonorthogonality(Effect):
    name = 'nonorthogonality'
    description = 'the sensitive axes are not at right angles (cross-axis sensitivity)'
    param_names = ('T_xy', 'T_xz', 'T_yz')
    unit = 'dimensionless'
    acts_on = 'axes'
    in_baseline = ('ml',)
    datasheet_unit = 'fraction (cross-axis sensitivity)'
    datasheet = 0.02

    def applicable(self, context, baseline):
        return (f'the {baseline} model already has non-orthogonality'
                if baseline in self.in_baseline else '')

    def columns(self, accel, temp, time, gravity=G0):
        cols = np.zeros((len(accel), 3, 3))
        cols[:, 0, 0] = accel[:, 1]
        cols[:, 0, 1] = accel[:, 2]
        cols[:, 1, 2] = accel[:, 2]
        return cols

    def magnitude(self, params, gravity=G0, sensitivity=(1.0, 1.0, 1.0)):
        angles = np.degrees(np.asarray(params, float) / np.asarray(sensitivity)[[0, 0, 1]])
        return 'axis angles off 90°: ' + ', '.join(
            f'{pair} {v:+.3f}°' for pair, v in zip(('xy', 'xz', 'yz'), angles))

    def hide_in(self, sensor, size):
        """Make T diagonal plus these cross-axis terms: a gn baseline lacks exactly them."""
        sensor.T = np.diag(np.diag(sensor.T))
        sensor.T[np.triu_indices(3, 1)] = size


class ScaleNonlinearity(PerAxisEffect):
    name = 'scale_nonlinearity'
    description = 'the scale factor changes with the acceleration (quadratic response)'
    param_names = ('k2_x', 'k2_y', 'k2_z')
    unit = 'fraction of reading per g'
    acts_on = 'scale'
    datasheet_unit = 'fraction of reading at 1 g'
    datasheet = 0.005
    sensor_range = (0.002, 0.005)
    sensor_field = 'nonlinearity'
    drawn_always = True

    def columns(self, accel, temp, time, gravity=G0):
        return _per_axis(accel ** 2 / gravity)

    label = 'nonlinearity'

    def axis_text(self, value, gravity):
        return f'{100 * value:+.3f} % of reading at 1 g'


class TemperatureBias(PerAxisEffect):
    name = 'temperature_bias'
    description = 'the zero-g offset moves with temperature'
    param_names = ('c_x', 'c_y', 'c_z')
    unit = 'm/s² per °C'
    variable = 'temperature'
    modelled_by_thermal_tables = True
    datasheet_unit = 'g per °C'
    datasheet = 1.5e-3
    sensor_range = (0.5e-3, 1.5e-3)
    sensor_field = 'bias_tempco'
    drawn_always = True

    def applicable(self, context, baseline):
        if not context.get('has_temp', True):
            return 'no temperature column'
        span = context.get('temp_span', 0.0)
        return '' if span >= 3.0 else f'temperature spans only {span:.1f} °C'

    def columns(self, accel, temp, time, gravity=G0):
        return _per_axis(np.repeat(temp[:, None], 3, axis=1))

    label = 'offset drift'

    def axis_text(self, value, gravity):
        return f'{1000 * value / gravity:+.3f} mg/°C'

    def to_si(self, value):
        return value * G0


class TemperatureScale(PerAxisEffect):
    name = 'temperature_scale'
    description = 'the scale factor moves with temperature'
    param_names = ('s_x', 's_y', 's_z')
    unit = '1 per °C'
    variable = 'temperature'
    acts_on = 'scale'
    modelled_by_thermal_tables = True
    datasheet_unit = '1 per °C'
    datasheet = 2.6e-4
    sensor_range = (0.1e-4, 2.6e-4)
    sensor_field = 'scale_tempco'
    drawn_always = True

    applicable = TemperatureBias.applicable

    def columns(self, accel, temp, time, gravity=G0):
        return _per_axis(temp[:, None] * accel)

    label = 'scale drift'

    def axis_text(self, value, gravity):
        return f'{100 * value:+.4f} %/°C'


class BiasDrift(PerAxisEffect):
    name = 'bias_drift'
    description = 'the zero-g offset wanders with time (not with temperature)'
    param_names = ('d_x', 'd_y', 'd_z')
    unit = 'm/s² per s'
    variable = 'time'
    datasheet_unit = 'g per min (not in the datasheet)'
    datasheet = 1e-3
    sensor_range = (0.5e-3, 2e-3)
    sensor_field = 'bias_drift'
    drawn_always = True
    one_pose = True

    def applicable(self, context, baseline):
        span = context.get('time_span', 0.0)
        if span < 30.0:
            return f'the session lasts only {span:.0f} s'
        return still_time_reason(context, baseline)

    def columns(self, accel, temp, time, gravity=G0):
        return _per_axis(np.repeat(time[:, None], 3, axis=1))

    label = 'offset drift'

    def axis_text(self, value, gravity):
        return f'{60000 * value / gravity:+.3f} mg/min'

    def to_si(self, value):
        return value * G0 / 60.0

    def contradiction(self, setfit, measured):
        """
        Return why the still windows contradict the drift as fitted, or ''.

        The drift the still windows show (``agreement.still_drift``: the slope of the
        readings inside windows whose temperature held steady) against the fitted one, each
        with its covariance: chi² with 3 degrees of freedom, contradicted below
        ``criterion.P_SUPPORT``.
        """
        from scipy import stats
        from .criterion import P_SUPPORT
        still = measured.still
        if still is None:
            return ''
        model, fit = setfit.model, setfit.fit
        params = model.split(fit.x)[2][self.name]
        k = len(params)
        index = model.index(self.name)
        cov = (np.linalg.pinv(fit.jac.T @ fit.jac)[index:index + k, index:index + k]
               * max(fit.gap ** 2, 1.0))
        delta = params - still['slope']
        total = cov + np.diag(np.asarray(still['se']) ** 2)
        chi2 = float(delta @ np.linalg.solve(total, delta))
        p = float(stats.chi2.sf(chi2, k))
        if p >= P_SUPPORT:
            return ''
        per_min = 60000.0 / G0
        return ('contradicted by the still windows: over '
                f'{still["seconds"]:.0f} s of still data (longest {still["longest_s"]:.0f} s) '
                'the offset drifts ' + ', '.join(
                    f'{axis} {per_min * v:+.3g} ± {per_min * e:.2g}'
                    for axis, v, e in zip('xyz', still['slope'], still['se']))
                + ' mg/min, not ' + ', '.join(f'{axis} {per_min * v:+.3g}'
                                              for axis, v in zip('xyz', params))
                + f' (p = {p:.1e})')


def start_slope(time, temp):
    """Return the temperature's rate at the start of the session, °C/s (first three windows)."""
    k = min(3, len(time))
    if k < 2 or np.ptp(time[:k]) <= 0:
        return 0.0
    return float(np.polyfit(time[:k] - time[0], temp[:k], 1)[0])


def lagged(time, temp, tau, behind=0.0):
    """
    Return a first-order lag of a temperature sampled at ``time``, same shape.

    The temperature is taken as linear between the samples (window mid times); the
    lagged one starts ``behind`` °C below the first temperature (0: in equilibrium) and
    follows tau dθ_lag/dt = θ - θ_lag exactly on each linear piece:
    θ_lag(t1) = θ1 - s tau + (θ_lag(t0) - θ0 + s tau) exp(-(t1 - t0) / tau), s the slope.
    ``tau`` and ``behind`` may be arrays of the same shape (B,): the result is then (B, N).

    :param time: (N,) s, increasing. :param temp: (N,) °C. :param tau: time constant, s.
    """
    tau = np.asarray(tau, float)
    behind = np.broadcast_to(np.asarray(behind, float), tau.shape)
    out = np.empty(tau.shape + (len(temp),))
    out[..., 0] = temp[0] - behind
    dt = np.diff(time)
    with np.errstate(divide='ignore', invalid='ignore'):
        slope = np.where(dt > 0, np.diff(temp) / np.where(dt > 0, dt, 1.0), 0.0)
    for k in range(1, len(temp)):
        st = slope[k - 1] * tau
        decay = np.exp(-dt[k - 1] / tau)
        out[..., k] = temp[k] - st + (out[..., k - 1] - temp[k - 1] + st) * decay
    return out


class TemperatureLag(PerAxisEffect):
    name = 'temperature_lag'
    description = ('the zero-g offset follows the die temperature, which lags the reported '
                   'temperature (first order, time constant tau)')
    param_names = ('c_x', 'c_y', 'c_z')
    unit = 'm/s² per °C (of the lagged temperature)'
    variable = 'temperature'
    history = True
    searched = 2
    continuous_search = True
    label = 'offset drift with the lagged temperature'
    datasheet_unit = 'g per °C of the die temperature'
    datasheet = 1.5e-3
    sensor_range = (0.5e-3, 1.5e-3)
    sensor_field = 'bias_tempco'
    sensor_settings = (('thermal_lag_s', 120.0),)
    on_device = False
    one_pose = True
    sim_note = 'the offset follows a die temperature 1-5 min behind the recorded one'

    SENSOR_TAU_S = (60.0, 300.0)
    """Range of the die's time constant of a random sensor that has the lag, s."""

    TAU_GRID = 16
    """Time constants tried (log-spaced) before the best one is refined."""

    START_GRID = (0.0, 0.03, 0.1, 0.2, 0.35, 0.6, 1.0)
    """How far the die lags at the first window, as a share of slope x tau (see ``bind``)."""

    def __init__(self, tau=None, time=None, lag=None, start=0.0, die=False):
        self.tau, self._time, self._lag, self.start = tau, time, lag, start
        if die:
            # One still pose (``modelgap.still_pose``): the offset curve at the die's temperature,
            # linearised, a share of the lag tau per axis; it turns with the heating.
            self.unit = 'share of tau: the die lags by share x tau'
            self.heating = True

    def applicable(self, context, baseline):
        reason = TemperatureBias.applicable(self, context, baseline)
        if reason:
            return reason
        span = context.get('time_span', 0.0)
        return '' if span >= 60.0 else f'the session lasts only {span:.0f} s'

    def tau_range(self, c):
        """
        Return the time constants worth trying in this session, s.

        From twice the typical spacing of the windows (a shorter lag cannot be resolved;
        at least 1 % of the session) to the session's span (a longer one turns the
        temperature's history into a slow integral that a drift imitates).
        """
        span = max(c.time_span, 1.0)
        spacing = float(np.median(np.diff(np.sort(c.time)))) if len(c.time) > 1 else 0.0
        low = min(max(0.01 * span, 2.0 * spacing), 0.5 * span)
        return np.geomspace(low, span, self.TAU_GRID)

    def bind(self, c, tau=None, start=0.0):
        """
        Return the effect bound to this session's temperature history.

        :param tau: time constant, s (default the middle of ``tau_range``).
        :param start: the die's lag behind the reported temperature at the first window,
            as a share of what a steady rise at the starting rate s would give (s tau): 0
            when the die was in equilibrium there, 1 when the temperature had been rising
            like that for much longer than tau (a warm-up under way for L seconds gives
            1 - exp(-L / tau)). Unknown, so searched with tau.
        """
        tau = float(np.median(self.tau_range(c))) if tau is None else float(tau)
        return self._bound(c, np.array([tau]), np.array([start]))[0]

    def _bound(self, c, taus, starts):
        order = np.argsort(c.time, kind='stable')
        time, temp = c.time[order], c.temp[order]
        behind = starts * start_slope(time, temp) * taus
        lags = lagged(time, temp, taus, behind)
        slope = getattr(c, 'slope', None)
        if slope is not None:
            # One still pose: offset(θ_die) - offset(θ) = offset'(θ) (θ_lag - θ) per axis.
            return [TemperatureLag(float(tau), time, (lag - temp)[:, None] * slope[order],
                                   float(start), die=True)
                    for tau, start, lag in zip(taus, starts, lags)]
        return [TemperatureLag(float(tau), time, lag - lag.mean(), float(start))
                for tau, start, lag in zip(taus, starts, lags)]

    def bindings(self, c, starts=None):
        """Return the grid of bindings over tau and start (``starts``: a coarser list)."""
        starts = self.START_GRID if starts is None else starts
        taus, starts = np.meshgrid(self.tau_range(c), starts, indexing='ij')
        return self._bound(c, taus.ravel(), starts.ravel())

    SIMULATED_STARTS = (0.0, 0.2, 1.0)
    """The starts the naming simulation (``power``) tries: its bindings are coarser."""

    def simulated_bindings(self, c):
        """Return the bindings the naming simulation injects and searches over."""
        return self.bindings(c, self.SIMULATED_STARTS)

    def search(self, c, score):
        """
        Return the binding that scores best: the grid of (tau, start), then both refined.

        The two trade off along a narrow valley (a die that starts further behind looks like
        a longer lag for a while), so they are refined in turn, three times: tau between its
        grid neighbours (bounded, in log), the start over [0, 1].
        """
        from scipy import optimize
        options = self.bindings(c)
        scores = [score(b) for b in options]
        k = int(np.argmax(scores))
        grid = self.tau_range(c)
        i = k // len(self.START_GRID)
        low, high = np.log(grid[max(i - 1, 0)]), np.log(grid[min(i + 1, len(grid) - 1)])
        log_tau, start, top = np.log(options[k].tau), options[k].start, scores[k]
        for _ in range(3):
            found = optimize.minimize_scalar(lambda v: -score(self.bind(c, np.exp(v), start)),
                                             bounds=(low, high), method='bounded',
                                             options={'xatol': 0.005})
            if -found.fun > top:
                log_tau, top = found.x, -found.fun
            found = optimize.minimize_scalar(lambda v: -score(self.bind(c, np.exp(log_tau), v)),
                                             bounds=(0.0, 1.0), method='bounded',
                                             options={'xatol': 0.002})
            if -found.fun > top:
                start, top = found.x, -found.fun
        return self.bind(c, np.exp(log_tau), start)

    def same_binding(self, other):
        return abs(np.log(other.tau / self.tau)) < 0.005 and other.start == self.start

    def searched_values(self):
        return {} if self.tau is None else {'tau_s': float(self.tau)}

    def columns(self, accel, temp, time, gravity=G0):
        if self._time is None:
            raise ValueError('temperature_lag needs a session: use bind(conditions, tau)')
        if self._lag.ndim == 2:
            return _per_axis(np.column_stack([np.interp(time, self._time, self._lag[:, i])
                                              for i in range(3)]))
        value = np.interp(time, self._time, self._lag)
        return _per_axis(np.repeat(value[:, None], 3, axis=1))

    def axis_text(self, value, gravity):
        return f'{1000 * value / gravity:+.3f} mg/°C'

    def magnitude(self, params, gravity=G0, sensitivity=(1.0, 1.0, 1.0)):
        if self._lag is not None and self._lag.ndim == 2:
            share = np.asarray(params, float)
            return ('the offset follows a die temperature that lags the reported one by '
                    + ', '.join(f'{axis} {v * self.tau:.3g} s' for axis, v in zip('xyz', share))
                    + f' (shares {", ".join(f"{v:+.2f}" for v in share)} of tau = '
                    f'{self.tau:.3g} s)')
        return (super().magnitude(params, gravity, sensitivity)
                + f'; the die lags the reported temperature by tau = {self.tau:.3g} s')

    def to_si(self, value):
        return value * G0

    def draw_into(self, sensor, rng, asked):
        """Give a random sensor the lag: its offset coefficient, then a die 1-5 min behind."""
        super().draw_into(sensor, rng, asked)
        sensor.thermal_lag_s = float(rng.uniform(*self.SENSOR_TAU_S))


class TemperatureRate(PerAxisEffect):
    name = 'temperature_rate'
    description = ('the offset follows the rate of temperature change smoothed over tau (a '
                   'temperature gradient across the package): heating reads differently from '
                   'cooling at the same temperature')
    param_names = ('k_x', 'k_y', 'k_z')
    unit = 'm/s² per °C of gradient (the temperature minus its first-order lag tau)'
    variable = 'temperature'
    history = True
    searched = 1
    continuous_search = True
    one_pose = True
    heating = True
    on_device = False
    label = 'offset with the heating rate'
    sim_note = ('a temperature gradient across the package (sim.chamber: accel-calib simulate '
                '--chamber --hysteresis MG)')

    TAU_GRID = 12
    """Time constants tried (log-spaced) before the best one is refined."""

    MAX_TAU_S = 180.0
    """Longest smoothing tried, s: a gradient across a package or a board settles in tens of
    seconds (30-60 s on a real chamber cycle); longer ones only imitate a bend of the curve
    on a warm-up, whose rate follows its temperature."""

    def __init__(self, tau=None, time=None, gradient=None):
        self.tau, self._time, self._gradient = tau, time, gradient

    def applicable(self, context, baseline):
        if baseline != 'still':
            return ('tested on one still pose while the temperature sweeps (diagnose '
                    '--calibration, fit --thermal --calibration)')
        reason = TemperatureBias.applicable(self, context, baseline)
        if reason:
            return reason
        span = context.get('time_span', 0.0)
        return '' if span >= 300.0 else f'the recording lasts only {span:.0f} s'

    def tau_range(self, c):
        """
        Return the smoothing times worth trying, s.

        From twice the spacing of the bins (at least 5 s) to a quarter of the recording (at
        most 30 min).
        """
        span = max(c.time_span, 1.0)
        spacing = float(np.median(np.diff(np.sort(c.time)))) if len(c.time) > 1 else 1.0
        low = max(2.0 * spacing, 5.0)
        return np.geomspace(low, max(min(0.25 * span, self.MAX_TAU_S), 2.0 * low), self.TAU_GRID)

    def bind(self, c, tau=None):
        """Return the effect bound to this session's temperature history at ``tau`` s."""
        from ..core.accelerometer.thermal_lag import LAG_GAP_S, lagged_temperature
        tau = float(np.median(self.tau_range(c))) if tau is None else float(tau)
        order = np.argsort(c.time, kind='stable')
        time, temp = c.time[order], c.temp[order]
        spacing = float(np.median(np.diff(time))) if len(time) > 1 else 1.0
        gradient = temp - lagged_temperature(time, temp, tau, max(LAG_GAP_S, 1.5 * spacing))
        return TemperatureRate(tau, time, gradient)

    def bindings(self, c):
        return [self.bind(c, tau) for tau in self.tau_range(c)]

    def search(self, c, score):
        """Return the binding that scores best: the grid of tau, then refined in between."""
        from scipy import optimize
        grid = self.tau_range(c)
        scores = [score(self.bind(c, tau)) for tau in grid]
        k = int(np.argmax(scores))
        low, high = np.log(grid[max(k - 1, 0)]), np.log(grid[min(k + 1, len(grid) - 1)])
        found = optimize.minimize_scalar(lambda v: -score(self.bind(c, np.exp(v))),
                                         bounds=(low, high), method='bounded',
                                         options={'xatol': 0.005})
        best = np.exp(found.x) if -found.fun > scores[k] else grid[k]
        return self.bind(c, best)

    def same_binding(self, other):
        return abs(np.log(other.tau / self.tau)) < 0.005

    def searched_values(self):
        return {} if self.tau is None else {'tau_s': float(self.tau)}

    def columns(self, accel, temp, time, gravity=G0):
        if self._time is None:
            raise ValueError('temperature_rate needs a session: use bind(conditions, tau)')
        value = np.interp(time, self._time, self._gradient)
        return _per_axis(np.repeat(value[:, None], 3, axis=1))

    def axis_text(self, value, gravity):
        return f'{1000 * value * self.tau / 60.0 / gravity:+.3f} mg per °C/min'

    def magnitude(self, params, gravity=G0, sensitivity=(1.0, 1.0, 1.0)):
        return (super().magnitude(params, gravity, sensitivity)
                + f' of heating (the rate smoothed over tau = {self.tau:.3g} s)')


EFFECTS = {effect.name: effect for effect in (
    Nonorthogonality(), ScaleNonlinearity(), TemperatureBias(), TemperatureScale(),
    BiasDrift(), TemperatureLag(), TemperatureRate(), BiasRandomWalk())}
"""The effect library, by spec name."""


def effect_of(entry):
    """Return the Effect for a library name or a (session-bound) Effect."""
    return EFFECTS[entry] if isinstance(entry, str) else entry


def name_of(entry):
    """Return the library name of a name or an Effect."""
    return entry if isinstance(entry, str) else entry.name
