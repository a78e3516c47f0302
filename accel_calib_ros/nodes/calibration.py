"""
ROS 2 node ``accel_calibration``: collect static poses, solve on request, save the file.

A thin shell around :mod:`accel_calib_ros.core`:

- ``imu/data_raw`` (sensor_msgs/Imu) and ``imu/temperature`` (sensor_msgs/Temperature),
  both with the sensor-data QoS, feed an :class:`OnlineStaticDetector`; every finished
  static window (a pose held still) is kept, at most ``max_windows`` of them.
- after each window one log line and a JSON ``std_msgs/String`` on ``~/status``
  (reliable, transient local, depth 1): windows collected, how well their directions
  cover the sphere and the next pose that would shrink the parameter uncertainty most.
- ``~/calibrate`` (std_srvs/Trigger) fits ``method`` to the window means and, only if the
  result is sound, writes ``calibration_file`` atomically; otherwise it refuses with the
  reason and leaves the file untouched. ``~/reset`` forgets the collected windows.
"""

from collections import deque
import json
import math
import os

import numpy as np
from rclpy.node import Node
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, qos_profile_sensor_data, QoSProfile,
                       ReliabilityPolicy)
from sensor_msgs.msg import Imu, Temperature
from std_msgs.msg import String
from std_srvs.srv import Trigger

from .common import declare, integer, number, run, text
from ..core.calibration import calibrate
from ..core.diagnose import diagnose_windows
from ..core.errors import CalibrationError, InputError
from ..core.ml import cramer_rao_bound, fit_ml
from ..core.thermal import MIN_WINDOWS_PER_BAND
from ..core.windows import distinct_directions, OnlineStaticDetector, StaticWindows
from ..dataio.calibration_file import default_calibration_path, save_calibration

METHODS = ('ml', 'gn', 'ml-bc')
THERMAL_MODES = ('auto', 'on', 'off')
RATE_SAMPLES = 50
"""Samples buffered to measure the sample rate from the stamps' median interval."""
MIN_WINDOW_NOISE = 0.005
"""Floor of the expected window-mean error, m/s² (about 0.5 mg).

White noise averages down to a few 1e-3 m/s² in a 2 s window, but a consumer MEMS
accelerometer's bias does not repeat between poses better than about 0.5 mg (bias
instability, hand and table vibration), and a 6-parameter ``gn`` fit leaves a
residual of that order on a sensor with small cross-axis terms. Below this floor a
residual is never a reason to refuse."""
PRIOR_WEIGHT = 1e-3
"""Weight (in typical windows) of the weak prior that keeps the pose ranking defined."""
DISTINCT_ANGLE_DEG = 15.0
QUEUE_DEPTH = 200
"""Input queue depth (samples): 1 s at 200 Hz, 0.2 s at 1 kHz."""


def calibration_path(value):
    """
    Check the ``calibration_file`` parameter: '' means the default, ``~`` is expanded.

    :param value: value as read.
    :return: the path to use.
    :raises ParameterProblem: not a string.
    """
    value = text('calibration_file', value, empty_ok=True)
    return os.path.expanduser(value) if value else default_calibration_path()


def measure_rate(stamps):
    """
    Sample rate from message stamps: nominal (median interval) and as received.

    The static-window detector counts samples, so it needs the rate at which samples
    actually arrive: with frames lost on the wire that is below the nominal rate.
    Gaps longer than 20 nominal intervals (a reconnect) are left out.

    :param stamps: increasing times, s.
    :return: (nominal Hz, received Hz), or (None, None) when the stamps do not tell.
    """
    dt = np.diff(np.asarray(stamps, float))
    dt = dt[dt > 0.0]
    if len(dt) < len(stamps) // 2:
        return None, None
    median = float(np.median(dt))
    kept = dt[dt <= 20.0 * median]
    return 1.0 / median, len(kept) / float(np.sum(kept))


def stamp_seconds(stamp):
    """builtin_interfaces/Time as float seconds."""
    return stamp.sec + stamp.nanosec * 1e-9


# -- pose advice ---------------------------------------------------------------------------

def cube_directions():
    """Return the 26 candidate poses (cube faces, edges, corners): unit vectors, names."""
    dirs, names = [], []
    for x in (-1, 0, 1):
        for y in (-1, 0, 1):
            for z in (-1, 0, 1):
                v = (x, y, z)
                if v == (0, 0, 0):
                    continue
                dirs.append(np.array(v, float) / math.sqrt(x * x + y * y + z * z))
                names.append(pose_name(v))
    order = np.argsort([sum(map(abs, np.sign(d))) for d in dirs], kind='stable')
    return np.array(dirs)[order], [names[i] for i in order]


def pose_name(v):
    """
    Name of the pose whose upward body direction is ``v`` (components -1, 0, 1).

    One axis: '+x up', '-z up'; several: 'x+z up', '-x-y+z up'.
    """
    terms = [('+' if c > 0 else '-') + axis for c, axis in zip(v, 'xyz') if c]
    name = ''.join(terms)
    if len(terms) > 1 and name.startswith('+'):
        name = name[1:]
    return name + ' up'


CANDIDATES, CANDIDATE_NAMES = cube_directions()


def current_estimate(means, weights, gravity):
    """(T, bias) from the windows so far: ML once there are 10, else the ideal sensor."""
    if len(means) >= 10:
        try:
            fit = fit_ml(means, weights, gravity, max_iter=30)
            if np.all(np.isfinite(fit.T)) and np.all(np.diag(fit.T) > 0.5):
                return fit.T, fit.bias
        except (CalibrationError, np.linalg.LinAlgError, ValueError):
            pass
    return np.eye(3), np.zeros(3)


def coverage(directions):
    """Sphere coverage of unit vectors (N, 3): (smallest scatter eigenvalue x 3, distinct)."""
    if len(directions) == 0:
        return 0.0, 0
    scatter = directions.T @ directions / len(directions)
    return (max(0.0, float(3.0 * np.linalg.eigvalsh(scatter)[0])),
            distinct_directions(directions, DISTINCT_ANGLE_DEG))


def next_pose(T, bias, directions, weights, gravity, sigma):
    """
    Rank the 26 cube poses by how much each would shrink the Cramér-Rao bound.

    The bound is the 9-parameter ML one whatever the method (``gn`` fits a subset of
    the same parameters, so the ranking carries over). The score is the trace of the
    bound, with T relative and the bias in units of gravity, after adding one window
    of typical weight in the candidate direction. A weak prior (all candidates at
    :data:`PRIOR_WEIGHT`) keeps the bound finite while there are fewer windows than
    parameters.

    :param T: (3, 3) current estimate; ``bias`` (3,) m/s².
    :param directions: (N, 3) unit directions of the windows so far.
    :param weights: (N,) their weights (samples).
    :param gravity: m/s²; ``sigma``: per-sample noise, m/s².

    :return: (name, direction (3,), relative trace decrease or NaN).
    """
    typical = float(np.median(weights)) if len(weights) else 1.0
    prior_w = np.full(len(CANDIDATES), PRIOR_WEIGHT * typical)
    base_u = np.vstack([directions.reshape(-1, 3), CANDIDATES])
    base_w = np.concatenate([np.asarray(weights, float), prior_w])
    scale = np.r_[np.ones(6), np.full(3, 1.0 / gravity)]

    def score(u, w):
        try:
            crb = cramer_rao_bound(T, bias, u, sigma, w, gravity)
        except np.linalg.LinAlgError:
            return math.inf
        return float(np.sum(np.diag(crb) * scale ** 2))

    before = score(base_u, base_w)
    scores = [score(np.vstack([base_u, c]), np.r_[base_w, typical]) for c in CANDIDATES]
    best = int(np.argmin(scores))
    gain = (before - scores[best]) / before if math.isfinite(before) and before > 0 \
        else float('nan')
    return CANDIDATE_NAMES[best], CANDIDATES[best], gain


# -- the node ------------------------------------------------------------------------------

class CalibrationNode(Node):
    """Collect static windows from the raw IMU stream and calibrate on request."""

    def __init__(self, **kwargs):
        super().__init__('accel_calibration', **kwargs)
        p = {}
        p['method'] = text('method', declare(
            self, 'method', 'ml', 'solver: ml (Sun & Xu), gn (6-parameter) or ml-bc'),
            METHODS)
        p['calibration_file'] = calibration_path(declare(
            self, 'calibration_file', default_calibration_path(),
            "YAML file written by ~/calibrate ('' = $ROS_HOME/accel_calib_ros/...)"))
        p['gravity'] = number('gravity', declare(
            self, 'gravity', 9.80665, 'local gravity magnitude, m/s2'), 9.7, 9.9)
        p['band_width_c'] = number('band_width_c', declare(
            self, 'band_width_c', 10.0, 'width of a temperature band, degC'), 0.0, None, True)
        p['thermal'] = text('thermal', declare(
            self, 'thermal', 'auto',
            'auto: temperature-band tables when >= 2 bands are filled; on; off'),
            THERMAL_MODES)
        p['max_residual_ratio'] = number('max_residual_ratio', declare(
            self, 'max_residual_ratio', 10.0,
            'refuse when the gravity-norm residual RMS exceeds this x window-mean noise'),
            1.0)
        p['max_scale_error'] = number('max_scale_error', declare(
            self, 'max_scale_error', 0.2, 'refuse when |T_ii - 1| exceeds this'), 0.0, None,
            True)
        p['max_cross_axis'] = number('max_cross_axis', declare(
            self, 'max_cross_axis', 0.1, 'refuse when |T_ij| / T_ii exceeds this'), 0.0, None,
            True)
        p['max_bias_g'] = number('max_bias_g', declare(
            self, 'max_bias_g', 0.25, 'refuse when a bias exceeds this many g'), 0.0, None,
            True)
        p['window_s'] = number('window_s', declare(
            self, 'window_s', 0.25, 'moving standard deviation window, s'), 0.0, 10.0, True)
        p['min_duration_s'] = number('min_duration_s', declare(
            self, 'min_duration_s', 1.0, 'shortest static window kept after trimming, s'),
            0.0, None, True)
        p['trim_s'] = number('trim_s', declare(
            self, 'trim_s', 0.2, 'cut from each end of a still stretch, s'), 0.0, 10.0)
        p['threshold_factor'] = number('threshold_factor', declare(
            self, 'threshold_factor', 3.0, 'still when moving std < factor x noise floor'),
            1.0, None, True)
        p['max_windows'] = integer('max_windows', declare(
            self, 'max_windows', 500, 'windows kept; the oldest are dropped beyond'), 10)
        p['max_weight_s'] = number('max_weight_s', declare(
            self, 'max_weight_s', 5.0, 'a window weighs at most this many seconds of samples'),
            0.0, None, True)
        p['rate_hz'] = number('rate_hz', declare(
            self, 'rate_hz', 0.0,
            'samples received per second; 0 = measure it from the first 50 stamps'),
            0.0)
        self.params = p
        self.windows = deque(maxlen=p['max_windows'])
        self.temperature = float('nan')
        self.rate_hz = p['rate_hz'] or None
        self.detector = self._new_detector() if self.rate_hz else None
        self._startup = []          # (t, accel) buffered while the rate is measured
        self._seq = 0
        self._last_result = None    # {'success', 'message'} of the last ~/calibrate

        status_qos = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST,
                                reliability=ReliabilityPolicy.RELIABLE,
                                durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.status_pub = self.create_publisher(String, '~/status', status_qos)
        # Sensor-data QoS (best effort, volatile) with a deeper queue than its 5, so a
        # solve or a burst does not drop samples.
        sub_qos = QoSProfile(depth=QUEUE_DEPTH, history=qos_profile_sensor_data.history,
                             reliability=qos_profile_sensor_data.reliability,
                             durability=qos_profile_sensor_data.durability)
        self.create_subscription(Imu, 'imu/data_raw', self.on_imu, sub_qos)
        self.create_subscription(Temperature, 'imu/temperature', self.on_temperature, sub_qos)
        self.create_service(Trigger, '~/calibrate', self.on_calibrate)
        self.create_service(Trigger, '~/reset', self.on_reset)
        self.publish_status()
        self.get_logger().info(
            f'collecting static poses (method {p["method"]}, file {p["calibration_file"]}); '
            'hold each pose still for 2 s, then call ~/calibrate')

    # -- input -----------------------------------------------------------------------------
    def _new_detector(self):
        p = self.params
        return OnlineStaticDetector(self.rate_hz, window_s=p['window_s'],
                                    min_duration_s=p['min_duration_s'],
                                    threshold_factor=p['threshold_factor'], trim_s=p['trim_s'])

    def on_temperature(self, msg):
        """
        Remember the latest temperature, °C.

        :param msg: sensor_msgs/Temperature.
        """
        self.temperature = float(msg.temperature)

    def on_imu(self, msg):
        """
        Feed one raw sample to the static-window detector.

        :param msg: sensor_msgs/Imu with raw linear_acceleration, m/s².
        """
        a = msg.linear_acceleration
        accel = (a.x, a.y, a.z)
        if not all(map(math.isfinite, accel)):
            return
        t = stamp_seconds(msg.header.stamp)
        if t <= 0.0:                                            # unstamped: receive time
            t = self.get_clock().now().nanoseconds * 1e-9
        if self.detector is None:
            self._startup.append((t, accel, self.temperature))
            if len(self._startup) < RATE_SAMPLES:
                return
            nominal, effective = measure_rate([s[0] for s in self._startup])
            if effective is None:
                self._startup = self._startup[-RATE_SAMPLES // 2:]
                return
            self.rate_hz = effective
            self.detector = self._new_detector()
            self.get_logger().info(f'sample rate {effective:.1f} Hz received (stamps '
                                   f'{nominal:.1f} Hz apart: '
                                   f'{max(0.0, 1.0 - effective / nominal):.0%} lost)')
            buffered, self._startup = self._startup, []
            for sample in buffered:
                self._add(self.detector.update(*sample))
            return
        self._add(self.detector.update(t, accel, self.temperature))

    def _add(self, window):
        if window is None:
            return
        self.windows.append(window)
        self.publish_status(window)

    # -- progress --------------------------------------------------------------------------
    def _arrays(self):
        w = list(self.windows)
        means = np.array([x['mean'] for x in w]).reshape(-1, 3)
        counts = np.array([x['count'] for x in w], float)
        scatter = np.array([x['scatter'] for x in w]).reshape(-1, 3)
        temps = np.array([x['temp'] for x in w], float)
        cap = self.params['max_weight_s'] * (self.rate_hz or 1.0)
        weights = np.minimum(counts, cap)
        dof = np.maximum(counts - 1, 0)
        noise = np.sqrt(np.sum(dof[:, None] * scatter ** 2, axis=0) / max(dof.sum(), 1.0))
        return means, weights, temps, noise

    def progress(self):
        """Summarise the collection as a dict (what ``~/status`` publishes)."""
        g = self.params['gravity']
        means, weights, temps, noise = self._arrays()
        d = {'windows': len(means), 'rate_hz': self.rate_hz, 'seq': self._seq,
             'coverage': {'min_eigenvalue_x3': 0.0, 'distinct_directions': 0},
             'next_pose': '+z up', 'next_direction': [0.0, 0.0, 1.0],
             'expected_uncertainty_decrease': None, 'last_window': None,
             'temperature_c': None, 'last_calibration': self._last_result}
        if len(means) == 0:
            return d
        T, bias = current_estimate(means, weights, g)
        u = np.linalg.solve(T, (means - bias).T).T
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        eig, distinct = coverage(u)
        sigma = max(float(np.sqrt(np.mean(noise ** 2))), MIN_WINDOW_NOISE)
        name, direction, gain = next_pose(T, bias, u, weights, g, sigma)
        finite_t = temps[np.isfinite(temps)]
        d['coverage'] = {'min_eigenvalue_x3': round(eig, 4), 'distinct_directions': distinct}
        d['next_pose'] = name
        d['next_direction'] = [round(float(v), 4) for v in direction]
        if math.isfinite(gain):
            d['expected_uncertainty_decrease'] = round(gain, 4)
        if len(finite_t):
            d['temperature_c'] = [round(float(finite_t.min()), 2),
                                  round(float(finite_t.max()), 2)]
        return d

    def publish_status(self, window=None):
        """
        Publish the progress JSON and, for a new window, log one line.

        :param window: the window just finished, or None.
        """
        self._seq += 1
        d = self.progress()
        if window is not None:
            d['last_window'] = {
                'mean': [round(float(v), 5) for v in window['mean']],
                'count': int(window['count']),
                'duration_s': round(window['t_stop'] - window['t_start'], 3)}
            c = d['coverage']
            self.get_logger().info(
                f'window {d["windows"]}: mean ({", ".join(f"{v:.3f}" for v in window["mean"])})'
                f' m/s2, {window["count"]} samples; coverage {c["min_eigenvalue_x3"]:.2f}, '
                f'{c["distinct_directions"]} distinct directions; next: hold {d["next_pose"]}')
        self.status_pub.publish(String(data=json.dumps(d)))

    # -- services --------------------------------------------------------------------------
    def on_reset(self, request, response):
        """
        Forget all collected windows.

        :param request: std_srvs/Trigger request (empty).
        :param response: std_srvs/Trigger response.
        :return: the response, success=True.
        """
        n = len(self.windows)
        self.windows.clear()
        if self.detector is not None:
            self.detector = self._new_detector()
        self.publish_status()
        response.success = True
        response.message = f'cleared {n} windows'
        self.get_logger().info(response.message)
        return response

    def on_calibrate(self, request, response):
        """
        Solve with the collected windows; save only a sound calibration.

        :param request: std_srvs/Trigger request (empty).
        :param response: std_srvs/Trigger response.
        :return: the response: success and the key figures, or the reason for refusal.
        """
        if self.detector is not None:
            self._add(self.detector.flush())
        try:
            response.message = self.solve()
            response.success = True
            self.get_logger().info(response.message)
        except CalibrationError as err:
            response.success = False
            response.message = f'refused: {err}'
            self.get_logger().warning(response.message)
        self._last_result = {'success': response.success, 'message': response.message}
        self.publish_status()
        return response

    def _thermal_wanted(self, temps, mode=None):
        mode = mode or self.params['thermal']
        if mode == 'off':
            return False
        finite = temps[np.isfinite(temps)]
        if mode == 'on':
            if not len(finite):
                raise CalibrationError('thermal:=on but no temperature was received')
            return True
        bands, counts = np.unique(np.floor(finite / self.params['band_width_c']),
                                  return_counts=True)
        return int(np.sum(counts >= MIN_WINDOWS_PER_BAND)) >= 2

    def solve(self):
        """Fit, check and save; return the success message or raise CalibrationError."""
        p = self.params
        g = p['gravity']
        means, weights, temps, noise = self._arrays()
        if len(means) == 0:
            raise CalibrationError('no static windows collected yet: hold the sensor still '
                                   'in at least 10 different orientations, 2 s each')
        thermal = self._thermal_wanted(temps)
        try:
            cal = calibrate(means, gravity=g, method=p['method'], weights=weights,
                            temps=temps if thermal else None, thermal=thermal,
                            band_width_c=p['band_width_c'], noise_std=noise,
                            source=f'ros node {self.get_fully_qualified_name()}')
        except InputError as err:
            raise CalibrationError(str(err)) from None
        except np.linalg.LinAlgError as err:
            raise CalibrationError(f'the fit failed numerically ({err}): '
                                   'add more distinct poses') from None
        if not cal.converged:
            raise CalibrationError(f'the {p["method"]} fit did not converge in '
                                   f'{cal.iterations} iterations: add more distinct poses')
        expected = max(float(np.sqrt(np.mean(noise ** 2) / np.median(weights))),
                       MIN_WINDOW_NOISE)
        if not cal.residual_rms <= p['max_residual_ratio'] * expected:
            raise CalibrationError(
                f'gravity-norm residual {cal.residual_rms:.4f} m/s2 is '
                f'{cal.residual_rms / expected:.0f}x the expected window noise '
                f'{expected:.4f} m/s2 (limit {p["max_residual_ratio"]:g}x): the sensor moved '
                'during the poses or the model does not fit this sensor'
                + ('' if thermal or not self._thermal_wanted(temps, 'auto') else
                   '; the windows fill two temperature bands: try thermal:=auto')
                + self._diagnose_hint(prefix='. '))
        problems = cal.physical_problems(p['max_scale_error'], p['max_cross_axis'],
                                         p['max_bias_g'])
        if problems:
            raise CalibrationError('not physical: ' + '; '.join(problems)
                                   + ' (are the readings in m/s2?)')
        bands = 0 if cal.thermal is None else len(cal.thermal.usable)
        try:
            save_calibration(cal, p['calibration_file'])
        except OSError as err:
            raise CalibrationError(f'cannot write {p["calibration_file"]}: {err}') from None
        with np.printoptions(precision=5, suppress=True):
            msg = (f'{cal.method} calibration from {len(means)} windows saved to '
                   f'{p["calibration_file"]}: scale {np.round(cal.scale, 5).tolist()}, '
                   f'bias {np.round(cal.bias, 4).tolist()} m/s2, non-orthogonality '
                   f'{np.round(cal.nonorthogonality_deg, 3).tolist()} deg (xy, xz, yz), '
                   f'residual {cal.residual_rms:.4f} m/s2, thermal bands {bands}')
        return msg + self._diagnose_hint(prefix='. ')

    def _diagnose_hint(self, prefix=''):
        """Return one sentence when the model-gap check names an effect the method lacks."""
        w = list(self.windows)
        count = np.array([x['count'] for x in w], int)
        windows = StaticWindows(
            start=np.zeros(len(w), int), stop=count,
            mean=np.array([x['mean'] for x in w]).reshape(-1, 3),
            scatter=np.array([x['scatter'] for x in w]).reshape(-1, 3), count=count,
            t_mid=np.array([x['t_mid'] for x in w], float),
            temp=np.array([x['temp'] for x in w], float))
        baseline = 'gn' if self.params['method'] == 'gn' else 'ml'
        try:
            report = diagnose_windows(windows, baseline, self.params['gravity'], replicates=0)
        except (CalibrationError, ValueError, np.linalg.LinAlgError) as err:
            self.get_logger().debug(f'model-gap check skipped: {err}')
            return ''
        if not report.missing_effects:
            return ''
        details = '; '.join(f'{step["effect"]} ({step["evidence"]["magnitude"]})'
                            for step in report.steps)
        return (f'{prefix}Note: the data show {details}, which the {self.params["method"]} '
                f'model does not include (gap {report.gap_before:.1f} -> '
                f'{report.gap_after:.1f})')


def main(args=None):
    """Run the node until Ctrl-C; exit status 2 on a bad parameter."""
    run(CalibrationNode, 'accel_calibration', args)


if __name__ == '__main__':
    main()
