"""Allan deviation: known white noise and random walk are recovered; the CLI contract."""

import json

from accel_calib_ros.cli import main
from accel_calib_ros.core.allan import allan, overlapping_adev
from accel_calib_ros.core.errors import CalibrationError
from accel_calib_ros.core.samples import Samples
import numpy as np
import pytest

RATE = 100.0


def still(seconds, density, walk=0.0, seed=0):
    """Return a still recording: white noise of ``density`` /√Hz plus a rate random walk."""
    rng = np.random.default_rng(seed)
    n = int(seconds * RATE)
    t = np.arange(n) / RATE
    white = rng.standard_normal((n, 3)) * density * np.sqrt(RATE)
    drift = np.cumsum(rng.standard_normal((n, 3)), axis=0) * walk / np.sqrt(RATE)
    accel = np.array([0.0, 0.0, 9.81]) + white + drift
    return Samples(t, accel, np.full(n, 25.0))


def test_white_noise_density_and_slope():
    density = 0.003        # 300 µg/√Hz
    result = allan(still(600, density))
    assert np.allclose(result.noise_density, density, rtol=0.05)
    for i in range(3):
        lo, hi = result.noise_density_ci[i]
        assert lo < result.noise_density[i] < hi
        # -1/2 slope over the whole curve: sigma(tau) sqrt(tau) stays at N.
        assert np.allclose(result.adev[i] * np.sqrt(result.tau), density, rtol=0.35)
    assert np.all(result.random_walk_ci[:, 0] == 0.0)       # no random walk resolved
    assert not result.bias_instability_reached.any()        # white: the curve still falls


def test_rate_random_walk_is_found():
    walk = 0.002
    result = allan(still(1200, 0.0005, walk=walk, seed=1))
    assert np.all(result.random_walk > 0)
    assert np.allclose(result.random_walk, walk, rtol=0.6)
    assert np.all(result.bias_instability_tau < result.tau[-1])


def test_matches_the_textbook_estimator_on_a_small_case():
    x = np.random.default_rng(3).standard_normal((50, 1))
    m = 4
    # sigma² = 1/(2 tau² (n - 2m)) sum (x_{k+2m} - 2 x_{k+m} + x_k)² on the integral.
    phase = np.concatenate([[0.0], np.cumsum(x[:, 0] - x[:, 0].mean())])
    d = phase[2 * m:] - 2 * phase[m:-m] + phase[:-2 * m]
    expected = np.sqrt(np.sum(d ** 2) / (2 * m ** 2 * len(d)))
    assert overlapping_adev(x, 1.0, [m])[0, 0] == pytest.approx(expected)


def test_cli_json_plot_and_errors(tmp_path, capsys):
    s = still(60, 0.003, seed=2)
    data = tmp_path / 'still.csv'
    rows = np.column_stack([s.t, s.accel, s.temp])
    np.savetxt(data, rows, delimiter=',', header='t,ax,ay,az,temp', comments='')
    plot = tmp_path / 'adev.png'
    assert main(['allan', str(data), '--json', '--plot', str(plot)]) == 0
    out = json.loads(capsys.readouterr().out)
    for key in ('axes', 'tau', 'adev', 'noise_density', 'bias_instability', 'random_walk',
                'noise_density_ci', 'bias_instability_ci', 'random_walk_ci'):
        assert key in out
    assert out['axes'] == ['ax', 'ay', 'az'] and len(out['adev'][0]) == len(out['tau'])
    assert plot.read_bytes()[:4] == b'\x89PNG'
    short = tmp_path / 'short.csv'
    np.savetxt(short, rows[:300], delimiter=',', header='t,ax,ay,az,temp', comments='')
    assert main(['allan', str(short)]) == 1
    assert 'needs at least' in capsys.readouterr().err
    assert main(['allan', str(tmp_path / 'missing.csv')]) == 2
    assert main(['allan', str(data), '--plot', str(data)]) == 2
    assert len(capsys.readouterr().err.strip().splitlines()) == 2


def test_too_short_is_a_calibration_error():
    with pytest.raises(CalibrationError):
        allan(still(5, 0.003))


def test_one_noise_density_convention_across_allan_diagnose_and_simulate(tmp_path, capsys):
    """
    Allan N everywhere: sigma(tau) = N/sqrt(tau), white samples std N sqrt(rate).

    N² is the two-sided PSD (half the one-sided level Welch returns); ``diagnose`` reads
    the same N from a session's windows; ``simulate --noise-from`` draws std N sqrt(rate).
    (``diagnose`` once printed the one-sided density, sqrt(2) N.)
    """
    from scipy import signal
    from accel_calib_ros.modelgap import diagnose
    from accel_calib_ros.sim.motion import random_directions, simulate_session
    from accel_calib_ros.sim.sensor import mpu9250_like
    density = 0.003                                     # N, m/s²/√Hz
    samples = still(300, density, seed=3)
    result = allan(samples)
    assert np.allclose(result.noise_density, density, rtol=0.05)
    summary = result.summary()
    assert np.allclose(summary['noise_density_ug_rthz'], density / 9.80665 * 1e6, rtol=0.05)
    assert 'N/sqrt(tau)' in summary['noise_density_convention']
    _, psd = signal.welch(samples.accel[:, 0] - samples.accel[:, 0].mean(), fs=RATE,
                          nperseg=1024)                  # one-sided by default
    assert np.sqrt(np.median(psd) / 2.0) == pytest.approx(density, rel=0.1)
    # diagnose: the windows of a session of a sensor with that white noise.
    rng = np.random.default_rng(4)
    sensor = mpu9250_like(rng, rate_hz=RATE)
    sensor.noise_std = np.full(3, density * np.sqrt(RATE))
    session = simulate_session(sensor, random_directions(20, rng), rng, hold_s=3.0,
                               rate_hz=RATE)
    noise = diagnose(session.samples, 'ml').noise()
    assert np.allclose(noise['noise_density_ug_rthz'], density / 9.80665 * 1e6, rtol=0.1)
    assert noise['noise_density_convention'] == summary['noise_density_convention']
    # simulate --noise-from keeps N at another rate: std N sqrt(rate).
    path = tmp_path / 'allan.json'
    path.write_text(json.dumps(summary))
    from accel_calib_ros.dataio.noise_file import noise_from_allan
    accel_std, _ = noise_from_allan(path, 400.0)
    assert np.allclose(accel_std, result.noise_density * np.sqrt(400.0))
    assert main(['allan', str(tmp_path / 'x.csv')]) == 2        # (missing file)
    capsys.readouterr()
