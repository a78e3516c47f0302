"""
The correction node's field monitor: ROS plumbing around ``core.monitor``.

The node appends each corrected sample to a list (the rate before the monitor's bias is
removed) and calls :meth:`NodeMonitor.flush` every ``block_n`` samples (``BLOCK_S`` of
stamps at the rate the stamps show): one
:class:`~accel_calib_ros.core.monitor.Block` goes to the
:class:`~accel_calib_ros.core.monitor.FieldMonitor` and :attr:`NodeMonitor.bias` (the
residual gyro bias the node subtracts) is refreshed. Here also:

- the parameters (:data:`PARAMS`, typed and ranged; a runtime change is applied to the
  monitor in place, keeping its state);
- ``~/health`` (std_msgs/String, one JSON object, latched: transient local, depth 1):
  the latest check, the same object ``accel-calib health --json`` gives per check, plus
  the gyro-bias state. A JSON string rather than a DiagnosticStatus: it carries the
  numbers as numbers (the bias shift vector, χ², the temperature range) for a script
  or a fleet tool to read, where /diagnostics carries the same in words for rqt;
- ``~/reset_gyro_bias`` (std_srvs/Trigger): back to the file's bias;
- the optional stationary input: ``stationary_topic`` of ``stationary_type``
  (std_msgs/Bool: true = stationary; geometry_msgs/TwistStamped, geometry_msgs/Twist or
  nav_msgs/Odometry: stationary when every linear component is below
  ``stationary_linear_m_s`` and every angular one below ``stationary_angular_rad_s``);
- ``gyro_bias_estimate_rad_s``: a read-only parameter the node keeps equal to the
  estimate (updated with each /diagnostics tick);
- two /diagnostics statuses: "gyro bias at rest" and "calibration health".

Thread safety: the Imu path runs on its own thread; the monitor is touched there (flush)
and from the control thread (reset, parameters, a new calibration) under one lock, taken
once per block on the Imu path.
"""

import json
import math
import threading
import time

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
import numpy as np
from rcl_interfaces.msg import ParameterDescriptor, ParameterType
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import String
from std_srvs.srv import Trigger

from .common import Param, ParameterProblem
from ..core.monitor import Block, FieldMonitor, MonitorSettings

STATIONARY_TYPES = ('std_msgs/Bool', 'geometry_msgs/TwistStamped', 'geometry_msgs/Twist',
                    'nav_msgs/Odometry')
"""Message types the stationary input may have."""
ESTIMATE_PARAM = 'gyro_bias_estimate_rad_s'
"""The read-only parameter that reports the gyro-bias estimate."""

PARAMS = [
    Param('gyro_bias_at_rest', True,
          're-estimate the gyro bias in still periods and subtract it (false: the bias of '
          'the file only)'),
    Param('gyro_bias_min_still_s', 1.0, 'still time before a period updates the gyro bias, s',
          low=0.2, high=60.0),
    Param('gyro_bias_limit_deg_s', 5.0,
          'largest gyro bias change from the file accepted per axis, deg/s', low=0.01,
          high=30.0),
    Param('gyro_bias_vertical_limit_deg_s', 1.0,
          'without a magnetometer or stationary signal: largest change along gravity, deg/s '
          '(a turn in place slower than this is taken for a bias)', low=0.0, high=30.0),
    Param('health_check', True,
          'check the calibration against gravity and its temperature range at rest'),
    Param('health_min_still_s', 2.0, 'shortest still period the health check uses, s',
          low=0.5, high=600.0),
    Param('health_false_alarm', 1e-4,
          'chance that one health check fails on a calibration that is fine', low=1e-9,
          high=0.1),
    Param('health_allowance_mg', 1.0,
          'bias change per axis not worth a recalibration (power-up to power-up), mg',
          low=0.0, high=100.0),
    Param('health_memory_s', 3600.0, 'an orientation not seen for this long is forgotten, s',
          low=10.0, high=1e7),
    Param('still_threshold_factor', 3.0,
          'still when the block standard deviation is below this x the noise floor',
          low=1.5, high=20.0),
    Param('still_max_rotation_deg_s', 5.0, 'largest rate of a still block, deg/s', low=0.1,
          high=90.0),
    Param('stationary_topic', '',
          "optional topic saying whether the robot is stationary ('' = none)"),
    Param('stationary_type', 'std_msgs/Bool', 'message type of stationary_topic',
          choices=STATIONARY_TYPES),
    Param('stationary_timeout_s', 0.5,
          'a stationary message older than this counts as unknown, s', low=0.05, high=60.0),
    Param('stationary_linear_m_s', 0.01,
          'a twist below this on every linear axis is stationary, m/s', low=0.0, high=10.0),
    Param('stationary_angular_rad_s', 0.005,
          'a twist below this on every angular axis is stationary, rad/s', low=0.0,
          high=10.0),
]
"""The monitor's parameters (the node adds them to its own)."""

BLOCK_S = 0.1
"""Time each block summarises, s."""


def settings_from(params):
    """Return the :class:`MonitorSettings` the node's parameters say."""
    return MonitorSettings(
        block_s=BLOCK_S, threshold_factor=params['still_threshold_factor'],
        max_rotation_deg_s=params['still_max_rotation_deg_s'],
        stationary_timeout_s=params['stationary_timeout_s'],
        gyro_bias_enabled=params['gyro_bias_at_rest'],
        gyro_min_still_s=params['gyro_bias_min_still_s'],
        gyro_bias_limit_deg_s=params['gyro_bias_limit_deg_s'],
        gyro_vertical_limit_deg_s=params['gyro_bias_vertical_limit_deg_s'],
        health_enabled=params['health_check'],
        health_min_still_s=params['health_min_still_s'],
        health_false_alarm=params['health_false_alarm'],
        health_allowance_mg=params['health_allowance_mg'],
        health_memory_s=params['health_memory_s'],
        temperature_margin_c=params['temperature_margin_c'])


def _stamp(stamp):
    return stamp.sec + stamp.nanosec * 1e-9


class NodeMonitor:
    """
    The field monitor of one correction node (see the module docstring).

    :param node: the correction node (its ``params`` hold :data:`PARAMS`).
    """

    def __init__(self, node):
        self.node = node
        self.lock = threading.Lock()
        self.monitor = None             # FieldMonitor of the calibration in use, or None
        self.active = False             # the Imu path feeds it (a monitor, a part on)
        self.buf = []                   # (ax, ay, az, gx, gy, gz, temp) since the last block
        self.mag = []                   # corrected field samples (µT) since the last block
        self.block_n = 10               # samples per block (follows the stamps: BLOCK_S)
        self.bias = (0.0, 0.0, 0.0)     # residual gyro bias to subtract, rad/s
        self._t_last = None             # stream time of the end of the last block, s
        self._clock0 = None             # (stamp, monotonic) when stamps do not advance
        self._problem = ''              # a failure of the monitor, said in /diagnostics
        self._published = None          # the HealthResult last sent on ~/health
        self._stationary_sub = None
        self._stationary_words = 'none (stationary_topic empty)'
        qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.health_pub = node.create_publisher(String, '~/health', qos)
        node.create_service(Trigger, '~/reset_gyro_bias', self.on_reset)
        node.declare_parameter(ESTIMATE_PARAM, [0.0, 0.0, 0.0], ParameterDescriptor(
            name=ESTIMATE_PARAM, type=ParameterType.PARAMETER_DOUBLE_ARRAY, read_only=True,
            description='the gyro bias change the node subtracts now (estimated at rest), '
                        'rad/s, x y z of the corrected frame; reset with ~/reset_gyro_bias; '
                        'reported by the node: a value given at start-up is ignored'),
            ignore_override=True)
        self._subscribe_stationary()

    # -- the calibration and the parameters ----------------------------------------------
    def use(self, cal):
        """Start afresh for calibration ``cal`` (None: no monitor)."""
        with self.lock:
            self.buf, self.mag = [], []
            self._t_last = None
            self._problem = ''
            self.monitor = None if cal is None else FieldMonitor(cal, settings_from(
                self.node.params))
            self.bias = (0.0, 0.0, 0.0)
            self._refresh()
        self.publish_health(force=True)

    def apply(self, changes):
        """Apply a runtime change of the monitor's parameters (keeps the state)."""
        if {'stationary_topic', 'stationary_type'} & set(changes):
            self._subscribe_stationary()
        with self.lock:
            if self.monitor is not None:
                self.monitor.apply_settings(settings_from(self.node.params))
                self.bias = tuple(float(v) for v in self.monitor.gyro_bias)
            self._refresh()

    def _refresh(self):
        """Say whether the Imu path feeds the monitor (under the lock)."""
        params = self.node.params
        self.active = self.monitor is not None and (params['gyro_bias_at_rest']
                                                    or params['health_check'])
        if not self.active:
            self.buf, self.mag = [], []
            self._t_last = None

    # -- the stream ----------------------------------------------------------------------
    def flush(self, stamp):
        """Hand the samples gathered so far to the monitor as one block (Imu thread)."""
        rows, self.buf = self.buf, []
        mag, self.mag = self.mag, []
        t_end = self._time(stamp)
        t_start, self._t_last = self._t_last, t_end
        if t_start is None or len(rows) < 2:
            return
        if t_end > t_start:         # the next block spans BLOCK_S at this rate
            self.block_n = min(max(int(round(len(rows) * BLOCK_S / (t_end - t_start))), 2),
                               10000)
        try:
            data = np.array(rows, float)
            temp = data[:, 6]
            known = temp[np.isfinite(temp)]
            m = np.array(mag, float).reshape(-1, 3) if mag else None
            block = Block(len(data), 0.5 * (t_start + t_end), t_end - t_start,
                          data[:, :3].mean(axis=0), data[:, :3].var(axis=0),
                          data[:, 3:6].mean(axis=0), data[:, 3:6].var(axis=0),
                          float(known.mean()) if len(known) else float('nan'),
                          0 if m is None else len(m), None if m is None else m.mean(axis=0),
                          None if m is None else m.var(axis=0))
            with self.lock:
                mon = self.monitor
                if mon is None:
                    return
                mon.add_block(block)
                bias = mon.gyro_bias
                if np.all(np.isfinite(bias)):
                    self.bias = (float(bias[0]), float(bias[1]), float(bias[2]))
            self._problem = ''
        except Exception as err:      # noqa: B902 - the node never dies of the monitor:
            # keep the last estimate (and the published stream) and say so.
            if not self._problem:
                self.node.get_logger().error(f'field monitor: {err}; keeping the last gyro '
                                             'bias estimate')
            self._problem = f'field monitor failed on a block: {err}'

    def _time(self, stamp):
        """Return the stream time of a message, s: its stamp, or the clock if stamps stall."""
        t = _stamp(stamp)
        if self._t_last is None or t > self._t_last:
            self._clock0 = None
            return t
        now = time.monotonic()
        if self._clock0 is None:
            self._clock0 = (self._t_last, now)
        return self._clock0[0] + (now - self._clock0[1])

    # -- the stationary input ------------------------------------------------------------
    def _subscribe_stationary(self):
        node = self.node
        if self._stationary_sub is not None:
            node.destroy_subscription(self._stationary_sub)
            self._stationary_sub = None
        topic, kind = node.params['stationary_topic'], node.params['stationary_type']
        if not topic:
            self._stationary_words = 'none (stationary_topic empty)'
            return
        if kind == 'std_msgs/Bool':
            from std_msgs.msg import Bool as msg_type
        elif kind == 'geometry_msgs/TwistStamped':
            from geometry_msgs.msg import TwistStamped as msg_type
        elif kind == 'geometry_msgs/Twist':
            from geometry_msgs.msg import Twist as msg_type
        else:
            from nav_msgs.msg import Odometry as msg_type
        self._stationary_sub = node.create_subscription(msg_type, topic, self.on_stationary,
                                                        10)
        self._stationary_words = f'{topic} ({kind}): nothing received yet'

    def on_stationary(self, msg):
        """Take one stationary message (control thread)."""
        if hasattr(msg, 'data'):
            value = bool(msg.data)
        else:
            twist = msg.twist.twist if hasattr(msg, 'pose') else \
                msg.twist if hasattr(msg, 'twist') else msg
            lin, ang = twist.linear, twist.angular
            lo, ao = self.node.params['stationary_linear_m_s'], \
                self.node.params['stationary_angular_rad_s']
            values = (lin.x, lin.y, lin.z, ang.x, ang.y, ang.z)
            if not all(math.isfinite(v) for v in values):
                self._stationary_words = 'a non-finite twist arrived: ignored'
                return
            value = max(abs(lin.x), abs(lin.y), abs(lin.z)) <= lo and \
                max(abs(ang.x), abs(ang.y), abs(ang.z)) <= ao
        t = self._t_last
        with self.lock:
            if self.monitor is not None and t is not None:
                self.monitor.set_stationary(t, value)
        self._stationary_words = (f'{self.node.params["stationary_topic"]}: '
                                  f'{"stationary" if value else "moving"}')

    # -- the reset service, the reports --------------------------------------------------
    def on_reset(self, request, response):
        """Reset the gyro-bias estimate to the file's bias (std_srvs/Trigger)."""
        with self.lock:
            mon = self.monitor
            if mon is None:
                response.success = False
                response.message = 'refused: no calibration loaded (nothing to reset)'
                return response
            before = np.degrees(mon.gyro_bias)
            mon.reset_gyro_bias()
            self.bias = (0.0, 0.0, 0.0)
        response.success = True
        response.message = ("gyro bias estimate reset to the calibration file's (it was "
                            + ', '.join(f'{v:+.4f}' for v in before) + ' deg/s)')
        self.node.get_logger().info(response.message)
        self.update_parameter()
        return response

    def update_parameter(self):
        """Keep the read-only parameter equal to the estimate (control thread)."""
        value = [float(v) for v in self.bias]
        try:
            old = self.node.get_parameter(ESTIMATE_PARAM).value
            if list(old) == value:
                return
            descriptor = self.node.describe_parameter(ESTIMATE_PARAM)
            # The node's own write of its read-only report: rclpy's internal setter with
            # the descriptor given (as declare_parameter does) skips the read-only check.
            self.node._set_parameters_atomically_common(
                [Parameter(ESTIMATE_PARAM, Parameter.Type.DOUBLE_ARRAY, value)],
                {ESTIMATE_PARAM: descriptor})
        except (AttributeError, TypeError, ParameterProblem) as err:   # another rclpy
            self._problem = f'cannot update {ESTIMATE_PARAM}: {err}'

    def publish_health(self, force=False):
        """Publish ``~/health`` when the check changed (or ``force``): one JSON object."""
        with self.lock:
            mon = self.monitor
            result = None if mon is None else mon.health.result
            gyro = None if mon is None else mon.gyro_summary()
        if result is self._published and not force:
            return
        self._published = result
        try:
            text = self._health_json(result, gyro)
        except (ValueError, TypeError) as err:     # never a non-finite number on a topic
            self._problem = f'~/health not published: {err}'
            return
        self.health_pub.publish(String(data=text))

    def _health_json(self, result, gyro):
        body = {'node': self.node.get_fully_qualified_name(),
                'calibration_file': self.node.path}
        if result is None:
            body.update({'level': 'unknown', 'healthy': None, 'recalibrate': False,
                         'message': 'no calibration loaded: nothing to check'})
        else:
            body.update(result.to_dict())
            body['gyro_bias_at_rest'] = gyro
        return json.dumps(body, allow_nan=False)

    def statuses(self):
        """Return the two DiagnosticStatus of the monitor (gyro bias, health)."""
        name = self.node.get_name()
        gyro = DiagnosticStatus(level=DiagnosticStatus.OK, name=f'{name}: gyro bias at rest')
        health = DiagnosticStatus(level=DiagnosticStatus.OK,
                                  name=f'{name}: calibration health')
        with self.lock:
            mon = self.monitor
            summary = None if mon is None else mon.gyro_summary()
            result = None if mon is None else mon.health.result
            still = None if mon is None else {
                'still_periods': mon.periods, 'still_time_s': round(mon.still_time_s, 1),
                'moving_because': mon.motion or 'still'}
        if mon is None:
            gyro.message = health.message = 'no calibration loaded: not monitoring'
            return [gyro, health]
        est = summary['estimate_deg_s']
        if not summary['enabled']:
            gyro.message = "off (gyro_bias_at_rest false): the file's bias only"
        else:
            gyro.message = (f'{summary["state"]}; change from the file ('
                            + ', '.join(f'{v:+.4f}' for v in est) + ') deg/s; along gravity: '
                            + summary['along_gravity'])
            limit = self.node.params['gyro_bias_limit_deg_s']
            if max(abs(v) for v in est) >= 0.999 * limit:
                gyro.level = DiagnosticStatus.WARN
                gyro.message += f'; at its limit of {limit:g} deg/s: recalibrate the gyro'
        if self._problem:
            gyro.level = DiagnosticStatus.WARN
            gyro.message += f'; {self._problem}'
        values = dict(summary, **still, stationary_input=self._stationary_words)
        gyro.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        if not self.node.params['health_check']:
            health.message = 'off (health_check false)'
        else:
            health.message = result.message
            if result.level == 'warn':
                health.level = DiagnosticStatus.WARN
        health.values = [KeyValue(key=k, value=str(v)) for k, v in result.to_dict().items()]
        return [gyro, health]
