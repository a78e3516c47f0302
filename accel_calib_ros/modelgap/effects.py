"""
The library of physical effects the model-gap workflow can add to a calibration.

An effect is one small class: its name (the spec's vocabulary), what it is
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

G0 = 9.80665


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

    def applicable(self, context, baseline):
        """Return '' when the session can show this effect, else the reason it cannot."""
        return ''

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

    def applicable(self, context, baseline):
        span = context.get('time_span', 0.0)
        return '' if span >= 30.0 else f'the session lasts only {span:.0f} s'

    def columns(self, accel, temp, time, gravity=G0):
        return _per_axis(np.repeat(time[:, None], 3, axis=1))

    label = 'offset drift'

    def axis_text(self, value, gravity):
        return f'{60000 * value / gravity:+.3f} mg/min'


EFFECTS = {effect.name: effect for effect in (
    Nonorthogonality(), ScaleNonlinearity(), TemperatureBias(), TemperatureScale(),
    BiasDrift())}
"""The effect library, by spec name."""
