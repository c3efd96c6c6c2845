"""Log times of a bag and the order its messages are written in. Pure (no rclpy).

**The rule.** MCAP itself allows Message records in any order (readers offer "log-time order"
reading: sorted by ``log_time``, ties in file order). What tools check, and what rwpend
guarantees, is the stricter rule of ``mcap doctor --strict-message-order``: in file order,
every message's ``log_time`` is >= the greatest ``log_time`` before it in the file (equal
log times are allowed), across all channels and chunks. rosbag2 Jazzy's MCAP plugin writes the
messages in the order its subscription callbacks hand them over, each with the middleware's
receive time (``node->now()`` with ``use_sim_time``), and does not reorder: its files are in
log-time order only as far as the callbacks come in that order. rwpend's writer enforces it.

* :class:`LogTimeGuard` -- applied by :class:`rwpend_bag.writer.BagWriter` to every message,
  whatever its caller gives: a message older than the last one written gets the last log time,
  counted per topic (and reported in ``recording_report.json``). Its own time stays in the
  MCAP ``publish_time``.
* :class:`ArrivalOrder` -- real time: the log time is the time the recorder took the message
  (its callback), in the order taken.
* :class:`SimTimeOrder` -- lockstep: log times on the simulated clock and a deterministic
  order, through a bounded reorder buffer (below).

**Lockstep log time** (:class:`SimTimeOrder`): a message whose type starts with a
``std_msgs/Header`` is logged at its ``header.stamp``; ``/clock`` (rosgraph_msgs/Clock) at its
value; any other message (``/rosout``, ``/parameter_events``: their stamps are not on the
simulated clock) at the newest ``/clock`` value taken so far. A header stamp more than
:data:`OFF_CLOCK_NS` ahead of the newest ``/clock`` (a node stamping wall time) is not sim
time: such a message is logged at the newest ``/clock`` too, counted ``off_clock``.

**Lockstep order**: messages are written sorted by (log time, topic name, arrival index within
the topic). A message is held until ``hold_clocks`` newer ``/clock`` values have been taken
after its log time -- the simulated time has passed it -- then released; the buffer holds at
most ``max_held`` messages (the smallest is released early beyond that, counted ``forced``).
A message that arrives after messages that sort after it were written (its log time <= the
released bound) is *late*: written at once, at max(its log time, the last written), counted
``late`` with how late it was. With nothing late or forced, the order depends only on the
messages and their stamps, not on when the recorder's callbacks ran, so two lockstep runs
that publish the same messages give the same order (see :mod:`rwpend_bag.sameness`).
Why it holds: in lockstep the simulator publishes sample k+1 (and its ``/clock``) only once
command k has come, so every loop message of sample k is published before ``/clock`` of
sample k+1; and a reliable keep-last publisher that keeps d messages, publishing one every n
samples, has dropped a message (a seq gap, reported) rather than delivering it once it is
n x d samples old (and the recorder's executor takes its subscriptions in turn, so what waits
in its own queues does not fall that far behind ``/clock`` either). The loop topics' publishers keep 100 (``QOS_CONTROL_PUB``,
``QOS_STATUS``): 100 samples for the per-sample topics, 1 000 for ``controller/status`` (every
10th sample), hence :data:`HOLD_CLOCKS`. Not covered (counted ``late``, never silent): a
sample the simulator ran on without its command (``lockstep_timeout``: the run itself is then
not reproducible, and the simulator counts ``late_commands``), ``controller/status`` every
more than 10 samples repaired after more than 1 000, and the non-loop topics (``/diagnostics``
has three publishers, not ordered among themselves).
"""
from __future__ import annotations

import heapq
import struct
from collections import deque
from dataclasses import dataclass
from typing import NamedTuple

from rwpend_ros.wire import unpack_clock_ns

from . import cdr

#: stamp kinds of a topic's type
STAMP_NONE = 'none'      # no Header: logged at the newest sim time
STAMP_HEADER = 'header'  # starts with std_msgs/Header: logged at header.stamp
STAMP_CLOCK = 'clock'    # rosgraph_msgs/msg/Clock: logged at its value, advances sim time

CLOCK_TYPE = 'rosgraph_msgs/msg/Clock'
#: /clock values (newer than the message's log time) taken before a held message is written
HOLD_CLOCKS = 1000
#: messages held at most (normally ~hold_clocks x topics: ~6 000 for the loop's 7 topics)
MAX_HELD = 50_000
#: a header stamp further ahead of the newest /clock than this is not on the simulated clock
OFF_CLOCK_NS = 60 * 1_000_000_000


def stamp_kind(type_name: str, schema_text: str) -> str:
    """How a topic of this type is logged in lockstep: STAMP_CLOCK, STAMP_HEADER or STAMP_NONE."""
    if type_name == CLOCK_TYPE:
        return STAMP_CLOCK
    return STAMP_HEADER if cdr.starts_with_header(type_name, schema_text) else STAMP_NONE


def leading_time_ns(data: bytes) -> int | None:
    """The builtin_interfaces/Time at the start of a CDR message (a Header's stamp, a Clock's
    value; either byte order, by the encapsulation's low bit) in ns
    (:func:`rwpend_ros.wire.unpack_clock_ns`); None when the bytes are too short or the time is
    negative."""
    try:
        return unpack_clock_ns(data)
    except (struct.error, ValueError):
        return None


class Entry(NamedTuple):
    """One message as it is to be written."""
    topic: str
    data: bytes
    log_ns: int
    publish_ns: int


class LogTimeGuard:
    """Non-decreasing log times in file order: :meth:`admit` returns the log time to write."""

    def __init__(self) -> None:
        self.last_ns: int | None = None
        self.raised: dict[str, int] = {}
        self.max_raise_ns: dict[str, int] = {}

    def admit(self, topic: str, log_ns: int) -> int:
        log_ns = int(log_ns)
        if self.last_ns is not None and log_ns < self.last_ns:
            self.raised[topic] = self.raised.get(topic, 0) + 1
            self.max_raise_ns[topic] = max(self.max_raise_ns.get(topic, 0), self.last_ns - log_ns)
            return self.last_ns
        self.last_ns = log_ns
        return log_ns

    def report(self) -> dict:
        return {'rule': 'log times non-decreasing in file order (mcap doctor --strict-message-order)',
                'raised': sum(self.raised.values()),
                'topics': {t: {'raised': n, 'max_raise_ns': self.max_raise_ns[t]}
                           for t, n in sorted(self.raised.items())}}


class ArrivalOrder:
    """Real time: each message logged at the time the recorder took it, in the order taken."""

    mode = 'receive'

    def add_topic(self, topic: str, kind: str) -> None:
        pass

    def push(self, topic: str, data: bytes, arrival_ns: int) -> list[Entry]:
        return [Entry(topic, data, int(arrival_ns), int(arrival_ns))]

    def flush(self) -> list[Entry]:
        return []

    def report(self) -> dict:
        return {'log_time': 'receive time (wall clock, when the recorder took the message)'}


@dataclass
class _TopicCounts:
    kind: str
    from_stamp: int = 0
    from_clock: int = 0
    at_sim_time: int = 0      # no stamp (or unreadable): the newest /clock
    off_clock: int = 0        # stamp too far ahead of /clock: the newest /clock
    late: int = 0
    max_late_ns: int = 0
    forced: int = 0
    index: int = 0            # arrivals so far (the order key within the topic)

    def summary(self) -> dict:
        d = {'stamp': self.kind, 'from_stamp': self.from_stamp, 'from_clock': self.from_clock,
             'at_sim_time': self.at_sim_time}
        for k in ('off_clock', 'late', 'max_late_ns', 'forced'):
            if getattr(self, k):
                d[k] = getattr(self, k)
        return d


class SimTimeOrder:
    """Lockstep: log times on the simulated clock, written in (log time, topic, arrival) order
    through a bounded reorder buffer (module docstring).

    Held messages are kept per log time (a sim time is shared by all the loop's topics of a
    sample), the log times in a heap: one heap operation per sample, not per message."""

    mode = 'sim'

    def __init__(self, hold_clocks: int = HOLD_CLOCKS, max_held: int = MAX_HELD,
                 off_clock_ns: int = OFF_CLOCK_NS) -> None:
        if hold_clocks < 1 or max_held < 1:
            raise ValueError('hold_clocks and max_held must be >= 1')
        self.hold_clocks = int(hold_clocks)
        self.max_held = int(max_held)
        self.off_clock_ns = int(off_clock_ns)
        self._topics: dict[str, _TopicCounts] = {}
        self._times: list[int] = []                                  # heap of held log times
        self._buckets: dict[int, list[tuple[str, int, bytes]]] = {}  # log time: (topic, index, data)
        self._clocks: deque[int] = deque(maxlen=self.hold_clocks + 1)
        self.held = 0
        self.sim_ns = 0               # newest /clock value (0 before the first)
        self.bound_ns = -1            # order final up to here: a message logged <= it is late
        self.last_ns = -1             # log time of the last message released
        self.peak_held = 0

    def add_topic(self, topic: str, kind: str) -> None:
        self._topics.setdefault(topic, _TopicCounts(kind))

    def push(self, topic: str, data: bytes, arrival_ns: int = 0) -> list[Entry]:
        """Take one message (in the order the recorder took them); returns what can be written
        now, in order. ``arrival_ns`` is not used: the order must not depend on it."""
        c = self._topics.get(topic)
        if c is None:
            c = self._topics[topic] = _TopicCounts(STAMP_NONE)
        kind = c.kind
        t = leading_time_ns(data) if kind != STAMP_NONE else None
        ticked = False
        if t is None:
            c.at_sim_time += 1
            t = self.sim_ns
        elif kind == STAMP_CLOCK:
            c.from_clock += 1
            if t > self.sim_ns or not self._clocks:
                self.sim_ns = t
                self._clocks.append(t)
                ticked = True
        elif t > self.sim_ns + self.off_clock_ns:
            c.off_clock += 1
            t = self.sim_ns
        else:
            c.from_stamp += 1
        index = c.index
        c.index = index + 1
        out: list[Entry] = []
        if t <= self.bound_ns:
            c.late += 1
            if self.bound_ns - t > c.max_late_ns:
                c.max_late_ns = self.bound_ns - t
            out.append(self._emit(topic, data, t))
        else:
            bucket = self._buckets.get(t)
            if bucket is None:
                self._buckets[t] = [(topic, index, data)]
                heapq.heappush(self._times, t)
            else:
                bucket.append((topic, index, data))
            self.held += 1
            if self.held > self.peak_held:
                self.peak_held = self.held
        if ticked and len(self._clocks) == self._clocks.maxlen:
            self._release(self._clocks[0], out)
        while self.held > self.max_held:
            t0 = self._times[0]
            for topic0, _, _ in self._buckets[t0]:
                self._topics[topic0].forced += 1
            self._release(t0, out)
        return out

    def _emit(self, topic: str, data: bytes, t: int) -> Entry:
        """A message written at once: at max(its log time, the last written)."""
        if t < self.last_ns:
            return Entry(topic, data, self.last_ns, t)
        self.last_ns = t
        return Entry(topic, data, t, t)

    def _release(self, bound_ns: int, out: list[Entry]) -> None:
        times, buckets = self._times, self._buckets
        while times and times[0] <= bound_ns:
            t = heapq.heappop(times)
            bucket = buckets.pop(t)
            bucket.sort()                 # (topic, index): unique, the data never compared
            self.held -= len(bucket)
            out.extend(Entry(topic, data, t, t) for topic, _, data in bucket)
            self.last_ns = t
        if bound_ns > self.bound_ns:
            self.bound_ns = bound_ns

    def flush(self) -> list[Entry]:
        """Everything still held, in order (at the end of the recording)."""
        out: list[Entry] = []
        if self._times:
            self._release(max(self._times), out)
        return out

    def report(self) -> dict:
        topics = {t: c.summary() for t, c in sorted(self._topics.items())}
        late = sum(c.late for c in self._topics.values())
        forced = sum(c.forced for c in self._topics.values())
        off = sum(c.off_clock for c in self._topics.values())
        return {'log_time': 'sim time (header stamp; /clock value; else the newest /clock)',
                'order': '(log time, topic, arrival within topic), held for '
                         f'{self.hold_clocks} /clock values',
                'hold_clocks': self.hold_clocks, 'max_held': self.max_held,
                'peak_held': self.peak_held, 'late': late, 'forced': forced, 'off_clock': off,
                'deterministic_order': late == 0 and forced == 0, 'topics': topics}


def describe(log_times: dict) -> list[str]:
    """Lines for the recorder's report from ``recording_report.json``'s ``log_times``: what the
    log times are, and every message whose log time or place had to be changed."""
    lines = []
    written = log_times.get('written', {})
    if 'hold_clocks' in log_times:
        det = log_times.get('deterministic_order')
        lines.append(f"log times: sim time, {'deterministic' if det else 'NOT deterministic'} order "
                     f"(late {log_times['late']}, forced {log_times['forced']}, "
                     f"peak {log_times['peak_held']} held)")
        for topic, c in log_times.get('topics', {}).items():
            if c.get('late'):
                lines.append(f"  LATE: {topic}: {c['late']} message(s) came after later ones were "
                             f"written (up to {c['max_late_ns'] / 1e6:.3f} ms of sim time): written "
                             'at once, out of the deterministic order')
            if c.get('forced'):
                lines.append(f"  FORCED: {topic}: {c['forced']} message(s) written before the sim "
                             f"time passed them (more than {log_times['max_held']} held)")
            if c.get('off_clock'):
                lines.append(f"  OFF CLOCK: {topic}: {c['off_clock']} header stamp(s) not on the "
                             'simulated clock: logged at the newest /clock')
    else:
        lines.append('log times: receive time')
    if written.get('raised'):
        for topic, c in written.get('topics', {}).items():
            lines.append(f"  RAISED: {topic}: {c['raised']} message(s) older than the message "
                         f"before them, written at its log time (up to {c['max_raise_ns'] / 1e6:.3f} "
                         'ms; own time kept as publish_time)')
    return lines
