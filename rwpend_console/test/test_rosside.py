"""The console's ROS side in-process (own contexts, a test domain id): polled taps take only the
newest sample, a watched rig's state and applied command come decimated into its feed (the
applied command taken only once the rig's samples flow), the subscriptions go with the last
page, the e-stop goes out on the rig's latched topic with a record on /diagnostics, and the
e-stop state shown is the plant's report."""
import time

import pytest

rclpy = pytest.importorskip('rclpy')

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from rclpy.context import Context  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.qos import QoSProfile  # noqa: E402
from std_msgs.msg import Bool  # noqa: E402

from rwpend_console.rosside import QOS_OBSERVER, DomainWatcher  # noqa: E402
from rwpend_console.taps import Tap, Taps  # noqa: E402
from rwpend_msgs.msg import ControllerStatus, PlantState, StateEstimate  # noqa: E402
from rwpend_ros.diagnostics import publish_diagnostic  # noqa: E402
from rwpend_ros.qos import QOS_CONTROL_PUB, QOS_LATCHED, QOS_STATUS  # noqa: E402
from rwpend_ros.testenv import test_domain_id  # noqa: E402


def wait(cond, timeout=30.0):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if cond():
            return True
        time.sleep(0.02)
    return False


@pytest.fixture
def domain():
    return test_domain_id()


@pytest.fixture
def peer(domain):
    ctx = Context()
    rclpy.init(context=ctx, domain_id=domain)
    node = Node('rig', namespace='/rig', context=ctx)
    yield node
    node.destroy_node()
    rclpy.try_shutdown(context=ctx)


def state(k):
    m = StateEstimate(seq=k, theta=3.1, theta_dot=0.01 * k, wheel_rate=2.0, energy=2.0, estimator='t')
    m.header.stamp.sec, m.header.stamp.nanosec = divmod(k * 1_000_000, 1_000_000_000)
    return m


def test_a_depth_one_tap_takes_the_newest_sample_only(peer, domain):
    pub = peer.create_publisher(StateEstimate, '/rig/state', QOS_CONTROL_PUB)
    ctx = Context()
    rclpy.init(context=ctx, domain_id=domain)
    taps = Taps(ctx, 'taps_test', 0.2)                     # polls every 200 ms
    got = []
    tap = Tap(StateEstimate, '/rig/state', QOS_OBSERVER, got.append)
    try:
        taps.start()
        taps.add(tap).result(timeout=10)
        assert wait(lambda: pub.get_subscription_count() == 1)
        time.sleep(0.5)
        for k in range(200):                               # a burst between two polls
            pub.publish(state(k))
        from rclpy.serialization import deserialize_message
        # until the last samples are taken (not a fixed pause: on a loaded host the burst's
        # delivery outlasted 0.5 s)
        assert wait(lambda: got and deserialize_message(got[-1][0][0], StateEstimate).seq >= 150)
        time.sleep(0.5)
        seqs = [deserialize_message(m[0][0], StateEstimate).seq for m in got]
        # one take per poll at most, never one per sample; the newest samples, in order
        assert len(got) <= tap.polls and len(got) < 50 and seqs == sorted(seqs) and seqs[-1] >= 150, seqs
        taps.remove(tap).result(timeout=10)
        assert wait(lambda: pub.get_subscription_count() == 0)
    finally:
        taps.close()
        rclpy.try_shutdown(context=ctx)
    with pytest.raises(ValueError):
        Taps(peer.context, 'bad', 0.0)


def test_a_watched_rig_feeds_the_page_and_the_estop_goes_out(peer, domain):
    st = peer.create_publisher(StateEstimate, '/rig/state', QOS_CONTROL_PUB)
    status = peer.create_publisher(ControllerStatus, '/rig/controller/status', QOS_STATUS)
    truth = peer.create_publisher(PlantState, '/rig/sim/true_state', QOS_CONTROL_PUB)
    diag_out = peer.create_publisher(DiagnosticArray, '/diagnostics', QOS_STATUS)
    diag_in = []
    peer.create_subscription(DiagnosticArray, '/diagnostics', diag_in.append, QOS_STATUS)
    estops = []
    peer.create_subscription(Bool, '/rig/estop', estops.append, QOS_LATCHED)
    from rclpy.executors import SingleThreadedExecutor
    ex = SingleThreadedExecutor(context=peer.context)
    ex.add_node(peer)
    w = DomainWatcher(domain, rate_hz=50.0)
    try:
        w.start()
        assert wait(lambda: '/rig' in w.rigs or (ex.spin_once(timeout_sec=0.01) or False))
        feed = w.watch('/rig')
        assert wait(lambda: st.get_subscription_count() == 1 and status.get_subscription_count() == 1)
        time.sleep(0.5)
        assert truth.get_subscription_count() == 0, 'sim/true_state not taken before the samples flow'
        for k in range(1000):                               # 1 s of samples at 1 kHz
            st.publish(state(k))
            if k >= 100:
                p = PlantState(seq=k, u_commanded=0.0, u_applied=5e-324 if k % 2 else 0.25)
                p.header.stamp = state(k).header.stamp
                truth.publish(p)
            if k % 10 == 0:
                m = ControllerStatus(mode='auto', law='swingup' if k < 500 else 'catch', u=1.0)
                m.header.stamp = state(k).header.stamp
                status.publish(m)
            time.sleep(0.001)
        time.sleep(0.5)
        batch, _ = feed.since(None, 20.0)
        assert 5 <= len(batch['s']) <= 51, len(batch['s'])   # decimated to <= 50 per second of samples
        assert [b[2] for b in batch['b']] == ['swingup', 'catch'], batch['b']
        assert truth.get_subscription_count() == 1
        assert 2 <= len(batch['a']) <= 46 and {r[1] for r in batch['a']} <= {0.0, 0.25}, batch['a']
        w.unwatch('/rig')
        assert wait(lambda: st.get_subscription_count() == 0 and truth.get_subscription_count() == 0), \
            'the subscriptions go with the last page'
        w.publish_estop('/rig', True, time.time_ns())
        assert wait(lambda: (ex.spin_once(timeout_sec=0.01) or True) and estops and any(
            s.name == '/rig/console: e-stop' for d in diag_in for s in d.status))
        assert estops[-1].data is True
        assert w.estop_state('/rig')['state'] == 'unknown', 'nothing from the plant yet: not "raised"'
        publish_diagnostic(diag_out, time.time_ns(), '/rig/sim: plant', '/rig', 2, 'e-stop latched: motor at zero',
                           {'estop': True})
        assert wait(lambda: w.estop_state('/rig')['state'] == 'raised')
        publish_diagnostic(diag_out, time.time_ns(), '/rig/sim: plant', '/rig', 0, 'running', {'estop': False})
        assert wait(lambda: w.estop_state('/rig')['state'] == 'clear')
        assert w.estop_state('/rig')['by'] == 'elsewhere' and w.summary('/rig')['estop'] is False
    finally:
        w.close()
        ex.shutdown()
