"""
The chip registry (``dataio.wire.chips``): one home per chip fact, read by everything.

The info frame's chip name, the conversion's temperature formula and sensitivities, the
magnetometer's axes and steps, the simulated device and the guide's serial input all read
the registry; a chip added there (an ICM-20948 with an AK09916 here, for the test) is
known to all of them at once.
"""

import argparse

from accel_calib_ros.dataio.wire import (BY_KEY, Chip, chip_name, chip_of, CHIPS, Converter,
                                         decode_info, DEFAULT_CHIP, InfoFrame, MagConverter,
                                         Magnetometer, ST2_BITM, TEMP_FORMULAS)
from accel_calib_ros.dataio.wire import chips
import numpy as np
import pytest

FIRMWARE_FACTS = {0x71: ('MPU-9250', 333.87, 21.0), 0x73: ('MPU-9255', 333.87, 21.0),
                  0x70: ('MPU-6500', 333.87, 21.0), 0x68: ('MPU-6050', 340.0, 36.53)}
"""WHO_AM_I and temperature formula of each chip, from the register maps (firmware-facts)."""

AK09916 = Magnetometer('AK09916', {16: 0.15}, 32752, False, ((0, 1), (1, -1), (2, -1)))
ICM20948 = Chip('icm20948', 'ICM-20948', 0xEA, chips.MPU6500_TEMP, chips.INVENSENSE_ACCEL,
                chips.INVENSENSE_GYRO, AK09916)


@pytest.fixture
def icm20948(monkeypatch):
    """Add one entry to the registry (its magnetometer too), for this test only."""
    monkeypatch.setitem(chips.CHIPS, ICM20948.who_am_i, ICM20948)
    monkeypatch.setitem(chips.BY_KEY, ICM20948.key, ICM20948)
    monkeypatch.setitem(chips.MAGNETOMETERS, AK09916.name, AK09916)
    return ICM20948


@pytest.mark.parametrize('who', sorted(FIRMWARE_FACTS))
def test_each_chip_has_its_name_and_temperature_formula(who):
    name, lsb, offset = FIRMWARE_FACTS[who]
    chip = chip_of(who)
    assert chip.name == name and chip_name(who) == name and BY_KEY[chip.key] is chip
    assert (chip.temp.lsb_per_c, chip.temp.offset_c) == (lsb, offset)
    conv = Converter(chip=chip)
    assert conv.to_si((0, 0, 16384, 3400, 131, 0, 0))[1] == pytest.approx(3400 / lsb + offset)
    assert TEMP_FORMULAS[conv.temp_formula] == (lsb, offset)
    info = InfoFrame(0, who, 2, 250, 1000, 1, 1_000_000, (2, 0))
    assert info.chip == name


def test_the_registry_is_keyed_by_who_am_i_and_unknown_chips_are_named_so():
    assert set(CHIPS) == set(FIRMWARE_FACTS) and DEFAULT_CHIP.who_am_i == 0x71
    assert chip_of(0x12) is None and chip_name(0x12) == 'unknown (0x12)'
    assert [c.magnetometer is not None for c in CHIPS.values()] == [True, True, False, False]


def test_the_ak8963_conversion_is_its_registry_entry():
    conv = MagConverter((176, 128, 64))
    field = conv.to_tesla((100, 200, 300, ST2_BITM))
    np.testing.assert_allclose(np.array(field) * 1e6, [200 * 0.15, 100 * 0.15 * 1.1875,
                                                       -300 * 0.15 * 0.75])
    assert conv.to_counts(field) == (100, 200, 300, ST2_BITM)


def test_a_new_chip_is_one_entry_known_to_every_reader(icm20948, monkeypatch):
    # The info frame names it, the conversion uses its formula and its magnetometer.
    assert InfoFrame(0, 0xEA, 2, 250, 1000, 1, 1_000_000, (2, 0)).chip == 'ICM-20948'
    mag = MagConverter((1, 2, 3), icm20948.magnetometer)        # no fuse ROM: ASA ignored
    field = np.array(mag.to_tesla((100, 200, 300, 0))) * 1e6       # one output width only
    np.testing.assert_allclose(field, [15.0, -30.0, -45.0])
    assert mag.to_counts(field * 1e-6)[:3] == (100, 200, 300)
    # The simulated device is one (its WHO_AM_I in the info frame, its formula on the wire).
    from accel_calib_ros.sim.device_port import Wire
    args = argparse.Namespace(ascii=False, frame_version=2, corrupt=0.0, rate=100.0, t0_us=0,
                              accel_range=2, gyro_range=250, chip='icm20948')
    wire = Wire(args, np.random.default_rng(0))
    info = decode_info(wire.info(True))
    assert info.who_am_i == 0xEA and info.chip == 'ICM-20948'
    # The guide's serial input takes its converters from the info frame.
    from accel_calib_ros.cli.guide_sources import SerialSource
    source = SerialSource.__new__(SerialSource)
    source.ranges, source._lock = (2, 250), __import__('threading').Lock()
    source._on_info(info._replace(mag_status=1))
    assert source.converter.temp_formula == 'mpu6500'
    assert source.mag_converter.magnetometer is AK09916


def test_the_simulated_device_can_be_each_chip():
    from accel_calib_ros.sim.device import add_arguments, DeviceError, VirtualSensor
    parser = argparse.ArgumentParser()
    add_arguments(parser)
    for key, chip in BY_KEY.items():
        sensor = VirtualSensor(parser.parse_args(['--chip', key]))
        assert sensor.converter.temp_formula == chip.temp.name
    with pytest.raises(DeviceError, match='MPU-6050 has no magnetometer'):
        VirtualSensor(parser.parse_args(['--chip', 'mpu6050', '--magnetometer']))


def test_the_driver_offers_the_registry_and_picks_the_formula_by_who_am_i():
    pytest.importorskip('rclpy')
    from types import SimpleNamespace
    from accel_calib_ros.nodes.driver import CHIP_CHOICES, Mpu9250Driver
    assert CHIP_CHOICES == ('auto',) + tuple(BY_KEY)
    for who, (_, lsb, _) in FIRMWARE_FACTS.items():
        node = SimpleNamespace(params={'chip': 'auto'},
                               device_info=InfoFrame(0, who, 2, 250, 1000, 1, 1, (2, 0)))
        formula = Mpu9250Driver._chip_formula(node)
        assert TEMP_FORMULAS[formula][0] == lsb
