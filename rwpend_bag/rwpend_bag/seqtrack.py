"""Per-topic ``seq`` tracking (messages whose first field after the Header is ``uint64 seq``)."""
from __future__ import annotations

from . import cdr, msgdefs

MAX_GAPS_LISTED = 50


class TopicSeq:
    __slots__ = ('received', 'first', 'last', 'lo', 'hi', 'gaps', 'missing', 'duplicates',
                 'out_of_order', 'tracks', 'steps')

    def __init__(self, tracks: bool):
        self.tracks = tracks
        self.received = 0
        self.first = self.last = self.lo = self.hi = None
        self.gaps: list[tuple[int, int]] = []
        self.missing = 0
        self.duplicates = 0
        self.out_of_order = 0
        self.steps: dict[int, int] = {}

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
            self.out_of_order += 1  # restart of the publisher, or reordering
        self.last = s
        self.lo = min(self.lo, s)
        self.hi = max(self.hi, s)

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
                 out_of_order=self.out_of_order)
        if self.missing == 0 and self.duplicates == 0 and self.out_of_order == 0:
            d['text'] = (f'recorded {self.received} of {expected} (no gaps), '
                         f'seq {self.first}..{self.last}')
        else:
            gaps = ', '.join(f'{a}' if a == b else f'{a}..{b}' for a, b in self.gaps[:10])
            more = ' ...' if len(self.gaps) > 10 else ''
            d['text'] = (f'recorded {self.received} of {expected}, seq {self.first}..{self.last}: '
                         f'missed {self.missing} in {len(self.gaps)} gap(s) [{gaps}{more}]'
                         + (f', {self.duplicates} duplicate(s)' if self.duplicates else '')
                         + (f', {self.out_of_order} out of order' if self.out_of_order else ''))
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
