"""
End-to-end demo on a simulated sensor: ``python -m accel_calib_ros.sim.demo``.

A virtual MPU9250 streams the interface's serial frames on a pseudo-terminal (with a
little byte corruption), and the three nodes run as separate processes on real
rclpy over DDS (a private domain, localhost only):

    device (pty) -> mpu9250_driver -> accel_calibration -> calibration.yaml
                                   -> accel_correction  -> imu/corrected

The device turns the sensor through a scripted sequence of random poses. Once the
calibration node has collected the first ``--poses`` windows, the demo calls
``~/calibrate``; the remaining poses were never seen by the calibration, and the
demo compares raw and corrected acceleration there with the truth (the simulated
sensor's own parameters), before and after; then the angular rate (the device's
gyroscope has scale and misalignment errors, which the calibration node fits from the
moves between the windows), and the magnetic field when ``imu/mag`` is published (the
driver does so from frame version 2's magnetometer block; with version-1 frames the
demo says it is absent).

With ``--board`` (``make demo-board``) the frames come from the real firmware instead:
its ELF runs on an emulated Arduino Uno (simavr) with an emulated MPU-9250 whose
registers replay the same kind of simulated session at 1 kHz, over a pty at 1 MBd:

    emulated MPU-9250 -> firmware on emulated Uno (pty) -> mpu9250_driver -> ...

This needs a source checkout (the board is a GPL-3 test program under test/firmware/hil/, never
installed) and the Debian packages of docs/firmware.md (installed when missing, as root).
"""

import argparse
import json
import os
import random
import signal
import subprocess
import sys
import tempfile
import time

import numpy as np
import yaml

from ..core.constants import G0


def _env():
    env = dict(os.environ)
    env.setdefault('ROS_DOMAIN_ID', str(random.randint(120, 200)))
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    os.environ.update({k: env[k] for k in ('ROS_DOMAIN_ID', 'ROS_AUTOMATIC_DISCOVERY_RANGE')})
    return env


def _start(args, log_path, env):
    log = open(log_path, 'w')
    return subprocess.Popen([sys.executable, '-m'] + args, stdout=log, stderr=subprocess.STDOUT,
                            env=env, start_new_session=True)


def _stop(proc):
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def _wait_for(path, timeout):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if os.path.exists(path):
            return True
        time.sleep(0.05)
    return False


class _Client:
    """In-process observer: status, raw and corrected streams, the calibrate service."""

    def __init__(self):
        import rclpy
        from rclpy.qos import qos_profile_sensor_data, QoSDurabilityPolicy, QoSProfile
        from sensor_msgs.msg import Imu
        from std_msgs.msg import String
        from std_srvs.srv import Trigger
        self.rclpy = rclpy
        self.context = rclpy.context.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node('accel_calib_demo', context=self.context)
        self.executor = rclpy.executors.SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        from sensor_msgs.msg import MagneticField
        self.status = {}
        self.raw, self.corrected = {}, {}
        self.raw_rate, self.corrected_rate = {}, {}
        self.raw_mag, self.corrected_mag = {}, {}
        self.collect = False
        latched = QoSProfile(depth=1, durability=QoSDurabilityPolicy.TRANSIENT_LOCAL)
        self.node.create_subscription(String, 'accel_calibration/status', self._on_status,
                                      latched)
        self.node.create_subscription(Imu, 'imu/data_raw', self._on_raw, qos_profile_sensor_data)
        self.node.create_subscription(Imu, 'imu/corrected', self._on_corrected,
                                      qos_profile_sensor_data)
        self.node.create_subscription(MagneticField, 'imu/mag', self._on_raw_mag,
                                      qos_profile_sensor_data)
        self.node.create_subscription(MagneticField, 'imu/mag_corrected',
                                      self._on_corrected_mag, qos_profile_sensor_data)
        self.calibrate = self.node.create_client(Trigger, 'accel_calibration/calibrate')
        self.Trigger = Trigger

    @staticmethod
    def _key(msg):
        return (msg.header.stamp.sec, msg.header.stamp.nanosec)

    @staticmethod
    def _vec(msg):
        a = msg.linear_acceleration
        return (a.x, a.y, a.z)

    def _on_status(self, msg):
        try:
            self.status = json.loads(msg.data)
        except ValueError:
            pass

    @staticmethod
    def _rate(msg):
        w = msg.angular_velocity
        return (w.x, w.y, w.z)

    @staticmethod
    def _field(msg):
        f = msg.magnetic_field
        return (f.x * 1e6, f.y * 1e6, f.z * 1e6)       # tesla -> µT

    def _on_raw(self, msg):
        if self.collect:
            self.raw[self._key(msg)] = self._vec(msg)
            self.raw_rate[self._key(msg)] = self._rate(msg)

    def _on_corrected(self, msg):
        if self.collect:
            self.corrected[self._key(msg)] = self._vec(msg)
            self.corrected_rate[self._key(msg)] = self._rate(msg)

    def _on_raw_mag(self, msg):
        if self.collect:
            self.raw_mag[self._key(msg)] = self._field(msg)

    def _on_corrected_mag(self, msg):
        if self.collect:
            self.corrected_mag[self._key(msg)] = self._field(msg)

    def spin(self, seconds):
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.05)

    def call_calibrate(self, timeout=60.0):
        if not self.calibrate.wait_for_service(timeout_sec=10.0):
            return None
        future = self.calibrate.call_async(self.Trigger.Request())
        self.executor.spin_until_future_complete(future, timeout_sec=timeout)
        return future.result()

    def close(self):
        self.node.destroy_node()
        self.rclpy.try_shutdown(context=self.context)


def _board_source(args, work, env, truth_path):
    """
    Build firmware and board, write the session's register values; return the board command.

    :raises RuntimeError: not a source checkout, or the toolchain is missing (one line).
    """
    from .device import _write_truth, add_arguments, VirtualSensor
    from ..dataio.wire.conversion import MagConverter
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    harness_src = os.path.join(root, 'test', 'firmware', 'hil', 'mpu_board.c')
    firmware = os.path.join(root, 'firmware')
    if not os.path.exists(harness_src) or not os.path.exists(os.path.join(firmware, 'Makefile')):
        raise RuntimeError('--board needs a source checkout (firmware/ and test/firmware/hil/)')
    for cmd, what in ((['sh', os.path.join(firmware, 'tools', 'ensure-toolchain.sh'), 'hil'],
                       'toolchain'), (['make', '-s', '-C', firmware], 'make firmware')):
        run = subprocess.run(cmd, capture_output=True, text=True)
        if run.returncode:
            lines = (run.stderr or run.stdout).strip().splitlines()
            raise RuntimeError(f'{what}: {lines[-1] if lines else "failed"}')
    board = os.path.join(work, 'mpu_board')
    flags = subprocess.run(['pkg-config', '--cflags', '--libs', 'simavr'], capture_output=True,
                           text=True).stdout.split() or ['-lsimavr']
    run = subprocess.run(['cc', '-O2', '-o', board, harness_src] + flags + ['-lelf'],
                         capture_output=True, text=True)
    if run.returncode:
        raise RuntimeError('cannot compile the emulated board: ' + run.stderr.strip()[-300:])
    total = args.poses + args.fresh
    dev = add_arguments(argparse.ArgumentParser()).parse_args(
        ['--poses', 'random', '--count', str(total), '--hold', str(args.hold), '--move',
         str(args.move), '--rate', '1000', '--seed', str(args.seed), '--gyro-errors',
         '--magnetometer'])
    sensor = VirtualSensor(dev)
    _write_truth(truth_path, sensor.truth())
    n = int(total * (args.hold + args.move) * 1000) + 120_000     # script, then 2 min held
    samples, fields = os.path.join(work, 'registers.bin'), os.path.join(work, 'ak8963.bin')
    sensor.counts(n, 0.0).astype('<i2').tofile(samples)
    # The AK8963 measures every 10 ms: the field of every 10th row, in its own axes and
    # counts (neutral factory adjustment, as the board is told with --asa).
    to_counts = MagConverter((128, 128, 128)).to_counts
    rows = [to_counts(row * 1e-6)[:3] if np.all(np.isfinite(row)) else (0, 0, 0)
            for row in sensor.last_mag[::10]]
    np.asarray(rows, '<i2').tofile(fields)
    return [board, '--elf', os.path.join(firmware, 'build', 'accel_calib_fw.elf'),
            '--link', os.path.join(work, 'imu0'), '--samples', samples, '--mag-samples',
            fields, '--asa', '128,128,128', '--seconds', '3600', '--wait-open', '120']


def run_ros_demo(args):
    """Run the three nodes on the simulated sensor; return the exit status."""
    env = _env()
    work = args.workdir or tempfile.mkdtemp(prefix='accel_calib_demo_')
    os.makedirs(work, exist_ok=True)
    link = os.path.join(work, 'imu0')
    truth_path = os.path.join(work, 'truth.yaml')
    calib_path = os.path.join(work, 'calibration.yaml')
    total = args.poses + args.fresh
    print(f'accel_calib_ros demo: ROS_DOMAIN_ID={env["ROS_DOMAIN_ID"]}, files in {work}')
    procs = []
    client = None
    try:
        if args.board:
            try:
                cmd = _board_source(args, work, env, truth_path)
            except RuntimeError as err:
                print(f'demo --board: {err}', file=sys.stderr)
                return 2
            print('firmware ELF on an emulated Uno + emulated MPU-9250 (simavr), 1 kHz, 1 MBd')
            log = open(os.path.join(work, 'board.log'), 'w')
            procs.append(subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=env,
                                          start_new_session=True))
        else:
            procs.append(_start(['accel_calib_ros.sim.device', '--link', link, '--poses', 'random',
                                 '--count', str(total), '--hold', str(args.hold), '--move',
                                 str(args.move), '--rate', str(args.rate), '--seed',
                                 str(args.seed), '--truth-out', truth_path, '--corrupt',
                                 str(args.corrupt), '--gyro-errors', '--magnetometer'],
                                os.path.join(work, 'device.log'), env))
        if not _wait_for(link, 20) or not _wait_for(truth_path, 20):
            print('demo: the simulated device did not start; see device.log', file=sys.stderr)
            return 1
        ros = ['--ros-args', '-p']
        procs.append(_start(['accel_calib_ros.nodes.driver'] + ros + [f'port:={link}'],
                            os.path.join(work, 'driver.log'), env))
        procs.append(_start(['accel_calib_ros.nodes.calibration'] + ros +
                            [f'calibration_file:={calib_path}', '-p', f'method:={args.method}',
                             '-p', f'field_uT:={FIELD_UT}'],
                            os.path.join(work, 'calibration.log'), env))
        procs.append(_start(['accel_calib_ros.nodes.correction'] + ros +
                            [f'calibration_file:={calib_path}'],
                            os.path.join(work, 'correction.log'), env))
        client = _Client()
        print(f'turning the virtual sensor through {args.poses} calibration poses '
              f'({args.hold:g} s hold, {args.move:g} s move)...')
        shown = -1
        deadline = time.monotonic() + args.poses * (args.hold + args.move) * 2 + 60
        while client.status.get('windows', 0) < args.poses:
            client.spin(0.2)
            windows = client.status.get('windows', 0)
            if windows != shown and windows:
                shown = windows
                print(f'  windows {windows:3d}/{args.poses}  ' + _advice_line(client.status))
            if time.monotonic() > deadline or any(p.poll() is not None for p in procs):
                print('demo: no progress; see the logs in ' + work, file=sys.stderr)
                return 1
        client.collect = True
        response = client.call_calibrate()
        if response is None:
            print('demo: ~/calibrate did not answer', file=sys.stderr)
            return 1
        print(f'~/calibrate -> success={response.success}: {response.message}')
        if not response.success:
            return 1
        client.spin(1.5)             # the correction node takes the new file up within 1 s
        for store in (client.raw, client.corrected, client.raw_rate, client.corrected_rate,
                      client.raw_mag, client.corrected_mag):
            store.clear()
        print(f'holding {args.fresh} fresh poses the calibration never saw...')
        client.spin(args.fresh * (args.hold + args.move) + 1.0)
        return _report(client, truth_path)
    finally:
        if client is not None:
            client.close()
        for proc in reversed(procs):
            _stop(proc)


def _report(client, truth_path):
    with open(truth_path) as f:
        truth = yaml.safe_load(f)
    T = np.asarray(truth['T'], float)
    bias = np.asarray(truth['bias_m_s2'] if 'bias_m_s2' in truth else truth['bias'], float)
    keys = sorted(set(client.raw) & set(client.corrected))
    if len(keys) < 100:
        print(f'demo: only {len(keys)} corrected samples arrived', file=sys.stderr)
        return 1
    raw = np.array([client.raw[k] for k in keys])
    corrected = np.array([client.corrected[k] for k in keys])
    true = np.linalg.solve(T, (raw - bias).T).T      # the simulated sensor's own inverse
    before = np.linalg.norm(raw - true, axis=1)
    after = np.linalg.norm(corrected - true, axis=1)
    print(f'\nerror against the truth over {len(keys)} samples at fresh poses (m/s²):')
    print(f'  raw        RMS {np.sqrt(np.mean(before ** 2)):.4f}   max {before.max():.4f}')
    print(f'  corrected  RMS {np.sqrt(np.mean(after ** 2)):.4f}   max {after.max():.4f}')
    _report_rates(client, truth, keys)
    _report_field(client, truth)
    return 0


def _rms(v):
    return float(np.sqrt(np.mean(np.sum(np.asarray(v) ** 2, axis=1))))


def _report_rates(client, truth, keys):
    """Raw and corrected angular rate against the truth (the simulated gyro's inverse)."""
    T = np.asarray(truth.get('gyro_T', np.eye(3)), float)
    bias = np.asarray(truth.get('gyro_bias_rad_s', np.zeros(3)), float)
    raw = np.array([client.raw_rate[k] for k in keys])
    corrected = np.array([client.corrected_rate[k] for k in keys])
    true = np.linalg.solve(T, (raw - bias).T).T
    print(f'  gyroscope over the same samples (rad/s, turns between the poses included; true '
          f'rate RMS {_rms(true):.4f}):')
    print(f'    raw        RMS {_rms(raw - true):.5f}')
    print(f'    corrected  RMS {_rms(corrected - true):.5f}')


def _report_field(client, truth):
    """Raw and corrected magnetic field against the truth, when imu/mag was published."""
    keys = sorted(set(client.raw_mag) & set(client.corrected_mag))
    if not client.raw_mag:
        print('  magnetometer: imu/mag is absent (the driver publishes it from frame version '
              "2's magnetometer block)")
        return
    if not keys or 'magnetometer' not in truth:
        print(f'  magnetometer: {len(client.raw_mag)} imu/mag samples but '
              + ('no imu/mag_corrected (no magnetometer calibration)' if not keys
                 else 'no magnetometer truth'))
        return
    m = truth['magnetometer']
    T, R, h = (np.asarray(m[k], float) for k in ('T', 'R', 'hard_iron_uT'))
    raw = np.array([client.raw_mag[k] for k in keys])
    corrected = np.array([client.corrected_mag[k] for k in keys])
    true = np.linalg.solve(T, (raw - h).T).T @ R      # the simulated magnetometer's inverse
    print(f'  magnetometer over {len(keys)} samples (µT; field {FIELD_UT:g} µT given to the '
          'calibration node):')
    print(f'    raw        RMS {_rms(raw - true):.3f}')
    print(f'    corrected  RMS {_rms(corrected - true):.3f}')


def run_offline_demo(args):
    """Without ROS: simulate a session, fit all three sensors, show the correction."""
    from .motion import random_directions, random_poses, simulate_session
    from .sensor import ak8963_like, EarthField, mpu9250_like, with_gyro_errors
    from ..core.accelerometer.fit import calibrate
    from ..core.outcomes import solve_gyro, solve_magnetometer
    from ..core.windows import detect_static_windows
    rng = np.random.default_rng(args.seed)
    sensor = mpu9250_like(rng)
    sensor = with_gyro_errors(sensor, np.random.default_rng([args.seed, 19, 1]))
    sensor.magnetometer = ak8963_like(np.random.default_rng([args.seed, 19, 2]))
    earth = EarthField(FIELD_UT, 60.0)
    session = simulate_session(sensor, random_poses(args.poses, rng), rng, hold_s=args.hold,
                               move_s=args.move, earth_field=earth, tremor_deg=0.3)
    windows = detect_static_windows(session.samples)
    fresh = G0 * random_directions(200, rng)
    raw = sensor.distort(fresh)
    print(f'simulated {args.poses} hand-held poses (accelerometer, gyroscope with scale and '
          f'misalignment errors, AK8963-like magnetometer), {len(windows)} static windows found')
    print('error against the truth at 200 fresh directions the calibration never saw:')
    print(f'accelerometer raw error RMS {_rms(raw - fresh):.4f} m/s² (at 1 g)')
    cal = None
    for method in ('gn', 'ml'):
        cal = calibrate(windows.mean, method=method, weights=windows.weights(5.0, 100.0),
                        noise_std=windows.noise_std)
        print(f'accelerometer {method}: corrected error RMS '
              f'{_rms(cal.correct(raw) - fresh):.4f} m/s² ({cal.iterations} iterations)')
    gyro = solve_gyro(session.samples, windows, cal)
    rates = random_directions(200, rng)                     # 1 rad/s in every direction
    raw_rate = rates @ sensor.gyro_T.T + sensor.gyro_bias
    print(f'gyroscope raw error RMS {_rms(raw_rate - rates):.4f} rad/s at 1 rad/s '
          f'(bias {np.linalg.norm(sensor.gyro_bias):.4f} rad/s)')
    if gyro.calibrated:
        print(f'gyroscope corrected error RMS {_rms(gyro.result.correct(raw_rate) - rates):.4f} '
              f'rad/s (predicted {gyro.predicted_accuracy:.5f} of the rate, '
              f'{gyro.result.moves_used} moves)')
    else:
        print(f'gyroscope not calibrated: {gyro.reason}')
    mag = solve_magnetometer(session.samples, windows, cal, field_uT=FIELD_UT)
    field = FIELD_UT * random_directions(200, rng)
    raw_field = sensor.magnetometer.distort(field)
    print(f'magnetometer raw error RMS {_rms(raw_field - field):.3f} µT in a {FIELD_UT:g} µT '
          'field')
    if mag.calibrated:
        print(f'magnetometer corrected error RMS {_rms(mag.result.correct(raw_field) - field):.3f}'
              f' µT (predicted {mag.predicted_accuracy:.3f} µT; field magnitude given, as from '
              'a geomagnetic model)')
    else:
        print(f'magnetometer not calibrated: {mag.reason}')
    return 0


FIELD_UT = 48.0
"""Magnitude of the simulated Earth field, µT (given to the magnetometer fit, as a user
would from a geomagnetic model: the fit cannot tell it from the sensor's own scale)."""


def _advice_line(status):
    """Return the calibration node's advice in words: accuracy now and the pose to hold."""
    acc = status.get('predicted_accuracy')
    now = 'predicted accuracy ' + ('not yet (too few poses)' if acc is None
                                   else f'{acc:.4f} m/s²')
    pose = status.get('next_pose')
    if isinstance(pose, dict):
        pose = pose.get('name')
    if status.get('enough') or pose == 'enough':
        return now + ': enough'
    return f'{now}; next: hold {pose}' if pose else now


def main(argv=None):
    """Run the demo; the ROS one when rclpy is importable, else the offline one."""
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('--poses', type=int, default=24, help='calibration poses')
    parser.add_argument('--fresh', type=int, default=4, help='fresh poses for the check')
    parser.add_argument('--hold', type=float, default=2.2, help='seconds per pose')
    parser.add_argument('--move', type=float, default=0.8, help='seconds per move')
    parser.add_argument('--rate', type=float, default=200.0, help='sensor rate, Hz')
    parser.add_argument('--corrupt', type=float, default=0.01, help='byte corruption rate')
    parser.add_argument('--method', default='ml', choices=('ml', 'gn', 'ml-bc'))
    parser.add_argument('--seed', type=int, default=7)
    parser.add_argument('--workdir', help='keep logs and files here')
    parser.add_argument('--offline', action='store_true', help='no ROS: core only')
    parser.add_argument('--board', action='store_true',
                        help='frames from the real firmware on an emulated Uno + MPU-9250 '
                             '(simavr; source checkout, see docs/firmware.md)')
    args = parser.parse_args(argv)
    if not args.offline:
        try:
            import rclpy  # noqa: F401
        except ImportError:
            print('rclpy is not importable: running the offline demo instead')
            args.offline = True
    return run_offline_demo(args) if args.offline else run_ros_demo(args)


if __name__ == '__main__':
    sys.exit(main())
