"""Detecting the student's manual steps on the rig from the encoder data (pure numpy, no rclpy).

Each detector takes the recent pendulum and motor counts (newest last) and the rig, and says
whether the step asked by a :class:`rwpend_lab.experiment.Prompt` has been done.  The names are
those of ``Prompt.detect``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def _angles(rig, pc, mc):
    dl = rig.count_angle
    pc, mc = np.asarray(pc, float), np.asarray(mc, float)
    return pc * dl, (pc + mc) * dl


def held_at(rig, pc, mc, angle: float, tol: float, still_s: float) -> bool:
    """The pendulum held still (within 2 counts) for ``still_s`` at ``angle`` +- ``tol`` (rad)."""
    n = int(round(still_s / rig.sample_period))
    if len(pc) < n:
        return False
    th, _ = _angles(rig, pc[-n:], mc[-n:])
    return bool(np.ptp(pc[-n:]) <= 2 and abs(abs(np.mean(th)) - angle) <= tol)


def released(rig, pc, mc, counts: int = 5) -> bool:
    """The pendulum moves: its count changed by more than ``counts`` within the last 50 ms."""
    n = int(round(0.05 / rig.sample_period))
    return len(pc) >= n and bool(np.ptp(pc[-n:]) > counts)


def still(rig, pc, mc, still_s: float) -> bool:
    """Neither encoder moved by more than one count for ``still_s``."""
    n = int(round(still_s / rig.sample_period))
    return len(pc) >= n and bool(np.ptp(pc[-n:]) <= 1 and np.ptp(np.asarray(pc[-n:]) + mc[-n:]) <= 1)


def upright(rig, pc, mc, tol: float) -> bool:
    """The pendulum within ``tol`` rad of upright (theta = pi from hanging)."""
    th, _ = _angles(rig, pc[-1:], mc[-1:])
    return bool(abs(np.remainder(th[0], 2 * np.pi) - np.pi) <= tol)


def spun(rig, pc, mc, speed: float) -> bool:
    """The wheel turns at about ``speed`` rad/s (half of it or more) over the last 20 ms."""
    n = int(round(0.02 / rig.sample_period))
    if len(mc) < n:
        return False
    w = (mc[-1] - mc[-n]) * rig.count_angle / ((n - 1) * rig.sample_period)
    return bool(abs(w) >= 0.5 * speed)


def bracket(rig, pc, mc, still_s: float = 1.0) -> bool:
    """Chapter 3 configuration: the pendulum encoder does not move (the pendulum is locked)."""
    n = int(round(still_s / rig.sample_period))
    return len(pc) >= n and bool(np.ptp(pc[-n:]) == 0)


def tap(rig, pc, mc, counts: int = 3) -> bool:
    """A tap: the pendulum count jumps by more than ``counts`` within 20 ms."""
    n = int(round(0.02 / rig.sample_period))
    return len(pc) >= n and bool(np.ptp(pc[-n:]) > counts)


def torque(rig, pc, mc, counts: int = 2, window_s: float = 1.0) -> bool:
    """A steady torque: the pendulum leans by more than ``counts`` on average over ``window_s``."""
    n = int(round(window_s / rig.sample_period))
    if len(pc) < n:
        return False
    x = np.remainder(np.asarray(pc[-n:]) * rig.count_angle, 2 * np.pi) - np.pi
    return bool(abs(np.mean(x)) > counts * rig.count_angle)


DETECTORS = {f.__name__: f for f in (held_at, released, still, upright, spun, bracket, tap, torque)}


# ----------------------------------------------------------------------------- the live sequence
@dataclass(frozen=True)
class StepEvent:
    """What :class:`StepSequence` asks the runner to do: ``show`` a prompt (``text``), a prompt
    was ``detected``, ``arm`` the controller (switch it to the run's mode), the run is ``done``,
    or a prompt ``timeout`` (``text`` says which)."""

    kind: str
    seq: int
    index: int = -1
    text: str = ''


class StepSequence:
    """The manual steps of one rig run, judged live from the encoder samples (pure: no rclpy).

    Samples come in with :meth:`feed` (device seq, pendulum and motor counts).  Prompt i is shown
    ``prompt.wait_s`` after the previous event (the start, or prompt i-1 detected) and detected by
    its detector of :data:`DETECTORS`; after ``arm_after`` prompts the controller is armed (0: it
    runs the run's mode from the start, nothing to arm).  The run's time origin is its last event
    less that event's time in the simulator run (``prompt.at``; 0 for the arm): a tap the
    simulator gives at 2 s and the student gives now puts the origin 2 s back.  The run is done
    ``duration`` s of samples after the origin.  Time is counted in samples (seq), not wall time.
    Detectors run every ``check_every`` samples on the last ``window_s`` s; samples the monitor
    missed (up to 0.2 s of them) count with the counts of the sample before them, so that every
    window is a span of time; duplicates and older samples are ignored.  The run ends
    ``tail_s`` after that, so that an origin refined from the bag (the first command of an armed
    law, :func:`rwpend_lab.data.trim`) still has ``duration`` s behind it."""

    def __init__(self, rig, prompts, arm_after: int, duration: float, timeout_s: float = 120.0,
                 window_s: float = 2.0, check_every: int = 5, tail_s: float = 0.5) -> None:
        from collections import deque
        self.rig, self.prompts, self.h = rig, list(prompts), float(rig.sample_period)
        if not 0 <= arm_after <= len(self.prompts):
            raise ValueError(f'arm_after must be in 0..{len(self.prompts)}, got {arm_after}')
        for p in self.prompts:
            if p.detect not in DETECTORS:
                raise ValueError(f'unknown detector {p.detect!r} (one of {", ".join(DETECTORS)})')
        self.arm_after = arm_after
        self.duration_n = int(round((duration + tail_s) / self.h))
        self.timeout_n = int(round(timeout_s / self.h))
        self.check_every = max(1, int(check_every))
        n = int(round(window_s / self.h))
        self.pc: deque = deque(maxlen=n)
        self.mc: deque = deque(maxlen=n)
        self.next = 0                  # index of the prompt to show / detect
        self.shown_at: int | None = None
        self.last_event: int | None = None
        self.armed_at: int | None = None
        self.detected: list[int] = []  # seq of each prompt's detection
        self.origin: int | None = None
        self.end: int | None = None
        self.finished = False
        self.failed = ''
        self._since_check = 0
        self._last_seq: int | None = None
        self.max_fill = int(round(0.2 / self.h))

    def _wait_n(self, i: int) -> int:
        return int(round(float(getattr(self.prompts[i], 'wait_s', 0.0)) / self.h))

    def feed(self, seq: int, pc: int, mc: int) -> list[StepEvent]:
        """One sample; the events it causes, in order."""
        if self.finished:
            return []
        last = self._last_seq
        if last is not None and seq <= last:
            return []                   # a duplicate or an old sample: already judged
        self._last_seq = seq
        gap = 0 if last is None else seq - last - 1
        if gap > self.max_fill:
            self.pc.clear()             # a long outage: judged again on fresh samples
            self.mc.clear()
        elif gap > 0 and self.pc:
            # samples this monitor did not get: the last counts held, so a window is a time span
            self.pc.extend([self.pc[-1]] * gap)
            self.mc.extend([self.mc[-1]] * gap)
        self.pc.append(pc)
        self.mc.append(mc)
        out: list[StepEvent] = []
        if self.last_event is None:
            self.last_event = seq
            if self.arm_after == 0 and not self.prompts:
                self._set_origin(seq, 0.0)
        if self.origin is None and self.next < len(self.prompts):
            p = self.prompts[self.next]
            if self.shown_at is None:
                if seq >= self.last_event + self._wait_n(self.next):
                    self.shown_at = seq
                    self.pc.clear()        # judged on samples from the prompt on
                    self.mc.clear()
                    self.pc.append(pc)
                    self.mc.append(mc)
                    out.append(StepEvent('show', seq, self.next, p.text))
                return out
            self._since_check += 1
            if self._since_check >= self.check_every:
                self._since_check = 0
                if DETECTORS[p.detect](self.rig, list(self.pc), list(self.mc), **dict(p.args)):
                    self.detected.append(seq)
                    self.last_event = seq
                    out.append(StepEvent('detected', seq, self.next, p.text))
                    self.next += 1
                    self.shown_at = None
                    if self.next == self.arm_after:
                        self.armed_at = seq
                        out.append(StepEvent('arm', seq, self.next - 1))
                    if self.next == len(self.prompts):
                        at = 0.0 if self.arm_after == len(self.prompts) else float(getattr(p, 'at', 0.0))
                        self._set_origin(seq, at)
                    return out
            if seq - self.shown_at > self.timeout_n:
                self.finished = True
                self.failed = (f'not detected within {self.timeout_n * self.h:g} s: "{p.text}" '
                               f'({p.detect})')
                out.append(StepEvent('timeout', seq, self.next, self.failed))
            return out
        if self.end is not None and seq >= self.end:
            self.finished = True
            out.append(StepEvent('done', seq))
        return out

    def _set_origin(self, seq: int, at: float) -> None:
        self.origin = seq - int(round(at / self.h))
        self.end = self.origin + self.duration_n
