"""
The sensor chips the host reads, one entry each, keyed by WHO_AM_I: the one home of them.

A :class:`Chip` says what the host needs to turn a chip's counts into SI units: its name
and its WHO_AM_I value, its temperature formula, its accelerometer and gyroscope
full-scale ranges with their sensitivities, and its magnetometer (a
:class:`Magnetometer`: its step per count, range, factory sensitivity adjustment and how
its axes sit in the accelerometer's frame). Everything that needs a chip fact reads it
here: the driver's ``chip`` parameter and its choice of formula, the info frame's chip
name (:mod:`.info`), the conversion of counts (:mod:`.conversion`), the simulated device
(``sim.device``) and the guide's serial input. Supporting another chip (an ICM-20948 with
its AK09916, say) is one entry in :data:`CHIPS`, and one in :data:`MAGNETOMETERS` for a
new magnetometer; the firmware must stream it too (docs/firmware.md).

Facts from the InvenSense MPU-6050, MPU-6500 and MPU-9250 register maps and the AK8963
datasheet. Standard library only.
"""

from typing import NamedTuple, Optional, Tuple


class TempFormula(NamedTuple):
    """
    A chip family's temperature formula: °C = counts / ``lsb_per_c`` + ``offset_c``.

    :param name: the family's name (the driver reports it in ``/diagnostics``).
    :param lsb_per_c: counts per °C.
    :param offset_c: °C at zero counts.
    """

    name: str
    lsb_per_c: float
    offset_c: float


class Magnetometer(NamedTuple):
    """
    A magnetometer inside (or beside) an IMU chip.

    :param name: its part name.
    :param ut_per_count: µT per count by output width in bits (the AK8963's ST2 BITM bit
        says which one a sample has; a single entry: always that one).
    :param counts_max: largest magnitude of a valid measurement, counts.
    :param adjustable: it has factory sensitivity adjustment values (ASA) in a fuse ROM.
    :param axes: for the accelerometer's x, y and z: (its own axis index, sign).
    """

    name: str
    ut_per_count: dict
    counts_max: int
    adjustable: bool
    axes: Tuple[Tuple[int, int], Tuple[int, int], Tuple[int, int]]


class Chip(NamedTuple):
    """
    One sensor chip.

    :param key: its name as a parameter value (``mpu9250``).
    :param name: its part name (``MPU-9250``).
    :param who_am_i: its WHO_AM_I register value.
    :param temp: its :class:`TempFormula`.
    :param accel_lsb_per_g: accelerometer counts per g by full-scale range (±g).
    :param gyro_lsb_per_dps: gyroscope counts per °/s by full-scale range (±°/s).
    :param magnetometer: its :class:`Magnetometer`, or None.
    """

    key: str
    name: str
    who_am_i: int
    temp: TempFormula
    accel_lsb_per_g: dict
    gyro_lsb_per_dps: dict
    magnetometer: Optional[Magnetometer]


MPU6500_TEMP = TempFormula('mpu6500', 333.87, 21.0)
"""MPU-6500, MPU-9250 and MPU-9255: counts / 333.87 + 21 °C."""
MPU6050_TEMP = TempFormula('mpu6050', 340.0, 36.53)
"""MPU-6050: counts / 340 + 36.53 °C."""
INVENSENSE_ACCEL = {2: 16384.0, 4: 8192.0, 8: 4096.0, 16: 2048.0}
"""Accelerometer counts per g of the MPU family, by full-scale range (±g)."""
INVENSENSE_GYRO = {250: 131.0, 500: 65.5, 1000: 32.8, 2000: 16.4}
"""Gyroscope counts per °/s of the MPU family, by full-scale range (±°/s)."""

AK8963 = Magnetometer('AK8963', {16: 0.15, 14: 0.6}, 32760, True, ((1, 1), (0, 1), (2, -1)))
"""The AK8963 of the MPU-9250/9255: ±4912 µT; mounted with x_acc = y_mag, y_acc = x_mag,
z_acc = -z_mag."""
MAGNETOMETERS = {m.name: m for m in (AK8963,)}
"""The magnetometers, by part name."""

CHIPS = {c.who_am_i: c for c in (
    Chip('mpu9250', 'MPU-9250', 0x71, MPU6500_TEMP, INVENSENSE_ACCEL, INVENSENSE_GYRO, AK8963),
    Chip('mpu9255', 'MPU-9255', 0x73, MPU6500_TEMP, INVENSENSE_ACCEL, INVENSENSE_GYRO, AK8963),
    Chip('mpu6500', 'MPU-6500', 0x70, MPU6500_TEMP, INVENSENSE_ACCEL, INVENSENSE_GYRO, None),
    Chip('mpu6050', 'MPU-6050', 0x68, MPU6050_TEMP, INVENSENSE_ACCEL, INVENSENSE_GYRO, None),
)}
"""The supported chips, by WHO_AM_I."""
BY_KEY = {c.key: c for c in CHIPS.values()}
"""The supported chips, by :attr:`Chip.key`."""
DEFAULT_CHIP = BY_KEY['mpu9250']
"""The chip assumed before the firmware says which one it has."""
TEMP_FORMULAS = {c.temp.name: (c.temp.lsb_per_c, c.temp.offset_c) for c in CHIPS.values()}
"""The temperature formulas of the supported chips, by family name: (counts per °C, °C at
zero counts)."""


def chip_of(who_am_i):
    """Return the :class:`Chip` whose WHO_AM_I is ``who_am_i`` (None: not supported)."""
    return CHIPS.get(who_am_i)


def chip_name(who_am_i):
    """Return the part name of a WHO_AM_I value ('unknown (0x..)' when not supported)."""
    chip = CHIPS.get(who_am_i)
    return chip.name if chip is not None else f'unknown (0x{who_am_i:02x})'
