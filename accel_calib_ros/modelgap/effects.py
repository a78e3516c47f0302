"""
The library of physical effects the model-gap workflow can add to a calibration.

An effect is one small class: its name (the interface's vocabulary), what it is
physically, its parameters with units, when a session can see it, and its
design-matrix columns: the change of the raw reading per unit parameter, evaluated
at the true acceleration, the temperature and the time. The same columns drive the
fit (``diagnose``) and the simulation (``Effect.apply``), so both always agree.
Adding an effect is adding one subclass to ``EFFECTS``, for example an offset that
moves with the square of the temperature::

    class TemperatureBias2(PerAxisEffect):
        name = 'temperature_bias_quadratic'
        description = 'the zero-g offset bends with temperature'
        param_names = ('c2_x', 'c2_y', 'c2_z')
        unit = 'm/s² per °C²'
        label = 'offset curvature'
        applicable = TemperatureBias.applicable

        def columns(self, accel, temp, time, gravity=G0):
            return _per_axis(np.repeat(temp[:, None] ** 2, 3, axis=1))

        def axis_text(self, value, gravity):
            return f'{1000 * value / gravity:+.4f} mg/°C²'

The search, the F-test, the ambiguity and visibility checks, the null simulation,
the report and the JSON then pick it up.
"""

import numpy as np

from ..core.constants import G0


class Effect:
    """
    Base class: a term ``raw += columns(a, temp, time) @ params`` of the sensor model.

    :param name: spec vocabulary name.
    :param description: one line of physics for people.
    :param param_names: names of the parameters, in order.
    :param unit: SI unit of the parameters.
    """

    name = ''
    description = ''
    param_names = ()
    unit = ''
    variable = 'direction'
    """The session variable the effect's residual follows (a ``diagnose`` probe name)."""
    searched = 0
    """Parameters chosen by a search before the fit (a time constant): counted in tests."""
    nests = ()
    """Library effects this one contains as a special case (it replaces them in a set)."""
    one_pose = False
    """Whether one still pose while the temperature sweeps can show it (``modelgap.still``:
    per-axis offsets in temperature and time, no direction, no scale)."""

    def applicable(self, context, baseline):
        """Return '' when the session can show this effect, else the reason it cannot."""
        return ''

    heating = False
    """Whether the effect depends on the direction of the temperature's change: then its
    columns change sign where the session heats instead of cools (``reverse_heating``), and
    its size counts what it does in the direction the session did not run (``still``)."""

    def reverse_heating(self, cols):
        """Return the columns (N, 3, k) at the same temperatures run the other way."""
        return -cols if self.heating else cols

    def bind(self, c):
        """
        Return the effect as it applies to one session (``model.Conditions``).

        Most effects are the same in every session. One whose columns depend on the
        session's history (a lagged temperature) or span (a smooth basis in time)
        returns a copy bound to that history, so that it can then be evaluated at any
        single condition (the worst case, a held-out window).
        """
        return self

    def bindings(self, c):
        """Return the session-bound versions to search over (one, unless a search is needed)."""
        return [self.bind(c)]

    def search(self, c, score):
        """Return the session-bound version with the highest ``score(bound)``."""
        options = self.bindings(c)
        if len(options) == 1:
            return options[0]
        return max(options, key=score)

    def columns(self, accel, temp, time, gravity=G0):
        """
        Return the design columns, shape (N, 3, k).

        :param accel: (N, 3) true specific force, m/s².
        :param temp: (N,) temperature minus the session mean, °C.
        :param time: (N,) time minus the session mean, s.
        """
        raise NotImplementedError

    def apply(self, params, accel, temp, time, gravity=G0):
        """Return the change of the raw reading (N, 3), m/s², for ``params`` (k,)."""
        return self.columns(accel, temp, time, gravity) @ np.asarray(params, float)

    def magnitude(self, params, gravity=G0, sensitivity=(1.0, 1.0, 1.0)):
        """
        Return the fitted size in the units a datasheet uses, as text.

        :param sensitivity: (3,) diagonal of the fitted T, readings per m/s² (1 for
            data in m/s²; the counts per m/s² for raw-count recordings).
        """
        raise NotImplementedError


def _per_axis(values):
    """Put a (N, 3) per-axis quantity on the diagonal of (N, 3, 3) columns."""
    cols = np.zeros(values.shape + (3,))
    for i in range(3):
        cols[:, i, i] = values[:, i]
    return cols


class Nonorthogonality(Effect):
    name = 'nonorthogonality'
    description = 'the sensitive axes are not at right angles (cross-axis sensitivity)'
    param_names = ('T_xy', 'T_xz', 'T_yz')
    unit = 'dimensionless'

    def applicable(self, context, baseline):
        return 'the ml model already has non-orthogonality' if baseline == 'ml' else ''

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


class PerAxisEffect(Effect):
    """An effect with one parameter per axis, reported per axis after dividing by T_ii."""

    label = ''

    def axis_text(self, value, gravity):
        """Return one axis's parameter (per unit sensitivity) as datasheet text."""
        raise NotImplementedError

    def magnitude(self, params, gravity=G0, sensitivity=(1.0, 1.0, 1.0)):
        params = np.asarray(params, float) / np.asarray(sensitivity)
        return f'{self.label} ' + ', '.join(
            f'{axis} {self.axis_text(v, gravity)}' for axis, v in zip('xyz', params))


class ScaleNonlinearity(PerAxisEffect):
    name = 'scale_nonlinearity'
    description = 'the scale factor changes with the acceleration (quadratic response)'
    param_names = ('k2_x', 'k2_y', 'k2_z')
    unit = 'fraction of reading per g'

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


class TemperatureScale(PerAxisEffect):
    name = 'temperature_scale'
    description = 'the scale factor moves with temperature'
    param_names = ('s_x', 's_y', 's_z')
    unit = '1 per °C'
    variable = 'temperature'

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


MONOTONIC = 0.9
"""On one still pose, a rank correlation of temperature with time beyond this hides a
time effect in the offset's curve."""


def still_time_reason(context, baseline):
    """
    Return why a time effect cannot be tested on one still pose here, or ''.

    The one-pose baseline follows the offset along the temperature; while the temperature
    only rises (or only falls), time is a function of it, and a drift or a wander is one
    more bend of that curve.
    """
    r = context.get('time_temp_rank', 0.0)
    if baseline != 'still' or abs(r) <= MONOTONIC:
        return ''
    return (f'temperature and time move together in this recording (rank correlation '
            f"{r:+.2f}): a change with time is a bend of the offset's curve here; let the "
            'temperature fall and rise again (a chamber cycle) to tell them apart')


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
    one_pose = True
    searched = 2
    label = 'offset drift with the lagged temperature'

    TAU_GRID = 16
    """Time constants tried (log-spaced) before the best one is refined."""

    START_GRID = (0.0, 0.03, 0.1, 0.2, 0.35, 0.6, 1.0)
    """How far the die lags at the first window, as a share of slope x tau (see ``bind``)."""

    def __init__(self, tau=None, time=None, lag=None, start=0.0, die=False):
        self.tau, self._time, self._lag, self.start = tau, time, lag, start
        if die:
            # One still pose: the offset curve at the die's temperature, linearised, a share
            # per axis of the lag tau (``modelgap.still``); it turns with the heating.
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


class TemperatureRate(PerAxisEffect):
    name = 'temperature_rate'
    description = ('the offset follows the rate of temperature change smoothed over tau (a '
                   'temperature gradient across the package): heating reads differently from '
                   'cooling at the same temperature')
    param_names = ('k_x', 'k_y', 'k_z')
    unit = 'm/s² per °C of gradient (the temperature minus its first-order lag tau)'
    variable = 'temperature'
    searched = 1
    one_pose = True
    heating = True
    label = 'offset with the heating rate'

    TAU_GRID = 12
    """Time constants tried (log-spaced) before the best one is refined."""

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
        return np.geomspace(low, max(min(0.25 * span, 1800.0), 2.0 * low), self.TAU_GRID)

    def bind(self, c, tau=None):
        """Return the effect bound to this session's temperature history at ``tau`` s."""
        from ..core.accelerometer.thermal_lag import GAP_S, lagged_temperature
        tau = float(np.median(self.tau_range(c))) if tau is None else float(tau)
        order = np.argsort(c.time, kind='stable')
        time, temp = c.time[order], c.temp[order]
        spacing = float(np.median(np.diff(time))) if len(time) > 1 else 1.0
        gradient = temp - lagged_temperature(time, temp, tau, max(GAP_S, 1.5 * spacing))
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


class BiasRandomWalk(Effect):
    name = 'bias_random_walk'
    description = ('the zero-g offset wanders with time (a smooth random walk, not a straight '
                   'line and not with temperature)')
    unit = 'm/s²'
    variable = 'time'
    one_pose = True
    nests = ('bias_drift',)

    def __init__(self, degree=None, start=0.0, span=1.0):
        self.degree, self.start, self.span = degree, start, span

    @property
    def param_names(self):
        if not self.degree:
            return ()
        return tuple(f'o_{axis}_{j}' for axis in 'xyz' for j in range(self.degree + 1))

    MAX_DEGREE = 4
    """Most cosine terms per axis (beside the trend): with it they hold most of a random
    walk's variance about its mean (its cosine coefficients fall like 1/k); a dependence with
    more structure (a cycle, a step) is left to the time probe and the step alternative."""

    @classmethod
    def degrees_for(cls, windows):
        """Return the numbers of smooth terms per axis to try in a session (2 to 4)."""
        return range(2, int(min(cls.MAX_DEGREE, max(2, (windows - 12) // 6))) + 1)

    def applicable(self, context, baseline):
        span = context.get('time_span', 0.0)
        if span < 60.0:
            return f'the session lasts only {span:.0f} s'
        windows = context.get('windows', 0)
        if windows < 30:
            return f'{windows} windows are too few to follow a wander'
        return still_time_reason(context, baseline)

    def bind(self, c, degree=2):
        return BiasRandomWalk(degree, float(np.min(c.time)), float(max(np.ptp(c.time), 1e-9)))

    def bindings(self, c):
        return [self.bind(c, d) for d in self.degrees_for(len(c.time))]

    def search(self, c, score):
        """Return the binding with the best BIC: a random walk is as rough as the data show."""
        n = len(c.time)
        return max(self.bindings(c), key=lambda b: score(b) - len(b.param_names) * np.log(n))

    def basis(self, time):
        """
        Return the wander's terms over the session, (N, degree + 1).

        u - 1/2 (a walk's trend: its cosine series converges slowly, so the straight part
        is a term of its own, and a plain drift is a special case) and cos(k pi u),
        k = 1..degree, u the time scaled to [0, 1] over the session.
        """
        u = np.clip((np.asarray(time, float) - self.start) / self.span, 0.0, 1.0)
        k = np.arange(1, self.degree + 1)
        return np.column_stack([u - 0.5, np.cos(np.pi * k[None, :] * u[:, None])])

    def columns(self, accel, temp, time, gravity=G0):
        if self.degree is None:
            raise ValueError('bias_random_walk needs a session: use bind(conditions)')
        phi = self.basis(time)
        k = self.degree + 1
        cols = np.zeros((len(time), 3, 3 * k))
        for i in range(3):
            cols[:, i, i * k:(i + 1) * k] = phi
        return cols

    def cosines(self, params):
        """Return the cosine coefficients of parameters (..., 3 (d + 1)) as (..., 3, d)."""
        p = np.asarray(params, float)
        return p.reshape(p.shape[:-1] + (3, self.degree + 1))[..., 1:]

    def brownian(self, time):
        """
        Return what a walk of K = 1 per √s does to these terms at window times ``time``.

        (variance of each cosine coefficient (d,), mean variance per window left beyond all
        the terms and a constant): a Brownian path from the session's start, covariance
        min(t_a, t_b), least-squares fitted by a constant and the terms.
        """
        t = np.asarray(time, float) - self.start
        m = np.minimum.outer(t, t)
        design = np.column_stack([np.ones(len(t)), self.basis(time)])
        a = np.linalg.pinv(design)
        factors = np.einsum('kn,nm,km->k', a, m, a)[2:]
        rest = np.eye(len(t)) - design @ a
        return factors, float(np.trace(rest @ m @ rest.T)) / len(t)

    def wander(self, params, gravity=G0, sensitivity=(1.0, 1.0, 1.0), points=200):
        """Return the offset wander over the session, (points, 3), in g per axis."""
        phi = self.basis(self.start + self.span * np.linspace(0.0, 1.0, points))
        coef = np.asarray(params, float).reshape(3, self.degree + 1)
        path = phi @ coef.T / np.asarray(sensitivity)
        return (path - path.mean(axis=0)) / gravity

    def magnitude(self, params, gravity=G0, sensitivity=(1.0, 1.0, 1.0)):
        path = self.wander(params, gravity, sensitivity)
        rms = np.sqrt(np.mean(path ** 2, axis=0))
        # A random walk of K per sqrt(s) wanders K sqrt(T / 6) RMS about its mean over T.
        k = rms / np.sqrt(self.span / 6.0)
        return ('offset wander ' + ', '.join(
            f'{axis} {1000 * r:.3f} mg RMS' for axis, r in zip('xyz', rms))
            + ' over the session; as a random walk about '
            + ', '.join(f'{1000 * v:.3g}' for v in k) + ' mg/√s')


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
