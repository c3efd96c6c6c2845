"""Smoke test of the controller node in-process (own context, own domain id)."""
import time

import pytest

rclpy = pytest.importorskip('rclpy')

from rclpy.context import Context  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402

from rwpend_msgs.msg import ControllerStatus, MotorCommand, StateEstimate  # noqa: E402
from rwpend_msgs.srv import SetMode  # noqa: E402
from rwpend_ros.qos import QOS_CONTROL, QOS_STATUS
from rwpend_ros.testenv import test_domain_id
from rwpend_control.controller_node import ControllerNode  # noqa: E402


@pytest.fixture
def env():
    ctx = Context()
    rclpy.init(context=ctx, domain_id=test_domain_id())
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
    assert not r.successful and 'out of range' in r.reason and 'nan' in r.reason   # rclpy's range check
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


def test_parameters_as_ros2cli_sends_them(env):
    """Typed parameters, the designed gains doubles; 'off' sent as YAML's false; a load of a dump
    (every parameter set again, the design parameters before the gains they design) keeps tuned
    gains; a design parameter changed redesigns its group unless a gain of it is set after."""
    from rcl_interfaces.msg import ParameterType
    node, peer, spin = env
    d = node.describe_parameter('balance.kdp')
    assert d.type == ParameterType.PARAMETER_DOUBLE and not d.dynamic_typing and 'balance' in d.description
    assert (d.floating_point_range[0].from_value, d.floating_point_range[0].to_value) == (-1e3, 1e3)
    assert node.describe_parameter('state_queue_depth').read_only
    for name, value in (('mode', 'wheel_velocity'), ('saturation_action', 'auto'),
                        ('wheel_speed_action', 'brake'), ('friction_compensation', 'model')):
        assert node.set_parameters([Parameter(name, value=value)])[0].successful
        assert node.set_parameters([Parameter(name, value=False)])[0].successful, name   # "off"
        assert node.get_parameter(name).value == 'off'
    assert node.ctrl.mode == 'off' and node.ctrl.config.friction_compensation == 'off'
    assert node.ctrl.config.saturation_action == 'off' and node.ctrl.config.wheel_speed_action == 'off'
    r = node.set_parameters([Parameter('mode', value=True)])[0]
    assert not r.successful and 'Wrong parameter type' in r.reason
    assert node.set_parameters([Parameter('wheel.ref', value=3)])[0].successful
    assert node.get_parameter('wheel.ref').value == 3.0 and node.ctrl.config.wheel_ref == 3.0
    # dump -> load: the same values again, in a dump's (sorted) order
    tuned = node.get_parameter('balance.kpp').value * 1.02
    assert node.set_parameters([Parameter('balance.kpp', value=tuned),
                                Parameter('swingup.c_e', value=1.2e5)])[0].successful
    spin(0.2)
    dump = {n: node.get_parameter(n).value for n in sorted(node.list_parameters([], 0).names)}
    writable = [n for n in dump if not node.describe_parameter(n).read_only]
    results = node.set_parameters([Parameter(n, value=dump[n]) for n in writable])
    assert all(r.successful for r in results), [(n, r.reason) for n, r in zip(writable, results) if not r.successful]
    spin(0.3)
    assert {n: node.get_parameter(n).value for n in dump} == dump
    assert node.ctrl.config.balance_kpp == tuned and node.ctrl.config.swingup_c_e == 1.2e5
    # a design parameter changed: its group redesigned (and shown), unless a gain is set after it
    assert node.set_parameters([Parameter('balance.design.omega0', value=13.3)])[0].successful
    assert node.get_parameter('balance.design.omega0').value == '13.3'
    spin(0.3, until=lambda: node.get_parameter('balance.kpp').value != tuned)
    designed = node.get_parameter('balance.kpp').value
    assert designed != tuned and node.ctrl.config.balance_kpp == designed
    r = node.set_parameters([Parameter('balance.design.omega0', value='1.5wp'), Parameter('balance.kpp', value=tuned)])
    assert all(x.successful for x in r)
    spin(0.3)
    assert node.get_parameter('balance.kpp').value == tuned == node.ctrl.config.balance_kpp
