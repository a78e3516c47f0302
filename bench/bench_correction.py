"""
Benchmark: the accel_correction node against a bare rclpy relay, side by side.

One publisher process sends ``sensor_msgs/Imu`` on ``imu/data_raw`` at ``--rate`` Hz
(header stamp = publish time). Two consumers run as separate processes on the same
input: the correction node (``imu/corrected``) and a bare relay that only subscribes
and republishes (``bench/relay``), both with the same QoS (best-effort input, reliable
output, depth 100). This process subscribes to both outputs and measures delivery
(received / published), latency (receive time - stamp) percentiles and the resident
memory of both consumers (VmRSS at the end of the input), their CPU time while the
input streams (user + system, /proc), and prints the ratios
the targets (RSS <= 1.2x the relay, p50 latency <= the relay's, 100 % delivered)::

    python bench/bench_correction.py [--rate 1000] [--duration 10]
"""

import argparse
import os
import random
import signal
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.abspath(__file__)


def _qos():
    from rclpy.qos import qos_profile_sensor_data, QoSProfile, ReliabilityPolicy
    sub = QoSProfile(depth=100, history=qos_profile_sensor_data.history,
                     reliability=qos_profile_sensor_data.reliability,
                     durability=qos_profile_sensor_data.durability)
    pub = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
    return sub, pub


def run_relay(topic='bench/relay'):
    """Subscribe to imu/data_raw and republish each message unchanged on ``topic``."""
    import rclpy
    from rclpy.executors import ExternalShutdownException
    from sensor_msgs.msg import Imu
    rclpy.init()
    node = rclpy.create_node('bench_relay' if topic == 'bench/relay' else 'bench_control')
    sub_qos, pub_qos = _qos()
    pub = node.create_publisher(Imu, topic, pub_qos)
    node.create_subscription(Imu, 'imu/data_raw', pub.publish, sub_qos)
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


def run_publisher(rate, duration, consumers):
    """Publish Imu messages at ``rate`` Hz for ``duration`` s; print the count sent."""
    import rclpy
    from sensor_msgs.msg import Imu
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    rclpy.init()
    node = rclpy.create_node('bench_publisher')
    pub = node.create_publisher(Imu, 'imu/data_raw',
                                QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
    end = time.monotonic() + 20.0
    while pub.get_subscription_count() < consumers and time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.05)
    time.sleep(1.0)
    msg = Imu()
    msg.header.frame_id = 'imu_link'
    msg.orientation_covariance[0] = -1.0
    msg.linear_acceleration.z = 9.81
    n = int(rate * duration)
    t0 = time.monotonic()
    for i in range(n):
        due = t0 + i / rate
        delay = due - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        now = time.time_ns()
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(now, 1_000_000_000)
        msg.linear_acceleration.x = 0.001 * (i % 100)
        pub.publish(msg)
    achieved = n / (time.monotonic() - t0)
    print(f'{n} {achieved:.1f}', flush=True)
    time.sleep(0.5)
    node.destroy_node()
    rclpy.try_shutdown()


def write_calibration(path):
    """Write a plausible calibration file for the correction node to apply."""
    from accel_calib_ros.core.accelerometer.fit import Calibration
    from accel_calib_ros.dataio.calibration_file import save_calibration
    T = np.array([[1.02, 0.01, -0.005], [0.0, 0.98, 0.012], [0.0, 0.0, 1.01]])
    save_calibration(Calibration(T=T, bias=[0.2, -0.1, 0.3], covariance=np.eye(9) * 1e-7,
                                 noise_std=np.full(3, 0.03)), path)


def rss_mib(pid):
    """Resident memory of a process, MiB (None when it is gone)."""
    try:
        with open(f'/proc/{pid}/status', encoding='ascii') as f:
            for line in f:
                if line.startswith('VmRSS:'):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        return None
    return None


def cpu_seconds(pid):
    """User + system CPU time of a process so far, s (None when it is gone)."""
    try:
        with open(f'/proc/{pid}/stat', encoding='ascii') as f:
            fields = f.read().rsplit(')', 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')
    except (OSError, IndexError, ValueError):
        return None


def percentile_row(name, published, stamps_ns):
    """One table row: delivery and latency percentiles in ms."""
    lat = np.asarray(stamps_ns, float) * 1e-6
    if len(lat) == 0:
        return f'{name:<22} {0:>8d} {0.0:>9.2f}%  {"-":>8} {"-":>8} {"-":>8}', None
    p50, p99 = np.percentile(lat, [50, 99])
    return (f'{name:<22} {len(lat):>8d} {100.0 * len(lat) / published:>9.2f}% '
            f'{p50:>8.3f} {p99:>8.3f} {lat.max():>8.3f}'), p50


def main():
    """Run the benchmark and print the table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--rate', type=float, default=1000.0, help='input rate, Hz')
    parser.add_argument('--duration', type=float, default=10.0, help='seconds of input')
    parser.add_argument('--role', choices=('main', 'relay', 'control', 'publisher'),
                        default='main', help=argparse.SUPPRESS)
    parser.add_argument('--control', action='store_true',
                        help='A/A check of the bench: a second bare relay in place of the '
                             "correction node (its ratios show the bench's own bias)")
    parser.add_argument('--consumers', type=int, default=2, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.role == 'relay':
        return run_relay()
    if args.role == 'control':
        return run_relay('imu/corrected')
    if args.role == 'publisher':
        return run_publisher(args.rate, args.duration, args.consumers)

    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from sensor_msgs.msg import Imu
    env = dict(os.environ)
    env.setdefault('ROS_DOMAIN_ID', str(random.randint(100, 200)))
    env.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    os.environ.update(env)
    tmp = tempfile.mkdtemp(prefix='bench_correction_')
    cal_path = os.path.join(tmp, 'calibration.yaml')
    write_calibration(cal_path)
    py = sys.executable
    procs = [
        subprocess.Popen([py, HERE, '--role', 'control'] if args.control else
                         [py, '-m', 'accel_calib_ros.nodes.correction', '--ros-args',
                          '--log-level', 'warn', '-p', f'calibration_file:={cal_path}'],
                         env=env),
        subprocess.Popen([py, HERE, '--role', 'relay'], env=env),
    ]
    rclpy.init()
    node = rclpy.create_node('bench_sink')
    _, pub_qos = _qos()
    lat = {'imu/corrected': [], 'bench/relay': []}

    def sink(topic):
        def cb(msg):
            now = time.time_ns()
            s = msg.header.stamp
            lat[topic].append(now - (s.sec * 1_000_000_000 + s.nanosec))
        return cb

    for topic in lat:
        node.create_subscription(Imu, topic, sink(topic), pub_qos)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    publisher = None
    peak = [0.0, 0.0]
    try:
        end = time.monotonic() + 30.0
        while any(node.count_publishers(t) == 0 for t in lat):
            if time.monotonic() > end:
                raise SystemExit('the consumers did not come up')
            executor.spin_once(timeout_sec=0.05)
        publisher = subprocess.Popen([py, HERE, '--role', 'publisher', '--rate', str(args.rate),
                                      '--duration', str(args.duration)],
                                     env=env, stdout=subprocess.PIPE, text=True)
        cpu_start = [cpu_seconds(p.pid) for p in procs]
        while publisher.poll() is None:
            executor.spin_once(timeout_sec=0.01)
            rss = [rss_mib(p.pid) for p in procs]
            if all(r is not None for r in rss):
                peak = [max(a, b) for a, b in zip(peak, rss)]
        grace = time.monotonic() + 1.0
        while time.monotonic() < grace:
            executor.spin_once(timeout_sec=0.01)
        cpu_end = [cpu_seconds(p.pid) for p in procs]
        sent, achieved = publisher.stdout.read().split()
        sent = int(sent)
    finally:
        for p in procs:
            p.send_signal(signal.SIGINT)
        for p in procs:
            try:
                p.wait(timeout=5)
            except subprocess.TimeoutExpired:
                p.kill()
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()

    print(f'input: {sent} Imu messages at {args.rate:g} Hz requested, {achieved} Hz achieved, '
          f'{os.cpu_count()} CPUs')
    print(f'{"path":<22} {"received":>8} {"delivered":>10} {"p50 ms":>8} {"p99 ms":>8} '
          f'{"max ms":>8}')
    row_c, p50_c = percentile_row('accel_correction', sent, lat['imu/corrected'])
    row_r, p50_r = percentile_row('bare rclpy relay', sent, lat['bench/relay'])
    print(row_c)
    print(row_r)
    print(f'{"resident memory (peak VmRSS)":<30} correction {peak[0]:.1f} MiB, '
          f'relay {peak[1]:.1f} MiB')
    if peak[1]:
        print(f'RSS ratio correction / relay: {peak[0] / peak[1]:.2f} (target <= 1.2)')
    if None not in cpu_start + cpu_end:
        cpu = [b - a for a, b in zip(cpu_start, cpu_end)]
        print(f'CPU while streaming: correction {cpu[0]:.2f} s, relay {cpu[1]:.2f} s '
              f'(ratio {cpu[0] / max(cpu[1], 1e-9):.2f})')
    if p50_c and p50_r:
        print(f'p50 ratio correction / relay: {p50_c / p50_r:.2f} (target <= 1.0)')
    print(f'delivered: correction {100.0 * len(lat["imu/corrected"]) / sent:.2f} %, relay '
          f'{100.0 * len(lat["bench/relay"]) / sent:.2f} % (target 100 %)')
    return 0


if __name__ == '__main__':
    sys.exit(main())
