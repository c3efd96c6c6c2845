"""In-process smoke test of the estimator node (own rclpy context, private namespace)."""
import math
import os
import uuid

import pytest

rclpy = pytest.importorskip('rclpy')
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from sensor_msgs.msg import JointState  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from rwpend_msgs.msg import EncoderCounts, MotorCommand, StateEstimate  # noqa: E402
from rwpend_ros.qos import QOS_CONTROL
from rwpend_estimation.estimator_node import EstimatorNode  # noqa: E402


@pytest.fixture
def graph():
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    ns = '/t' + uuid.uuid4().hex[:8]
    node = EstimatorNode(context=ctx, namespace=ns,
                         parameter_overrides=[Parameter('estimator', value='joint5')])
    tester = rclpy.create_node('tester', namespace=ns, context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    ex.add_node(tester)
    yield node, tester, ex
    ex.shutdown()
    node.destroy_node()
    tester.destroy_node()
    rclpy.shutdown(context=ctx)


def sample(seq, **counts):
    """EncoderCounts stamped as a plant stamps them: 100 + seq s (the order gate wants stamps
    that do not go back)."""
    m = EncoderCounts(seq=seq, **counts)
    m.header.stamp.sec = 100 + seq
    return m


def spin_until(ex, cond, timeout=5.0):
    import time
    end = time.monotonic() + timeout
    while not cond() and time.monotonic() < end:
        ex.spin_once(timeout_sec=0.01)
    return cond()


def test_node_publishes_refuses_and_switches(graph):
    node, tester, ex = graph
    states, joints = [], []
    tester.create_subscription(StateEstimate, 'state', states.append, QOS_CONTROL)
    tester.create_subscription(JointState, 'joint_states', joints.append, QOS_CONTROL)
    pub_enc = tester.create_publisher(EncoderCounts, 'encoders', QOS_CONTROL)
    pub_cmd = tester.create_publisher(MotorCommand, 'command', QOS_CONTROL)
    assert spin_until(ex, lambda: pub_enc.get_subscription_count() > 0
                      and tester.count_subscribers(pub_cmd.topic_name) > 0)
    pub_cmd.publish(MotorCommand(seq=0, u=float('nan')))
    pub_cmd.publish(MotorCommand(seq=1, u=25.0))
    assert spin_until(ex, lambda: node.refused_commands == 1 and node.align.u == 10.0)
    for k in range(2, 7):
        m = EncoderCounts(seq=k, pendulum_counts=2 * (k - 2), motor_counts=5 * (k - 2))
        m.header.stamp.sec = 100 + k
        pub_enc.publish(m)
        assert spin_until(ex, lambda: len(states) == k - 1 and len(joints) == k - 1)
        # answer the sample like a controller (the estimator waits for command k-1)
        pub_cmd.publish(MotorCommand(seq=k, u=25.0))
        assert spin_until(ex, lambda: node.align.u_seq == k)
    s = states[-1]
    assert (s.seq, s.header.stamp.sec, s.estimator) == (6, 106, 'joint5')
    assert s.theta == pytest.approx(8 * node.rig.count_angle)
    assert joints[-1].name == ['pendulum', 'wheel']
    assert joints[-1].position[1] == pytest.approx(20 * node.rig.count_angle)   # relative wheel joint
    assert (s.resyncs, s.missed) == (0, 0)
    # absurd sample: counted, ignored
    pub_enc.publish(sample(7, pendulum_counts=10 ** 8, motor_counts=0))
    assert spin_until(ex, lambda: node.est.gap_stats.refused == 1)
    # parameters: refused with the reason, accepted ones switch without a jump
    res = node.set_parameters([Parameter('zeta', value=float('nan'))])[0]
    assert not res.successful and 'zeta out of range' in res.reason   # rclpy's range check
    res = node.set_parameters([Parameter('estimator', value='kalman')])[0]
    assert not res.successful and 'estimator must be one of' in res.reason
    assert node.config.estimator == 'joint5'
    assert node.set_parameters([Parameter('estimator', value='filtered')])[0].successful
    assert node.est.name == 'filtered'
    assert node.set_parameters([Parameter('publish_joint_states', value=False)])[0].successful
    pub_cmd.publish(MotorCommand(seq=7, u=25.0))
    assert spin_until(ex, lambda: node.align.u_seq == 7)
    pub_enc.publish(sample(8, pendulum_counts=10, motor_counts=25))
    assert spin_until(ex, lambda: len(states) == 6)
    assert states[-1].estimator == 'filtered'
    assert states[-1].theta - s.theta == pytest.approx(2 * node.rig.count_angle)
    assert math.isfinite(states[-1].theta_dot)
    assert len(joints) == 5
    pub_cmd.publish(MotorCommand(seq=8, u=25.0))
    assert spin_until(ex, lambda: node.align.u_seq == 8)
    # ~/reset: refused while the loop drives the rig (u = 25 answered seq 8) ...
    cli = tester.create_client(Trigger, node.get_fully_qualified_name() + '/reset')
    assert spin_until(ex, cli.service_is_ready)
    fut = cli.call_async(Trigger.Request())
    assert spin_until(ex, fut.done) and not fut.result().success
    assert 'reset refused: the loop is driving the rig' in fut.result().message
    assert node.refused_resets == 1 and states[-1].seq == 8
    # ... taken once the last non-zero command is more than RESET_QUIET_S old
    from rwpend_estimation.estimator_node import RESET_QUIET_S
    node.last_drive_seq = 8 - int(RESET_QUIET_S / node.rig.sample_period) - 1
    fut = cli.call_async(Trigger.Request())
    assert spin_until(ex, fut.done) and fut.result().success
    pub_enc.publish(sample(9, pendulum_counts=11, motor_counts=25))
    assert spin_until(ex, lambda: len(states) == 7)
    assert states[-1].theta == pytest.approx(node.rig.count_angle)
    assert states[-1].resyncs == 1                 # the reset re-initialised the estimate
    # a gap too long to bridge: re-synchronised on the counts, visible in the state
    pub_enc.publish(sample(600, pendulum_counts=111, motor_counts=25))
    assert spin_until(ex, lambda: len(states) == 8)
    assert (states[-1].resyncs, states[-1].missed) == (2, 590)
    assert states[-1].theta == pytest.approx(101 * node.rig.count_angle)
    gs = node.est.gap_stats
    assert gs.longest_gap == 590 and 'gap of 590' in gs.last_resync and gs.refused == 1
    # a short gap is bridged
    pub_enc.publish(sample(601, pendulum_counts=112, motor_counts=25))
    pub_enc.publish(sample(605, pendulum_counts=116, motor_counts=25))
    assert spin_until(ex, lambda: len(states) == 10)
    assert (states[-1].resyncs, states[-1].missed) == (2, 3)
    assert node.est.gap_stats.bridged == 1 + 3     # the refused seq 7 and these
