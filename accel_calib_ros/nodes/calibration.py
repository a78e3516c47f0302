"""
ROS 2 node ``accel_calibration``: collect static poses, advise, solve on request, save.

The live front door of the session floor; docs/calibration_node.md describes it whole.
The samples come in on a node and thread of their own (:mod:`.calibration_intake`); every
0.1 s they go to the streaming static-window detector and to the IMU collector, and each
window brings the advice (``~/advice``, ``~/status``, ``/diagnostics``). ``~/calibrate``
fits, judges, saves and records with the session floor (``session.finish``) in a worker
thread (:mod:`.calibration_job`) and answers when it is done, while the samples,
``/diagnostics`` and the parameter services go on; a second call meanwhile is refused
with the reason. The model-gap check follows in the worker and
lands on ``~/status``.
"""

from collections import deque
import json
import math
import os
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
import numpy as np
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.task import Future
from std_msgs.msg import String
from std_srvs.srv import Trigger

from .calibration_intake import Intake, subscribe
from .calibration_job import Job, run_job, worker
from .calibration_params import check_rate, PARAMS, sensor_param  # noqa: F401
from .common import (calibration_path, declare_parameters, expand_path, hardware_id,
                     make_directory, ParameterProblem, run, unsafe_output)
from ..core.advice import advise, coverage
from ..core.collector import ImuCollector
from ..core.errors import CalibrationError, InputError
from ..core.finite import finite_or_none
from ..core.windows import DEFAULTS, OnlineStaticDetector
from ..session.accept import CollectedImu, NODE, refused, Settings, SI_UNITS
from ..session.windows import Window, WindowSet

LATCHED = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST,
                     reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
PROCESS_PERIOD_S = 0.1
"""How often the samples taken in go to the detector, s."""
COLLECT_BLOCK = 200
"""Samples handed to the collector at a time (the magnetometer samples of their time between)."""


def safe_json(obj):
    """JSON text with every non-finite number replaced by null (never NaN/Infinity)."""
    def clean(value):
        if isinstance(value, float):
            return value if math.isfinite(value) else None
        if isinstance(value, dict):
            return {k: clean(v) for k, v in value.items()}
        if isinstance(value, (list, tuple)):
            return [clean(v) for v in value]
        if isinstance(value, np.generic):
            return clean(value.item())
        if isinstance(value, np.ndarray):
            return clean(value.tolist())
        return value
    return json.dumps(clean(obj), allow_nan=False)


class CalibrationNode(Node):
    """Collect static windows from the raw IMU stream, advise, and calibrate on request."""

    def __init__(self, **kwargs):
        super().__init__('accel_calibration', **kwargs)
        self.params = declare_parameters(self, PARAMS, self._on_params)
        if self.params['threshold_factor'] and self.params['threshold_factor'] < 1.0:
            raise ParameterProblem("parameter 'threshold_factor' must be 0 or >= 1, got "
                                   f"{self.params['threshold_factor']!r}")
        check_rate(self.params['rate_hz'])
        self.params['sensor_id'] = sensor_param(self.params['sensor_id'])
        expand_path(self.params['history_file'], 'history_file')
        self.path = calibration_path(self.params['calibration_file'])
        files = (('calibration_file', self.path), ('history_file', self.history_path()))
        for what, path in files:
            reason = unsafe_output(path)
            if reason:      # the file system may change: log it now, refuse each write
                self.get_logger().error(f'{what}: {reason}; it will not be written')
        self._make_directory(self.path)
        self.windows = deque(maxlen=self.params['max_windows'])
        self.detector = self._new_detector()
        self._seq = 0
        self._last_result = None    # {'success', 'message', ...} of the last ~/calibrate
        self._advice = None
        self._model_gap = None
        self._coverage = None       # fraction of the sphere of field directions seen
        self.imu = ImuCollector(self.params['max_gyro_samples'],
                                self.params['max_mag_samples'])
        self._worker = worker('accel_calibration_fit')
        self._solving = None        # monotonic start of the ~/calibrate that runs, or None
        self._gap = (0, None)       # (number of the check asked for, its finished future)
        self._gap_asked = 0
        self._gap_guard = self.create_guard_condition(self._on_model_gap)

        self.status_pub = self.create_publisher(String, '~/status', LATCHED)
        self.advice_pub = self.create_publisher(String, '~/advice', LATCHED)
        self.diag_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        # The samples in a callback group of their own: nodes.common.run spins it on the
        # main thread with nothing else in its wait set, so nothing of this node's
        # (services, timers, advice) delays them. One node per process: a __node:=
        # remap names exactly one node.
        self.intake = Intake(lambda: self.get_clock().now().nanoseconds * 1e-9)
        self.stream_group = MutuallyExclusiveCallbackGroup()
        subscribe(self, self.intake, self.stream_group)
        # Re-entrant: a second call is answered (refused) while the first one runs.
        self.create_service(Trigger, '~/calibrate', self.on_calibrate,
                            callback_group=ReentrantCallbackGroup())
        self.create_service(Trigger, '~/reset', self.on_reset)
        self.create_timer(PROCESS_PERIOD_S, self.process_pending)
        self.create_timer(1.0, self.publish_diagnostics)
        self.publish_status(advice=True)
        self.get_logger().info(
            f'collecting static poses (method {self.params["method"]}, file {self.path}); '
            'hold each pose still for 2 s, follow ~/advice, then call ~/calibrate')

    def destroy_node(self):
        """Stop the worker (waiting for the work it has begun), then destroy the node."""
        self._worker.shutdown(wait=True, cancel_futures=True)
        return super().destroy_node()

    # -- parameters ------------------------------------------------------------------------
    def _detector_settings(self):
        p = self.params
        return {name: p[name] or DEFAULTS[name]
                for name in ('window_s', 'min_duration_s', 'trim_s', 'threshold_factor')}

    def _new_detector(self):
        return OnlineStaticDetector(self.params['rate_hz'] or None,
                                    use_gyro=self.params['use_gyro'],
                                    gravity=self.params['gravity'],
                                    **self._detector_settings())

    def _make_directory(self, path):
        make_directory(path, self.get_logger())

    def _on_params(self, changes):
        """Apply a runtime parameter change (called by the common mechanism)."""
        if changes.get('threshold_factor', 0.0) and changes['threshold_factor'] < 1.0:
            raise ParameterProblem("parameter 'threshold_factor' must be 0 or >= 1")
        if 'rate_hz' in changes:
            check_rate(changes['rate_hz'])
        if 'sensor_id' in changes:
            self.params['sensor_id'] = sensor_param(changes['sensor_id'])
        if 'history_file' in changes:
            reason = unsafe_output(self.history_path())
            if reason:
                raise ParameterProblem(f'history_file: {reason}')
        if 'calibration_file' in changes:
            path = calibration_path(changes['calibration_file'])
            reason = unsafe_output(path)
            if reason:
                raise ParameterProblem(f'calibration_file: {reason}')
            self.path = path
            self._make_directory(self.path)
        if 'max_windows' in changes:
            self.windows = deque(self.windows, maxlen=changes['max_windows'])
        if set(changes) & {'window_s', 'min_duration_s', 'trim_s', 'threshold_factor',
                           'use_gyro', 'rate_hz', 'gravity'}:
            self.process_pending()
            for window in self.detector.finish():
                self._add(window, publish=False)
            self.detector = self._new_detector()
        if set(changes) & {'target_accuracy', 'method', 'gravity', 'max_weight_s',
                           'max_windows'}:
            self.publish_status(advice=True)

    # -- input -----------------------------------------------------------------------------
    def on_imu(self, msg):
        """Take one raw sample (sensor_msgs/Imu, serialised or not): :class:`Intake`."""
        self.intake.on_imu(msg)

    def on_mag(self, msg):
        """Take one magnetometer sample (sensor_msgs/MagneticField, tesla)."""
        self.intake.on_mag(msg)

    def on_temperature(self, msg):
        """Remember the latest temperature (sensor_msgs/Temperature)."""
        self.intake.on_temperature(msg)

    @property
    def frame_id(self):
        """Return the frame_id of the imu/data_raw messages ('' before the first)."""
        return self.intake.frame_id

    def process_pending(self):
        """Hand the samples taken in to the collector and the detector; announce new windows."""
        rows, mags = self.intake.take()
        rows = np.array(rows, float).reshape(-1, 8)
        k = 0                   # each magnetometer sample joins the samples of its time
        for start in range(0, len(rows), COLLECT_BLOCK):
            block = rows[start:start + COLLECT_BLOCK]
            while k < len(mags) and mags[k][0] <= block[-1, 0]:
                self.imu.add_mag(mags[k][0], mags[k][1:4])
                k += 1
            self.imu.add_samples(block)
        for m in mags[k:]:      # ahead of the samples: they wait for theirs
            self.imu.add_mag(m[0], m[1:4])
        if not len(rows):
            return
        gyro = rows[:, 4:7]
        windows = self.detector.feed(rows[:, 0], rows[:, 1:4], rows[:, 7],
                                     gyro if np.all(np.isfinite(gyro)) else None)
        for window in windows:
            self._add(window, publish=False)
        if windows:
            self.publish_status(self.windows[-1], advice=True)

    def _add(self, window, publish=True):
        if window is None:
            return
        window = Window.from_detector(window)
        self.windows.append(window)
        if publish:
            self.publish_status(window, advice=True)

    # -- progress --------------------------------------------------------------------------
    def window_set(self, extra=()):
        """Return the windows kept (and ``extra`` ones) as a WindowSet."""
        return WindowSet.from_windows(list(self.windows) + [
            w if isinstance(w, Window) else Window.from_detector(w) for w in extra])

    def _arrays(self, extra=()):
        obs = self.window_set(extra).observations(self.params['max_weight_s'],
                                                  self.detector.rate_hz)
        noise = obs.noise if obs.noise is not None else np.zeros(3)
        return obs.readings, obs.weights, obs.temps, noise

    def _method(self):
        return 'gn' if self.params['method'] == 'gn' else 'ml'

    def compute_advice(self):
        """Return the §5 advice (interface.md) for the windows so far (numbers finite or None)."""
        means, weights, _, noise = self._arrays()
        try:
            advice = advise(means, weights, noise if len(means) else 0.03,
                            self.params['gravity'], method=self._method(),
                            target=self.params['target_accuracy'])
        except (InputError, CalibrationError, ValueError, np.linalg.LinAlgError) as err:
            self.get_logger().debug(f'advice skipped: {err}')
            return None, None
        return advice, advice.to_dict()

    def progress(self, advice=None):
        """Summarise the collection as a dict (what ``~/status`` publishes)."""
        means, weights, temps, noise = self._arrays()
        d = {'windows': len(means), 'rate_hz': finite_or_none(self.detector.rate_hz, 3),
             'seq': self._seq, 'dropped_samples': self.intake.dropped,
             'samples_received': self.intake.received, 'calibrating': self._solving is not None,
             'coverage': {'min_eigenvalue_x3': 0.0, 'distinct_directions': 0},
             'predicted_accuracy': None, 'target_accuracy': self.params['target_accuracy'],
             'enough': False, 'next_pose': None, 'last_window': None,
             'temperature_c': None, 'last_calibration': self._last_result,
             'model_gap': self._model_gap, 'imu': self.imu.state(self._coverage)}
        if self._advice is not None:
            a = self._advice
            d['predicted_accuracy'] = a['predicted_accuracy']
            d['enough'] = a['enough']
            d['next_pose'] = a['next_pose']
        if advice is not None and advice.directions is not None and len(advice.directions):
            eig, distinct = coverage(advice.directions)
            d['coverage'] = {'min_eigenvalue_x3': round(eig, 4),
                             'distinct_directions': int(distinct)}
        elif self._last_coverage is not None:
            d['coverage'] = self._last_coverage
        finite_t = temps[np.isfinite(temps)]
        if len(finite_t):
            d['temperature_c'] = [round(float(finite_t.min()), 2),
                                  round(float(finite_t.max()), 2)]
        self._last_coverage = d['coverage']
        return d

    _last_coverage = None

    def publish_status(self, window=None, advice=False):
        """
        Publish ``~/status`` (and ``~/advice`` when asked); log one line for a new window.

        :param window: the window just finished, or None.
        :param advice: recompute and publish the advice.
        """
        self._seq += 1
        obj = None
        if advice:
            obj, self._advice = self.compute_advice()
            self._coverage = self.imu.coverage() if len(self.imu.mag) >= 10 else None
            if self._advice is not None:
                self.advice_pub.publish(String(data=safe_json(self._advice)))
        d = self.progress(obj)
        if window is not None:
            d['last_window'] = {
                'mean': [finite_or_none(v, 5) for v in window.mean],
                'count': int(window.count), 'duration_s': finite_or_none(window.duration_s, 3)}
            pose = d['next_pose']
            acc = d['predicted_accuracy']
            self.get_logger().info(
                f'window {d["windows"]}: mean ({", ".join(f"{v:.3f}" for v in window.mean)})'
                f' m/s2, {window.count} samples; predicted accuracy '
                + (f'{acc:.4f} m/s2' if acc is not None else 'not yet')
                + ('; enough' if d['enough'] else
                   f'; next: {pose["name"]}' if pose else ''))
        self.status_pub.publish(String(data=safe_json(d)))

    def publish_diagnostics(self):
        """Publish the collection state on /diagnostics (REP-107)."""
        n = len(self.windows)
        acc = self._advice['predicted_accuracy'] if self._advice else None
        status = DiagnosticStatus(level=DiagnosticStatus.OK,
                                  name=f'{self.get_name()}: collection',
                                  hardware_id=hardware_id(self.frame_id))
        status.message = f'{n} static windows' + (
            f', predicted accuracy {acc:.4f} m/s2' if acc is not None else '')
        if self.detector.rate_hz is None:
            status.level = DiagnosticStatus.WARN
            status.message = 'no imu/data_raw received yet'
        if self._last_result is not None and not self._last_result['success']:
            status.level = DiagnosticStatus.WARN
            status.message += '; last calibration refused'
        values = {'windows': n, 'rate_hz': finite_or_none(self.detector.rate_hz, 2),
                  'imu_received': self.intake.received,
                  'dropped_non_finite_samples': self.intake.dropped,
                  'calibrating': self._solving is not None,
                  'predicted_accuracy_m_s2': acc,
                  'target_accuracy_m_s2': self.params['target_accuracy'],
                  'calibration_file': self.path,
                  'last_calibration': (self._last_result or {}).get('message', 'none')}
        imu = self.imu.state(self._coverage)
        values.update({'gyro_received': imu['gyro_received'],
                       'raw_samples_kept': imu['raw_samples'],
                       'mag_received': imu['mag_received'], 'mag_samples_kept': imu['mag_samples'],
                       'mag_coverage': imu['mag_coverage']})
        status.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.get_clock().now().to_msg()
        self.diag_pub.publish(array)

    # -- services --------------------------------------------------------------------------
    def on_reset(self, request, response):
        """
        Forget all collected windows (a calibration running goes on with its own copy).

        :param request: std_srvs/Trigger request (empty).
        :param response: std_srvs/Trigger response.
        :return: the response, success=True.
        """
        n = len(self.windows)
        self.intake.take()
        self.windows.clear()
        self.imu.clear()
        self.detector.finish()
        self._model_gap = None
        self.publish_status(advice=True)
        response.success = True
        response.message = f'cleared {n} windows'
        self.get_logger().info(response.message)
        return response

    async def on_calibrate(self, request, response):
        """
        Solve with the collected windows in the worker; save only a sound calibration.

        The window being held right now counts too. The executor goes on while the worker
        fits (this coroutine waits); a call while one runs is refused at once, with the
        reason. The model-gap check runs after the response and lands on ``~/status``.

        :param request: std_srvs/Trigger request (empty).
        :param response: std_srvs/Trigger response.
        :return: the response: success, the key figures and the predicted accuracy, or
            the reason for refusal.
        """
        if self._solving is not None:
            response.success = False
            response.message = (
                'refused: a calibration is already running (started '
                f'{time.monotonic() - self._solving:.1f} s ago); its result comes in the '
                'response to that call and on ~/status')
            self.get_logger().warning(response.message)
            return response
        self._solving = time.monotonic()
        job = None
        try:
            job = self._job()
            self.publish_status()
            done = Future(executor=self.executor)
            done.add_done_callback(lambda _: None)      # its result wakes the executor
            self._worker.submit(run_job, job).add_done_callback(done.set_result)
            outcome, notes = (await done).result()
        except Exception as err:        # noqa: B902 - a bug must not take the node down
            self.get_logger().error(f'~/calibrate failed: {type(err).__name__}: {err}')
            outcome, notes = refused(f'internal error: {type(err).__name__}: {err}',
                                     words=NODE), []
        finally:
            self._solving = None
        self._report(outcome, notes, response)
        if job is not None:
            cal = outcome.calibration
            self._schedule_model_gap(job.windows, None if cal is None or cal.thermal is None
                                     else len(cal.thermal.usable))
        return response

    def calibrate_and_wait(self, timeout=300.0):
        """
        Run ``~/calibrate`` from this thread and wait for its response (a node not spun).

        The same path as the service (the work in the worker thread); for scripts and tests
        that drive the node's callbacks themselves.

        :raises TimeoutError: no response within ``timeout`` s.
        """
        call = self.on_calibrate(Trigger.Request(), Trigger.Response())
        deadline = time.monotonic() + timeout
        while True:
            try:
                call.send(None)
            except StopIteration as done:
                return done.value
            if time.monotonic() > deadline:
                call.close()
                raise TimeoutError(f'~/calibrate did not answer within {timeout:g} s')
            time.sleep(0.002)

    def _job(self):
        """Take what ~/calibrate needs, copied (the executor thread goes on changing it)."""
        self.process_pending()
        for window in self.detector.release():
            self._add(window, publish=False)
        windows = self.window_set(self.detector.peek())
        history = self.history_path() if self.params['history'] else None
        return Job(windows=windows,
                   rate_hz=self.detector.rate_hz,
                   settings=self.settings(), imu=CollectedImu(self.imu.snapshot(), windows),
                   path=self.path, history=history,
                   now=self.get_clock().now().nanoseconds * 1e-9)

    def _report(self, outcome, notes, response):
        """Answer, log and publish the outcome of ~/calibrate (the executor thread)."""
        response.success, response.message = outcome.accepted, outcome.message()
        log = self.get_logger()
        if outcome.accepted:
            for warning in outcome.warnings + notes:
                log.warning(warning)
            for o in (outcome.gyro, outcome.magnetometer):
                if o.status in ('insufficient', 'refused'):
                    log.warning(f'{o.sensor} not calibrated ({o.status}): {o.reason}')
            log.info(response.message)
        else:
            log.warning(response.message)
        self._last_result = {'success': response.success, 'message': response.message,
                             'predicted_accuracy': finite_or_none(outcome.predicted_accuracy,
                                                                  6),
                             'max_predicted_error': self.params['max_predicted_error']}
        self._last_result.update(outcome.json_keys())
        self._last_result['sensors'] = outcome.sensors()
        self._model_gap = None
        self.publish_status()

    def settings(self):
        """Return the session settings of the parameters now."""
        p = self.params
        return Settings(method=p['method'], gravity=p['gravity'], thermal=p['thermal'],
                        band_width_c=p['band_width_c'],
                        max_predicted_error=p['max_predicted_error'],
                        max_residual_ratio=p['max_residual_ratio'], refuse_unphysical=True,
                        max_weight_s=p['max_weight_s'],
                        max_scale_error=p['max_scale_error'],
                        max_cross_axis=p['max_cross_axis'], max_bias_g=p['max_bias_g'],
                        max_gyro_error=p['max_gyro_error'], max_mag_error=p['max_mag_error'],
                        field_uT=p['field_uT'] or None,
                        sensor_id=p['sensor_id'] or self.frame_id or None,
                        input_units=SI_UNITS,
                        source=f'ros node {self.get_fully_qualified_name()}', words=NODE)

    def history_path(self):
        """Return the history database path ('' = next to the calibration file)."""
        value = self.params['history_file']
        if value:
            return expand_path(value, 'history_file')
        return os.path.join(os.path.dirname(os.path.abspath(calibration_path(
            self.params['calibration_file']))), 'history.sqlite')

    # -- model-gap check (in the worker, after the response) -----------------------------
    def _schedule_model_gap(self, windows, thermal_bands):
        from ..session.gap import model_gap
        self._gap_asked += 1
        number = self._gap_asked
        work = self._worker.submit(model_gap, windows, self._method(), self.params['gravity'],
                                   self.detector.rate_hz, thermal_bands, self.params['method'])

        def finished(future):           # the worker thread: hand it to the executor
            self._gap = (number, future)
            try:
                self._gap_guard.trigger()
            except Exception:           # noqa: B902 - the node was destroyed meanwhile
                pass
        work.add_done_callback(finished)

    def _on_model_gap(self):
        """Publish the model-gap check that just finished (the latest one asked for)."""
        number, future = self._gap
        if future is None or number != self._gap_asked or future.cancelled():
            return
        try:
            gap = future.result()
        except (CalibrationError, InputError, ValueError, np.linalg.LinAlgError) as err:
            gap = {'missing_effects': [], 'note': f'skipped: {err}'}
        self._gap = (number, None)
        self._model_gap = gap
        if gap and gap['note'] and not gap['note'].startswith('skipped'):
            self.get_logger().info(f'model-gap check: {gap["note"]}')
        self.publish_status()

    def model_gap(self, windows, baseline, thermal_bands=None):
        """
        Run the model-gap check on the windows (``session.gap``) here; return the dict.

        Effects the calibration already models (the temperature tables when it has
        usable bands) are not reported as missing.
        """
        from ..session.gap import model_gap
        return model_gap(WindowSet.from_windows(windows), baseline, self.params['gravity'],
                         self.detector.rate_hz, thermal_bands, self.params['method'])


def main(args=None):
    """Run the node until Ctrl-C; exit status 2 on a bad parameter."""
    run(CalibrationNode, 'accel_calibration', args)


if __name__ == '__main__':
    main()
