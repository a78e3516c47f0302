"""Order statistics without numpy.ma (``core.stats``): the numbers of np.median / np.quantile."""

from accel_calib_ros.core.stats import median, quantile
import numpy as np


def test_median_and_quantile_match_numpy():
    rng = np.random.default_rng(0)
    for shape in ((1,), (2,), (7,), (10,), (1000, 3), (5, 3)):
        x = rng.normal(size=shape)
        assert abs(median(x) - np.median(x)) < 1e-15
        if len(shape) == 2:
            np.testing.assert_allclose(median(x, axis=0), np.median(x, axis=0), rtol=0,
                                       atol=1e-15)
        for q in (0.0, 0.02, 0.5, 0.97, 1.0):
            assert abs(quantile(x, q) - np.quantile(x, q)) < 1e-14
    assert np.isnan(median([1.0, np.nan, 2.0])) and np.isnan(median([]))
    assert np.isnan(median(np.zeros((0, 3)), axis=0)).all()
