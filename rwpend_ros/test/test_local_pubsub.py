"""rwpend_ros.nodes.local_subscription with a real rclpy node: every loop subscription's order
gate drops duplicates and older messages, and counts them."""
from __future__ import annotations

import os

import pytest
import rclpy

from rwpend_ros.testenv import test_domain_id
from rwpend_msgs.msg import MotorCommand
from rwpend_ros import wire
from rwpend_ros.nodes import RwNode, local_subscription
from rwpend_ros.qos import QOS_CONTROL
from rwpend_ros.transport import apply_transport


@pytest.fixture
def node(monkeypatch):
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    apply_transport(env)                             # as every rwpend process: UDP on localhost
    for k, v in env.items():
        monkeypatch.setenv(k, v)
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=test_domain_id())
    n = RwNode('sub_side', namespace='/order_test', context=ctx)
    yield n
    n.destroy_node()
    rclpy.shutdown(context=ctx)


def command(seq, u, sec=0):
    return wire.pack_command(wire.pack_header(sec, 0, 'rwpend'), seq, u)


def test_the_order_gate_drops_duplicates_and_older_messages(node):
    """A repeat, an older message and bytes too short to read are dropped and counted; a
    publisher that starts again (seq 0, a later stamp) is taken."""
    got = []
    sub = local_subscription(node, MotorCommand, 'command', got.append, QOS_CONTROL)
    assert sub.topic_name == '/order_test/command'
    take = sub.sub.callback                          # what DDS calls with the message's bytes
    for k in range(3):
        take(command(k, float(k), sec=k))
    take(command(2, 2.0, sec=2))                     # a repeat
    take(command(1, 5.0, sec=0))                     # an older one
    take(b'\x00\x01')                                # too short to read
    assert [wire.unpack_command(d)[0] for d in got] == [0, 1, 2]
    g = sub.gate
    assert (g.duplicates, g.stale, g.taken, sub.malformed) == (1, 1, 3, 1)
    take(command(0, 0.0, sec=9))                     # the publisher started again (seq 0)
    assert g.restarts == 1 and len(got) == 4
