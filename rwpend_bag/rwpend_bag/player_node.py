"""Player node ``player``: publishes a bag's raw bytes with the original timing.

The schedule (pure, :func:`rwpend_bag.player_core.schedule`) is played against a monotonic
clock: sleep until ~1.5 ms before each message, then busy-wait, then publish the wire bytes.
Ctrl-C (SIGINT) or SIGTERM ends the playback between two messages (exit status 0): the player
publishes from its own loop, not from an executor, so rclpy's signal handler -- which shuts the
context down at once, under a publish in progress ("publisher's context is invalid") -- is not
installed; the player's own handler only asks the loop to stop.
"""
from __future__ import annotations

import signal
import sys
import threading
import time

import rclpy
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from . import msgdefs
from .player_core import Schedule, wait_until

DEPTH = 1000


def _qos_from_offered(offered: list[dict]) -> QoSProfile:
    rel = ReliabilityPolicy.RELIABLE
    dur = DurabilityPolicy.VOLATILE
    if offered:
        if all(str(q.get('reliability', '')).lower() in ('best_effort', '2') for q in offered):
            rel = ReliabilityPolicy.BEST_EFFORT
        if all(str(q.get('durability', '')).lower() in ('transient_local', '1') for q in offered):
            dur = DurabilityPolicy.TRANSIENT_LOCAL
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=DEPTH, reliability=rel, durability=dur)


class Player(Node):
    def __init__(self, sched: Schedule, clock: bool):
        super().__init__('player')
        self.sched = sched
        self.pubs: dict[int, object] = {}
        for i, t in enumerate(sched.topics):
            try:
                cls = msgdefs.import_message_class(t.type)
            except (ImportError, ValueError) as exc:
                print(f'play: skipping {t.name}: {exc}', file=sys.stderr, flush=True)
                continue
            self.pubs[i] = self.create_publisher(cls, t.out_name, _qos_from_offered(t.qos))
        self.clock_pub = None
        if clock:
            from rosgraph_msgs.msg import Clock
            self._Clock = Clock
            self.clock_pub = self.create_publisher(Clock, '/clock', 10)

    def wait_for_subscribers(self, timeout: float, stop: threading.Event) -> None:
        end = time.monotonic() + timeout
        while time.monotonic() < end and not stop.is_set():
            if any(p.get_subscription_count() > 0 for p in self.pubs.values()):
                return
            stop.wait(0.02)

    def play_once(self, rate: float, stop: threading.Event) -> list[float]:
        """One pass, until ``stop`` is set; returns the lateness (s) of every publish."""
        s = self.sched
        idx, data, rel = s.topic_index, s.datas, s.rel_ns
        pubs = self.pubs
        late = []
        clock_pub = self.clock_pub
        last_clock = None
        t0 = time.monotonic() + 0.05
        for k in range(len(data)):
            target = t0 + rel[k] / 1e9 / rate
            if not wait_until(target, stop):
                break
            late.append(time.monotonic() - target)
            if clock_pub is not None:
                ns = int(s.log_ns[k])
                if last_clock is None or ns - last_clock >= 1_000_000:
                    msg = self._Clock()
                    msg.clock.sec, msg.clock.nanosec = divmod(ns, 1_000_000_000)
                    clock_pub.publish(msg)
                    last_clock = ns
            p = pubs.get(int(idx[k]))
            if p is not None:
                p.publish(data[k])
        return late


def run(sched: Schedule, rate: float, loop: bool, clock: bool, wait: float = 2.0) -> int:
    from rwpend_ros.transport import apply_transport_or_exit
    apply_transport_or_exit()  # before rclpy.init
    stop = threading.Event()
    previous = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGINT, signal.SIGTERM)}
    node = None
    try:
        # not sys.argv: its --remap a:=b would become rcl remap rules; no rclpy signal handler
        # (module doc)
        rclpy.init(args=[], signal_handler_options=SignalHandlerOptions.NO)
        node = Player(sched, clock)
        if not node.pubs:
            print('play: no playable topic', file=sys.stderr, flush=True)
            return 1
        node.wait_for_subscribers(wait, stop)
        span = float(sched.rel_ns[-1]) / 1e9 if len(sched) else 0.0
        print(f'play: playing {len(sched)} messages on {len(node.pubs)} topics ({span:.1f} s at rate '
              f'{rate:g}{", looped" if loop else ""})', flush=True)
        while not stop.is_set():
            late = node.play_once(rate, stop)
            if late:
                late.sort()
                print(f'play: {len(late)} messages, lateness median {late[len(late)//2]*1e3:.3f} ms, '
                      f'max {late[-1]*1e3:.3f} ms', flush=True)
            if not loop:
                break
        if stop.is_set():
            print('play: stopped', flush=True)
        time.sleep(0.3)  # let reliable writers deliver the tail
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    return 0
