"""core.correction.Corrector (the correction node's filter), without ROS."""

from accel_calib_ros.core.calibration import Calibration
from accel_calib_ros.core.correction import Corrector, UNCALIBRATED_COVARIANCE, without_level
import numpy as np


def _calibration(trim=None):
    rng = np.random.default_rng(7)
    T = np.diag(1.0 + rng.uniform(-0.03, 0.03, 3))
    T[np.triu_indices(3, 1)] = rng.uniform(-0.02, 0.02, 3)
    gyro_T = np.eye(3) + rng.uniform(-0.02, 0.02, (3, 3))
    return Calibration(T=T, bias=rng.uniform(-0.5, 0.5, 3), covariance=np.eye(9) * 1e-8,
                       noise_std=np.full(3, 0.03), gyro_bias=rng.uniform(-0.05, 0.05, 3),
                       gyro_T=gyro_T, level_roll_pitch_rad=trim)


def test_corrector_matches_the_calibration_sample_by_sample():
    for trim in (None, (0.03, -0.02)):
        cal = _calibration(trim)
        c = Corrector(cal)
        L = cal.level_rotation()
        rng = np.random.default_rng(8)
        for raw, rate in zip(rng.normal(0, 9.8, (20, 3)), rng.normal(0, 1.0, (20, 3))):
            np.testing.assert_allclose(c.correct(*raw, float('nan')),
                                       L @ cal.correct(raw)[0], atol=1e-12)
            np.testing.assert_allclose(c.correct_gyro(*rate, float('nan')),
                                       L @ cal.correct_gyro(rate)[0], atol=1e-12)
        assert c.trimmed == (trim is not None)
        assert not Corrector(without_level(cal)).trimmed


def test_pass_through_without_a_calibration():
    c = Corrector(None)
    assert c.correct(1.0, 2.0, 3.0, 25.0) == (1.0, 2.0, 3.0)
    assert c.correct_gyro(0.1, 0.2, 0.3, 25.0) == (0.1, 0.2, 0.3)
    np.testing.assert_array_equal(c.covariance, UNCALIBRATED_COVARIANCE)
    assert not c.trimmed and c.gyro_words() == 'none'
