"""
Benchmark: the MPU9250 frame parser and clock mapper, CPU time per frame.

Prints frames parsed per second of CPU time (``time.process_time``), for frame versions 1
and 2, for a clean stream and for one with 2 % of its bytes flipped, at two read sizes
(64 bytes is a typical USB-serial read at 200 Hz, 4096 a backlog), the number of intact
frames the parser lost at 2 % corruption (must be 0), and the cost of the ClockMapper and
of the ASCII line parser. Then, over ``--garbage-frames`` frames (default 10⁶) at 1 kHz,
for a stream of uniformly random axes (no plausibility check can help there) and for a
sensor-like stream (gravity plus noise), with 2 % and 20 % of the bytes XORed with a
random non-zero byte, for both frame versions: garbage frames published per 10⁶ (a
published frame that was not sent) and intact frames lost. bench/bench_reliability.py has
the other kinds of damage (drops, insertions, bursts).

The clock sweep: a board whose µs clock is -5000..+5000 ppm off streams
at 1 kHz through the simulated USB-serial transport (sim/transport.py: 1 ms USB frames, or
an Uno's 64-byte packets, reader latency and stalls) for ``--clock-seconds``; per row the
share of stamps within 1 ms of the true sample time (plus the transport's smallest delay,
which no host can see), the largest error, stamps not after their predecessor
(backwards), steps under 45 % of a period (bunched), the range of the steps over the
period, and the rate error the mapping found::

The link rows: the virtual device (sim/device.py) on a pty, read by
the ROS-free SerialLink in this process, with a 2.5 s UART stall, an unplug and replug, a
version-1 re-lock after a 1030 ms stall, and a device clock 2000 ppm fast; per row the
samples the device never sent (its ``--report``) against those the link counted lost,
the frames it wrote against those delivered, and the stamps' spread around the true
sample grid::

    python bench/bench_driver.py [--frames 100000] [--garbage-frames 1000000]
                                 [--clock-seconds 60] [--no-link]
"""

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time

from accel_calib_ros.dataio.link import SerialLink
from accel_calib_ros.dataio.wire import (AsciiLineParser, Converter, encode,
                                         encode_ascii_line, FRAME_SIZE, FRAME_V2_SIZE,
                                         FrameParser, RawFrame, SPIKE_COUNTS)
from accel_calib_ros.dataio.wire.clock import Stamper
from accel_calib_ros.sim.transport import stamp_quality, stamp_reads, usb_reads
import numpy as np

CLOCK_PPM = (-5000, -3000, -2000, -1000, 0, 1000, 2000, 3000, 5000)


def frame(k, t_us, counts, version):
    if version == 1:
        return RawFrame(k & 0xFF, t_us & 0xFFFFFFFF, tuple(counts))
    return RawFrame(k & 0xFFFF, t_us & 0xFFFFFFFF, tuple(counts), None, 2)


def make_stream(n, rng, version=1):
    counts = rng.integers(-32768, 32768, (n, 7))
    counts[:, 3] = 1335 + rng.integers(-30, 31, n)              # a plausible 25 °C
    frames = [frame(k, 4_290_000_000 + 5000 * k, c, version)
              for k, c in enumerate(counts.tolist())]
    return frames, b''.join(encode(f) for f in frames)


def corrupt(data, fraction, rng, size=FRAME_SIZE):
    buf = np.frombuffer(data, np.uint8).copy()
    hit = np.flatnonzero(rng.random(len(buf)) < fraction)
    buf[hit] ^= rng.integers(1, 256, len(hit)).astype(np.uint8)
    return buf.tobytes(), set((hit // size).tolist())


def parse(data, chunk, **options):
    parser = FrameParser(**options)
    out = []
    start = time.process_time()
    for k in range(0, len(data), chunk):
        out += parser.feed(data[k:k + chunk])
    out += parser.flush()
    return out, parser, time.process_time() - start


def make_1khz_stream(n, rng, kind, version=1):
    """Frames at 1 kHz: ``uniform`` random axes or ``sensor`` (1 g on z plus noise)."""
    if kind == 'uniform':
        counts = rng.integers(-32768, 32768, (n, 7))
    else:
        counts = np.zeros((n, 7), np.int64)
        counts[:, :3] = np.round(rng.normal(0, 70, (n, 3)) + [0, 0, 16384])
        counts[:, 4:] = np.round(rng.normal(0, 15, (n, 3)))
    counts[:, 3] = 1335 + rng.integers(-30, 31, n)              # about 25 °C
    frames = [frame(k, 4_290_000_000 + 1000 * k, c, version)
              for k, c in enumerate(counts.tolist())]
    return frames, b''.join(encode(f) for f in frames)


def garbage_table(n, rng, spike=False):
    """Print garbage per 10⁶ and intact frames lost at 2 % and 20 % byte corruption."""
    print(f'garbage test: {n} frames per cell, bytes XORed with a random non-zero byte')
    worst_lost_2 = 0
    for version, kind in ((1, 'uniform'), (1, 'sensor'), (2, 'uniform'), (2, 'sensor')):
        frames, clean = make_1khz_stream(n, rng, kind, version)
        sent = set(frames)
        size = FRAME_SIZE if version == 1 else FRAME_V2_SIZE
        for fraction in (0.02, 0.20):
            dirty, damaged = corrupt(clean, fraction, rng, size)
            out, parser, cpu = parse(dirty, 4096,
                                     spike_counts=SPIKE_COUNTS if spike else None)
            got = set(out)
            garbage = sum(f not in sent for f in out)
            lost = sum(1 for k, f in enumerate(frames) if k not in damaged and f not in got)
            if fraction == 0.02:
                worst_lost_2 = max(worst_lost_2, lost)
            print(f'  v{version} {kind:8s} {fraction * 100:4.0f} %: garbage '
                  f'{garbage * 1e6 / n:8.1f} per 10⁶'
                  f'  intact frames lost {lost} of {n - len(damaged)}'
                  f'  (published {len(out)}, rejected {parser.rejected}, {n / cpu:,.0f} frames/s'
                  ' CPU)')
    return worst_lost_2


def main():
    ap = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    ap.add_argument('--frames', type=int, default=100_000)
    ap.add_argument('--garbage-frames', type=int, default=1_000_000)
    ap.add_argument('--clock-seconds', type=float, default=60.0,
                    help='seconds of stream per row of the clock sweep (0: no sweep)')
    ap.add_argument('--no-link', action='store_true',
                    help='leave out the link rows (the virtual device on a pty)')
    ap.add_argument('--spike', action='store_true',
                    help='garbage test with the optional spike check (band-limited signals)')
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    status = 0
    for version in (1, 2):
        status |= cpu_table(args.frames, rng, version)
    frames, _ = make_stream(args.frames, rng)
    status |= other_costs(frames, rng)
    if args.clock_seconds > 0:
        status |= clock_table(args.clock_seconds)
    if not args.no_link:
        status |= link_table()
    if args.garbage_frames > 0:
        status |= garbage_table(args.garbage_frames, rng, args.spike) != 0
    if status:
        print('bench_driver: FAILED (frames lost, or stamps off)', file=sys.stderr)
    return status


def cpu_table(n, rng, version):
    """Print parser CPU time for one frame version; return 1 when an intact frame was lost."""
    frames, clean = make_stream(n, rng, version)
    size = FRAME_SIZE if version == 1 else FRAME_V2_SIZE
    dirty, damaged = corrupt(clean, 0.02, rng, size)
    intact = [f for k, f in enumerate(frames) if k not in damaged]
    print(f'version {version}: {n} frames of {size} bytes; '
          f'2 % corruption damages {len(damaged)} of them')
    status = 0
    for name, data in (('clean', clean), ('2 % corrupt', dirty)):
        for chunk in (64, 4096):
            out, parser, cpu = parse(data, chunk)
            line = (f'  {name:12s} reads of {chunk:5d} B: {len(out) / cpu:10,.0f} frames/s CPU'
                    f'  (crc_errors {parser.crc_errors}, lost_frames {parser.lost_frames}, '
                    f'bytes_skipped {parser.bytes_skipped})')
            if data is dirty:
                got = set(out)
                lost = sum(f not in got for f in intact)
                bogus = len(got - set(frames))
                line += f'\n{"":16s}lost valid frames: {lost}; corrupted frames passing ' \
                        f'the CRC and every check: {bogus}'
                status |= lost != 0
            elif len(out) != len(frames):
                status = 1
            print(line)
    return status


def other_costs(frames, rng):
    """Print the cost of the stamps, the converter and the ASCII parser."""
    stamper = Stamper('device')
    conv = Converter()
    host = 1.7e9 + np.arange(len(frames)) / 200.0 + rng.uniform(0, 0.004, len(frames))
    start = time.process_time()
    for k in range(0, len(frames), 4):              # reads of 4 frames
        stamper.stamps(stamper.observe(frames[k:k + 4], float(host[min(k + 3, len(host) - 1)])))
        for f in frames[k:k + 4]:
            conv.to_si(f.counts)
    cpu = time.process_time() - start
    print(f'  Stamper (observe + stamps) + Converter.to_si: {len(frames) / cpu:10,.0f} '
          'frames/s CPU')

    text = b''.join(encode_ascii_line(f.counts, f.t_us) for f in frames[:20000])
    ascii_parser = AsciiLineParser()
    start = time.process_time()
    n = 0
    for k in range(0, len(text), 256):
        n += len(ascii_parser.feed(text[k:k + 256]))
    cpu = time.process_time() - start
    print(f'  ASCII lines: {n / cpu:10,.0f} lines/s CPU (bad lines {ascii_parser.bad_lines})')
    return 0


def clock_table(seconds):
    """Print the clock sweep; return 1 when a row at ±3000 ppm misses its targets."""
    print(f'clock sweep: {seconds:g} s at 1 kHz per row; error = stamp - (sample time + '
          'smallest transport delay)')
    status = 0
    for transport in ('usb', 'packets'):
        for timestamp in ('device', 'host'):
            ppms = CLOCK_PPM if timestamp == 'device' else (-3000, 3000)
            for ppm in ppms:
                t_us, true, reads = usb_reads(seconds, 1000.0, ppm,
                                              np.random.default_rng(abs(ppm) + 1), transport)
                stamps, stamper = stamp_reads(t_us, reads, timestamp)
                q = stamp_quality(stamps, true)
                settled = stamp_quality(stamps[2000:], true[2000:])
                print(f'  {transport:7s} {timestamp:6s} {ppm:+6d} ppm: within 1 ms '
                      f'{100 * q["within_1ms"]:6.2f} % (after 2 s '
                      f'{100 * settled["within_1ms"]:6.2f} %), max {q["max_ms"]:5.2f} ms, '
                      f'p99 {q["p99_ms"]:5.2f} ms, backwards {q["backwards"]}, bunched '
                      f'{q["bunched"]}, steps {q["spacing"][0]:.3f}..'
                      f'{q["spacing"][1]:.3f} of a period, rate error found '
                      f'{stamper.mapper.drift_ppm:+8.1f} ppm')
                if timestamp == 'device' and abs(ppm) <= 3000 and (
                        q['within_1ms'] < 0.99 or q['backwards'] or q['bunched']):
                    status = 1
    return status


def link_run(device_args, seconds, rate=200.0, reconnect_max_s=0.4):
    """Run the virtual device under a SerialLink; return (report, snapshot, frames, stamps)."""
    got = {'frames': [], 'stamps': []}
    lock = threading.Lock()

    def on_samples(frames, stamps):
        with lock:
            got['frames'] += frames
            got['stamps'] += stamps
    with tempfile.TemporaryDirectory() as tmp:
        path, report = os.path.join(tmp, 'imu0'), os.path.join(tmp, 'device.json')
        link = SerialLink(path, 1_000_000, on_samples=on_samples, reconnect_min_s=0.1,
                          reconnect_max_s=reconnect_max_s)
        link.start()                                # it waits for the port quietly
        device = subprocess.Popen(
            [sys.executable, '-m', 'accel_calib_ros.sim.device', '--link', path, '--rate',
             str(rate), '--poses', 'faces', '--count', '1', '--hold', '600', '--report',
             report] + device_args, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL)
        device.stdout.readline()
        time.sleep(seconds)
        device.send_signal(signal.SIGINT)
        device.wait(10)
        device.stdout.close()
        time.sleep(0.5)
        link.stop()
        with open(report) as f:
            done = json.load(f)
    return done, link.snapshot(), got['frames'], got['stamps']


def link_table():
    """Print the link rows; return 1 when a loss was miscounted or a sent frame lost."""
    print('link rows: the virtual device on a pty, read by SerialLink (never sent = the '
          "device's report; counted = lost_frames)")
    status = 0
    rows = (('UART stall 2.5 s, v2, 200 Hz', ['--stall', '3:2.5'], 8.0, 200.0, 0.4),
            ('unplug 2 s + replug, v2, 200 Hz', ['--unplug-at', '3', '--unplug-s', '2'], 9.0,
             200.0, 2.0),
            ('v1 re-lock: stall 1.03 s, 1 kHz', ['--frame-version', '1', '--stall', '3:1.03'],
             7.0, 1000.0, 0.4))
    for name, args, seconds, rate, reconnect in rows:
        report, snap, frames, _ = link_run(args, seconds, rate, reconnect)
        c = snap['counters']
        never = sum(report['never_sent'].values())
        # Every sample from the first delivered to the last: delivered, or counted lost.
        span = round(((frames[-1].t_us - frames[0].t_us) & 0xFFFFFFFF) / (1e6 / rate)) + 1
        unaccounted = span - len(frames) - c['lost_frames']
        print(f'  {name:34s}: never sent {never:5d}, counted lost {c["lost_frames"]:5d}, '
              f'gaps uncounted {c["gaps_uncounted"]}; of the {span} samples from the first '
              f'delivered to the last, delivered {len(frames)}, unaccounted {unaccounted}; '
              f'watchdog reopens {snap["watchdog_reopens"]}, reconnects '
              f'{snap["reconnects"]}')
        status |= abs(c['lost_frames'] - never) > 3 or unaccounted != 0
    report, snap, frames, stamps = link_run(['--clock-ppm', '2000', '--stall', '8:0.1'], 14.0,
                                            1000.0)
    period_us = 1e3 * (1 + 2000e-6)
    t0 = report['t0_us']
    k = np.array([round(((f.t_us - t0) & 0xFFFFFFFF) / period_us) for f in frames])
    offsets = np.array(stamps) - (report['start_time'] + k / 1000.0)
    late = offsets[np.array(stamps) > stamps[0] + 2.0]
    steps = np.diff(stamps)
    print(f'  {"+2000 ppm clock, 1 kHz, 14 s":34s}: stamps around the sample grid after 2 s: '
          f'spread {1e3 * np.ptp(late):.3f} ms (p1..p99 '
          f'{1e3 * (np.percentile(late, 99) - np.percentile(late, 1)):.3f} ms), median '
          f'{1e3 * np.median(late):.3f} ms after the sample (the pty and the 10 ms batches '
          f'of the device); backwards {int(np.sum(steps <= 0))}, bunched '
          f'{int(np.sum(steps < 0.45e-3))}; rate error found {snap["drift_ppm"]:+.0f} ppm; '
          f'lost {snap["counters"]["lost_frames"]} of never sent '
          f'{sum(report["never_sent"].values())}; from the first stamp: spread '
          f'{1e3 * np.ptp(offsets):.3f} ms')
    status |= np.ptp(late) > 2e-3 or int(np.sum(steps <= 0)) > 0
    return status


if __name__ == '__main__':
    sys.exit(main())
