"""
The work of ``~/calibrate``, off the executor: a snapshot, then the session floor in a thread.

The executor thread takes a :class:`Job` (the windows, the observations, the settings, a
copy of what the collector kept, the paths: nothing the executor goes on changing) and
hands it to one worker thread, which runs :func:`run_job`: the session floor's
``session.finish.finish_session`` (fit and accept, save, history).
The model-gap check after the response runs in the same thread. Meanwhile the samples,
``/diagnostics`` and the parameter services go on.

A thread, not a process: the fits spend their time in numpy and scipy, which release the
global interpreter lock in their array loops, and the samples come in on a thread of their
own that needs the lock only a few microseconds per message; measured on a 1 kHz
three-sensor session (bench/bench_calibration_node.py), the parameter services answered
within tens of milliseconds and every sample was taken in during the call, without the
start-up, memory and copying of a second interpreter.
"""

from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
import threading
from typing import Optional

from ..session.settings import NODE


@dataclass
class Job:
    """
    Everything ``~/calibrate`` needs, copied when it was called.

    :param windows: the session's WindowSet (the windows kept and the one held now).
    :param rate_hz: the sample rate, Hz (the weight cap of windows without their own).
    :param settings: the session Settings of the parameters.
    :param imu: ``session.accept.CollectedImu`` over a copy of the collector.
    :param path: the calibration file.
    :param history: the history database, or None (not recorded).
    :param now: the node's clock at the call, s (window times of a device clock).
    """

    windows: object
    rate_hz: Optional[float]
    settings: object
    imu: object
    path: str
    history: Optional[str]
    now: float


STOPPING = NODE.stopping
"""The refusal of a ``~/calibrate`` answered on SIGINT or SIGTERM before its save."""


def run_job(job, may_save=None):
    """
    Fit, judge, save and record one session in the worker thread (as ``fit`` and ``guide``).

    :param may_save: callable -> bool asked right before the save (:meth:`Call.may_save`):
        False refuses the outcome (:data:`STOPPING`) and nothing is written.
    :return: (Outcome, notes): the notes are what the node logs as warnings (the history
        could not record it).
    """
    from ..session.finish import finish_session, HistoryTarget
    outcome = finish_session(job.windows, job.settings, job.imu, rate_hz=job.rate_hz,
                             output=job.path, history=HistoryTarget(job.history, now=job.now)
                             if job.history else None, may_save=may_save)
    return outcome, outcome.notes


class Call:
    """
    One ``~/calibrate`` in progress: answered exactly once, never saved after a stop.

    The worker's result reaches the service coroutine through ``done`` (an rclpy Future
    of the node's executor, its result a ``concurrent.futures.Future`` of (Outcome,
    notes)). On a stop (:meth:`stop`) the call is answered at once with a refusal, unless
    the save has begun: then the save completes and is answered.

    :param done: the rclpy Future the service callback awaits.
    :param imu: the job's ``CollectedImu`` (the words of a refusal).
    """

    def __init__(self, done, imu):
        self.done, self.imu = done, imu
        self.lock = threading.Lock()
        self.saving = False
        self.stopping = False
        self.answered = False

    def may_save(self):
        """Return whether the worker may save now (worker thread): not after a stop."""
        with self.lock:
            self.saving = not self.stopping
            return self.saving

    def finish(self, result):
        """Hand the worker's result (a concurrent Future) to the call, unless answered."""
        with self.lock:
            if self.answered:
                return
            self.answered = True
        self.done.set_result(result)

    def stop(self, refused):
        """
        Answer with ``refused`` (Outcome, notes) now, unless the save has begun.

        :return: whether the call was answered here.
        """
        with self.lock:
            self.stopping = True
            if self.saving or self.answered:
                return False
            self.answered = True
        result = Future()
        result.set_result(refused)
        self.done.set_result(result)
        return True


def worker(name):
    """Return the node's one worker thread, warming up (an executor of one)."""
    pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix=name)
    pool.submit(warm_up)
    return pool


def warm_up():
    """
    Import what the fits, the advice and the model-gap check use, in the worker.

    scipy and the fits take about half a second to import; done here, the first window's
    advice and the first ``~/calibrate`` do not hold the executor for it.
    """
    import importlib
    for name in ('scipy.optimize', 'scipy.linalg', 'scipy.stats', 'scipy.spatial.transform',
                 '..core.accelerometer.fit', '..core.information', '..core.gyroscope.fit',
                 '..core.magnetometer.fit', '..core.outcomes', '..modelgap.workflow',
                 '..session.gap', '..session.finish', '..session.persist', '..dataio.history'):
        try:
            importlib.import_module(name, __package__)
        except ImportError:         # an optional part missing: its first use says so
            pass
