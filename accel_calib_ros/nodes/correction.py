"""
ROS 2 node ``accel_correction``: apply the saved calibration to the live IMU stream.

``imu/data_raw``, ``imu/temperature``, ``imu/mag`` in; ``imu/corrected`` and
``imu/mag_corrected`` out, compensated for the current temperature, levelled when a trim
is stored (then in ``level_frame_id``, its transform on ``/tf_static``:
:mod:`.level_frame`), with the field monitor's gyro bias at rest and calibration health
(:mod:`.correction_monitor`). Only a calibration made for this node's sensor is applied.
The math is :class:`core.correction.Corrector`; this module is the shell: parameters,
messages, hot reload, ``/diagnostics``. Behaviour in full: docs/correction_node.md.
"""

from collections import deque
import math
import os

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
import numpy as np
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.node import Node
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, qos_profile_sensor_data, QoSProfile,
                       ReliabilityPolicy)
from sensor_msgs.msg import Imu, MagneticField, Temperature
from std_srvs.srv import Trigger

from .correction_monitor import NodeMonitor, PARAMS as MONITOR_PARAMS
from .level_frame import LevelFrame
from .parameters import declare_parameters, Param, ParameterProblem
from .paths import check_frame_id, check_topic_name, hardware_id, sensor_files, status_name
from .spinning import run
from ..core.constants import TESLA_PER_UT
from ..core.correction import (Corrector, UNCALIBRATED_COVARIANCE,  # noqa: F401 - re-exported
                               UNCALIBRATED_GYRO_BIAS_STD, UNCALIBRATED_STD, without_level)
from ..core.errors import CalibrationError, InputError
from ..dataio.calibration_file import load_calibration

QUEUE_DEPTH = 100
"""Subscription and publisher queue depth: 0.1 s at 1 kHz, rides out a file reload."""
LEVEL_BUFFER = 5000
"""Raw samples kept for ``~/level`` (5 s at 1 kHz)."""
WARN_PERIOD_S = 30.0
"""Throttle of the repeated warnings (temperature outside the calibrated range)."""


def file_key(path):
    """(st_mtime_ns, st_size, st_ino) of ``path``, or None if it does not exist."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_mtime_ns, st.st_size, st.st_ino


PARAMS = [
    Param('frame_id', 'imu_link',
          "the sensor's frame_id (the driver's): with the namespace it names the sensor "
          '(sensor_id) and its default calibration file', empty_ok=False),
    Param('sensor_id', '',
          "the sensor corrected ('' = namespace/frame_id, e.g. robot1/imu_link): a "
          'calibration file made for another sensor is refused'),
    Param('accept_other_sensor', False,
          'apply a calibration file made for another sensor (its sensor_id differs): on '
          'purpose only'),
    Param('calibration_file', '',
          "calibration YAML to apply ('' = $ROS_HOME/accel_calib_ros/<sensor_id>/"
          'calibration.yaml); re-read whenever it changes; a change at runtime must name '
          'a file that exists'),
    Param('reload_period_s', 0.25, 'how often the file is checked for changes, s',
          low=0.01, high=60.0),
    Param('temperature_margin_c', 2.0,
          'warn when the temperature leaves the calibrated range by more than this, degC',
          low=0.0, high=100.0),
    Param('level_duration_s', 2.0, 'seconds of samples ~/level averages', low=0.1,
          high=5.0),
    Param('diagnostics_period_s', 1.0,
          '/diagnostics period, s (checked every reload_period_s)', low=0.1, high=60.0,
          read_only=True),
    Param('level_frame_id', '',
          "frame_id of imu/corrected and imu/mag_corrected while a level trim is applied ('' "
          "= the raw frame_id + '_level'); without a trim the raw frame_id passes"),
] + MONITOR_PARAMS


class CorrectionNode(Node):
    """Correct the raw accelerometer stream with the calibration file, reloading it live."""

    def __init__(self, **kwargs):
        super().__init__('accel_correction', **kwargs)
        self.params = declare_parameters(self, PARAMS, self._check_params, self._apply_params)
        self._check_params(self.params, self.params)
        self.sensor, self.path = self._files(self.params)
        self.corrector = Corrector(None)
        self.temperature = float('nan')
        self._key = ()              # file key last acted on (loaded or rejected); () = never
        self._file_problem = ''     # why the file on disk is not the one in use
        self._file_level = DiagnosticStatus.WARN    # how bad that is
        self._samples = 0
        self._mag_samples = 0       # imu/mag messages received
        self._mag_published = 0
        self._dropped = 0           # messages not published: a non-finite field
        self._temp_problem = ''
        self._lag_restart = None        # stamp of the last restart of the hysteresis term
        self._rate_hz = None        # messages per second, measured at each diagnostics tick
        self._rate_mark = (None, 0)
        self._recent = deque(maxlen=LEVEL_BUFFER)   # (t, ax, ay, az, temp) for ~/level
        self._frames = ('', '')     # (raw frame_id, the one published) last seen
        self.level_frame = LevelFrame(self)
        self.monitor = NodeMonitor(self)
        self.check_file(initial=True)

        pub_qos = QoSProfile(depth=QUEUE_DEPTH, history=HistoryPolicy.KEEP_LAST,
                             reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.VOLATILE)
        sub_qos = QoSProfile(depth=QUEUE_DEPTH, history=qos_profile_sensor_data.history,
                             reliability=qos_profile_sensor_data.reliability,
                             durability=qos_profile_sensor_data.durability)
        # One node per process (a remap names exactly one node): the Imu path has a
        # callback group of its own, which nodes.spinning runs on an executor and thread
        # of its own (nothing else to wait on: no more executor work per message than a
        # bare relay), the rest of the node on another.
        self.stream_group = MutuallyExclusiveCallbackGroup()
        self.pub = self.create_publisher(Imu, 'imu/corrected', pub_qos)
        self.create_subscription(Imu, 'imu/data_raw', self.on_imu, sub_qos,
                                 callback_group=self.stream_group)
        self.diag_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self.create_subscription(Temperature, 'imu/temperature', self.on_temperature, sub_qos)
        # The magnetometer (100 Hz) with the rest: the Imu path keeps its thread alone.
        self.mag_pub = self.create_publisher(MagneticField, 'imu/mag_corrected', pub_qos)
        self.create_subscription(MagneticField, 'imu/mag', self.on_mag, sub_qos)
        self.create_service(Trigger, '~/level', self.on_level)
        # One timer for both chores (fewer entities for the executor to wait on).
        self._next_diagnostics = 0.0
        self._reload_timer = self.create_timer(self.params['reload_period_s'], self._tick)

    def _files(self, params):
        """Return (sensor id, calibration file) the parameters ``params`` say."""
        return sensor_files(self.get_namespace(), params)

    def _check_params(self, changes, proposed):
        """Refuse a start-up value or a change the node cannot work with (no side effects)."""
        check_frame_id(proposed['frame_id'])
        check_frame_id(proposed['level_frame_id'], 'level_frame_id', empty_ok=True)
        check_topic_name(proposed['stationary_topic'], 'stationary_topic')
        _, path = self._files(proposed)
        if changes is not proposed and set(changes) & {'calibration_file', 'frame_id',
                                                       'sensor_id'} \
                and path != self.path and not os.path.exists(path):
            raise ParameterProblem(f'calibration_file {path}: no such file (the node keeps '
                                   f'{self.path})')

    def _apply_params(self, changes):
        """Make an accepted change take effect (called after rclpy stored it)."""
        if set(changes) & {'calibration_file', 'frame_id', 'sensor_id',
                           'accept_other_sensor'}:
            self.sensor, self.path = self._files(self.params)
            self._key = ()
            self.check_file()
        if 'reload_period_s' in changes:
            self.destroy_timer(self._reload_timer)
            self._reload_timer = self.create_timer(changes['reload_period_s'], self._tick)
        if set(changes) & {'level_frame_id', 'frame_id'}:
            self._frames = ('', '')
            self._update_level_frame()
        if set(changes) & ({p.name for p in MONITOR_PARAMS} | {'temperature_margin_c'}):
            self.monitor.apply(changes)

    def _tick(self):
        """Check the file; publish /diagnostics when its period has passed."""
        self.check_file()
        now = self.get_clock().now().nanoseconds * 1e-9
        if now >= self._next_diagnostics:
            self._next_diagnostics = now + self.params['diagnostics_period_s']
            self.publish_diagnostics()
            self.monitor.update_parameter()
        self.monitor.publish_health()

    # -- the stream ------------------------------------------------------------------------
    def on_temperature(self, msg):
        """
        Remember the latest temperature, °C; warn outside the calibrated range.

        :param msg: sensor_msgs/Temperature.
        """
        temp = msg.temperature
        self.temperature = temp if math.isfinite(temp) else float('nan')
        lag = self.corrector.lag
        if lag is not None and math.isfinite(temp):
            stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
            if stamp <= 0.0:                # no stamp: the time it came
                stamp = self.get_clock().now().nanoseconds * 1e-9
            before = lag.restarts
            self.corrector.take_temperature(stamp, temp)
            if lag.restarts > before:
                self._lag_restart = stamp
                self.get_logger().warning(
                    'imu/temperature paused (or stepped back) for more than '
                    f'{lag.gap_s:g} s: the heating/cooling term restarts from zero',
                    throttle_duration_sec=WARN_PERIOD_S)
        self._check_range()

    def on_imu(self, msg):
        """
        Correct one sample and republish it (dropped if any output is not finite).

        :param msg: sensor_msgs/Imu from the driver (modified in place and published).
        """
        c = self.corrector
        temp = self.temperature
        self._samples += 1
        a = msg.linear_acceleration
        w = msg.angular_velocity
        o = msg.orientation
        self._recent.append((a.x, a.y, a.z, temp))
        a.x, a.y, a.z = x, y, z = c.correct(a.x, a.y, a.z, temp)
        w.x, w.y, w.z = gx, gy, gz = c.correct_gyro(w.x, w.y, w.z, temp)
        msg.linear_acceleration_covariance = c.covariance
        # The incoming covariances rarely change: judge them once per distinct value
        # (cached on the corrector, so a new calibration starts afresh).
        key = msg.orientation_covariance.tobytes() + msg.angular_velocity_covariance.tobytes()
        if key != c.cov_key:
            wcov = c.gyro_covariance(msg.angular_velocity_covariance)
            c.cov_finite = bool(np.all(np.isfinite(msg.orientation_covariance)) and np.all(
                np.isfinite(msg.angular_velocity_covariance if wcov is None else wcov)))
            c.wcov, c.cov_key = wcov, key
        if c.wcov is not None:
            if c.gyro_rate_var:     # the calibration's relative error at this rate
                wcov = c.wcov.copy()
                extra = c.gyro_rate_var * (gx * gx + gy * gy + gz * gz)
                wcov[0] += extra
                wcov[4] += extra
                wcov[8] += extra
                msg.angular_velocity_covariance = wcov
            else:
                msg.angular_velocity_covariance = c.wcov
        check = x + y + z + gx + gy + gz + o.x + o.y + o.z + o.w
        if check - check != 0.0 or not c.cov_finite:      # NaN or infinite somewhere
            self._dropped += 1
            if self._dropped == 1 or self._dropped % 1000 == 0:
                self.get_logger().warning(
                    f'dropped {self._dropped} message(s) with a non-finite value')
            return
        mon = self.monitor
        if mon.active:      # the field monitor: one list append, a block every 0.1 s
            buf = mon.buf
            st = msg.header.stamp
            buf.append((st.sec + st.nanosec * 1e-9, x, y, z, gx, gy, gz, temp))
            if len(buf) >= mon.block_n:
                mon.flush()
            bx, by, bz = mon.bias
            w.x, w.y, w.z = gx - bx, gy - by, gz - bz
        h = msg.header
        if h.frame_id != self._frames[0]:       # the sensor's frame (a new one: rare)
            self._frames = (h.frame_id, self.level_frame_id(h.frame_id))
        if c.trimmed:       # levelled axes: the frame says so
            h.frame_id = self._frames[1]
        self.pub.publish(msg)

    def on_mag(self, msg):
        """
        Correct one magnetometer sample into ``imu/mag_corrected`` (with a magnetometer part).

        :param msg: sensor_msgs/MagneticField from the driver, tesla (modified, published).
        """
        self._mag_samples += 1
        c = self.corrector
        if c.mag_M is None:
            return
        f = msg.magnetic_field
        f.x, f.y, f.z = x, y, z = c.correct_mag(f.x, f.y, f.z)
        cov = c.mag_covariance(msg.magnetic_field_covariance)
        if x - x != 0.0 or y - y != 0.0 or z - z != 0.0 or not np.all(np.isfinite(cov)):
            self._dropped += 1
            return
        msg.magnetic_field_covariance = cov
        mon = self.monitor
        if mon.active:
            mon.mag.append((x / TESLA_PER_UT, y / TESLA_PER_UT, z / TESLA_PER_UT))
        if c.trimmed:
            h = msg.header
            frames = self._frames
            h.frame_id = frames[1] if h.frame_id == frames[0] \
                else self.level_frame_id(h.frame_id)
        self._mag_published += 1
        self.mag_pub.publish(msg)

    def level_frame_id(self, raw):
        """Return the frame_id of the levelled output for a raw ``frame_id``."""
        return self.params['level_frame_id'] or f'{raw or self.params["frame_id"]}_level'

    def magnetometer_state(self):
        """Say what happens to ``imu/mag`` (diagnostics)."""
        if self.corrector.mag_M is not None:
            return ('corrected on imu/mag_corrected' if self._mag_samples
                    else 'calibrated, but no imu/mag received')
        if self._mag_samples:
            return 'imu/mag arrives but the calibration has no magnetometer part: not corrected'
        return 'no imu/mag received, no magnetometer calibration'

    # -- the calibration file ----------------------------------------------------------------
    def check_file(self, initial=False):
        """
        Load the calibration file when it changed; keep the old one if it is bad.

        A file made for another sensor (its ``sensor_id``) is refused: nothing of it is
        applied, ``/diagnostics`` says ERROR, unless ``accept_other_sensor``.

        :param initial: first check at start-up (logs the outcome either way).
        """
        self._check_temperature()
        key = file_key(self.path)
        if key == self._key:
            return
        self._key = key
        if key is None:
            if self.corrector.cal is None:
                self._problem(f'no calibration file {self.path}', 'passing the raw '
                              f'acceleration through, covariance ({UNCALIBRATED_STD} '
                              'm/s2)^2 per axis, until one appears')
            else:
                self._problem(f'calibration file {self.path} disappeared',
                              'keeping the calibration loaded before')
            return
        try:
            cal = load_calibration(self.path)
            corrector = Corrector(cal)
        except (InputError, np.linalg.LinAlgError, ValueError) as err:
            self._problem(f'bad calibration file {self.path}: {err}',
                          'keeping the previous calibration' if self.corrector.cal is not None
                          else 'still passing the raw acceleration through')
            return
        other = self._other_sensor(cal)
        if other:
            if self.corrector.cal is not None and self._other_sensor(self.corrector.cal):
                self._use(Corrector(None), 'dropped the calibration of another sensor:')
            self._problem(f'calibration file {self.path} {other}', 'not applied: set '
                          'sensor_id to its sensor, or accept_other_sensor:=true on purpose',
                          DiagnosticStatus.ERROR)
            return
        self._use(corrector, 'loaded' if initial else 'reloaded')

    def _other_sensor(self, cal):
        """Say why ``cal`` is another sensor's ('' when it is this one's or unknown)."""
        made_for = cal.sensor_id
        if made_for is None or self.params['accept_other_sensor']:
            return ''
        from ..dataio.sensor_id import normalise_sensor_id
        try:
            same = normalise_sensor_id(made_for) == self.sensor
        except InputError:
            same = False
        return '' if same else (f'was made for sensor {made_for!r}, this node corrects '
                                f'{self.sensor!r}')

    def _problem(self, problem, consequence, level=DiagnosticStatus.WARN):
        """Note why the file is not in use (/diagnostics); log it when it is news."""
        if problem != self._file_problem:
            log = self.get_logger()
            if level == DiagnosticStatus.ERROR:     # rclpy: one severity per call site
                log.error(f'{problem}: {consequence}')
            else:
                log.warning(f'{problem}: {consequence}')
        self._file_problem, self._file_level = problem, level

    def _use(self, corrector, verb):
        corrector.adopt(self.corrector)     # the temperature's lag goes on over a reload
        self.corrector = corrector
        self._file_problem = ''
        cal = corrector.cal
        self.monitor.use(cal)       # a new calibration: the field monitor starts afresh
        self._update_level_frame()
        if cal is None:
            self.get_logger().warning(f'{verb} passing the raw acceleration through')
            return
        std = np.sqrt(np.diag(cal.acceleration_covariance()))
        acc = cal.predicted_accuracy
        self.get_logger().info(
            f'{verb} {cal.method} calibration {self.path} (sensor {cal.sensor_id}, created '
            f'{cal.created}, scale {np.round(cal.scale, 5).tolist()}, bias '
            f'{np.round(cal.bias, 4).tolist()} m/s2, thermal bands '
            f'{0 if cal.thermal is None else len(cal.thermal.usable)}, '
            f'per-axis std {np.round(std, 4).tolist()} m/s2'
            + (f', predicted accuracy {acc:.4f} m/s2' if acc is not None else '')
            + (', gyro bias' if cal.gyro_bias is not None else '')
            + (', gyro scale and misalignment' if cal.gyro_T is not None else '')
            + (', magnetometer' if cal.magnetometer is not None else '')
            + (', level trim' if cal.level_roll_pitch_rad is not None else '') + ')')
        if cal.level_roll_pitch_rad is not None:
            self.get_logger().info(f'level frame: {self.level_frame.words()}')
        self._check_range()

    def _update_level_frame(self):
        """Make the level frame's transform of the trim in force known (/tf_static)."""
        cal = self.corrector.cal
        trim = None if cal is None or cal.level_roll_pitch_rad is None \
            else cal.level_rotation()
        raw = self._frames[0] or self.params['frame_id']
        self.level_frame.update(raw, self.level_frame_id(raw), trim)

    def _check_temperature(self):
        cal = self.corrector.cal
        if self._samples < 200 or cal is None or cal.thermal is None \
                or not cal.thermal.usable or math.isfinite(self.temperature):
            return
        self.get_logger().warning(
            'the calibration has temperature tables but no imu/temperature arrived: '
            'correcting without the temperature drift', once=True)

    def _check_range(self):
        """Warn (throttled) when the temperature is outside the calibrated range."""
        cal = self.corrector.cal
        temp = self.temperature
        rng = None if cal is None else cal.temperature_range_c
        if rng is None or not math.isfinite(temp):
            self._temp_problem = ''
            return
        margin = self.params['temperature_margin_c']
        low, high = rng
        if low - margin <= temp <= high + margin:
            self._temp_problem = ''
            return
        beyond = ('the offset tables are continued linearly there (an extrapolation)'
                  if cal.thermal is not None and cal.thermal.extrapolation == 'linear'
                  else 'expect larger errors')
        self._temp_problem = (f'temperature {temp:.1f} degC is outside the calibrated range '
                              f'{low:.1f} .. {high:.1f} degC: {beyond}')
        self.get_logger().warning(self._temp_problem, throttle_duration_sec=WARN_PERIOD_S)

    # -- level trim ------------------------------------------------------------------------
    def on_level(self, request, response):
        """
        Measure the level trim from the last samples, save it, then apply it.

        Copy-on-write: a copy of the calibration in use gets the trim and is saved through
        the session floor (``session.persist.save``, atomically); only once the file is
        written does the node apply it. A refused or failed save changes nothing.

        :param request: std_srvs/Trigger request (empty).
        :param response: std_srvs/Trigger response.
        :return: the response: the roll and pitch stored and how the level frame's
            transform is made known, or the reason for refusal.
        """
        from ..core.level import level_trim
        cal = self.corrector.cal
        try:
            if cal is None:
                raise CalibrationError('no calibration loaded: calibrate the accelerometer '
                                       'first (the trim is stored in its file)')
            rows = list(self._recent.copy())      # copy(): atomic against the stream
            if not rows:
                raise CalibrationError('no imu/data_raw received yet')
            data = np.array(rows, float)
            n = int(round(self.params['level_duration_s'] * (self._rate_hz or 100.0)))
            data = data[-max(n, 1):]
            levelled = without_level(cal)
            plain = Corrector(levelled)
            corrected = np.array([plain.correct(x, y, z, t) for x, y, z, t in data])
            trim = level_trim(corrected, cal.gravity)
            levelled.level_roll_pitch_rad = (trim['roll_rad'], trim['pitch_rad'])
            self._save(levelled)
        except (CalibrationError, InputError, OSError) as err:
            response.success = False
            response.message = f'refused: {err}' if isinstance(err, CalibrationError) else \
                f'refused: the trim was not saved ({err}); the calibration in force is unchanged'
            self.get_logger().warning(response.message)
            return response
        self._key = file_key(self.path)
        self._use(Corrector(levelled), 'levelled')
        response.success = True
        response.message = (f'level trim stored in {self.path}: roll '
                            f'{math.degrees(trim["roll_rad"]):.3f} deg, pitch '
                            f'{math.degrees(trim["pitch_rad"]):.3f} deg from '
                            f'{trim["samples"]} samples; level frame: '
                            f'{self.level_frame.words()}')
        self.get_logger().info(response.message)
        return response

    def _save(self, cal):
        """Write ``cal`` to the calibration file through the session floor (atomically)."""
        from ..session.accept import Outcome
        from ..session.persist import save
        save(Outcome(calibration=cal), self.path, carry=())

    # -- diagnostics -----------------------------------------------------------------------
    def publish_diagnostics(self):
        """Publish the calibration state on /diagnostics (REP-107)."""
        self.diag_pub.publish(self.diagnostics())

    def diagnostics(self):
        """Return the calibration state (and the field monitor's) as a DiagnosticArray."""
        cal = self.corrector.cal
        now = self.get_clock().now().nanoseconds * 1e-9
        then, count = self._rate_mark
        if then is not None and now > then and self._samples > count:
            self._rate_hz = (self._samples - count) / (now - then)
        self._rate_mark = (now, self._samples)
        status = DiagnosticStatus(level=DiagnosticStatus.OK,
                                  name=status_name(self, 'calibration'),
                                  hardware_id=hardware_id(self.sensor))
        if cal is None:
            status.level = DiagnosticStatus.WARN
            status.message = ('uncalibrated: passing the raw acceleration through with '
                              f'covariance ({UNCALIBRATED_STD} m/s2)^2 per axis')
        else:
            status.message = (f'{cal.method} calibration applied; gyro: '
                              f'{self.corrector.gyro_words()}; magnetometer: '
                              f'{self.magnetometer_state()}')
        problems = [p for p in (self._file_problem, self._temp_problem) if p]
        if self._file_problem and cal is not None:
            problems[0] += ': keeping the last good calibration'
        level = self._file_level if self._file_problem else DiagnosticStatus.WARN
        if self._frames[0] and self._frames[0] != self.params['frame_id']:
            problems.append(f'imu/data_raw is in frame {self._frames[0]}, parameter frame_id '
                            f'is {self.params["frame_id"]}')
        frame = self.level_frame.words()
        if frame and not self.level_frame.publishes:
            problems.append(frame)
        lag = self.corrector.lag
        if lag is not None and self._lag_restart is not None and lag.time is not None \
                and lag.time - self._lag_restart < 3.0 * lag.tau_s:
            problems.append(f'imu/temperature paused for more than {lag.gap_s:g} s: the '
                            'heating/cooling term restarted from zero (it rebuilds over '
                            f'about {3.0 * lag.tau_s:.0f} s)')
        if problems:
            status.level = max(status.level, level, DiagnosticStatus.WARN)
            status.message += '; ' + '; '.join(problems)
        values = {'sensor_id': self.sensor, 'calibration_file': self.path,
                  'file_sensor_id': 'none' if cal is None else cal.sensor_id or 'unknown',
                  'samples': self._samples,
                  'dropped_non_finite': self._dropped,
                  'rate_hz': 'unknown' if self._rate_hz is None else round(self._rate_hz, 1),
                  'temperature_c': self.temperature if math.isfinite(self.temperature)
                  else 'unknown'}
        if cal is not None:
            values.update({'created': cal.created,
                           'predicted_accuracy_m_s2': cal.predicted_accuracy,
                           'temperature_range_c': cal.temperature_range_c,
                           'gyro_bias': cal.gyro_bias is not None,
                           'gyro_correction': self.corrector.gyro_words(),
                           'gyro_predicted_accuracy': cal.gyro_predicted_accuracy,
                           'magnetometer_predicted_accuracy_uT': None
                           if cal.magnetometer is None
                           else cal.magnetometer.predicted_accuracy,
                           'level_trim': cal.level_roll_pitch_rad is not None,
                           'hysteresis': 'none' if lag is None else
                           f'{cal.hysteresis.effect}, tau {lag.tau_s:.0f} s, gradient '
                           f'{lag.gradient:+.3f} degC',
                           'hysteresis_restarts': 0 if lag is None else lag.restarts,
                           'level_frame': frame or 'none (no trim)'})
        values.update({'magnetometer': self.magnetometer_state(),
                       'mag_samples': self._mag_samples,
                       'mag_corrected_published': self._mag_published})
        status.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        monitor = self.monitor.statuses()
        for part in monitor:        # the monitor's parts: under this node's names and id
            part.name = status_name(self, part.name.split(': ', 1)[-1])
            part.hardware_id = status.hardware_id
        array = DiagnosticArray(status=[status] + monitor)
        array.header.stamp = self.get_clock().now().to_msg()
        return array


def main(args=None):
    """Run the node until SIGINT or SIGTERM; exit status 2 on a bad parameter."""
    run(CorrectionNode, 'accel_correction', args)


if __name__ == '__main__':
    main()
