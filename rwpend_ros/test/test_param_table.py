"""rwpend_ros.params.ParameterTable on a real rclpy node (no other process): declared with the
real type, description, range and read-only flag; overrides and set values read by the tools'
rules; anything else refused with the reason, nothing changed."""
from __future__ import annotations

import pytest
import rclpy
from rcl_interfaces.msg import ParameterType
from rclpy.node import Node
from rclpy.parameter import Parameter

from rwpend_model.rig import DESCRIPTIONS, Rig
from rwpend_ros.params import ConfigError, ParameterTable, declare_rig, descriptor, rig_specs
from rwpend_ros.paramspec import ParamSpec
from rwpend_ros.testenv import test_domain_id

SPECS = [
    ParamSpec('mode', 'off', 'operating mode', choices=('off', 'balance')),
    ParamSpec('gain', -1.0, 'a gain', low=-10.0, high=0.0),
    ParamSpec('period', 1.0, 'a period', low=0.0, low_open=True, read_only=True),
    ParamSpec('count', 3, 'a count', low=1, high=10),
    ParamSpec('taps', [-1.0], 'times', read_only=True),
    ParamSpec('k', None, 'designed', kind='double'),
]


@pytest.fixture
def make_node():
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=test_domain_id())
    made = []

    def make(**overrides):
        node = Node(f'pt{len(made)}', namespace='/param_table_test', context=ctx,
                    parameter_overrides=[Parameter(k, value=v) for k, v in overrides.items()])
        made.append(node)
        table = ParameterTable(node)
        return node, table
    yield make
    for node in made:
        node.destroy_node()
    rclpy.shutdown(context=ctx)


def test_declared_with_type_description_range_read_only(make_node):
    node, table = make_node()
    values = table.declare(SPECS)
    assert values == {'mode': 'off', 'gain': -1.0, 'period': 1.0, 'count': 3, 'taps': [-1.0], 'k': None}
    d = node.describe_parameter('gain')
    assert d.type == ParameterType.PARAMETER_DOUBLE and d.description == 'a gain'
    assert (d.floating_point_range[0].from_value, d.floating_point_range[0].to_value) == (-10.0, 0.0)
    d = node.describe_parameter('count')
    assert d.type == ParameterType.PARAMETER_INTEGER and d.integer_range[0].to_value == 10
    d = node.describe_parameter('period')
    assert d.read_only and d.additional_constraints == '> 0' and not d.floating_point_range
    assert node.describe_parameter('mode').additional_constraints == 'one of: off, balance'
    assert not node.describe_parameter('mode').dynamic_typing
    d = node.describe_parameter('k')        # no default: a double all the same
    assert d.type == ParameterType.PARAMETER_DOUBLE and not d.dynamic_typing
    assert node.set_parameters([Parameter('k', value=2)])[0].successful
    assert node.get_parameter('k').value == 2.0


def test_overrides_read_as_the_type_or_refused(make_node):
    node, table = make_node(mode=False, gain=-3, period=2, taps=[0, 1], k=5)
    assert table.declare(SPECS) == {'mode': 'off', 'gain': -3.0, 'period': 2.0, 'count': 3,
                                    'taps': [0.0, 1.0], 'k': 5.0}
    assert node.get_parameter('gain').type_ == Parameter.Type.DOUBLE
    assert node.describe_parameter('period').read_only
    for overrides, reason in (({'gain': 'soon'}, "gain must be a number, got 'soon'"),
                              ({'gain': 5.0}, 'gain must be <= 0, got 5.0'),
                              ({'period': 0.0}, 'period must be > 0, got 0.0'),
                              ({'mode': 'bogus'}, "mode must be one of off, balance, got 'bogus'"),
                              ({'mode': True}, 'mode must be a string, got True'),
                              ({'count': 2.5}, 'count must be an integer, got 2.5'),
                              ({'count': 11}, 'count must be <= 10, got 11')):
        node, table = make_node(**overrides)
        with pytest.raises(ConfigError) as info:
            table.declare(SPECS)
        assert str(info.value).startswith(reason)


def test_set_values_read_as_the_type_the_rest_refused_with_the_reason(make_node):
    node, table = make_node()
    table.declare(SPECS)
    r = node.set_parameters([Parameter('mode', value='balance'), Parameter('mode', value=False),
                             Parameter('gain', value=-4), Parameter('count', value=5)])
    assert all(x.successful for x in r), r
    assert node.get_parameter('mode').value == 'off'
    assert node.get_parameter('gain').value == -4.0 and node.get_parameter('gain').type_ == Parameter.Type.DOUBLE
    for param, words in ((Parameter('gain', value='abc'), 'Wrong parameter type'),
                         (Parameter('mode', value=True), 'Wrong parameter type'),
                         (Parameter('count', value=2.5), 'Wrong parameter type'),
                         (Parameter('gain', value=1.0), 'out of range'),
                         (Parameter('mode', value='bogus'), 'mode must be one of off, balance'),
                         (Parameter('count', value=0), 'out of range'),
                         (Parameter('period', value=2.0), 'read-only'),
                         (Parameter('gain', Parameter.Type.NOT_SET), 'cannot be undeclared')):
        r = node.set_parameters([param])[0]
        assert not r.successful and words in r.reason, (param.name, r.reason)
    assert (node.get_parameter('mode').value, node.get_parameter('gain').value,
            node.get_parameter('count').value, node.get_parameter('period').value) == ('off', -4.0, 5, 1.0)
    # all or nothing
    r = node.set_parameters_atomically([Parameter('gain', value=-2), Parameter('count', value=0)])
    assert not r.successful and node.get_parameter('gain').value == -4.0


def test_rig_parameters(make_node):
    assert {s.name for s in rig_specs()} == {'rig.' + n for n in DESCRIPTIONS}
    node, table = make_node(**{'rig.g': 10})     # an integer for a double
    rig = declare_rig(table)
    assert isinstance(rig, Rig) and rig.g == 10.0
    d = node.describe_parameter('rig.sample_period')
    assert d.read_only and d.description.startswith('sampling period h, s')
    assert (d.floating_point_range[0].from_value, d.floating_point_range[0].to_value) == (1e-5, 0.1)
    assert node.describe_parameter('rig.counts_per_rev').type == ParameterType.PARAMETER_INTEGER
    assert node.describe_parameter('rig.pwm_steps').additional_constraints == '>= 0'
    node, table = make_node(**{'rig.g': -1.0})
    with pytest.raises(ConfigError, match='rig.g must be > 0'):
        declare_rig(table)


def test_descriptor_of_an_integer_range_with_a_step():
    d = descriptor(ParamSpec('sign', 1, 'a sign', low=-1, high=1, step=2, read_only=True))
    r = d.integer_range[0]
    assert (r.from_value, r.to_value, r.step, d.read_only) == (-1, 1, 2, True)


def test_an_override_the_node_does_not_declare_is_refused_with_the_nearest_names(make_node):
    """rclpy ignores an override no parameter takes (a misspelt name would leave the default in
    place); the table names it, with the declared names nearest to it."""
    node, table = make_node(gian=-2.0, count=4)
    table.declare(SPECS)
    assert table.undeclared_overrides() == ['gian']
    with pytest.raises(ConfigError, match=r"has no parameter 'gian' \(did you mean gain\?\)"):
        table.refuse_undeclared()
    node, table = make_node(count=4)
    table.declare(SPECS)
    assert table.undeclared_overrides() == []
    table.refuse_undeclared()
    assert node.get_parameter('count').value == 4
