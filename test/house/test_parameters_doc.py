"""
docs/parameters.md is generated from the nodes' parameter tables, and config/*.yaml sets them.

The tables are read without starting ROS (the node modules import rclpy's types, so this
needs rclpy installed, not a running graph).
"""

import os

import pytest
import yaml

pytest.importorskip('rclpy')

ROOT = os.path.join(os.path.dirname(__file__), '..', '..')


def test_the_parameter_document_is_the_tables_as_they_are():
    from accel_calib_ros.nodes.parameter_docs import markdown
    with open(os.path.join(ROOT, 'docs', 'parameters.md'), encoding='utf-8') as f:
        written = f.read()
    assert written == markdown(), ('docs/parameters.md is stale: python -m '
                                   'accel_calib_ros.nodes.parameter_docs > docs/parameters.md')


@pytest.mark.parametrize('node', ['mpu9250_driver', 'accel_calibration', 'accel_correction'])
def test_each_config_file_sets_every_parameter_to_an_allowed_value(node):
    from accel_calib_ros.nodes.parameter_docs import NODES, reported, tables
    config = {n: c for n, _, c, _ in NODES}[node]
    with open(os.path.join(ROOT, 'config', config), encoding='utf-8') as f:
        values = yaml.safe_load(f)['/**']['ros__parameters']
    params = tables()[node]
    declared = [p.name for p in params]
    written = set(declared) | {name for name, _ in reported().get(node, ())}
    assert sorted(set(declared) - set(values)) == [], f'config/{config} leaves them out'
    assert sorted(set(values) - written) == [], f'config/{config} sets parameters no node has'
    for p in params:
        p.check(values[p.name])             # raises with the reason when not allowed
