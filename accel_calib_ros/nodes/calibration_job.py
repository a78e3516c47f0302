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

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Optional


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


def run_job(job):
    """
    Fit, judge, save and record one session in the worker thread (as ``fit`` and ``guide``).

    :return: (Outcome, notes): the notes are what the node logs as warnings (the history
        could not record it).
    """
    from ..session.finish import finish_session, HistoryTarget
    outcome = finish_session(job.windows, job.settings, job.imu, rate_hz=job.rate_hz,
                             output=job.path, history=HistoryTarget(job.history, now=job.now)
                             if job.history else None)
    return outcome, outcome.notes


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
