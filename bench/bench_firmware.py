"""
Benchmark: the firmware on the emulated board (simavr), at 1 MBd and at 115200 baud.

Builds the firmware twice and the board (test/hil/mpu_board.c; needs the Debian packages
of docs/firmware.md), runs each for ``--seconds`` simulated seconds as fast as the host
allows, parses the UART with the driver's parser and prints flash/RAM used, frames per
simulated second, lost samples (seq gaps) and CRC errors::

    python bench/bench_firmware.py [--seconds 10]
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile

from accel_calib_ros.dataio.mpu9250_frame import FrameParser

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, 'test'))


def main():
    from firmware_tools import build_firmware, build_harness, ENSURE
    ap = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    ap.add_argument('--seconds', type=float, default=10.0)
    args = ap.parse_args()
    if subprocess.run(['sh', ENSURE, 'hil']).returncode:
        return 1
    work = tempfile.mkdtemp(prefix='bench_firmware_')
    board = build_harness(work)
    for baud in (1_000_000, 115200):
        elf = build_firmware(os.path.join(work, f'fw-{baud}'), FW_BAUD=baud)
        size = subprocess.run(['avr-size', '-C', '--mcu=atmega328p', elf], capture_output=True,
                              text=True).stdout
        used = [line.strip() for line in size.splitlines() if line.startswith(('Program',
                                                                               'Data'))]
        out = os.path.join(work, f'uart-{baud}.bin')
        run = subprocess.run([board, '--elf', elf, '--uart-out', out, '--fast', '--seconds',
                              str(args.seconds)], capture_output=True, text=True, check=True)
        report = json.loads(run.stdout.strip().splitlines()[-1])
        parser = FrameParser()
        with open(out, 'rb') as f:
            frames = parser.feed(f.read()) + parser.flush()
        span_s = ((frames[-1].t_us - frames[0].t_us) & 0xFFFFFFFF) * 1e-6
        samples = len(frames) + parser.lost_frames
        print(f'FW_BAUD={baud}: {"; ".join(used)}')
        print(f'  {len(frames)} frames in {span_s:.3f} s of device time: '
              f'{len(frames) / span_s:.1f} frames/s of {samples / span_s:.1f} samples/s; '
              f'lost samples {parser.lost_frames} ({100.0 * parser.lost_frames / samples:.1f} %),'
              f' CRC errors {parser.crc_errors}; emulated UART {report["baud"]:.0f} baud, '
              f'SCL {report["scl_hz"] / 1e3:.0f} kHz')
    return 0


if __name__ == '__main__':
    sys.exit(main())
