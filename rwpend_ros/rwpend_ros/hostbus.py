"""Same-host fast path for the loop's wire bytes between PROCESSES (the counterpart of
:mod:`rwpend_ros.intra`, which works inside one process). Pure: sockets and threads, no rclpy
(the rclpy glue is :class:`rwpend_ros.common.LocalPublisher` / :func:`rwpend_ros.common.local_subscription`).

Why: a DDS hop between two processes of this host costs ~100-140 us p50 on the 2-core VM
(Fast DDS over the loopback, a receive thread woken, then the executor's thread), three of them
per sample; a datagram on a Unix socket read by a thread that runs the callback itself costs
~25 us (PERFORMANCE.md, 14.). So the publisher of a loop topic (encoders, state, command)
first sends the message as one datagram to every subscriber of the topic on this host, then
publishes it on DDS as before: the recorder and every other reader still get it through DDS,
and DDS stays the path whenever the fast one is missing (another host, another network
namespace, a full socket, a subscriber just started).

Addresses: an abstract Unix socket per subscription, named from (domain id, topic, subscriber
node's fully qualified name) by :func:`address`; the publisher learns the subscribers' node names
from the ROS graph. Nothing is created in the file system, nothing outlives its process.

Rules (what keeps it safe):

* the receiving thread runs the subscription's callback holding :data:`CALLBACK_LOCK`, the
  process-wide lock every other callback of our nodes holds too (``RwNode``), so a node's
  callbacks still run one at a time;
* every subscriber gets each message once and in the publisher's order: :class:`Merge`
  delivers a fast message only once the two paths have met (the DDS copy of the newest fast
  message arrived), drops the DDS copies of messages delivered fast, and goes back to DDS alone
  whenever DDS brings a message the fast path did not (a publisher that stopped sending fast,
  another publisher);
* a send that fails (receiver gone, its socket full) drops that receiver until the publisher
  looks at the graph again: the receiver gets everything through DDS meanwhile;
* the bytes sent are the bytes DDS delivers: a message is padded to a multiple of 4 bytes
  (:func:`pad4`) before it goes out either way (Fast DDS pads the serialized payload across
  processes, and the copies are matched byte for byte);
* keep-last subscriptions (the controller's ``state``) keep their depth on the fast path too:
  of a backlog only the newest ``depth`` are delivered;
* ``RWPEND_HOST_BUS=0`` turns it off (for comparisons).
"""
from __future__ import annotations

import errno
import hashlib
import os
import socket
import threading
from collections import deque
from typing import Callable, Iterable

from rwpend_ros.intra import take_copy

#: held by every callback of our nodes (executor thread) and by the receiving threads
CALLBACK_LOCK = threading.RLock()
#: fast-delivered messages per subscription whose DDS copy has not come yet
KEEP = 1024
#: largest message sent fast (the loop's messages are < 200 bytes); a bigger one goes by DDS
#: alone (Sender.send), so a receiver never reads a cut datagram
MAX_DATAGRAM = 65536


def enabled(env=None) -> bool:
    """``RWPEND_HOST_BUS``: 1 (or unset) = on, 0 = off; ValueError for anything else."""
    env = os.environ if env is None else env
    value = env.get('RWPEND_HOST_BUS', '1').strip() or '1'
    if value not in ('0', '1'):
        raise ValueError(f"RWPEND_HOST_BUS={env['RWPEND_HOST_BUS']!r}: expected 0 (off) or 1 (on)")
    return value == '1'


def address(domain_id: int, topic: str, node_fqn: str) -> bytes:
    """The abstract socket address of ``node_fqn``'s subscription to ``topic`` (fully
    qualified) in ROS domain ``domain_id``."""
    key = f'{int(domain_id)}\n{topic}\n{node_fqn}'.encode()
    return b'\0rwpend-hostbus-' + hashlib.sha1(key).hexdigest()[:32].encode()


def pad4(data: bytes) -> bytes:
    """``data`` padded with zeros to a multiple of 4 bytes, as a serialized payload arrives from
    another process (CDR's trailing padding)."""
    n = len(data) & 3
    return data + bytes(4 - n) if n else data


def node_fqn(namespace: str, name: str) -> str:
    """'/ns' + 'name' -> '/ns/name' ('/' + 'name' -> '/name')."""
    return namespace.rstrip('/') + '/' + name


#: addresses bound by this process: a publisher of this process does not send to them
#: (:mod:`rwpend_ros.intra` or DDS serves subscribers of its own process; a socket between two
#: threads of one process was measured and is slower, PERFORMANCE.md, 14.)
_LOCAL: set[bytes] = set()
_RECEIVERS: list['Receiver'] = []


class Merge:
    """Joins the two paths of one subscription into one stream: each message once, in order.

    ``from_fast`` / ``from_dds`` are called with :data:`CALLBACK_LOCK` held. Two modes:
    *syncing* (DDS delivers, fast messages are only remembered) and *fast* (fast delivers, DDS
    copies of those are dropped). Syncing -> fast when the DDS copy of the newest fast message
    arrives: DDS has then delivered everything up to it. Fast -> syncing when DDS brings a
    message the fast path did not deliver (it is delivered)."""

    __slots__ = ('deliver', 'fast_mode', 'pending', 'newest_fast', 'fast', 'dds', 'duplicates',
                 'skipped', 'resyncs')

    def __init__(self, deliver: Callable[[bytes], None]) -> None:
        self.deliver = deliver
        self.fast_mode = False
        self.pending: deque[bytes] = deque(maxlen=KEEP)
        self.newest_fast: bytes | None = None
        self.fast = 0          # delivered from the fast path
        self.dds = 0           # delivered from DDS
        self.duplicates = 0    # DDS copies dropped
        self.skipped = 0       # fast messages not delivered (keep-last depth)
        self.resyncs = 0       # fast -> syncing

    def from_fast(self, data: bytes, deliver: bool = True) -> None:
        """A message from the fast path; ``deliver=False``: taken but not delivered (an older
        message of a keep-last backlog; its DDS copy is dropped all the same)."""
        if not self.fast_mode:
            self.newest_fast = data
            return
        self.pending.append(data)
        if deliver:
            self.fast += 1
            self.deliver(data)
        else:
            self.skipped += 1

    def from_dds(self, data: bytes) -> None:
        if self.fast_mode:
            if take_copy(self.pending, data):
                self.duplicates += 1
                return
            self.fast_mode = False       # the fast path missed this one: DDS alone until they meet
            self.pending.clear()
            self.newest_fast = None
            self.resyncs += 1
        self.dds += 1
        self.deliver(data)
        if self.newest_fast is not None and data == self.newest_fast:
            self.fast_mode = True
            self.newest_fast = None

    def counters(self) -> dict[str, int]:
        return {'fast': self.fast, 'dds': self.dds, 'duplicates': self.duplicates,
                'skipped': self.skipped, 'resyncs': self.resyncs}


class Receiver:
    """The fast path's end in a subscriber: binds ``addr`` and starts a thread that hands each
    datagram to ``merge.from_fast`` holding :data:`CALLBACK_LOCK`. Of a backlog found when the
    lock is taken, only the newest ``depth`` are delivered. ``on_error(exc)`` gets an exception
    raised by the callback (the thread stops; DDS delivers from then on). OSError from ``bind``
    (address in use: two nodes of one name) propagates: no fast path then."""

    def __init__(self, addr: bytes, merge: Merge, depth: int,
                 on_error: Callable[[BaseException], None] | None = None,
                 on_start: Callable[[int], None] | None = None) -> None:
        self.addr = addr
        self.merge = merge
        self.depth = max(1, int(depth))
        self.on_error = on_error
        self.on_start = on_start
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        try:
            self.sock.bind(addr)
        except OSError:
            self.sock.close()
            raise
        _LOCAL.add(addr)
        _RECEIVERS.append(self)
        self.closed = False
        self.thread = threading.Thread(target=self._run, name='hostbus-rx', daemon=True)
        self.thread.start()

    def _run(self) -> None:
        raise_priority()
        if self.on_start is not None:
            self.on_start(threading.get_ident())
        sock, merge, depth = self.sock, self.merge, self.depth
        while True:
            try:
                first = sock.recv(MAX_DATAGRAM)
            except OSError:
                return               # closed
            with CALLBACK_LOCK:
                if self.closed:
                    return
                batch = [first]
                while True:          # what else came meanwhile
                    try:
                        batch.append(sock.recv(MAX_DATAGRAM, socket.MSG_DONTWAIT))
                    except OSError:
                        break
                try:
                    n_old = len(batch) - depth
                    for i, data in enumerate(batch):
                        merge.from_fast(data, deliver=i >= n_old)
                except BaseException as exc:  # noqa: BLE001 - reported like an executor callback's
                    self.closed = True
                    if self.on_error is not None:
                        self.on_error(exc)
                    return

    def close(self) -> None:
        with CALLBACK_LOCK:
            self.closed = True
        _LOCAL.discard(self.addr)
        try:
            self.sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        self.sock.close()
        if self in _RECEIVERS:
            _RECEIVERS.remove(self)


def raise_priority() -> None:
    """The calling thread one real-time priority above its process's when the process runs
    SCHED_FIFO / SCHED_RR (``--rt-priority``): a receiving thread then preempts the process's
    DDS threads, which carry only the DDS copies of what it delivers. Nothing otherwise.
    Measured: the share of messages DDS delivered first fell from 7-25 % to 1-9 % (lockstep,
    PERFORMANCE.md, 14.)."""
    try:
        policy = os.sched_getscheduler(0)
        if policy in (os.SCHED_FIFO, os.SCHED_RR):
            prio = os.sched_getparam(0).sched_priority
            if prio < os.sched_get_priority_max(policy):
                os.sched_setscheduler(0, policy, os.sched_param(prio + 1))
    except (OSError, AttributeError):    # not permitted / not Linux: the inherited priority
        pass


def close_all() -> None:
    """Close every receiver of this process (``run_nodes``, when its nodes are destroyed)."""
    for r in list(_RECEIVERS):
        r.close()


class Sender:
    """The fast path's start in a publisher: ``send`` writes the message to every target (one
    non-blocking datagram each). A target with no receiver bound (not on this host, not started
    yet, gone) is *absent*; one whose send failed otherwise (its socket full) is *dropped*;
    both get DDS alone until ``set_targets`` gives them again. Thread-safe for one sending
    thread next to the thread calling ``set_targets``."""

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.targets: tuple[bytes, ...] = ()
        self.sent = 0
        self.failed = 0          # sends that failed for another reason than an absent receiver
        self.dropped = False     # a target was dropped (failed) since the last set_targets
        self.too_big = 0         # messages over MAX_DATAGRAM, left to DDS

    def set_targets(self, addrs: Iterable[bytes]) -> None:
        self.targets = tuple(a for a in dict.fromkeys(addrs) if a not in _LOCAL)
        self.dropped = False

    def send(self, data: bytes) -> None:
        if len(data) > MAX_DATAGRAM:
            self.too_big += 1
            return
        for addr in self.targets:
            try:
                self.sock.sendto(data, socket.MSG_DONTWAIT, addr)
                self.sent += 1
            except OSError as exc:   # no such receiver (any more), its socket full, too big
                self.targets = tuple(a for a in self.targets if a != addr)
                if exc.errno not in (errno.ECONNREFUSED, errno.ENOENT):
                    self.failed += 1
                    self.dropped = True

    def close(self) -> None:
        self.targets = ()
        self.sock.close()
