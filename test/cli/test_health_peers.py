"""
``accel-calib health`` on the real recordings (test/data/peers).

A calibration fitted on a session is healthy on it and on the same sensor's other
recordings: no false alarm on real noise.
"""

from accel_calib_ros.cli import main
import peer_data
import pytest

pytestmark = pytest.mark.skipif(
    not all(peer_data.available(n) for n in ('imu_tk', 'imucal', 'mpu6050_tomisuarez2')),
    reason='peer recordings not present')


def cli(*argv):
    return main([str(a) for a in argv])


def test_real_sessions_are_healthy_on_themselves_and_their_sensors_other_recordings(
        tmp_path, capsys):
    imu_tk = peer_data.to_spec_csv(peer_data.imu_tk(), tmp_path / 'imu_tk.csv')
    units = ['--counts-per-g', '4065', '--counts-offset', '32768']
    assert cli('fit', imu_tk, *units, '--gravity', '9.81744', '-o', tmp_path / 'x.yaml') == 0
    assert cli('health', tmp_path / 'x.yaml', imu_tk, *units) == 0
    mpu = peer_data.to_spec_csv(peer_data.mpu6050(counts=True), tmp_path / 'mpu.csv')
    assert cli('fit', mpu, '--range', '2', '--max-predicted-error', '1',
               '-o', tmp_path / 'm.yaml') == 0
    for which in ('calibration', 'still', 'static_test'):
        path = peer_data.to_spec_csv(peer_data.mpu6050(which, counts=True),
                                     tmp_path / f'{which}.csv')
        assert cli('health', tmp_path / 'm.yaml', path, '--range', '2') == 0, which
    turn = peer_data.to_spec_csv(peer_data.mpu6050_turn(), tmp_path / 'turn.csv')
    assert cli('health', tmp_path / 'm.yaml', turn) == 0
    imucal = peer_data.to_spec_csv(peer_data.imucal_ferraris()[0], tmp_path / 'imucal.csv')
    assert cli('fit', imucal, '--method', 'gn', '--max-predicted-error', '1',
               '-o', tmp_path / 'i.yaml') == 0
    assert cli('health', tmp_path / 'i.yaml', imucal) == 0
    capsys.readouterr()
