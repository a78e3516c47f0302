"""
How a node process runs: its executors and threads, and an orderly stop on a signal.

One node per process (a ``__node:=`` remap names exactly one node). A node whose hot
path is a callback group of its own (``node.stream_group``: the calibration node's three
sensor subscriptions, the correction node's Imu path) is spun by two
:class:`GroupExecutor`, each on a thread of its own: the stream group alone (nothing else
in its wait set: no parameter services, timers or other subscriptions, the per-message
executor work of a bare relay) and everything else. The same class serves the second
executor the node without taking it from the first (``node.executor`` stays the one of
the services and timers): rclpy's public API only, as the custom executor of
ros2/examples (``examples_rclpy_executors/custom_executor.py``) shows.
(bench/bench_calibration_node.py and bench/bench_correction.py measured it against a
MultiThreadedExecutor with the same callback groups: docs/calibration_node.md.)

:func:`run` takes SIGINT and SIGTERM itself (rclpy's handlers would shut the context down
at once, with a service call still unanswered): on the signal it asks the node to stop
(``node.stop_requested()``, when it has one: the calibration node answers a running
``~/calibrate`` then), waits until no callback is in progress, then shuts down; exit
status 0, or 2 for a bad parameter at start-up.
"""

import signal
import sys
import threading
import time

import rclpy
from rclpy.executors import (ConditionReachedException, Executor, ExternalShutdownException,
                             ShutdownException, TimeoutException)
from rclpy.signals import SignalHandlerOptions

from .parameters import ParameterProblem

STOP_WAIT_S = 10.0
"""Longest wait on a signal for the callbacks in progress (a save) to finish, s."""


class GroupExecutor(Executor):
    """
    A single-threaded executor of one callback group of its nodes, or of all but it.

    :param group: the callback group.
    :param inside: True: run the group's callbacks only; False: everything but them.
    :param context: the rclpy Context (default: the global one).
    """

    def __init__(self, group, inside, context=None):
        super().__init__(context=context)
        self.group, self.inside = group, inside
        self.served = []        # nodes spun here but added to (owned by) another executor
        self.in_progress = set()    # callbacks begun and not done (a coroutine waiting)

    def can_execute(self, entity):
        """Return True for entities of this executor's side of the group, when ready."""
        return (entity.callback_group is self.group) == self.inside \
            and super().can_execute(entity)

    def serve(self, node):
        """Spin ``node`` too without taking it from the executor it was added to."""
        self.served.append(node)
        self.wake()

    def get_nodes(self):
        """Return the nodes added to this executor and those it serves."""
        owned = super().get_nodes()
        return owned + [n for n in self.served if n not in owned]

    def spin_once(self, timeout_sec=None):
        """Wait for one ready callback of this side and run it in this thread."""
        try:
            handler, _, _ = self.wait_for_ready_callbacks(timeout_sec)
        except (ShutdownException, TimeoutException, ConditionReachedException):
            return
        handler()
        if handler.done():
            self.in_progress.discard(handler)
            handler.result()        # raises what the callback raised
        else:
            self.in_progress.add(handler)

    @property
    def idle(self):
        """Whether no callback is in progress (every service call begun was answered)."""
        self.in_progress = {h for h in self.in_progress if not h.done()}
        return not self.in_progress


class Spinner:
    """
    The executors and threads of one node (see the module docstring).

    :param node: the node; ``node.stream_group`` (optional) is its hot path.
    """

    def __init__(self, node):
        self.node = node
        self.error = None
        group = getattr(node, 'stream_group', None)
        self.control = GroupExecutor(group, inside=False, context=node.context)
        self.control.add_node(node)
        self.executors = [self.control]
        if group is not None:
            stream = GroupExecutor(group, inside=True, context=node.context)
            stream.serve(node)
            self.executors.append(stream)
        self.threads = [threading.Thread(target=self._spin, args=(e,), daemon=True,
                                         name='stream' if e.inside else 'control')
                        for e in self.executors]

    def start(self):
        """Spin each executor in a thread of its own."""
        for thread in self.threads:
            thread.start()

    def _spin(self, executor):
        try:
            while self.node.context.ok() and self.error is None:
                executor.spin_once()
        except (ExternalShutdownException, ShutdownException):
            pass
        except Exception as err:        # noqa: B902 - said by run(), then the process ends
            if self.node.context.ok():
                self.error = err

    @property
    def running(self):
        """Whether every thread spins (none ended with an error)."""
        return self.error is None and all(t.is_alive() for t in self.threads)

    def wait_idle(self, timeout):
        """Wait until no callback is in progress; return whether none is."""
        end = time.monotonic() + timeout
        while not self.control.idle:
            if time.monotonic() > end or self.error is not None:
                return False
            time.sleep(0.01)
        return True

    def stop(self):
        """Shut the executors down and join the threads."""
        rclpy.try_shutdown(context=self.node.context)
        for executor in self.executors:
            executor.shutdown(timeout_sec=2.0)
        for thread in self.threads:
            thread.join(timeout=2.0)


def run(node_class, logger_name, args=None):
    """
    Run a node until SIGINT or SIGTERM; exit status 2 on a bad parameter.

    :param node_class: the Node subclass to build (no arguments).
    :param logger_name: logger for the parameter error (the node name).
    :param args: command-line arguments for rclpy.init.
    """
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    signalled = []
    stop = threading.Event()

    def on_signal(number, frame):
        signalled.append(number)
        stop.set()
    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    node = spinner = None
    code = 0
    try:
        node = node_class()
        spinner = Spinner(node)
        spinner.start()
        while not stop.wait(0.2) and spinner.running:
            pass
        if spinner.error is None:
            stop_requested = getattr(node, 'stop_requested', None)
            if stop_requested is not None:
                stop_requested()
            if not spinner.wait_idle(STOP_WAIT_S) and len(signalled) < 2:
                node.get_logger().warning(f'stopping with a callback still in progress after '
                                          f'{STOP_WAIT_S:g} s')
    except ParameterProblem as err:
        rclpy.logging.get_logger(logger_name).error(str(err))
        code = 2
    finally:
        if spinner is not None:
            spinner.stop()
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
        for number, handler in previous.items():
            signal.signal(number, handler)
    if spinner is not None and spinner.error is not None:
        rclpy.logging.get_logger(logger_name).error(
            f'stopped by an error: {type(spinner.error).__name__}: {spinner.error}')
        raise spinner.error
    if code:
        sys.exit(code)
