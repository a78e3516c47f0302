"""
Plumbing shared by the three nodes: parameter checks and the main loop.

Parameters are declared with dynamic typing and checked here, so a bad value gives
one log line naming the parameter and exit status 2 instead of a traceback.
"""

import math
import sys

from rcl_interfaces.msg import ParameterDescriptor
import rclpy
from rclpy.executors import ExternalShutdownException


class ParameterProblem(ValueError):
    """A node parameter has a value the node cannot work with (exit status 2)."""


def declare(node, name, default, description):
    """
    Declare a parameter that accepts any type, so that validation can name it.

    A YAML ``2`` for a parameter declared ``1.0`` would otherwise raise a type error
    deep inside rclpy; here :func:`number`, :func:`text` and friends check the type.

    :param node: the node.
    :param name: parameter name.
    :param default: default value.
    :param description: one-line description shown by ``ros2 param describe``.
    :return: the value given at start-up (or the default).
    """
    desc = ParameterDescriptor(description=description, dynamic_typing=True)
    return node.declare_parameter(name, default, desc).value


def number(name, value, low=None, high=None, low_open=False):
    """
    Check a numeric parameter and return it as float.

    :param name: parameter name (for the message).
    :param value: value as read.
    :param low: smallest allowed value (or None).
    :param high: largest allowed value (or None).
    :param low_open: the value must be strictly above ``low``.
    :return: float value.
    :raises ParameterProblem: wrong type, not finite or out of range.
    """
    if isinstance(value, bool) or not isinstance(value, (int, float)) \
            or not math.isfinite(value):
        raise ParameterProblem(f'parameter {name!r} must be a finite number, got {value!r}')
    value = float(value)
    if low is not None and (value < low or (low_open and value <= low)):
        raise ParameterProblem(f'parameter {name!r} must be {">" if low_open else ">="} '
                               f'{low:g}, got {value:g}')
    if high is not None and value > high:
        raise ParameterProblem(f'parameter {name!r} must be <= {high:g}, got {value:g}')
    return value


def integer(name, value, low=None):
    """
    Check an integer parameter.

    :param name: parameter name.
    :param value: value as read.
    :param low: smallest allowed value (or None).
    :return: int value.
    :raises ParameterProblem: wrong type or out of range.
    """
    if isinstance(value, bool) or not isinstance(value, int):
        raise ParameterProblem(f'parameter {name!r} must be an integer, got {value!r}')
    if low is not None and value < low:
        raise ParameterProblem(f'parameter {name!r} must be >= {low}, got {value}')
    return value


def text(name, value, choices=None, empty_ok=False):
    """
    Check a string parameter.

    :param name: parameter name.
    :param value: value as read.
    :param choices: allowed values (or None for any string).
    :param empty_ok: whether '' is allowed.
    :return: str value.
    :raises ParameterProblem: wrong type, empty or not one of ``choices``.
    """
    if not isinstance(value, str):
        raise ParameterProblem(f'parameter {name!r} must be a string, got {value!r}')
    if choices is not None and value not in choices:
        raise ParameterProblem(f'parameter {name!r} must be one of {", ".join(choices)}; '
                               f'got {value!r}')
    if not value and not empty_ok:
        raise ParameterProblem(f'parameter {name!r} must not be empty')
    return value


def choice(name, value, allowed):
    """
    Check a parameter against a list of allowed values (a YAML 2.0 matches 2).

    :return: the matching allowed value.
    :raises ParameterProblem: not one of ``allowed``.
    """
    for option in allowed:
        if isinstance(value, type(option)) and not isinstance(value, bool) and value == option:
            return option
        if isinstance(option, int) and isinstance(value, float) and value == option:
            return option
    text = ', '.join(str(a) for a in allowed)
    raise ParameterProblem(f'parameter {name!r} must be one of {text}; got {value!r}')


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
    try:
        node = node_class()
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
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    if code:
        sys.exit(code)
