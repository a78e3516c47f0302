#!/usr/bin/env python3
"""
Start-up cost of ``accel-calib``: whole-process wall time against the import floor.

The floor is ``python -c "import numpy, yaml"`` with the same interpreter: what any
command of the package must pay at least. Measured in one run, interleaved (floor,
fit, --help, ... repeated), so machine load hits all of them alike; each figure is the
median of ``--runs`` runs. Also lists the heavy modules each command imports.

Targets: fit on a 24-window accelerometer session <= 1.5x the floor;
--help <= 1.2x. Since fit calibrates all three sensors of a session, the work of
the fit itself is shown apart: ``fit --help`` is the start-up of the fit command (its
imports and parser), the accelerometer-only row is fit without gyro columns, the
24-window row has the gyro columns of ``simulate`` (so fit also calibrates the gyroscope)
and the three-sensor row adds a magnetometer (``simulate --gyro-errors --magnetometer``).
Prints figures, asserts nothing. Usage: python bench/bench_startup.py [--runs N]
"""

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time

HEAVY = ('scipy', 'matplotlib', 'rosbags', 'rich', 'tqdm', 'accel_calib_ros.sim.device',
         'accel_calib_ros.sim.sensor', 'accel_calib_ros.modelgap')

PROBE = ('import runpy, sys; sys.argv = {argv!r}; '
         'from accel_calib_ros.cli import main\n'
         'try:\n    main(sys.argv[1:])\nfinally:\n'
         '    print(" ".join(m for m in {heavy!r} if m in sys.modules), file=sys.stderr)')


def wall(cmd, env):
    """Return the wall time of one process run, s (stdout discarded)."""
    start = time.perf_counter()
    subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env,
                   check=False)
    return time.perf_counter() - start


def heavy_modules(argv, env):
    """Return the heavy modules loaded by running ``accel-calib argv`` in-process."""
    code = PROBE.format(argv=['accel-calib'] + argv, heavy=HEAVY)
    done = subprocess.run([sys.executable, '-c', code], stdout=subprocess.DEVNULL,
                          stderr=subprocess.PIPE, text=True, env=env, check=False)
    return done.stderr.strip().splitlines()[-1] if done.stderr.strip() else ''


def main():
    """Measure and print the start-up ratios."""
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('--runs', type=int, default=9, help='runs per command (default 9)')
    args = parser.parse_args()
    env = dict(os.environ)
    env.pop('PYTHONDONTWRITEBYTECODE', None)
    script = os.path.join(os.path.dirname(sys.executable), 'accel-calib')
    cli = [script] if os.path.exists(script) else [sys.executable, '-m', 'accel_calib_ros.cli']
    with tempfile.TemporaryDirectory() as tmp:
        data = os.path.join(tmp, 'session.csv')
        subprocess.run(cli + ['simulate', '-o', data, '--poses', '24', '--seed', '1'],
                       check=True, stdout=subprocess.DEVNULL, env=env)
        imu = os.path.join(tmp, 'imu.csv')
        subprocess.run(cli + ['simulate', '-o', imu, '--poses', '24', '--seed', '1',
                              '--gyro-errors', '--magnetometer'],
                       check=True, stdout=subprocess.DEVNULL, env=env)
        accel_only = os.path.join(tmp, 'accel.csv')
        with open(data) as src, open(accel_only, 'w') as dst:
            dst.writelines(','.join(line.rstrip('\n').split(',')[:5]) + '\n' for line in src)
        commands = {
            'floor (python -c "import numpy, yaml")': [sys.executable, '-c',
                                                       'import numpy, yaml'],
            'accel-calib --help': cli + ['--help'],
            'accel-calib fit --help': cli + ['fit', '--help'],
            'accel-calib fit (24 windows)': cli + ['fit', data],
            'accel-calib fit --json': cli + ['fit', data, '--json'],
            'accel-calib fit (accelerometer only)': cli + ['fit', accel_only],
            'accel-calib fit (three sensors)': cli + ['fit', imu],
            'accel-calib apply --help': cli + ['apply', '--help'],
        }
        for cmd in commands.values():      # warm the page cache and the .pyc files
            wall(cmd, env)
        times = {name: [] for name in commands}
        for _ in range(args.runs):
            for name, cmd in commands.items():
                times[name].append(wall(cmd, env))
        floor_name = next(iter(commands))
        floor = statistics.median(times[floor_name])
        print(f'start-up, median of {args.runs} interleaved runs ({sys.executable})')
        for name, values in times.items():
            med = statistics.median(values)
            print(f'  {name:42s} {med * 1e3:7.1f} ms  {med / floor:5.2f}x floor'
                  f'  (min {min(values) * 1e3:.1f}, max {max(values) * 1e3:.1f} ms)')
        fit = statistics.median(times['accel-calib fit (24 windows)']) / floor
        helped = statistics.median(times['accel-calib --help']) / floor
        print(f'RATIO fit/floor {fit:.2f} (target <= 1.5); '
              f'--help/floor {helped:.2f} (target <= 1.2); fit --help/floor '
              f'{statistics.median(times["accel-calib fit --help"]) / floor:.2f} (start-up); '
              f'accelerometer-only fit/floor '
              f'{statistics.median(times["accel-calib fit (accelerometer only)"]) / floor:.2f} '
              '(target <= 1.5); three-sensor fit/floor '
              f'{statistics.median(times["accel-calib fit (three sensors)"]) / floor:.2f}')
        low = min(times[floor_name])
        print(f'  (fastest runs, less sensitive to a loaded machine: fit/floor '
              f'{min(times["accel-calib fit (24 windows)"]) / low:.2f}, --help/floor '
              f'{min(times["accel-calib --help"]) / low:.2f})')
        print('heavy modules imported:')
        for argv in (['--help'], ['fit', data], ['apply', '--help']):
            shown = ' '.join(a if a != data else 'session.csv' for a in argv)
            print(f'  accel-calib {shown:24s} {heavy_modules(argv, env) or "none"}')


if __name__ == '__main__':
    main()
