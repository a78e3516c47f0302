"""
The calibration node's intake: every message taken in, as little work as possible each.

The three sensor topics are read in a callback group of their own, spun on its own
executor and thread (``nodes.spinning``: nothing else in that wait set, no parameter
services, no timers), with a queue deep enough for two seconds at 1 kHz. A message is
read from its serialised form (``raw=True``): the stamp and the nine numbers the node
needs are unpacked where the CDR encoding puts them (a few microseconds, against some
50 for building the Python message), with rclpy's own
deserialisation as the fallback for anything else. :class:`Intake` only appends rows
under a lock; the node's timer takes them every 0.1 s (:meth:`Intake.take`) for the
detector and the collector, so nothing the samples wait for runs on their thread.

Time order: every consumer of the samples (the streaming detector, the collector, the
gyroscope's moves, the magnetometer's pairing) needs increasing times. The stamps step
back when a bag loops, a simulator restarts or another device (clock) takes over; the
intake then shifts the times of what follows so that it starts :data:`RESTART_GAP_S`
after the last sample taken in (:class:`StreamTime`): each consumer sees a gap, where it
already restarts (a window never spans it, a gyro move across it is dropped), and
nothing is ever out of order. A magnetometer sample farther than
:data:`MAG_TOLERANCE_S` from the newest Imu time is dropped (at a step, the ones of the
other side).
"""

import math
import struct
import threading

from rclpy.qos import qos_profile_sensor_data, QoSProfile
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import Imu, MagneticField, Temperature

QUEUE_DEPTH = 2000
"""Input queue depth, messages: 2 s at 1 kHz, 10 s at 200 Hz (the reader's history)."""
CDR_LE = b'\x00\x01'
"""The encapsulation of little-endian plain CDR (what the middleware writes on x86 and ARM)."""
_HEAD = struct.Struct('<iII')                   # stamp sec, nanosec, frame_id length
_IMU = struct.Struct('<15d')                    # angular velocity, its covariance, accel
_THREE = struct.Struct('<3d')
_ONE = struct.Struct('<d')
RESTART_GAP_S = 10.0
"""The gap a step back in the stamps becomes, s (beyond every consumer's gap limit)."""
MAG_TOLERANCE_S = 1.0
"""A magnetometer sample this far from the newest Imu time is dropped, s."""


def _body(data):
    """
    Return (stamp s, frame_id length, offset of the first double) of a serialised message.

    A ``std_msgs/Header`` first: stamp (int32, uint32), frame_id (uint32 length with the
    terminating NUL, then its bytes); the doubles after it are aligned to 8 bytes from
    the end of the 4-byte encapsulation header. None when ``data`` is not little-endian
    CDR.
    """
    if data[:2] != CDR_LE or len(data) < 16:
        return None
    sec, nsec, n = _HEAD.unpack_from(data, 4)
    return sec + nsec * 1e-9, n, 4 + ((12 + n + 7) & ~7)


def stamp_seconds(stamp):
    """builtin_interfaces/Time as float seconds."""
    return stamp.sec + stamp.nanosec * 1e-9


class StreamTime:
    """
    Times that never go back: a step back starts a new stretch :data:`RESTART_GAP_S` later.

    ``steps`` counts the steps back; ``last`` is the newest time given, s.
    """

    def __init__(self):
        self.offset = 0.0
        self.last = None
        self.steps = 0

    def __call__(self, t):
        """
        Return the non-decreasing time of a stamp ``t`` (s), in arrival order.

        A repeated stamp (a FIFO burst stamped once, a stepping ``/clock``) stays as it is:
        the consumers take equal times, and a restart for each would leave no window.
        """
        t += self.offset
        last = self.last
        if last is not None and t < last:
            self.offset += last + RESTART_GAP_S - t
            t = last + RESTART_GAP_S
            self.steps += 1
        self.last = t
        return t


class Intake:
    """
    What the stream thread takes in, until the node's timer takes it over.

    :param now: callable returning the node's clock now, s (stamps of unstamped messages).
    """

    def __init__(self, now):
        self.now = now
        self.lock = threading.Lock()
        self.rows = []          # (t, ax, ay, az, gx, gy, gz, temp), gyro NaN when unknown
        self.mags = []          # (t, mx, my, mz) µT
        self.temperature = math.nan
        self.frame_id = ''
        self.received = 0       # imu/data_raw messages taken in
        self.dropped = 0        # of them with a non-finite acceleration
        self.mag_received = 0
        self.mag_dropped = 0    # magnetometer samples not near the Imu times (a step)
        self.time = StreamTime()

    # -- the callbacks (stream thread) -----------------------------------------------------
    def on_imu(self, msg):
        """
        Take one raw sample (sensor_msgs/Imu, serialised or as a message).

        :param msg: bytes from a ``raw=True`` subscription, or a sensor_msgs/Imu.
        """
        head = _body(msg) if isinstance(msg, (bytes, bytearray)) else None
        if head is not None and len(msg) >= head[2] + 296:
            t, n, at = head
            v = _IMU.unpack_from(msg, at + 104)
            gyro = v[0:3] if v[3] >= 0.0 else (math.nan,) * 3
            accel = v[12:15]
            if not self.frame_id:
                self.frame_id = bytes(msg[16:15 + n]).decode('utf-8', 'replace')
        else:
            if isinstance(msg, (bytes, bytearray)):
                msg = deserialize_message(bytes(msg), Imu)
            t = stamp_seconds(msg.header.stamp)
            a, w = msg.linear_acceleration, msg.angular_velocity
            accel = (a.x, a.y, a.z)
            gyro = (w.x, w.y, w.z) if msg.angular_velocity_covariance[0] >= 0.0 \
                else (math.nan,) * 3
            if not self.frame_id:
                self.frame_id = msg.header.frame_id
        self.received += 1
        if not (math.isfinite(accel[0]) and math.isfinite(accel[1])
                and math.isfinite(accel[2])):
            self.dropped += 1
            return
        if t <= 0.0:                                            # unstamped: receive time
            t = self.now()
        row = (self.time(t),) + tuple(accel) + tuple(gyro) + (self.temperature,)
        with self.lock:
            self.rows.append(row)

    def on_mag(self, msg):
        """
        Take one magnetometer sample (sensor_msgs/MagneticField, tesla -> µT).

        :param msg: bytes from a ``raw=True`` subscription, or a sensor_msgs/MagneticField.
        """
        head = _body(msg) if isinstance(msg, (bytes, bytearray)) else None
        if head is not None and len(msg) >= head[2] + 24:
            t, _, at = head
            f = _THREE.unpack_from(msg, at)
        else:
            if isinstance(msg, (bytes, bytearray)):
                msg = deserialize_message(bytes(msg), MagneticField)
            t = stamp_seconds(msg.header.stamp)
            m = msg.magnetic_field
            f = (m.x, m.y, m.z)
        if t <= 0.0:
            t = self.now()
        self.mag_received += 1
        t += self.time.offset
        last = self.time.last
        if last is not None and abs(t - last) > MAG_TOLERANCE_S:
            self.mag_dropped += 1
            return
        with self.lock:
            self.mags.append((t, f[0] * 1e6, f[1] * 1e6, f[2] * 1e6))

    def on_temperature(self, msg):
        """
        Remember the latest temperature, °C (sensor_msgs/Temperature, serialised or not).

        :param msg: bytes from a ``raw=True`` subscription, or a sensor_msgs/Temperature.
        """
        head = _body(msg) if isinstance(msg, (bytes, bytearray)) else None
        if head is not None and len(msg) >= head[2] + 8:
            value = _ONE.unpack_from(msg, head[2])[0]
        else:
            if isinstance(msg, (bytes, bytearray)):
                msg = deserialize_message(bytes(msg), Temperature)
            value = msg.temperature
        if math.isfinite(value):
            self.temperature = float(value)

    # -- the node's side (its timer, its services) -----------------------------------------
    def take(self):
        """Return (rows, magnetometer rows) taken in since the last call, and forget them."""
        with self.lock:
            rows, mags = self.rows, self.mags
            self.rows, self.mags = [], []
        return rows, mags

    def pending(self):
        """Return how many rows wait for the node's timer."""
        return len(self.rows)


def subscribe(node, intake, group=None):
    """
    Subscribe ``node`` to the three sensor topics, serialised, into ``intake``.

    :param group: the callback group of the three subscriptions (the node's stream group).
    """
    qos = QoSProfile(depth=QUEUE_DEPTH, history=qos_profile_sensor_data.history,
                     reliability=qos_profile_sensor_data.reliability,
                     durability=qos_profile_sensor_data.durability)
    node.create_subscription(Imu, 'imu/data_raw', intake.on_imu, qos, raw=True,
                             callback_group=group)
    node.create_subscription(Temperature, 'imu/temperature', intake.on_temperature, qos,
                             raw=True, callback_group=group)
    node.create_subscription(MagneticField, 'imu/mag', intake.on_mag, qos, raw=True,
                             callback_group=group)
