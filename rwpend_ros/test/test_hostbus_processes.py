"""The same-host fast path between two real processes (rclpy nodes): a topic whose only
subscribers take the fast path is not written to DDS at all (fast only); a plain DDS subscriber
that joins gets every message through DDS from then on; the fast subscriber gets each message
once and in order throughout."""
from __future__ import annotations

import os
import random
import subprocess
import sys
import textwrap
import time

import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from rwpend_msgs.msg import MotorCommand
from rwpend_ros import hostbus, wire
from rwpend_ros.common import QOS_CONTROL, QOS_CONTROL_PUB, LocalPublisher
from rwpend_ros.intra import BUS
from rwpend_ros.transport import apply_transport

SUBSCRIBER = textwrap.dedent('''
    import sys, time, rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.node import Node
    from rwpend_msgs.msg import MotorCommand
    from rwpend_ros import wire
    from rwpend_ros.common import QOS_CONTROL, local_subscription
    rclpy.init()
    node = Node('fast_sub', namespace='/hostbus_proc_test')
    got = []
    local_subscription(node, MotorCommand, 'command', lambda d: got.append(wire.unpack_command(d)[0]),
                       QOS_CONTROL)
    ex = SingleThreadedExecutor(); ex.add_node(node)
    print('ready', flush=True)
    end = time.monotonic() + 60
    while time.monotonic() < end and not (got and got[-1] == 999999):
        ex.spin_once(timeout_sec=0.05)
    m = node.hostbus_merges['/hostbus_proc_test/command'].counters()
    print('got', ' '.join(map(str, got)), flush=True)
    print('counters', m['fast'], m['dds'], m['duplicates'], m['resyncs'], flush=True)
''')


@pytest.mark.timeout(90)
def test_fast_only_until_a_dds_subscriber_joins(monkeypatch):
    domain = random.SystemRandom().randint(100, 230)
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', ROS_DOMAIN_ID=str(domain),
               RWPEND_HOST_BUS='1')
    apply_transport(env)
    for k, v in env.items():
        monkeypatch.setenv(k, v)
    sub = subprocess.Popen([sys.executable, '-c', SUBSCRIBER], env=env, stdout=subprocess.PIPE,
                           stderr=subprocess.STDOUT, text=True)
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=domain)
    node = Node('fast_pub', namespace='/hostbus_proc_test', context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    try:
        assert sub.stdout.readline().strip() == 'ready'
        pub = LocalPublisher(node, MotorCommand, 'command', QOS_CONTROL_PUB)
        dds_writes = []
        real_publish = pub.pub.publish
        monkeypatch.setattr(pub.pub, 'publish', lambda d: (dds_writes.append(wire.unpack_command(d)[0]),
                                                           real_publish(d)))
        end = time.monotonic() + 20
        while not pub.sender.targets or pub.get_subscription_count() != 1:
            assert time.monotonic() < end, 'the subscriber never showed up'
            ex.spin_once(timeout_sec=0.05)
        header = wire.pack_header(0, 0, 'rwpend')
        seq = 0

        def send(n):
            nonlocal seq
            for _ in range(n):
                seq += 1
                pub.publish(wire.pack_command(header, seq, 0.5))
                ex.spin_once(timeout_sec=0.001)
        send(200)
        assert len(dds_writes) <= 1, 'fast only: at most the first message goes to DDS'
        # a plain DDS reader joins (a recorder, a ros2 topic echo): DDS carries every message again
        other = Node('dds_sub', namespace='/hostbus_proc_test', context=ctx)
        ex.add_node(other)
        seen = []
        other.create_subscription(MotorCommand, 'command', lambda m: seen.append(m.seq), QOS_CONTROL)
        end = time.monotonic() + 20
        while pub.get_subscription_count() != 2:
            assert time.monotonic() < end
            ex.spin_once(timeout_sec=0.05)
        first_shared = seq + 1
        send(200)
        end = time.monotonic() + 10
        while (not seen or seen[-1] != seq) and time.monotonic() < end:
            ex.spin_once(timeout_sec=0.05)
        assert seen == list(range(first_shared, seq + 1))
        assert set(range(first_shared, seq + 1)) <= set(dds_writes)
        # it leaves: fast only again, once the publisher has looked at the graph
        ex.remove_node(other)
        other.destroy_node()
        end = time.monotonic() + 20
        while pub.get_subscription_count() != 1:
            assert time.monotonic() < end
            ex.spin_once(timeout_sec=0.05)
        for _ in range(40):       # a few refresh periods: the targets are read again
            ex.spin_once(timeout_sec=0.02)
        n_dds = len(dds_writes)
        send(200)
        assert len(dds_writes) - n_dds <= 1
        pub.publish(wire.pack_command(header, 999999, 0.0))    # the end
        out, _ = sub.communicate(timeout=30)
    finally:
        if sub.poll() is None:
            sub.kill()
        hostbus.close_all()
        BUS.reset()
        node.destroy_node()
        rclpy.shutdown(context=ctx)
    lines = dict(line.split(' ', 1) for line in out.splitlines() if ' ' in line)
    got = [int(x) for x in lines['got'].split()]
    assert got == list(range(1, seq + 1)) + [999999], 'each once, in order, nothing lost'
    fast, dds, dup, resyncs = map(int, lines['counters'].split())
    assert fast >= 398, lines['counters']     # the fast-only phases, at least
