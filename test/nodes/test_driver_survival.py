"""
The driver never goes mute: failed publishes are counted and survived.

Regression: one ``publish()`` that raised (Fast DDS's transient "cannot publish data")
set the stop flag, the reader thread ended for good and ``/diagnostics`` said
``not connected: `` with an empty reason.
"""

import time

from accel_calib_ros.dataio.wire import encode_frame_v2, encode_info_v2, InfoFrame
import pytest
from test_driver_device_info import Rig

pytestmark = pytest.mark.ros

INFO = InfoFrame(0, 0x71, 2, 250, 1000, 1, 1_000_000, (2, 0), 2, 0, info_version=2)


@pytest.fixture
def rig(tmp_path):
    made = Rig(tmp_path)
    yield made
    made.close()


def frames(start, n):
    return b''.join(encode_frame_v2(k, 1000 * k, (k % 30000, 0, 16384, 1335, 0, 0, 0))
                    for k in range(start, start + n))


def test_failed_publishes_are_counted_logged_and_survived(rig):
    node = rig.node
    real_imu, real_temp = node.imu_pub.publish, node.temp_pub.publish
    failures = []

    def flaky(real):
        def publish(msg):
            if len(failures) < 40 and (len(failures) < 5 or msg.header.stamp.nanosec % 7 == 0):
                failures.append(msg)
                raise RuntimeError('failed to publish: cannot publish data')
            return real(msg)
        return publish
    node.imu_pub.publish = flaky(real_imu)
    node.temp_pub.publish = flaky(real_temp)
    time.sleep(0.3)
    rig.write(encode_info_v2(INFO))
    for k in range(0, 1000, 50):                      # 1 s of samples, in real time
        rig.write(frames(k, 50))
        rig.spin_until(lambda: False, 0.05)

    def imu_failed():
        return sum(1 for m in failures if hasattr(m, 'linear_acceleration'))
    assert rig.spin_until(lambda: node.published + imu_failed() >= 999 and
                          len(rig.imu) == node.published, 10)
    assert node.publish_errors == len(failures) >= 5
    assert not node.link.stopped and node.link.reader_errors == 0

    def reported():
        status, values = rig.status()
        return values is not None and int(values['publish_errors']) == len(failures)
    assert rig.spin_until(reported, 5)
    # The publisher heals: every later sample is published, and the report says OK again.
    node.imu_pub.publish, node.temp_pub.publish = real_imu, real_temp
    before = len(rig.imu)
    for k in range(1000, 3000, 50):
        rig.write(frames(k, 50))
        rig.spin_until(lambda: False, 0.05)
    assert rig.spin_until(lambda: len(rig.imu) - before >= 2000, 10)
    assert rig.spin_until(lambda: rig.status()[0] is not None and
                          rig.status()[0].message == 'streaming', 5)


def test_the_report_names_why_it_is_not_connected(rig):
    """No port: the message carries the reason, never an empty one."""
    node = rig.node
    node.link.reopen(port='/nonexistent/tty')
    assert rig.spin_until(lambda: rig.status()[0] is not None and
                          'not connected' in rig.status()[0].message, 5)
    status, _ = rig.status()
    assert status.level == b'\x02' and 'No such file' in status.message
