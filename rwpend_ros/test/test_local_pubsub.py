"""rwpend_ros.nodes.LocalPublisher / local_subscription with real rclpy nodes: the in-process
bus (rwpend_ros.intra) of a composed process delivers wire bytes and message objects
(serialized) to a subscriber of another node of the process, on the executor's thread only;
every loop subscription's order gate drops duplicates and older messages."""
from __future__ import annotations

import os
import threading

import pytest
import rclpy

from rwpend_ros.testenv import test_domain_id
from rwpend_msgs.msg import MotorCommand
from rwpend_ros import wire
from rwpend_ros.intra import LocalBus
from rwpend_ros.nodes import LocalPublisher, RwNode, local_subscription
from rwpend_ros.qos import QOS_CONTROL, QOS_CONTROL_PUB
from rwpend_ros.transport import apply_transport


@pytest.fixture
def nodes(monkeypatch):
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    apply_transport(env)                             # as every rwpend process: UDP on localhost
    for k, v in env.items():
        monkeypatch.setenv(k, v)
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=test_domain_id())
    bus = LocalBus()
    a = RwNode('pub_side', bus=bus, namespace='/intra_test', context=ctx)
    b = RwNode('sub_side', bus=bus, namespace='/intra_test', context=ctx)
    yield a, b, bus
    bus.close()
    a.destroy_node()
    b.destroy_node()
    rclpy.shutdown(context=ctx)


def command(seq, u, sec=0):
    return wire.pack_command(wire.pack_header(sec, 0, 'rwpend'), seq, u)


def test_bytes_and_objects_reach_the_local_subscriber(nodes):
    a, b, bus = nodes
    got = []
    sub = local_subscription(b, MotorCommand, 'command', got.append, QOS_CONTROL)
    pub = LocalPublisher(a, MotorCommand, 'command', QOS_CONTROL_PUB)
    assert pub.topic == sub.topic_name == '/intra_test/command'
    assert pub.get_subscription_count() >= 0          # the rclpy publisher's API is there
    bus.thread = threading.get_ident()
    pub.publish(command(7, 1.5, sec=3))
    assert [wire.unpack_command(d) for d in got] == [(7, 1.5)]
    msg = MotorCommand(seq=8, u=-2.0)                 # an object goes through DDS (nobody spins)
    pub.publish(msg)
    assert len(got) == 1 and sub.local.delivered == 1


def test_nothing_local_before_the_executor_runs(nodes):
    a, b, bus = nodes
    got = []
    local_subscription(b, MotorCommand, 'command', got.append, QOS_CONTROL)
    pub = LocalPublisher(a, MotorCommand, 'command', QOS_CONTROL_PUB)
    bus.thread = None
    pub.publish(command(1, 0.0))
    assert got == []                                 # DDS only (nobody spins here)


def test_a_publisher_without_intra_leaves_the_bus_out(nodes):
    """``LocalPublisher(intra=False)`` (the lockstep simulator's encoders): a subscriber of the
    process gets the message through DDS, not inside ``publish()``."""
    a, b, bus = nodes
    got = []
    local_subscription(b, MotorCommand, 'command', got.append, QOS_CONTROL)
    pub = LocalPublisher(a, MotorCommand, 'command', QOS_CONTROL_PUB, intra=False)
    bus.thread = threading.get_ident()
    pub.publish(command(1, 0.5))
    assert got == [] and pub.bus is None


def test_a_node_busy_in_a_callback_gets_a_local_message_after_it(nodes):
    """A subscriber of the process whose node has a callback running (here a timer-like call
    of ``b``) gets the message when that callback has returned, on the same thread."""
    a, b, bus = nodes
    got = []
    local_subscription(b, MotorCommand, 'command', lambda d: got.append(('rx', d)), QOS_CONTROL)
    pub = LocalPublisher(a, MotorCommand, 'command', QOS_CONTROL_PUB)
    bus.thread = threading.get_ident()
    data = command(2, 0.25)

    def b_callback():
        pub.publish(data)                # e.g. b's state answered by a's command
        got.append(('b done', None))
    bus.call(b, b_callback)
    assert [g[0] for g in got] == ['b done', 'rx'] and wire.unpack_command(got[1][1]) == (2, 0.25)


def test_the_order_gate_drops_duplicates_and_older_messages_whatever_the_path(nodes):
    """The DDS copy of a message delivered by the bus is dropped by the bus; a copy it no longer
    remembers, an older message and a repeat are dropped by the gate, and counted."""
    a, b, bus = nodes
    got = []
    sub = local_subscription(b, MotorCommand, 'command', got.append, QOS_CONTROL)
    pub = LocalPublisher(a, MotorCommand, 'command', QOS_CONTROL_PUB)
    bus.thread = threading.get_ident()
    for k in range(3):
        pub.publish(command(k, float(k), sec=k))
    sub.local.from_dds(command(1, 1.0, sec=1))       # its DDS copy: dropped by the bus
    sub.local.pending.clear()                        # copies the bus forgot ...
    sub.local.from_dds(command(2, 2.0, sec=2))       # ... are dropped by the gate
    sub.local.from_dds(command(1, 5.0, sec=0))       # an older one
    sub.local.from_dds(b'\x00\x01')                  # too short to read
    assert [wire.unpack_command(d)[0] for d in got] == [0, 1, 2]
    g = sub.gate
    assert (g.duplicates, g.stale, g.taken, sub.malformed) == (1, 1, 3, 1)
    assert sub.local.duplicates == 1
    sub.local.from_dds(command(0, 0.0, sec=9))       # the publisher started again (seq 0)
    assert g.restarts == 1 and len(got) == 4


def test_a_bad_intra_process_setting_stops_the_process_before_rclpy(monkeypatch, capsys):
    from rwpend_ros.runner import run_nodes
    monkeypatch.setenv('RWPEND_INTRA_PROCESS', 'off')
    built = []
    assert run_nodes([lambda bus: built.append(1), lambda bus: built.append(2)]) == 2
    assert built == [] and 'RWPEND_INTRA_PROCESS' in capsys.readouterr().err
