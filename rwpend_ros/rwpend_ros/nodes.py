"""The rclpy side of a loop node: callbacks that run holding the loop's lock in the loop's process
(:class:`LockedCallbacks`, :class:`RwNode`), the loop's subscriptions of wire bytes
(:func:`local_subscription`, with the order gate of :mod:`rwpend_ros.order`), and housekeeping
in the loop's slack of a node in a process of its own (:class:`SlackTimer`). Algorithms live in
the pure packages; this module only deals with rclpy.
"""
from __future__ import annotations

import struct
from typing import Callable

from rclpy.node import Node

from rwpend_ros import wire
from rwpend_ros.order import OrderGate, SourceGates

class LockedCallbacks:
    """Mixin for an rclpy Node class of the loop's process: when the node has the loop's lock
    (``self.loop_lock``, :class:`rwpend_loop.host.LoopLock`), its callbacks (subscriptions,
    timers, services, parameter callbacks, and those rclpy makes itself through these methods:
    parameter services, ``/clock``) all run through :meth:`LoopLock.call`, holding it: a
    parameter change or a service call applies between two samples, whichever thread runs it.
    Without one (a process of one node) the callbacks are rclpy's as given. ``self.loop_lock``
    must be set before the Node's ``__init__`` (rclpy creates the parameter services there):
    :class:`RwNode` does it."""

    loop_lock = None

    def _locked(self, callback):
        lock = self.loop_lock
        if lock is None or callback is None:
            return callback

        def run(*args, **kwargs):
            return lock.call(callback, *args, **kwargs)
        run.__wrapped__ = callback      # rclpy reads the callback's signature through it
        return run

    def create_subscription(self, msg_type, topic, callback, *args, **kwargs):
        return super().create_subscription(msg_type, topic, self._locked(callback), *args, **kwargs)

    def create_timer(self, timer_period_sec, callback, *args, **kwargs):
        return super().create_timer(timer_period_sec, self._locked(callback), *args, **kwargs)

    def create_service(self, srv_type, srv_name, callback, *args, **kwargs):
        return super().create_service(srv_type, srv_name, self._locked(callback), *args, **kwargs)

    def add_on_set_parameters_callback(self, callback):
        return super().add_on_set_parameters_callback(self._locked(callback))

    def add_pre_set_parameters_callback(self, callback):
        return super().add_pre_set_parameters_callback(self._locked(callback))

    def add_post_set_parameters_callback(self, callback):
        return super().add_post_set_parameters_callback(self._locked(callback))


def estop_subscriptions(node, callback) -> list:
    """The subscriptions of topic ``estop`` (std_msgs/Bool) of a plant-side node: one latched
    (a publisher's last value reaches a node that starts later) and one that matches any
    publisher (``ros2 topic pub /rwpend/estop std_msgs/msg/Bool "{data: true}"`` is volatile, which a
    latched subscription never matches); a message seen by both is taken twice, which changes
    nothing (the e-stop is a level, not an event)."""
    from std_msgs.msg import Bool
    from rwpend_ros.qos import QOS_ANY_PUBLISHER, QOS_LATCHED
    return [node.create_subscription(Bool, 'estop', callback, QOS_LATCHED),
            node.create_subscription(Bool, 'estop', callback, QOS_ANY_PUBLISHER)]


class SlackTimer:
    """A periodic timer of a node in a process of its own whose work must not delay a sample
    (diagnostics: 0.35-0.6 ms of CPU holding the GIL on the project's machine; PERFORMANCE.md,
    "What each mechanism buys"). While samples come (:meth:`sample_done` was called since the
    last tick) the tick only marks the work due, and the next per-sample callback runs it right
    after its sample is out. When no sample came since the last tick the work runs at the tick,
    as a plain timer's would; so it never waits longer than one period more than the timer
    alone. A node of the loop's process has no timer here: the loop runs its work between
    samples (rwpend_loop.host). Events that must be reported at once (an e-stop, a stale
    state) do not go through it."""

    def __init__(self, node, period: float, fn: Callable[[], None]) -> None:
        self.fn = fn
        self.samples = 0         # per-sample callbacks that reported (sample_done)
        self._seen = 0           # ... as of the last tick
        self.due = False
        self.in_slack = 0        # runs in the loop's slack
        self.at_tick = 0         # runs at the tick (no loop running)
        if getattr(node, 'hosted', False):
            return               # a node of the loop's process: the loop runs fn (rwpend_loop.host)
        node.create_timer(period, self._tick)

    def _tick(self) -> None:
        if self.samples != self._seen:
            self._seen = self.samples
            self.due = True
        else:
            self.due = False
            self.at_tick += 1
            self.fn()

    def sample_done(self) -> None:
        """Called at the end of the node's per-sample callback."""
        self.samples += 1
        if self.due:
            self.due = False
            self.in_slack += 1
            self.fn()


class RwNode(LockedCallbacks, Node):
    """rclpy Node with :class:`LockedCallbacks` (the simulator, estimator and controller);
    ``loop_lock``: the loop's lock when the loop's process hosts the node (None: a process of
    its own)."""

    def __init__(self, node_name: str, loop_lock=None, **kwargs) -> None:
        self.loop_lock = loop_lock
        super().__init__(node_name, **kwargs)


def say_other_clock(node, stamp_s: float, now_s: float) -> str | None:
    """The first stamped sample a node takes from a topic, ``stamp_s``, against its clock
    ``now_s``: :func:`rwpend_ros.health.other_clock` for the node's ``use_sim_time``, said once
    in its log when not None (the caller keeps it for /diagnostics ``other_clock``)."""
    from rwpend_ros.health import other_clock
    why = other_clock(stamp_s, now_s, bool(node.get_parameter('use_sim_time').value))
    if why:
        node.get_logger().warn(why)
    return why


class LoopSubscription:
    """What :func:`local_subscription` made: the rclpy subscription and the order gate
    (:class:`rwpend_ros.order.OrderGate` or :class:`~rwpend_ros.order.SourceGates`, None for a
    topic without seq); ``malformed``: messages too short to read a seq from (dropped)."""

    def __init__(self, sub, gate) -> None:
        self.sub = sub
        self.gate = gate
        self.malformed = 0
        self.topic_name = sub.topic_name

    def summary(self) -> str:
        """One line for /diagnostics: what the gate took and stopped."""
        text = self.gate.summary() if self.gate is not None else ''
        if self.malformed:
            text += f', malformed {self.malformed}'
        return text


def local_subscription(node, msg_type, topic: str, callback: Callable[[bytes], None], qos,
                       ordered: bool = True, sender: Callable[[bytes], int] | None = None) -> LoopSubscription:
    """A raw subscription of a loop topic: ``callback`` takes wire bytes, once per message and in
    order -- the order gate (``ordered``: the message starts with a Header and a seq, as every
    loop message) drops duplicates and messages older than the last one taken, and counts them;
    with ``sender`` (the sender's id from the bytes: :func:`rwpend_ros.wire.command_sender`) one
    gate per sender (:class:`rwpend_ros.order.SourceGates`), so that the streams of two senders
    on one topic both reach ``callback``, each once and in order. In the loop's process the gate
    and the callback run holding the loop's lock (:class:`LockedCallbacks`): the loop reads the
    gate's counters for /diagnostics from its own thread."""
    gate = (SourceGates() if sender is not None else OrderGate()) if ordered else None
    holder: list[LoopSubscription] = []

    def gated(data):
        try:
            seq, stamp = wire.message_seq_stamp(data)
            admitted = (gate.admit(sender(data), seq, stamp) if sender is not None
                        else gate.admit(seq, stamp))
        except struct.error:
            holder[0].malformed += 1
            return
        if admitted:
            callback(data)
    take = gated if ordered else callback
    if isinstance(node, LockedCallbacks):
        take = node._locked(take)
    sub = Node.create_subscription(node, msg_type, topic, take, qos, raw=True)
    holder.append(LoopSubscription(sub, gate))
    return holder[0]
