"""
What an effect of the model-gap library is: the one class every effect derives from.

An effect is a term ``raw += columns(a, temp, time) @ params`` of the sensor model. All
the workflow and the simulator ask of an effect is a method or an attribute of
:class:`Effect`, with a default that suits most effects; a subclass overrides only what
its physics changes. No other module keeps a rule keyed by an effect's name.

- **fit**: ``columns``, ``applicable``, ``magnitude``; ``bind``/``bindings``/``search``,
  ``searched`` and ``continuous_search`` for a parameter found by a search (a time
  constant); ``nests``;
- **selection**: ``variable`` (its family), ``in_baseline`` (the baselines that already
  hold it), ``contradiction`` (a measurement about it alone that contradicts it as
  fitted: the still data of a drift);
- **naming power** (``power``): ``simulated_bindings``, ``simulate_shapes`` (how a
  replicate of it is drawn), ``replay_veto`` (its contradiction, replayed);
- **verdict**: ``roughness`` (what it leaves that no smooth term follows);
- **advice**: ``separation_advice`` from ``variable``, ``acts_on``, ``history`` and
  ``free_curve``: what to record to tell it from another effect;
- **calibration node**: ``modelled_by_thermal_tables``;
- **simulator** (``sim.sensor``, ``accel-calib simulate``, the virtual device):
  ``datasheet`` and ``sensor_range`` in ``datasheet_unit`` (``to_si``), ``sensor_field`` and
  ``sensor_settings`` or, without a field, its own ``columns`` (``hide_in``, ``draw_into``),
  ``drawn_always``, ``on_device``, ``sim_note``.
"""

from dataclasses import dataclass

import numpy as np

from ..core.constants import G0


@dataclass
class Measurements:
    """
    What the session measured beside the windows' fit, for an effect to check itself against.

    :param conditions: the session's ``model.Conditions``.
    :param still: the drift the still windows show (``agreement.still_drift``), or None.
    :param noise_dof: degrees of freedom of the measured noise level (inf: known).
    """

    conditions: object
    still: dict = None
    noise_dof: float = float('inf')


SEPARATE_BY_POSES = 'record more poses spread over the sphere (each axis up, down and sideways)'
"""The advice when nothing about two effects' families separates them better."""

TOGETHER_R = 0.9
"""|r| of temperature and time from which a straight line in time imitates temperature."""


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
    """Its family: the session variable its residual follows ('direction', 'temperature' or
    'time'; a ``diagnose`` probe name)."""
    acts_on = 'offset'
    """What it changes: 'offset', 'scale' (in proportion to the acceleration) or 'axes' (the
    cross-axis terms). Two effects of one family that change different things separate by
    poses."""
    history = False
    """Its response follows the history of its variable (a lag), not only its present value."""
    free_curve = False
    """It follows any smooth curve of its variable (a wander), not one fixed shape."""
    searched = 0
    """Parameters chosen by a search before the fit (a time constant): counted in tests."""
    continuous_search = False
    """Its searched parameter is continuous (a time constant): chosen again about every joint
    fit (``setfit.SessionFits``), not only on the residuals of the set without it."""
    nests = ()
    """Library effects this one contains as a special case (it replaces them in a set)."""
    in_baseline = ()
    """Baselines ('ml', 'gn') whose model holds its terms already: it is not tested there, and
    a baseline without them names it only when the ``ml`` fit's own terms are significant."""
    modelled_by_thermal_tables = False
    """The calibration's temperature-band tables model it: the calibration node does not
    report it missing when the calibration has usable bands (``session.gap``)."""
    one_pose = False
    """One still pose while the temperature sweeps can show it (``modelgap.still_pose``: per-axis
    offsets in temperature and time; no direction, no scale)."""
    heating = False
    """It depends on the direction of the temperature's change: its columns change sign
    where the session heats instead of cools (``reverse_heating``), and its size counts what
    it does in the direction a one-pose recording did not run (``modelgap.still_pose``)."""

    # -- the simulator ----------------------------------------------------------------------

    datasheet = None
    """Size per axis at which the simulator hides it (``sim.sensor.with_datasheet_effect`` at
    1x), in ``datasheet_unit``; None: the simulator cannot show it."""
    datasheet_unit = ''
    """The unit of ``datasheet`` and ``sensor_range`` (``to_si`` converts to the sensor's)."""
    sensor_range = None
    """(low, high) of the size per axis of a random MPU-9250-like sensor that has it
    (``sim.sensor.mpu9250_like(effects=...)``), in ``datasheet_unit``; None: part of every
    simulated sensor (cross-axis terms), not switched on by name."""
    sensor_field = ''
    """The ``sim.sensor.SensorModel`` field (3,) that holds its size in SI units; '' for an
    effect simulated by its own ``columns`` (``SensorModel.library_effects``)."""
    sensor_settings = ()
    """Other SensorModel fields set with the datasheet size: ((field, value), ...)."""
    drawn_always = False
    """Part of every random sensor's draws, asked for or not, in library order (the first
    effects: seeded sessions keep their numbers). Others are drawn only when asked, after
    those, in library order, so adding an effect changes no existing seeded session."""
    on_device = True
    """The virtual device (``accel-calib simulate-device --effects``) can show it. It holds
    its last pose with ``SensorModel.measure``, which has no session history (no lag, no
    wander)."""
    sim_note = ''
    """A few words on how the simulator shows it (``accel-calib simulate --help``)."""

    def applicable(self, context, baseline):
        """Return '' when the session can show this effect, else the reason it cannot."""
        return ''

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

    def simulated_bindings(self, c):
        """Return the bindings the naming simulation (``power``) injects and searches over."""
        return self.bindings(c)

    def same_binding(self, other):
        """Tell whether another binding of the search is this one (``continuous_search``)."""
        return True

    def searched_values(self):
        """Return the searched parameters as found, JSON-ready (the step's evidence)."""
        return {}

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

    # -- what measurements about it alone say ------------------------------------------------

    def contradiction(self, setfit, measured):
        """
        Return why a measurement about this effect alone contradicts it as fitted, or ''.

        :param setfit: the ``setfit.SetFit`` of a set that holds it (its model, fit, basis).
        :param measured: :class:`Measurements` of the session.
        """
        return ''

    def roughness(self, model, x, c):
        """
        Return the variance per window it leaves beyond its terms along gravity, (m/s²)².

        0 for an effect its terms describe exactly; a random walk leaves its roughness
        (the verdict then judges what is left against it).
        """
        return 0.0

    # -- the naming simulation (``power``) -----------------------------------------------------

    def simulate_shapes(self, design, rng, count):
        """
        Return ``count`` replicates of the effect with a worst case of 1 mg, (count, N).

        Each replicate: one of its simulated bindings not confounded with a named effect,
        at random, and a random direction of its parameters, as the change of the
        normalised residuals (``design``: ``power.Design``).
        """
        options = [b for b in design.options[self.name] if not b.confounded]
        truth = rng.integers(len(options), size=count)
        shape = np.zeros((count, design.n))
        for j in np.unique(truth):
            b = options[j]
            idx = np.flatnonzero(truth == j)
            u = rng.standard_normal((len(idx), b.cols.shape[1]))
            u /= b.size_mg(u)[:, None]
            shape[idx] = u @ b.cols.T
        return shape

    def replay_veto(self, stack, params, chi2, design):
        """
        Return, for replicates that chose bindings of ``stack``, why each is contradicted.

        The naming simulation's replay of ``contradiction``: (R,) reasons ('' where none), or
        None when the effect has no contradiction to replay.

        :param stack: ``power.Stack`` of the bindings. :param params: (R, k) fitted parameters.
        :param chi2: (R,) chi² with the effect. :param design: ``power.Design``.
        """
        return None

    def reverse_heating(self, cols):
        """Return its columns (N, 3, k) at the same temperatures run the other way."""
        return -cols if self.heating else cols

    # -- what to record to tell it from another --------------------------------------------------

    def separation_advice(self, other, c):
        """
        Return what to record so that this effect and ``other`` can be told apart, or ''.

        By family: a time effect and a temperature effect separate when temperature and
        time do (a wandering offset follows a smooth temperature curve as well, a straight
        drift one that moves with time); two temperature effects by poses when one changes
        the offset and the other the scale, by the speed of the temperature when one
        follows its history. '' leaves the general advice (``SEPARATE_BY_POSES``).

        :param c: the session's ``model.Conditions``.
        """
        families = {self.variable, other.variable}
        if families == {'time', 'temperature'}:
            timed = self if self.variable == 'time' else other
            r = float(np.corrcoef(c.temp, c.time)[0, 1]) if c.temp_span > 0 else 0.0
            if timed.free_curve or abs(r) < TOGETHER_R:
                return ('the temperature follows a smooth curve in time, which a wandering '
                        'offset can follow too; let the temperature go up and down more than '
                        'once, or hold it steady for a while, so the two separate')
            return (f'temperature and time move together in this session (r = {r:.2f}); hold '
                    'the temperature steady for a while, or let it fall, so the two separate')
        if families == {'temperature'}:
            if self.acts_on != other.acts_on:
                return ('record poses with each axis both up and down at every temperature, '
                        'so an offset and a scale change look different')
            if self.history != other.history:
                return ('change the temperature faster than the die follows it (a step, or '
                        'warm-up and cool-down), or hold each temperature until the die '
                        'settles')
            if self.history and other.history:
                return ('ramp at two different rates, with holds between them: a die that lags '
                        "moves the offset by the curve's slope times its lag, a gradient by "
                        'the rate whatever the slope')
        return ''

    # -- the simulator ----------------------------------------------------------------------

    def to_si(self, value):
        """Return a size in ``datasheet_unit`` in the SI unit of the sensor's field."""
        return value

    def hide_in(self, sensor, size):
        """
        Give a ``sim.sensor.SensorModel`` copy this effect of ``size`` (3,) per axis, SI.

        The field ``sensor_field`` (and ``sensor_settings``); without one, the effect's own
        columns with ``size`` as its parameters (``SensorModel.library_effects``).
        """
        if self.sensor_field:
            setattr(sensor, self.sensor_field, size)
        else:
            if len(self.param_names) != len(size):
                raise NotImplementedError(f'{self.name}: say how the simulator shows it '
                                          '(sensor_field or hide_in)')
            sensor.library_effects = tuple(sensor.library_effects) + ((self, size),)
        for key, value in self.sensor_settings:
            setattr(sensor, key, value)

    def draw(self, rng):
        """Return a random size per axis (3,), SI: uniform in ``sensor_range``, random signs."""
        low, high = self.sensor_range
        return self.to_si(rng.uniform(low, high, 3) * rng.choice([-1.0, 1.0], 3))

    def draw_into(self, sensor, rng, asked):
        """
        Give a random sensor (``mpu9250_like``) this effect of a random size.

        A field another effect asked for sets as well keeps that one's size (the lag's offset
        coefficient is the temperature_bias's when both are asked for).

        :param asked: the library Effects asked for.
        """
        if not any(other is not self and self.sensor_field
                   and other.sensor_field == self.sensor_field for other in asked):
            self.hide_in(sensor, self.draw(rng))


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


def _per_axis(values):
    """Put a (N, 3) per-axis quantity on the diagonal of (N, 3, 3) columns."""
    cols = np.zeros(values.shape + (3,))
    for i in range(3):
        cols[:, i, i] = values[:, i]
    return cols


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
