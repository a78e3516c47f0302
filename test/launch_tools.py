"""
The launch file turned into the processes launch_ros would start (launch is not on PyPI).

:func:`load_description` imports ``launch/accel_calib.launch.py`` with recording stand-ins
for ``launch``/``launch_ros``; :func:`command_lines` evaluates its arguments, conditions
and Node actions the way launch_ros (Jazzy) does: ``<executable> --ros-args -r
__node:=NAME [-r __ns:=/NS]``, then each parameter file as ``--params-file`` and each
dict of parameters written to a temporary file keyed by the node's full name (``/NS/NAME``)
whose values are substitutions read as YAML (``true`` a bool, ``'' `` refused), then the
node's remappings as ``-r NAME:FROM:=TO``.
"""

import importlib.util
import os
import sys
import types

import yaml


class Config:
    """Stand-in of ``launch.substitutions.LaunchConfiguration``."""

    def __init__(self, name):
        self.name = name


class Action:
    """Stand-in of a launch action: its kind and its arguments."""

    def __init__(self, kind, *args, **kwargs):
        self.kind, self.args, self.kwargs = kind, args, kwargs


def load_description(launch_file, share_dir, monkeypatch):
    """Import ``launch_file`` with recording stand-ins; return its list of actions."""
    modules = {
        'launch': {'LaunchDescription': lambda actions: list(actions)},
        'launch.actions': {'DeclareLaunchArgument': lambda *a, **k: Action('arg', *a, **k)},
        'launch.conditions': {'IfCondition': lambda *a, **k: Action('if', *a, **k)},
        'launch.substitutions': {'LaunchConfiguration': Config},
        'launch_ros.actions': {'Node': lambda *a, **k: Action('node', *a, **k)},
        'launch_ros': {},
        'ament_index_python.packages': {'get_package_share_directory': lambda p: share_dir},
        'ament_index_python': {},
    }
    for name, attrs in modules.items():
        module = types.ModuleType(name)
        module.__dict__.update(attrs)
        monkeypatch.setitem(sys.modules, name, module)
    spec = importlib.util.spec_from_file_location('accel_calib_launch', launch_file)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.generate_launch_description()


def arguments(actions):
    """Return {name: (default value, description)} of the declared launch arguments."""
    return {a.args[0]: (a.kwargs.get('default_value'), a.kwargs.get('description'))
            for a in actions if a.kind == 'arg'}


def _text(value, configs):
    return configs[value.name] if isinstance(value, Config) else value


def _parameter_value(name, value, configs):
    """Evaluate a dict value as launch_ros does: a substitution is read as YAML."""
    if not isinstance(value, Config):
        return value
    loaded = yaml.safe_load(configs[value.name])
    if type(loaded) not in (bool, int, float, str):
        raise TypeError(f'launch_ros refuses parameter {name}={configs[value.name]!r} '
                        f'(YAML {type(loaded).__name__})')
    return loaded


def command_lines(actions, given, folder, executable_path):
    """
    Return the processes launch_ros would start, as dicts (name, namespace, cmd, ...).

    :param given: launch arguments given on the command line (``name:=value``).
    :param folder: where the temporary parameter files go.
    :param executable_path: f(package, executable) -> path of the program to run.
    """
    configs = {name: default for name, (default, _) in arguments(actions).items()}
    unknown = set(given) - set(configs)
    if unknown:
        raise KeyError(f'undeclared launch arguments {sorted(unknown)}')
    configs.update(given)
    out = []
    for action in actions:
        if action.kind != 'node':
            continue
        kw = action.kwargs
        condition = kw.get('condition')
        if condition is not None:
            value = _text(condition.args[0], configs).strip().lower()
            if value not in ('true', 'false', '1', '0'):
                raise ValueError(f'IfCondition needs true or false, not {value!r}')
            if value in ('false', '0'):
                continue
        name = kw['name']
        namespace = _text(kw.get('namespace', ''), configs) or ''
        namespace = '/' + namespace.strip('/') if namespace.strip('/') else ''
        full = f'{namespace}/{name}'
        cmd = [executable_path(kw['package'], kw['executable']), '--ros-args',
               '-r', f'__node:={name}']
        if namespace:
            cmd += ['-r', f'__ns:={namespace}']
        files = []
        for k, params in enumerate(kw.get('parameters', [])):
            if isinstance(params, dict):
                values = {p: _parameter_value(p, v, configs) for p, v in params.items()}
                path = os.path.join(folder, f'launch_params_{name}_{k}.yaml')
                with open(path, 'w', encoding='utf-8') as f:
                    yaml.safe_dump({full: {'ros__parameters': values}}, f)
            else:
                path = _text(params, configs)
            files.append(path)
            cmd += ['--params-file', path]
        for src, dst in kw.get('remappings', []):
            cmd += ['-r', f'{name}:{_text(src, configs)}:={_text(dst, configs)}']
        out.append({'name': name, 'namespace': namespace or '/', 'package': kw['package'],
                    'executable': kw['executable'], 'cmd': cmd, 'parameter_files': files})
    return out
