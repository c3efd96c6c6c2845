"""Decimation on the console's side of the wire: the loop publishes at 1 kHz (h = 1 ms), a page
or a Foxglove panel needs a few tens of samples per second.

* :class:`Decimator` keeps at most one sample per period of the samples' own time (their header
  stamps: sim time in lockstep, the wall clock in real time), the first at or after each multiple
  of the period, so the kept samples lie on a regular grid whatever the arrival jitter.
* :class:`RateLimiter` keeps at most ``rate_hz`` messages per second of the receiver's clock, in
  short bursts (the bridge: any topic, stamped or not).

Both are pure (no rclpy): the nodes give them the times.
"""
from __future__ import annotations

#: a stamp this much older than the newest kept one means a new run (a restarted simulator,
#: a replayed bag): the decimator starts again instead of waiting for time to catch up
RESTART_NS = 1_000_000_000


class Decimator:
    """At most one sample per ``1 / rate_hz`` s of sample time (``admit`` says which)."""

    def __init__(self, rate_hz: float) -> None:
        if not (isinstance(rate_hz, (int, float)) and 0 < rate_hz <= 1e6):
            raise ValueError(f'decimation rate must be in (0, 1e6] Hz, got {rate_hz!r}')
        self.period_ns = max(1, int(round(1e9 / rate_hz)))
        self.next_ns: int | None = None   # the grid point the next kept sample must reach
        self.last_ns = 0                  # stamp of the newest kept sample
        self.seen = 0
        self.kept = 0

    def admit(self, stamp_ns: int) -> bool:
        """True when the sample stamped ``stamp_ns`` is to be kept."""
        self.seen += 1
        restart = self.next_ns is not None and stamp_ns < self.last_ns - RESTART_NS
        if self.next_ns is not None and stamp_ns < self.next_ns and not restart:
            return False
        self.next_ns = (stamp_ns // self.period_ns + 1) * self.period_ns
        self.last_ns = stamp_ns
        self.kept += 1
        return True


class RateLimiter:
    """At most ``rate_hz`` messages per second of the receiver's clock on average, in bursts of
    up to ``burst`` (a token bucket): a 1 kHz topic comes down to ``rate_hz``, while the
    once-a-second messages of several publishers on one topic (``/diagnostics``) all pass.
    ``rate_hz`` 0: every message."""

    def __init__(self, rate_hz: float, burst: int = 1) -> None:
        if not (isinstance(rate_hz, (int, float)) and 0 <= rate_hz <= 1e6):
            raise ValueError(f'rate must be in [0, 1e6] Hz (0 = every message), got {rate_hz!r}')
        if not (isinstance(burst, int) and burst >= 1):
            raise ValueError(f'burst must be an integer >= 1, got {burst!r}')
        self.rate_hz = float(rate_hz)
        self.burst = burst
        self.tokens = float(burst)
        self.last_ns: int | None = None
        self.passed = 0
        self.dropped = 0

    def admit(self, now_ns: int) -> bool:
        if self.rate_hz:
            if self.last_ns is not None:
                self.tokens = min(self.burst, self.tokens + max(0, now_ns - self.last_ns) * 1e-9 * self.rate_hz)
            self.last_ns = now_ns
            if self.tokens < 1.0:
                self.dropped += 1
                return False
            self.tokens -= 1.0
        self.passed += 1
        return True
