"""
Which sensor a node serves and where its files are: the sensor id, the default files, names.

One sensor, one identity across the three nodes and the host: the namespace of the nodes
and the sensor's ``frame_id`` (the driver's parameter, and the ``frame_id`` parameter of
the calibration and correction nodes). From them:

- the sensor id (:func:`sensor_id`): ``imu_link`` at the root namespace,
  ``robot1/imu_link`` under ``/robot1``; the calibration node records it in the file and
  the history, the correction node refuses a file made for another;
- the default files (:func:`calibration_path`, :func:`history_path`):
  ``$ROS_HOME/accel_calib_ros/<sensor id>/calibration.yaml`` and ``history.sqlite``
  beside it, so two robots (or two IMUs) on one host never share a calibration;
- the ``/diagnostics`` names and ``hardware_id`` (:func:`status_name`,
  :func:`hardware_id`): unique across robots.

And the rules every node follows for a file it is given: ``~`` expanded (an unknown
``~user`` refused), a device, FIFO, socket or directory never replaced
(:func:`unsafe_output`), its folder made (:func:`make_directory`).
"""

import os

from .parameters import ParameterProblem


def sensor_id(namespace, frame_id):
    """
    Return the id of the sensor of ``frame_id`` under ``namespace``.

    :param namespace: the node's namespace (``/``, ``/robot1``).
    :param frame_id: the sensor's frame_id (``imu_link``).
    :return: ``imu_link`` at the root, ``robot1/imu_link`` under ``/robot1``.
    """
    parts = [p for p in f'{namespace}/{frame_id}'.split('/') if p]
    return '/'.join(parts)


def sensor_param(value):
    """
    Normalise a ``sensor_id`` parameter ('' stays '': namespace and frame_id name it).

    :raises ParameterProblem: not printable, too long (``dataio.sensor_id``).
    """
    if not value:
        return value
    from ..core.errors import InputError
    from ..dataio.sensor_id import normalise_sensor_id
    try:
        return normalise_sensor_id(value)
    except InputError as err:
        raise ParameterProblem(f"parameter 'sensor_id': {err}") from None


def check_frame_id(value, name='frame_id', empty_ok=False):
    """
    Refuse a frame_id tf2 would not take: a leading ``/``, blanks, unprintable characters.

    :param value: the parameter's value.
    :param name: the parameter's name, for the message.
    :param empty_ok: whether '' is allowed (it means a default).
    :raises ParameterProblem: with the reason.
    """
    if not value:
        if empty_ok:
            return
        raise ParameterProblem(f'parameter {name!r} must not be empty')
    if value.startswith('/'):
        raise ParameterProblem(f'parameter {name!r} must be a tf2 frame id: no leading '
                               f"'/' (tf2 refuses it; use {value.lstrip('/')!r}), got "
                               f'{value!r}')
    if any(c.isspace() for c in value) or not value.isprintable():
        raise ParameterProblem(f'parameter {name!r} must be a tf2 frame id (no blanks, '
                               f'printable), got {value!r}')


def check_topic_name(value, name):
    """
    Refuse a topic name rclpy would not subscribe to ('' is allowed: no topic).

    rclpy's own check passes a NUL (the C layer then cuts the name there): unprintable
    characters are refused first.

    :raises ParameterProblem: with the reason.
    """
    if not value:
        return
    from rclpy.exceptions import InvalidTopicNameException
    from rclpy.validate_topic_name import validate_topic_name
    if not value.isprintable():
        raise ParameterProblem(f'parameter {name!r} must be a topic name (printable), got '
                               f'{value!r}')
    try:
        validate_topic_name(value)
    except InvalidTopicNameException as err:
        reason = str(err).splitlines()[0].replace('Invalid topic name: ', '').rstrip(':')
        raise ParameterProblem(f'parameter {name!r} must be a topic name ({reason}), got '
                               f'{value!r}') from None


def hardware_id(sensor):
    """
    Return the ``/diagnostics`` ``hardware_id`` of a sensor: its :func:`sensor_id`.

    The three nodes report the same sensor under the same ``hardware_id`` (the namespace
    and the frame_id), so that a diagnostics aggregator groups them and two robots'
    sensors stay apart; the serial port is a value (``port``), not the id.
    """
    return str(sensor)


def status_name(node, part):
    """
    Return a ``/diagnostics`` status name, ``<node>: <part>``, unique across robots.

    The node's fully qualified name without its leading ``/``: ``accel_correction:
    calibration`` at the root, ``robot1/accel_correction: calibration`` under ``/robot1``.
    """
    return f'{node.get_fully_qualified_name().lstrip("/")}: {part}'


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


def calibration_path(value, sensor, name='calibration_file'):
    """
    Resolve a ``calibration_file`` parameter: '' means the sensor's default, ``~`` expanded.

    :param value: value as read.
    :param sensor: the sensor id (:func:`sensor_id`).
    :param name: the parameter's name, for the message.
    :return: the path ($ROS_HOME/accel_calib_ros/<sensor>/calibration.yaml by default).
    :raises ParameterProblem: ``~user`` names no user.
    """
    if value:
        return expand_path(value, name)
    from ..dataio.calibration_file import default_calibration_path
    return default_calibration_path(sensor)


def sensor_files(namespace, params):
    """
    Return (sensor id, calibration file) the node's parameters say.

    :param namespace: the node's namespace.
    :param params: its parameter values (``sensor_id``, ``frame_id``, ``calibration_file``).
    :raises ParameterProblem: a sensor id or a ``~user`` the node cannot take.
    """
    sensor = sensor_param(params['sensor_id']) or sensor_id(namespace, params['frame_id'])
    return sensor, calibration_path(params['calibration_file'], sensor)


def history_path(value, calibration_file):
    """
    Resolve a ``history_file`` parameter: '' means ``history.sqlite`` beside the calibration.

    :param value: value as read.
    :param calibration_file: the calibration file in use (resolved).
    :raises ParameterProblem: ``~user`` names no user.
    """
    if value:
        return expand_path(value, 'history_file')
    return os.path.join(os.path.dirname(os.path.abspath(calibration_file)), 'history.sqlite')


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
