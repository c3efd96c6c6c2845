"""Same-host fast path for the loop's wire bytes between PROCESSES (the counterpart of
:mod:`rwpend_ros.intra`, which works inside one process). Pure: sockets and threads, no rclpy
(the rclpy glue is :class:`rwpend_ros.common.LocalPublisher` / :func:`rwpend_ros.common.local_subscription`).

Why: a DDS hop between two processes of this host costs ~100-140 us p50 on the 2-core VM
(Fast DDS over the loopback, a receive thread woken, then the executor's thread), three of them
per sample; a datagram on a Unix socket read by a thread that runs the callback itself costs
~25 us (PERFORMANCE.md, 14.). So the publisher of a loop topic (encoders, state, command)
first sends the message as one datagram to every subscriber of the topic on this host, then
publishes it on DDS -- unless every subscriber DDS matched is one the datagram just reached
(*fast only*, PERFORMANCE.md 15.): any other reader (our recorder by default, a tool of a full
ROS install, a node on another host) gets every message through DDS, and DDS stays the path
whenever the fast one is missing (another host, another network namespace, a full socket, a
subscriber just started).

Addresses: an abstract Unix socket per subscription, named from (domain id, topic, subscriber
node's fully qualified name) by :func:`address`; the publisher learns the subscribers' node names
from the ROS graph. Nothing is created in the file system, nothing outlives its process. A
subscriber woken per message (a node of the loop) binds a datagram socket; a *polled* one (the
recorder, which drains now and then) listens on a SOCK_SEQPACKET socket and each publisher
connects to it: a datagram socket holds 10 messages (``net.unix.max_dgram_qlen``), a connection
as many as the publisher's send buffer (:data:`SEND_BUFFER`: ~250 loop messages with Debian's
default ``net.core.wmem_max``, thousands where it is higher).

Rules (what keeps it safe):

* the receiving thread runs the subscription's callback holding :data:`CALLBACK_LOCK`, the
  process-wide lock every other callback of our nodes holds too (``RwNode``), so a node's
  callbacks still run one at a time;
* every subscriber gets each message once and in the publisher's order: :class:`Merge`
  delivers a fast message only once the two paths have met (the DDS copy of the newest fast
  message arrived) or its *marker* (the publisher's last DDS write before it) has come, drops
  the DDS copies of messages delivered fast, and goes back to DDS alone whenever DDS brings a
  message the fast path did not (a publisher that stopped sending fast, another publisher);
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
import select
import socket
import struct
import threading
from collections import deque
from typing import Callable, Iterable

from rwpend_ros.intra import take_copy

#: held by every callback of our nodes (executor thread) and by the receiving threads
CALLBACK_LOCK = threading.RLock()
#: fast-delivered messages per subscription whose DDS copy has not come yet
KEEP = 1024
#: ... for a polled subscriber (the recorder): its DDS copies (a composed process writes some
#: topics to DDS for its own nodes) may lag far behind on a busy recorder; one older than this
#: would be taken for a new message
KEEP_POLLED = 8192
#: largest message sent fast (the loop's messages are < 200 bytes); a bigger one goes by DDS
#: alone (Sender.send), so a receiver never reads a cut datagram
MAX_DATAGRAM = 65536
#: send buffer (bytes) asked for a connection to a polled receiver (the kernel caps it at
#: ``net.core.wmem_max``): how much a recorder that runs behind can have waiting
SEND_BUFFER = 1 << 20
#: fast messages a :class:`Merge` holds at most while it waits for their marker (a polled
#: subscriber, the recorder, holds up to KEEP)
HOLD = 32
#: ... and seconds its receiving thread waits for the marker before it delivers them anyway
HOLD_S = 0.05


def enabled(env=None, name: str = 'RWPEND_HOST_BUS', default: str = '1') -> bool:
    """``RWPEND_HOST_BUS`` (or ``name``): 1 = on, 0 = off, unset or empty = ``default``;
    ValueError for anything else."""
    env = os.environ if env is None else env
    value = env.get(name, default).strip() or default
    if value not in ('0', '1'):
        raise ValueError(f"{name}={env[name]!r}: expected 0 (off) or 1 (on)")
    return value == '1'


def recorder_enabled(env=None) -> bool:
    """``RWPEND_RECORDER_FAST_PATH``: 1 or unset = the recorder takes the fast path too (with
    ``RWPEND_HOST_BUS``), 0 = it reads DDS only (rwpend_bag.recorder_node, PERFORMANCE.md 15.
    and 16.). Checks both variables: a bad value of either is a ValueError."""
    host = enabled(env)
    return enabled(env, 'RWPEND_RECORDER_FAST_PATH', '1') and host


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
#: SO_TIMESTAMPNS (Linux; not in Python's socket module): the kernel stamps a datagram with the
#: time it was queued to the socket
SO_TIMESTAMPNS = 35
_TIMESPEC = struct.Struct('@qq')
_CMSG_SPACE = socket.CMSG_SPACE(_TIMESPEC.size)
_STAMP = threading.local()
_STAMP.ns = 0


def delivery_stamp() -> int:
    """While a polled receiver's message is delivered (in the callback, on that thread): the
    time it arrived in the socket (ns since the epoch, CLOCK_REALTIME); while a DDS message of a
    subscription with ``dds_info`` is (:func:`rwpend_ros.common.local_subscription`): the time
    DDS received it; 0 otherwise (a thread receiver)."""
    return getattr(_STAMP, 'ns', 0)


def set_stamp(ns: int) -> int:
    """Set what :func:`delivery_stamp` returns on this thread; returns the previous value."""
    before = getattr(_STAMP, 'ns', 0)
    _STAMP.ns = ns
    return before
_RECEIVERS: list['Receiver'] = []


class Merge:
    """Joins the two paths of one subscription into one stream: each message once, in order.

    ``from_fast`` / ``from_dds`` are called with :data:`CALLBACK_LOCK` held. Two modes:
    *syncing* (DDS delivers, fast messages are only remembered) and *fast* (fast delivers, DDS
    copies of those are dropped). Syncing -> fast when the DDS copy of the newest fast message
    arrives: DDS has then delivered everything up to it. Fast -> syncing when DDS brings a
    message the fast path did not deliver (it is delivered).

    Every fast message carries ``marker``, the publisher's last message written to DDS before
    it (None: none yet). A *fast-only* message (not written to DDS: every subscriber of the
    topic takes the fast path, :meth:`Sender.send`) is delivered in syncing mode too. A fast
    message whose marker this subscription has not seen on either path (the publisher wrote a
    message to DDS alone: a send to this subscriber failed, or it was not a target yet) is
    *held*, with those after it, until DDS brings the marker (at most ``hold`` messages, and
    :data:`HOLD_S` s on a receiving thread: a marker DDS never brings -- a best-effort or
    keep-last reader lost it -- does not stop the stream). A marker that comes after all is
    delivered then, late: nothing is lost.

    A fast message DDS skipped is delivered from the fast path (counted ``recovered``), late
    rather than lost: when DDS brings a later one of those remembered while syncing, or when
    the held messages go without their marker. DDS skips messages written before the
    publisher's writer matched this subscription's reader (at start-up the graph, hence the
    fast path, can know a subscriber before DDS has matched it), and those a keep-last reader
    drops. (The fast copy of a message is always taken before its DDS copy: the publisher
    sends it first, and :meth:`from_dds` drains the socket first -- so one remembered and not
    brought by DDS before a later one was not brought at all.)"""

    __slots__ = ('deliver', 'hold', 'drain', 'fast_mode', 'pending', 'held', 'waiting', 'last_dds',
                 'accepted', 'fast', 'dds', 'duplicates', 'skipped', 'resyncs', 'recovered', 'keep', 'syncing',
                 'sync_set')

    def __init__(self, deliver: Callable[[bytes], None], hold: int = 0, keep: int = KEEP) -> None:
        self.deliver = deliver
        #: messages held at most (default :data:`HOLD`; a recorder, which can wait, holds more)
        self.hold = hold or HOLD
        #: takes what the fast path has brought and not handed over yet (Receiver.drain)
        self.drain: Callable[[], None] | None = None
        self.fast_mode = False
        self.pending: deque[bytes] = deque(maxlen=keep)
        #: syncing: the fast messages (data, deliver, stamp, marker) DDS has not brought yet, in
        #: order (at most ``keep``), and their bytes
        self.keep = keep
        self.syncing: deque[tuple[bytes, bool, int, bytes | None]] = deque()
        self.sync_set: set[bytes] = set()
        #: fast messages (data, deliver, stamp, marker) waiting for a marker
        self.held: list[tuple[bytes, bool, int, bytes | None]] = []
        self.waiting: bytes | None = None          # ... the marker
        self.last_dds: bytes | None = None         # the newest message DDS brought
        self.accepted: bytes | None = None         # the marker of the newest fast one delivered
        self.fast = 0          # delivered from the fast path
        self.dds = 0           # delivered from DDS
        self.duplicates = 0    # DDS copies dropped
        self.skipped = 0       # fast messages not delivered (keep-last depth)
        self.resyncs = 0       # fast -> syncing
        self.recovered = 0     # delivered from the fast path after DDS skipped them

    def from_fast(self, data: bytes, deliver: bool = True, fast_only: bool = False,
                  marker: bytes | None = None, stamp: int = 0) -> None:
        """A message from the fast path; ``deliver=False``: taken but not delivered (an older
        message of a keep-last backlog; its DDS copy is dropped all the same); ``fast_only``:
        not written to DDS; ``marker``: the publisher's last message written to DDS before it
        (None: none); ``stamp``: its arrival time (ns, :func:`delivery_stamp` while it is
        delivered; 0 = unknown)."""
        if self.held:
            self.held.append((data, deliver, stamp, marker))
            if len(self.held) >= self.hold:      # the marker is not coming
                self._flush(force=True)
            return
        if not self.fast_mode and not fast_only:
            self.syncing.append((data, deliver, stamp, marker))
            self.sync_set.add(data)
            if len(self.syncing) > self.keep:
                self.sync_set.discard(self.syncing.popleft()[0])
            return
        if not self._seen(marker):  # the publisher wrote a message to DDS alone that has not come yet
            self.held.append((data, deliver, stamp, marker))
            self.waiting = marker
            return
        if not self.fast_mode:
            self._to_fast_mode()                 # DDS brought all the publisher wrote to it
        self.accepted = marker
        self._take(data, deliver, stamp)

    def _to_fast_mode(self) -> None:
        self.fast_mode = True
        self.syncing.clear()
        self.sync_set.clear()

    @property
    def newest_fast(self) -> bytes | None:
        """Syncing: the newest fast message DDS has not brought yet (None: none)."""
        return self.syncing[-1][0] if self.syncing else None

    def _seen(self, marker: bytes | None) -> bool:
        """Whether this subscription has the message ``marker`` (from either path)."""
        return (marker is None or marker == self.accepted or marker == self.last_dds
                or (bool(self.pending) and (marker == self.pending[-1] or marker in self.pending)))

    def _take(self, data: bytes, deliver: bool, stamp: int = 0) -> None:
        self.pending.append(data)
        if deliver:
            self.fast += 1
            if not stamp:            # a receiving thread's message: no arrival time to hand on
                self.deliver(data)
                return
            before = set_stamp(stamp)
            try:
                self.deliver(data)
            finally:
                set_stamp(before)      # a DDS message being delivered keeps its own
        else:
            self.skipped += 1

    def flush_held(self) -> None:
        """Deliver the held messages without their marker (it did not come in time)."""
        if self.held:
            self._flush(force=True)

    def finish(self) -> None:
        """The subscriber stops (the recorder, after its last drain): DDS brings nothing more,
        so what is held or remembered while syncing is delivered now, in order."""
        if self.held:
            self._flush(force=True)
        else:
            self._recover(None)

    def _flush(self, force: bool = False) -> None:
        """Deliver the held messages up to the first whose marker has not come (``force``: all
        of them); -> fast mode. A marker that comes after all is delivered then: late, never
        lost."""
        held, self.held = self.held, []
        if force:                # the fast messages remembered while syncing come before them
            self._recover(None)
        self._to_fast_mode()
        self.waiting = None
        for i, (data, deliver, stamp, marker) in enumerate(held):
            if not force and i and not self._seen(marker):
                self.held = held[i:]         # another message went to DDS alone: wait for it
                self.waiting = marker
                return
            self.accepted = marker
            self._take(data, deliver, stamp)

    def from_dds(self, data: bytes) -> None:
        """A message from DDS. The fast path's datagrams waiting in the socket are taken first:
        the publisher sent them before it wrote ``data`` to DDS."""
        if self.drain is not None:
            self.drain()
        previous, self.last_dds = self.last_dds, data
        if self.held and data != self.waiting and any(h[0] == data for h in self.held):
            self._flush(force=True)      # DDS brought a held one: the marker is lost
            take_copy(self.pending, data)
            self.duplicates += 1
            return
        if take_copy(self.pending, data):    # a copy of one delivered fast (in either mode)
            self.duplicates += 1
            return
        if self.fast_mode:
            self.fast_mode = False       # the fast path missed this one: DDS alone until they meet
            self.resyncs += 1
        synced = data in self.sync_set
        if synced:                       # remembered while syncing: those before it DDS skipped
            self._recover(data)
        elif self.held and data == self.waiting:
            self._recover(None)          # the marker: every one remembered came before it
        elif self.syncing:
            self._recover_chain(previous)
        self.dds += 1
        self.deliver(data)
        if self.held:
            if data == self.waiting:
                self._flush()
        elif synced:
            self._sync()

    def _recover(self, upto: bytes | None) -> None:
        """Deliver the fast messages remembered while syncing that come before ``upto`` (None:
        all of them), which DDS skipped -- it brings ``upto`` now, or the held messages go without
        their marker -- and take ``upto`` off the list (DDS delivers it)."""
        while self.syncing:
            if self.syncing[0][0] == upto:
                self.sync_set.discard(self.syncing.popleft()[0])
                return
            self._recover_oldest()

    def _recover_chain(self, previous: bytes | None) -> None:
        """DDS brings, right after ``previous``, a message the fast path did not: the publisher
        wrote it to DDS alone. A remembered message whose marker is ``previous`` was written to
        DDS after ``previous`` and before it, so DDS skipped it: delivered now, before it, and so
        on down the chain (one whose marker is the message just recovered)."""
        while self.syncing and self.syncing[0][3] == previous:
            previous = self._recover_oldest()

    def _recover_oldest(self) -> bytes:
        """Deliver the oldest remembered message (DDS skipped it); returns it."""
        data, deliver, stamp, marker = self.syncing.popleft()
        self.sync_set.discard(data)
        self.recovered += deliver
        self.accepted = marker
        self._take(data, deliver, stamp)
        return data

    def _sync(self) -> None:
        """Syncing, DDS just delivered a message the fast path brought too (:meth:`_recover`
        took it and those before it off the list): DDS has delivered everything up to it, so
        the fast messages after it are delivered now (a slow DDS reader need not catch up with
        the newest one) and their DDS copies dropped; -> fast mode. One whose marker has not come
        (the publisher wrote a message to DDS alone in between) is held with those after it, as
        in :meth:`from_fast`."""
        rest = list(self.syncing)
        self._to_fast_mode()
        for j, (d, deliver, stamp, marker) in enumerate(rest):
            if not self._seen(marker):
                self.held = rest[j:]
                self.waiting = marker
                return
            self.accepted = marker
            self._take(d, deliver, stamp)

    def counters(self) -> dict[str, int]:
        return {'fast': self.fast, 'dds': self.dds, 'duplicates': self.duplicates,
                'skipped': self.skipped, 'resyncs': self.resyncs, 'recovered': self.recovered}


class Receiver:
    """The fast path's end in a subscriber: binds ``addr`` and starts a thread that hands each
    datagram to ``merge.from_fast`` holding :data:`CALLBACK_LOCK`. Of a backlog found when the
    lock is taken, only the newest ``depth`` are delivered. ``on_error(exc)`` gets an exception
    raised by the callback (the thread stops; DDS delivers from then on). OSError from ``bind``
    (address in use: two nodes of one name) propagates: no fast path then.

    ``polled``: no thread; the owner calls :meth:`drain` (holding the lock) now and then, and
    each message is delivered with the kernel's time of its arrival in the socket
    (:func:`delivery_stamp`) -- for a reader that needs the arrival times but not a wake-up per
    message (the recorder: PERFORMANCE.md, 15.). It listens on a SOCK_SEQPACKET socket, each
    publisher connects (:class:`Sender`): what waits for the drain is bounded by the
    publisher's send buffer (:data:`SEND_BUFFER`), not by ``net.unix.max_dgram_qlen`` (10 on
    Debian) as on a datagram socket; a send that finds it full goes to DDS instead."""

    def __init__(self, addr: bytes, merge: Merge, depth: int,
                 on_error: Callable[[BaseException], None] | None = None,
                 on_start: Callable[[int], None] | None = None, polled: bool = False) -> None:
        self.addr = addr
        self.merge = merge
        self.depth = max(1, int(depth))
        self.on_error = on_error
        self.on_start = on_start
        self.polled = polled
        #: polled: the publishers' connections, in the order they came
        self.conns: list[socket.socket] = []
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET if polled else socket.SOCK_DGRAM)
        try:
            self.sock.bind(addr)
            if polled:
                self.sock.listen(64)
                self.sock.setblocking(False)
        except OSError:
            self.sock.close()
            raise
        _LOCAL.add(addr)
        _RECEIVERS.append(self)
        self.closed = False
        self.malformed = 0       # datagrams that are not ours (ignored)
        merge.drain = self.drain
        self.thread = None
        if not polled:
            self.thread = threading.Thread(target=self._run, name='hostbus-rx', daemon=True)
            self.thread.start()

    def _run(self) -> None:
        raise_priority()
        if self.on_start is not None:
            self.on_start(threading.get_ident())
        poller = select.poll()
        poller.register(self.sock, select.POLLIN)
        merge = self.merge
        while True:
            # the datagrams stay in the socket until the lock is held: a DDS copy taken
            # meanwhile drains them first (Merge.from_dds), so nothing sent before it is behind it
            try:
                # only this thread fills merge.held: then wait for the marker HOLD_S at most
                events = poller.poll(HOLD_S * 1000 if merge.held else None)
            except OSError:
                return
            if any(ev & (select.POLLNVAL | select.POLLERR) for _, ev in events):
                return               # closed
            if not self._locked(self.drain if events else merge.flush_held):
                return

    def drain(self) -> int:
        """Hand every datagram waiting in the socket to the merge (the lock held); of more
        than ``depth``, the older ones are taken without being delivered (keep-last). Returns
        how many there were."""
        batch = []
        sock = self.sock
        if self.polled:
            self._drain_connections(batch)
        else:
            try:
                while True:
                    batch.append((sock.recv(MAX_DATAGRAM, socket.MSG_DONTWAIT), 0))
            except OSError:
                pass
        n_old = len(batch) - self.depth
        for i, (datagram, stamp) in enumerate(batch):
            message = unpack(datagram)
            if message is None:
                self.malformed += 1
                continue
            data, fast_only, marker = message
            self.merge.from_fast(data, i >= n_old, fast_only, marker, stamp)
        return len(batch)

    def _drain_connections(self, batch: list) -> None:
        """Polled: accept the new connections, then take what each holds, with its arrival
        time (a message sent before its connection was accepted has none: 0)."""
        while True:
            try:
                conn, _ = self.sock.accept()
            except OSError:          # none waiting (or closed)
                break
            conn.setblocking(False)
            try:
                conn.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
            except OSError:
                pass
            self.conns.append(conn)
        for conn in list(self.conns):
            while True:
                try:
                    data, anc, _, _ = conn.recvmsg(MAX_DATAGRAM, _CMSG_SPACE)
                except BlockingIOError:
                    break
                except OSError:      # reset by the publisher
                    data = b''
                if not data:         # the publisher closed it (a message is never empty)
                    self.conns.remove(conn)
                    conn.close()
                    break
                stamp = 0
                for level, kind, value in anc:
                    if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS and len(value) >= 16:
                        sec, nsec = _TIMESPEC.unpack_from(value)
                        stamp = sec * 1_000_000_000 + nsec
                batch.append((data, stamp))

    def _locked(self, fn, *args) -> bool:
        """``fn(*args)`` holding the lock; False when the thread must end (closed, or the
        callback raised: reported to ``on_error``, DDS delivers from then on)."""
        with CALLBACK_LOCK:
            if self.closed:
                return False
            try:
                fn(*args)
            except BaseException as exc:  # noqa: BLE001 - reported like an executor callback's
                if self.on_error is not None:
                    self.on_error(exc)
                self.close()     # senders find it gone: DDS alone from then on
                return False
        return True

    def close(self) -> None:
        with CALLBACK_LOCK:
            self.closed = True
        _LOCAL.discard(self.addr)
        try:
            self.sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        self.sock.close()
        for conn in self.conns:
            conn.close()
        self.conns = []
        if self in _RECEIVERS:
            _RECEIVERS.remove(self)


def pack(data: bytes, fast_only: bool = False, marker: bytes | None = None) -> bytes:
    """The datagram of ``data``: a first byte, bit 0 = fast only (not written to DDS), bit 1 =
    a marker follows (the publisher's last message written to DDS before this one: its length
    in 4 bytes little-endian, then its bytes); then the message."""
    kind = (1 if fast_only else 0) | (0 if marker is None else 2)
    if marker is None:
        return bytes((kind,)) + data
    return bytes((kind,)) + len(marker).to_bytes(4, 'little') + marker + data


def unpack(datagram: bytes) -> tuple[bytes, bool, bytes | None] | None:
    """(message, fast_only, marker) of a datagram of :func:`pack`; None if it is not one."""
    if not datagram or datagram[0] > 3:
        return None
    kind = datagram[0]
    if not kind & 2:
        return datagram[1:], bool(kind & 1), None
    if len(datagram) >= 5:
        n = int.from_bytes(datagram[1:5], 'little')
        if 5 + n <= len(datagram):
            return datagram[5 + n:], bool(kind & 1), datagram[5:5 + n]
    return None


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
    non-blocking datagram each; to a polled receiver, on a connection ``set_targets`` opened).
    A target with no receiver bound (not on this host, not started yet, gone) is *absent*; one
    whose send failed otherwise (its socket full) is *dropped*; both get DDS alone until
    ``set_targets`` gives them again. Thread-safe for one sending thread next to the thread
    calling ``set_targets``."""

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        #: connections to polled receivers (SOCK_SEQPACKET), by address; replaced as a whole
        #: by set_targets, a broken one only closed by send
        self.conns: dict[bytes, socket.socket] = {}
        self.targets: tuple[bytes, ...] = ()
        self.sent = 0
        self.failed = 0          # sends that failed for another reason than an absent receiver
        self.dropped = False     # a target was dropped (failed) since the last set_targets
        self.too_big = 0         # messages over MAX_DATAGRAM, left to DDS
        #: the newest message written to DDS (the marker of the fast-only ones after it)
        self.marker: bytes | None = None
        #: the targets changed since the last DDS write: the next message goes to DDS too
        self.fresh = True

    def set_targets(self, addrs: Iterable[bytes]) -> None:
        targets = tuple(a for a in dict.fromkeys(addrs) if a not in _LOCAL)
        conns = {}
        for addr in targets:     # a polled receiver listens: connect (once) to it
            conn = self.conns.get(addr)
            conns[addr] = conn if conn is not None and conn.fileno() != -1 else _connect(addr)
        self.conns = {a: c for a, c in conns.items() if c is not None}
        if targets != self.targets:
            self.fresh = True
        self.targets = targets
        self.dropped = False

    def send(self, data: bytes, fast_only: bool = False, marker: bytes | None = None) -> bool:
        """Send ``data`` to every target; ``fast_only``: it will not be written to DDS,
        ``marker`` is the last message that was. True when every target got it (a target whose
        send fails is gone from ``targets``)."""
        datagram = pack(data, fast_only, marker)
        if len(datagram) > MAX_DATAGRAM:
            self.too_big += 1
            return False
        ok = bool(self.targets)
        conns = self.conns
        for addr in self.targets:
            conn = conns.get(addr)
            try:
                if conn is None:
                    self.sock.sendto(datagram, socket.MSG_DONTWAIT, addr)
                else:
                    conn.send(datagram, socket.MSG_DONTWAIT | socket.MSG_NOSIGNAL)
                self.sent += 1
            except OSError as exc:   # no such receiver (any more), its socket full
                ok = False
                self.targets = tuple(a for a in self.targets if a != addr)
                if exc.errno in _GONE:
                    if conn is not None:
                        conn.close()     # set_targets connects again if it comes back
                else:
                    self.failed += 1
                    self.dropped = True
        return ok

    def close(self) -> None:
        self.targets = ()
        self.sock.close()
        for conn in self.conns.values():
            conn.close()
        self.conns = {}


#: errors of a send to a receiver that is not there (any more); EAGAIN (full) is not one
_GONE = frozenset({errno.ECONNREFUSED, errno.ENOENT, errno.ECONNRESET, errno.EPIPE, errno.ENOTCONN,
                   errno.EBADF})


def _connect(addr: bytes) -> socket.socket | None:
    """A connection to the polled receiver at ``addr`` (SOCK_SEQPACKET, non-blocking, with
    :data:`SEND_BUFFER`); None when none listens there (absent, or a datagram receiver)."""
    conn = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
    try:
        conn.setblocking(False)
        conn.connect(addr)
    except OSError:
        conn.close()
        return None
    try:
        conn.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, SEND_BUFFER)
    except OSError:
        pass
    return conn
