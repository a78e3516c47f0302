"""The simulators take the noise an Allan analysis measured (``--noise-from``)."""

import argparse
import json

from accel_calib_ros.cli import main
from accel_calib_ros.dataio.recording import write_samples_csv
from accel_calib_ros.sim import device
from accel_calib_ros.sim.motion import iter_session
from accel_calib_ros.sim.sensor import SensorModel
import numpy as np
import pytest

ACCEL_STD = np.array([0.01, 0.03, 0.05])     # m/s² per sample, unlike the default 0.021
GYRO_STD = np.array([0.001, 0.004, 0.0025])  # rad/s per sample, unlike the default 0.002


def _columns(path):
    data = np.genfromtxt(path, delimiter=',', names=True)
    return np.column_stack([data[k] for k in ('ax', 'ay', 'az', 'gx', 'gy', 'gz')])


def test_a_simulation_takes_the_measured_noise(tmp_path, capsys):
    # A still recording of a sensor with a known noise, analysed by allan --json.
    sensor = SensorModel(noise_std=ACCEL_STD, gyro_noise_std=GYRO_STD)
    still = tmp_path / 'still.csv'
    write_samples_csv(still, (p.samples for p in iter_session(
        sensor, [[0.0, 0.0, 1.0]], np.random.default_rng(1), hold_s=120.0)))
    assert main(['allan', str(still), '--json']) == 0
    path = tmp_path / 'allan.json'
    path.write_text(capsys.readouterr().out)
    # A new simulation with that noise: its per-axis std matches the known noise.
    out = tmp_path / 'again.csv'
    assert main(['simulate', '-o', str(out), '--poses', '1', '--hold', '120', '--seed', '3',
                 '--noise-from', str(path), '--json']) == 0
    truth = json.loads(capsys.readouterr().out)['truth']
    std = np.std(_columns(out), axis=0)
    np.testing.assert_allclose(std, np.r_[ACCEL_STD, GYRO_STD], rtol=0.04)
    np.testing.assert_allclose(truth['noise_std_m_s2'], ACCEL_STD, rtol=0.04)
    np.testing.assert_allclose(truth['gyro_noise_std_rad_s'], GYRO_STD, rtol=0.04)
    # At twice the rate the noise density is kept: the per-sample std grows by sqrt(2).
    fast = tmp_path / 'fast.csv'
    assert main(['simulate', '-o', str(fast), '--poses', '1', '--hold', '60', '--rate', '200',
                 '--noise-from', str(path)]) == 0
    np.testing.assert_allclose(np.std(_columns(fast), axis=0),
                               np.sqrt(2) * np.r_[ACCEL_STD, GYRO_STD], rtol=0.05)
    # simulate-device takes the same file.
    virtual = device.VirtualSensor(device_args(path, '--rate', '100'))
    np.testing.assert_allclose(virtual.sensor.noise_std, ACCEL_STD, rtol=0.04)
    np.testing.assert_allclose(virtual.sensor.gyro_noise_std, GYRO_STD, rtol=0.04)


def _good():
    return {'axes': ['ax', 'ay', 'az'], 'white_sample_std': [0.02, 0.02, 0.02],
            'rate_hz': 100.0}


BAD = {
    'missing key': lambda d: d.pop('white_sample_std'),
    'no rate': lambda d: d.pop('rate_hz'),
    'wrong length': lambda d: d.update(white_sample_std=[0.02, 0.02]),
    'negative': lambda d: d.update(white_sample_std=[0.02, -0.01, 0.02]),
    'not a number': lambda d: d.update(white_sample_std=[0.02, 'x', 0.02]),
    'wrong axes': lambda d: d.update(axes=['gx', 'gy', 'gz']),
    'zero rate': lambda d: d.update(rate_hz=0),
}


CASES = sorted(BAD) + ['non-finite', 'not json', 'not an object', 'directory', 'same as output']


@pytest.mark.parametrize('case', CASES)
def test_a_bad_noise_file_is_one_line_and_exit_2(case, tmp_path, capsys):
    path = tmp_path / 'allan.json'
    out = tmp_path / 'sim.csv'
    d = _good()
    if case in BAD:
        BAD[case](d)
        path.write_text(json.dumps(d))
    elif case == 'non-finite':
        path.write_text(json.dumps(d).replace('0.02, 0.02]', '0.02, NaN]'))
    elif case == 'not json':
        path.write_bytes(b'\xff\xfe{')
    elif case == 'not an object':
        path.write_text('[1, 2, 3]')
    elif case == 'directory':
        path = tmp_path
    else:
        path.write_text(json.dumps(d))
        out = path
    before = path.read_bytes() if path.is_file() else None
    code = main(['simulate', '-o', str(out), '--poses', '1', '--hold', '1',
                 '--noise-from', str(path)])
    err = capsys.readouterr().err
    assert code == 2 and err.count('\n') == 1 and 'Traceback' not in err, err
    assert case != 'same as output' or path.read_bytes() == before
    assert case == 'same as output' or not out.exists()
    if case in BAD or case == 'non-finite':
        assert device.run(device_args(path)) == 2


def device_args(path, *extra):
    parser = argparse.ArgumentParser()
    device.add_arguments(parser)
    return parser.parse_args(['--noise-from', str(path), *extra])
