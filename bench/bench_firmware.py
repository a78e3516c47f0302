"""
Benchmark: the firmware on the emulated board (simavr): throughput and recovery.

Builds the firmware (frame version 2 at 1 MBd, version 1 at 1 MBd, version 2 at 115200
baud) and the board (test/firmware/hil/mpu_board.c; needs the Debian packages of docs/firmware.md),
runs each for ``--seconds`` simulated seconds as fast as the host allows, parses the UART
with the driver's parser and prints flash/RAM used, frames per simulated second, lost
samples (seq gaps), CRC errors and magnetometer blocks per second. Then it injects each
fault of the board once (INT silent for 50 ms, the sensor's registers lost, I2C not
acknowledged for 40 ms, SDA held low for 30 ms) and prints the outage, how long after the
fault's end the stream resumed, the recoveries and the samples counted as lost::

    python bench/bench_firmware.py [--seconds 10]
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile

from accel_calib_ros.dataio.wire import FrameParser

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(ROOT, 'test'))
FAULTS = ['int-silent:1000:50', 'brownout:1000.5', 'nack:1000:40', 'sda-stuck:1000:30']


def run_board(board, elf, out, *args):
    run = subprocess.run([board, '--elf', elf, '--uart-out', out, '--fast'] + list(args),
                         capture_output=True, text=True, check=True)
    report = json.loads(run.stdout.strip().splitlines()[-1])
    parser = FrameParser()
    with open(out, 'rb') as f:
        frames = parser.feed(f.read()) + parser.flush()
    return report, frames, parser


def main():
    from firmware_tools import build_firmware, build_harness, ENSURE
    ap = argparse.ArgumentParser(description=__doc__.strip().splitlines()[0])
    ap.add_argument('--seconds', type=float, default=10.0)
    args = ap.parse_args()
    if subprocess.run(['sh', ENSURE, 'hil']).returncode:
        return 1
    work = tempfile.mkdtemp(prefix='bench_firmware_')
    board = build_harness(work)
    status = 0
    elfs = {}
    for name, settings in (('v2 1 MBd', {}), ('v1 1 MBd', {'FW_FRAME_VERSION': 1}),
                           ('v2 115200 Bd', {'FW_BAUD': 115200})):
        elf = build_firmware(os.path.join(work, name.replace(' ', '-')), **settings)
        elfs[name] = elf
        size = subprocess.run(['avr-size', '-C', '--mcu=atmega328p', elf], capture_output=True,
                              text=True).stdout
        used = [line.strip() for line in size.splitlines() if line.startswith(('Program',
                                                                               'Data'))]
        report, frames, parser = run_board(board, elf, os.path.join(work, 'uart.bin'),
                                           '--seconds', str(args.seconds))
        span_s = ((frames[-1].t_us - frames[0].t_us) & 0xFFFFFFFF) * 1e-6
        samples = len(frames) + parser.lost_frames
        print(f'{name} {settings or ""}: {"; ".join(used)}')
        print(f'  {len(frames)} frames in {span_s:.3f} s of device time: '
              f'{len(frames) / span_s:.1f} frames/s of {samples / span_s:.1f} samples/s; '
              f'lost samples {parser.lost_frames} ({100.0 * parser.lost_frames / samples:.1f} %),'
              f' CRC errors {parser.crc_errors}; emulated UART {report["baud"]:.0f} baud, '
              f'SCL {report["scl_hz"] / 1e3:.0f} kHz; {report["wall_seconds"]:.2f} s of wall '
              f'time; AK8963 blocks {sum(f.mag is not None for f in frames) / span_s:.1f}/s '
              f'of {report["mag_samples"] / report["sim_seconds"]:.1f} measurements/s')
        status |= parser.crc_errors != 0
    print('recovery (v2 1 MBd, faults at 1.0 s of simulated time):')
    for spec in FAULTS:
        report, frames, parser = run_board(board, elfs['v2 1 MBd'],
                                           os.path.join(work, 'fault.bin'), '--seconds', '2',
                                           '--fault', spec)
        (fault,) = report['faults']
        before = [f for f in frames if f.t_us < fault['start_us']]
        after = [f for f in frames if f.t_us >= fault['start_us']]
        info = parser.take_infos()[-1]
        outage = (after[0].t_us - before[-1].t_us) / 1000
        resumed = (after[0].t_us - fault['end_us']) / 1000
        gap = (after[0].seq - before[-1].seq) & 0xFFFF
        print(f'  {spec:22s} outage {outage:5.1f} ms, resumed {resumed:5.1f} ms after the fault '
              f'ended; {info.recoveries} recoveries ({info.recovery_text}), '
              f'{info.i2c_errors} failed I2C transfers, {report["scl_pulses"]} SCL pulses; '
              f'seq gap {gap}, lost samples counted {parser.lost_frames}')
        status |= not 0 <= resumed <= 50 or parser.lost_frames != gap - 1
    return status


if __name__ == '__main__':
    sys.exit(main())
