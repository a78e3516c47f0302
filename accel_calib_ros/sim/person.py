"""
A simulated person who calibrates a sensor by hand, following the advice or not.

Used by the closed-loop tests, ``bench/bench_advice.py`` and ``accel-calib guide
--simulate``. The person holds each pose with an error of a few degrees (a board
resting on an uneven hand or table) and shakes a little (hand tremor adds noise to
every sample of a window); each window mean also carries a small error that does not
average down (bias instability).
"""

from dataclasses import dataclass, field

import numpy as np

from .sensor import G0
from ..core.advice import advise, DEFAULT_TARGET, true_accuracy


def tilt(direction, error_deg, rng):
    """
    Return ``direction`` turned by ``error_deg`` about a random perpendicular axis.

    :param direction: (3,) unit vector.
    :param error_deg: rotation angle, degrees.
    :param rng: numpy Generator.
    :return: (3,) unit vector ``error_deg`` away from ``direction``.
    """
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    axis = np.cross(d, rng.standard_normal(3))
    axis /= np.linalg.norm(axis)
    angle = np.radians(error_deg)
    return d * np.cos(angle) + np.cross(axis, d) * np.sin(angle)


@dataclass
class Person:
    """
    How a simulated person holds poses.

    :param error_deg: RMS pose error, degrees (each pose is off by about this much).
    :param tremor_std: hand tremor, m/s² per sample on each axis.
    :param samples: samples averaged in each window (about 1.5 s at 100 Hz).
    :param repeatability: error of each window mean that does not average down, m/s².
    """

    error_deg: float = 3.0
    tremor_std: float = 0.02
    samples: int = 150
    repeatability: float = 3e-4

    def hold(self, sensor, direction, rng, gravity=G0, temp=None):
        """
        Hold one pose: return (actual unit direction, window mean (3,) m/s², noise (3,)).

        :param sensor: simulate.SensorModel.
        :param direction: (3,) the pose asked for.
        :param temp: °C or None.
        """
        actual = tilt(direction, abs(rng.normal(0.0, self.error_deg)), rng)
        noise = np.sqrt(sensor.noise_std ** 2 + self.tremor_std ** 2)
        temps = None if temp is None else np.array([float(temp)])
        mean = sensor.distort(gravity * actual[None], temps)[0]
        mean = mean + rng.standard_normal(3) * noise / np.sqrt(self.samples)
        mean = mean + rng.standard_normal(3) * self.repeatability
        return actual, mean, noise


@dataclass
class LoopStep:
    """One pose of a closed loop: the advice before it was held and the errors after."""

    poses: int
    predicted: float
    true: float
    enough: bool
    asked: str


@dataclass
class LoopResult:
    """A closed-loop session: its steps and the poses needed to be 'enough'."""

    steps: list = field(default_factory=list)
    poses_to_enough: int = None
    true_at_enough: float = None
    predicted_at_enough: float = None
    means: np.ndarray = None
    weights: np.ndarray = None
    noise: np.ndarray = None


def closed_loop(sensor, rng, policy='advised', person=None, method='ml',
                target=DEFAULT_TARGET, max_poses=40, gravity=G0, start=None):
    """
    Let a simulated person calibrate ``sensor`` until the advice says enough.

    :param sensor: simulate.SensorModel (the truth).
    :param rng: numpy Generator.
    :param policy: 'advised' (hold the advised pose) or 'random' (uniform on the sphere).
    :param person: Person (default a careful one).
    :param start: (K, 3) directions held first, whatever the policy.
    :return: LoopResult; ``poses_to_enough`` is None when it never got there.
    """
    from ..core.accelerometer.fit import calibrate
    person = person or Person()
    means, noise = [], None
    result = LoopResult()
    queue = [] if start is None else list(np.asarray(start, float).reshape(-1, 3))
    weights = []
    for _ in range(max_poses + 1):
        m = np.array(means).reshape(-1, 3)
        w = np.array(weights, float)
        adv = advise(m, w, noise if noise is not None else sensor.noise_std, gravity, method,
                     target)
        true_error = float('nan')
        if adv.predicted_accuracy is not None:
            try:
                cal = calibrate(m, gravity, method, w)
                true_error = true_accuracy(cal.T, cal.bias, sensor.T, sensor.bias, gravity)
            except Exception:       # noqa: B902 - a failed fit counts as not there yet
                pass
        if result.steps or len(m):
            result.steps.append(LoopStep(len(m), adv.predicted_accuracy, true_error, adv.enough,
                                         adv.next_pose.name if adv.next_pose else ''))
        if adv.enough and not queue:
            result.poses_to_enough = len(m)
            result.true_at_enough = true_error
            result.predicted_at_enough = adv.predicted_accuracy
            break
        if len(m) >= max_poses:
            break
        if queue:
            asked = queue.pop(0)
        elif policy == 'advised':
            asked = adv.next_pose.gravity_direction
        else:
            v = rng.standard_normal(3)
            asked = v / np.linalg.norm(v)
        _, mean, noise = person.hold(sensor, asked, rng, gravity)
        means.append(mean)
        weights.append(person.samples)
    result.means = np.array(means).reshape(-1, 3)
    result.weights = np.array(weights, float)
    result.noise = noise
    return result
