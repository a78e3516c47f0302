#!/usr/bin/env python3
"""
Big recordings: wall time and peak memory of simulate, fit and apply on long CSV files.

For each row count, ``accel-calib simulate`` writes a 24-pose CSV of about that many
rows (100 Hz, temperature and gyro columns), ``fit`` calibrates it and ``apply``
corrects it; each runs as its own process and its peak resident memory is read from the
kernel (``wait4``). Target: apply and simulate of 10⁷ rows in <= 500 MiB.

Prints figures, asserts nothing.
Usage: python bench/bench_bigfile.py [--rows 1e6,1e7] [--dir DIR] [--bag]
"""

import argparse
import os
import subprocess
import sys
import tempfile
import time

RATE_HZ = 100.0
POSES = 24
MOVE_S = 1.5


def run(cmd):
    """Run a command; return (wall seconds, peak RSS MiB, exit status)."""
    start = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    seconds = time.perf_counter() - start
    proc.returncode = os.waitstatus_to_exitcode(status)
    err = proc.stderr.read().decode(errors='replace').strip()
    proc.stderr.close()
    if proc.returncode != 0:
        print(f'    {" ".join(cmd[1:3])} failed ({proc.returncode}): {err[-300:]}')
    return seconds, usage.ru_maxrss / 1024.0, proc.returncode


def main():
    """Measure and print the figures."""
    parser = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    parser.add_argument('--rows', default='1e6',
                        help='comma-separated row counts (default 1e6; 1e7 takes minutes)')
    parser.add_argument('--dir', help='scratch folder (default: a temporary one)')
    parser.add_argument('--bag', action='store_true', help='also simulate into an .mcap bag')
    parser.add_argument('--skip', default='', help='comma-separated steps to skip: fit')
    args = parser.parse_args()
    script = os.path.join(os.path.dirname(sys.executable), 'accel-calib')
    cli = [script] if os.path.exists(script) else [sys.executable, '-m', 'accel_calib_ros.cli']
    skip = {s.strip() for s in args.skip.split(',') if s.strip()}
    with tempfile.TemporaryDirectory(dir=args.dir) as tmp:
        print(f'{"rows":>10s} {"step":10s} {"seconds":>8s} {"peak RSS MiB":>13s} '
              f'{"file MB":>8s} {"rows/s":>10s}')
        for text in args.rows.split(','):
            rows = int(float(text))
            hold = max((rows - (POSES - 1) * MOVE_S * RATE_HZ) / (POSES * RATE_HZ), 1.0)
            data = os.path.join(tmp, 'big.csv')
            out = os.path.join(tmp, 'corrected.csv')
            cal = os.path.join(tmp, 'cal.yaml')
            steps = [('simulate', cli + ['simulate', '-o', data, '--poses', str(POSES),
                                         '--hold', f'{hold:.6f}', '--move', str(MOVE_S),
                                         '--rate', str(RATE_HZ), '--temp', '20', '35'])]
            if 'fit' not in skip:
                steps.append(('fit', cli + ['fit', data, '-o', cal]))
            else:
                small = os.path.join(tmp, 'small.csv')
                subprocess.run(cli + ['simulate', '-o', small], check=True,
                               stdout=subprocess.DEVNULL)
                subprocess.run(cli + ['fit', small, '-o', cal], check=True,
                               stdout=subprocess.DEVNULL)
            steps.append(('apply', cli + ['apply', cal, data, '-o', out]))
            if args.bag:
                steps.append(('simulate→mcap', cli + [
                    'simulate', '-o', os.path.join(tmp, 'big.mcap'), '--poses', str(POSES),
                    '--hold', f'{hold:.6f}', '--move', str(MOVE_S), '--rate',
                    str(RATE_HZ)]))
            for name, cmd in steps:
                seconds, rss, status = run(cmd)
                size = os.path.getsize(data) / 1e6 if os.path.exists(data) else float('nan')
                print(f'{rows:10d} {name:10s} {seconds:8.1f} {rss:13.0f} {size:8.0f} '
                      f'{rows / seconds:10.0f}' + ('' if status == 0 else '  FAILED'),
                      flush=True)
            for path in (data, out):
                if os.path.exists(path):
                    os.unlink(path)


if __name__ == '__main__':
    main()
