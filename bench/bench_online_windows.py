"""
Benchmark: the calibration node's streaming detector against ``accel-calib fit``'s.

Simulated sessions (random poses, 0.7 s moves) at 100-1000 Hz with 1.0 s and 1.5 s
holds go through :func:`core.windows.detect_static_windows` (what the CLI uses) and
through :class:`core.windows.OnlineStaticDetector` fed in chunks of 100 samples (what
the node does), with the same settings. Printed per case: holds, windows found by
each, the share of the offline windows the online one finds identically (same
middle within 5 samples, same length within 1 %), and the same with a start-up burst
(1 s of samples at rest stamped 0.1 ms apart) and with every third hold turning slowly
(3 deg/s)::

    python bench/bench_online_windows.py [--poses 40]
"""

import argparse
import sys
import time

from accel_calib_ros.core.windows import DEFAULTS, detect_static_windows, OnlineStaticDetector
from accel_calib_ros.sim.motion import random_directions, simulate_session
from accel_calib_ros.sim.sensor import mpu9250_like
import numpy as np

SHORT = {'window_s': 0.25, 'trim_s': 0.1, 'min_duration_s': 0.3}
OFFLINE_GYRO = 'max_rotation_rad_s' in DEFAULTS


def online(samples, settings, burst=0):
    """Stream a recording through the online detector; return windows and seconds."""
    det = OnlineStaticDetector(use_gyro=OFFLINE_GYRO, **settings)
    out = []
    t0 = time.perf_counter()
    if burst:
        # Stale samples queued before the session (the sensor at rest: a copy of the
        # session's first samples), delivered at once: stamps 0.1 ms apart.
        t = samples.t[0] - 1e-4 * np.arange(burst, 0, -1) - 0.005
        out += det.feed(t, samples.accel[:burst], None,
                        None if samples.gyro is None else samples.gyro[:burst])
    for i in range(0, len(samples.t), 100):
        part = slice(i, i + 100)
        out += det.feed(samples.t[part], samples.accel[part], samples.temp[part],
                        None if samples.gyro is None else samples.gyro[part])
    out += det.finish()
    return out, time.perf_counter() - t0


def matched(found, offline, rate):
    """Share of the offline windows found identically online."""
    if not len(offline):
        return float('nan')
    hits = 0
    for k in range(len(offline)):
        for w in found:
            if abs(w['t_mid'] - offline.t_mid[k]) < 5.0 / rate \
                    and abs(w['count'] - offline.count[k]) <= max(3, 0.01 * w['count']):
                hits += 1
                break
    return hits / len(offline)


def main():
    """Run the cases and print the table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument('--poses', type=int, default=40, help='poses per session')
    args = parser.parse_args()
    print(f'offline gyro test: {"yes" if OFFLINE_GYRO else "no (both without)"}')
    print(f'{"rate Hz":>7} {"hold s":>6} {"case":<10} {"holds":>5} {"offline":>7} '
          f'{"online":>6} {"same %":>7} {"us/sample":>9}')
    for hold, settings in ((1.0, SHORT), (1.5, {})):
        for rate in (100.0, 200.0, 500.0, 1000.0):
            for case in ('plain', 'burst', 'turns'):
                rng = np.random.default_rng(int(rate) + int(10 * hold))
                sensor = mpu9250_like(rng, rate_hz=rate)
                s = simulate_session(sensor, random_directions(args.poses, rng), rng,
                                     hold_s=hold, move_s=0.7, rate_hz=rate, lead_s=hold)
                if case == 'turns':
                    starts = np.flatnonzero(np.diff(np.r_[-1, s.pose]) != 0)
                    n = int(hold * rate)
                    for a in starts:
                        if s.pose[a] >= 0 and s.pose[a] % 3 == 1:
                            s.samples.gyro[a + n // 2:a + n] += [0.0, 0.0, np.radians(3.0)]
                offline = detect_static_windows(s.samples, **settings)
                found, seconds = online(s.samples, settings,
                                        burst=int(1.0 * rate) if case == 'burst' else 0)
                print(f'{rate:>7.0f} {hold:>6.1f} {case:<10} {args.poses:>5d} '
                      f'{len(offline):>7d} {len(found):>6d} '
                      f'{100 * matched(found, offline, rate):>7.1f} '
                      f'{1e6 * seconds / len(s.samples.t):>9.1f}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
