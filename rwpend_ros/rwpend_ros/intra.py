"""In-process delivery of wire bytes between nodes of ONE process (composed mode), the rclpy
counterpart of rclcpp's intra-process communication. Pure: no rclpy import (the rclpy glue is
:func:`rwpend_ros.common.local_publisher` / :func:`rwpend_ros.common.local_subscription`).

Why: between two nodes of one process a message still goes through DDS -- the publisher hands
it to Fast DDS, whose listener queues an event, and the executor takes it after the
publisher's callback has returned: ~120 us p50 per hop at 1 kHz, as much as a hop between
processes (PERFORMANCE.md, 12.). Through the bus the subscriber's callback runs inside
``publish()``: before the DDS write (``state`` -> controller: the shortest path), or right
after it (``command`` -> simulator: an estimator of the process then has command k, through
DDS, before the sample k+1 the simulator publishes in lockstep -- the order of separate
processes).

Rules (what keeps it safe):

* only on the executor's thread (:attr:`LocalBus.thread`, set by ``run_nodes`` once the nodes
  are built; None = off) and on the receiving threads of the same-host fast path
  (:attr:`LocalBus.extra_threads`, :mod:`rwpend_ros.hostbus`; they hold the process's callback
  lock): a publish from another thread (the simulator's real-time sample loop) goes through
  DDS as before, so a node's callbacks still run one at a time;
* a local subscriber whose callback is running already (on the stack, further up) is not
  entered again: the message then takes the DDS path like any other;
* the message is published on DDS too, after the local delivery: other processes (the
  recorder, a monitor) see exactly what they saw before;
* the DDS copy of a message the subscriber already got through the bus is dropped by its DDS
  callback (same bytes as one of the last :data:`KEEP` delivered locally); a message from
  another process is delivered as before;
* ``RWPEND_INTRA_PROCESS=0`` turns the bus off (for comparisons).

Only topics whose subscriber opts in use it (``state`` -> controller, ``command`` -> simulator),
and no callback reached through it publishes on a bus topic the chain came from, so a local
delivery never cycles.
"""
from __future__ import annotations

import os
import threading
from collections import deque
from typing import Callable

#: how many locally delivered messages per subscription wait for their DDS copy
KEEP = 64


def take_copy(pending: deque, data: bytes) -> bool:
    """True (and ``data`` gone from ``pending``) when ``data`` is the copy of a message already
    delivered another way. DDS keeps a publisher's order: the copies of the older pending
    messages will not come any more (a keep-last reader dropped them), so they go too. Shared
    with :class:`rwpend_ros.hostbus.Merge`."""
    if pending and data in pending:
        while pending.popleft() != data:
            pass
        return True
    return False


class _LocalSub:
    __slots__ = ('callback', 'before_dds', 'pending', 'active', 'delivered', 'duplicates', 'sink')

    def __init__(self, callback: Callable[[bytes], None], before_dds: bool = True) -> None:
        self.callback = callback
        self.before_dds = before_dds  # delivered before the DDS write (else right after it)
        self.pending: deque[bytes] = deque(maxlen=KEEP)   # delivered locally, DDS copy not seen yet
        self.active = False          # its callback is running (on the executor's thread)
        self.delivered = 0           # messages delivered through the bus
        self.duplicates = 0          # DDS copies dropped
        #: where a DDS message not delivered locally goes (run; the same-host fast path's merge)
        self.sink: Callable[[bytes], None] = self.run

    def run(self, data: bytes) -> None:
        self.active = True
        try:
            self.callback(data)
        finally:
            self.active = False

    def from_dds(self, data: bytes) -> None:
        """The DDS subscription's callback: drops the copy of a message the bus delivered."""
        if take_copy(self.pending, data):
            self.duplicates += 1
            return
        self.sink(data)


class LocalBus:
    """The process's registry of local subscriptions, by fully qualified topic name."""

    def __init__(self, enabled: bool | None = None) -> None:
        if enabled is None:
            enabled = os.environ.get('RWPEND_INTRA_PROCESS', '1') != '0'
        self.enabled = enabled
        #: ident of the executor's thread; None until run_nodes starts spinning (bus off)
        self.thread: int | None = None
        #: idents of other threads that run callbacks holding the callback lock (hostbus)
        self.extra_threads: set[int] = set()
        self.topics: dict[str, list[_LocalSub]] = {}

    def subscribe(self, topic: str, callback: Callable[[bytes], None], before_dds: bool = True) -> _LocalSub:
        """Register ``callback`` for ``topic``; give the returned object's ``from_dds`` to the
        DDS subscription as its callback. ``before_dds``: called before the message is written
        to DDS (the shortest path), else right after it (the DDS readers, in this process too,
        then get the message before anything the callback publishes)."""
        sub = _LocalSub(callback, before_dds)
        self.topics.setdefault(topic, []).append(sub)
        return sub

    def unsubscribe(self, topic: str, sub: _LocalSub) -> None:
        subs = self.topics.get(topic, [])
        if sub in subs:
            subs.remove(sub)
        if not subs:
            self.topics.pop(topic, None)

    def local(self, topic: str) -> list[_LocalSub]:
        """The subscriptions a publish on ``topic`` from this thread delivers to directly."""
        if not self.enabled or self.thread is None:
            return []
        subs = self.topics.get(topic)
        if not subs:
            return []
        ident = threading.get_ident()
        if ident != self.thread and ident not in self.extra_threads:
            return []
        return [s for s in subs if not s.active]

    def publish(self, topic: str, data: bytes, dds_publish: Callable[[bytes], None]) -> None:
        """Deliver ``data`` to the local subscribers of ``topic`` (in their callbacks, now) and
        publish it on DDS with ``dds_publish``: the ``before_dds`` subscribers first, then the
        DDS write, then the others."""
        subs = self.local(topic)
        if not subs:
            dds_publish(data)
            return
        # the DDS copies are taken by the executor, i.e. after this returns: marking a message
        # as delivered before or after the DDS write is the same
        try:
            for sub in subs:
                if sub.before_dds:
                    sub.pending.append(data)
                    sub.delivered += 1
                    sub.run(data)
        finally:   # whatever a local callback did, the message goes out on DDS (recorded)
            dds_publish(data)
        for sub in subs:   # not reached when a callback above raised: DDS delivers to these
            if not sub.before_dds and not sub.active:
                sub.pending.append(data)
                sub.delivered += 1
                sub.run(data)

    def reset(self) -> None:
        """Off, and no subscription (run_nodes, when its nodes are destroyed)."""
        self.thread = None
        self.extra_threads.clear()
        self.topics.clear()


#: the bus of this process
BUS = LocalBus()
