"""
The firmware's info frame (docs/firmware.md): what the board found and configured.

Two layouts, both decoded:

- version 1 (``0xA5 0x49``, 22 bytes, CRC-8): status, chip, ranges, rate, baud, firmware
  version; sent by firmware 1.x;
- version 2 (``0xA5 0x4A``, 34 bytes, CRC-16/CCITT-FALSE): the same, plus the data frame
  version the firmware sends, the magnetometer (AK8963 presence and its factory
  sensitivity adjustment ASA), and the recovery counters (sensor re-initialisations,
  failed I²C transfers, cause of the last recovery).
"""

import struct
from typing import NamedTuple, Tuple

from .chips import chip_name
from .crc import crc16, crc8

INFO_SYNC = b'\xa5\x49'
INFO_V2_SYNC = b'\xa5\x4a'
INFO_SIZE = 22
INFO_V2_SIZE = 34
INFO_MAGIC = b'ACFW'
INFO_VERSION = 1
INFO_STATUS = {0: 'streaming', 1: 'unknown chip (WHO_AM_I not recognised): not streaming',
               2: 'no sensor answers at I2C address 0x68: not streaming',
               3: 'sensor did not accept its configuration: not streaming'}
MAG_UNKNOWN, MAG_ABSENT, MAG_AK8963, MAG_FAILED = 255, 0, 1, 2
MAG_STATUS = {MAG_UNKNOWN: 'not reported by the firmware',
              MAG_ABSENT: 'absent (no AK8963 answers)',
              MAG_AK8963: 'AK8963',
              MAG_FAILED: 'AK8963 did not accept its configuration'}
"""Values of the info frame's magnetometer field."""
RECOVERY_CAUSES = {0: 'none', 1: 'data-ready silent', 2: 'I2C not acknowledged',
                   3: 'I2C transfer timed out', 4: 'I2C bus stuck (SDA held low)'}
"""Cause of the firmware's last sensor recovery (info frame version 2)."""

_INFO = struct.Struct('<BBBBHHBIBB4s')
_INFO_V2 = struct.Struct('<BBBBHHBIBBBB3sHHBB4s')


class InfoFrame(NamedTuple):
    """
    The firmware's info frame.

    :param status: 0 streaming, 1 unknown chip, 2 no sensor answer, 3 configuration failed.
    :param who_am_i: the sensor's WHO_AM_I register (0 when nothing answered).
    :param accel_range_g: accelerometer full scale, ±g.
    :param gyro_range_dps: gyroscope full scale, ±°/s.
    :param rate_hz: configured sample rate, Hz.
    :param dlpf_cfg: CONFIG.DLPF_CFG.
    :param baud: UART baud rate the firmware was built for.
    :param fw_version: (major, minor).
    :param frame_version: version of the data frames the firmware sends (1 or 2).
    :param mag_status: :data:`MAG_STATUS` key (:data:`MAG_UNKNOWN` in a version-1 info frame).
    :param asa: AK8963 factory sensitivity adjustment (ASAX, ASAY, ASAZ), 0..255 each; zeros
        when there is no AK8963.
    :param recoveries: sensor recoveries (bus recovery, re-initialisation and read-back of the
        configuration) since start-up, uint16.
    :param i2c_errors: I²C transfers that failed (not acknowledged, timed out, bus stuck),
        uint16.
    :param last_recovery: :data:`RECOVERY_CAUSES` key of the last recovery.
    :param info_version: layout of the frame it was decoded from (1 or 2).
    """

    status: int
    who_am_i: int
    accel_range_g: int
    gyro_range_dps: int
    rate_hz: int
    dlpf_cfg: int
    baud: int
    fw_version: Tuple[int, int]
    frame_version: int = 1
    mag_status: int = MAG_UNKNOWN
    asa: Tuple[int, int, int] = (0, 0, 0)
    recoveries: int = 0
    i2c_errors: int = 0
    last_recovery: int = 0
    info_version: int = 1

    @property
    def chip(self):
        """Chip name from WHO_AM_I (``chips.CHIPS``; 'unknown (0x..)' otherwise)."""
        return chip_name(self.who_am_i)

    @property
    def status_text(self):
        """Return the status in words."""
        return INFO_STATUS.get(self.status, f'status {self.status}')

    @property
    def mag_text(self):
        """Return the magnetometer status in words."""
        return MAG_STATUS.get(self.mag_status, f'magnetometer status {self.mag_status}')

    @property
    def recovery_text(self):
        """Return the cause of the last recovery in words."""
        return RECOVERY_CAUSES.get(self.last_recovery, f'cause {self.last_recovery}')


def encode_info(info):
    """
    Encode a version-1 info frame (22 bytes, the layout of firmware 1.x).

    :param info: InfoFrame (the fields after ``fw_version`` are not in this layout).
    :return: bytes.
    """
    body = _INFO.pack(INFO_VERSION, info.status, info.who_am_i, info.accel_range_g,
                      info.gyro_range_dps, info.rate_hz, info.dlpf_cfg, info.baud,
                      info.fw_version[0], info.fw_version[1], INFO_MAGIC)
    return INFO_SYNC + body + bytes((crc8(body),))


def encode_info_v2(info):
    """
    Encode a version-2 info frame (34 bytes).

    :param info: InfoFrame.
    :return: bytes.
    :raises struct.error: a field outside its width.
    """
    body = _INFO_V2.pack(2, info.status, info.who_am_i, info.accel_range_g,
                         info.gyro_range_dps, info.rate_hz, info.dlpf_cfg, info.baud,
                         info.fw_version[0], info.fw_version[1], info.frame_version,
                         info.mag_status, bytes(info.asa), info.recoveries, info.i2c_errors,
                         info.last_recovery, 0, INFO_MAGIC)
    return INFO_V2_SYNC + body + struct.pack('<H', crc16(body))


def decode_info(frame):
    """
    Decode an info frame of either layout.

    :param frame: bytes starting with an info sync (longer input is allowed).
    :return: InfoFrame, or None when it is not a valid info frame.
    """
    head = bytes(frame[:2])
    if head == INFO_SYNC:
        if len(frame) < INFO_SIZE or crc8(frame[2:INFO_SIZE]) != 0:
            return None
        (version, status, who, accel, gyro, rate, dlpf, baud, major, minor,
         magic) = _INFO.unpack_from(frame, 2)
        if version != INFO_VERSION or magic != INFO_MAGIC:
            return None
        return InfoFrame(status, who, accel, gyro, rate, dlpf, baud, (major, minor))
    if head == INFO_V2_SYNC:
        end = INFO_V2_SIZE
        if len(frame) < end or \
                crc16(frame[2:end - 2]) != frame[end - 2] | (frame[end - 1] << 8):
            return None
        (version, status, who, accel, gyro, rate, dlpf, baud, major, minor, frame_version,
         mag, asa, recoveries, i2c_errors, cause, _, magic) = _INFO_V2.unpack_from(frame, 2)
        if version != 2 or magic != INFO_MAGIC:
            return None
        return InfoFrame(status, who, accel, gyro, rate, dlpf, baud, (major, minor),
                         frame_version, mag, tuple(asa), recoveries, i2c_errors, cause, 2)
    return None
