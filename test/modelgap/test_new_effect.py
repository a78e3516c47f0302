"""
Adding an effect is adding one class: the example in ``modelgap.effects`` is all it takes.

The class is taken from the module's docstring and executed as written, then registered
for the test only. Nothing else in the package knows its name, yet the simulator hides it,
``diagnose_windows`` names it, the naming simulation states its power, the ambiguity advice
knows its family, and ``accel-calib simulate`` and the virtual device take it.
"""

import argparse
import json
import textwrap

from accel_calib_ros.cli import main
from accel_calib_ros.core.constants import G0
from accel_calib_ros.modelgap import diagnose_windows
from accel_calib_ros.modelgap.effects import EFFECTS
from accel_calib_ros.modelgap.evidence import separation_advice
from accel_calib_ros.sim import device
from accel_calib_ros.sim.motion import random_directions, simulate_static_windows
from accel_calib_ros.sim.sensor import mpu9250_like, with_datasheet_effect
import numpy as np
import pytest
import yaml

HOLD_S, WINDOWS = 3.5, 60


def hump(t):
    """Return a temperature that rises and falls again (10 -> 45 -> 10 °C), not with time."""
    return 10.0 + 35.0 * np.sin(np.pi * np.asarray(t, float) / (WINDOWS * HOLD_S))


def example_class():
    """Return the class of the ``effects`` docstring, executed as written there."""
    from accel_calib_ros.modelgap import effects
    block = effects.__doc__.split('::\n\n', 1)[1].split('\n\nand listing', 1)[0]
    namespace = dict(vars(effects))
    exec(textwrap.dedent(block), namespace)       # noqa: S102 - the package's own docstring
    return namespace['TemperatureBiasQuadratic']


@pytest.fixture
def new(monkeypatch):
    """Register the example effect for one test (last in the library, as documented)."""
    effect = example_class()()
    assert effect.name not in EFFECTS
    monkeypatch.setitem(EFFECTS, effect.name, effect)
    return effect


def test_the_example_effect_is_simulated_named_and_measured(new):
    rng = np.random.default_rng(13)
    sensor = with_datasheet_effect(mpu9250_like(rng), new.name, rng)
    assert [e for e, _ in sensor.library_effects] == [new]
    hidden = sensor.library_effects[0][1]
    np.testing.assert_allclose(np.abs(hidden), 0.05e-3 * G0 * np.array([1.0, 0.75, 0.5]))
    # The curvature about the session's mean temperature: the simulator takes the
    # temperature from temp_ref, the fit from the session's mean.
    sensor.temp_ref = float(np.mean(hump((np.arange(WINDOWS) + 0.5) * HOLD_S)))
    windows = simulate_static_windows(sensor, random_directions(WINDOWS, rng), rng, HOLD_S,
                                      temperature=hump)
    result = diagnose_windows(windows, 'ml')
    assert result.missing_effects == [new.name], result.text()
    evidence = result.steps[0]['evidence']
    assert 'offset curvature' in evidence['magnitude'] and 'mg/°C²' in evidence['magnitude']
    np.testing.assert_allclose(evidence['params'], hidden, rtol=0.1)
    assert result.gap_before > 5.0 and result.gap_after < 1.5
    assert result.explained
    assert new.name in result.summary()['parameters']['effects']


def test_the_example_effect_gets_a_power_figure_and_advice_by_its_family(new):
    rng = np.random.default_rng(14)
    windows = simulate_static_windows(mpu9250_like(rng), random_directions(WINDOWS, rng), rng,
                                      HOLD_S, temperature=hump)
    result = diagnose_windows(windows, 'ml')
    assert result.missing_effects == [] and new.name in result.tested
    figure = result.power()['per_effect'][new.name]
    assert figure['min_named_mg'] is not None, figure
    assert result.threshold_mg <= figure['min_named_mg'] <= 16 * result.threshold_mg
    assert f'{new.name} {figure["min_named_mg"]:.2g} mg' in result.text()
    # Its family is temperature, it changes the offset and has no history: the advice
    # against a drift, a scale change and a lag is temperature_bias's.
    c = result.conditions
    for other in ('bias_drift', 'temperature_scale', 'temperature_lag'):
        advice = separation_advice(new.name, other, c)
        assert advice == separation_advice('temperature_bias', other, c)
        assert advice == separation_advice(other, new.name, c)
    assert 'up and down' in separation_advice(new.name, 'temperature_scale', c)


def test_the_cli_and_the_virtual_device_take_the_example_effect(new, tmp_path, capsys):
    assert main(['simulate', '--help']) == 0
    assert new.name in capsys.readouterr().out
    data, truth = tmp_path / 's.csv', tmp_path / 'truth.yaml'
    assert main(['simulate', '-o', str(data), '--effects', new.name, '--poses', '12',
                 '--hold', '1', '--truth', str(truth), '--temp', '15', '35', '--json']) == 0
    summary = json.loads(capsys.readouterr().out)
    params = summary['truth']['library_effects'][new.name]['params']
    size = np.abs(params) / G0
    assert np.all((size >= 0.02e-3 - 1e-12) & (size <= 0.05e-3 + 1e-12)), size
    assert yaml.safe_load(truth.read_text())['library_effects'][new.name]['params'] == params
    # The same sensor without it: the other draws are unchanged (it is drawn last).
    plain = mpu9250_like(np.random.default_rng(0))
    drawn = mpu9250_like(np.random.default_rng(0), effects=[new.name])
    np.testing.assert_array_equal(plain.T, drawn.T)
    np.testing.assert_array_equal(plain.bias, drawn.bias)
    assert new.name in device.device_effects()
    parser = argparse.ArgumentParser()
    device.add_arguments(parser)
    args = parser.parse_args(['--poses', 'random', '--count', '2', '--effects', new.name])
    virtual = device.VirtualSensor(args)
    assert [e for e, _ in virtual.sensor.library_effects] == [new]
