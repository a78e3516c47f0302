"""
docs/parameters.md from the nodes' parameter tables (``python -m`` this module).

Each node declares its parameters once (a ``PARAMS`` list of typed, ranged, described
parameters); this prints them as Markdown, one table per node, without starting ROS (the
node modules are imported, no context is made). ``test/house/test_parameters_doc.py``
checks that docs/parameters.md is this output and that config/*.yaml sets exactly these
parameters, each to an allowed value.
"""

import importlib
import sys

NODES = (('mpu9250_driver', 'driver', 'driver.yaml', 'docs/driver.md'),
         ('accel_calibration', 'calibration_params', 'calibration.yaml',
          'docs/calibration_node.md'),
         ('accel_correction', 'correction', 'correction.yaml', 'docs/correction_node.md'))
"""(node name, module of its ``PARAMS``, its file in config/, its document)."""
REPORTED = {'accel_correction': (('correction_monitor', 'ESTIMATE_PARAM',
                                  'the gyro bias change the node subtracts now, rad/s (x, y, '
                                  'z); `ros2 param get` reads it, a value set is ignored'),)}
"""Read-only parameters a node writes itself: (module, attribute holding the name, meaning)."""


def tables():
    """Return {node name: its parameters (``Param``), in declaration order}."""
    return {name: list(importlib.import_module(f'{__package__}.{module}').PARAMS)
            for name, module, _, _ in NODES}


def reported():
    """Return {node name: [(parameter name, meaning)]} of the parameters a node writes."""
    return {node: [(getattr(importlib.import_module(f'{__package__}.{module}'), attr), text)
                   for module, attr, text in entries] for node, entries in REPORTED.items()}


def _cell(text):
    return str(text).replace('|', '\\|').replace('\n', ' ')


def _value(value):
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, str):
        return f"'{value}'"
    if isinstance(value, float):
        return f'{value:g}'
    return str(value)


def markdown():
    """Return docs/parameters.md."""
    lines = ['# Node parameters', '',
             "Generated from the nodes' parameter tables by `python -m "
             'accel_calib_ros.nodes.parameter_docs > docs/parameters.md`; do not edit by '
             'hand (`test/house/test_parameters_doc.py` checks it, and that `config/*.yaml` '
             'sets each of them to an allowed value).', '',
             'Every parameter is typed and ranged: a start-up value outside its range stops '
             'the node with the reason (exit status 2), a runtime change (`ros2 param set`) '
             'takes effect or is refused with the reason; `read-only` ones need a restart. '
             '`ros2 param describe` shows the same description.', '']
    for (name, _, config, doc), params in zip(NODES, tables().values()):
        lines += [f'## {name}', '',
                  f'`config/{config}`; behaviour: [{doc[5:]}]({doc[5:]}).', '',
                  '| parameter | type | default | allowed | description |',
                  '|---|---|---|---|---|']
        for p in params:
            allowed = p.constraints() + ('; read-only' if p.read_only else '')
            lines.append(f'| `{p.name}` | {p.kind} | {_cell(_value(p.default))} | '
                         f'{_cell(allowed.lstrip("; ")) or "any"} | {_cell(p.description)} |')
        for param, text in reported().get(name, ()):
            lines.append(f'| `{param}` | reported | | read-only: the node writes it | '
                         f'{_cell(text)} |')
        lines.append('')
    return '\n'.join(lines)


def main():
    """Print docs/parameters.md."""
    sys.stdout.write(markdown())
    return 0


if __name__ == '__main__':
    sys.exit(main())
