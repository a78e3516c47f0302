#!/usr/bin/env python3
"""
Benchmark: the accel_calibration node keeps up while it calibrates.

A whole-IMU session (accelerometer and gyroscope at ``--rate`` Hz, magnetometer at
100 Hz, temperature at 10 Hz) is simulated and replayed in real time, from pre-serialised
messages, to the calibration node running as its own process (as ``ros2 run``). After
``--poses`` held poses ``~/calibrate`` is called while the replay goes on; meanwhile
``get_parameters`` is asked every 50 ms. Printed:

- intake: the Imu messages the node took in (its ``/diagnostics`` count) over those
  published, in normal use (before the call) and around the call (from 1 s before the
  call to 3 s after its response, the model-gap check included);
- the parameter latency (max, p99 and unanswered requests) and the longest gap between
  two ``/diagnostics`` messages around the call;
- the ``~/calibrate`` response time and its first words.

Usage: python bench/bench_calibration_node.py [--rate 1000] [--poses 14] [--after 12]
Prints figures (the lines start with RESULT), asserts nothing.
"""

import argparse
import os
import random
import subprocess
import sys
import tempfile
import threading
import time

import numpy as np

PARAMS_PERIOD_S = 0.05
"""How often ``get_parameters`` is asked around the call, s."""
PARAMS_TIMEOUT_S = 5.0
"""A parameter request not answered within this is counted as unanswered."""


def simulate(rate_hz, poses, after_s, seed=1):
    """Return the Session: ``poses`` held poses, then more poses for ``after_s`` seconds."""
    from accel_calib_ros.sim import sensor as sim
    from accel_calib_ros.sim.motion import random_poses, simulate_session
    rng = np.random.default_rng(seed)
    sensor = sim.with_gyro_errors(sim.mpu9250_like(rng, rate_hz), np.random.default_rng(seed + 1))
    sensor.magnetometer = sim.ak8963_like(np.random.default_rng(seed + 2))
    hold_s, move_s = 2.0, 0.8
    extra = int(np.ceil(after_s / (hold_s + move_s))) + 1
    return simulate_session(sensor, random_poses(poses + extra, rng), rng, hold_s=hold_s,
                            move_s=move_s, rate_hz=rate_hz, tremor_deg=0.2), hold_s + move_s


def serialised(session, t0):
    """
    Return [(offset s, topic index, bytes)] in time order: Imu, MagneticField, Temperature.

    One message of each type is serialised by rclpy; the others are that template with the
    stamp and the values written in place (CDR little endian, frame_id ``imu_link``): a
    minute at 1 kHz takes a second, not the minutes of building 60 000 messages.
    """
    import struct
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import Imu, MagneticField, Temperature
    s = session.samples
    imu = Imu()
    imu.header.frame_id = 'imu_link'
    imu.orientation_covariance[0] = -1.0
    templates = [bytearray(serialize_message(m)) for m in
                 (imu, MagneticField(header=imu.header), Temperature(header=imu.header))]
    start = 28                      # the first double after the header ('imu_link')
    imu_vel, imu_acc = start + 104, start + 200
    rows = s.mag_rows if s.mag is not None else np.zeros(len(s.t), bool)
    temp_every = max(int(round(1.0 / (10.0 * float(np.median(np.diff(s.t)))))), 1)
    out = []

    def fill(index, sec, nsec, *at_values):
        b = bytearray(templates[index])
        struct.pack_into('<iI', b, 4, sec, nsec)
        for at, values in at_values:
            struct.pack_into(f'<{len(values)}d', b, at, *values)
        return bytes(b)
    for k, t in enumerate(s.t.tolist()):
        stamp = t0 + t
        sec, nsec = int(stamp), int(round((stamp % 1.0) * 1e9)) % 1_000_000_000
        out.append((t, 0, fill(0, sec, nsec, (imu_vel, s.gyro[k].tolist()),
                               (imu_acc, s.accel[k].tolist()))))
        if rows[k]:
            out.append((t, 1, fill(1, sec, nsec, (start, (s.mag[k] * 1e-6).tolist()))))
        if k % temp_every == 0:
            temp = float(s.temp[k]) if s.temp is not None else 25.0
            out.append((t, 2, fill(2, sec, nsec, (start, [temp]))))
    return out


class Bench:
    """The replaying publisher, the service clients and what the node reports."""

    def __init__(self):
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rcl_interfaces.srv import GetParameters
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import Imu, MagneticField, Temperature
        from std_srvs.srv import Trigger
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node('bench_calibration_peer', context=self.context)
        qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)   # as the driver
        self.pubs = [self.node.create_publisher(Imu, 'imu/data_raw', qos),
                     self.node.create_publisher(MagneticField, 'imu/mag', qos),
                     self.node.create_publisher(Temperature, 'imu/temperature', qos)]
        self.diagnostics = []           # (receive wall time, stamp s, values dict)
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diag, 50)
        self.calibrate = self.node.create_client(Trigger, 'accel_calibration/calibrate')
        self.params = self.node.create_client(GetParameters,
                                              'accel_calibration/get_parameters')
        self.GetParameters, self.Trigger = GetParameters, Trigger
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.published = []             # (wall time, Imu messages published so far)
        self.lock = threading.Lock()

    def _on_diag(self, msg):
        for status in msg.status:
            if status.name.endswith(': collection'):
                values = {kv.key: kv.value for kv in status.values}
                stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
                self.diagnostics.append((time.time(), stamp, values))

    def spin(self, seconds, pending=None, latencies=None):
        """Process callbacks for ``seconds``; note the parameter requests answered."""
        end = time.monotonic() + seconds
        while True:
            self.executor.spin_once(timeout_sec=0.005)
            if pending is not None:
                now = time.monotonic()
                for future in [f for f in pending if f.done()]:
                    start, sent = pending.pop(future)
                    latencies.append((sent, now - start))
            if time.monotonic() >= end:
                break

    def replay(self, messages, t0, stop):
        """Publish each message when the wall clock reaches its time (in a thread)."""
        imu = 0
        for offset, topic, data in messages:
            if stop.is_set():
                break
            delay = t0 + offset - time.time()
            if delay > 0:
                time.sleep(delay)
            self.pubs[topic].publish(data)
            if topic == 0:
                imu += 1
                with self.lock:
                    self.published.append((time.time(), imu))
        with self.lock:
            self.published.append((time.time(), imu))

    def published_at(self, wall):
        """Return the Imu messages published up to wall time ``wall``."""
        import bisect
        with self.lock:
            rows = list(self.published)
        k = bisect.bisect_right([w for w, _ in rows], wall)
        return rows[k - 1][1] if k else 0

    def close(self):
        """Tear down."""
        import rclpy
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def received(values):
    """Return the Imu messages the node reports taken in (older nodes: raw samples kept)."""
    for key in ('imu_received', 'raw_samples_kept'):
        if key in values:
            return int(values[key])
    return None


def intake(bench, start, end):
    """Return (taken in, published) between the diagnostics nearest the wall times."""
    diag = [(stamp, received(v)) for _, stamp, v in bench.diagnostics if received(v) is not None]
    before = [d for d in diag if d[0] <= start]
    after = [d for d in diag if d[0] >= end]
    if not after:
        after = diag[-1:]
    a = before[-1] if before else (start, 0)
    b = after[0]
    return b[1] - a[1], bench.published_at(b[0]) - bench.published_at(a[0])


def main():
    """Run the node, replay, calibrate, print the figures."""
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('--rate', type=float, default=1000.0, help='Imu rate, Hz')
    parser.add_argument('--poses', type=int, default=14,
                        help='poses held before ~/calibrate (default 14: about 40 s at 1 kHz)')
    parser.add_argument('--after', type=float, default=12.0,
                        help='seconds the replay goes on after the call (default 12)')
    parser.add_argument('--node-args', default='',
                        help='extra "-p name:=value" parameters of the node, space separated')
    parser.add_argument('--module', default='accel_calib_ros.nodes.calibration',
                        help='node module to run (python -m)')
    args = parser.parse_args()
    os.environ.setdefault('ROS_DOMAIN_ID', str(random.randint(120, 200)))
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    print(f'simulating {args.poses} poses at {args.rate:g} Hz and {args.after:g} s more ...',
          flush=True)
    session, pose_s = simulate(args.rate, args.poses, args.after)
    with tempfile.TemporaryDirectory() as tmp:
        log_path = os.path.join(tmp, 'node.log')
        cmd = [sys.executable, '-m', args.module, '--ros-args',
               '-p', f'calibration_file:={os.path.join(tmp, "calibration.yaml")}']
        for extra in args.node_args.split():
            cmd += ['-p', extra]
        with open(log_path, 'w') as log:
            proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT,
                                    stdin=subprocess.DEVNULL)
        bench = Bench()
        try:
            run(bench, session, pose_s, args, proc.pid)
        finally:
            bench.close()
            proc.send_signal(2)
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
            with open(log_path) as f:
                text = f.read()
            if 'Traceback' in text or proc.returncode not in (0, -2):
                print(f'node log (exit {proc.returncode}):\n{text[-3000:]}')


def cpu_seconds(pid):
    """Return the CPU time a process (and its waited-for children) used so far, s."""
    try:
        with open(f'/proc/{pid}/stat') as f:
            fields = f.read().rsplit(')', 1)[1].split()
    except OSError:
        return float('nan')
    return sum(int(v) for v in fields[11:15]) / os.sysconf('SC_CLK_TCK')


def run(bench, session, pose_s, args, pid):
    """Replay, call, probe, report."""
    if not bench.spin_until_ready():
        print('RESULT the node did not come up')
        return
    messages = serialised(session, time.time())   # stamps: the node reads only their spacing
    t0 = time.time() + 1.0
    stop = threading.Event()
    thread = threading.Thread(target=bench.replay, args=(messages, t0, stop), daemon=True)
    thread.start()
    call_at = t0 + session.samples.t[0] + args.poses * pose_s + 2.0
    latencies, pending = [], {}

    def probe():
        future = bench.params.call_async(bench.GetParameters.Request(names=['method']))
        pending[future] = (time.monotonic(), time.time())

    timer = bench.node.create_timer(PARAMS_PERIOD_S, probe)
    bench.spin(max(t0 + 1.0 - time.time(), 0.0), pending, latencies)
    cpu0, wall0 = cpu_seconds(pid), time.time()
    bench.spin(max(call_at - time.time(), 0.0), pending, latencies)
    cpu_normal = (cpu_seconds(pid) - cpu0) / (time.time() - wall0)
    called = time.time()
    future = bench.calibrate.call_async(bench.Trigger.Request())
    bench.spin(0.05, pending, latencies)
    again = bench.calibrate.call_async(bench.Trigger.Request())     # while it runs
    while not again.done() and time.time() - called < 120:
        bench.spin(0.005, pending, latencies)
    refused_in = time.time() - called - 0.05
    while not future.done() and time.time() - called < 120:
        bench.spin(0.005, pending, latencies)
    answered = time.time()
    bench.spin(3.0, pending, latencies)
    bench.node.destroy_timer(timer)
    end = time.monotonic() + PARAMS_TIMEOUT_S
    while pending and time.monotonic() < end:
        bench.spin(0.01, pending, latencies)
    unanswered = [sent for _, sent in pending.values()]
    thread.join()
    bench.spin(2.5)
    response = future.result() if future.done() else None
    normal = intake(bench, t0, called - 1.0)
    around = intake(bench, called - 1.0, answered + 3.0)
    total = intake(bench, t0 - 1.0, time.time())
    lat = np.array([ms for sent, ms in latencies if called - 1.0 <= sent <= answered + 3.0]) * 1e3
    before = np.array([ms for sent, ms in latencies if t0 + 2.0 <= sent < called - 1.0]) * 1e3
    late = [(sent - called, ms) for sent, ms in latencies if ms > 0.1]
    stamps = [stamp for _, stamp, _ in bench.diagnostics
              if called - 2.0 <= stamp <= answered + 3.0]
    gaps = np.diff(stamps) if len(stamps) > 1 else np.array([np.nan])
    print(f'~/calibrate answered in {answered - called:.2f} s: '
          + ('no answer' if response is None else
             f'success={response.success}: {response.message[:100]} ...'))
    if response is not None:
        for part in response.message.split('. '):
            if part.startswith(('gyroscope:', 'magnetometer:')):
                print(f'  {part[:110]}')
    second = again.result() if again.done() else None
    print(f'RESULT a second ~/calibrate during the first answered in {refused_in:.3f} s: '
          + ('no answer' if second is None else
             f'success={second.success}: {second.message[:110]}'))
    print(f'RESULT intake normal {_ratio(normal)} ; around the call {_ratio(around)} ; '
          f'whole replay {_ratio(total)}')
    print(f'RESULT node CPU in normal use {100 * cpu_normal:.0f} % of one core')
    print(f'RESULT get_parameters during the call: {len(lat)} answered, max '
          f'{lat.max() if len(lat) else float("nan"):.1f} ms, p99 '
          f'{np.percentile(lat, 99) if len(lat) else float("nan"):.1f} ms, median '
          f'{np.median(lat) if len(lat) else float("nan"):.1f} ms; '
          f'{sum(called - 1.0 <= t <= answered + 3.0 for t in unanswered)} unanswered')
    print(f'RESULT get_parameters in normal use: {len(before)} answered, max '
          f'{before.max() if len(before) else float("nan"):.1f} ms, p99 '
          f'{np.percentile(before, 99) if len(before) else float("nan"):.1f} ms; '
          f'{sum(t < called - 1.0 for t in unanswered)} unanswered')
    if late:
        print('  answers slower than 100 ms (s from the call, ms): '
              + ', '.join(f'{t:+.2f} {1e3 * ms:.0f}' for t, ms in late[:12]))
    print(f'RESULT longest gap between /diagnostics around the call: {np.nanmax(gaps):.2f} s '
          '(period 1 s)')


def _ratio(pair):
    taken, sent = pair
    return f'{taken}/{sent} = {100.0 * taken / max(sent, 1):.2f} %'


def _spin_until_ready(self, timeout=20.0):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if self.calibrate.service_is_ready() and self.params.service_is_ready() and \
                self.pubs[0].get_subscription_count() > 0:
            self.spin(0.5)
            return True
        self.executor.spin_once(timeout_sec=0.05)
    return False


Bench.spin_until_ready = _spin_until_ready


if __name__ == '__main__':
    main()
