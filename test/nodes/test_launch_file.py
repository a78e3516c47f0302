"""The launch file, read with stand-ins for launch/launch_ros (not installable from PyPI)."""

import importlib.util
import os
import sys
import types

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def load_description(monkeypatch):
    """Import launch/accel_calib.launch.py with recording stand-ins; return its actions."""
    def record(kind):
        class Action:
            def __init__(self, *args, **kwargs):
                self.kind, self.args, self.kwargs = kind, args, kwargs
        return Action
    modules = {
        'launch': {'LaunchDescription': lambda actions: actions},
        'launch.actions': {'DeclareLaunchArgument': record('arg')},
        'launch.conditions': {'IfCondition': record('if')},
        'launch.substitutions': {'LaunchConfiguration': record('config')},
        'launch_ros.actions': {'Node': record('node')},
        'launch_ros': {},
        'ament_index_python.packages': {'get_package_share_directory': lambda p: ROOT},
        'ament_index_python': {},
    }
    for name, attrs in modules.items():
        module = types.ModuleType(name)
        module.__dict__.update(attrs)
        monkeypatch.setitem(sys.modules, name, module)
    spec = importlib.util.spec_from_file_location(
        'accel_calib_launch', os.path.join(ROOT, 'launch', 'accel_calib.launch.py'))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.generate_launch_description()


def test_madgwick_chain_reads_the_corrected_stream(monkeypatch):
    actions = load_description(monkeypatch)
    args = {a.args[0]: a.kwargs.get('default_value') for a in actions if a.kind == 'arg'}
    assert args['chain_madgwick'] == 'false' and args['calibrate'] == 'true'
    nodes = {a.kwargs['executable']: a.kwargs for a in actions if a.kind == 'node'}
    assert {'mpu9250_driver', 'accel_calibration', 'accel_correction'} <= set(nodes)
    madgwick = nodes['imu_filter_madgwick_node']
    assert madgwick['package'] == 'imu_filter_madgwick'
    assert ('imu/data_raw', 'imu/corrected') in madgwick['remappings']
    assert madgwick['condition'].args[0].args[0] == 'chain_madgwick'
    # The magnetometer (issue 19): off by default, and from the corrected topic when on.
    assert args['use_mag'] == 'false'
    assert ('imu/mag', 'imu/mag_corrected') in madgwick['remappings']
    assert madgwick['parameters'][0]['use_mag'].args[0] == 'use_mag'
    for name in ('calibration', 'correction', 'driver'):
        assert os.path.exists(os.path.join(ROOT, 'config', f'{name}.yaml'))
