"""
The binary data frames of interface.md §1 (version 1) and 1b (version 2).

Version 1, 22 bytes::

    0xA5 0x5A | seq u8 | t_us u32 LE | ax ay az temp gx gy gz (7 x i16 BE) | crc8

CRC-8 (polynomial 0x07) over bytes 2..20.

Version 2, 25 bytes (32 with the magnetometer block)::

    0xA5 0x5B | flags | seq u16 LE | t_us u32 LE | 7 x i16 BE
      [| HXL HXH HYL HYH HZL HZH ST2]  (flags bit 0)  | crc16 LE

CRC-16/CCITT-FALSE over bytes 2 .. end-2. Flag bits 1..7 are reserved and must be 0.
"""

import struct
from typing import NamedTuple, Optional, Tuple

from .crc import crc16, crc8

SYNC0 = 0xA5
SYNC_V1 = b'\xa5\x5a'
SYNC_V2 = b'\xa5\x5b'
SYNC = SYNC_V1
"""Sync word of frame version 1 (the name older code imports)."""
FRAME_SIZE = 22
"""Size of a version-1 frame, bytes."""
FRAME_V1_SIZE = 22
FRAME_V2_SIZE = 25
"""Size of a version-2 frame without the magnetometer block, bytes."""
MAG_BLOCK_SIZE = 7
FRAME_V2_MAG_SIZE = FRAME_V2_SIZE + MAG_BLOCK_SIZE
FLAG_MAG = 0x01
"""Version-2 flags bit 0: the AK8963 block is present."""
FLAGS_RESERVED = 0xFE
ST2_HOFL = 0x08
"""AK8963 ST2 bit 3: magnetic sensor overflow (the sample is not valid)."""
ST2_BITM = 0x10
"""AK8963 ST2 bit 4: 16-bit output (0.15 µT per count; 14-bit: 0.6 µT)."""
INT16_MIN, INT16_MAX = -32768, 32767

HEAD_V1 = struct.Struct('<BI')
HEAD_V2 = struct.Struct('<BHI')
BLOCK = struct.Struct('>7h')
MAG = struct.Struct('<3hB')


class RawFrame(NamedTuple):
    """
    One sample as it came off the wire, in raw counts.

    :param seq: frame counter, 0..255 (version 1) or 0..65535 (version 2); None for ASCII.
    :param t_us: device clock in µs, uint32 (None when the source does not send it).
    :param counts: seven ints (ax, ay, az, temp, gx, gy, gz).
    :param mag: AK8963 block (hx, hy, hz, st2): three int16 counts in the magnetometer's own
        axes and its ST2 byte; None when the frame carries no magnetometer block.
    :param version: frame version, 1 or 2 (ASCII lines, which have none, say 1).
    """

    seq: Optional[int]
    t_us: Optional[int]
    counts: Tuple[int, ...]
    mag: Optional[Tuple[int, int, int, int]] = None
    version: int = 1


def encode_frame(seq, t_us, counts):
    """
    Encode one version-1 frame.

    :param seq: frame counter (taken modulo 256).
    :param t_us: device clock in µs (taken modulo 2**32).
    :param counts: seven int16 counts (ax, ay, az, temp, gx, gy, gz).
    :return: 22 bytes.
    :raises struct.error: a count is outside int16.
    """
    body = HEAD_V1.pack(int(seq) & 0xFF, int(t_us) & 0xFFFFFFFF) + \
        BLOCK.pack(*(int(c) for c in counts))
    return SYNC_V1 + body + bytes((crc8(body),))


def encode_frame_v2(seq, t_us, counts, mag=None):
    """
    Encode one version-2 frame.

    :param seq: sample counter (taken modulo 65536).
    :param t_us: device clock in µs (taken modulo 2**32).
    :param counts: seven int16 counts (ax, ay, az, temp, gx, gy, gz).
    :param mag: None, or (hx, hy, hz, st2): AK8963 counts (int16, its own axes) and ST2.
    :return: 25 bytes, or 32 with the magnetometer block.
    :raises struct.error: a count is outside int16 (or st2 outside 0..255).
    """
    flags = 0 if mag is None else FLAG_MAG
    body = HEAD_V2.pack(flags, int(seq) & 0xFFFF, int(t_us) & 0xFFFFFFFF) + \
        BLOCK.pack(*(int(c) for c in counts))
    if mag is not None:
        body += MAG.pack(*(int(v) for v in mag))
    return SYNC_V2 + body + struct.pack('<H', crc16(body))


def encode(frame):
    """
    Encode a :class:`RawFrame` in its own version.

    :param frame: RawFrame with ``version`` 1 or 2.
    :return: bytes.
    :raises ValueError: another version, or a magnetometer block on a version-1 frame.
    """
    if frame.version == 2:
        return encode_frame_v2(frame.seq, frame.t_us, frame.counts, frame.mag)
    if frame.version == 1 and frame.mag is None:
        return encode_frame(frame.seq, frame.t_us, frame.counts)
    raise ValueError(f'cannot encode a version-{frame.version} frame'
                     + (' with a magnetometer block' if frame.mag is not None else ''))


def frame_size(data, start=0):
    """
    Size of the data frame that starts at ``data[start]`` from its header bytes.

    :return: bytes of the frame, 0 when the header is not a data frame header, or None
        when more bytes are needed to tell.
    """
    if len(data) < start + 2:
        return None
    if data[start] != SYNC0:
        return 0
    kind = data[start + 1]
    if kind == 0x5A:
        return FRAME_V1_SIZE
    if kind != 0x5B:
        return 0
    if len(data) < start + 3:
        return None
    flags = data[start + 2]
    if flags & FLAGS_RESERVED:
        return 0
    return FRAME_V2_MAG_SIZE if flags & FLAG_MAG else FRAME_V2_SIZE


def decode_frame(data):
    """
    Decode exactly one data frame (either version), checking its sync, flags and CRC.

    :param data: bytes of one frame.
    :return: RawFrame, or None when it is not a valid frame of that exact length.
    """
    size = frame_size(data)
    if not size or size != len(data):
        return None
    if data[1] == 0x5A:
        if crc8(data[2:size]) != 0:
            return None
        seq, t_us = HEAD_V1.unpack_from(data, 2)
        return RawFrame(seq, t_us, BLOCK.unpack_from(data, 7))
    if crc16(data[2:size - 2]) != data[size - 2] | (data[size - 1] << 8):
        return None
    flags, seq, t_us = HEAD_V2.unpack_from(data, 2)
    mag = MAG.unpack_from(data, 23) if flags & FLAG_MAG else None
    return RawFrame(seq, t_us, BLOCK.unpack_from(data, 9), mag, 2)
