"""``accel-calib guide`` in a real terminal: tmux send-keys and capture-pane."""

import os
import re
import shlex
import shutil
import subprocess
import sys
import time
import uuid

from accel_calib_ros.dataio.calibration_file import load_calibration
import numpy as np
import pytest

pytestmark = pytest.mark.skipif(
    shutil.which('tmux') is None,
    reason='tmux is not installed (apt-get install tmux); the live terminal test needs it')


class Tmux:
    """A private tmux server with one pane running a plain shell."""

    def __init__(self, cwd):
        self.socket = f'accel-calib-test-{uuid.uuid4().hex[:8]}'
        self.run('new-session', '-d', '-s', 'guide', '-x', '100', '-y', '60', '-c', str(cwd),
                 'env -i PATH=/usr/bin:/bin HOME=/tmp TERM=xterm-256color '
                 'bash --norc --noprofile')

    def run(self, *args):
        return subprocess.run(['tmux', '-L', self.socket, *args], check=True,
                              capture_output=True, text=True, timeout=10).stdout

    def send(self, text, enter=True):
        self.run('send-keys', '-t', 'guide', '-l', text)
        if enter:
            self.run('send-keys', '-t', 'guide', 'Enter')

    def screen(self):
        return self.run('capture-pane', '-p', '-t', 'guide', '-S', '-200')

    def wait_for(self, predicate, timeout_s, what):
        deadline = time.monotonic() + timeout_s
        seen = []
        while time.monotonic() < deadline:
            text = self.screen()
            seen.append(text)
            if predicate(text):
                return text, seen
            time.sleep(0.2)
        raise AssertionError(f'timed out waiting for {what}; screen:\n{seen[-1]}')

    def close(self):
        subprocess.run(['tmux', '-L', self.socket, 'kill-server'], capture_output=True,
                       timeout=10)


@pytest.fixture
def tmux(tmp_path):
    t = Tmux(tmp_path)
    yield t
    t.close()


def _command(*args):
    return ' '.join(shlex.quote(a) for a in
                    [sys.executable, '-m', 'accel_calib_ros.cli', 'guide', *args])


def test_guide_walks_a_simulated_person_to_a_written_calibration(tmux, tmp_path):
    out = tmp_path / 'calibration.yaml'
    env = f'PYTHONPATH={shlex.quote(os.pathsep.join(sys.path))} '
    tmux.send(env + _command('--simulate', '--speed', '15', '--seed', '4', '-o', str(out),
                             '--timeout', '90') + '; echo GUIDE-EXIT=$?')
    mid, _ = tmux.wait_for(lambda s: 'next pose:' in s and 'windows' in s, 30.0,
                           'the procedure')
    for words in ('gravity now', 'hold', 'predicted accuracy', 'target 0.0100'):
        assert words in mid
    final, seen = tmux.wait_for(lambda s: re.search(r'GUIDE-EXIT=\d', s), 120.0, 'the end')
    assert 'GUIDE-EXIT=0' in final
    assert 'ENOUGH' in final and f'wrote calibration {out}' in final.replace('\n', '')
    # The screen walked through several poses: the advice changed as windows came in.
    names = {line.split('next pose:')[1].split('(')[0].strip(' ─╮')
             for text in seen for line in text.splitlines() if 'next pose:' in line}
    assert len(names) >= 3
    cal = load_calibration(out)
    assert 0 < cal.predicted_accuracy <= 0.01
    assert np.all(np.abs(np.diag(cal.T) - 1.0) < 0.05)


def test_q_stops_the_guide_without_writing(tmux, tmp_path):
    out = tmp_path / 'calibration.yaml'
    env = f'PYTHONPATH={shlex.quote(os.pathsep.join(sys.path))} '
    tmux.send(env + _command('--simulate', '--speed', '1', '-o', str(out), '--timeout', '60')
              + '; echo GUIDE-EXIT=$?')
    tmux.wait_for(lambda s: 'hold' in s and 'q: stop' in s, 30.0, 'the procedure')
    tmux.send('q', enter=False)
    final, _ = tmux.wait_for(lambda s: re.search(r'GUIDE-EXIT=\d', s), 30.0, 'the end')
    assert 'stopped: nothing written' in final and 'GUIDE-EXIT=1' in final
    assert not out.exists()
