"""
The calibration node keeps up while it calibrates, on real rclpy over DDS.

The node runs as ``main()`` runs it: its stream group on one executor and thread, the node
itself (parameters, services, timers) on another. It is handed a long three-sensor session
at 1 kHz through its callbacks (fast, serialised messages as DDS delivers them), then a
peer in its own context streams the rest of the session in real time while it asks for
``get_parameters`` every 20 ms and calls ``~/calibrate`` twice. Checked: every sample of
normal use taken in (>= 99.9 %), >= 97 % around the call, the parameters answered within
100 ms meanwhile, the second call refused at once with the reason, and the first one
answered with all three sensors. (bench/bench_calibration_node.py prints the figures
against the node as its own process.)
"""

import struct
import threading
import time

from accel_calib_ros.nodes.calibration import CalibrationNode
from accel_calib_ros.nodes.common import GroupExecutor
from accel_calib_ros.sim import sensor as sim
from accel_calib_ros.sim.motion import random_poses, simulate_session
import numpy as np
import pytest
from rcl_interfaces.srv import GetParameters
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from sensor_msgs.msg import Imu, MagneticField
from std_srvs.srv import Trigger

pytestmark = pytest.mark.ros

RATE_HZ = 1000.0
LIVE_S = 9.0
"""Seconds of the session streamed in real time (the rest is handed in through callbacks)."""


def serialised(samples, t0=1000.0):
    """Return [(t s, 0 for Imu / 1 for MagneticField, bytes)]: rclpy's CDR, values patched in."""
    imu = Imu()
    imu.header.frame_id = 'imu_link'
    imu.orientation_covariance[0] = -1.0
    templates = [serialize_message(imu), serialize_message(MagneticField(header=imu.header))]
    first = 28                          # the first double after a header with 'imu_link'
    out = []
    mag_rows = samples.mag_rows         # (a property: computed once here)
    for k, t in enumerate(samples.t.tolist()):
        stamp = t0 + t
        head = struct.pack('<iI', int(stamp), int(round((stamp % 1.0) * 1e9)) % 10 ** 9)
        b = bytearray(templates[0])
        b[4:12] = head
        struct.pack_into('<3d', b, first + 104, *samples.gyro[k].tolist())
        struct.pack_into('<3d', b, first + 200, *samples.accel[k].tolist())
        out.append((t, 0, bytes(b)))
        if mag_rows[k]:
            b = bytearray(templates[1])
            b[4:12] = head
            struct.pack_into('<3d', b, first, *(samples.mag[k] * 1e-6).tolist())
            out.append((t, 1, bytes(b)))
    return out


@pytest.fixture(scope='module')
def messages():
    """Simulate a 1 kHz whole-IMU session of 24 poses (about 70 s), serialised."""
    rng = np.random.default_rng(31)
    sensor = sim.with_gyro_errors(sim.mpu9250_like(rng, RATE_HZ), np.random.default_rng(32))
    sensor.magnetometer = sim.ak8963_like(np.random.default_rng(33))
    s = simulate_session(sensor, random_poses(24, rng), rng, hold_s=2.0, move_s=0.8,
                         rate_hz=RATE_HZ, tremor_deg=0.2).samples
    return serialised(s), float(s.t[-1])


class Spun:
    """The node spun as main() spins it: its stream group and the rest each on a thread."""

    def __init__(self, node):
        self.executors = []
        self.threads = []
        for inside in (True, False):
            executor = GroupExecutor(node.stream_group, inside, context=node.context)
            if inside:
                executor.share_node(node)
            else:
                executor.add_node(node)
            thread = threading.Thread(target=self._spin, args=(executor,), daemon=True)
            self.executors.append(executor)
            self.threads.append(thread)
            thread.start()

    @staticmethod
    def _spin(executor):
        """Spin until the executor is shut down."""
        try:
            executor.spin()
        except Exception:                       # noqa: B902 - the context went down
            pass

    def stop(self):
        for executor in self.executors:
            executor.shutdown(timeout_sec=2.0)
        for thread in self.threads:
            thread.join(timeout=5.0)


class Peer:
    """A peer in its own context: the live stream, the two clients, the latencies."""

    def __init__(self):
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node('responsive_peer', context=self.context)
        qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)   # the driver's
        self.pubs = [self.node.create_publisher(Imu, 'imu/data_raw', qos),
                     self.node.create_publisher(MagneticField, 'imu/mag', qos)]
        self.calibrate = self.node.create_client(Trigger, 'accel_calibration/calibrate')
        self.params = self.node.create_client(GetParameters,
                                              'accel_calibration/get_parameters')
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.published = []                     # (monotonic, Imu messages so far)
        self.asked, self.latencies = {}, []

    def spin(self, seconds=0.0, until=None):
        end = time.monotonic() + seconds
        while time.monotonic() < end or (until is not None and not until()):
            self.executor.spin_once(timeout_sec=0.005)
            now = time.monotonic()
            for future in [f for f in self.asked if f.done()]:
                self.latencies.append(now - self.asked.pop(future))
            if until is not None and now > end + 120.0:
                break

    def ask_parameters(self):
        self.asked[self.params.call_async(GetParameters.Request(names=['method']))] = \
            time.monotonic()

    def stream(self, messages, start):
        """Publish each message when its time comes (a thread)."""
        n = 0
        t_first = messages[0][0]
        for t, topic, data in messages:
            delay = start + (t - t_first) - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            self.pubs[topic].publish(data)
            if topic == 0:
                n += 1
                self.published.append((time.monotonic(), n))

    def published_by(self, when):
        done = [n for t, n in self.published if t <= when]
        return done[-1] if done else 0

    def close(self):
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def test_samples_and_parameters_are_served_while_a_long_session_calibrates(tmp_path, messages):
    messages, t_end = messages
    split = t_end - LIVE_S
    handed = [m for m in messages if m[0] < split]
    live = [m for m in messages if m[0] >= split]
    context = rclpy.Context()
    rclpy.init(context=context)
    node = CalibrationNode(context=context, parameter_overrides=[
        Parameter('calibration_file', value=str(tmp_path / 'calibration.yaml'))])
    callbacks = (node.on_imu, node.on_mag)
    for _, topic, data in handed:               # as DDS delivers them: serialised
        callbacks[topic](data)
    node.process_pending()
    before = len(node.windows)
    spun, peer = Spun(node), Peer()
    try:
        peer.spin(until=lambda: peer.calibrate.service_is_ready()
                  and peer.params.service_is_ready()
                  and peer.pubs[0].get_subscription_count() > 0)
        peer.spin(0.5)
        received0 = node.intake.received
        start = time.monotonic() + 0.2
        feeder = threading.Thread(target=peer.stream, args=(live, start), daemon=True)
        feeder.start()
        timer = peer.node.create_timer(0.02, peer.ask_parameters)
        peer.spin(LIVE_S - 4.0)
        now = time.monotonic()          # (what was published 50 ms ago has arrived by now)
        normal = (node.intake.received - received0, peer.published_by(now - 0.05))
        normal_latency = max(peer.latencies)

        mark = (time.monotonic(), node.intake.received)
        first = peer.calibrate.call_async(Trigger.Request())
        peer.spin(0.05)
        second = peer.calibrate.call_async(Trigger.Request())
        asked = time.monotonic()
        peer.spin(until=second.done)
        refused_in = time.monotonic() - asked
        peer.latencies.clear()
        peer.spin(until=first.done)
        peer.spin(1.0)
        calling = max(peer.latencies) if peer.latencies else float('inf')
        # A request still out counts when it has waited longer than the bound (one asked
        # in the last few milliseconds has not had its chance to be answered yet).
        unanswered = sum(time.monotonic() - t > 0.1 for t in peer.asked.values())
        around = (node.intake.received - mark[1],
                  peer.published_by(time.monotonic()) - peer.published_by(mark[0]))
        peer.node.destroy_timer(timer)
        feeder.join(timeout=LIVE_S + 10.0)
        peer.spin(0.5)
        total = (node.intake.received - received0, peer.published[-1][1])
    finally:
        spun.stop()
        peer.close()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
    print(f'windows handed in {before}; intake normal {normal}, around the call {around}, '
          f'whole live stream {total}; parameters: {normal_latency * 1e3:.1f} ms max in '
          f'normal use, {calling * 1e3:.1f} ms max during the call; second call answered '
          f'in {refused_in:.3f} s')
    response = first.result()
    assert response.success, response.message
    assert 'gyroscope: calibrated' in response.message
    assert 'magnetometer: calibrated' in response.message
    refusal = second.result()
    assert not refusal.success and 'already running' in refusal.message
    assert refused_in < 0.5
    assert calling < 0.1 and unanswered == 0
    assert normal[0] >= 0.999 * normal[1] and normal[1] > 4000
    assert around[0] >= 0.97 * around[1]
    assert total[0] >= 0.999 * total[1]
