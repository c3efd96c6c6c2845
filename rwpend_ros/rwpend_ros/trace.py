"""Per-sample timing trace of the control loop, for profiling (``./rwpend bench --trace``).

Off unless ``RWPEND_TRACE`` names a directory: :func:`tracer` then returns a :class:`Trace`, else
None, so a node's hot path pays one ``if`` when tracing is off. Each node marks events of its
own with the sample's seq and ``time.monotonic_ns()`` (CLOCK_MONOTONIC: one clock for every
process of the host), and writes ``<dir>/<node>-<pid>.trace`` (text: ``event seq ns`` per line)
when it closes. :func:`load` and :func:`stages` (pure, no rclpy) put the files of one run back
together: per seq, the time of each event, and the time spent between consecutive events.

Events of the stack (in the order of one sample's path):

    sim.tick    the sample's ideal instant (real time: t0 + k h on the monotonic clock)
    sim.pub     the simulator starts publishing the encoder sample
    est.rx      the estimator's callback receives it
    est.pub     the estimator publishes the state
    ctl.rx      the controller's callback receives the state
    ctl.pub     the controller publishes the command
    sim.rx      the simulator's callback receives the command

and, in every traced process, ``gc.start`` / ``gc.stop`` (seq = the generation collected) around
each collection of Python's cyclic garbage collector.
"""
from __future__ import annotations

import os
import statistics
import time
from array import array
from pathlib import Path

ORDER = ('sim.tick', 'sim.pub', 'est.rx', 'est.pub', 'ctl.rx', 'ctl.pub', 'sim.rx')


class Trace:
    """Marks in memory (three flat arrays), written once by :meth:`dump`."""

    def __init__(self, directory: str | os.PathLike, node: str) -> None:
        self.path = Path(directory) / f'{node}-{os.getpid()}.trace'
        self.events: list[str] = []
        self._ids: dict[str, int] = {}
        self.ev = array('b')
        self.seq = array('q')
        self.ns = array('q')
        import gc
        gc.callbacks.append(self._gc)      # collections of the cyclic GC: gc.start / gc.stop

    def _gc(self, phase: str, info: dict) -> None:
        self('gc.' + phase, info.get('generation', -1))

    def __call__(self, event: str, seq: int, ns: int | None = None) -> None:
        i = self._ids.get(event)
        if i is None:
            i = self._ids[event] = len(self.events)
            self.events.append(event)
        self.ev.append(i)
        self.seq.append(int(seq))
        self.ns.append(time.monotonic_ns() if ns is None else int(ns))

    def dump(self) -> Path:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with open(self.path, 'w', encoding='ascii') as f:
            for e, s, t in zip(self.ev, self.seq, self.ns):
                f.write(f'{self.events[e]} {s} {t}\n')
        return self.path


def tracer(node: str, environ=None) -> Trace | None:
    """A Trace for ``node`` when ``RWPEND_TRACE`` is set, else None."""
    d = (os.environ if environ is None else environ).get('RWPEND_TRACE', '').strip()
    return Trace(d, node) if d else None


def load(directory: str | os.PathLike) -> dict[str, dict[int, int]]:
    """Every ``*.trace`` of a run: event -> {seq: ns} (the first mark of a seq wins)."""
    out: dict[str, dict[int, int]] = {}
    for p in sorted(Path(directory).glob('*.trace')):
        with open(p, encoding='ascii') as f:
            for line in f:
                parts = line.split()
                if len(parts) != 3:
                    continue
                d = out.setdefault(parts[0], {})
                d.setdefault(int(parts[1]), int(parts[2]))
    return out


def stages(marks: dict[str, dict[int, int]], order=ORDER, seqs=None) -> dict[str, list[float]]:
    """Microseconds between consecutive events of ``order`` (those present, sorted by when they
    happen: the median time after the first), per seq that has all of them, plus ``total``
    (first to last). ``seqs`` restricts the seqs considered."""
    present = [e for e in order if e in marks]
    if len(present) < 2:
        return {}
    common = set(marks[present[0]])
    for e in present[1:]:
        common &= set(marks[e])
    if seqs is not None:
        common &= set(seqs)
    if common:      # in the order they happen (in one loop the write comes before the publishing)
        first = marks[present[0]]
        present.sort(key=lambda e: statistics.median(marks[e][s] - first[s] for s in common))
    out: dict[str, list[float]] = {f'{a} -> {b}': [] for a, b in zip(present, present[1:])}
    out['total'] = []
    for s in sorted(common):
        for a, b in zip(present, present[1:]):
            out[f'{a} -> {b}'].append((marks[b][s] - marks[a][s]) / 1e3)
        out['total'].append((marks[present[-1]][s] - marks[present[0]][s]) / 1e3)
    return out
