"""SIGTERM and SIGHUP clean up exactly like SIGINT: exit 128+N, no temp file."""

import os
import signal
import subprocess
import sys
import time

from accel_calib_ros import cli
from accel_calib_ros.cli import main
from accel_calib_ros.core.samples import Samples
from accel_calib_ros.dataio.atomic import atomic_path
from accel_calib_ros.dataio.recording import write_samples_csv
import numpy as np
import pytest


@pytest.fixture(scope='module')
def big_csv(tmp_path_factory):
    """
    Write a CSV that takes ``apply`` a few seconds, so the signal lands mid-write.

    About 2 s of writing, which a loaded 2-core machine needs (600 000 rows left 0.7 s).
    """
    folder = tmp_path_factory.mktemp('signals')
    n = 1_500_000
    rng = np.random.default_rng(0)
    accel = rng.normal(0, 0.01, (n, 3)) + [0.0, 0.0, 9.80665]
    path = folder / 'big.csv'
    write_samples_csv(path, Samples(np.arange(n) * 0.005, accel, np.full(n, 25.0)))
    cal = folder / 'cal.yaml'
    from accel_calib_ros.core.calibration import Calibration
    from accel_calib_ros.dataio.calibration_file import save_calibration
    save_calibration(Calibration(T=np.diag([1.01, 0.99, 1.0]), bias=[0.1, -0.2, 0.3]), cal)
    return path, cal


def _temp_files(folder):
    return [n for n in os.listdir(folder) if n.startswith('.') and '.tmp' in n]


@pytest.mark.parametrize('signum', [signal.SIGTERM, signal.SIGHUP, signal.SIGINT])
def test_a_stopping_signal_mid_write_leaves_no_temp_file(tmp_path, big_csv, signum):
    """SIGTERM during ``apply`` left a 48 MB hidden temp file."""
    data, cal = big_csv
    out = tmp_path / 'corrected.csv'
    out.write_text('old\n')
    proc = subprocess.Popen([sys.executable, '-m', 'accel_calib_ros.cli', 'apply', str(cal),
                             str(data), '-o', str(out)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while not _temp_files(tmp_path) and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.01)
    assert proc.poll() is None, 'apply ended before the signal: make the file bigger'
    time.sleep(0.05)                                # well inside the write
    proc.send_signal(signum)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 128 + signum, err
    assert err.count('\n') == 1 and 'partial output removed' in err, err
    assert _temp_files(tmp_path) == [] and out.read_text() == 'old\n'


def test_the_handlers_raise_where_the_program_is_and_are_restored(tmp_path, monkeypatch,
                                                                  capsys):
    """In-process: a SIGTERM inside a write removes the temp file; main returns 143."""
    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    target = tmp_path / 'x.csv'

    def command(args, out):
        with atomic_path(target) as tmp:
            with open(tmp, 'w') as f:
                f.write('half')
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(5)               # the handler raises before this ends
        return 0

    monkeypatch.setattr(cli, 'command_module', lambda name: type('M', (), {
        'run': staticmethod(command), 'add_arguments': staticmethod(lambda p: None)}))
    assert main(['allan']) == 143
    assert 'stopped by SIGTERM' in capsys.readouterr().err
    assert os.listdir(tmp_path) == []
    assert {s: signal.getsignal(s) for s in before} == before


def test_an_ignored_sighup_stays_ignored(monkeypatch):
    """Under nohup (SIGHUP ignored) the command keeps running when the terminal goes."""
    old = signal.signal(signal.SIGHUP, signal.SIG_IGN)
    try:
        seen = []

        def command(args, out):
            os.kill(os.getpid(), signal.SIGHUP)
            time.sleep(0.05)
            seen.append(signal.getsignal(signal.SIGHUP))
            return 0

        monkeypatch.setattr(cli, 'command_module', lambda name: type('M', (), {
            'run': staticmethod(command), 'add_arguments': staticmethod(lambda p: None)}))
        assert main(['allan']) == 0 and seen == [signal.SIG_IGN]
    finally:
        signal.signal(signal.SIGHUP, old)


def test_guide_stopped_by_sigterm_writes_nothing_and_says_143(tmp_path):
    """The guide catches the interrupt itself: it returns 128+N like main does."""
    out = tmp_path / 'cal.yaml'
    proc = subprocess.Popen([sys.executable, '-m', 'accel_calib_ros.cli', 'guide', '--simulate',
                             '-o', str(out), '--timeout', '60'], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)
    time.sleep(3.0)
    assert proc.poll() is None
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 143, err
    assert os.listdir(tmp_path) == []
