"""
Raw counts to SI units (REP-103) and back: accelerometer, gyroscope, temperature, AK8963.

Sensitivities from the InvenSense MPU-9250 register map and the AK8963 datasheet.
"""

import math

from .frames import INT16_MAX, INT16_MIN, ST2_BITM, ST2_HOFL
from ...core.constants import G0

ACCEL_LSB_PER_G = {2: 16384.0, 4: 8192.0, 8: 4096.0, 16: 2048.0}
"""Accelerometer sensitivity per full-scale range (±g), counts per g."""
GYRO_LSB_PER_DPS = {250: 131.0, 500: 65.5, 1000: 32.8, 2000: 16.4}
"""Gyroscope sensitivity per full-scale range (±°/s), counts per °/s."""
TEMP_LSB_PER_C = 333.87
TEMP_OFFSET_C = 21.0
TEMP_FORMULAS = {'mpu6500': (333.87, 21.0), 'mpu6050': (340.0, 36.53)}
"""Temperature count per °C and offset: MPU-6500/9250/9255 and MPU-6050 families."""
MAG_UT_PER_COUNT = {True: 0.15, False: 0.6}
"""AK8963 sensitivity, µT per count: 16-bit output (ST2 BITM set) and 14-bit output."""
MAG_COUNTS_MAX = 32760
"""AK8963 16-bit measurement range, counts (±4912 µT)."""


def _range_key(name, value, table, unit):
    try:
        number = float(value)
    except (TypeError, ValueError):
        number = math.nan
    for key in table:
        if number == key:
            return key
    allowed = ', '.join(str(k) for k in table)
    raise ValueError(f'unsupported {name} {value!r}: use one of {allowed} ({unit})')


def accel_scale(range_g):
    """
    Return m/s² per count for an accelerometer full-scale range.

    :param range_g: ±2, 4, 8 or 16 g.
    :raises ValueError: unsupported range.
    """
    return G0 / ACCEL_LSB_PER_G[_range_key('accelerometer range', range_g, ACCEL_LSB_PER_G,
                                           '±g')]


def gyro_scale(range_dps):
    """
    Return rad/s per count for a gyroscope full-scale range.

    :param range_dps: ±250, 500, 1000 or 2000 °/s.
    :raises ValueError: unsupported range.
    """
    key = _range_key('gyroscope range', range_dps, GYRO_LSB_PER_DPS, '±°/s')
    return math.radians(1.0) / GYRO_LSB_PER_DPS[key]


def temp_c(count):
    """Temperature in °C of a raw count (MPU-6500/9250 formula)."""
    return count / TEMP_LSB_PER_C + TEMP_OFFSET_C


class Converter:
    """
    Raw counts to SI units (REP-103) and back, for given full-scale ranges.

    :param accel_range_g: ±2, 4, 8 or 16.
    :param gyro_range_dps: ±250, 500, 1000 or 2000.
    :param temp_formula: ``mpu6500`` (MPU-6500/9250/9255: counts/333.87 + 21 °C) or
        ``mpu6050`` (counts/340 + 36.53 °C).
    :raises ValueError: unsupported range or formula, with the allowed values.
    """

    def __init__(self, accel_range_g=2, gyro_range_dps=250, temp_formula='mpu6500'):
        self.accel_scale = accel_scale(accel_range_g)
        self.gyro_scale = gyro_scale(gyro_range_dps)
        if temp_formula not in TEMP_FORMULAS:
            raise ValueError(f'unsupported temperature formula {temp_formula!r}: use one of '
                             f'{", ".join(TEMP_FORMULAS)}')
        self.temp_formula = temp_formula
        self.temp_lsb_per_c, self.temp_offset_c = TEMP_FORMULAS[temp_formula]

    def to_si(self, counts):
        """
        Convert seven counts to SI.

        :param counts: (ax, ay, az, temp, gx, gy, gz) counts.
        :return: ((ax, ay, az) m/s², temperature °C, (gx, gy, gz) rad/s).
        """
        a = self.accel_scale
        g = self.gyro_scale
        ax, ay, az, t, gx, gy, gz = counts
        return ((ax * a, ay * a, az * a), t / self.temp_lsb_per_c + self.temp_offset_c,
                (gx * g, gy * g, gz * g))

    def to_counts(self, accel, temp, gyro):
        """
        Convert SI readings to seven counts, rounded and clipped to int16 (the device side).

        :param accel: (3,) m/s².
        :param temp: °C.
        :param gyro: (3,) rad/s.
        :return: tuple of seven ints.
        """
        def clip(value):
            return max(INT16_MIN, min(INT16_MAX, int(round(value))))
        return (tuple(clip(v / self.accel_scale) for v in accel) +
                (clip((temp - self.temp_offset_c) * self.temp_lsb_per_c),) +
                tuple(clip(v / self.gyro_scale) for v in gyro))

    def to_counts_array(self, accel, temp, gyro):
        """
        Vectorised :meth:`to_counts`.

        :param accel: (N, 3) m/s².
        :param temp: (N,) °C.
        :param gyro: (N, 3) rad/s.
        :return: (N, 7) int16 array.
        """
        import numpy as np
        accel = np.asarray(accel, float).reshape(-1, 3)
        n = len(accel)
        out = np.empty((n, 7))
        out[:, :3] = accel / self.accel_scale
        out[:, 3] = (np.broadcast_to(np.asarray(temp, float), (n,)) - self.temp_offset_c) \
            * self.temp_lsb_per_c
        out[:, 4:] = np.asarray(gyro, float).reshape(-1, 3) / self.gyro_scale
        return np.clip(np.round(out), INT16_MIN, INT16_MAX).astype(np.int16)


def asa_factor(asa):
    """
    AK8963 factory sensitivity adjustment of one axis: (ASA − 128)/256 + 1.

    :param asa: fuse ROM byte, 0..255.
    """
    return (asa - 128) / 256.0 + 1.0


class MagConverter:
    """
    AK8963 counts (its own axes) to tesla in the accelerometer's frame, and back.

    The AK8963 inside an MPU-9250 is mounted with x_mag = y_acc, y_mag = x_acc,
    z_mag = −z_acc, so x_acc = y_mag, y_acc = x_mag, z_acc = −z_mag. Each magnetometer
    axis is scaled by 0.15 µT per count (16-bit output; 0.6 µT for 14-bit) times its
    factory adjustment :func:`asa_factor`.

    :param asa: (ASAX, ASAY, ASAZ) from the fuse ROM (the info frame); (128, 128, 128)
        means no adjustment.
    :raises ValueError: an ASA value outside 0..255.
    """

    def __init__(self, asa=(128, 128, 128)):
        asa = tuple(int(a) for a in asa)
        if len(asa) != 3 or any(not 0 <= a <= 255 for a in asa):
            raise ValueError(f'ASA must be three bytes 0..255, got {asa!r}')
        self.asa = asa
        self.adjust = tuple(asa_factor(a) for a in asa)

    def to_tesla(self, mag):
        """
        Convert one AK8963 block.

        :param mag: (hx, hy, hz, st2) counts and ST2.
        :return: (x, y, z) tesla in the accelerometer frame, or None when ST2 reports an
            overflow (HOFL: the sample is not valid).
        """
        hx, hy, hz, st2 = mag
        if st2 & ST2_HOFL:
            return None
        ut = MAG_UT_PER_COUNT[bool(st2 & ST2_BITM)] * 1e-6
        ax, ay, az = self.adjust
        return (hy * ut * ay, hx * ut * ax, -hz * ut * az)

    def to_counts(self, field_t):
        """
        Convert a field in the accelerometer frame to an AK8963 block (16-bit output).

        :param field_t: (x, y, z) tesla, accelerometer frame.
        :return: (hx, hy, hz, st2) with ST2 BITM set, and HOFL set when an axis is beyond
            the measurement range (the counts are then clipped).
        """
        x, y, z = (float(v) for v in field_t)
        ut = MAG_UT_PER_COUNT[True] * 1e-6
        ax, ay, az = self.adjust
        raw = (y / (ut * ax), x / (ut * ay), -z / (ut * az))      # hx, hy, hz
        st2 = ST2_BITM
        out = []
        for value in raw:
            if not math.isfinite(value) or abs(value) > MAG_COUNTS_MAX:
                st2 |= ST2_HOFL
                value = 0.0 if math.isnan(value) else math.copysign(MAG_COUNTS_MAX, value)
            out.append(int(round(value)))
        return (out[0], out[1], out[2], st2)
