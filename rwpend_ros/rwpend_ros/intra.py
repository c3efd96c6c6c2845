"""In-process delivery of wire bytes between the nodes of ONE process (composition), the rclpy
counterpart of rclcpp's intra-process communication. Pure: no rclpy import (the rclpy glue is
:class:`rwpend_ros.nodes.LocalPublisher` / :func:`rwpend_ros.nodes.local_subscription`).

Why: rclpy has no intra-process communication. Between two nodes of one process a message goes
through Fast DDS (writer, reader, listener, event queue) and the executor takes it after the
publisher's callback has returned: ~75-130 us per hop at 1 kHz on the project's machine, about
what a hop between processes costs. Through the bus the subscriber's callback runs inside
``publish()`` (PERFORMANCE.md, "What each mechanism buys").

One switch: ``RWPEND_INTRA_PROCESS=0`` (the composer then creates no bus and every message goes
through DDS). A process of one node has no bus.

The bus is an object the composer (:func:`rwpend_ros.runner.run_nodes`) creates and hands to
each node it builds; nothing here is global. Rules (what keeps it safe):

* every callback of the process's nodes runs holding :attr:`LocalBus.lock`
  (:class:`rwpend_ros.nodes.LockedCallbacks`), so a node's callbacks run one at a time whichever
  thread runs them;
* delivery happens only on the executor's thread (:attr:`LocalBus.thread`) and on the threads
  registered in :attr:`LocalBus.extra_threads` (the simulator's real-time sample loop, which
  runs each tick holding the lock); a publish from any other thread goes through DDS;
* a subscriber whose node (its ``owner``) has a callback running already is not entered again:
  the message is *deferred* and delivered on the same thread, holding the same lock, right after
  the outermost callback returns (:meth:`LocalBus.call`), in the order published. So an estimator
  composed with its controller takes command k after it has published state k and before
  anything else -- the order of separate processes;
* the message is written to DDS too, after the local delivery: other processes (the recorder, a
  monitor) see exactly what they would see without the bus;
* the DDS copy of a message a subscriber already got through the bus is dropped by its DDS
  callback (the same bytes as one of the last :data:`KEEP` delivered locally). Whatever slips
  through (a copy later than KEEP messages) is stopped by the subscription's order gate
  (:mod:`rwpend_ros.order`): a subscriber never takes a message twice.

The lockstep simulator's ``encoders`` publisher opts out (``LocalPublisher(intra=False)``): there
every sample would be deferred from the one before (simulator -> estimator -> controller ->
simulator) and the whole run would go on in one flush, the executor never getting its thread
back.
"""
from __future__ import annotations

import os
import threading
from collections import deque
from typing import Callable, Hashable

#: how many locally delivered messages per subscription wait for their DDS copy
KEEP = 64


def enabled(env=None) -> bool:
    """``RWPEND_INTRA_PROCESS``: 1 or unset = on, 0 = off; anything else is refused (ValueError)."""
    value = (os.environ if env is None else env).get('RWPEND_INTRA_PROCESS', '1').strip() or '1'
    if value not in ('0', '1'):
        raise ValueError(f'RWPEND_INTRA_PROCESS={value!r}: expected 0 (off) or 1 (on)')
    return value == '1'


def take_copy(pending: deque, data: bytes) -> bool:
    """True (and ``data`` gone from ``pending``) when ``data`` is the copy of a message already
    delivered locally. DDS keeps a publisher's order: the copies of the older pending messages
    will not come any more (a keep-last reader dropped them), so they go too."""
    if pending and data in pending:
        while pending.popleft() != data:
            pass
        return True
    return False


class LocalSub:
    """One subscription on the bus; give :meth:`from_dds` to the DDS subscription."""

    __slots__ = ('bus', 'callback', 'owner', 'before_dds', 'pending', 'delivered', 'deferred',
                 'duplicates')

    def __init__(self, bus: 'LocalBus', callback: Callable[[bytes], None], before_dds: bool,
                 owner: Hashable) -> None:
        self.bus = bus
        self.callback = callback
        #: the node whose callbacks run one at a time (None given: the subscription alone)
        self.owner = self if owner is None else owner
        self.before_dds = before_dds  # delivered before the DDS write (else right after it)
        self.pending: deque[bytes] = deque(maxlen=KEEP)   # delivered locally, DDS copy not seen yet
        self.delivered = 0            # messages delivered through the bus
        self.deferred = 0             # of those, delivered after the callback of its node returned
        self.duplicates = 0           # DDS copies dropped

    def run(self, data: bytes) -> None:
        self.bus.call(self.owner, self.callback, data)

    def from_dds(self, data: bytes) -> None:
        """A message from DDS: dropped when it is the copy of one the bus delivered."""
        if take_copy(self.pending, data):
            self.duplicates += 1
            return
        self.run(data)


class LocalBus:
    """The bus of one composed process: its lock, its local subscriptions by topic, the deferred
    messages and the jobs for the loop's slack."""

    def __init__(self) -> None:
        #: held by every callback of the process's nodes and by the extra threads
        self.lock = threading.RLock()
        #: ident of the executor's thread; None until the composer starts spinning (bus off)
        self.thread: int | None = None
        #: idents of other threads that run callbacks holding the lock (the sample loop)
        self.extra_threads: set[int] = set()
        self.topics: dict[str, list[LocalSub]] = {}
        #: owner -> how many of its callbacks are on the stack
        self.busy: dict[Hashable, int] = {}
        self.depth = 0                # callbacks running through call() (nesting depth)
        #: messages for busy owners, delivered when the outermost callback returns
        self.deferred: deque[tuple[LocalSub, bytes]] = deque()
        #: work for the loop's slack (after()): one job each time an outermost callback returns
        self.slack: deque[Callable[[], None]] = deque()
        self.slack_jobs = 0           # jobs run in the slack

    def subscribe(self, topic: str, callback: Callable[[bytes], None], owner: Hashable = None,
                  before_dds: bool = True) -> LocalSub:
        """Register ``callback`` of node ``owner`` for ``topic``. ``before_dds``: called before
        the message is written to DDS (the shortest path), else right after it (the DDS readers
        of this process then get the message before anything the callback publishes)."""
        sub = LocalSub(self, callback, before_dds, owner)
        self.topics.setdefault(topic, []).append(sub)
        return sub

    def unsubscribe(self, topic: str, sub: LocalSub) -> None:
        subs = self.topics.get(topic, [])
        if sub in subs:
            subs.remove(sub)
        if not subs:
            self.topics.pop(topic, None)

    def local(self, topic: str) -> list[LocalSub]:
        """The subscriptions a publish on ``topic`` from this thread reaches through the bus."""
        if self.thread is None:
            return []
        subs = self.topics.get(topic)
        if not subs:
            return []
        ident = threading.get_ident()
        if ident != self.thread and ident not in self.extra_threads:
            return []
        return subs

    def publish(self, topic: str, data: bytes, dds_publish: Callable[[bytes], None]) -> None:
        """Deliver ``data`` to the local subscribers of ``topic`` (now, or deferred if their node
        is busy) and write it to DDS with ``dds_publish``: the ``before_dds`` subscribers first,
        then the DDS write, then the others."""
        subs = self.local(topic)
        if not subs:
            dds_publish(data)
            return
        try:
            for sub in subs:
                if sub.before_dds:
                    self._deliver(sub, data)
        finally:   # whatever a local callback did, the message goes out on DDS (recorded)
            dds_publish(data)
        for sub in subs:
            if not sub.before_dds:
                self._deliver(sub, data)

    def _deliver(self, sub: LocalSub, data: bytes) -> None:
        sub.pending.append(data)
        sub.delivered += 1
        if sub.owner in self.busy:
            sub.deferred += 1
            self.deferred.append((sub, data))
        else:
            sub.run(data)

    def call(self, owner: Hashable, fn: Callable, *args, **kwargs):
        """``fn(*args, **kwargs)`` as a callback of ``owner`` (its node), holding the lock: the
        node is busy meanwhile, so a message for it published meanwhile waits; when the outermost
        call returns, the messages deferred meanwhile are delivered, in order (and those they
        defer in turn), then one job of the slack runs."""
        with self.lock:
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
        deferred), on the same thread, holding the lock -- now if none runs. For work that must
        not run while a sample is on its way (:class:`rwpend_ros.nodes.SlackTimer`): in a
        composed process, after the whole chain of one sample. One job per outermost return; a
        job already waiting is not queued twice."""
        if not self.depth:
            with self.lock:
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

    def close(self) -> None:
        """Off, and no subscription (when the process's nodes are destroyed)."""
        self.thread = None
        self.extra_threads.clear()
        self.topics.clear()
        self.busy.clear()
        self.deferred.clear()
        self.slack.clear()
        self.depth = 0
