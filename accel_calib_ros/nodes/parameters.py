"""
The nodes' parameters: each described once, typed and ranged; a change checked, then applied.

Describe each parameter once with a :class:`Param` (type, range, choices, description,
read-only); :func:`declare_parameters` declares them all with a full
``ParameterDescriptor`` (what ``ros2 param describe`` shows), checks the start-up values
(a bad one raises :class:`ParameterProblem`: one log line and exit status 2 through
``spinning.run``) and registers two callbacks for every later ``ros2 param set``:

- on set (before rclpy stores anything): type, range, finiteness, choices, then the
  node's own ``check(changes, proposed)``; a refusal leaves everything as it was and
  ``SetParametersResult.reason`` says why;
- post set (after rclpy has stored the accepted values): the node's
  ``apply(changes)``, the side effects. Should applying fail all the same, the old values
  are set again (their side effects with them) and the node logs why.

An integer given for a floating-point parameter (a YAML ``2`` for ``2.0``) is accepted.
rclpy's public API only: the overrides are read by declaring (no private attribute).
"""

import math
import sys

from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                ParameterType, SetParametersResult)
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.parameter import Parameter


class ParameterProblem(ValueError):
    """A node parameter has a value the node cannot work with (exit status 2)."""


_KINDS = {
    'bool': ParameterType.PARAMETER_BOOL,
    'integer': ParameterType.PARAMETER_INTEGER,
    'double': ParameterType.PARAMETER_DOUBLE,
    'string': ParameterType.PARAMETER_STRING,
    'double_array': ParameterType.PARAMETER_DOUBLE_ARRAY,
    'string_array': ParameterType.PARAMETER_STRING_ARRAY,
}
_BIG = sys.float_info.max
_BIG_INT = 2 ** 63 - 1


def _is_number(value):
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _same(value, choice):
    """Whether ``value`` equals ``choice`` (numbers compare by value, 2 == 2.0)."""
    if _is_number(value) and _is_number(choice):
        return value == choice
    return type(value) is type(choice) and value == choice


class Param:
    """
    One node parameter: its type, default, allowed values and description.

    :param name: parameter name.
    :param default: default value; its Python type sets the parameter type unless
        ``kind`` is given (bool, int -> integer, float -> double, str -> string).
    :param description: one line for ``ros2 param describe`` (units in it).
    :param low: smallest allowed value (numbers; None = unbounded).
    :param high: largest allowed value (numbers; None = unbounded).
    :param low_open: the value must be strictly above ``low``.
    :param high_open: the value must be strictly below ``high``.
    :param choices: allowed values (strings or numbers), or None.
    :param empty_ok: for strings: whether '' is allowed.
    :param read_only: a change needs a restart: refused at runtime.
    :param kind: 'bool', 'integer', 'double', 'string', 'double_array' or 'string_array'.
    :param length: for arrays: the required number of elements, or None.
    """

    def __init__(self, name, default, description, low=None, high=None, low_open=False,
                 high_open=False, choices=None, empty_ok=True, read_only=False, kind=None,
                 length=None):
        if kind is None:
            if isinstance(default, bool):
                kind = 'bool'
            elif isinstance(default, int):
                kind = 'integer'
            elif isinstance(default, float):
                kind = 'double'
            elif isinstance(default, str):
                kind = 'string'
            else:
                raise TypeError(f'parameter {name!r}: give kind= for a default {default!r}')
        if kind not in _KINDS:
            raise ValueError(f'parameter {name!r}: unknown kind {kind!r}')
        self.name, self.description, self.kind = name, description, kind
        self.low, self.high, self.low_open, self.high_open = low, high, low_open, high_open
        self.choices = None if choices is None else tuple(choices)
        self.empty_ok, self.read_only, self.length = empty_ok, read_only, length
        self.default = self.check(default)

    # -- validation ----------------------------------------------------------------------
    def constraints(self):
        """Return the allowed values in words ('' when any value of the type goes)."""
        parts = []
        if self.choices is not None:
            parts.append('one of ' + ', '.join(str(c) for c in self.choices))
        if self.low is not None:
            parts.append(f'{">" if self.low_open else ">="} {self.low:g}')
        if self.high is not None:
            parts.append(f'{"<" if self.high_open else "<="} {self.high:g}')
        if self.kind == 'string' and not self.empty_ok:
            parts.append('not empty')
        if self.kind in ('double', 'double_array'):
            parts.append('finite')
        if self.length is not None:
            parts.append(f'{self.length} elements')
        return ', '.join(parts)

    def _problem(self, what, value):
        return ParameterProblem(f'parameter {self.name!r} must be {what}, got {value!r}')

    def _number(self, value):
        """Check one number against type, finiteness and range; return it typed."""
        if self.kind in ('integer',):
            if not isinstance(value, int) or isinstance(value, bool):
                raise self._problem('an integer', value)
        else:
            if not _is_number(value) or not math.isfinite(value):
                raise self._problem('a finite number', value)
            value = float(value)
        if self.low is not None and (value < self.low or (self.low_open and value <= self.low)):
            raise self._problem(f'{">" if self.low_open else ">="} {self.low:g}', value)
        if self.high is not None and (value > self.high
                                      or (self.high_open and value >= self.high)):
            raise self._problem(f'{"<" if self.high_open else "<="} {self.high:g}', value)
        return value

    def check(self, value):
        """
        Check a value for this parameter and return it with the declared type.

        :param value: value as given (YAML, command line, ``ros2 param set``).
        :return: the value (int -> float for a double parameter, tuples -> lists).
        :raises ParameterProblem: wrong type, not finite, out of range, not a choice.
        """
        kind = self.kind
        if kind == 'bool':
            if not isinstance(value, bool):
                raise self._problem('true or false', value)
        elif kind in ('integer', 'double'):
            value = self._number(value)
        elif kind == 'string':
            if not isinstance(value, str):
                raise self._problem('a string', value)
            if not value and not self.empty_ok:
                raise ParameterProblem(f'parameter {self.name!r} must not be empty')
        else:
            if isinstance(value, str) or not hasattr(value, '__len__'):
                raise self._problem('a list', value)
            if self.length is not None and len(value) != self.length:
                raise self._problem(f'a list of {self.length}', value)
            if kind == 'double_array':
                value = [self._number(v) for v in value]
            else:
                if not all(isinstance(v, str) for v in value):
                    raise self._problem('a list of strings', value)
                value = list(value)
        if self.choices is not None and not any(_same(value, c) for c in self.choices):
            raise self._problem('one of ' + ', '.join(str(c) for c in self.choices), value)
        return value

    # -- description ---------------------------------------------------------------------
    def descriptor(self):
        """Return the rcl_interfaces ParameterDescriptor of this parameter."""
        d = ParameterDescriptor(name=self.name, type=_KINDS[self.kind],
                                description=self.description
                                + (' (read-only: restart the node to change it)'
                                   if self.read_only else ''),
                                additional_constraints=self.constraints(),
                                read_only=self.read_only)
        if self.kind in ('double', 'double_array') and (self.low is not None
                                                        or self.high is not None):
            d.floating_point_range = [FloatingPointRange(
                from_value=-_BIG if self.low is None else float(self.low),
                to_value=_BIG if self.high is None else float(self.high), step=0.0)]
        elif self.kind == 'integer' and (self.low is not None or self.high is not None):
            d.integer_range = [IntegerRange(
                from_value=-_BIG_INT if self.low is None else int(math.ceil(self.low)),
                to_value=_BIG_INT if self.high is None else int(math.floor(self.high)),
                step=0)]
        return d


class Parameters(dict):
    """
    The node's current parameter values (a dict name -> value) kept in step with ROS.

    Built by :func:`declare_parameters`; ``specs`` maps each name to its :class:`Param`.
    """

    def __init__(self, specs):
        super().__init__((p.name, p.default) for p in specs)
        self.specs = {p.name: p for p in specs}


def _start_up_value(node, spec):
    """
    Declare ``spec`` with its override (``-p``, ``--params-file``) checked; return the value.

    rclpy checks the type and the range of an override while declaring; where it refuses
    (an integer for a double, a value out of range, a wrong type), the override is read
    by declaring the parameter untyped for a moment, then checked and typed here, so that
    the message names the parameter and what it must be.
    """
    descriptor = spec.descriptor()
    try:
        value = node.declare_parameter(spec.name, spec.default, descriptor).value
    except (InvalidParameterTypeException, InvalidParameterValueException):
        given = node.declare_parameter(spec.name, spec.default,
                                       ParameterDescriptor(dynamic_typing=True)).value
        node.undeclare_parameter(spec.name)
        value = spec.check(given)
        node.declare_parameter(spec.name, value, spec.descriptor(), ignore_override=True)
        return value
    return spec.check(value)


def declare_parameters(node, specs, check=None, apply=None):
    """
    Declare typed, ranged, documented parameters; check every runtime change, then apply it.

    Start-up values (``-p``, ``--params-file``) are checked first: a bad one raises
    :class:`ParameterProblem` naming the parameter (exit status 2 through
    ``spinning.run``). Later changes (``ros2 param set``, the SetParameters service,
    ``node.set_parameters``) pass rclpy's descriptor checks (type, range, read-only), then
    :meth:`Param.check` (finite, open bounds, choices), then ``check(changes, proposed)``
    (no side effects: raise :class:`ParameterProblem` to refuse, with the reason). Once
    rclpy has stored them, the returned dict holds the new values and ``apply(changes)``
    makes them take effect; should it raise, the old values are set again and applied.

    :param node: the rclpy Node.
    :param specs: list of :class:`Param`.
    :param check: callable(changes, proposed) -> None, or None: ``changes`` is ``{name:
        value}`` of the changed parameters, ``proposed`` every value as it would be.
    :param apply: callable(changes) making a change take effect, or None (then every
        parameter is effectively read-only: changes are refused with a reason).
    :return: :class:`Parameters`, the live values.
    :raises ParameterProblem: a start-up value is not allowed.
    """
    values = Parameters(specs)
    for spec in specs:
        values[spec.name] = _start_up_value(node, spec)
    log = node.get_logger()
    rolling_back = False        # the old values are being set again (post_set failed)

    def coerce(parameters):
        """Let an integer stand for a floating-point value (pre-set: before type checks)."""
        out = []
        for p in parameters:
            spec = values.specs.get(p.name)
            if spec is not None and spec.kind == 'double' and p.type_ == Parameter.Type.INTEGER:
                p = Parameter(p.name, Parameter.Type.DOUBLE, float(p.value))
            elif spec is not None and spec.kind == 'double_array' \
                    and p.type_ == Parameter.Type.INTEGER_ARRAY:
                p = Parameter(p.name, Parameter.Type.DOUBLE_ARRAY, [float(v) for v in p.value])
            out.append(p)
        return out

    def changes_of(parameters):
        return {p.name: values.specs[p.name].check(p.value) for p in parameters
                if p.name in values.specs}

    def on_set(parameters):
        try:
            names = [p.name for p in parameters if p.name in values.specs]
            if names and apply is None:
                raise ParameterProblem(
                    f'parameter {names[0]!r} cannot be changed at runtime: restart the node')
            changes = changes_of(parameters)
            if changes and check is not None and not rolling_back:
                check(changes, {**values, **changes})
        except ParameterProblem as err:
            log.warning(f'refused: {err}')
            return SetParametersResult(successful=False, reason=str(err))
        return SetParametersResult(successful=True)

    def post_set(parameters):
        nonlocal rolling_back
        changes = changes_of(parameters)
        if not changes:
            return
        saved = {k: values[k] for k in changes}
        values.update(changes)
        try:
            apply(changes)
        except Exception as err:        # noqa: B902 - a half-applied change is undone
            values.update(saved)
            if rolling_back:
                log.error(f'could not restore {sorted(saved)}: {type(err).__name__}: {err}')
                return
            log.error(f'could not apply {changes}: {type(err).__name__}: {err}; '
                      f'back to {saved}')
            rolling_back = True
            try:
                node.set_parameters([Parameter(k, value=v) for k, v in saved.items()])
            finally:
                rolling_back = False
            return
        log.info('parameters changed: ' + ', '.join(f'{k}={v!r}' for k, v in changes.items()))

    node.add_pre_set_parameters_callback(coerce)
    node.add_on_set_parameters_callback(on_set)
    node.add_post_set_parameters_callback(post_set)
    return values


class ReportParameter:
    """
    A parameter the node keeps equal to something it reports; a set from outside is refused.

    rclpy has no public way for a node to write its own read-only parameter, so the
    parameter is declared writable, its description says that it is a report, and an
    on-set callback refuses every write but the node's own (:meth:`report`).

    :param node: the rclpy Node.
    :param name: parameter name.
    :param default: initial value (its type is the parameter's).
    :param description: one line for ``ros2 param describe``.
    """

    def __init__(self, node, name, default, description):
        self.node, self.name = node, name
        self._own = False
        node.declare_parameter(name, default, ParameterDescriptor(
            name=name, type=Parameter.Type.from_parameter_value(default).value,
            description=description + ' (a report of the node: a set is refused)'),
            ignore_override=True)
        node.add_on_set_parameters_callback(self._on_set)

    def _on_set(self, parameters):
        if self._own or all(p.name != self.name for p in parameters):
            return SetParametersResult(successful=True)
        return SetParametersResult(successful=False,
                                   reason=f'{self.name} is reported by the node: read-only')

    @property
    def value(self):
        """Return the value reported now."""
        return self.node.get_parameter(self.name).value

    def report(self, value):
        """Report ``value`` (the node's own write); return whether rclpy stored it."""
        self._own = True
        try:
            (result,) = self.node.set_parameters([Parameter(self.name, value=value)])
        finally:
            self._own = False
        return result.successful
