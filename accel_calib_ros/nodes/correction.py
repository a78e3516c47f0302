"""
ROS 2 node ``accel_correction``: apply the saved calibration to the live IMU stream.

``imu/data_raw``, ``imu/temperature``, ``imu/mag`` in; ``imu/corrected`` and
``imu/mag_corrected`` out, compensated for the current temperature, levelled when a trim
is stored (then in ``level_frame_id``), with the field monitor's gyro bias at rest and
calibration health (:mod:`.correction_monitor`). The math is
:class:`core.correction.Corrector`; this module is the shell: parameters, messages,
hot reload, ``/diagnostics``. Behaviour in full: docs/correction_node.md.
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

from .common import (calibration_path, declare_parameters, hardware_id, Param, ParameterProblem,
                     run, Throttled)
from .correction_monitor import NodeMonitor, PARAMS as MONITOR_PARAMS
from ..core.constants import TESLA_PER_UT
from ..core.correction import (Corrector, UNCALIBRATED_COVARIANCE,  # noqa: F401 - re-exported
                               UNCALIBRATED_GYRO_BIAS_STD, UNCALIBRATED_STD, without_level)
from ..core.errors import CalibrationError, InputError
from ..dataio.calibration_file import load_calibration, save_calibration

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


def check_frame_id(value, name='level_frame_id'):
    """Refuse a frame_id tf2 would not take (a leading '/', blanks); '' is the default."""
    if value and (value.startswith('/') or any(c.isspace() for c in value)
                  or not value.isprintable()):
        raise ParameterProblem(f'parameter {name!r} must be a tf2 frame id (no leading '
                               f"'/', no blanks), got {value!r}")


PARAMS = [
    Param('calibration_file', '',
          "calibration YAML to apply ('' = $ROS_HOME/accel_calib_ros/calibration.yaml); "
          're-read whenever it changes'),
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
        self.params = declare_parameters(self, PARAMS, self._on_params)
        check_frame_id(self.params['level_frame_id'])
        self.path = calibration_path(self.params['calibration_file'])
        self.corrector = Corrector(None)
        self.temperature = float('nan')
        self._key = ()              # file key last acted on (loaded or rejected); () = never
        self._file_problem = ''     # why the file on disk is not the one in use
        self._warned_missing = False
        self._warned_no_temp = False
        self._samples = 0
        self._mag_samples = 0       # imu/mag messages received
        self._mag_published = 0
        self._dropped = 0           # messages not published: a non-finite field
        self._warn = Throttled(self.get_logger(), WARN_PERIOD_S)
        self._temp_problem = ''
        self._rate_hz = None        # messages per second, measured at each diagnostics tick
        self._rate_mark = (None, 0)
        self._recent = deque(maxlen=LEVEL_BUFFER)   # (t, ax, ay, az, temp) for ~/level
        self._frames = ('', '')     # (raw frame_id, the one published) last seen
        self.monitor = NodeMonitor(self)
        self.check_file(initial=True)

        pub_qos = QoSProfile(depth=QUEUE_DEPTH, history=HistoryPolicy.KEEP_LAST,
                             reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.VOLATILE)
        sub_qos = QoSProfile(depth=QUEUE_DEPTH, history=qos_profile_sensor_data.history,
                             reliability=qos_profile_sensor_data.reliability,
                             durability=qos_profile_sensor_data.durability)
        # One node per process (a remap names exactly one node): the Imu path has a
        # callback group of its own, which run() spins on an executor of its own (nothing
        # else to wait on: no more executor work per message than a bare relay), the
        # rest of the node on another thread (nodes/common.run).
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

    def _on_params(self, changes):
        """Apply a runtime parameter change (called by the common mechanism)."""
        if 'calibration_file' in changes:
            self.path = calibration_path(changes['calibration_file'])
            self._key = ()
            self._warned_missing = False
            self.check_file()
        if 'reload_period_s' in changes:
            self.destroy_timer(self._reload_timer)
            self._reload_timer = self.create_timer(changes['reload_period_s'], self._tick)
        if 'level_frame_id' in changes:
            check_frame_id(changes['level_frame_id'])
            self._frames = ('', '')
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
        if h.frame_id != self._frames[0]:       # the sensor's frame: also its hardware_id
            self._frames = (h.frame_id, self.level_frame(h.frame_id))
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
            h.frame_id = frames[1] if h.frame_id == frames[0] else self.level_frame(h.frame_id)
        self._mag_published += 1
        self.mag_pub.publish(msg)

    def level_frame(self, raw):
        """Return the frame_id of the levelled output for a raw ``frame_id``."""
        return self.params['level_frame_id'] or f'{raw or "imu_link"}_level'

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

        :param initial: first check at start-up (logs the outcome either way).
        """
        self._check_temperature()
        key = file_key(self.path)
        if key == self._key:
            return
        self._key = key
        log = self.get_logger()
        if key is None:
            if self.corrector.cal is None:
                self._file_problem = f'no calibration file {self.path}'
                if not self._warned_missing:
                    log.warning(f'no calibration file {self.path}: passing the raw '
                                'acceleration through, covariance '
                                f'({UNCALIBRATED_STD} m/s2)^2 per axis, until one appears')
                    self._warned_missing = True
            else:
                self._file_problem = f'calibration file {self.path} disappeared'
                log.warning(f'calibration file {self.path} disappeared: keeping the '
                            'calibration loaded before')
            return
        try:
            cal = load_calibration(self.path)
            corrector = Corrector(cal)
        except (InputError, np.linalg.LinAlgError, ValueError) as err:
            self._file_problem = f'bad calibration file: {err}'
            log.error(f'ignoring calibration file {self.path}: {err}; '
                      + ('keeping the previous calibration' if self.corrector.cal is not None
                         else 'still passing the raw acceleration through'))
            return
        self._use(corrector, 'loaded' if initial else 'reloaded')

    def _use(self, corrector, verb):
        self.corrector = corrector
        self._file_problem = ''
        cal = corrector.cal
        self.monitor.use(cal)       # a new calibration: the field monitor starts afresh
        std = np.sqrt(np.diag(cal.acceleration_covariance()))
        acc = cal.predicted_accuracy
        self.get_logger().info(
            f'{verb} {cal.method} calibration {self.path} (created {cal.created}, scale '
            f'{np.round(cal.scale, 5).tolist()}, bias {np.round(cal.bias, 4).tolist()} '
            f'm/s2, thermal bands {0 if cal.thermal is None else len(cal.thermal.usable)}, '
            f'per-axis std {np.round(std, 4).tolist()} m/s2'
            + (f', predicted accuracy {acc:.4f} m/s2' if acc is not None else '')
            + (', gyro bias' if cal.gyro_bias is not None else '')
            + (', gyro scale and misalignment' if cal.gyro_T is not None else '')
            + (', magnetometer' if cal.magnetometer is not None else '')
            + (', level trim' if cal.level_roll_pitch_rad is not None else '') + ')')
        self._check_range()

    def _check_temperature(self):
        cal = self.corrector.cal
        if self._warned_no_temp or self._samples < 200 or cal is None \
                or cal.thermal is None or not cal.thermal.usable \
                or math.isfinite(self.temperature):
            return
        self._warned_no_temp = True
        self.get_logger().warning(
            'the calibration has temperature tables but no imu/temperature arrived: '
            'correcting without the temperature drift')

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
        self._temp_problem = (f'temperature {temp:.1f} degC is outside the calibrated range '
                              f'{low:.1f} .. {high:.1f} degC: expect larger errors')
        self._warn('temperature', 'warning', self._temp_problem)

    # -- level trim ------------------------------------------------------------------------
    def on_level(self, request, response):
        """
        Measure the level trim from the last samples and store it in the calibration file.

        :param request: std_srvs/Trigger request (empty).
        :param response: std_srvs/Trigger response.
        :return: the response: the roll and pitch stored, or the reason for refusal.
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
            plain = Corrector(without_level(cal))
            corrected = np.array([plain.correct(x, y, z, t) for x, y, z, t in data])
            trim = level_trim(corrected, cal.gravity)
            cal.level_roll_pitch_rad = (trim['roll_rad'], trim['pitch_rad'])
            save_calibration(cal, self.path)
        except (CalibrationError, InputError, OSError) as err:
            response.success = False
            response.message = f'refused: {err}'
            self.get_logger().warning(response.message)
            self.check_file()
            return response
        self._key = file_key(self.path)
        self._use(Corrector(cal), 'levelled')
        response.success = True
        response.message = (f'level trim stored in {self.path}: roll '
                            f'{math.degrees(trim["roll_rad"]):.3f} deg, pitch '
                            f'{math.degrees(trim["pitch_rad"]):.3f} deg from '
                            f'{trim["samples"]} samples')
        self.get_logger().info(response.message)
        return response

    # -- diagnostics -----------------------------------------------------------------------
    def publish_diagnostics(self):
        """Publish the calibration state on /diagnostics (REP-107)."""
        cal = self.corrector.cal
        now = self.get_clock().now().nanoseconds * 1e-9
        then, count = self._rate_mark
        if then is not None and now > then and self._samples > count:
            self._rate_hz = (self._samples - count) / (now - then)
        self._rate_mark = (now, self._samples)
        status = DiagnosticStatus(level=DiagnosticStatus.OK,
                                  name=f'{self.get_name()}: calibration',
                                  hardware_id=hardware_id(self._frames[0]))
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
        if problems:
            status.level = DiagnosticStatus.WARN
            status.message += '; ' + '; '.join(problems)
        values = {'calibration_file': self.path, 'samples': self._samples,
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
                           'level_trim': cal.level_roll_pitch_rad is not None})
        values.update({'magnetometer': self.magnetometer_state(),
                       'mag_samples': self._mag_samples,
                       'mag_corrected_published': self._mag_published})
        status.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        monitor = self.monitor.statuses()
        for part in monitor:
            part.hardware_id = status.hardware_id
        array = DiagnosticArray(status=[status] + monitor)
        array.header.stamp = self.get_clock().now().to_msg()
        self.diag_pub.publish(array)


def main(args=None):
    """Run the node until Ctrl-C; exit status 2 on a bad parameter."""
    run(CorrectionNode, 'accel_correction', args)


if __name__ == '__main__':
    main()
