"""The streaming static-window detector against the offline one (core/windows/)."""

from accel_calib_ros.core.windows import (DEFAULTS, detect_static_windows, OnlineStaticDetector)
from accel_calib_ros.sim.motion import random_directions, simulate_session
from accel_calib_ros.sim.sensor import mpu9250_like
import numpy as np
import pytest

SHORT = {'window_s': 0.25, 'trim_s': 0.1, 'min_duration_s': 0.3}
"""Settings with which a 1.0 s hold leaves a window (the defaults need about 1.4 s)."""
OFFLINE_GYRO = 'max_rotation_rad_s' in DEFAULTS
"""Whether the offline detector has the gyro test (then both use it)."""


def stream(det, samples, chunk=100):
    """Feed a recording in chunks as a node would; return every window."""
    out = []
    for i in range(0, len(samples.t), chunk):
        part = slice(i, i + chunk)
        out += det.feed(samples.t[part], samples.accel[part], samples.temp[part],
                        None if samples.gyro is None else samples.gyro[part])
    return out + det.finish()


def matched(online, offline, rate):
    """Count online windows that are an offline window (same middle, same length)."""
    hits = 0
    for w in online:
        k = np.argmin(np.abs(offline.t_mid - w['t_mid']))
        if abs(offline.t_mid[k] - w['t_mid']) < 5.0 / rate \
                and abs(offline.count[k] - w['count']) <= max(3, 0.01 * w['count']):
            hits += 1
    return hits


@pytest.mark.parametrize('rate, hold, settings', [(100.0, 1.0, SHORT), (1000.0, 1.0, SHORT),
                                                  (200.0, 1.5, {})])
def test_same_windows_as_the_offline_detector(rate, hold, settings):
    rng = np.random.default_rng(int(rate))
    sensor = mpu9250_like(rng, rate_hz=rate)
    s = simulate_session(sensor, random_directions(24, rng), rng, hold_s=hold, move_s=0.7,
                         rate_hz=rate, lead_s=hold)
    offline = detect_static_windows(s.samples, **settings)
    online = stream(OnlineStaticDetector(use_gyro=OFFLINE_GYRO, **settings), s.samples)
    assert len(offline) == 24
    assert len(online) == len(offline)
    assert matched(online, offline, rate) >= 0.95 * len(offline)
    means = np.array([w['mean'] for w in online])
    assert np.abs(means - offline.mean).max() < 0.01


def test_slow_turns_are_not_windows():
    rate, hold = 200.0, 2.0
    rng = np.random.default_rng(3)
    sensor = mpu9250_like(rng, rate_hz=rate)
    s = simulate_session(sensor, random_directions(12, rng), rng, hold_s=hold, move_s=0.7,
                         rate_hz=rate, lead_s=hold)
    # Every third hold turns slowly (3 deg/s about z: the accelerometer barely sees it)
    # during its whole second half.
    starts = np.flatnonzero(np.diff(np.r_[-1, s.pose]) != 0)
    turned = [a for a in starts if s.pose[a] >= 0 and s.pose[a] % 3 == 1]
    n = int(hold * rate)
    for a in turned:
        s.samples.gyro[a + n // 2:a + n] += [0.0, 0.0, np.radians(3.0)]
    det = OnlineStaticDetector(max_rotation_rad_s=np.radians(2.0))
    online = stream(det, s.samples)
    for w in online:
        for a in turned:
            t_turn = s.samples.t[a + n // 2]
            assert w['t_stop'] < t_turn or w['t_start'] > s.samples.t[a + n - 1]
    assert len(online) >= 12 - len(turned)
    if OFFLINE_GYRO:
        offline = detect_static_windows(s.samples)
        assert len(online) == len(offline)


def test_rate_is_tracked_and_memory_is_bounded():
    rng = np.random.default_rng(5)
    det = OnlineStaticDetector()
    # 2 s of samples queued at start-up (stamps 0.1 ms apart), then 200 Hz.
    det.feed(1e-4 * np.arange(400), [0, 0, 9.8] + rng.normal(0, 0.02, (400, 3)))
    t = 0.05 + np.arange(40000) / 200.0
    accel = [0, 0, 9.8] + rng.normal(0, 0.02, (40000, 3))
    for i in range(0, 40000, 500):
        det.feed(t[i:i + 500], accel[i:i + 500])
        assert det.retained_samples() <= det.cap + 500 + 2 * det.n + 300
    assert abs(det.rate_hz - 200.0) < 1.0
    (window,) = det.finish()
    assert window['count'] > 39000
    np.testing.assert_allclose(window['mean'], accel.mean(axis=0), atol=1e-3)
