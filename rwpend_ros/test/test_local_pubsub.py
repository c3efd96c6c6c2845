"""rwpend_ros.common.LocalPublisher / local_subscription with real rclpy nodes: the in-process
bus (rwpend_ros.intra) delivers wire bytes and message objects (serialized) to a subscriber of
another node of the process, on the executor's thread only."""
from __future__ import annotations

import os
import random
import threading

import pytest
import rclpy
from rclpy.node import Node

from rwpend_msgs.msg import MotorCommand
from rwpend_ros import hostbus, wire
from rwpend_ros.common import QOS_CONTROL, QOS_CONTROL_PUB, LocalPublisher, local_subscription
from rwpend_ros.intra import BUS
from rwpend_ros.transport import apply_transport


@pytest.fixture
def nodes(monkeypatch):
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    apply_transport(env)                             # as every rwpend process: UDP on localhost
    for k, v in env.items():
        monkeypatch.setenv(k, v)
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=random.SystemRandom().randint(100, 230))
    a = Node('pub_side', namespace='/intra_test', context=ctx)
    b = Node('sub_side', namespace='/intra_test', context=ctx)
    yield a, b
    hostbus.close_all()
    BUS.reset()
    a.destroy_node()
    b.destroy_node()
    rclpy.shutdown(context=ctx)


def test_bytes_and_objects_reach_the_local_subscriber(nodes):
    a, b = nodes
    got = []
    sub = local_subscription(b, MotorCommand, 'command', got.append, QOS_CONTROL)
    pub = LocalPublisher(a, MotorCommand, 'command', QOS_CONTROL_PUB)
    assert pub.topic == sub.topic_name == '/intra_test/command'
    assert pub.get_subscription_count() >= 0          # the rclpy publisher's API is there
    BUS.thread = threading.get_ident()
    header = wire.pack_header(3, 4, 'rwpend')
    pub.publish(wire.pack_command(header, 7, 1.5))
    msg = MotorCommand(seq=8, u=-2.0)
    msg.header.frame_id = 'rwpend'
    pub.publish(msg)                                 # e.g. the controller's watchdog zero
    assert [wire.unpack_command(d) for d in got] == [(7, 1.5), (8, -2.0)]


def test_nothing_local_before_the_executor_runs(nodes):
    a, b = nodes
    got = []
    local_subscription(b, MotorCommand, 'command', got.append, QOS_CONTROL)
    pub = LocalPublisher(a, MotorCommand, 'command', QOS_CONTROL_PUB)
    BUS.thread = None
    pub.publish(MotorCommand(seq=1, u=0.0))
    assert got == []                                 # DDS only (nobody spins here)


def test_a_publisher_without_intra_leaves_the_bus_out(nodes):
    """``LocalPublisher(intra=False)`` (the lockstep simulator's encoders): a subscriber of the
    process gets the message through DDS, not inside ``publish()``."""
    a, b = nodes
    got = []
    local_subscription(b, MotorCommand, 'command', got.append, QOS_CONTROL)
    pub = LocalPublisher(a, MotorCommand, 'command', QOS_CONTROL_PUB, intra=False)
    BUS.thread = threading.get_ident()
    pub.publish(wire.pack_command(wire.pack_header(0, 0, 'rwpend'), 1, 0.5))
    assert got == [] and pub.dds_writes == 1


def test_a_node_busy_in_a_callback_gets_a_local_message_after_it(nodes):
    """A subscriber of the process whose node has a callback running (here a timer-like call
    of ``b``) gets the message when that callback has returned, on the same thread."""
    a, b = nodes
    got = []
    local_subscription(b, MotorCommand, 'command', lambda d: got.append(('rx', d)), QOS_CONTROL)
    pub = LocalPublisher(a, MotorCommand, 'command', QOS_CONTROL_PUB)
    BUS.thread = threading.get_ident()
    data = wire.pack_command(wire.pack_header(0, 0, 'rwpend'), 2, 0.25)

    def b_callback():
        pub.publish(data)                # e.g. b's state answered by a's command
        got.append(('b done', None))
    BUS.call(b, b_callback)
    assert [g[0] for g in got] == ['b done', 'rx'] and wire.unpack_command(got[1][1]) == (2, 0.25)


def test_a_bad_host_bus_setting_stops_the_process_before_rclpy(monkeypatch, capsys):
    from rwpend_ros.common import run_nodes
    monkeypatch.setenv('RWPEND_HOST_BUS', 'off')
    built = []
    assert run_nodes([lambda: built.append(1)]) == 2
    assert built == [] and 'RWPEND_HOST_BUS' in capsys.readouterr().err


def test_a_subscriber_the_fast_path_misses_is_looked_for_at_every_tick_for_a_while(nodes, monkeypatch):
    """DDS matched a subscriber the fast path does not reach (absent from a graph reading, or
    its receiver not there at the first send): the graph is read again at every tick for
    HOST_SETTLE_PERIOD after the number of subscribers changed, not only every
    HOST_RETRY_PERIOD -- or its publisher writes every message to DDS for that long."""
    from types import SimpleNamespace

    from rwpend_ros.common import HOST_REFRESH_PERIOD, HOST_RETRY_PERIOD, HOST_SETTLE_PERIOD
    a, _ = nodes
    pub = LocalPublisher(a, MotorCommand, 'command', QOS_CONTROL_PUB)
    assert pub.sender is not None
    info = SimpleNamespace(node_namespace='/intra_test', node_name='not_there', qos_profile=QOS_CONTROL)
    reads = []
    monkeypatch.setattr(pub.pub, 'get_subscription_count', lambda: 1)
    monkeypatch.setattr(a, 'get_subscriptions_info_by_topic', lambda topic: reads.append(topic) or [info])
    header = wire.pack_header(0, 0, 'rwpend')

    def tick(i):
        pub.publish(wire.pack_command(header, i, 0.0))   # the send fails: gone from the targets
        assert pub.sender.targets == ()
        pub._refresh()

    pub._refresh()
    assert len(reads) == 1 and len(pub.sender.targets) == 1
    settle = int(HOST_SETTLE_PERIOD / HOST_REFRESH_PERIOD)
    for i in range(settle - 1):
        tick(i)
    assert len(reads) == settle          # every tick while settling
    for i in range(4):
        tick(i)                          # settled: back to every HOST_RETRY_PERIOD
    n = len(reads)
    for i in range(int(HOST_RETRY_PERIOD / HOST_REFRESH_PERIOD) - 1):
        tick(i)
    assert len(reads) <= n + 1
    assert pub.dds_writes > 0            # meanwhile DDS carried every message: nothing lost
