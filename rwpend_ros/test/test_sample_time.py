"""rwpend_ros.simtime.sample_time / SampleTime: lockstep nodes take their ROS time from the
samples' stamps instead of /clock (real rclpy nodes, no other process)."""
from __future__ import annotations


import pytest
import rclpy
from rclpy.node import Node
from rclpy.parameter import Parameter

from rwpend_ros import wire
from rwpend_ros.params import ConfigError, ParameterTable
from rwpend_ros.simtime import sample_time
from rwpend_ros.testenv import test_domain_id


@pytest.fixture
def make_node():
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=test_domain_id())
    made = []

    def make(**params):
        node = Node(f'st{len(made)}', namespace='/sample_time_test', context=ctx,
                    parameter_overrides=[Parameter(k, value=v) for k, v in params.items()])
        made.append(node)
        return node
    yield make
    for node in made:
        node.destroy_node()
    rclpy.shutdown(context=ctx)


def clock_subscribed(node) -> bool:
    return any(s.topic_name == '/clock' for s in node.subscriptions)


def encoders(sec, nanosec, seq=1):
    return wire.pack_encoders(wire.pack_header(sec, nanosec, 'rwpend'), seq, 10, -20)


def test_the_clock_follows_the_stamps_forward_only_and_clock_is_not_subscribed(make_node):
    node = make_node(use_sim_time=True, time_from_samples=True)
    st = sample_time(node, ParameterTable(node))
    assert st is not None and not clock_subscribed(node)
    assert node.get_clock().now().nanoseconds == 0           # sim time not started
    st(encoders(2, 5_000_000))
    assert node.get_clock().now().nanoseconds == 2_005_000_000
    st(encoders(1, 0))                                        # older: ignored
    st(b'\0\1')                                               # malformed: ignored
    assert node.get_clock().now().nanoseconds == 2_005_000_000
    st(wire.pack_command(wire.pack_header(3, 0, 'x'), 9, 0.5))  # any message with a Header
    assert node.get_clock().now().nanoseconds == 3_000_000_000


def test_off_by_default_and_refused_without_sim_time(make_node):
    plain = make_node(use_sim_time=True)
    assert sample_time(plain, ParameterTable(plain)) is None and clock_subscribed(plain)
    assert plain.describe_parameter('time_from_samples').read_only
    with pytest.raises(ConfigError, match='needs use_sim_time'):
        node = make_node(time_from_samples=True)
        sample_time(node, ParameterTable(node))
    with pytest.raises(ConfigError, match='must be true or false'):
        node = make_node(time_from_samples='yes')
        sample_time(node, ParameterTable(node))
