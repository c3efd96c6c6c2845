"""Per-topic ``seq`` tracking (messages whose first field after the Header is ``uint64 seq``)."""
from __future__ import annotations

from bisect import bisect_right

from . import cdr, msgdefs

MAX_GAPS_LISTED = 50


class TopicSeq:
    """Seq accounting of one topic. A seq below the newest is *out of order*: one that falls
    in a gap of the publisher's current run (since its seq last went back) fills it -- it
    came late, it is not missing -- and the newest stays the newest; any other (a restart of
    the publisher, a duplicate of an old one) starts a new run from it."""
    __slots__ = ('received', 'first', 'last', 'lo', 'hi', 'gaps', 'missing', 'duplicates',
                 'out_of_order', 'tracks', 'steps', 'run_start', 'late')

    def __init__(self, tracks: bool):
        self.tracks = tracks
        self.received = 0
        self.first = self.last = self.lo = self.hi = None
        self.gaps: list[tuple[int, int]] = []
        self.missing = 0
        self.duplicates = 0
        self.out_of_order = 0
        self.late = 0            # out of order, filled a gap
        self.steps: dict[int, int] = {}
        self.run_start = 0       # index in gaps of the current run's first gap

    def add_seq(self, s: int) -> None:
        self.received += 1
        if self.last is None:
            self.first = self.lo = self.hi = s
        elif s == self.last + 1:
            pass
        elif s > self.last + 1:
            if len(self.steps) < 64 or s - self.last in self.steps:
                self.steps[s - self.last] = self.steps.get(s - self.last, 0) + 1
            self.gaps.append((self.last + 1, s - 1))
            self.missing += s - self.last - 1
        elif s == self.last:
            self.duplicates += 1
        else:
            self.out_of_order += 1
            if self._fill(s):
                self.late += 1
                return               # came late: the newest stays the newest
            self.run_start = len(self.gaps)   # restart of the publisher (or an old duplicate)
        self.last = s
        self.lo = min(self.lo, s)
        self.hi = max(self.hi, s)

    def _fill(self, s: int) -> bool:
        """``s`` (below the newest) is in a gap of the current run: the gap shrinks or splits,
        one less missing. False when it is in none."""
        gaps = self.gaps
        i = bisect_right(gaps, (s, float('inf')), lo=self.run_start) - 1
        if i < self.run_start or not gaps[i][0] <= s <= gaps[i][1]:
            return False
        a, b = gaps[i]
        gaps[i:i + 1] = [g for g in ((a, s - 1), (s + 1, b)) if g[0] <= g[1]]
        self.missing -= 1
        return True

    def summary(self) -> dict:
        d = {'received': self.received}
        if not self.tracks or self.first is None:
            d['seq'] = None
            d['text'] = f'recorded {self.received} (no seq field)'
            return d
        stride = max(self.steps, key=self.steps.get) if self.steps else 1
        if stride > 1 and self.steps[stride] * 2 > self.received:
            # a sub-sampled stream (e.g. controller/status every N samples): seq steps are by design
            d.update(seq={'first': self.first, 'last': self.last, 'min': self.lo, 'max': self.hi},
                     stride=stride, missing=None, duplicates=self.duplicates, out_of_order=self.out_of_order)
            d['text'] = (f'recorded {self.received}, seq {self.first}..{self.last} every {stride} '
                         f'samples (sub-sampled topic: seq steps not counted as losses)')
            return d
        expected = self.received + self.missing - self.duplicates
        d.update(seq={'first': self.first, 'last': self.last, 'min': self.lo, 'max': self.hi},
                 missing=self.missing, gaps=[list(g) for g in self.gaps[:MAX_GAPS_LISTED]],
                 gap_count=len(self.gaps), duplicates=self.duplicates,
                 out_of_order=self.out_of_order, late=self.late)
        if self.missing == 0 and self.duplicates == 0 and self.out_of_order == 0:
            d['text'] = (f'recorded {self.received} of {expected} (no gaps), '
                         f'seq {self.first}..{self.last}')
        else:
            gaps = ', '.join(f'{a}' if a == b else f'{a}..{b}' for a, b in self.gaps[:10])
            more = ' ...' if len(self.gaps) > 10 else ''
            restarts = self.out_of_order - self.late
            d['text'] = (f'recorded {self.received} of {expected}, seq {self.first}..{self.last}: '
                         + (f'missed {self.missing} in {len(self.gaps)} gap(s) [{gaps}{more}]'
                            if self.missing else 'no gaps')
                         + (f', {self.duplicates} duplicate(s)' if self.duplicates else '')
                         + (f', {self.late} came late (out of order)' if self.late else '')
                         + (f', {restarts} went back (publisher restarted?)' if restarts else ''))
        return d


class SeqTracker:
    """Feed raw CDR bytes per topic; ``report()`` gives counts, seq ranges and gaps."""

    def __init__(self):
        self.topics: dict[str, TopicSeq] = {}

    def register(self, topic: str, type_name: str, definition: str | None = None) -> None:
        if topic in self.topics:
            return
        try:
            text = definition or msgdefs.joined_definition(type_name)
            tracks = cdr.header_seq_layout(msgdefs.full_type(type_name), text)
        except Exception:  # noqa: BLE001 - unknown definition: count only
            tracks = False
        self.topics[topic] = TopicSeq(tracks)

    def add(self, topic: str, data: bytes) -> None:
        t = self.topics.get(topic)
        if t is None:
            t = self.topics[topic] = TopicSeq(False)
        if t.tracks:
            s = cdr.seq_of(data)
            if s is not None:
                t.add_seq(s)
                return
        t.received += 1

    def add_seq_array(self, topic: str, seqs) -> None:
        t = self.topics.setdefault(topic, TopicSeq(True))
        for s in seqs:
            t.add_seq(int(s))

    def report(self) -> dict[str, dict]:
        return {name: t.summary() for name, t in sorted(self.topics.items())}
