"""The firmware's portable C frame encoder, compiled for the host, against the Python one."""

import subprocess

from accel_calib_ros.dataio.wire import (decode_frame, decode_info, encode_frame,
                                         encode_frame_v2, encode_info, encode_info_v2,
                                         FrameParser, InfoFrame, RawFrame)
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


def test_v2_data_frames_byte_identical(encoder):
    """Frame version 2, with and without the AK8963 block, seq and t_us wraps."""
    rng = np.random.default_rng(11)
    n = 3000
    counts = rng.integers(-32768, 32768, (n, 7))
    mags = rng.integers(-32768, 32768, (n, 3))
    st2 = rng.integers(0, 256, n)
    has_mag = rng.random(n) < 0.3
    counts[:4] = [[-32768] * 7, [32767] * 7, [0] * 7, [-1] * 7]
    mags[:4] = [[-32768] * 3, [32767] * 3, [0] * 3, [-1] * 3]
    seqs = rng.integers(0, 65536, n)
    t_us = rng.integers(0, 2 ** 32, n, dtype=np.uint64)
    seqs[5:9] = [65534, 65535, 0, 1]                           # seq wrap
    t_us[5:9] = [2 ** 32 - 2000, 2 ** 32 - 1000, 0, 1000]      # t_us wrap
    counts[5:9, 3] = 1000                                       # a plausible 24 °C
    lines, want = [], []
    for k in range(n):
        mag = tuple(mags[k].tolist()) + (int(st2[k]),) if has_mag[k] else None
        block = ' '.join(str(v) for v in (mag or (0, 0, 0, 0)))
        lines.append(f'E {seqs[k]} {t_us[k]} ' + ' '.join(str(c) for c in counts[k].tolist())
                     + f' {int(has_mag[k])} {block}')
        want.append(encode_frame_v2(int(seqs[k]), int(t_us[k]), counts[k].tolist(), mag))
    got = run_encoder(encoder, lines)
    assert len(got) == n and got == want
    assert {len(g) for g in got} == {25, 32}
    assert [decode_frame(g).mag is not None for g in got] == has_mag.tolist()
    parser = FrameParser()                      # the wrap frames 5..8 continue each other
    out = parser.feed(b''.join(got[5:9])) + parser.flush()
    assert [(f.seq, f.t_us, f.version) for f in out] == [
        (65534, 2 ** 32 - 2000, 2), (65535, 2 ** 32 - 1000, 2), (0, 0, 2), (1, 1000, 2)]
    assert parser.lost_frames == 0


def test_v2_info_frames_byte_identical(encoder):
    rng = np.random.default_rng(12)
    infos = [InfoFrame(0, 0x71, 2, 250, 1000, 1, 1_000_000, (2, 0), 2, 1, (176, 177, 165), 0,
                       0, 0, 2),
             InfoFrame(2, 0, 16, 2000, 4, 6, 115200, (255, 255), 1, 0, (0, 0, 0), 65535,
                       65535, 4, 2)]
    for _ in range(300):
        infos.append(InfoFrame(
            int(rng.integers(0, 4)), int(rng.integers(0, 256)), int(rng.choice([2, 4, 8, 16])),
            int(rng.choice([250, 500, 1000, 2000])), int(rng.integers(1, 65536)),
            int(rng.integers(0, 8)), int(rng.integers(0, 2 ** 32)),
            (int(rng.integers(0, 256)), int(rng.integers(0, 256))), int(rng.integers(1, 3)),
            int(rng.integers(0, 3)), tuple(int(v) for v in rng.integers(0, 256, 3)),
            int(rng.integers(0, 65536)), int(rng.integers(0, 65536)), int(rng.integers(0, 5)),
            2))
    lines = [f'J {i.status} {i.who_am_i} {i.accel_range_g} {i.gyro_range_dps} {i.rate_hz} '
             f'{i.dlpf_cfg} {i.baud} {i.fw_version[0]} {i.fw_version[1]} {i.frame_version} '
             f'{i.mag_status} {i.asa[0]} {i.asa[1]} {i.asa[2]} {i.recoveries} {i.i2c_errors} '
             f'{i.last_recovery}' for i in infos]
    got = run_encoder(encoder, lines)
    assert got == [encode_info_v2(i) for i in infos]
    assert [decode_info(f) for f in got] == infos
    parser = FrameParser()
    frame = encode_frame_v2(1, 1000, (0, 0, 16384, 1000, 0, 0, 0))
    assert parser.feed(got[0] + frame + got[1]) == []           # one frame: unconfirmed
    assert parser.take_infos() == infos[:2]
    assert decode_frame(frame) == RawFrame(1, 1000, (0, 0, 16384, 1000, 0, 0, 0), None, 2)


def test_the_chip_list_of_the_spec_the_firmware_and_the_driver_agree():
    """Regression: interface.md §7 listed ICM-20608-class parts the firmware refuses."""
    import os
    import re
    from accel_calib_ros.dataio.wire import CHIPS
    from firmware_tools import FIRMWARE, ROOT
    with open(os.path.join(FIRMWARE, 'src', 'main.c')) as f:
        source = f.read()
    known = re.search(r'known_chip\(uint8_t who\)\s*{\s*return ([^;]*);', source).group(1)
    firmware = {int(h, 16) for h in re.findall(r'who == (0x[0-9a-fA-F]+)', known)}
    with open(os.path.join(ROOT, 'docs', 'interface.md')) as f:
        section = f.read().split('## 7. Firmware')[1].split('## 8.')[0]
    streamed = section.split('the chips the firmware streams')[0].split('WHO_AM_I')[-1]
    spec = {int(h, 16) for h in re.findall(r'0x[0-9a-fA-F]{2}', streamed)}
    assert firmware == spec == set(CHIPS) == {0x71, 0x73, 0x70, 0x68}
    assert 'ICM' not in section.split('the chips the firmware streams')[0]
