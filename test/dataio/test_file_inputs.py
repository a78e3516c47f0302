"""Files a user hands over: one line, exit 2, never an internal error."""

import json
import os

from accel_calib_ros.cli import main
from accel_calib_ros.cli.common import MAX_MESSAGE, message_line
from accel_calib_ros.core.errors import InputError
from accel_calib_ros.dataio.calibration_file import load_calibration
from accel_calib_ros.dataio.noise_file import noise_from_allan
import pytest

DATA_COMMANDS = ('fit', 'advise', 'allan', 'diagnose', 'apply')


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope='module')
def calibration(tmp_path_factory):
    folder = tmp_path_factory.mktemp('inputs16')
    data = folder / 's.csv'
    assert main(['simulate', '-o', str(data), '--poses', '12', '--seed', '3']) == 0
    cal = folder / 'cal.yaml'
    assert main(['fit', str(data), '-o', str(cal)]) == 0
    return cal


def _argv(command, path, calibration, tmp_path):
    if command == 'apply':
        return ['apply', calibration, path, '-o', tmp_path / 'out.csv']
    return [command, path]


HOSTILE = {
    'first field 200 KiB': 't' * 200_000 + ',ax,ay,az\n0,0,0,9.8\n',
    'no newline at all': 'x' * 300_000,
    'json named csv': json.dumps({f'key{k}': list(range(30)) for k in range(4000)}),
    'json pretty': json.dumps({'t': [0, 1], 'ax': [0, 0]}, indent=2),
    'data field 200 KiB': 't,ax,ay,az\n0,0,0,9.8\n' + '1' * 200_000 + ',0,0,9.8\n',
    'quote never closed': 't,ax,ay,az\n"0,0,0,9.8\n' + '1,0,0,9.8\n' * 1000,
    'nul bytes': 't,ax,ay,az\n0,0\x00,0,9.8\n',
    'header of 5000 columns': ','.join(f'c{k}' for k in range(5000)) + '\n',
    'control characters': 't,ax,ay,az\n\x1b[2J\x1b]0;owned\x07,0,0,9.8\n',
}


@pytest.mark.parametrize('content', sorted(HOSTILE))
@pytest.mark.parametrize('command', DATA_COMMANDS)
def test_hostile_csv_is_one_short_line(tmp_path, capsys, calibration, content, command):
    """A >128 KiB field, no newline: "internal error"; a JSON file: a 380 kB error line."""
    path = tmp_path / 'in.csv'
    path.write_text(HOSTILE[content])
    code, out, err = run(capsys, *_argv(command, path, calibration, tmp_path))
    assert code == 2, (content, err[:300])
    assert err.count('\n') == 1 and len(err) <= MAX_MESSAGE + 1, (content, err[:300])
    assert 'internal error' not in err and '\x1b' not in err and '\x07' not in err
    assert not (tmp_path / 'out.csv').exists()


def test_json_named_csv_says_it_looks_like_json(tmp_path, capsys):
    path = tmp_path / 'allan.csv'
    path.write_text(HOSTILE['json named csv'])
    code, _, err = run(capsys, 'fit', path)
    assert code == 2 and 'looks like JSON' in err


def test_a_fifo_or_device_as_input_is_refused_without_blocking(tmp_path, capsys, calibration):
    fifo = tmp_path / 'data.csv'
    os.mkfifo(fifo)
    for command in DATA_COMMANDS:
        code, _, err = run(capsys, *_argv(command, fifo, calibration, tmp_path))
        assert code == 2 and 'not a regular file' in err, err
    allan = tmp_path / 'allan.json'
    os.mkfifo(allan)
    with pytest.raises(InputError, match='not a regular file'):
        noise_from_allan(allan, 100.0)
    with pytest.raises(InputError, match='not a regular file'):
        noise_from_allan('/dev/zero', 100.0)
    with pytest.raises(InputError, match='not a regular file'):
        load_calibration('/dev/zero')


def test_message_line_is_one_printable_line_of_bounded_length():
    text = 'accel-calib: error: /' + 'deep/' * 200 + 'x.csv: bad\nsecond\x1b[31m line \u202e end'
    line = message_line(text)
    assert len(line) <= MAX_MESSAGE and '\n' not in line and '\x1b' not in line
    assert '\u202e' not in line and line.endswith('end')
    assert message_line('short') == 'short'
    words = 'word ' * 100
    assert len(message_line(words)) <= MAX_MESSAGE


CALIBRATION = """format: accel_calib_ros/calibration
version: 1
method: ml
gravity_m_s2: 9.80665
T: [[1, 0, 0], [0, 1, 0], [0, 0, 1]]
bias_m_s2: [0, 0, 0]
"""


@pytest.mark.parametrize('text, words', [
    (CALIBRATION + 'bias_m_s2: [1, 1, 1]\n', "duplicate key 'bias_m_s2' (line 6 and line 7)"),
    (CALIBRATION + 'fit: {observations: 3, observations: 4}\n', "duplicate key 'observations'"),
    (CALIBRATION.replace('version: 1', 'version: "1"'),
     "version must be the integer 1, found the string '1'"),
    (CALIBRATION.replace('version: 1', 'version: 2'),
     'version must be the integer 1, found the integer 2'),
    (CALIBRATION.replace('version: 1', 'version: 1.0'),
     'version must be the integer 1, found the number 1.0'),
    (CALIBRATION.replace('version: 1', 'version: true'),
     'version must be the integer 1, found the boolean True'),
    (CALIBRATION.replace('version: 1\n', ''), 'version must be the integer 1, found nothing'),
])
def test_calibration_file_duplicates_and_versions_say_what_was_found(tmp_path, text, words):
    path = tmp_path / 'cal.yaml'
    path.write_text(text)
    with pytest.raises(InputError) as info:
        load_calibration(path)
    assert words in str(info.value) and '\n' not in str(info.value)


def test_the_good_calibration_still_loads(tmp_path):
    path = tmp_path / 'cal.yaml'
    path.write_text(CALIBRATION + 'fit: {observations: 3}\nsensor_id: imu\n')
    assert load_calibration(path).sensor_id == 'imu'
    path.write_text(CALIBRATION + 'thermal:\n  band_width_c: 10\n  bands: []\n'
                    'x: &a {k: 1}\ny: *a\n')
    load_calibration(path)                              # anchors and aliases are not duplicates


def test_noise_file_duplicate_keys_are_refused(tmp_path):
    path = tmp_path / 'allan.json'
    path.write_text('{"axes": ["ax", "ay", "az"], "white_sample_std": [0.01, 0.01, 0.01], '
                    '"rate_hz": 100, "rate_hz": 1000}')
    with pytest.raises(InputError, match="duplicate key 'rate_hz'"):
        noise_from_allan(path, 100.0)
