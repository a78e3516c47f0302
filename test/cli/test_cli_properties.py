"""Property-based tests: nothing a user can type reaches a traceback or "internal error"."""

import contextlib
import io
import json
import os

from accel_calib_ros.cli import main
from hypothesis import given, HealthCheck, settings, strategies as st
import pytest

_NUMBERS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.integers(-10 ** 6, 10 ** 6).map(str),
    st.sampled_from(['nan', 'inf', '-inf', '1e400', '-0', '0', '1e-400', '0x10', '', ' ',
                     '1_0', '١', 'NaN', '5', '2.5']),
    st.text(max_size=6))

_FIT_OPTIONS = ['--min-window-s', '--threshold-factor', '--max-weight-s', '--band-width',
                '--gravity', '--max-predicted-error', '--method', '--mode']
_SIM_OPTIONS = ['--hold', '--move', '--rate', '--temp', '--seed', '--gravity', '--poses',
                '--effects']


def _run(argv):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main([str(a) for a in argv])
    return code, out.getvalue(), err.getvalue()


def _check(code, out, err):
    assert code in (0, 1, 2), (code, err)
    assert 'Traceback' not in err and 'internal error' not in err, err
    if code == 2:
        assert err.count('\n') == 1, err


@pytest.fixture(scope='module')
def small_session(tmp_path_factory):
    folder = tmp_path_factory.mktemp('prop')
    data = folder / 's.csv'
    assert main(['simulate', '-o', str(data), '--poses', '14', '--hold', '2', '--move', '1',
                 '--seed', '2']) == 0
    return folder, data


@settings(max_examples=60, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(st.lists(st.tuples(st.sampled_from(_FIT_OPTIONS), _NUMBERS), min_size=1, max_size=3),
       st.booleans())
def test_property_fit_options(small_session, options, as_json):
    folder, data = small_session
    output = folder / 'fuzz.yaml'
    if output.exists():
        output.unlink()
    argv = ['fit', data, '-o', output] + (['--json'] if as_json else [])
    for name, value in options:
        argv += [name, value] if not value.startswith('-') else [f'{name}={value}']
    before = data.read_bytes()
    code, out, err = _run(argv)
    _check(code, out, err)
    assert data.read_bytes() == before
    assert output.exists() == (code == 0)
    if as_json and code in (0, 1) and out:
        json.loads(out)                                   # strict JSON, no NaN


@settings(max_examples=40, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(st.sampled_from(_SIM_OPTIONS), _NUMBERS)
def test_property_simulate_options(small_session, name, value):
    folder, _ = small_session
    output = folder / 'sim.csv'
    if output.exists():
        output.unlink()
    argv = ['simulate', '-o', output, '--poses', '3', '--hold', '0.3', '--move', '0.2',
            '--rate', '50']
    argv += [name, value] if not value.startswith('-') else [f'{name}={value}']
    if name == '--poses' and value.strip().isdecimal() and int(value) > 50:
        argv += ['--hold', '0.02', '--move', '0.02']       # keep a valid huge count quick
    code, out, err = _run(argv)
    _check(code, out, err)
    assert output.exists() == (code == 0)
    if code == 0:
        with open(output) as f:
            text = f.read().lower()
        assert 'nan' not in text and 'inf' not in text


@settings(max_examples=30, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(st.binary(max_size=300))
def test_property_apply_with_any_calibration_bytes(small_session, blob):
    folder, data = small_session
    calib, output = folder / 'any.yaml', folder / 'applied.csv'
    calib.write_bytes(blob)
    if output.exists():
        output.unlink()
    code, out, err = _run(['apply', calib, data, '-o', output])
    _check(code, out, err)
    assert code == 2 and not output.exists()             # random bytes are never a calibration
    assert os.path.exists(calib) and calib.read_bytes() == blob
