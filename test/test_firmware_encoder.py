"""The firmware's portable C frame encoder, compiled for the host, against the Python one."""

import subprocess

from accel_calib_ros.dataio.mpu9250_frame import (decode_info, encode_frame, encode_info,
                                                  FrameParser, InfoFrame)
from firmware_tools import build_host_encoder, ensure_toolchain
import numpy as np
import pytest


@pytest.fixture(scope='module')
def encoder(tmp_path_factory):
    ensure_toolchain('host')
    return build_host_encoder(tmp_path_factory.mktemp('encoder'))


def run_encoder(exe, lines):
    out = subprocess.run([exe], input='\n'.join(lines) + '\n', capture_output=True,
                         text=True, timeout=60, check=True).stdout.split()
    return [bytes.fromhex(h) for h in out]


def test_data_frames_byte_identical(encoder):
    rng = np.random.default_rng(9)
    n = 3000
    counts = rng.integers(-32768, 32768, (n, 7))
    counts[:5] = [[-32768] * 7, [32767] * 7, [0] * 7, [-1] * 7, [1, -1, 256, -256, 255, 0, 0]]
    seqs = rng.integers(0, 256, n)
    t_us = rng.integers(0, 2 ** 32, n, dtype=np.uint64)
    seqs[5:9] = [254, 255, 0, 1]                               # seq wrap
    t_us[5:9] = [2 ** 32 - 2000, 2 ** 32 - 1000, 0, 1000]      # t_us wrap
    counts[5:9, 3] = 1000                                       # a plausible 24 °C
    lines = [f'D {s} {t} ' + ' '.join(str(c) for c in row)
             for s, t, row in zip(seqs.tolist(), t_us.tolist(), counts.tolist())]
    got = run_encoder(encoder, lines)
    want = [encode_frame(s, t, row) for s, t, row in
            zip(seqs.tolist(), t_us.tolist(), counts.tolist())]
    assert len(got) == n
    assert got == want
    parser = FrameParser()                      # the wrap frames 5..8 continue each other
    out = parser.feed(b''.join(got[5:9])) + parser.flush()
    assert [(f.seq, f.t_us) for f in out] == [(254, 2 ** 32 - 2000), (255, 2 ** 32 - 1000),
                                              (0, 0), (1, 1000)]
    assert parser.lost_frames == 0


def test_info_frames_byte_identical(encoder):
    rng = np.random.default_rng(10)
    infos = [InfoFrame(0, 0x71, 2, 250, 1000, 1, 1_000_000, (1, 0)),
             InfoFrame(1, 0x12, 16, 2000, 4, 6, 115200, (255, 255))]
    for _ in range(300):
        infos.append(InfoFrame(int(rng.integers(0, 4)), int(rng.integers(0, 256)),
                               int(rng.choice([2, 4, 8, 16])),
                               int(rng.choice([250, 500, 1000, 2000])),
                               int(rng.integers(1, 65536)), int(rng.integers(0, 8)),
                               int(rng.integers(0, 2 ** 32)),
                               (int(rng.integers(0, 256)), int(rng.integers(0, 256)))))
    lines = [f'I {i.status} {i.who_am_i} {i.accel_range_g} {i.gyro_range_dps} {i.rate_hz} '
             f'{i.dlpf_cfg} {i.baud} {i.fw_version[0]} {i.fw_version[1]}' for i in infos]
    got = run_encoder(encoder, lines)
    assert got == [encode_info(i) for i in infos]
    assert [decode_info(f) for f in got] == infos
    assert infos[0].chip == 'MPU-9250' and infos[1].chip.startswith('unknown')
    broken = bytearray(got[0])
    broken[5] ^= 0x01
    assert decode_info(bytes(broken)) is None
    parser = FrameParser()
    assert parser.feed(b''.join(got[:2])) == []
    assert parser.take_infos() == infos[:2] and parser.take_infos() == []
