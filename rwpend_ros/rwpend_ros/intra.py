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
  lock; the simulator's real-time sample loop registers there and runs each tick holding it):
  a publish from any other thread goes through DDS as before, so a node's callbacks still run
  one at a time;
* a subscriber whose node (its ``owner``) has a callback running already (on the stack,
  further up: :meth:`LocalBus.call` marks the node busy) is not entered again: the message is
  *deferred*, delivered on the same thread, holding the same lock, right after the outermost
  callback returns (:meth:`LocalBus.call`), in the order published. So an estimator composed
  with its controller takes command k after it has published state k and before anything
  else -- the order of separate processes -- and needs no DDS copy (PERFORMANCE.md, 18.);
* the message is published on DDS too, after the local delivery: other processes (the
  recorder, a monitor) see exactly what they saw before;
* the DDS copy of a message the subscriber already got through the bus is dropped by its DDS
  callback (same bytes as one of the last :data:`KEEP` delivered locally); a message from
  another process is delivered as before;
* ``RWPEND_INTRA_PROCESS=0`` turns the bus off (for comparisons).

Only topics whose subscriber opts in use it (``state`` -> controller, ``command`` -> simulator
and estimator, ``encoders`` -> estimator). The lockstep simulator's ``encoders`` publisher opts
out (``LocalPublisher(intra=False)``): there every sample would be deferred from the one before
(simulator -> estimator -> controller -> simulator), and the whole run would go on in one flush,
the executor never getting its thread back. So a chain of local deliveries ends after one
sample.
"""
from __future__ import annotations

import os
import threading
from collections import deque
from typing import Callable, Hashable

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
    __slots__ = ('bus', 'callback', 'owner', 'before_dds', 'pending', 'delivered', 'deferred',
                 'duplicates', 'sink')

    def __init__(self, bus: 'LocalBus', callback: Callable[[bytes], None], before_dds: bool = True,
                 owner: Hashable = None) -> None:
        self.bus = bus
        self.callback = callback
        #: the node whose callbacks run one at a time (None: the subscription alone)
        self.owner = self if owner is None else owner
        self.before_dds = before_dds  # delivered before the DDS write (else right after it)
        self.pending: deque[bytes] = deque(maxlen=KEEP)   # delivered locally, DDS copy not seen yet
        self.delivered = 0           # messages delivered through the bus
        self.deferred = 0            # of those, delivered after the callback of its node returned
        self.duplicates = 0          # DDS copies dropped
        #: where a DDS message not delivered locally goes (run; the same-host fast path's merge)
        self.sink: Callable[[bytes], None] = self.run

    @property
    def active(self) -> bool:
        """A callback of its node is running (on the stack)."""
        return self.owner in self.bus.busy

    def run(self, data: bytes) -> None:
        self.bus.call(self.owner, self.callback, data)

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
        #: owner -> how many of its callbacks are on the stack (all under the callback lock)
        self.busy: dict[Hashable, int] = {}
        #: callbacks running through :meth:`call` (nesting depth)
        self.depth = 0
        #: messages for busy owners, delivered when the outermost callback returns
        self.deferred: deque[tuple[_LocalSub, bytes]] = deque()
        #: work for the loop's slack (:meth:`after`): one job each time an outermost callback returns
        self.slack: deque[Callable[[], None]] = deque()
        self.slack_jobs = 0      # jobs run in the slack

    def subscribe(self, topic: str, callback: Callable[[bytes], None], before_dds: bool = True,
                  owner: Hashable = None) -> _LocalSub:
        """Register ``callback`` for ``topic``; give the returned object's ``from_dds`` to the
        DDS subscription as its callback. ``before_dds``: called before the message is written
        to DDS (the shortest path), else right after it (the DDS readers, in this process too,
        then get the message before anything the callback publishes). ``owner``: the node (its
        other callbacks mark it busy through :meth:`call`); None = the subscription alone."""
        sub = _LocalSub(self, callback, before_dds, owner)
        self.topics.setdefault(topic, []).append(sub)
        return sub

    def unsubscribe(self, topic: str, sub: _LocalSub) -> None:
        subs = self.topics.get(topic, [])
        if sub in subs:
            subs.remove(sub)
        if not subs:
            self.topics.pop(topic, None)

    def local(self, topic: str) -> list[_LocalSub]:
        """The subscriptions a publish on ``topic`` from this thread delivers to directly (now,
        or deferred when their node is busy)."""
        if not self.enabled or self.thread is None:
            return []
        subs = self.topics.get(topic)
        if not subs:
            return []
        ident = threading.get_ident()
        if ident != self.thread and ident not in self.extra_threads:
            return []
        return subs

    def publish(self, topic: str, data: bytes, dds_publish: Callable[[bytes], None]) -> None:
        """Deliver ``data`` to the local subscribers of ``topic`` (in their callbacks, now, or
        deferred if their node is busy) and publish it on DDS with ``dds_publish``: the
        ``before_dds`` subscribers first, then the DDS write, then the others."""
        subs = self.local(topic)
        if not subs:
            dds_publish(data)
            return
        # the DDS copies are taken by the executor, i.e. after this returns: marking a message
        # as delivered before or after the DDS write is the same
        try:
            for sub in subs:
                if sub.before_dds:
                    self._deliver(sub, data)
        finally:   # whatever a local callback did, the message goes out on DDS (recorded)
            dds_publish(data)
        for sub in subs:   # not reached when a callback above raised: DDS delivers to these
            if not sub.before_dds:
                self._deliver(sub, data)

    def _deliver(self, sub: _LocalSub, data: bytes) -> None:
        sub.pending.append(data)
        sub.delivered += 1
        if sub.owner in self.busy:
            sub.deferred += 1
            self.deferred.append((sub, data))
        else:
            sub.run(data)

    def call(self, owner: Hashable, fn: Callable, *args, **kwargs):
        """``fn(*args, **kwargs)`` as a callback of ``owner`` (its node): marked busy meanwhile, so a
        message for it published meanwhile waits; when the outermost such call returns, the
        messages deferred meanwhile are delivered, in order (and those they defer in turn).
        Called holding the process's callback lock. If ``fn`` raises, what was deferred waits
        for the next outermost call to return."""
        busy = self.busy
        busy[owner] = busy.get(owner, 0) + 1
        self.depth += 1
        try:
            result = fn(*args, **kwargs)
        finally:
            self.depth -= 1
            n = busy[owner] - 1
            if n:
                busy[owner] = n
            else:
                del busy[owner]
        if not self.depth:
            if self.deferred:
                self._flush()
            if self.slack:
                self._run_slack()
        return result

    def after(self, fn: Callable[[], None]) -> None:
        """Run ``fn()`` when the outermost callback running now returns (after the messages it
        deferred), on the same thread, holding the same lock -- now if no callback runs through
        :meth:`call`. Called from a node's per-sample callback for work that must not run while
        a sample is on its way (diagnostics, :class:`rwpend_ros.common.SlackTimer`): in
        separate processes that is right after the callback; in a composed process, after the
        whole chain of one sample (estimator, controller, the simulator's command). One job
        runs per outermost return, so the jobs of several nodes that fall due together go in
        successive samples; a job already waiting is not queued twice."""
        if not self.depth:
            fn()
        elif fn not in self.slack:
            self.slack.append(fn)

    def _run_slack(self) -> None:
        fn = self.slack.popleft()
        self.slack_jobs += 1
        self.depth += 1          # calls inside the job defer / flush as inside a callback
        try:
            fn()
        finally:
            self.depth -= 1
        if self.deferred:
            self._flush()

    def _flush(self) -> None:
        deferred = self.deferred
        self.depth += 1          # the calls below do not flush in turn: this loop does
        try:
            while deferred:
                sub, data = deferred.popleft()
                sub.run(data)
        finally:
            self.depth -= 1

    def reset(self) -> None:
        """Off, and no subscription (run_nodes, when its nodes are destroyed)."""
        self.thread = None
        self.extra_threads.clear()
        self.topics.clear()
        self.busy.clear()
        self.deferred.clear()
        self.slack.clear()
        self.depth = 0


#: the bus of this process
BUS = LocalBus()
