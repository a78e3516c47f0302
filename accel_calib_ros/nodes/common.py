"""
Plumbing shared by the three nodes: typed parameters, their runtime changes, the main loop.

The parameter mechanism (``contract-params``): describe each parameter once with a
:class:`Param` (type, range, choices, description, read-only), then
:func:`declare_parameters` declares them all with a full ``ParameterDescriptor`` (what
``ros2 param describe`` shows), checks the start-up values (a bad one raises
:class:`ParameterProblem`: one log line and exit status 2 through :func:`run`), and
registers the callbacks that check every later ``ros2 param set``: type, range,
finiteness, choices. A valid change is stored and handed to the node's ``on_change``
hook, which applies it (or raises :class:`ParameterProblem` to refuse it); a refused
change leaves everything as it was and ``SetParametersResult.reason`` says why. An
integer given for a floating-point parameter (a YAML ``2`` for ``2.0``) is accepted.
"""

import math
import os
import sys
import time

from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                ParameterType, SetParametersResult)
import rclpy
import rclpy.executors
from rclpy.executors import ExternalShutdownException
from rclpy.parameter import Parameter


class ParameterProblem(ValueError):
    """A node parameter has a value the node cannot work with (exit status 2)."""


# -- typed parameters (contract-params) ----------------------------------------------------

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


def declare_parameters(node, specs, on_change=None):
    """
    Declare typed, ranged, documented parameters and check every runtime change.

    Start-up values (``-p``, ``--params-file``) are checked first: a bad one raises
    :class:`ParameterProblem` naming the parameter (exit status 2 through :func:`run`).
    Later changes (``ros2 param set``, the SetParameters service,
    ``node.set_parameters``) pass rclpy's descriptor checks (type, range, read-only),
    then :meth:`Param.check` (finite, open bounds, choices); the accepted values are
    stored in the returned dict and ``on_change(changes)`` is called with
    ``{name: value}`` of the changed ones. If the hook raises :class:`ParameterProblem`
    (or ValueError) the stored values are restored and the change is refused with the
    message as its reason.

    :param node: the rclpy Node.
    :param specs: list of :class:`Param`.
    :param on_change: callable(changes dict) applying a change, or None (then every
        parameter is effectively read-only: changes are refused with a reason).
    :return: :class:`Parameters`, the live values.
    :raises ParameterProblem: a start-up value is not allowed.
    """
    values = Parameters(specs)
    overrides = getattr(node, '_parameter_overrides', {}) or {}
    for spec in specs:
        value = spec.default
        if spec.name in overrides:
            value = spec.check(overrides[spec.name].value)
        node.declare_parameter(spec.name, value, spec.descriptor(), ignore_override=True)
        values[spec.name] = value

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

    def on_set(parameters):
        changes = {}
        try:
            for p in parameters:
                spec = values.specs.get(p.name)
                if spec is None:
                    continue
                if on_change is None:
                    raise ParameterProblem(
                        f'parameter {p.name!r} cannot be changed at runtime: restart the node')
                changes[p.name] = spec.check(p.value)
        except ParameterProblem as err:
            node.get_logger().warning(f'refused: {err}')
            return SetParametersResult(successful=False, reason=str(err))
        if not changes:
            return SetParametersResult(successful=True)
        saved = {k: values[k] for k in changes}
        values.update(changes)
        try:
            on_change(changes)
        except (ParameterProblem, ValueError) as err:
            values.update(saved)
            node.get_logger().warning(f'refused: {err}')
            return SetParametersResult(successful=False, reason=str(err))
        node.get_logger().info('parameters changed: ' + ', '.join(
            f'{k}={v!r}' for k, v in changes.items()))
        return SetParametersResult(successful=True)

    node.add_pre_set_parameters_callback(coerce)
    node.add_on_set_parameters_callback(on_set)
    return values


def expand_path(value, name):
    """
    Expand a leading ``~`` or ``~user`` of a file parameter; refuse an unknown user.

    :param value: the parameter's value.
    :param name: the parameter's name, for the message.
    :raises ParameterProblem: ``~user`` names no user (no folder literally named ``~user``
        is ever created).
    """
    if not value.startswith('~'):
        return value
    expanded = os.path.expanduser(value)
    if expanded.startswith('~'):
        head = value.split(os.sep, 1)[0]
        raise ParameterProblem(f'parameter {name!r}: there is no user to expand {head} to '
                               f'(got {value!r})')
    return expanded


def calibration_path(value, name='calibration_file'):
    """
    Resolve a ``calibration_file`` parameter: '' means the default, ``~`` is expanded.

    :param value: value as read.
    :param name: the parameter's name, for the message.
    :return: the path to use ($ROS_HOME/accel_calib_ros/calibration.yaml by default).
    :raises ParameterProblem: ``~user`` names no user.
    """
    if value:
        return expand_path(value, name)
    from ..dataio.calibration_file import default_calibration_path
    return default_calibration_path()


def unsafe_output(path):
    """
    Say why a node must not write ``path``, or None when it may.

    The rules of every writer (:func:`dataio.atomic.output_target`): a device, a FIFO, a
    socket or a directory is never replaced, and no other user's symbolic link is
    followed. A node logs the reason and refuses the write; it never dies of it.

    :param path: the file a node would write.
    :return: the reason (one line), or None.
    """
    from ..dataio.atomic import output_target, UnsafeOutput
    try:
        output_target(path)
    except UnsafeOutput as err:
        return str(err)
    except OSError as err:
        return f'{path}: {err.strerror or err}'
    return None


def make_directory(path, logger=None):
    """
    Create the directory of ``path`` if missing; log (not raise) when it cannot be made.

    :param path: a file path.
    :param logger: rclpy logger for the warning, or None.
    :return: whether the directory exists now.
    """
    folder = os.path.dirname(os.path.abspath(path))
    try:
        os.makedirs(folder, exist_ok=True)
        return True
    except OSError as err:
        if logger is not None:
            logger.warning(f'cannot create {folder}: {err}')
        return False


def hardware_id(frame_id):
    """
    Return the ``/diagnostics`` ``hardware_id`` of an IMU: its ``frame_id``, one per sensor.

    The convention of the three nodes: the driver, the calibration node and the correction
    node report the same sensor under the same ``hardware_id``, the ``frame_id`` of its
    messages (the driver's ``frame_id`` parameter, ``imu_link`` by default), so that a
    diagnostics aggregator groups them; the serial port is a value (``port``), not the id.

    :param frame_id: the IMU's frame_id.
    :return: str.
    """
    return str(frame_id)


class Throttled:
    """
    Log a kind of message at most once per ``period_s`` (monotonic time), per node.

    :param logger: the node's logger.
    :param period_s: shortest time between two lines of the same kind, s.
    """

    def __init__(self, logger, period_s):
        self.logger = logger
        self.period_s = float(period_s)
        self._last = {}

    def __call__(self, kind, level, text):
        """Log ``text`` with method ``level`` ('warning', 'error', ...) unless too soon."""
        now = time.monotonic()
        if now - self._last.get(kind, -math.inf) >= self.period_s:
            self._last[kind] = now
            getattr(self.logger, level)(text)


def _spin_quietly(executor):
    """Spin until shutdown; the end of the context is not an error here."""
    try:
        executor.spin()
    except (ExternalShutdownException, RuntimeError, KeyboardInterrupt):
        pass


class GroupExecutor(rclpy.executors.SingleThreadedExecutor):
    """
    A single-threaded executor that runs only one callback group of a node, or all but it.

    Two of them share one node (one node per process, so a ``__node:=`` remap names
    exactly one node): the hot path's group on one thread, with nothing else in its
    wait set (no parameter services, timers or other subscriptions: the per-message
    executor work of a bare relay), everything else on another. rclpy's executors pick
    entities through :meth:`can_execute`; a node belongs (``node.executor``) to the one
    added with :meth:`add_node`, the other shares it through :meth:`share_node`.

    :param group: the callback group.
    :param inside: True: run the group's callbacks only; False: everything but them.
    """

    def __init__(self, group, inside, context=None):
        super().__init__(context=context)
        self.group, self.inside = group, inside

    def can_execute(self, entity):
        """Return True for entities of this executor's side of the group, when ready."""
        return (entity.callback_group is self.group) == self.inside \
            and super().can_execute(entity)

    def share_node(self, node):
        """Spin ``node`` too without taking it from the executor it belongs to."""
        with self._nodes_lock:
            self._nodes.add(node)
        self._guard.trigger()


def run(node_class, logger_name, args=None):
    """
    Run a node until Ctrl-C; exit status 2 on a bad parameter.

    :param node_class: the Node subclass to build (no arguments).
    :param logger_name: logger for the parameter error (the node name).
    :param args: command-line arguments for rclpy.init.
    """
    rclpy.init(args=args)
    node = None
    code = 0
    control = thread = None
    try:
        node = node_class()
        group = getattr(node, 'stream_group', None)
        if group is not None:
            # The node's hot path is one callback group: it gets the main thread and an
            # executor of its own; the rest (parameters, services, timers) is spun in a
            # background thread.
            import threading
            control = GroupExecutor(group, inside=False)
            control.add_node(node)
            thread = threading.Thread(target=_spin_quietly, args=(control,), daemon=True)
            thread.start()
            main = GroupExecutor(group, inside=True)
            main.share_node(node)
            main.spin()
        else:
            rclpy.spin(node)
    except ParameterProblem as err:
        rclpy.logging.get_logger(logger_name).error(str(err))
        code = 2
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except RuntimeError:
        # A SIGINT landing inside a pybind11 call surfaces as RuntimeError (a known rclpy
        # race at shutdown); only a real error while the context is still up is reported.
        if rclpy.ok():
            raise
    finally:
        if control is not None:            # stop the background spin before teardown
            rclpy.try_shutdown()
            control.shutdown(timeout_sec=2.0)
            thread.join(timeout=2.0)
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    if code:
        sys.exit(code)
