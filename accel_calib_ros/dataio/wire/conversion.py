"""
Raw counts to SI units (REP-103) and back: accelerometer, gyroscope, temperature, magnetometer.

The sensitivities, temperature formulas and magnetometer steps are the chip's
(:mod:`.chips`, the one home of them); the MPU-9250 and its AK8963 unless told otherwise.
"""

import math

from .chips import AK8963, DEFAULT_CHIP, TEMP_FORMULAS
from .frames import INT16_MAX, INT16_MIN, ST2_BITM, ST2_HOFL
from ...core.constants import G0

ACCEL_LSB_PER_G = DEFAULT_CHIP.accel_lsb_per_g
"""Accelerometer sensitivity per full-scale range (±g), counts per g (the default chip's)."""
GYRO_LSB_PER_DPS = DEFAULT_CHIP.gyro_lsb_per_dps
"""Gyroscope sensitivity per full-scale range (±°/s), counts per °/s (the default chip's)."""
MAG_UT_PER_COUNT = {True: AK8963.ut_per_count[16], False: AK8963.ut_per_count[14]}
"""AK8963 sensitivity, µT per count: 16-bit output (ST2 BITM set) and 14-bit output."""


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


def accel_scale(range_g, chip=DEFAULT_CHIP):
    """
    Return m/s² per count for an accelerometer full-scale range of ``chip``.

    :param range_g: a full-scale range of the chip, ±g (2, 4, 8 or 16 on the MPU family).
    :raises ValueError: unsupported range.
    """
    table = chip.accel_lsb_per_g
    return G0 / table[_range_key('accelerometer range', range_g, table, '±g')]


def gyro_scale(range_dps, chip=DEFAULT_CHIP):
    """
    Return rad/s per count for a gyroscope full-scale range of ``chip``.

    :param range_dps: a full-scale range of the chip, ±°/s (250 .. 2000 on the MPU family).
    :raises ValueError: unsupported range.
    """
    table = chip.gyro_lsb_per_dps
    return math.radians(1.0) / table[_range_key('gyroscope range', range_dps, table, '±°/s')]


def temp_c(count, chip=DEFAULT_CHIP):
    """Temperature in °C of a raw count (the chip's formula)."""
    return count / chip.temp.lsb_per_c + chip.temp.offset_c


class Converter:
    """
    Raw counts to SI units (REP-103) and back, for given full-scale ranges.

    :param accel_range_g: a full-scale range of the chip, ±g.
    :param gyro_range_dps: a full-scale range of the chip, ±°/s.
    :param temp_formula: a temperature formula by name (``chips.TEMP_FORMULAS``:
        ``mpu6500`` counts/333.87 + 21 °C, ``mpu6050`` counts/340 + 36.53 °C), or None:
        the chip's.
    :param chip: the ``chips.Chip`` (default the MPU-9250).
    :raises ValueError: unsupported range or formula, with the allowed values.
    """

    def __init__(self, accel_range_g=2, gyro_range_dps=250, temp_formula=None,
                 chip=DEFAULT_CHIP):
        self.accel_scale = accel_scale(accel_range_g, chip)
        self.gyro_scale = gyro_scale(gyro_range_dps, chip)
        temp_formula = temp_formula or chip.temp.name
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
    Magnetometer counts (its own axes) to tesla in the accelerometer's frame, and back.

    The AK8963 inside an MPU-9250 is mounted with x_mag = y_acc, y_mag = x_acc,
    z_mag = −z_acc, so x_acc = y_mag, y_acc = x_mag, z_acc = −z_mag (its
    ``chips.Magnetometer.axes``). Each magnetometer axis is scaled by its step (the AK8963:
    0.15 µT per count at 16-bit output, 0.6 µT at 14-bit) times its factory adjustment
    :func:`asa_factor`.

    :param asa: (ASAX, ASAY, ASAZ) from the fuse ROM (the info frame); (128, 128, 128)
        means no adjustment (and a magnetometer without a fuse ROM has none).
    :param magnetometer: the ``chips.Magnetometer`` (default the AK8963).
    :raises ValueError: an ASA value outside 0..255.
    """

    def __init__(self, asa=(128, 128, 128), magnetometer=AK8963):
        asa = tuple(int(a) for a in asa)
        if len(asa) != 3 or any(not 0 <= a <= 255 for a in asa):
            raise ValueError(f'ASA must be three bytes 0..255, got {asa!r}')
        if not magnetometer.adjustable:
            asa = (128, 128, 128)
        self.asa = asa
        self.magnetometer = magnetometer
        self.adjust = tuple(asa_factor(a) for a in asa)
        steps = magnetometer.ut_per_count
        self._ut = {True: steps[max(steps)] * 1e-6, False: steps[min(steps)] * 1e-6}

    def to_tesla(self, mag):
        """
        Convert one magnetometer block.

        :param mag: (hx, hy, hz, st2) counts and ST2.
        :return: (x, y, z) tesla in the accelerometer frame, or None when ST2 reports an
            overflow (HOFL: the sample is not valid).
        """
        if mag[3] & ST2_HOFL:
            return None
        ut = self._ut[bool(mag[3] & ST2_BITM)]
        adjust = self.adjust
        return tuple(sign * mag[k] * ut * adjust[k] for k, sign in self.magnetometer.axes)

    def to_counts(self, field_t):
        """
        Convert a field in the accelerometer frame to a block at the widest output.

        :param field_t: (x, y, z) tesla, accelerometer frame.
        :return: (hx, hy, hz, st2) with ST2 BITM set, and HOFL set when an axis is beyond
            the measurement range (the counts are then clipped).
        """
        ut = self._ut[True]
        limit = self.magnetometer.counts_max
        raw = [0.0, 0.0, 0.0]                   # hx, hy, hz
        for value, (k, sign) in zip(field_t, self.magnetometer.axes):
            raw[k] = sign * float(value) / (ut * self.adjust[k])
        st2 = ST2_BITM
        out = []
        for value in raw:
            if not math.isfinite(value) or abs(value) > limit:
                st2 |= ST2_HOFL
                value = 0.0 if math.isnan(value) else math.copysign(limit, value)
            out.append(int(round(value)))
        return (out[0], out[1], out[2], st2)
