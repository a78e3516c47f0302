"""
ROS 2 node ``accel_correction``: apply the saved calibration to the live IMU stream.

Subscribes to ``imu/data_raw`` (sensor_msgs/Imu) and ``imu/temperature``
(sensor_msgs/Temperature) and publishes ``imu/corrected`` (sensor_msgs/Imu): the same
message with ``linear_acceleration = Calibration.correct(raw, latest temperature)`` and
``linear_acceleration_covariance`` = the calibration's per-sample covariance (row-major,
(m/s²)²). Every other field (header, orientation and its covariance, angular velocity
and its covariance) is passed through untouched.

Hot reload: ``calibration_file`` is checked every ``reload_period_s``; when its
(mtime, size, inode) changes it is loaded, and only a valid file replaces the
calibration in use. Without any calibration the data pass through unchanged with a
large diagonal covariance of (:data:`UNCALIBRATED_STD`)² per axis, so downstream nodes
keep running but can tell the acceleration is uncalibrated (REP-145's -1 would claim
it is not reported at all).
"""

import math
import os

import numpy as np
from rclpy.node import Node
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, qos_profile_sensor_data, QoSProfile,
                       ReliabilityPolicy)
from sensor_msgs.msg import Imu, Temperature

from .calibration import calibration_path
from .common import declare, number, run
from ..core.errors import InputError
from ..dataio.calibration_file import default_calibration_path, load_calibration

UNCALIBRATED_STD = 0.5
"""Per-axis standard deviation reported while no calibration is loaded, m/s²."""
UNCALIBRATED_COVARIANCE = np.diag([UNCALIBRATED_STD ** 2] * 3).reshape(9)
QUEUE_DEPTH = 100
"""Subscription and publisher queue depth: 0.1 s at 1 kHz, rides out a file reload."""


class Corrector:
    """
    Precomputed correction of one calibration: plain-float 3x3 math per sample.

    :param cal: Calibration, or None for the pass-through.
    """

    def __init__(self, cal=None):
        self.cal = cal
        if cal is None:
            self.R = None
            self.bias = (0.0, 0.0, 0.0)
            self.covariance = UNCALIBRATED_COVARIANCE.copy()
        else:
            self.R = tuple(tuple(float(v) for v in row) for row in np.linalg.inv(cal.T))
            self.bias = tuple(float(v) for v in cal.bias)
            self.covariance = np.ascontiguousarray(
                cal.acceleration_covariance(), dtype=np.float64).reshape(9)
        self._drift_temp = None
        self._coef = None

    def coefficients(self, temp):
        """Drift (quadratic, linear, offset) per axis at ``temp`` °C, or None (no drift)."""
        cal = self.cal
        if cal is None or cal.thermal is None or not cal.thermal.usable \
                or not math.isfinite(temp):
            return None
        if temp != self._drift_temp:      # temperature changes far slower than samples
            quad, lin, off = cal.thermal.coefficients(np.array([temp]))
            self._coef = tuple(zip(quad[0].tolist(), lin[0].tolist(), off[0].tolist()))
            self._drift_temp = temp
        return self._coef

    def correct(self, x, y, z, temp):
        """Corrected (x, y, z) m/s² for one raw sample at ``temp`` °C."""
        if self.R is None:
            return x, y, z
        bx, by, bz = self.bias
        coef = self.coefficients(temp)
        if coef is not None:
            (qx, lx, ox), (qy, ly, oy), (qz, lz, oz) = coef
            bx += qx * x * x + lx * x + ox
            by += qy * y * y + ly * y + oy
            bz += qz * z * z + lz * z + oz
        x, y, z = x - bx, y - by, z - bz
        (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = self.R
        return (r00 * x + r01 * y + r02 * z,
                r10 * x + r11 * y + r12 * z,
                r20 * x + r21 * y + r22 * z)


def file_key(path):
    """(st_mtime_ns, st_size, st_ino) of ``path``, or None if it does not exist."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_mtime_ns, st.st_size, st.st_ino


class CorrectionNode(Node):
    """Correct the raw accelerometer stream with the calibration file, reloading it live."""

    def __init__(self, **kwargs):
        super().__init__('accel_correction', **kwargs)
        self.path = calibration_path(declare(
            self, 'calibration_file', default_calibration_path(),
            "calibration YAML to apply ('' = $ROS_HOME/accel_calib_ros/calibration.yaml)"))
        period = number('reload_period_s', declare(
            self, 'reload_period_s', 0.25, 'how often the file is checked for changes, s'),
            0.0, 60.0, True)
        self.corrector = Corrector(None)
        self.temperature = float('nan')
        self._key = ()              # file key last acted on (loaded or rejected); () = never
        self._warned_missing = False
        self._warned_no_temp = False
        self._samples = 0
        self.check_file(initial=True)

        pub_qos = QoSProfile(depth=QUEUE_DEPTH, history=HistoryPolicy.KEEP_LAST,
                             reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.VOLATILE)
        sub_qos = QoSProfile(depth=QUEUE_DEPTH, history=qos_profile_sensor_data.history,
                             reliability=qos_profile_sensor_data.reliability,
                             durability=qos_profile_sensor_data.durability)
        self.pub = self.create_publisher(Imu, 'imu/corrected', pub_qos)
        self.create_subscription(Imu, 'imu/data_raw', self.on_imu, sub_qos)
        self.create_subscription(Temperature, 'imu/temperature', self.on_temperature, sub_qos)
        self.create_timer(period, self.check_file)

    def on_temperature(self, msg):
        """
        Remember the latest temperature, °C.

        :param msg: sensor_msgs/Temperature.
        """
        self.temperature = msg.temperature

    def on_imu(self, msg):
        """
        Correct one sample and republish it.

        :param msg: sensor_msgs/Imu from the driver (modified in place and published).
        """
        c = self.corrector
        self._samples += 1
        a = msg.linear_acceleration
        a.x, a.y, a.z = c.correct(a.x, a.y, a.z, self.temperature)
        msg.linear_acceleration_covariance = c.covariance
        self.pub.publish(msg)

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
                if not self._warned_missing:
                    log.warning(f'no calibration file {self.path}: passing the raw '
                                'acceleration through, covariance '
                                f'({UNCALIBRATED_STD} m/s2)^2 per axis, until one appears')
                    self._warned_missing = True
            else:
                log.warning(f'calibration file {self.path} disappeared: keeping the '
                            'calibration loaded before')
            return
        try:
            cal = load_calibration(self.path)
            corrector = Corrector(cal)
        except (InputError, np.linalg.LinAlgError, ValueError) as err:
            log.error(f'ignoring calibration file {self.path}: {err}; '
                      + ('keeping the previous calibration' if self.corrector.cal is not None
                         else 'still passing the raw acceleration through'))
            return
        self.corrector = corrector
        std = np.sqrt(np.diag(cal.acceleration_covariance()))
        log.info(f'{"loaded" if initial else "reloaded"} {cal.method} calibration '
                 f'{self.path} (created {cal.created}, scale '
                 f'{np.round(cal.scale, 5).tolist()}, bias {np.round(cal.bias, 4).tolist()} '
                 f'm/s2, thermal bands '
                 f'{0 if cal.thermal is None else len(cal.thermal.usable)}, '
                 f'per-axis std {np.round(std, 4).tolist()} m/s2)')

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


def main(args=None):
    """Run the node until Ctrl-C; exit status 2 on a bad parameter."""
    run(CorrectionNode, 'accel_correction', args)


if __name__ == '__main__':
    main()
