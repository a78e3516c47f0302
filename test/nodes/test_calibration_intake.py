"""The calibration node's intake on its own: the times it gives the samples."""

from accel_calib_ros.nodes.calibration_intake import RESTART_GAP_S, StreamTime
import pytest


def test_a_step_back_becomes_a_gap_and_a_repeated_stamp_stays():
    """Regression: every repeated stamp became a 10 s gap, so no window could form."""
    times = StreamTime()
    got = [times(t) for t in (1.0, 1.0, 1.0, 1.001, 0.5, 0.501, 0.501)]
    gap = 1.001 + RESTART_GAP_S
    assert got == pytest.approx([1.0, 1.0, 1.0, 1.001, gap, gap + 0.001, gap + 0.001])
    assert times.steps == 1
