"""The virtual MPU-9250 (``sim.device``): what it sends after its scripted session."""

import argparse

from accel_calib_ros.sim import device
import numpy as np


def _args(*extra):
    parser = argparse.ArgumentParser()
    device.add_arguments(parser)
    return parser.parse_args(['--poses', 'random', '--count', '2', '--hold', '0.5',
                              '--move', '0.3', '--rate', '200', '--gyro-errors', *extra])


def test_the_pose_held_after_the_script_keeps_the_gyro_bias():
    """Held still after the script, the raw rate is the sensor's bias plus noise, as in it."""
    virtual = device.VirtualSensor(_args())
    bias = virtual.sensor.gyro_bias
    assert np.abs(bias).max() > 0.005            # --gyro-errors: a bias worth seeing
    scripted = int(round((2 * 0.5 + 0.3) * 200))
    counts = virtual.counts(scripted + 2000, 0.0)
    held = counts[scripted + 200:, 4:7].astype(float) * virtual.converter.gyro_scale
    # Mean of 1800 samples: the noise (~0.002 rad/s) averages to ~5e-5 rad/s; one count
    # of the ±250 °/s range is 1.3e-4 rad/s.
    np.testing.assert_allclose(held.mean(axis=0), bias, atol=3e-4)
    # The scripted holds read the same bias.
    first_hold = counts[20:90, 4:7].astype(float) * virtual.converter.gyro_scale
    np.testing.assert_allclose(first_hold.mean(axis=0), bias, atol=1e-3)
