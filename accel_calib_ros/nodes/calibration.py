"""
ROS 2 node ``accel_calibration``: collect static poses, advise, solve on request, save.

The live front door of the session floor; docs/calibration_node.md describes it whole.
The samples come in on a callback group and thread of their own
(:mod:`.calibration_intake`); every 0.1 s they go to the streaming static-window detector
and to the IMU collector (:meth:`CalibrationNode.process_pending`: where one more
per-sample state would go), and each window brings the advice (``~/advice``,
``~/status``, ``/diagnostics``: :mod:`.calibration_report`). ``~/calibrate`` fits, judges
and saves with the session floor (``session.finish``)
in a worker thread (:mod:`.calibration_job`) and answers when it is done, while the
samples, ``/diagnostics`` and the parameter services go on; a second call meanwhile is
refused with the reason, and so is a call on SIGINT before its save has begun. The
model-gap check follows in the worker and lands on ``~/status``. The calibration is made
for the sensor of the namespace and ``frame_id`` (``sensor_id``), in its own files.
"""

from collections import deque
import time

from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.task import Future
from std_msgs.msg import String
from std_srvs.srv import Trigger

from .calibration_intake import Intake, subscribe
from .calibration_job import Call, Job, run_job, STOPPING, worker
from .calibration_params import check_rate, PARAMS
from .calibration_report import Progress
from .calibration_thermal import new_binner, run_thermal, thermal_job
from .parameters import declare_parameters, ParameterProblem
from .paths import (check_frame_id, history_path, make_directory, sensor_files, sensor_param,
                    unsafe_output)
from .spinning import run
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


class CalibrationNode(Progress, Node):
    """Collect static windows from the raw IMU stream, advise, and calibrate on request."""

    def __init__(self, **kwargs):
        super().__init__('accel_calibration', **kwargs)
        self.params = declare_parameters(self, PARAMS, self._check_params, self._apply_params)
        self._check_params(self.params, self.params)
        self.params['sensor_id'] = sensor_param(self.params['sensor_id'])
        self.sensor, self.path, self.history = self._files(self.params)
        for what, path in (('calibration_file', self.path), ('history_file', self.history)):
            reason = unsafe_output(path)
            if reason:      # the file system may change: log it now, refuse each write
                self.get_logger().error(f'{what}: {reason}; it will not be written')
        self._make_directory(self.path)
        self.windows = deque(maxlen=self.params['max_windows'])
        self.detector = self._new_detector()
        self._seq = 0
        self._last_result = None    # {'success', 'message', ...} of the last ~/calibrate
        self._last_thermal = None   # the same of the last ~/calibrate_thermal
        self.thermal = new_binner(self.params)  # 10 s bins for ~/calibrate_thermal
        self._advice = None
        self._last_coverage = None  # the coverage last published (kept between windows)
        self._model_gap = None
        self._coverage = None       # fraction of the sphere of field directions seen
        self.imu = ImuCollector(self.params['max_gyro_samples'],
                                self.params['max_mag_samples'])
        self._worker = worker('accel_calibration_fit')
        self._solving = None        # monotonic start of the ~/calibrate that runs, or None
        self._call = None           # its Call
        self._stopping = False      # a signal came: calls are refused, no save begins
        self._gap = (0, None)       # (number of the check asked for, its finished future)
        self._gap_asked = 0
        self._gap_guard = self.create_guard_condition(self._on_model_gap)

        self.status_pub = self.create_publisher(String, '~/status', LATCHED)
        self.advice_pub = self.create_publisher(String, '~/advice', LATCHED)
        self.diag_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        # The samples in a callback group of their own: nodes.spinning runs it on a thread
        # and executor of its own with nothing else in its wait set, so nothing of this
        # node's (services, timers, advice) delays them. One node per process: a __node:=
        # remap names exactly one node.
        self.intake = Intake(lambda: self.get_clock().now().nanoseconds * 1e-9)
        self.stream_group = MutuallyExclusiveCallbackGroup()
        subscribe(self, self.intake, self.stream_group)
        # Re-entrant: a second call is answered (refused) while the first one runs.
        self.create_service(Trigger, '~/calibrate', self.on_calibrate,
                            callback_group=ReentrantCallbackGroup())
        self.create_service(Trigger, '~/calibrate_thermal', self.on_calibrate_thermal,
                            callback_group=ReentrantCallbackGroup())
        self.create_service(Trigger, '~/reset', self.on_reset)
        self.create_timer(PROCESS_PERIOD_S, self.process_pending)
        self.create_timer(1.0, self.publish_diagnostics)
        self.publish_status(advice=True)
        self.get_logger().info(
            f'collecting static poses of sensor {self.sensor} (method '
            f'{self.params["method"]}, file {self.path}); hold each pose still for 2 s, '
            'follow ~/advice, then call ~/calibrate')

    def destroy_node(self):
        """Stop the worker (waiting for the work it has begun), then destroy the node."""
        self._worker.shutdown(wait=True, cancel_futures=True)
        return super().destroy_node()

    def stop_requested(self):
        """
        Stop on a signal (``nodes.spinning.run``): answer a running ``~/calibrate`` now.

        From here on a call is refused ("shutting down") and no save begins; a call whose
        save has begun completes and is answered (``run`` waits for it).
        """
        self._stopping = True
        call = self._call
        if call is not None:
            call.stop(self._refused(STOPPING, call.imu))

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

    def _files(self, params):
        """Return (sensor id, calibration file, history file) the parameters ``params`` say."""
        sensor, path = sensor_files(self.get_namespace(), params)
        return sensor, path, history_path(params['history_file'], path)

    def _check_params(self, changes, proposed):
        """Refuse a start-up value or a change the node cannot work with (no side effects)."""
        if proposed['threshold_factor'] and proposed['threshold_factor'] < 1.0:
            raise ParameterProblem("parameter 'threshold_factor' must be 0 or >= 1, got "
                                   f"{proposed['threshold_factor']!r}")
        check_rate(proposed['rate_hz'])
        check_frame_id(proposed['frame_id'])
        _, path, history = self._files(proposed)
        if changes is proposed or not set(changes) & {'sensor_id', 'frame_id',
                                                      'calibration_file', 'history_file'}:
            return                      # start-up: logged in __init__ (the disk may change)
        for name, value in (('calibration_file', path), ('history_file', history)):
            reason = unsafe_output(value)
            if reason:
                raise ParameterProblem(f'{name}: {reason}')

    def _apply_params(self, changes):
        """Make an accepted change take effect (called after rclpy stored it)."""
        if 'sensor_id' in changes:
            self.params['sensor_id'] = sensor_param(changes['sensor_id'])
        if set(changes) & {'sensor_id', 'frame_id', 'calibration_file', 'history_file'}:
            self.sensor, self.path, self.history = self._files(self.params)
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
        self.thermal.extend(rows[:, 0], rows[:, 1:4], rows[:, 7], gyro)
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
        self.thermal.clear()
        self.detector.finish()
        self._model_gap = None
        self._last_coverage = self._coverage = None
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
        if self._stopping or self._solving is not None:
            response.success = False
            response.message = f'refused: {STOPPING}' if self._stopping else (
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
            call = self._call = Call(done, job.imu)
            self._worker.submit(run_job, job, call.may_save).add_done_callback(call.finish)
            if self._stopping:
                self.stop_requested()
            outcome, notes = (await done).result()
        except Exception as err:        # noqa: B902 - a bug must not take the node down
            self.get_logger().error(f'~/calibrate failed: {type(err).__name__}: {err}')
            outcome, notes = self._refused(f'internal error: {type(err).__name__}: {err}')
        finally:
            self._solving = self._call = None
        self._report(outcome, notes, response)
        if job is not None and not self._stopping:
            cal = outcome.calibration
            self._schedule_model_gap(job.windows, None if cal is None or cal.thermal is None
                                     else len(cal.thermal.usable))
        return response

    async def on_calibrate_thermal(self, request, response):
        """
        Fit the thermal part of one still pose to the bins collected, on top of the file.

        As ``accel-calib fit --thermal --calibration``: the robot sat still while the
        temperature swept (a warm-up). In the worker; refused at once while a calibration
        runs or the node stops; a refusal leaves the file as it was.

        :param request: std_srvs/Trigger request (empty).
        :param response: std_srvs/Trigger response: success and the summary, or the reason.
        """
        if self._stopping or self._solving is not None:
            response.success = False
            response.message = f'refused: {STOPPING}' if self._stopping else \
                'refused: a calibration is already running; call again when it has answered'
            return response
        self._solving = time.monotonic()
        try:
            self.process_pending()
            job = thermal_job(self)
            if isinstance(job, str):
                success, message, notes = False, f'refused: {job}', []
            else:
                done = Future(executor=self.executor)
                done.add_done_callback(lambda _: None)      # its result wakes the executor
                call = self._call = Call(done, None)      # a signal answers it (refused)
                self._worker.submit(run_thermal, job, call.may_save).add_done_callback(
                    call.finish)
                if self._stopping:
                    self.stop_requested()
                result = (await done).result()
                success, message, notes = result if len(result) == 3 else \
                    (False, f'refused: {STOPPING}', [])
        except Exception as err:        # noqa: B902 - a bug must not take the node down
            success, message, notes = False, f'internal error: {type(err).__name__}: {err}', []
        finally:
            self._solving = self._call = None
        log = self.get_logger()
        if success:         # rclpy: one severity per call site
            log.info(f'~/calibrate_thermal: {message}')
        else:
            log.warning(f'~/calibrate_thermal: {message}')
        for note in notes:
            log.warning(f'~/calibrate_thermal: {note}')
        self._last_thermal = {'success': success, 'message': message, 'notes': notes}
        response.success, response.message = success, message
        self.publish_status()
        return response

    @staticmethod
    def _refused(reason, imu=None):
        """Return (a refused Outcome, no notes): ``reason``, the other sensors not fitted."""
        return refused(reason, imu, words=NODE), []

    def calibrate_and_wait(self, timeout=300.0):
        """
        Run ``~/calibrate`` from this thread and wait for its response (a node not spun).

        The same path as the service (the work in the worker thread); for scripts and tests
        that drive the node's callbacks themselves.

        :raises TimeoutError: no response within ``timeout`` s.
        """
        return self._wait(self.on_calibrate, '~/calibrate', timeout)

    def calibrate_thermal_and_wait(self, timeout=300.0):
        """Run ``~/calibrate_thermal`` as :meth:`calibrate_and_wait` runs ``~/calibrate``."""
        return self._wait(self.on_calibrate_thermal, '~/calibrate_thermal', timeout)

    @staticmethod
    def _wait(service, name, timeout):
        call = service(Trigger.Request(), Trigger.Response())
        deadline = time.monotonic() + timeout
        while True:
            try:
                call.send(None)
            except StopIteration as done:
                return done.value
            if time.monotonic() > deadline:
                call.close()
                raise TimeoutError(f'{name} did not answer within {timeout:g} s')
            time.sleep(0.002)

    def _job(self):
        """Take what ~/calibrate needs, copied (the executor thread goes on changing it)."""
        self.process_pending()
        for window in self.detector.release():
            self._add(window, publish=False)
        windows = self.window_set(self.detector.peek())
        history = self.history if self.params['history'] else None
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
                        sensor_id=self.sensor,
                        input_units=SI_UNITS,
                        source=f'ros node {self.get_fully_qualified_name()}', words=NODE)

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
