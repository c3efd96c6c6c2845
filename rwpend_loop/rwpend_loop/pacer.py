"""The real-time pacer: sample k at t0 + k h on the monotonic clock (absolute deadlines: a late
sample does not shift the ones after it). Pure (no rclpy); the clock and the sleep are given,
so the pacing is tested on a fake clock.

    pacer = Pacer(period_ns=1_000_000)
    pacer.run(lambda k: loop.step(behind=pacer.behind) is not None, stop)   # in the loop thread

A sample whose work ends after the next instant is *late* (:meth:`behind` tells the loop while
it computes, so the plant holds the previous command over that interval, as a rig would); the
pacer then goes on with the next sample at once and counts an overrun when it starts more than
one period after its instant. Samples are never skipped: the simulated plant advances one
interval per sample, so a loop that falls behind catches up back to back.
"""
from __future__ import annotations

import threading
import time
from typing import Callable


class Pacer:
    def __init__(self, period_ns: int, clock_ns: Callable[[], int] = time.monotonic_ns,
                 sleep: Callable[[float], None] = time.sleep) -> None:
        if isinstance(period_ns, bool) or not isinstance(period_ns, int) or period_ns <= 0:
            raise ValueError(f'period_ns must be a positive integer, got {period_ns!r}')
        self.period_ns = period_ns
        self.clock_ns = clock_ns
        self.sleep = sleep
        self.t0 = 0
        self.k = 0                # the sample being served
        self.overruns = 0         # samples started more than one period after their instant
        self.max_lag_ns = 0       # the largest start lag seen

    def deadline(self, k: int) -> int:
        """The instant of sample k (monotonic ns)."""
        return self.t0 + k * self.period_ns

    def behind(self) -> bool:
        """The instant of the sample after the one being served has passed."""
        return self.clock_ns() >= self.t0 + (self.k + 1) * self.period_ns

    def run(self, tick: Callable[[int], bool], stop: threading.Event, t0_ns: int | None = None) -> int:
        """Call ``tick(k)`` at each instant until it returns False or ``stop`` is set; returns
        the samples served. ``t0_ns``: the instant of sample 0 (default: now)."""
        self.t0 = self.clock_ns() if t0_ns is None else t0_ns
        k = 0
        while not stop.is_set():
            self.k = k
            lag = self.clock_ns() - self.deadline(k)
            if lag > self.max_lag_ns:
                self.max_lag_ns = lag
            if lag > self.period_ns:
                self.overruns += 1
            if not tick(k):
                break
            k += 1
            delay = self.deadline(k) - self.clock_ns()
            if delay > 0:
                self.sleep(delay / 1e9)
        return k
