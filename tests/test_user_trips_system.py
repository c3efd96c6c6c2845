"""System tests of what a ROS user and a lab student trip over: an e-stop from any publisher (the
volatile one ``ros2 topic pub`` makes), a cleared e-stop that leaves the rig at zero torque until
a mode is chosen again, and ``~/reset`` refused while the loop drives the rig."""
from __future__ import annotations

import signal
import subprocess
import textwrap
import time

import numpy as np
import pytest

from test_safety_system import RWPEND, UPRIGHT, deviation, rwpend, series, strings

#: publishes std_msgs/Bool on /rwpend/estop with rclpy's default QoS (reliable, volatile, depth
#: 10), as ``ros2 topic pub --once /rwpend/estop std_msgs/msg/Bool "{data: true}"`` does
VOLATILE_ESTOP = textwrap.dedent('''
    import sys, time
    import rclpy
    from std_msgs.msg import Bool
    rclpy.init()
    node = rclpy.create_node('user_estop')
    pub = node.create_publisher(Bool, '/rwpend/estop', 10)
    # a volatile message reaches only the readers matched when it is sent: wait until the
    # simulator's volatile reader is known and every known volatile reader is matched (a
    # recorder's may match first; a transient-local reader never matches this publisher)
    from rclpy.qos import DurabilityPolicy
    def ready():
        readers = [r for r in node.get_subscriptions_info_by_topic('/rwpend/estop')
                   if r.qos_profile.durability == DurabilityPolicy.VOLATILE]
        return (any(r.node_name == 'sim' for r in readers)
                and pub.get_subscription_count() >= len(readers))
    end = time.monotonic() + 20
    while not ready() and time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.05)
    print('matched', pub.get_subscription_count(), 'ready' if ready() else 'NOT READY', flush=True)
    pub.publish(Bool(data=sys.argv[1] == 'true'))
    end = time.monotonic() + 1.0
    while time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.05)
''')

RESET = textwrap.dedent('''
    import rclpy
    from std_srvs.srv import Trigger
    rclpy.init()
    node = rclpy.create_node('user_reset')
    cli = node.create_client(Trigger, '/rwpend/estimator/reset')
    assert cli.wait_for_service(timeout_sec=20)
    fut = cli.call_async(Trigger.Request())
    rclpy.spin_until_future_complete(node, fut, timeout_sec=20)
    r = fut.result()
    print('success', r.success, r.message, flush=True)
''')


def wait_for(log, text: str, stack, within: float = 60.0) -> None:
    end = time.monotonic() + within
    while text not in log.read_text():
        assert stack.poll() is None and time.monotonic() < end, log.read_text()[-3000:]
        time.sleep(0.1)


def start(tmp_path, env, *args):
    bag = tmp_path / 'bag'
    log = tmp_path / 'stack.log'
    stack = subprocess.Popen([RWPEND, 'up', '--lockstep', '--theta0', str(UPRIGHT), '--record', str(bag), *args],
                             env=env, stdout=open(log, 'w'), stderr=subprocess.STDOUT, start_new_session=True)
    return stack, bag, log


def stop(stack, log) -> str:
    stack.send_signal(signal.SIGINT)
    stack.wait(timeout=60)
    out = log.read_text()
    assert stack.returncode == 0 and 'Traceback' not in out, out[-3000:]
    return out


@pytest.mark.system
@pytest.mark.timeout(180)
def test_estop_from_a_volatile_publisher_and_no_torque_after_the_clear_until_a_mode_is_set(tmp_path, ros_env):
    stack, bag, log = start(tmp_path, ros_env, '--mode', 'auto')
    try:
        wait_for(log, 'auto/catch', stack)
        time.sleep(1.0)
        p = rwpend(['exec', 'python', '-c', VOLATILE_ESTOP, 'true'], ros_env)
        assert 'matched' in p.stdout and 'NOT READY' not in p.stdout, p.stdout
        wait_for(log, 'E-STOP raised', stack, 20)
        wait_for(log, 'e-stop raised: off', stack, 20)      # the controller switched off
        time.sleep(1.0)
        assert 'cleared' in rwpend(['estop', '--clear'], ros_env).stdout
        wait_for(log, 'e-stop cleared: off', stack, 20)
        time.sleep(2.0)
        refused = rwpend(['mode', 'auto'], ros_env, check=False)
        wait_for(log, 'set_mode auto', stack, 20)
        time.sleep(1.0)         # lockstep: > 0.1 s of simulated time driven by the new mode
    finally:
        out = stop(stack, log)
    assert refused.returncode == 0, refused.stdout + refused.stderr
    truth = series(bag, '/rwpend/sim/true_state')
    status = strings(bag, '/rwpend/controller/status', ['mode', 'reason'])
    reasons = [reason for _, _, reason in status]
    raised = next(i for i, r in enumerate(reasons) if r.startswith('e-stop raised'))
    cleared = next(i for i, r in enumerate(reasons) if r.startswith('e-stop cleared'))
    resumed = next(i for i, r in enumerate(reasons) if r == 'set_mode auto' and i > cleared)
    t = [log_ns for log_ns, _, _ in status]
    log_ns = truth['_log_ns']
    # from the e-stop to the mode set again, the plant held zero: under the e-stop, and after
    # the clear because the controller stayed off
    held = (log_ns > t[raised] + 20_000_000) & (log_ns < t[resumed])
    after_clear = (log_ns > t[cleared]) & (log_ns < t[resumed])
    assert after_clear.sum() > 1000, 'a second and more between the clear and the new mode'
    assert np.all(truth['u_commanded'][held] == 0.0)
    assert all(mode == 'off' for _, mode, _ in status[raised:resumed]), status[raised:resumed]
    # the mode chosen again drives the rig again
    assert np.any(truth['u_commanded'][log_ns > t[resumed] + 100_000_000] != 0.0)
    assert 'Traceback' not in out


@pytest.mark.system
@pytest.mark.timeout(180)
def test_reset_is_refused_while_balancing(tmp_path, ros_env):
    stack, bag, log = start(tmp_path, ros_env, '--mode', 'balance')
    try:
        wait_for(log, 'set_mode balance', stack)
        time.sleep(1.5)
        p = rwpend(['exec', 'python', '-c', RESET], ros_env)
        time.sleep(1.0)
    finally:
        stop(stack, log)
    assert 'success False' in p.stdout and 'reset refused: the loop is driving the rig' in p.stdout, p.stdout
    state = series(bag, '/rwpend/state')
    assert np.max(np.abs(deviation(state['theta']))) < 0.1, 'the estimate kept the absolute angle: no jump'
    status = strings(bag, '/rwpend/controller/status', ['mode'])
    assert all(mode == 'balance' for _, mode in status[1:]), status[:5]

