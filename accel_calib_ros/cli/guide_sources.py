"""
Where the guide's samples come from: a serial port, a ROS topic or a simulated person.

Each source has ``label``, ``read(session)`` -> (t (N,) s, accel (N, 3) m/s², temp (N,) °C)
and ``close()``. After a read, ``last_gyro`` holds the N angular rates (rad/s) when the
source has them (else None) and ``last_mag`` the magnetometer samples read (times (M,)
s, field (M, 3) µT) when it has one (else None). The serial port is read through
``dataio.link`` (the driver's link); the link (pyserial) and rclpy are imported only by
the source that needs them.
"""

import math
import time

import numpy as np

from ..core.constants import G0
from ..core.errors import InputError


def _slerp(a, b, s):
    """Point a fraction ``s`` of the way along the great circle from unit ``a`` to ``b``."""
    dot = float(np.clip(a @ b, -1.0, 1.0))
    if dot < -0.999:            # opposite: turn over a perpendicular axis
        p = np.cross(a, [1.0, 0.0, 0.0] if abs(a[0]) < 0.9 else [0.0, 1.0, 0.0])
        p /= np.linalg.norm(p)
        return _slerp(a, p, 2 * s) if s < 0.5 else _slerp(p, b, 2 * s - 1)
    omega = math.acos(dot)
    if omega < 1e-9:
        return b.copy()
    v = (math.sin((1 - s) * omega) * a + math.sin(s * omega) * b) / math.sin(omega)
    return v / np.linalg.norm(v)


class SimulatedSource:
    """
    A simulated MPU9250 held by a simulated person who follows the guide.

    The person holds a pose until the guide has captured it, waits a reaction time,
    turns to the pose the guide asks for (off by a few degrees) in ``turn_s`` with the
    hand's acceleration, and holds again. Time runs ``speed`` times faster than the wall
    clock, so a test of a whole session takes seconds.
    """

    label = 'simulated sensor and person'
    last_gyro = None
    last_mag = None

    def __init__(self, rate_hz=100.0, speed=1.0, seed=0, error_deg=3.0, turn_s=2.0,
                 temp=25.0, gravity=G0, tremor=0.02, reaction_s=0.5, magnetometer=False):
        from ..sim.sensor import ak8963_like, EarthField, mpu9250_like, with_gyro_errors
        self.rng = np.random.default_rng(seed)
        self.sensor = mpu9250_like(self.rng, rate_hz)
        # The gyroscope (and magnetometer) from generators of their own: the accelerometer
        # and the person are those of a session without them.
        self.sensor = with_gyro_errors(self.sensor, np.random.default_rng([seed, 19, 1]))
        if magnetometer:
            self.sensor.magnetometer = ak8963_like(np.random.default_rng([seed, 19, 2]))
        self.field_world = EarthField().world()
        self._imu_rng = np.random.default_rng([seed, 19, 3])
        self.orientation = np.eye(3)        # body to world, kept in step with the direction
        self.rate = rate_hz
        self.speed = speed
        self.error_deg = error_deg
        self.turn_s = turn_s
        self.temp = temp
        self.gravity = gravity
        self.tremor = tremor
        self.reaction_s = reaction_s
        self.t = 0.0
        self._wall0 = None
        self.direction = np.array([0.0, 0.0, 1.0])
        self.state, self._since, self._from, self._to = 'holding', 0.0, None, None
        self._axis = np.array([1.0, 0.0, 0.0])

    def _person(self, session, t):
        if self.state == 'holding':
            if session is not None and session.tracker.state == 'captured' \
                    and not session.enough:
                if self._since is None:
                    self._since = t
                if t - self._since >= self.reaction_s:
                    from ..sim.person import tilt
                    self._from = self.direction.copy()
                    self._to = tilt(session.target_direction, abs(self.rng.normal(
                        0.0, self.error_deg)), self.rng)
                    self.state, self._since = 'turning', t
                    axis = np.cross(self._from, self.rng.standard_normal(3))
                    self._axis = axis / np.linalg.norm(axis)
            else:
                self._since = None
        elif self.state == 'turning':
            s = (t - self._since) / self.turn_s
            if s >= 1.0:
                self.direction = self._to
                self.state, self._since = 'holding', None
                return np.zeros(3)
            smooth = s * s * (3 - 2 * s)
            self.direction = _slerp(self._from, self._to, smooth)
            return 1.5 * math.sin(math.pi * s) * self._axis
        return np.zeros(3)

    def read(self, session):
        """Return the samples (t, accel, temp) due by now; sleeps a little."""
        time.sleep(0.02)
        now = time.monotonic()
        if self._wall0 is None:
            self._wall0 = now - 0.02
        due = (now - self._wall0) * self.speed
        n = min(int((due - self.t) * self.rate), int(5 * self.rate))
        if n <= 0:
            return np.zeros(0), np.zeros((0, 3)), np.zeros(0)
        t = self.t + np.arange(n) / self.rate
        true = np.empty((n, 3))
        rate = np.empty((n, 3))
        field = np.empty((n, 3))
        for k in range(n):
            before = self.direction
            motion = self._person(session, t[k])
            true[k] = self.gravity * self.direction + motion
            # The body rate that turns the gravity direction this way (none about it):
            # d' = d x w, so w = -(d_k x d_k+1) / dt, integrated into the orientation.
            rate[k] = -np.cross(before, self.direction) * self.rate
            self.orientation = self.orientation @ _rotation(rate[k] / self.rate)
            field[k] = self.orientation.T @ self.field_world
        self.t = t[-1] + 1.0 / self.rate
        temp = np.full(n, float(self.temp))
        raw = self.sensor.measure(true, self.rng, temp)
        raw = raw + self.rng.standard_normal(raw.shape) * self.tremor
        s = self.sensor
        self.last_gyro = rate @ s.gyro_T.T + s.gyro_bias \
            + self._imu_rng.standard_normal((n, 3)) * s.gyro_noise_std
        mag = s.magnetometer
        self.last_mag = None if mag is None else (
            t, mag.distort(field) + self._imu_rng.standard_normal((n, 3)) * mag.noise_std)
        return t, raw, temp

    def close(self):
        """Nothing to release."""


def _rotation(phi):
    """Rotation matrix exp([phi]x) of a rotation vector (3,), radians (Rodrigues)."""
    angle = float(np.linalg.norm(phi))
    if angle < 1e-12:
        return np.eye(3)
    k = np.asarray(phi, float) / angle
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * (K @ K)


class SerialSource:
    """
    The board's frames (interface.md §1, §1b) or ASCII lines, read by ``dataio.link``.

    The link is the driver's (``dataio.link.SerialLink``): it reopens the port with back-off,
    asks for the firmware's info frame, maps the device clock onto host time and skips and
    counts corrupt bytes. The info frame names the chip (``dataio.wire.chips``: its
    temperature formula, ranges and sensitivities) and the ranges in use; without one
    (ASCII lines, an old firmware) ``accel_range`` and ``gyro_range`` apply. Magnetometer
    samples (frame version 2) are converted with the info frame's sensitivity adjustment.

    :raises InputError: the port cannot be opened.
    """

    last_mag = None

    def __init__(self, port, baud=1000000, ascii_lines=False, accel_range=2, gyro_range=250,
                 wait_s=2.0):
        import threading
        from ..dataio.link import READ_TIMEOUT_S, SerialLink
        from ..dataio.link.serial_link import open_serial, PORT_ERRORS
        from ..dataio.wire import Converter, MagConverter
        self.label = f'serial {port} at {baud} baud'
        try:
            first = [open_serial(port, baud, READ_TIMEOUT_S)]   # one clear line when it cannot
        except PORT_ERRORS as err:
            raise InputError(f'cannot open {port}: {err}') from None

        def open_port(path, rate, timeout):     # the port opened above first, then anew
            return first.pop() if first else open_serial(path, rate, timeout)

        self.ranges = (accel_range, gyro_range)
        self.converter = Converter(accel_range, gyro_range)
        self.mag_converter = MagConverter()
        self.info = None
        self._lock = threading.Lock()
        self._got = []                  # (stamps, accel, temp, gyro, mag) per delivery
        self.last_gyro = None
        self.link = SerialLink(port, baud, 'ascii' if ascii_lines else 'binary', 'device',
                               open_port=open_port, on_samples=self._on_samples,
                               on_info=self._on_info, on_connect=self._on_connect)
        self.link.start()
        deadline = time.monotonic() + wait_s
        while self.link.opened_at is None and time.monotonic() < deadline:
            time.sleep(0.005)

    def _on_connect(self):
        """Forget the info frame: the device may have restarted or been swapped."""
        self._on_info(None)

    def _on_info(self, info):
        """Take the chip and the ranges of the firmware's info frame (the reader thread)."""
        from ..dataio.wire import chip_of, Converter, DEFAULT_CHIP, MAG_AK8963, MagConverter
        chip = (info is not None and chip_of(info.who_am_i)) or DEFAULT_CHIP
        accel, gyro = self.ranges
        if info is not None and info.status == 0 and info.accel_range_g in \
                chip.accel_lsb_per_g and info.gyro_range_dps in chip.gyro_lsb_per_dps:
            accel, gyro = info.accel_range_g, info.gyro_range_dps
        mag = MagConverter(info.asa, chip.magnetometer or DEFAULT_CHIP.magnetometer) \
            if info is not None and info.mag_status == MAG_AK8963 else MagConverter()
        with self._lock:
            self.info = info
            self.converter = Converter(accel, gyro, chip=chip)
            self.mag_converter = mag

    def _on_samples(self, frames, stamps):
        """Convert the link's frames (the reader thread); :meth:`read` takes them."""
        with self._lock:
            to_si, to_tesla = self.converter.to_si, self.mag_converter.to_tesla
        accel, temp, gyro, mag = [], [], [], []
        for frame, stamp in zip(frames, stamps):
            a, c, w = to_si(frame.counts)
            accel.append(a)
            temp.append(c)
            gyro.append(w)
            field = None if frame.mag is None else to_tesla(frame.mag)
            if field is not None:
                mag.append((stamp, [v * 1e6 for v in field]))
        with self._lock:
            self._got.append((list(stamps), accel, temp, gyro, mag))

    def read(self, session):
        """Return the samples (t, accel, temp) received since the last call; sleeps a little."""
        with self._lock:
            got, self._got = self._got, []
        if not got:
            time.sleep(0.02)
        t = np.array([v for g in got for v in g[0]], float)
        self.last_gyro = np.array([v for g in got for v in g[3]], float).reshape(-1, 3)
        mags = [m for g in got for m in g[4]]
        self.last_mag = (np.array([m[0] for m in mags], float),
                         np.array([m[1] for m in mags], float).reshape(-1, 3)) if mags else None
        return (t, np.array([v for g in got for v in g[1]], float).reshape(-1, 3),
                np.array([v for g in got for v in g[2]], float))

    def close(self):
        """Stop the link (the port is closed)."""
        self.link.stop()


class RosSource:
    """sensor_msgs/Imu (and Temperature) from ROS 2 topics; rclpy is imported here."""

    def __init__(self, topic, temp_topic=None, mag_topic=None):
        try:
            import rclpy
            from rclpy.qos import qos_profile_sensor_data
            from sensor_msgs.msg import Imu, MagneticField, Temperature
        except ImportError as err:
            raise InputError(f'ROS 2 (rclpy) is not available: {err}') from None
        from rclpy.executors import SingleThreadedExecutor
        self.label = f'ROS topic {topic}'
        self.rclpy = rclpy
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node('accel_calib_guide', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.buffer = []
        self.mags = []
        self.last_gyro = self.last_mag = None
        self.temp = math.nan
        self.node.create_subscription(Imu, topic, self._on_imu, qos_profile_sensor_data)
        if temp_topic:
            self.node.create_subscription(Temperature, temp_topic, self._on_temp,
                                          qos_profile_sensor_data)
        if mag_topic:
            self.node.create_subscription(MagneticField, mag_topic, self._on_mag,
                                          qos_profile_sensor_data)

    @staticmethod
    def _stamp(msg):
        stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        return stamp if stamp > 0 else time.monotonic()

    def _on_imu(self, msg):
        a, w = msg.linear_acceleration, msg.angular_velocity
        rate = (w.x, w.y, w.z) if msg.angular_velocity_covariance[0] >= 0 else (math.nan,) * 3
        self.buffer.append((self._stamp(msg), (a.x, a.y, a.z), self.temp, rate))

    def _on_mag(self, msg):
        f = msg.magnetic_field
        self.mags.append((self._stamp(msg), (f.x * 1e6, f.y * 1e6, f.z * 1e6)))

    def _on_temp(self, msg):
        self.temp = float(msg.temperature)

    def read(self, session):
        """Spin briefly; return the samples (t, accel, temp) received."""
        deadline = time.monotonic() + 0.05
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.01)
        got, self.buffer = self.buffer, []
        got = [g for g in got if all(map(math.isfinite, g[1]))]
        gyro = np.array([g[3] for g in got], float).reshape(-1, 3)
        self.last_gyro = gyro if len(gyro) and np.isfinite(gyro).all() else None
        mags, self.mags = self.mags, []
        self.last_mag = (np.array([m[0] for m in mags]),
                         np.array([m[1] for m in mags]).reshape(-1, 3)) if mags else None
        return (np.array([g[0] for g in got]), np.array([g[1] for g in got]).reshape(-1, 3),
                np.array([g[2] for g in got], float))

    def close(self):
        """Leave the ROS graph."""
        self.executor.shutdown()
        self.node.destroy_node()
        self.rclpy.try_shutdown(context=self.context)
