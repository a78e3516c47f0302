"""The one accept-or-refuse decision shared by ``accel-calib fit`` and the node."""

from accel_calib_ros.core.accelerometer.fit import calibrate
from accel_calib_ros.core.acceptance import review
from accel_calib_ros.core.poses import CANDIDATE_POSES
from accel_calib_ros.sim.motion import random_directions, simulate_window_means
from accel_calib_ros.sim.sensor import mpu9250_like
import numpy as np


def _fit(directions, seed=1):
    rng = np.random.default_rng(seed)
    sensor = mpu9250_like(rng)
    means = simulate_window_means(sensor, directions, 300, rng)
    noise = np.full(3, 0.02)
    return calibrate(means, weights=np.full(len(directions), 300.0), noise_std=noise)


def test_a_good_fit_is_accepted_and_a_strict_limit_or_no_convergence_refuses_it():
    cal = _fit(random_directions(30, np.random.default_rng(2)))
    acc = cal.predicted_accuracy
    verdict = review(cal, 0.02)
    assert 0 < acc <= 0.02 and verdict.accepted and verdict.refusal is None
    assert verdict.reasons == [] and verdict.poses == []
    strict = review(cal, acc / 3, limit_name='--max-predicted-error')
    assert not strict.accepted and not strict.accuracy_ok
    assert strict.refusal.count('\n') == 0 and '--max-predicted-error' in strict.refusal
    # It names the pose that helps most, never one within 25° of a direction held.
    assert strict.poses and strict.poses[0][0] in strict.refusal
    named = np.array([d for d, name in CANDIDATE_POSES if name in dict(strict.poses)])
    held = cal.information.directions
    assert np.degrees(np.arccos(np.max(named @ held.T))) >= 25.0
    assert all(after < acc for _, after in strict.poses)
    cal.converged = False
    assert 'did not converge' in review(cal, 0.02).refusal
    assert review(cal, 0.02, allow_unconverged=True).accepted


def test_a_tilt_only_fit_names_the_face_it_never_saw():
    tilt = np.radians(np.r_[0.0, np.full(6, 12.0), np.full(8, 24.0)])
    azimuth = np.r_[0.0, np.arange(6) * np.pi / 3, np.arange(8) * np.pi / 4]
    dirs = np.c_[np.sin(tilt) * np.cos(azimuth), np.sin(tilt) * np.sin(azimuth),
                 np.cos(tilt)]
    verdict = review(_fit(dirs), 0.02)
    assert not verdict.accepted and 'z axis down' in verdict.refusal
    assert [name for name, _ in verdict.poses][0] == 'z axis down'


def test_a_fit_in_g_is_refused_or_warned_as_not_physical():
    rng = np.random.default_rng(3)
    u = random_directions(30, rng)
    means = 0.6 * 9.80665 * u + 5.0 + rng.normal(0, 0.002, (30, 3))
    cal = calibrate(means, weights=np.full(30, 300.0), noise_std=np.full(3, 0.02))
    refused = review(cal, 10.0, refuse_unphysical=True)
    assert not refused.accepted and 'not physical' in refused.refusal
    assert refused.physical_problems
    warned = review(cal, 10.0)
    assert warned.accepted and any('m/s²' in w for w in warned.warnings)
