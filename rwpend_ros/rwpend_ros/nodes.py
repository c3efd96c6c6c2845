"""The rclpy side of a loop node: callbacks that run one at a time with the in-process bus of a
composed process (:class:`LockedCallbacks`, :class:`RwNode`), the loop's publishers and
subscriptions (:class:`LocalPublisher`, :func:`local_subscription`: the bus of
:mod:`rwpend_ros.intra` when there is one, DDS always, and the order gate of
:mod:`rwpend_ros.order` on every loop subscription), and housekeeping in the loop's slack
(:class:`SlackTimer`). Algorithms live in the pure packages; this module only deals with rclpy.
"""
from __future__ import annotations

import struct
from typing import Callable

from rclpy.node import Node

from rwpend_ros import wire
from rwpend_ros.order import OrderGate, SourceGates

class LockedCallbacks:
    """Mixin for an rclpy Node class of a composed process: when the node has an in-process bus
    (``self.bus``, :class:`rwpend_ros.intra.LocalBus`), its callbacks (subscriptions, timers,
    services, parameter callbacks, and those rclpy makes itself through these methods:
    parameter services, ``/clock``) all run through :meth:`LocalBus.call`, holding the bus's
    lock: the nodes' callbacks run one at a time whichever thread runs them, and a message the
    bus has for the node meanwhile waits until the callback returns. Without a bus (a process of
    one node) the callbacks are rclpy's as given. ``self.bus`` must be set before the Node's
    ``__init__`` (rclpy creates the parameter services there): :class:`RwNode` does it."""

    bus = None

    def _locked(self, callback):
        bus = self.bus
        if bus is None or callback is None:
            return callback

        def run(*args, **kwargs):
            return bus.call(self, callback, *args, **kwargs)
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
    """A periodic timer of a loop node whose work must not delay a sample (diagnostics: 0.35-0.6
    ms of CPU holding the GIL on the project's machine; PERFORMANCE.md, "What each mechanism buys").
    While the loop runs (:meth:`sample_done` was called since the last tick) the tick only marks the
    work due, and the next per-sample callback runs it right after its sample is out -- in a
    composed process after the sample's whole chain (:meth:`rwpend_ros.intra.LocalBus.after`).
    When no sample came since the last tick the work runs at the tick, as a plain timer's would;
    so it never waits longer than one period more than the timer alone. Events that must be
    reported at once (an e-stop, a stale state) do not go through it."""

    def __init__(self, node, period: float, fn: Callable[[], None]) -> None:
        self.fn = fn
        self.bus = getattr(node, 'bus', None)
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
            if self.bus is not None:
                self.bus.after(self.fn)
            else:
                self.fn()


class RwNode(LockedCallbacks, Node):
    """rclpy Node with :class:`LockedCallbacks` (the simulator, estimator and controller);
    ``bus``: the in-process bus of a composed process (None: a process of its own)."""

    def __init__(self, node_name: str, bus=None, **kwargs) -> None:
        self.bus = bus
        super().__init__(node_name, **kwargs)


class LocalPublisher:
    """A publisher of the loop's wire bytes: a message goes first to the subscribers of
    :func:`local_subscription` in this process (the node's in-process bus, if it has one and
    ``intra``), then to DDS as usual. Takes wire bytes (the per-sample path) or message objects;
    everything else is the rclpy publisher's (``get_subscription_count`` ...). ``publish`` may be
    called from another thread than the executor's (the simulator's sample loop): the bus then
    delivers only if that thread is one of its extra threads."""

    def __init__(self, node, msg_type, topic: str, qos, intra: bool = True) -> None:
        self.pub = node.create_publisher(msg_type, topic, qos)
        self.topic = self.pub.topic_name
        #: the bus that carries it to subscribers of this process (None: DDS only)
        self.bus = getattr(node, 'bus', None) if intra else None

    def publish(self, data) -> None:
        bus = self.bus
        if bus is None or not isinstance(data, (bytes, bytearray)):
            self.pub.publish(data)
        else:
            bus.publish(self.topic, data, self.pub.publish)

    def local_subscribers(self) -> list:
        """The subscribers of this process a publish from this thread reaches through the bus."""
        return self.bus.local(self.topic) if self.bus is not None else []

    def __getattr__(self, name):
        if name == 'pub':           # not built (the publisher's creation failed)
            raise AttributeError(name)
        return getattr(self.pub, name)


class LoopSubscription:
    """What :func:`local_subscription` made: the rclpy subscription, the order gate
    (:class:`rwpend_ros.order.OrderGate` or :class:`~rwpend_ros.order.SourceGates`, None for a
    topic without seq) and the bus subscription
    (None without a bus); ``malformed``: messages too short to read a seq from (dropped)."""

    def __init__(self, sub, gate, local) -> None:
        self.sub = sub
        self.gate = gate
        self.local = local
        self.malformed = 0
        self.topic_name = sub.topic_name

    def summary(self) -> str:
        """One line for /diagnostics: what the gate took and stopped, the bus's share."""
        text = self.gate.summary() if self.gate is not None else ''
        if self.malformed:
            text += f', malformed {self.malformed}'
        if self.local is not None:
            text += (f'; in-process {self.local.delivered} (deferred {self.local.deferred}), '
                     f'DDS copies dropped {self.local.duplicates}')
        return text


def local_subscription(node, msg_type, topic: str, callback: Callable[[bytes], None], qos,
                       before_dds: bool = True, intra: bool = True, ordered: bool = True,
                       sender: Callable[[bytes], int] | None = None) -> LoopSubscription:
    """A raw subscription of a loop topic: ``callback`` takes wire bytes, once per message and in
    order -- the order gate (``ordered``: the message starts with a Header and a seq, as every
    loop message) drops duplicates and messages older than the last one taken, and counts them;
    with ``sender`` (the sender's id from the bytes: :func:`rwpend_ros.wire.command_sender`) one
    gate per sender (:class:`rwpend_ros.order.SourceGates`), so that the streams of two senders
    on one topic both reach ``callback``, each once and in order.
    With the node's in-process bus (``intra``) it also takes the messages of a
    :class:`LocalPublisher` of this process directly (``before_dds``: see
    :meth:`rwpend_ros.intra.LocalBus.subscribe`); their DDS copies are dropped."""
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
    bus = getattr(node, 'bus', None) if intra else None
    local = None
    if bus is not None:
        local = bus.subscribe(node.resolve_topic_name(topic), take, owner=node, before_dds=before_dds)
    try:
        # not LockedCallbacks.create_subscription: the bus's from_dds runs the callback through
        # LocalBus.call itself
        sub = Node.create_subscription(node, msg_type, topic,
                                       local.from_dds if local is not None else take, qos, raw=True)
    except BaseException:
        if local is not None:
            bus.unsubscribe(node.resolve_topic_name(topic), local)
        raise
    holder.append(LoopSubscription(sub, gate, local))
    return holder[0]
