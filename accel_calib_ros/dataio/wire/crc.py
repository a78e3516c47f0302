"""
Check values of the serial frames: CRC-8 (frame version 1) and CRC-16 (version 2).

Both are plain, non-reflected CRCs with no final xor; the tables are built here from the
polynomials, and the tests compare them with a textbook bit-by-bit computation.
"""

import binascii


def _make_crc8_table():
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = ((crc << 1) ^ 0x07) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table.append(crc)
    return tuple(table)


CRC8_TABLE = _make_crc8_table()
"""CRC-8 lookup table, polynomial 0x07."""


def crc8(data):
    """
    CRC-8 (polynomial 0x07, init 0, no reflection, no final xor) of ``data``.

    :param data: bytes-like object.
    :return: int in 0..255.
    """
    table = CRC8_TABLE
    crc = 0
    for byte in data:
        crc = table[crc ^ byte]
    return crc


def crc16(data, init=0xFFFF):
    """
    CRC-16/CCITT-FALSE (polynomial 0x1021, init 0xFFFF, no reflection, no final xor).

    ``binascii.crc_hqx`` is this CRC with a caller-given initial value (CRC-16/XMODEM
    with init 0), computed in C.

    :param data: bytes-like object.
    :param init: initial value (0xFFFF for CCITT-FALSE).
    :return: int in 0..65535 (check value of b'123456789': 0x29B1).
    """
    return binascii.crc_hqx(data, init)
