"""The guide's pieces without a terminal: hold tracking, drawing, serial input, usage."""

import os
import time

from accel_calib_ros.cli import main
from accel_calib_ros.cli.guide import board_drawing
from accel_calib_ros.cli.guide_session import GuideSession
from accel_calib_ros.cli.guide_sources import SerialSource
from accel_calib_ros.core.advice import CANDIDATE_POSES
from accel_calib_ros.dataio.wire import (encode_frame, encode_frame_v2, encode_info,
                                         encode_info_v2, InfoFrame, MAG_AK8963, ST2_BITM)
from accel_calib_ros.sim.motion import simulate_session
from accel_calib_ros.sim.sensor import mpu9250_like
import numpy as np
import pytest


def test_drawing_names_the_side_up_and_each_axis():
    flat = board_drawing([0, 0, 1])
    assert 'chip side up' in flat and 'z axis ↑ +90° up' in flat
    assert 'upside down' in board_drawing([0, 0, -1])
    edge = board_drawing([1, 1, 0])
    assert '+x +y sides up' in edge and 'tilted 45°' in edge and 'z axis → level' in edge
    corner = board_drawing([-1, 1, 1])
    assert '-x +y +z sides up' in corner and 'x axis ↘ 35° down' in corner
    for direction, _ in CANDIDATE_POSES:
        assert len(board_drawing(direction).splitlines()) >= 8


def test_one_window_per_held_pose_and_the_advice_follows():
    rng = np.random.default_rng(0)
    sensor = mpu9250_like(rng)
    directions = np.array([d for d, _ in CANDIDATE_POSES[:8]])
    session = simulate_session(sensor, directions, rng, hold_s=5.0, move_s=1.5)
    s = session.samples
    guide = GuideSession(100.0, hold_s=2.0)
    names = []
    for k in range(0, len(s.t), 37):            # chunks, as they arrive from a device
        if guide.update(s.t[k:k + 37], s.accel[k:k + 37], s.temp[k:k + 37]):
            names.append(guide.advice.next_pose.name)
    assert len(guide.windows) == 8              # held 5 s each, captured once each
    means = np.array([w.mean for w in guide.windows])
    u = means / np.linalg.norm(means, axis=1, keepdims=True)
    assert np.all(np.einsum('ij,ij->i', u, directions) > np.cos(np.radians(10)))
    assert names[-1] not in [n for _, n in CANDIDATE_POSES[:8]]
    status = guide.status()
    assert status['windows'] == 8 and status['state'] == 'captured'


def read_port(data, want, timeout=8.0):
    """Write ``data`` to a pty read by a SerialSource; return its samples and the source."""
    master, slave = os.openpty()
    try:
        source = SerialSource(os.ttyname(slave), 1000000)
        os.write(master, data)
        got, mags = [np.zeros(0), np.zeros((0, 3)), np.zeros(0)], []
        deadline = time.monotonic() + timeout
        while len(got[0]) < want and time.monotonic() < deadline:
            t, a, temp = source.read(None)
            got = [np.concatenate([got[0], t]), np.vstack([got[1], a]),
                   np.concatenate([got[2], temp])]
            if source.last_mag is not None:
                mags.append(source.last_mag[1])
        source.close()
    finally:
        os.close(master)
        os.close(slave)
    return got, mags, source


def test_serial_source_reads_the_chip_and_ranges_of_the_info_frame():
    info = InfoFrame(0, 0x68, 4, 500, 1000, 1, 1_000_000, (2, 0))   # an MPU-6050 at ±4 g
    counts = [(0, 0, 8192, -333, 0, 0, 0)] * 150 + [(8192, 0, 0, -333, 0, 0, 0)] * 150
    data = b''.join(encode_frame(k, 1000 + 1000 * k, c) for k, c in enumerate(counts))
    bad = 2 * 22 + 9                                         # a data byte of frame 2
    data = encode_info(info) + b'\x00\xa5' + data[:bad] + bytes([data[bad] ^ 0xff]) + \
        data[bad + 1:]
    (t, a, temp), _, source = read_port(data, 290)
    assert len(t) >= 290 and source.info == info    # the damaged frame (and its neighbour)
    np.testing.assert_allclose(a[-1], [9.80665, 0, 0], atol=1e-9)            # ±4 g counts
    np.testing.assert_allclose(temp[-1], -333 / 340.0 + 36.53, atol=1e-9)    # the 6050's
    assert abs(t[-1] - time.time()) < 60         # the device clock mapped to host time:
    periods = np.diff(t) / 1e-3                  # whole periods (2 where a frame was lost)
    np.testing.assert_allclose(periods, np.round(periods), atol=1e-3)
    assert np.all(np.round(periods) >= 1) and np.median(periods) == pytest.approx(1.0, abs=1e-3)


def test_serial_source_gains_the_magnetometer_with_its_adjustment():
    info = InfoFrame(0, 0x71, 2, 250, 1000, 1, 1_000_000, (2, 0), 2, MAG_AK8963,
                     (176, 128, 64))
    block = (100, 200, 300, ST2_BITM)                       # hx, hy, hz in its own axes
    data = encode_info_v2(info) + b''.join(
        encode_frame_v2(k, 1000 * k, (0, 0, 16384, 0, 0, 0, 0), block if k % 10 == 0 else None)
        for k in range(300))
    (t, _, _), mags, _ = read_port(data, 290)
    assert len(t) >= 290 and mags
    # x_acc = y_mag, y_acc = x_mag, z_acc = -z_mag; 0.15 µT a count; (ASA-128)/256+1
    np.testing.assert_allclose(np.vstack(mags)[-1], [200 * 0.15, 100 * 0.15 * 1.1875,
                                                     -300 * 0.15 * 0.75], rtol=1e-9)


def test_the_guide_reads_the_port_through_the_link():
    import inspect
    from accel_calib_ros.cli import guide_sources
    code = inspect.getsource(guide_sources.SerialSource)
    assert 'SerialLink' in code and 'serial.Serial(' not in code


@pytest.mark.parametrize('argv, words', [
    (['--port', '/nonexistent/ttyUSB9'], 'cannot open'),
    (['--simulate', '-o', 'same.yaml', '--record', 'same.yaml'], 'different files'),
    (['--simulate', '--speed', '0'], 'must be positive'),
])
def test_guide_bad_usage_is_one_line_and_exit_2(tmp_path, capsys, monkeypatch, argv, words):
    monkeypatch.chdir(tmp_path)
    assert main(['guide', *argv]) == 2
    err = capsys.readouterr().err
    assert words in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / 'same.yaml').exists()


def test_ros_source_receives_imu_and_temperature_from_topics():
    rclpy = pytest.importorskip('rclpy')
    from accel_calib_ros.cli.guide_sources import RosSource
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import Imu, Temperature
    source = RosSource('guide_test/imu', 'guide_test/temperature')
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    node = rclpy.create_node('guide_test_publisher', context=ctx)
    try:
        imu_pub = node.create_publisher(Imu, 'guide_test/imu', qos_profile_sensor_data)
        temp_pub = node.create_publisher(Temperature, 'guide_test/temperature',
                                         qos_profile_sensor_data)
        got = []
        deadline = time.monotonic() + 20.0
        k = 0
        while len(got) < 20 and time.monotonic() < deadline:
            temp_pub.publish(Temperature(temperature=31.5))
            msg = Imu()
            msg.header.stamp.sec, msg.header.stamp.nanosec = 100 + k // 100, (k % 100) * 10 ** 7
            msg.linear_acceleration.x, msg.linear_acceleration.z = 0.5, 9.8
            imu_pub.publish(msg)             # 20 Hz: real time, never a burst
            k += 1
            t, a, temp = source.read(None)
            got.extend(zip(t, a, temp))
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=ctx)
        source.close()
    assert len(got) >= 20
    t, a, temp = (np.array(v) for v in zip(*got))
    np.testing.assert_allclose(a[-1], [0.5, 0.0, 9.8])
    assert temp[-1] == 31.5 and np.all(np.diff(t) > 0)


@pytest.mark.parametrize('argv, words', [
    (['--simulate', '--seed', '-1'], '--seed'),
    (['--simulate', '--rate', '1e308'], '--rate'),
    (['--simulate', '--speed', '1e308'], '--speed'),
    (['--simulate', '--temp', 'nan'], '--temp'),
    (['--simulate', '--gravity', '1e308'], '--gravity'),
    (['--port', 'same.yaml', '-o', 'same.yaml'], 'destroy the input'),
    (['--port', 'same.yaml', '--record', './same.yaml'], 'destroy the input'),
])
def test_guide_out_of_range_options_are_usage_errors(tmp_path, capsys, monkeypatch,
                                                     argv, words):
    monkeypatch.chdir(tmp_path)
    (tmp_path / 'same.yaml').write_text('keep me\n')
    assert main(['guide', '--timeout', '1', *argv]) == 2
    err = capsys.readouterr().err
    assert words in err and len(err.strip().splitlines()) == 1
    assert (tmp_path / 'same.yaml').read_text() == 'keep me\n'


def test_the_guide_windows_carry_the_rate_and_the_fit_its_bias():
    from accel_calib_ros.sim.sensor import with_gyro_errors
    from accel_calib_ros.sim.motion import random_directions
    rng = np.random.default_rng(3)
    sensor = with_gyro_errors(mpu9250_like(rng), np.random.default_rng(4))
    directions = random_directions(12, rng)
    s = simulate_session(sensor, directions, rng, hold_s=3.0, move_s=1.5).samples
    guide = GuideSession(100.0, hold_s=2.0)
    for k in range(0, len(s.t), 50):
        guide.update(s.t[k:k + 50], s.accel[k:k + 50], s.temp[k:k + 50], s.gyro[k:k + 50])
    assert len(guide.windows) == 12 and all(w.gyro_mean is not None for w in guide.windows)
    from accel_calib_ros.session.settings import DEFAULT_SETTINGS, GUIDE
    outcome = guide.finish(DEFAULT_SETTINGS.replace(words=GUIDE))
    assert outcome.accepted, outcome.refusal
    np.testing.assert_allclose(outcome.calibration.gyro_bias, sensor.gyro_bias, atol=2e-3)


def test_by_default_the_guide_writes_the_files_the_nodes_read(tmp_path, monkeypatch):
    """Regression: it wrote $ROS_HOME/accel_calib_ros/calibration.yaml, which no node reads."""
    from accel_calib_ros.cli import build_parser
    from accel_calib_ros.cli.guide import files
    monkeypatch.setenv('ROS_HOME', str(tmp_path))
    home = tmp_path / 'accel_calib_ros'           # the nodes': <namespace>/<frame_id> folders
    args = build_parser('guide').parse_args(['guide', '--simulate'])
    assert files(args) == (str(home / 'imu_link' / 'calibration.yaml'), None)
    args = build_parser('guide').parse_args(['guide', '--simulate', '--history', '--sensor',
                                             'robot1/imu_link'])
    folder = home / 'robot1' / 'imu_link'
    assert files(args) == (str(folder / 'calibration.yaml'), str(folder / 'history.sqlite'))
    assert args.sensor == 'robot1/imu_link'                 # recorded in the file as well
