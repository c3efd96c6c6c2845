"""The order gate of a loop subscription: a node never takes a message older than one it already
took on the same topic, nor the same message twice. Pure: no rclpy.

Every message of the loop (EncoderCounts, StateEstimate, MotorCommand, PlantState) carries the
``seq`` of its sample and a header stamp. DDS (reliable, one writer) already delivers a writer's
messages once and in order; the gate makes that a guarantee of every subscription whatever the
path (DDS, a replayed bag, two publishers on one topic by mistake, a plant that restarted) and
counts what it stopped, for ``/diagnostics``::

    gate = OrderGate()
    if gate.admit(seq, stamp_ns):
        ...take the message...

Rules, for a message (seq, stamp) after the last one taken (last_seq, last_stamp):

* ``seq > last_seq`` and a stamp not older: taken; ``seq > last_seq + 1`` counts a gap
  (``missing`` += the seqs between);
* ``seq == last_seq`` and the same stamp: a duplicate, dropped;
* ``seq <= last_seq`` and a newer stamp, or anything after :data:`RESTART_SILENCE` s without a
  message taken: the publisher started again (a restarted simulator or driver counts from 0; on the wall
  clock its stamps are newer; a lockstep simulator's stamps start again at 0 too, but a restart
  takes a new process, seconds of silence): taken, counted as a restart;
* otherwise (an older seq or an older stamp, no silence): stale, dropped -- e.g. a late copy of
  a message of the publisher's previous run, whose seq may be higher than the new run's.

(seq, stamp) alone cannot tell a restarted lockstep run from a late copy of its first messages
(same seq, same stamp, same bytes); the silence does. A copy delayed by more than the silence
would be taken as a restart -- one message -- and the stream goes on from the next one.
"""
from __future__ import annotations

import time

#: s without a message taken after which a lower seq is a new run of the publisher
RESTART_SILENCE = 0.5


class OrderGate:
    """Per-subscription order and duplicate filter (see the module doc)."""

    __slots__ = ('last_seq', 'last_stamp', 'last_time', 'taken', 'duplicates', 'stale', 'restarts',
                 'gaps', 'missing')

    def __init__(self) -> None:
        self.last_seq: int | None = None
        self.last_stamp = 0
        self.last_time = 0.0  # monotonic s when the last message was taken
        self.taken = 0
        self.duplicates = 0   # the same message again
        self.stale = 0        # older than the last one taken
        self.restarts = 0     # the publisher counted from 0 again / newer stamps with a lower seq
        self.gaps = 0         # times seq jumped forward by more than one
        self.missing = 0      # seqs skipped by those jumps

    def admit(self, seq: int, stamp_ns: int, now: float | None = None) -> bool:
        """True when the message (``seq``, header stamp in ns; ``now``: monotonic s, default the
        clock's) is to be taken."""
        now = time.monotonic() if now is None else now
        last = self.last_seq
        if last is not None:
            if seq == last and stamp_ns == self.last_stamp:
                self.duplicates += 1
                return False
            newer_seq, newer_stamp = seq > last, stamp_ns > self.last_stamp
            if newer_seq and (newer_stamp or stamp_ns == self.last_stamp):
                if seq > last + 1:
                    self.gaps += 1
                    self.missing += seq - last - 1
            elif (not newer_seq and newer_stamp) or now - self.last_time >= RESTART_SILENCE:
                self.restarts += 1
            else:
                self.stale += 1
                return False
        self.last_seq = seq
        self.last_stamp = stamp_ns
        self.last_time = now
        self.taken += 1
        return True

    def counters(self) -> dict[str, int]:
        return {'taken': self.taken, 'duplicates': self.duplicates, 'stale': self.stale,
                'restarts': self.restarts, 'gaps': self.gaps, 'missing': self.missing}

    def summary(self) -> str:
        """One line for /diagnostics."""
        return (f'taken {self.taken}, duplicates {self.duplicates}, stale {self.stale}, '
                f'restarts {self.restarts}, gaps {self.gaps} ({self.missing} missing)')


class SourceGates:
    """Order gates per sender, for a topic whose messages say who sent them (``MotorCommand``'s
    ``controller_id``): two controllers on one rig answer the same samples with the same seq
    and stamp, so one gate for the topic would take whichever came first and drop the other as
    a duplicate -- the plant could not tell them apart. With a gate per sender each sender's
    stream is taken once and in order, and the plant decides whom to obey
    (:class:`rwpend_ros.claim.CommandClaim`). At most ``max_sources`` gates are kept (the least
    recently heard sender's goes first), so a stream of made-up ids cannot grow it."""

    def __init__(self, max_sources: int = 8) -> None:
        if max_sources < 1:
            raise ValueError('max_sources must be >= 1')
        self.max_sources = max_sources
        self.gates: dict[int, OrderGate] = {}
        self.evicted = 0          # gates dropped to keep max_sources
        self.retired = {k: 0 for k in OrderGate().counters()}   # their counts, kept in the sums

    def admit(self, source: int, seq: int, stamp_ns: int, now: float | None = None) -> bool:
        """:meth:`OrderGate.admit` of ``source``'s gate."""
        gate = self.gates.pop(source, None)
        if gate is None:
            gate = OrderGate()
            if len(self.gates) >= self.max_sources:
                old = self.gates.pop(next(iter(self.gates)))
                for k, v in old.counters().items():
                    self.retired[k] += v
                self.evicted += 1
        self.gates[source] = gate             # most recently heard last
        return gate.admit(seq, stamp_ns, now)

    def counters(self) -> dict[str, int]:
        total = dict(self.retired)
        for gate in self.gates.values():
            for k, v in gate.counters().items():
                total[k] += v
        return total

    def summary(self) -> str:
        """One line for /diagnostics: the sums over the senders, and how many there were."""
        c = self.counters()
        text = (f"taken {c['taken']}, duplicates {c['duplicates']}, stale {c['stale']}, "
                f"restarts {c['restarts']}, gaps {c['gaps']} ({c['missing']} missing)")
        if len(self.gates) > 1 or self.evicted:
            text += f', senders {len(self.gates)}' + (f' (+{self.evicted} forgotten)' if self.evicted else '')
        return text
