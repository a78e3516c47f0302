"""
The driver on a live link: heavy noise, a silent port, then clean frames again.

The real driver node runs in-process on the slave side of a pty; a writer thread plays
the device on the master side in real time. Each frame carries its own number in ``ax``,
so the test knows which of the frames sent were published.
"""

import os
import random
import threading
import time

from accel_calib_ros.dataio.wire import encode_frame, encode_frame_v2
from diagnostic_msgs.msg import DiagnosticArray
import pytest
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu
from test_driver_device_info import Rig

pytestmark = pytest.mark.ros

RATE_HZ = 500
BATCH = 5                               # frames per write: a write every 10 ms
ACCEL_SCALE = 9.80665 / 16384           # ±2 g


class Device(threading.Thread):
    """
    Write frames in real time: ``phases`` is a list of (kind, seconds).

    Kinds: ``clean``; ``noise`` (every byte XORed with a random byte with probability 0.3,
    plus a burst of random bytes per batch); ``silent`` (nothing).

    :param version: frame version, 1 or 2.
    """

    def __init__(self, rig, phases, version):
        super().__init__(daemon=True)
        self.rig, self.phases, self.version = rig, phases, version
        self.sent = {}                  # frame number -> monotonic time it was written
        self.starts = {}                # phase index -> monotonic start time
        self.rng = random.Random(15)
        self.stop = threading.Event()

    def frame(self, k):
        counts = (k % 30000, 0, 16384, 1335, 1, 2, 3)   # ax = frame number
        if self.version == 1:
            return encode_frame(k & 0xFF, 7000 + 2000 * k, counts)
        return encode_frame_v2(k & 0xFFFF, 7000 + 2000 * k, counts)

    def noisy(self, data):
        buf = bytearray(data)
        for i in range(len(buf)):
            if self.rng.random() < 0.3:
                buf[i] ^= self.rng.randrange(1, 256)
        return bytes(buf) + self.rng.randbytes(self.rng.randrange(0, 60))

    def run(self):
        k = 0
        t_next = time.monotonic()
        for index, (kind, seconds) in enumerate(self.phases):
            start = time.monotonic()
            self.starts[index] = start
            while time.monotonic() - start < seconds and not self.stop.is_set():
                data = b''.join(self.frame(k + j) for j in range(BATCH))
                now = time.monotonic()
                if kind == 'clean':
                    for j in range(BATCH):
                        self.sent[k + j] = now
                if kind != 'silent':
                    os.write(self.rig.master, data if kind == 'clean' else self.noisy(data))
                k += BATCH
                t_next += BATCH / RATE_HZ
                time.sleep(max(0.0, t_next - time.monotonic()))


@pytest.fixture
def rig(tmp_path):
    made = Rig(tmp_path)
    yield made
    made.close()


def run_link(rig, phases, version):
    """Play the phases; return (device, {frame number: arrival}, [(time, level, message)])."""
    device = Device(rig, phases, version)
    got = {}
    levels = []

    def on_imu(msg):
        got.setdefault(int(round(msg.linear_acceleration.x / ACCEL_SCALE)), time.monotonic())

    def on_diag(array):
        for status in array.status:
            if status.name.endswith('serial'):
                levels.append((time.monotonic(), status.level, status.message))
    qos = QoSProfile(depth=5000, reliability=ReliabilityPolicy.RELIABLE)
    rig.sub.create_subscription(Imu, 'imu/data_raw', on_imu, qos)
    rig.sub.create_subscription(DiagnosticArray, '/diagnostics', on_diag, 10)
    time.sleep(0.3)                                      # the driver opens the pty
    device.start()
    total = sum(seconds for _, seconds in phases) + 1.5
    rig.spin_until(lambda: False, total)
    device.stop.set()
    device.join(2.0)
    return device, got, levels


@pytest.mark.parametrize('version', [2, 1])
def test_noise_then_clean_frames_publishing_recovers(rig, version):
    """3 s of heavy noise, then clean frames: ≥ 95 % of them published within 2 s."""
    device, got, levels = run_link(rig, [('clean', 1.5), ('noise', 3.0), ('clean', 4.0)],
                                   version)
    noise_start, clean_start = device.starts[1], device.starts[2]
    first = [k for k, t in device.sent.items() if t < noise_start]
    assert sum(k in got for k in first) >= 0.95 * len(first)
    late = [k for k, t in device.sent.items() if clean_start + 2.0 <= t < clean_start + 3.5]
    assert len(late) >= 0.9 * 1.5 * RATE_HZ                # the writer kept its rate
    published = sum(k in got for k in late)
    assert published >= 0.95 * len(late), (published, len(late))
    resumed = min(device.sent[k] for k in got if device.sent.get(k, 0) >= clean_start)
    assert resumed - clean_start < 2.0                      # and it starts much sooner
    print(f'v{version}: publishing resumed with the frame sent {resumed - clean_start:.3f} s '
          f'after the noise; {published} of {len(late)} frames sent 2.0-3.5 s later '
          f'published ({100 * published / len(late):.1f} %)')
    noise = [(lvl, msg) for t, lvl, msg in levels if noise_start + 1.0 <= t < clean_start]
    assert any(lvl == b'\x02' for lvl, _ in noise), noise   # ERROR while nothing valid came
    after = [lvl for t, lvl, _ in levels if clean_start + 1.5 <= t < clean_start + 4.0]
    assert after and after[-1] == b'\x00', levels[-4:]      # OK again once frames flow
    node = rig.node
    assert node.watchdog_reopens >= 1 and node.reader_errors == 0
    assert node.parser.internal_errors == 0
    values = rig.status()[1]
    assert values['frame_version'] == str(version)
    assert int(values['watchdog_reopens']) == node.watchdog_reopens


def test_a_silent_port_is_an_error_and_reopened(rig):
    """The device goes quiet mid-stream: ERROR within a period, the port reopened."""
    device, got, levels = run_link(rig, [('clean', 1.5), ('silent', 3.0), ('clean', 2.5)], 2)
    quiet_start, back = device.starts[1], device.starts[2]
    quiet = [(lvl, msg) for t, lvl, msg in levels if quiet_start + 1.05 <= t < back]
    assert quiet and all(lvl == b'\x02' for lvl, _ in quiet), quiet
    assert any('no valid frame' in msg for _, msg in quiet)
    assert any('reopened' in msg for _, msg in quiet)
    assert rig.node.watchdog_reopens >= 2                    # at 0.5 s, then 2 s later
    late = [k for k, t in device.sent.items() if t >= back + 1.0]
    assert sum(k in got for k in late) >= 0.95 * len(late)
    assert [lvl for t, lvl, _ in levels if back + 1.2 <= t < back + 2.5][-1:] == [b'\x00']
