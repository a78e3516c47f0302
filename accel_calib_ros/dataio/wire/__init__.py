"""
The MPU9250 serial wire: frames, info frames, parser, ASCII lines, units, device clock.

ROS-free and hardware-free, so it can be tested and benchmarked on its own.

- :mod:`.frames`: data frames, version 1 (interface.md §1, 22 bytes, CRC-8) and
  version 2 (section 1b, 25 or 32 bytes, CRC-16, optional AK8963 block);
- :mod:`.info`: the firmware's info frame, both layouts (docs/firmware.md);
- :mod:`.parser`: :class:`FrameParser`, the incremental parser that never raises;
- :mod:`.ascii`: the hobby-firmware text line format;
- :mod:`.chips`: the sensor chips by WHO_AM_I (temperature formula, ranges and
  sensitivities, magnetometer): the one home of every chip fact;
- :mod:`.conversion`: counts to SI (accelerometer, gyroscope, temperature, the magnetometer
  in tesla);
- :mod:`.clock`: :class:`ClockMapper`, device µs clock onto host time.
"""

from .ascii import AsciiLineParser, encode_ascii_line
from .chips import (BY_KEY, Chip, chip_name, chip_of, CHIPS, DEFAULT_CHIP, Magnetometer,
                    MAGNETOMETERS, TEMP_FORMULAS)
from .clock import ClockMapper
from .conversion import (ACCEL_LSB_PER_G, accel_scale, asa_factor, Converter, G0, GYRO_LSB_PER_DPS,
                         gyro_scale, MAG_UT_PER_COUNT, MagConverter, temp_c)
from .crc import crc16, crc8, CRC8_TABLE
from .frames import (decode_frame, encode, encode_frame, encode_frame_v2, FLAG_MAG, FRAME_SIZE,
                     frame_size, FRAME_V1_SIZE, FRAME_V2_MAG_SIZE, FRAME_V2_SIZE, INT16_MAX,
                     INT16_MIN, MAG_BLOCK_SIZE, RawFrame, ST2_BITM, ST2_HOFL, SYNC, SYNC_V1,
                     SYNC_V2)
from .info import (decode_info, encode_info, encode_info_v2, INFO_MAGIC, INFO_SIZE,
                   INFO_STATUS, INFO_SYNC, INFO_V2_SIZE, INFO_V2_SYNC, INFO_VERSION, InfoFrame,
                   MAG_ABSENT, MAG_AK8963, MAG_FAILED, MAG_STATUS, MAG_UNKNOWN, RECOVERY_CAUSES)
from .parser import (FrameParser, MAX_GAP_S, QUALITY_WINDOW_FRAMES, SPIKE_COUNTS, STRICT_BELOW,
                     temp_counts_range, TEMP_PLAUSIBLE_C, TEMP_STEP_C)

__all__ = [
    'ACCEL_LSB_PER_G', 'accel_scale', 'asa_factor', 'AsciiLineParser', 'BY_KEY', 'Chip',
    'chip_name', 'chip_of', 'CHIPS', 'ClockMapper', 'DEFAULT_CHIP', 'Magnetometer',
    'MAGNETOMETERS', 'Converter', 'CRC8_TABLE', 'crc16', 'crc8', 'decode_frame', 'decode_info',
    'encode', 'encode_ascii_line', 'encode_frame', 'encode_frame_v2', 'encode_info',
    'encode_info_v2', 'FLAG_MAG', 'FRAME_SIZE', 'FRAME_V1_SIZE', 'FRAME_V2_MAG_SIZE',
    'FRAME_V2_SIZE', 'frame_size', 'FrameParser', 'G0', 'GYRO_LSB_PER_DPS', 'gyro_scale',
    'INFO_MAGIC', 'INFO_SIZE', 'INFO_STATUS', 'INFO_SYNC', 'INFO_V2_SIZE', 'INFO_V2_SYNC',
    'INFO_VERSION', 'InfoFrame', 'INT16_MAX', 'INT16_MIN', 'MAG_ABSENT', 'MAG_AK8963',
    'MAG_BLOCK_SIZE', 'MAG_FAILED', 'MAG_STATUS', 'MAG_UNKNOWN', 'MAG_UT_PER_COUNT',
    'MagConverter', 'MAX_GAP_S', 'QUALITY_WINDOW_FRAMES', 'RawFrame', 'RECOVERY_CAUSES',
    'SPIKE_COUNTS', 'ST2_BITM', 'ST2_HOFL', 'STRICT_BELOW', 'SYNC', 'SYNC_V1', 'SYNC_V2', 'temp_c',
    'temp_counts_range', 'TEMP_FORMULAS', 'TEMP_PLAUSIBLE_C', 'TEMP_STEP_C',
]
