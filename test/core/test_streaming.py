"""Big files and start-up: streaming simulate/apply, Ctrl-C, suffixes, lazy imports."""

import io
import json
import os
import signal
import subprocess
import sys
import time

from accel_calib_ros.cli import main, progress
from accel_calib_ros.core.errors import InputError
from accel_calib_ros.core.samples import Samples
from accel_calib_ros.dataio.recording import (csv_writer, iter_samples, load_samples, write_bag,
                                              write_samples_csv)
from accel_calib_ros.sim import motion as sim_motion
from accel_calib_ros.sim import sensor as sim
import numpy as np
import pytest

CLI = [sys.executable, '-m', 'accel_calib_ros.cli']


def session(seed=0, poses=5, **kwargs):
    """Return (sensor, directions, fresh generator) of a small simulated session."""
    rng = np.random.default_rng(seed)
    return sim.mpu9250_like(rng), sim_motion.random_directions(poses, rng), \
        np.random.default_rng(seed + 100)


def test_iter_session_pieces_join_to_the_whole_session():
    sensor, directions, _ = session()
    whole = sim_motion.simulate_session(sensor, directions, np.random.default_rng(7),
                                        hold_s=np.array([2.0, 0.01, 3.0, 1.0, 2.0]),
                                        temperature=(15.0, 30.0))
    pieces = list(sim_motion.iter_session(sensor, directions, np.random.default_rng(7),
                                          hold_s=np.array([2.0, 0.01, 3.0, 1.0, 2.0]),
                                          temperature=(15.0, 30.0), chunk_rows=120))
    assert len(pieces) > 5
    assert len(whole.samples) == sim_motion.session_length(
        directions, hold_s=np.array([2.0, 0.01, 3.0, 1.0, 2.0]))
    for name in ('t', 'accel', 'temp', 'gyro'):
        joined = np.concatenate([getattr(p.samples, name) for p in pieces])
        np.testing.assert_array_equal(joined, getattr(whole.samples, name))
    np.testing.assert_array_equal(np.concatenate([p.pose for p in pieces]), whole.pose)
    assert whole.samples.temp[0] == 15.0 and whole.samples.temp[-1] == pytest.approx(30.0)
    # Held poses: gravity along the pose direction; the gyro sees the moves (and its bias).
    held = whole.pose >= 0
    np.testing.assert_allclose(whole.true_accel[held],
                               sim.G0 * directions[whole.pose[held]], atol=1e-9)
    still = np.abs(whole.samples.gyro[held] - sensor.gyro_bias).max(axis=1)
    assert np.median(still) < 0.01 and np.abs(whole.samples.gyro[~held]).max() > 0.3


def test_iter_samples_pieces_equal_load_samples(tmp_path):
    sensor, directions, rng = session()
    s = sim_motion.simulate_session(sensor, directions, rng).samples
    path = tmp_path / 'a.csv'
    write_samples_csv(path, s)
    whole = load_samples(path)
    read = []
    pieces = list(iter_samples(path, chunk_rows=97, on_read=read.append))
    assert len(pieces) == -(-len(s) // 97)
    assert sum(read) == os.path.getsize(path) - len('t,ax,ay,az,temp,gx,gy,gz\n')
    for name in ('t', 'accel', 'temp', 'gyro'):
        np.testing.assert_array_equal(np.concatenate([getattr(p, name) for p in pieces]),
                                      getattr(whole, name))


def test_streamed_reader_reports_problems_in_later_pieces(tmp_path):
    lines = ['t,ax,ay,az'] + [f'{i * 0.01:.2f},0,0,9.8' for i in range(50)]
    lines[40] = '0.05,0,0,9.8'                                  # file line 41 goes back
    path = tmp_path / 'back.csv'
    path.write_text('\n'.join(lines) + '\n')
    with pytest.raises(InputError, match='line 41: time goes backwards'):
        list(iter_samples(path, chunk_rows=10))
    lines[40] = '0.395,0,nan,9.8'
    path.write_text('\n'.join(lines) + '\n')
    with pytest.raises(InputError, match='NaN or infinite.*acceleration.*41'):
        list(iter_samples(path, chunk_rows=10))
    lines[40] = '0.395,0,oops,9.8'
    path.write_text('\n'.join(lines) + '\n')
    with pytest.raises(InputError, match="line 41: column 'ay' holds 'oops'"):
        list(iter_samples(path, chunk_rows=10))


def test_csv_writer_in_pieces_and_bag_from_pieces(tmp_path):
    sensor, directions, rng = session()
    pieces = [p.samples for p in sim_motion.iter_session(sensor, directions, rng, chunk_rows=200)]
    whole = Samples(*(np.concatenate([getattr(p, n) for p in pieces])
                      for n in ('t', 'accel', 'temp', 'gyro')))
    path = tmp_path / 'w.csv'
    with csv_writer(path, has_temp=True, has_gyro=True) as writer:
        for piece in pieces:
            writer.write(piece)
        with pytest.raises(InputError, match='temp and gyro'):
            writer.write(Samples(piece.t, piece.accel))
    assert writer.rows == len(whole)
    np.testing.assert_allclose(load_samples(path).accel, whole.accel, rtol=1e-8)
    bag = tmp_path / 'w.mcap'
    write_bag(bag, iter(pieces))
    back = load_samples(bag)
    np.testing.assert_allclose(back.accel, whole.accel)
    np.testing.assert_allclose(back.temp, whole.temp)


def test_output_suffix_is_checked(tmp_path, capsys):
    for argv in (['simulate', '-o', str(tmp_path / 'NAME')],
                 ['simulate', '-o', str(tmp_path / 'x.txt')],
                 ['apply', 'c.yaml', 'd.csv', '-o', str(tmp_path / 'out.mcap')]):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert err.count('\n') == 1 and '.csv' in err, err
    assert os.listdir(tmp_path) == []


def test_apply_streams_and_matches_the_whole_file_correction(tmp_path, capsys, monkeypatch):
    from accel_calib_ros.dataio import csv_io, recording
    data, calib, out = tmp_path / 's.csv', tmp_path / 'c.yaml', tmp_path / 'o.csv'
    assert main(['simulate', '-o', str(data), '--poses', '12', '--temp', '20', '30']) == 0
    assert main(['fit', str(data), '-o', str(calib)]) == 0
    capsys.readouterr()
    monkeypatch.setattr(csv_io, 'PARSE_CHUNK_ROWS', 333)   # many pieces
    monkeypatch.setattr(recording.iter_samples, '__defaults__',
                        (333,) + recording.iter_samples.__defaults__[1:])
    assert main(['apply', str(calib), str(data), '-o', str(out), '--json']) == 0
    summary = json.loads(capsys.readouterr().out)
    from accel_calib_ros.dataio.calibration_file import load_calibration
    raw = load_samples(data)
    expect = load_calibration(calib).correct(raw.accel, raw.temp)
    got = load_samples(out)
    assert summary['samples'] == len(raw) == len(got)
    np.testing.assert_allclose(got.accel, expect, rtol=1e-8, atol=1e-9)
    assert summary['mean_norm_after'] == pytest.approx(
        np.linalg.norm(expect, axis=1).mean(), rel=1e-9)


def test_ctrl_c_stops_simulate_cleanly(tmp_path):
    out = tmp_path / 'big.csv'
    proc = subprocess.Popen(CLI + ['simulate', '-o', str(out), '--poses', '6',
                                   '--hold', '5000'],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and not any(
            name.endswith('.tmp.csv') and os.path.getsize(tmp_path / name) > 0
            for name in os.listdir(tmp_path)):
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 130
    assert stderr.count('\n') == 1 and 'interrupted' in stderr and 'Traceback' not in stderr
    assert os.listdir(tmp_path) == []          # neither the output nor a temporary file


def test_simulate_device_streams_a_long_hold_and_stops_on_sigint(tmp_path):
    proc = subprocess.Popen(CLI + ['simulate-device', '--hold', '100000', '--rate', '500'],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        pty = proc.stdout.readline().strip()      # printed once the device is plugged in
        assert pty.startswith('/dev/'), proc.stderr.read()
        fd = os.open(pty, os.O_RDONLY | os.O_NONBLOCK)
        got, deadline = b'', time.monotonic() + 20
        while len(got) < 2000 and time.monotonic() < deadline:
            try:
                got += os.read(fd, 4096)
            except BlockingIOError:
                time.sleep(0.02)
        os.close(fd)
        assert len(got) >= 2000                   # frames flow long before 10⁸ samples
        proc.send_signal(signal.SIGINT)
        _, stderr = proc.communicate(timeout=20)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0 and 'frames written' in stderr


def test_progress_bar_only_on_a_terminal_after_the_delay(monkeypatch):
    class Tty(io.StringIO):
        def isatty(self):
            return True

    monkeypatch.setattr(progress, 'DELAY_S', 0.0)
    pipe = io.StringIO()
    with progress.Progress(100, 'x', stream=pipe) as bar:
        bar.update(50)
    assert pipe.getvalue() == '' and bar.done == 50
    tty = Tty()
    with progress.Progress(100, 'work', stream=tty) as bar:
        bar.update(30)
        bar.update(30)
    assert 'work' in tty.getvalue() and '30' in tty.getvalue()  # the bar, at 30 of 100
    monkeypatch.setattr(progress, 'DELAY_S', 3600.0)
    tty = Tty()
    with progress.Progress(100, 'slow', stream=tty) as bar:
        bar.update(100)
    assert tty.getvalue() == ''


@pytest.mark.parametrize('argv', [['--help'], ['fit', 'DATA'], ['apply', '--help']])
def test_light_commands_import_no_heavy_module(tmp_path, argv):
    data = tmp_path / 's.csv'
    write_samples_csv(data, sim_motion.simulate_session(*session(poses=8)).samples)
    argv = [str(data) if a == 'DATA' else a for a in argv]
    code = ('import sys\nfrom accel_calib_ros.cli import main\n'
            f'try:\n    main({argv!r})\nexcept SystemExit:\n    pass\n'
            'heavy = ("scipy", "matplotlib", "rosbags", "rich", "tqdm", '
            '"accel_calib_ros.sim.device", "accel_calib_ros.sim.sensor", '
            '"accel_calib_ros.modelgap")\n'
            'print("LOADED", [m for m in heavy if m in sys.modules])\n')
    done = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                          timeout=60)
    assert 'LOADED []' in done.stdout, done.stdout + done.stderr
