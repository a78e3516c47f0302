"""
What the calibration node says about its collection: ``~/status``, ``~/advice``, ``/diagnostics``.

A mixin of :class:`~.calibration.CalibrationNode` (its windows, detector, collector,
intake and publishers): the progress JSON of ``~/status`` (interface.md §5 advice
inside), the advice on ``~/advice`` and the collection's ``/diagnostics`` status. Every
number goes out finite or null (:func:`safe_json`).
"""

import json
import math

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
import numpy as np
from std_msgs.msg import String

from .calibration_thermal import thermal_status
from .paths import hardware_id, status_name
from ..core.advice import advise, coverage
from ..core.errors import CalibrationError, InputError
from ..core.finite import finite_or_none
from ..session.windows import Window, WindowSet


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


class Progress:
    """The calibration node's reports (a mixin: see the module docstring)."""

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
             'model_gap': self._model_gap, 'imu': self.imu.state(self._coverage),
             'thermal': thermal_status(self), 'last_thermal': self._last_thermal}
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
                                  name=status_name(self, 'collection'),
                                  hardware_id=hardware_id(self.sensor))
        status.message = f'{n} static windows' + (
            f', predicted accuracy {acc:.4f} m/s2' if acc is not None else '')
        problems = []
        if self.detector.rate_hz is None:
            problems.append('no imu/data_raw received yet')
        frame = self.frame_id
        if frame and frame != self.params['frame_id']:
            problems.append(f'imu/data_raw is in frame {frame}, parameter frame_id is '
                            f"{self.params['frame_id']}: the calibration is made for sensor "
                            f'{self.sensor}')
        if self._last_result is not None and not self._last_result['success']:
            problems.append('last calibration refused')
        if problems:
            status.level = DiagnosticStatus.WARN
            status.message = ('' if self.detector.rate_hz is None else status.message + '; ') \
                + '; '.join(problems)
        values = {'windows': n, 'rate_hz': finite_or_none(self.detector.rate_hz, 2),
                  'imu_received': self.intake.received,
                  'dropped_non_finite_samples': self.intake.dropped,
                  'time_steps_back': self.intake.time.steps,
                  'calibrating': self._solving is not None,
                  'predicted_accuracy_m_s2': acc,
                  'target_accuracy_m_s2': self.params['target_accuracy'],
                  'sensor_id': self.sensor, 'calibration_file': self.path,
                  'last_calibration': (self._last_result or {}).get('message', 'none')}
        imu = self.imu.state(self._coverage)
        values.update({'gyro_received': imu['gyro_received'],
                       'raw_samples_kept': imu['raw_samples'],
                       'mag_received': imu['mag_received'], 'mag_samples_kept': imu['mag_samples'],
                       'mag_dropped_at_time_steps': self.intake.mag_dropped,
                       'mag_coverage': imu['mag_coverage']})
        status.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.get_clock().now().to_msg()
        self.diag_pub.publish(array)
