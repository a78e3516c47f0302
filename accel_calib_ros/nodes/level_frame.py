"""
The level frame's transform: raw frame -> level frame on ``/tf_static``, or the command for it.

While a level trim ``L`` is in force the correction node publishes its corrected messages
in the level frame (``v_level = L · v_raw``). A TF consumer needs the transform between
the two frames: the level frame's pose in the raw frame is the rotation ``Lᵀ`` (no
translation). :class:`LevelFrame` publishes it as a static transform on ``/tf_static``
(``tf2_msgs/TFMessage``, transient local: what ``tf2_ros.StaticTransformBroadcaster``
sends) whenever the trim or the frames change. ``tf2_msgs`` comes with every ROS
install but not as a PyPI wheel: where it cannot be imported, the node says instead the
exact command that publishes the same transform (:func:`static_transform_command`,
Jazzy's argument style), in the answer of ``~/level`` and in ``/diagnostics``.
"""

import math

import numpy as np

TF_STATIC = '/tf_static'
"""The topic of static transforms."""


def euler_zyx(R):
    """
    Return the roll, pitch and yaw (rad) of ``R = Rz(yaw) · Ry(pitch) · Rx(roll)``.

    The convention of tf2's ``setRPY`` and of ``static_transform_publisher``.
    """
    R = np.asarray(R, float)
    pitch = math.asin(max(-1.0, min(1.0, -R[2, 0])))
    return math.atan2(R[2, 1], R[2, 2]), pitch, math.atan2(R[1, 0], R[0, 0])


def quaternion(R):
    """Return the unit quaternion of a rotation matrix ``R``: (x, y, z, w), w >= 0."""
    R = np.asarray(R, float)
    w = math.sqrt(max(0.0, 1.0 + R[0, 0] + R[1, 1] + R[2, 2])) / 2.0
    x = math.sqrt(max(0.0, 1.0 + R[0, 0] - R[1, 1] - R[2, 2])) / 2.0
    y = math.sqrt(max(0.0, 1.0 - R[0, 0] + R[1, 1] - R[2, 2])) / 2.0
    z = math.sqrt(max(0.0, 1.0 - R[0, 0] - R[1, 1] + R[2, 2])) / 2.0
    x = math.copysign(x, R[2, 1] - R[1, 2])
    y = math.copysign(y, R[0, 2] - R[2, 0])
    z = math.copysign(z, R[1, 0] - R[0, 1])
    norm = math.sqrt(x * x + y * y + z * z + w * w)
    return x / norm, y / norm, z / norm, w / norm


def level_pose(L):
    """Return the rotation of the level frame in the raw frame (``Lᵀ``) for a trim ``L``."""
    return np.asarray(L, float).T


def static_transform_command(parent, child, L):
    """
    Return the command that publishes the level frame's static transform (Jazzy style).

    :param parent: the raw frame_id.
    :param child: the level frame_id.
    :param L: the level trim (3, 3), raw -> level.
    """
    roll, pitch, yaw = euler_zyx(level_pose(L))
    return ('ros2 run tf2_ros static_transform_publisher --x 0 --y 0 --z 0 '
            f'--roll {roll:.9f} --pitch {pitch:.9f} --yaw {yaw:.9f} '
            f'--frame-id {parent} --child-frame-id {child}')


def tf_message_type():
    """Return ``tf2_msgs.msg.TFMessage``, or None where tf2_msgs is not installed."""
    try:
        from tf2_msgs.msg import TFMessage
    except ImportError:
        return None
    return TFMessage


class LevelFrame:
    """
    Keeps ``/tf_static`` (or the words for it) in step with the trim in force.

    :param node: the correction node (its clock, its publisher).
    :param message_type: the TFMessage type (default: :func:`tf_message_type`; None:
        tf2_msgs is absent, the command is given instead).
    :param publisher: a publisher to use (a test's; default: one made on ``/tf_static``).
    """

    def __init__(self, node, message_type=None, publisher=None):
        self.node = node
        self.message_type = message_type or tf_message_type()
        self.publisher = publisher
        if self.publisher is None and self.message_type is not None:
            from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
            qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
            self.publisher = node.create_publisher(self.message_type, TF_STATIC, qos)
        self.state = None       # (parent, child, L) last made known, or None
        self.published = 0

    @property
    def publishes(self):
        """Whether the transform goes on ``/tf_static`` (tf2_msgs is there)."""
        return self.publisher is not None

    def update(self, parent, child, L):
        """
        Make the transform of the trim ``L`` known (once per change of trim or frames).

        :param L: the level trim (3, 3), or None without one (nothing to publish).
        :return: None.
        """
        if L is None:
            self.state = None
            return
        state = (parent, child, np.asarray(L, float))
        old = self.state
        if old is not None and old[:2] == state[:2] and np.array_equal(old[2], state[2]):
            return
        self.state = state
        if self.publishes:
            self.publisher.publish(self.message(parent, child, L))
            self.published += 1

    def message(self, parent, child, L):
        """Return the TFMessage of the level frame's transform."""
        from geometry_msgs.msg import TransformStamped
        t = TransformStamped()
        t.header.stamp = self.node.get_clock().now().to_msg()
        t.header.frame_id, t.child_frame_id = parent, child
        q = t.transform.rotation
        q.x, q.y, q.z, q.w = quaternion(level_pose(L))
        return self.message_type(transforms=[t])

    def words(self):
        """Say how the level frame's transform is made known (for ~/level, /diagnostics)."""
        if self.state is None:
            return ''
        parent, child, L = self.state
        if self.publishes:
            return f'{parent} -> {child} published on {TF_STATIC}'
        return (f'tf2_msgs is not installed: nothing publishes {parent} -> {child}; run: '
                + static_transform_command(parent, child, L))
