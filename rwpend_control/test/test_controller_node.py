"""Smoke test of the controller node in-process (own context, own domain id)."""
import os
import time

import pytest

rclpy = pytest.importorskip('rclpy')

from rclpy.context import Context  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402

from rwpend_msgs.msg import ControllerStatus, MotorCommand, StateEstimate  # noqa: E402
from rwpend_msgs.srv import SetMode  # noqa: E402
from rwpend_ros.common import QOS_CONTROL, QOS_STATUS  # noqa: E402
from rwpend_control.controller_node import ControllerNode  # noqa: E402


@pytest.fixture
def env():
    ctx = Context()
    rclpy.init(context=ctx, domain_id=100 + os.getpid() % 100)
    node = ControllerNode(context=ctx, namespace='/t', parameter_overrides=[
        Parameter('balance.design.omega0', value='2wp'), Parameter('patch.kpp', value=-389.0),
        # states come every ~5 ms here: keep the stale-state watchdog out of this test
        Parameter('state_timeout_samples', value=1000)])
    peer = Node('peer', context=ctx, namespace='/t')
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    ex.add_node(peer)

    def spin(seconds=0.2, until=None):
        end = time.time() + seconds
        while time.time() < end and not (until and until()):
            ex.spin_once(timeout_sec=0.01)
    yield node, peer, spin
    ex.shutdown()
    node.destroy_node()
    peer.destroy_node()
    rclpy.shutdown(context=ctx)


def test_node(env):
    node, peer, spin = env
    # design parameters used for gains not given; explicit ones kept
    assert node.get_parameter('balance.kpp').value == pytest.approx(-440.49, abs=0.1)
    assert node.get_parameter('patch.kpp').value == -389.0
    # validation with reasons, old values kept
    r = node.set_parameters([Parameter('balance.kpp', value=145.0)])[0]
    assert not r.successful and 'unstable' in r.reason
    r = node.set_parameters([Parameter('balance.kpp', value=float('nan'))])[0]
    assert not r.successful and 'finite' in r.reason
    assert node.ctrl.config.balance_kpp == pytest.approx(-440.49, abs=0.1)
    r = node.set_parameters([Parameter('balance.design.omega0', value='1.5wp')])[0]
    assert r.successful
    spin(0.3, until=lambda: abs(node.get_parameter('balance.kpp').value + 279.2) < 0.1)
    assert node.ctrl.config.balance_kpp == pytest.approx(-279.21, abs=0.01)
    assert node.get_parameter('balance.kpp').value == pytest.approx(-279.21, abs=0.01)
    r = node.set_parameters([Parameter('mode', value='bogus')])[0]
    assert not r.successful

    cmds, sts = [], []
    peer.create_subscription(MotorCommand, 'command', cmds.append, QOS_CONTROL)
    peer.create_subscription(ControllerStatus, 'controller/status', sts.append, QOS_STATUS)
    pub = peer.create_publisher(StateEstimate, 'state', QOS_CONTROL)
    cli = peer.create_client(SetMode, 'controller/set_mode')
    spin(0.5, until=lambda: pub.get_subscription_count() > 0 and cli.service_is_ready())
    fut = cli.call_async(SetMode.Request(mode='auto'))
    spin(2.0, until=fut.done)
    res = fut.result()
    assert res.success and res.previous_mode == 'off'
    spin(0.2, until=lambda: node.get_parameter('mode').value == 'auto')
    assert node.get_parameter('mode').value == 'auto'
    for k in range(25):
        m = StateEstimate()
        m.seq = 1000 + k
        m.header.stamp.sec = 100
        m.header.stamp.nanosec = k * 1_000_000
        if k == 20:
            m.theta_dot = float('nan')
        pub.publish(m)
        spin(0.005)
    spin(1.0, until=lambda: len(cmds) >= 25 and len(sts) >= 3)
    assert [c.seq for c in cmds] == list(range(1000, 1025))
    assert cmds[0].u == 10.0 and cmds[20].u == 0.0
    assert cmds[3].header.stamp.nanosec == 3_000_000
    assert sts[0].mode == 'auto' and sts[0].law == 'swingup' and sts[0].switch_count == 1
    assert any(s.fault.startswith('bad state') for s in sts)
    r = node.set_parameters([Parameter('mode', value='balance')])[0]
    assert not r.successful and 'balance refused' in r.reason
