"""
The correction node's field monitor: ROS plumbing around ``core.monitor``.

The node appends each corrected sample with its stamp (the rate before the monitor's
bias is removed) to a list and calls :meth:`NodeMonitor.flush` every ``block_n``
samples (about a block's worth): the rows go to
:meth:`~accel_calib_ros.core.monitor.FieldMonitor.feed`, which cuts them into blocks on
the stamps exactly as ``accel-calib health`` cuts a recording (one way, in the core: a
gap or a step of the sample clock either way restarts the time-ordered state), and
:attr:`NodeMonitor.bias` (the residual gyro bias the node subtracts) is refreshed. Here
also:

- the parameters (:data:`PARAMS`, typed and ranged; a runtime change is applied to the
  monitor in place, keeping its state);
- the sensor's history: ``history.sqlite`` beside the calibration file, read once per
  calibration (its calibrations of the file's ``sensor_id``: the session-to-session
  scatter becomes the health check's allowance);
- ``~/health`` (std_msgs/String, one JSON object, latched: transient local, depth 1):
  the latest check, the same object ``accel-calib health --json`` gives per check, plus
  the gyro-bias state, the sensor fault and the time without a still period. A JSON
  string rather than a DiagnosticStatus: it carries the numbers as numbers for a script
  or a fleet tool to read, where /diagnostics carries the same in words for rqt;
- ``~/reset_gyro_bias`` (std_srvs/Trigger): back to the file's bias;
- the optional stationary input: ``stationary_topic`` of ``stationary_type``
  (std_msgs/Bool: true = stationary; geometry_msgs/TwistStamped, geometry_msgs/Twist or
  nav_msgs/Odometry: stationary when every linear component is below
  ``stationary_linear_m_s`` and every angular one below ``stationary_angular_rad_s``);
- ``gyro_bias_estimate_rad_s``: a parameter the node keeps equal to the estimate
  (updated with each /diagnostics tick, through rclpy's public ``set_parameters``; any
  other change is refused: it is a report);
- two /diagnostics statuses: "gyro bias at rest" and "calibration health": ERROR while
  the sensor is frozen, WARN when no still period came for ``still_timeout_s``, when the
  temperature is outside the calibrated range, when the calibration should be redone.

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
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import String
from std_srvs.srv import Trigger

from .parameters import Param, ReportParameter
from ..core.monitor import FieldMonitor, MonitorSettings

STATIONARY_TYPES = ('std_msgs/Bool', 'geometry_msgs/TwistStamped', 'geometry_msgs/Twist',
                    'nav_msgs/Odometry')
"""Message types the stationary input may have."""
ESTIMATE_PARAM = 'gyro_bias_estimate_rad_s'
"""The read-only parameter that reports the gyro-bias estimate."""

PARAMS = [
    Param('gyro_bias_at_rest', True,
          're-estimate the gyro bias in still periods and subtract it (false: the bias of '
          'the file only); across gravity always, along gravity as far as '
          'gyro_bias_vertical_limit_deg_s, a magnetometer or a stationary signal allow'),
    Param('gyro_bias_min_still_s', 1.0, 'still time before a period updates the gyro bias, s',
          low=0.2, high=60.0),
    Param('gyro_bias_limit_deg_s', 30.0,
          'largest gyro bias change from the file accepted per axis, deg/s (MPU-9250: its '
          'zero-rate output moves +-30 deg/s over temperature)', low=0.01, high=60.0),
    Param('gyro_bias_vertical_limit_deg_s', 0.2,
          'without a magnetometer or stationary signal: largest rate about gravity at rest '
          'taken for a bias, deg/s (a turn in place slower than this is absorbed; a faster '
          'one is not absorbed at all)', low=0.0, high=30.0),
    Param('gyro_bias_stationary_limit_deg_s', 1.0,
          'the same while the stationary signal says stationary, deg/s (a turntable turning '
          'faster is not absorbed)', low=0.0, high=30.0),
    Param('gyro_bias_powerup_limit_deg_s', 1.0,
          'the same in the first still period after a start or ~/reset_gyro_bias, unless a '
          'turn set off from rest: the power-up change of the zero-rate output, deg/s',
          low=0.0, high=30.0),
    Param('health_check', True,
          'check the calibration against gravity and its temperature range at rest'),
    Param('health_min_still_s', 2.0, 'shortest still period the health check uses, s',
          low=0.5, high=600.0),
    Param('health_false_alarm', 1e-4,
          'chance that one health check says recalibrate on a calibration that is fine',
          low=1e-9, high=0.1),
    Param('health_allowance_mg', 1.0,
          'bias change per axis between sessions not worth a recalibration, mg, when the '
          "sensor's history (history.sqlite beside the file) has fewer than 3 calibrations",
          low=0.0, high=100.0),
    Param('health_memory_s', 3600.0, 'an orientation not seen for this long is forgotten, s',
          low=10.0, high=1e7),
    Param('still_threshold_factor', 3.0,
          'still when the block standard deviation is below this x the noise floor',
          low=1.5, high=20.0),
    Param('still_max_rotation_deg_s', 5.0,
          "largest rate of a still block, deg/s, from the gyro's zero measured at rest",
          low=0.1, high=90.0),
    Param('still_timeout_s', 300.0,
          'WARN when no still period came for this long, s (the monitor cannot check)',
          low=1.0, high=1e6),
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
"""Time each block summarises (at least; longer below 80 Hz), s."""
HISTORY_NAME = 'history.sqlite'
"""The sensor history read beside the calibration file."""
STAMP_STALL_S = 1.0
"""Imu stamps that have not advanced for this long (wall clock, s) are said in the statuses."""


def settings_from(params):
    """Return the :class:`MonitorSettings` the node's parameters say."""
    return MonitorSettings(
        block_s=BLOCK_S, threshold_factor=params['still_threshold_factor'],
        max_rotation_deg_s=params['still_max_rotation_deg_s'],
        stationary_timeout_s=params['stationary_timeout_s'],
        still_timeout_s=params['still_timeout_s'],
        gyro_bias_enabled=params['gyro_bias_at_rest'],
        gyro_min_still_s=params['gyro_bias_min_still_s'],
        gyro_bias_limit_deg_s=params['gyro_bias_limit_deg_s'],
        gyro_vertical_limit_deg_s=params['gyro_bias_vertical_limit_deg_s'],
        gyro_stationary_limit_deg_s=params['gyro_bias_stationary_limit_deg_s'],
        gyro_powerup_limit_deg_s=params['gyro_bias_powerup_limit_deg_s'],
        health_enabled=params['health_check'],
        health_min_still_s=params['health_min_still_s'],
        health_false_alarm=params['health_false_alarm'],
        health_allowance_mg=params['health_allowance_mg'],
        health_memory_s=params['health_memory_s'],
        temperature_margin_c=params['temperature_margin_c'])


def sensor_history(calibration_path, sensor_id):
    """
    Return the calibrations of ``sensor_id`` in the history beside a calibration file.

    :return: (list of dicts or None, words on what was read).
    """
    import os
    path = os.path.join(os.path.dirname(os.path.abspath(calibration_path)), HISTORY_NAME)
    if not sensor_id:
        return None, 'none (the calibration names no sensor_id)'
    if not os.path.isfile(path):
        return None, f'none (no {path})'
    from ..dataio.history import History
    try:
        with History(path, readonly=True) as db:
            rows = db.calibrations(sensor_id)
    except Exception as err:    # noqa: B902 - a damaged history must not stop the monitor
        return None, f'{path} not read ({str(err)[:120]})'
    return rows, f'{path}: {len(rows)} calibration(s) of {sensor_id}'


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
        self.buf = []                   # (t, ax, ay, az, gx, gy, gz, temp) since the last flush
        self.mag = []                   # corrected field samples (µT) since the last flush
        self.block_n = 10               # samples per flush (about one block at the rate seen)
        self.bias = (0.0, 0.0, 0.0)     # residual gyro bias to subtract, rad/s
        self.history = 'none'           # what was read of the sensor's history
        self._t_last = None             # stamp of the newest sample handed over, s
        self._stalled_since = None      # monotonic time since which the stamps stall
        self._fed = time.monotonic()    # when samples were last handed over (wall clock)
        self._problem = ''              # a failure of the monitor, said in /diagnostics
        self._published = None          # the HealthResult last sent on ~/health
        self._stationary_sub = None
        self._stationary_words = 'none (stationary_topic empty)'
        qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.health_pub = node.create_publisher(String, '~/health', qos)
        node.create_service(Trigger, '~/reset_gyro_bias', self.on_reset)
        self.estimate = ReportParameter(
            node, ESTIMATE_PARAM, [0.0, 0.0, 0.0],
            'the gyro bias change the node subtracts now (estimated at rest), rad/s, x y z '
            'of the corrected frame; reset with ~/reset_gyro_bias')
        self._subscribe_stationary()

    # -- the calibration and the parameters ----------------------------------------------
    def use(self, cal):
        """Start afresh for calibration ``cal`` (None: no monitor)."""
        history, words = (None, 'none') if cal is None else \
            sensor_history(self.node.path, getattr(cal, 'sensor_id', None))
        with self.lock:
            self.buf, self.mag = [], []
            self._t_last = None
            self._problem = ''
            self.history = words
            self.monitor = None if cal is None else FieldMonitor(cal, settings_from(
                self.node.params), history)
            self.bias = (0.0, 0.0, 0.0)
            self._fed = time.monotonic()
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
    def flush(self, stamp=None):
        """
        Hand the samples gathered so far to the monitor (Imu thread).

        :param stamp: unused (each row carries its own stamp); kept for callers.
        """
        rows, self.buf = self.buf, []
        mag, self.mag = self.mag, []
        if not rows:
            return
        try:
            data = np.array(rows, float)
            t = data[:, 0]
            if not self._advancing(t):
                self._fed = time.monotonic()        # the messages come; their stamps do not
                return
            m = mag_t = None
            if mag:
                m = np.array(mag, float).reshape(-1, 3)
                # The field joins the samples it arrived among (its stamps are not kept).
                mag_t = np.linspace(t[0], t[-1], len(m) + 2)[1:-1]
            with self.lock:
                mon = self.monitor
                if mon is None:
                    return
                mon.feed(t, data[:, 1:4], data[:, 4:7], data[:, 7], m, mag_t)
                rate, step = mon.cutter.rate_hz, mon.cutter.step_s
                if rate and step:
                    self.block_n = min(max(int(round(rate * step)), 2), 10000)
                bias = mon.gyro_bias
                if np.all(np.isfinite(bias)):
                    self.bias = (float(bias[0]), float(bias[1]), float(bias[2]))
            self._t_last = float(t[-1])
            self._fed = time.monotonic()
            self._problem = ''
        except Exception as err:      # noqa: B902 - the node never dies of the monitor:
            # keep the last estimate (and the published stream) and say so.
            if not self._problem:
                self.node.get_logger().error(f'field monitor: {err}; keeping the last gyro '
                                             'bias estimate')
            self._problem = f'field monitor failed on a block: {err}'

    def _advancing(self, stamps):
        """
        Whether a block's stamps advance, within it or since the last block handed over.

        Stamps that do not (unstamped messages, a frozen header) give the monitor no clock
        to cut blocks or time still periods by: such rows are not handed over, and from
        when the stall began the statuses say so (``STAMP_STALL_S`` later).
        """
        if stamps[-1] > stamps[0] or (self._t_last is not None and stamps[-1] > self._t_last):
            self._stalled_since = None
            return True
        if self._stalled_since is None:
            self._stalled_since = time.monotonic()
        return False

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
        """Keep the estimate's parameter equal to the estimate (control thread)."""
        value = [float(v) for v in self.bias]
        if list(self.estimate.value) != value and not self.estimate.report(value):
            self._problem = f'cannot update {ESTIMATE_PARAM}'

    def publish_health(self, force=False):
        """Publish ``~/health`` when the check or the monitor's state changed: one JSON object."""
        with self.lock:
            mon = self.monitor
            result = None if mon is None else mon.health.result
            gyro = None if mon is None else mon.gyro_summary()
            state = None if mon is None else self._state(mon)
        key = (id(result), None if state is None else
               (state['sensor_fault'] is not None, bool(state['idle']), state['too_slow']))
        if key == self._published and not force:
            return
        self._published = key
        try:
            text = self._health_json(result, gyro, state)
        except (ValueError, TypeError) as err:     # never a non-finite number on a topic
            self._problem = f'~/health not published: {err}'
            return
        self.health_pub.publish(String(data=text))

    def _state(self, mon):
        """Return the monitor's state beside its last check (under the lock), JSON-ready."""
        now = time.monotonic()
        quiet = now - self._fed
        stalled = 0.0 if self._stalled_since is None else now - self._stalled_since
        idle = mon.idle_words()
        if self.active and quiet >= mon.settings.still_timeout_s:
            idle = (f'no imu/data_raw for {quiet:.0f} s: the gyro bias and the calibration '
                    'are not being checked')
        elif self.active and stalled >= STAMP_STALL_S:
            idle = (f'the imu/data_raw stamps have not advanced for {stalled:.0f} s '
                    '(unstamped or frozen headers): the gyro bias and the calibration are '
                    'not being checked')
        return {'sensor_fault': mon.fault, 'idle': idle,
                'idle_s': round(mon.idle_s(), 1), 'too_slow': mon.too_slow,
                'still_periods': mon.periods, 'still_time_s': round(mon.still_time_s, 1),
                'moving_because': mon.motion or 'still',
                'periods_not_rests': dict(mon.rejected),
                'rows_skipped_non_finite': mon.skipped_rows,
                'clock_steps': mon.cutter.steps, 'rate_hz': mon.cutter.rate_hz,
                'history': self.history}

    def _health_json(self, result, gyro, state):
        body = {'node': self.node.get_fully_qualified_name(),
                'calibration_file': self.node.path}
        if result is None:
            body.update({'level': 'unknown', 'healthy': None, 'recalibrate': False,
                         'message': 'no calibration loaded: nothing to check'})
        else:
            body.update(result.to_dict())
            body.update(state)
            body['gyro_bias_at_rest'] = gyro
            if state['sensor_fault'] is not None:
                body.update({'level': 'error', 'healthy': False,
                             'message': state['sensor_fault']['message']})
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
            state = None if mon is None else self._state(mon)
        if mon is None:
            gyro.message = health.message = 'no calibration loaded: not monitoring'
            return [gyro, health]
        est = summary['estimate_deg_s']
        if not summary['enabled']:
            gyro.message = "off (gyro_bias_at_rest false): the file's bias only"
        else:
            gyro.message = (f'{summary["state"]}; change from the file ('
                            + ', '.join(f'{v:+.4f}' for v in est) + ') deg/s; followed: '
                            + summary['followed'] + '; along gravity: '
                            + summary['along_gravity'])
            limit = self.node.params['gyro_bias_limit_deg_s']
            if max(abs(v) for v in est) >= 0.999 * limit:
                _warn(gyro, f'at its limit of {limit:g} deg/s: recalibrate the gyro')
            if summary['held_about_gravity_deg_s']:
                gyro.level = DiagnosticStatus.WARN
        if self._problem:
            _warn(gyro, self._problem)
        if not self.node.params['health_check']:
            health.message = 'off (health_check false)'
        else:
            health.message = result.message
            if result.level in ('warn', 'recalibrate'):
                health.level = DiagnosticStatus.WARN
        for status in (gyro, health):
            for words in (state['too_slow'], state['idle']):
                if words:
                    _warn(status, words)
            if state['sensor_fault'] is not None:
                status.level = DiagnosticStatus.ERROR
                status.message = f'{state["sensor_fault"]["message"]}; {status.message}'
        values = dict(summary, **state, stationary_input=self._stationary_words)
        gyro.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        health.values = [KeyValue(key=k, value=str(v)) for k, v in
                         dict(result.to_dict(), **state).items()]
        return [gyro, health]


def _warn(status, words):
    """Raise ``status`` to WARN (no lower) and add ``words`` to its message."""
    if status.level < DiagnosticStatus.WARN:
        status.level = DiagnosticStatus.WARN
    status.message = f'{status.message}; {words}' if status.message else words
