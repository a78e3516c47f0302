"""
ROS 2 node ``accel_calibration``: collect static poses, advise, solve on request, save.

A thin shell around :mod:`accel_calib_ros.core`:

- ``imu/data_raw`` (sensor_msgs/Imu) and ``imu/temperature`` (sensor_msgs/Temperature),
  both with the sensor-data QoS, are buffered and handed in chunks to the
  :class:`~accel_calib_ros.core.windows.OnlineStaticDetector`, the streaming form of
  the detector ``accel-calib fit`` uses (same parameters, same windows; the sample rate
  is tracked all along; the gyro joins the stillness test). At most ``max_windows``
  windows are kept.
- after each window: one log line, the advice of :func:`core.advice.advise` (interface.md §5
  JSON) on ``~/advice`` and the progress on ``~/status`` (both std_msgs/String JSON,
  reliable, transient local, depth 1), and ``/diagnostics`` at 1 Hz.
- ``~/calibrate`` (std_srvs/Trigger) fits ``method`` to the windows and, only if the
  result is sound (converged, residual, physical, predicted accuracy at most
  ``max_predicted_error``), writes ``calibration_file`` atomically with the gyro bias
  of the windows; otherwise it refuses with the reason and the file stays byte-for-byte
  as it was. The model-gap check runs after the response and is published on
  ``~/status``. ``~/reset`` forgets the collected windows.
- the whole IMU (interface.md §9, §10): the raw samples (bounded ring, ``max_gyro_samples``)
  and ``imu/mag`` (sensor_msgs/MagneticField, tesla; decimated, ``max_mag_samples``)
  are kept (:class:`core.collector.ImuCollector`); once the accelerometer calibration
  is accepted, ``~/calibrate`` also fits the gyroscope's scale and misalignment from
  the moves between the windows and the magnetometer, and stores each part that
  passes its own limit (``max_gyro_error``, ``max_mag_error``). A sensor whose data
  are absent or insufficient is reported as such (response, ``~/status``), never as a
  failure of the accelerometer calibration.
"""

from collections import deque
import json
import math
import os

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
import numpy as np
from rclpy.node import Node
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, qos_profile_sensor_data, QoSProfile,
                       ReliabilityPolicy)
from sensor_msgs.msg import Imu, MagneticField, Temperature
from std_msgs.msg import String
from std_srvs.srv import Trigger

from .common import (calibration_path, declare_parameters, expand_path, make_directory, Param,
                     ParameterProblem, run, unsafe_output)
from ..core.advice import advise, coverage
from ..core.collector import DEFAULT_MAX_MAG_SAMPLES, DEFAULT_MAX_SAMPLES, ImuCollector
from ..core.constants import G0
from ..core.errors import CalibrationError, InputError
from ..core.finite import finite_or_none
from ..core.outcomes import DEFAULT_MAX_GYRO_ERROR, DEFAULT_MAX_MAG_ERROR
from ..core.windows import DEFAULTS, OnlineStaticDetector
from ..session.accept import (CollectedImu, fit_and_accept, NODE, Outcome, Settings, SI_UNITS,
                              THERMAL_MODES)
from ..session.windows import Window, WindowSet

METHODS = ('ml', 'gn', 'ml-bc')
MIN_RATE_HZ = 1.0
"""Lowest nonzero ``rate_hz`` accepted, Hz (an IMU below 1 Hz is a unit mistake)."""
QUEUE_DEPTH = 200
"""Input queue depth (samples): 1 s at 200 Hz, 0.2 s at 1 kHz."""
CHUNK = 100
"""Samples buffered before they go to the detector (also flushed every 0.1 s)."""
LATCHED = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST,
                     reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)


def stamp_seconds(stamp):
    """builtin_interfaces/Time as float seconds."""
    return stamp.sec + stamp.nanosec * 1e-9


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


def _detector_param(name, description):
    return Param(name, 0.0, description + f' (0 = as accel-calib fit: {DEFAULTS[name]:g} s)'
                 if name.endswith('_s') else description
                 + f' (0 = as accel-calib fit: {DEFAULTS[name]:g})', low=0.0, high=60.0)


PARAMS = [
    Param('method', 'ml', 'solver: ml (Sun & Xu, 9 parameters), gn (6 parameters) or ml-bc',
          choices=METHODS),
    Param('calibration_file', '',
          "YAML file written by ~/calibrate ('' = $ROS_HOME/accel_calib_ros/"
          'calibration.yaml); its directory is created'),
    Param('gravity', G0, 'local gravity magnitude, m/s2', low=9.7, high=9.9),
    Param('band_width_c', 10.0, 'width of a temperature band, degC', low=0.1, high=100.0),
    Param('thermal', 'auto',
          'auto: temperature-band tables when >= 2 bands are filled; on; off',
          choices=THERMAL_MODES),
    Param('max_residual_ratio', 10.0,
          'refuse when the gravity-norm residual RMS exceeds this x window-mean noise',
          low=1.0),
    Param('max_scale_error', 0.2, 'refuse when |T_ii - 1| exceeds this', low=0.0,
          low_open=True, high=1.0),
    Param('max_cross_axis', 0.1, 'refuse when |T_ij| / T_ii exceeds this', low=0.0,
          low_open=True, high=1.0),
    Param('max_bias_g', 0.25, 'refuse when a bias exceeds this many g', low=0.0,
          low_open=True, high=2.0),
    Param('max_predicted_error', 0.02,
          'refuse when the predicted accuracy (RMS error at 1 g over all orientations) '
          'exceeds this, m/s2', low=0.0, low_open=True, high=10.0),
    Param('target_accuracy', 0.01,
          'predicted accuracy that is enough: the advice says "enough" below it, m/s2',
          low=0.0, low_open=True, high=10.0),
    _detector_param('window_s', 'moving standard deviation window, s'),
    _detector_param('min_duration_s', 'shortest static window kept after trimming, s'),
    _detector_param('trim_s', 'cut from each end of a still stretch, s'),
    _detector_param('threshold_factor', 'still when moving std < factor x noise floor'),
    Param('use_gyro', True, 'the angular rate must be still too (when the driver sends it)'),
    Param('max_windows', 500, 'windows kept; the oldest are dropped beyond', low=10,
          high=100000),
    Param('max_weight_s', 5.0, 'a window weighs at most this many seconds of samples',
          low=1e-3, high=3600.0),
    Param('rate_hz', 0.0,
          'sample rate to start with, Hz: 0 (measure it from the stamps; always tracked) '
          f'or {MIN_RATE_HZ:g} .. 100000', low=0.0, high=100000.0),
    Param('sensor_id', '',
          "name of the sensor in the history ('' = the messages' frame_id); printable, "
          'surrounding spaces dropped'),
    Param('history', True,
          'record each saved calibration and its windows in the history database'),
    Param('history_file', '',
          "history database ('' = history.sqlite next to calibration_file)"),
    Param('max_gyro_samples', DEFAULT_MAX_SAMPLES,
          'raw samples kept for the gyroscope scale/misalignment fit (36 bytes each; the '
          'moves between the windows still kept are used; 0 = no gyro T)', low=0,
          high=10_000_000, read_only=True),
    Param('max_mag_samples', DEFAULT_MAX_MAG_SAMPLES,
          'imu/mag samples kept for the magnetometer fit (decimated by 2 whenever full; '
          '0 = no magnetometer calibration)', low=0, high=1_000_000, read_only=True),
    Param('max_gyro_error', DEFAULT_MAX_GYRO_ERROR,
          'store the gyro scale/misalignment only when its predicted accuracy (RMS '
          'relative rate error over all directions) is at most this', low=0.0,
          low_open=True, high=1.0),
    Param('max_mag_error', DEFAULT_MAX_MAG_ERROR,
          'store the magnetometer calibration only when its predicted accuracy (RMS field '
          'error over all directions) is at most this, uT', low=0.0, low_open=True,
          high=1000.0),
    Param('field_uT', 0.0,
          'known local magnetic field magnitude, uT (0 = fitted, trusting the '
          'magnetometer sensitivity on average)', low=0.0, high=1000.0),
]


class CalibrationNode(Node):
    """Collect static windows from the raw IMU stream, advise, and calibrate on request."""

    def __init__(self, **kwargs):
        super().__init__('accel_calibration', **kwargs)
        self.params = declare_parameters(self, PARAMS, self._on_params)
        if self.params['threshold_factor'] and self.params['threshold_factor'] < 1.0:
            raise ParameterProblem("parameter 'threshold_factor' must be 0 or >= 1, got "
                                   f"{self.params['threshold_factor']!r}")
        _check_rate(self.params['rate_hz'])
        self.params['sensor_id'] = _sensor_param(self.params['sensor_id'])
        expand_path(self.params['history_file'], 'history_file')
        self.path = calibration_path(self.params['calibration_file'])
        files = (('calibration_file', self.path), ('history_file', self.history_path()))
        for what, path in files:
            reason = unsafe_output(path)
            if reason:      # the file system may change: log it now, refuse each write
                self.get_logger().error(f'{what}: {reason}; it will not be written')
        self._make_directory(self.path)
        self.windows = deque(maxlen=self.params['max_windows'])
        self.temperature = float('nan')
        self.frame_id = ''
        self.detector = self._new_detector()
        self._pending = []          # (t, ax, ay, az, gx, gy, gz, temp) not yet detected
        self._seq = 0
        self._dropped = 0           # samples with a non-finite acceleration
        self._last_result = None    # {'success', 'message', ...} of the last ~/calibrate
        self._advice = None
        self._model_gap = None
        self._gap_timer = None
        self.imu = ImuCollector(self.params['max_gyro_samples'],
                                self.params['max_mag_samples'])
        self._imu_result = None     # (gyro, magnetometer) SensorOutcome of ~/calibrate
        self._coverage = None       # fraction of the sphere of field directions seen

        self.status_pub = self.create_publisher(String, '~/status', LATCHED)
        self.advice_pub = self.create_publisher(String, '~/advice', LATCHED)
        self.diag_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        # Sensor-data QoS (best effort, volatile) with a deeper queue than its 5, so a
        # solve or a burst does not drop samples.
        sub_qos = QoSProfile(depth=QUEUE_DEPTH, history=qos_profile_sensor_data.history,
                             reliability=qos_profile_sensor_data.reliability,
                             durability=qos_profile_sensor_data.durability)
        self.create_subscription(Imu, 'imu/data_raw', self.on_imu, sub_qos)
        self.create_subscription(Temperature, 'imu/temperature', self.on_temperature, sub_qos)
        self.create_subscription(MagneticField, 'imu/mag', self.on_mag, sub_qos)
        self.create_service(Trigger, '~/calibrate', self.on_calibrate)
        self.create_service(Trigger, '~/reset', self.on_reset)
        self.create_timer(0.1, self.process_pending)
        self.create_timer(1.0, self.publish_diagnostics)
        self.publish_status(advice=True)
        self.get_logger().info(
            f'collecting static poses (method {self.params["method"]}, file {self.path}); '
            'hold each pose still for 2 s, follow ~/advice, then call ~/calibrate')

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
            _check_rate(changes['rate_hz'])
        if 'sensor_id' in changes:
            self.params['sensor_id'] = _sensor_param(changes['sensor_id'])
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
    def on_temperature(self, msg):
        """
        Remember the latest temperature, °C.

        :param msg: sensor_msgs/Temperature.
        """
        if math.isfinite(msg.temperature):
            self.temperature = float(msg.temperature)

    def on_imu(self, msg):
        """
        Buffer one raw sample for the static-window detector.

        :param msg: sensor_msgs/Imu with raw linear_acceleration, m/s².
        """
        a, w = msg.linear_acceleration, msg.angular_velocity
        if not (math.isfinite(a.x) and math.isfinite(a.y) and math.isfinite(a.z)):
            self._dropped += 1
            return
        t = stamp_seconds(msg.header.stamp)
        if t <= 0.0:                                            # unstamped: receive time
            t = self.get_clock().now().nanoseconds * 1e-9
        if not self.frame_id:
            self.frame_id = msg.header.frame_id
        gyro_known = msg.angular_velocity_covariance[0] >= 0.0
        self._pending.append((t, a.x, a.y, a.z) + ((w.x, w.y, w.z) if gyro_known
                                                   else (math.nan,) * 3)
                             + (self.temperature,))
        if len(self._pending) >= CHUNK:
            self.process_pending()

    def on_mag(self, msg):
        """
        Offer one magnetometer sample to the collector (tesla -> µT).

        :param msg: sensor_msgs/MagneticField in the accelerometer frame.
        """
        f = msg.magnetic_field
        t = stamp_seconds(msg.header.stamp)
        if t <= 0.0:                                            # unstamped: receive time
            t = self.get_clock().now().nanoseconds * 1e-9
        self.imu.add_mag(t, (f.x * 1e6, f.y * 1e6, f.z * 1e6))

    def process_pending(self):
        """Hand the buffered samples to the detector; keep and announce new windows."""
        if not self._pending:
            return
        rows = np.array(self._pending, float)
        self._pending = []
        self.imu.add_samples(rows)
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
             'seq': self._seq, 'dropped_samples': self._dropped,
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
                                  hardware_id=self.params['sensor_id'] or self.frame_id)
        status.message = f'{n} static windows' + (
            f', predicted accuracy {acc:.4f} m/s2' if acc is not None else '')
        if self.detector.rate_hz is None:
            status.level = DiagnosticStatus.WARN
            status.message = 'no imu/data_raw received yet'
        if self._last_result is not None and not self._last_result['success']:
            status.level = DiagnosticStatus.WARN
            status.message += '; last calibration refused'
        values = {'windows': n, 'rate_hz': finite_or_none(self.detector.rate_hz, 2),
                  'dropped_non_finite_samples': self._dropped,
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
        Forget all collected windows.

        :param request: std_srvs/Trigger request (empty).
        :param response: std_srvs/Trigger response.
        :return: the response, success=True.
        """
        n = len(self.windows)
        self._pending = []
        self.windows.clear()
        self.imu.clear()
        self.detector.finish()
        self._model_gap = None
        self.publish_status(advice=True)
        response.success = True
        response.message = f'cleared {n} windows'
        self.get_logger().info(response.message)
        return response

    def on_calibrate(self, request, response):
        """
        Solve with the collected windows; save only a sound calibration.

        The window being held right now counts too. The model-gap check runs after the
        response (one-shot timer) and lands on ``~/status``.

        :param request: std_srvs/Trigger request (empty).
        :param response: std_srvs/Trigger response.
        :return: the response: success, the key figures and the predicted accuracy, or
            the reason for refusal.
        """
        self.process_pending()
        for window in self.detector.release():
            self._add(window, publish=False)
        held = [Window.from_detector(w) for w in self.detector.peek()]
        outcome = self.solve(held)
        response.success, response.message = outcome.accepted, outcome.message()
        if outcome.accepted:
            for warning in outcome.warnings:
                self.get_logger().warning(warning)
            for o in (outcome.gyro, outcome.magnetometer):
                if o.status in ('insufficient', 'refused'):
                    self.get_logger().warning(f'{o.sensor} not calibrated ({o.status}): '
                                              f'{o.reason}')
            self.get_logger().info(response.message)
        else:
            self.get_logger().warning(response.message)
        self._last_result = {'success': response.success, 'message': response.message,
                             'predicted_accuracy': finite_or_none(outcome.predicted_accuracy,
                                                                  6),
                             'max_predicted_error': self.params['max_predicted_error']}
        self._last_result.update(outcome.json_keys())
        self._last_result['sensors'] = outcome.sensors()
        self._model_gap = None
        self.publish_status()
        cal = outcome.calibration
        self._schedule_model_gap(held, None if cal is None or cal.thermal is None
                                 else len(cal.thermal.usable))
        return response

    def settings(self):
        """Return the session settings of the parameters now."""
        p = self.params
        return Settings(method=p['method'], gravity=p['gravity'], thermal=p['thermal'],
                        band_width_c=p['band_width_c'],
                        max_predicted_error=p['max_predicted_error'],
                        max_residual_ratio=p['max_residual_ratio'], refuse_unphysical=True,
                        max_scale_error=p['max_scale_error'],
                        max_cross_axis=p['max_cross_axis'], max_bias_g=p['max_bias_g'],
                        max_gyro_error=p['max_gyro_error'], max_mag_error=p['max_mag_error'],
                        field_uT=p['field_uT'] or None,
                        sensor_id=p['sensor_id'] or self.frame_id or None,
                        input_units=SI_UNITS,
                        source=f'ros node {self.get_fully_qualified_name()}', words=NODE)

    def solve(self, held=()):
        """
        Fit, judge (``session.accept``) and save (``session.persist``).

        :param held: windows of the pose being held now (not yet finished).
        :return: the session Outcome (``refusal`` says why when it is not accepted).
        """
        from ..session.persist import save
        windows = self.window_set(held)
        obs = windows.observations(self.params['max_weight_s'], self.detector.rate_hz)
        try:
            outcome = fit_and_accept(obs, self.settings(), CollectedImu(self.imu, windows))
        except InputError as err:
            return Outcome(refusal=str(err), observations=len(obs)).refuse(str(err))
        if not outcome.accepted:
            return outcome
        self._make_directory(self.path)
        try:
            save(outcome, self.path)
        except (OSError, InputError, CalibrationError) as err:
            return outcome.refuse(f'cannot write {self.path}: {err}')
        self.record_history(outcome.calibration, windows, obs.weights)
        return outcome

    def history_path(self):
        """Return the history database path ('' = next to the calibration file)."""
        value = self.params['history_file']
        if value:
            return expand_path(value, 'history_file')
        return os.path.join(os.path.dirname(os.path.abspath(calibration_path(
            self.params['calibration_file']))), 'history.sqlite')

    def record_history(self, cal, windows, weights):
        """Record a saved calibration and its windows (a failure is logged, not fatal)."""
        if not self.params['history']:
            return
        import sqlite3
        from ..session.persist import record_history, window_times
        try:
            sensor = _sensor_param(cal.sensor_id or 'imu') or 'imu'
        except ParameterProblem as err:     # a frame_id no sensor id may be
            self.get_logger().warning(f'history not recorded: {err}')
            return
        now = self.get_clock().now().nanoseconds * 1e-9
        gyro = windows.gyro_mean if windows.gyro_mean is not None else \
            np.full((len(windows), 3), np.nan)
        try:            # one session: the windows and the calibration, one transaction
            record_history(self.history_path(), sensor, cal, windows.mean, windows.temp,
                           weights, window_times(windows.t_mid, now=now), gyro,
                           windows=len(windows))
        except (InputError, ParameterProblem, sqlite3.Error, OSError, ValueError) as err:
            self.get_logger().warning(f'history not recorded: {err}')

    # -- model-gap check (off the service's critical path) ------------------------------
    def _schedule_model_gap(self, held, thermal_bands):
        if self._gap_timer is not None:
            self.destroy_timer(self._gap_timer)
        windows = list(self.windows) + list(held)
        method = self._method()

        def run_once():
            self.destroy_timer(self._gap_timer)
            self._gap_timer = None
            self._model_gap = self.model_gap(windows, method, thermal_bands)
            self.publish_status()
        self._gap_timer = self.create_timer(0.01, run_once)

    def model_gap(self, windows, baseline, thermal_bands=None):
        """
        Run the model-gap check on the windows (``session.gap``); return a dict for ``~/status``.

        Effects the calibration already models (the temperature tables when it has
        usable bands) are not reported as missing.
        """
        from ..session.gap import model_gap
        gap = model_gap(WindowSet.from_windows(windows), baseline, self.params['gravity'],
                        self.detector.rate_hz, thermal_bands, self.params['method'])
        if gap and gap['note'] and not gap['note'].startswith('skipped'):
            self.get_logger().info(f'model-gap check: {gap["note"]}')
        return gap


def _check_rate(rate_hz):
    """Refuse a starting rate that is neither 0 (measure it) nor an IMU's."""
    if rate_hz and rate_hz < MIN_RATE_HZ:
        raise ParameterProblem(f"parameter 'rate_hz' must be 0 or >= {MIN_RATE_HZ:g} Hz, got "
                               f'{rate_hz!r}')


def _sensor_param(value):
    """Normalise a sensor id parameter ('' stays '': the frame_id is used)."""
    if not value:
        return value
    from ..dataio.sensor_id import normalise_sensor_id
    try:
        return normalise_sensor_id(value)
    except InputError as err:
        raise ParameterProblem(f"parameter 'sensor_id': {err}") from None


def main(args=None):
    """Run the node until Ctrl-C; exit status 2 on a bad parameter."""
    run(CalibrationNode, 'accel_calibration', args)


if __name__ == '__main__':
    main()
