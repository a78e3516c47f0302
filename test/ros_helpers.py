"""
Reusable helpers for tests that run nodes as subprocesses on real rclpy over DDS.

- :func:`start_node` / :func:`stop_node`: a node module as ``python -m`` with
  ``--ros-args -p k:=v``, output in a temporary log file.
- :func:`start_device` / :func:`stop_device`: the virtual MPU9250 on a pty.
- :class:`Processes`: starts both kinds and stops everything left (use it in a
  fixture's ``finally``).
- :class:`Collector`: an in-process node in its own Context that records messages.
- :func:`nodes_in_a_context`: build nodes in-process in their own Context (never spun),
  destroyed at the end.

Every wait has a timeout; the environment (ROS_DOMAIN_ID set by conftest) is inherited.
"""

import contextlib
import os
import select
import signal
import subprocess
import sys
import tempfile
import time

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.qos import qos_profile_sensor_data

STOP_TIMEOUT_S = 10.0


def _param_text(value):
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, (list, tuple)):
        return '[' + ','.join(_param_text(v) for v in value) + ']'
    return str(value)


def _log_file(prefix, log_dir=None):
    fd, path = tempfile.mkstemp(prefix=prefix, suffix='.log', dir=log_dir)
    return os.fdopen(fd, 'w'), path


def read_log(proc):
    """Return the text a process wrote so far (its ``log_path``), '' if none."""
    path = getattr(proc, 'log_path', None)
    if not path or not os.path.exists(path):
        return ''
    with open(path, errors='replace') as f:
        return f.read()


def start_node(module, params=None, *extra_args, log_dir=None, env=None):
    """
    Start ``python -m module --ros-args -p k:=v ... *extra_args`` in the background.

    :param module: module with a ``main`` (e.g. ``accel_calib_ros.nodes.driver``).
    :param params: dict of parameter name -> value (bool, number, str or list).
    :param extra_args: more arguments after the parameters (e.g. ``-r``, remaps).
    :param log_dir: folder for the log file (default: the system temp folder).
    :param env: environment (default: inherited).
    :return: subprocess.Popen with ``log_path`` (stdout and stderr together).
    """
    cmd = [sys.executable, '-m', module, '--ros-args']
    for name, value in (params or {}).items():
        cmd += ['-p', f'{name}:={_param_text(value)}']
    cmd += list(extra_args)
    log, path = _log_file(module.rsplit('.', 1)[-1] + '-', log_dir)
    with log:
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=env,
                                stdin=subprocess.DEVNULL)
    proc.log_path = path
    return proc


def stop_node(proc, timeout=STOP_TIMEOUT_S):
    """
    Stop a process with SIGINT (SIGKILL after ``timeout`` s).

    :return: (return code, log text); the code is the one of a process that had
        already exited, or ``-9`` when it had to be killed.
    """
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=timeout)
    for stream in (proc.stdout, proc.stderr):
        if stream is not None:
            stream.close()
    return proc.returncode, read_log(proc)


def wait_exit(proc, timeout):
    """Wait for a process to exit by itself; return its code or None on timeout."""
    try:
        return proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        return None


def start_device(args=(), timeout=15.0, log_dir=None, env=None):
    """
    Start the virtual MPU9250 (``python -m accel_calib_ros.sim.device *args``).

    :param args: device options (e.g. ``['--link', path, '--corrupt', '0.02']``).
    :param timeout: seconds to wait for it to print its pty path.
    :return: (subprocess.Popen with ``log_path`` for stderr, slave pty path).
    :raises RuntimeError: it exited or printed nothing in time (the log is in the message).
    """
    log, path = _log_file('device-', log_dir)
    cmd = [sys.executable, '-m', 'accel_calib_ros.sim.device'] + [str(a) for a in args]
    with log:
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=log, env=env,
                                stdin=subprocess.DEVNULL)
    proc.log_path = path
    deadline = time.monotonic() + timeout
    line = b''
    fd = proc.stdout.fileno()
    while not line.endswith(b'\n'):
        left = deadline - time.monotonic()
        if left <= 0 or proc.poll() is not None:
            break
        ready, _, _ = select.select([fd], [], [], min(left, 0.2))
        if ready:
            chunk = os.read(fd, 1)
            if not chunk:
                break
            line += chunk
    if not line.endswith(b'\n'):
        stop_node(proc)
        raise RuntimeError(f'the virtual device did not start: {read_log(proc)[-2000:]}')
    return proc, line.decode().strip()


def stop_device(proc, timeout=STOP_TIMEOUT_S):
    """Stop the virtual device; return (return code, its stderr summary text)."""
    return stop_node(proc, timeout)


class Processes:
    """
    Starts nodes and devices and stops whatever is still running in :meth:`stop_all`.

    :param log_dir: folder for the logs (e.g. pytest's ``tmp_path``).
    """

    def __init__(self, log_dir=None):
        self.log_dir = str(log_dir) if log_dir is not None else None
        self.procs = []

    def node(self, module, params=None, *extra_args):
        """Start a node process; see :func:`start_node`."""
        proc = start_node(module, params, *extra_args, log_dir=self.log_dir)
        self.procs.append(proc)
        return proc

    def device(self, args=(), timeout=15.0):
        """Start the virtual device; see :func:`start_device`. Return (proc, path)."""
        proc, path = start_device(args, timeout, log_dir=self.log_dir)
        self.procs.append(proc)
        return proc, path

    def stop_all(self):
        """Stop every process still running, newest first."""
        for proc in reversed(self.procs):
            try:
                stop_node(proc)
            except Exception:            # noqa: B902 - cleanup must reach every process
                pass
        self.procs.clear()


class Collector:
    """
    In-process subscriber node in its own rclpy Context that records messages.

    :param topics: dict of topic name -> message type.
    :param qos: QoS of the subscriptions (default ``qos_profile_sensor_data``).
    :param name: node name.
    """

    def __init__(self, topics, qos=qos_profile_sensor_data, name='test_collector'):
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.messages = {topic: [] for topic in topics}
        for topic, msg_type in topics.items():
            self.node.create_subscription(msg_type, topic, self.messages[topic].append, qos)

    def spin(self, seconds):
        """Process callbacks for ``seconds``."""
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=min(0.05, max(deadline - time.monotonic(), 0)))

    def spin_until(self, predicate, timeout):
        """
        Process callbacks until ``predicate()`` holds or ``timeout`` s pass.

        :return: whether the predicate held.
        """
        deadline = time.monotonic() + timeout
        while True:
            if predicate():
                return True
            if time.monotonic() >= deadline:
                return False
            self.executor.spin_once(timeout_sec=0.05)

    def count(self, topic):
        """Return the number of messages recorded on ``topic``."""
        return len(self.messages[topic])

    def clear(self):
        """Forget every recorded message."""
        for stored in self.messages.values():
            stored.clear()

    def close(self):
        """Destroy the node and shut its context down."""
        try:
            self.executor.shutdown(timeout_sec=1.0)
            self.node.destroy_node()
        finally:
            rclpy.try_shutdown(context=self.context)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def serial_status(collector, topic='/diagnostics'):
    """
    Return the newest driver status on /diagnostics as a dict (or None).

    Its key-value pairs, plus ``level`` and ``hardware_id``; ``collector`` records
    ``topic`` (diagnostic_msgs/DiagnosticArray).
    """
    for array in reversed(collector.messages[topic]):
        for status in array.status:
            if status.name == 'mpu9250_driver: serial':
                values = {kv.key: kv.value for kv in status.values}
                values['level'] = status.level
                values['hardware_id'] = status.hardware_id
                return values
    return None


@contextlib.contextmanager
def nodes_in_a_context(**defaults):
    """
    Yield ``build(cls, **params)``: nodes in their own Context, destroyed at the end.

    The nodes are never spun: a test drives their callbacks. ``defaults`` are parameters
    every node gets unless ``params`` names them.
    """
    context = rclpy.Context()
    rclpy.init(context=context)
    made = []

    def build(cls, **params):
        params = {**defaults, **params}
        made.append(cls(context=context, parameter_overrides=[
            Parameter(k, value=v) for k, v in params.items()]))
        return made[-1]
    try:
        yield build
    finally:
        for node in made:
            node.destroy_node()
        rclpy.try_shutdown(context=context)
