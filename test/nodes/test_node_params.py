"""The nodes' parameter mechanism (nodes/parameters.py), in-process on rclpy's public API."""

from accel_calib_ros.nodes.parameters import (declare_parameters, Param, ParameterProblem,
                                              ReportParameter)
import pytest
import rclpy
from rclpy.parameter import Parameter

pytestmark = pytest.mark.ros

SPECS = [
    Param('gain', 1.5, 'a gain, 1', low=0.0, low_open=True, high=10.0),
    Param('count', 5, 'a count', low=1),
    Param('method', 'ml', 'solver', choices=('ml', 'gn')),
    Param('port', '/dev/x', 'serial port', empty_ok=False, read_only=True),
    Param('flag', False, 'a switch'),
]


@pytest.fixture
def make_node():
    context = rclpy.Context()
    rclpy.init(context=context)
    made = []

    def make(overrides=(), check=None, apply=None):
        node = rclpy.create_node(f'params_{len(made)}', context=context,
                                 parameter_overrides=list(overrides))
        made.append(node)
        return node, declare_parameters(node, SPECS, check, apply)
    yield make
    for node in made:
        node.destroy_node()
    rclpy.try_shutdown(context=context)


def test_descriptors_and_start_up_values(make_node):
    node, values = make_node([Parameter('gain', value=2)])      # YAML 2 for 2.0
    assert values['gain'] == 2.0 and isinstance(values['gain'], float)
    assert node.get_parameter('gain').value == 2.0
    assert node.get_parameter('gain').type_ == Parameter.Type.DOUBLE
    d = node.describe_parameter('gain')
    assert d.type == Parameter.Type.DOUBLE.value
    assert d.floating_point_range[0].from_value == 0.0
    assert d.floating_point_range[0].to_value == 10.0
    assert 'gain' in d.description and '> 0' in d.additional_constraints
    assert node.describe_parameter('count').integer_range[0].from_value == 1
    assert node.describe_parameter('port').read_only
    for bad in (Parameter('gain', value=0.0), Parameter('gain', value=float('nan')),
                Parameter('gain', value=11.0), Parameter('gain', value='fast'),
                Parameter('method', value='foo'), Parameter('count', value=1.5),
                Parameter('port', value='')):
        with pytest.raises(ParameterProblem, match=f"parameter '{bad.name}' must"):
            make_node([bad])


def test_runtime_changes_checked_then_applied(make_node):
    checked, applied = [], []

    def check(changes, proposed):
        checked.append(dict(proposed))
        if changes.get('count') == 13:
            raise ParameterProblem('13 is unlucky')

    def apply(changes):
        # Applied after rclpy stored the value: the node reads it back the same.
        applied.append({k: node.get_parameter(k).value for k in changes})

    node, values = make_node(check=check, apply=apply)
    (r,) = node.set_parameters([Parameter('gain', value=3)])      # int for a double
    assert r.successful, r.reason
    assert values['gain'] == 3.0 and applied == [{'gain': 3.0}]
    assert checked[-1]['gain'] == 3.0 and checked[-1]['count'] == 5
    refused = {'gain': float('inf'), 'method': 'lm', 'port': '/dev/y', 'flag': 'yes',
               'count': 13}
    for name, value in refused.items():
        (r,) = node.set_parameters([Parameter(name, value=value)])
        assert not r.successful and r.reason, name
        assert node.get_parameter(name).value == values[name] != value
    (r,) = node.set_parameters([Parameter('gain', value=0.0)])     # open bound
    assert not r.successful and '> 0' in r.reason
    (r,) = node.set_parameters([Parameter('count', value=13)])
    assert 'unlucky' in r.reason and values['count'] == 5
    assert applied == [{'gain': 3.0}]


def test_a_change_that_fails_to_apply_is_rolled_back(make_node):
    effects = []

    def apply(changes):
        effects.append(dict(changes))
        if changes.get('count') == 7:
            raise OSError('the device went away')

    node, values = make_node(apply=apply)
    (r,) = node.set_parameters([Parameter('count', value=7)])
    assert r.successful                    # rclpy had stored it: the rollback follows
    assert node.get_parameter('count').value == 5 and values['count'] == 5
    assert effects == [{'count': 7}, {'count': 5}]         # the side effects undone


def test_without_hook_changes_are_refused(make_node):
    node, values = make_node()
    (r,) = node.set_parameters([Parameter('gain', value=2.5)])
    assert not r.successful and 'restart' in r.reason
    assert values['gain'] == 1.5


def test_a_report_parameter_is_written_by_the_node_only(make_node):
    node, _ = make_node()
    report = ReportParameter(node, 'estimate', [0.0, 0.0], 'what the node found')
    (r,) = node.set_parameters([Parameter('estimate', value=[1.0, 2.0])])
    assert not r.successful and 'read-only' in r.reason
    assert report.report([0.5, -0.5]) and list(report.value) == [0.5, -0.5]
    assert 'a set is refused' in node.describe_parameter('estimate').description
