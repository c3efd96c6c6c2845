"""How well the serial link keeps up: each sample's delay on the device's clock, and the link's
health over a window of its counters, with what to do about it. Pure: no rclpy, no I/O.

:class:`DelayMeter` measures how late the PC takes each sample. :func:`assess` compares two
snapshots of the link's counters (:meth:`rwpend_driver.link.DriverLink.counter_values`) and
returns the findings, each with a level (WARN, ERROR) and the advice the driver logs;
:class:`Throttle` keeps that log to one line per finding kind every ``interval`` s.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

OK, WARN, ERROR = 0, 1, 2
MASK32 = 0xFFFFFFFF

#: share of a window's samples lost, refused or late above which a finding is an ERROR
ERROR_SHARE = 0.01
#: share of a window's samples late above which lateness is a finding at all (WARN)
LATE_WARN_SHARE = 0.01
LATE_ERROR_SHARE = 0.10

ADVICE_KEEP_UP = ('the PC side does not keep the sample rate: run the stack with --rt-priority 50 '
                  'and --cpu-latency 0 (the emulator with --rt-priority 60), keep other load off '
                  'this PC, or use a longer sample period (the firmware\'s and the stack\'s: '
                  './rwpend emulate --h 0.002, ./rwpend up --h 0.002)')
ADVICE_WIRE = ('frames are corrupted on the way: check the cable and its connectors, and that the '
               'baud parameter matches the firmware')
ADVICE_DEVICE_READS = ('the device does not take what the driver sends: check that the firmware '
                       'runs (its watchdog stops the motor meanwhile)')
ADVICE_CONTROLLER = ('the controller answers too late: see its /diagnostics (stale states) and run '
                     'the stack with --rt-priority 50')


class DelayMeter:
    """How late the PC takes each sample, on the device's own clock.

    A SAMPLE carries ``time_us``, the device's clock when it was taken; ``rx - time_us`` is the
    offset between the two clocks plus the sample's delay (UART/USB transfer, the OS, the link
    thread). The smallest value seen is the offset plus the fastest transfer; a sample's delay
    is its value above that floor. The floor rises by ``drift_ppm`` of the device's time (a
    crystal drifts 20-100 ppm), so a device clock running slow is not taken for growing delay
    for long: a new, lower value resets it. :meth:`reset` at every (re)connection.
    """

    def __init__(self, drift_ppm: float = 200.0) -> None:
        if not 0.0 <= drift_ppm <= 10_000.0:
            raise ValueError(f'drift_ppm must be in [0, 10000], got {drift_ppm!r}')
        self.drift = drift_ppm * 1e-6
        self.reset()

    def reset(self) -> None:
        self.prev_raw: int | None = None
        self.dev_us = 0              # the device's clock, unwrapped (u32 microseconds wrap)
        self.floor: float | None = None
        self.floor_at = 0

    def delay_us(self, time_us: int, rx_us: float) -> float:
        """The delay of a sample stamped ``time_us`` (device) received at ``rx_us`` (PC)."""
        if self.prev_raw is not None:
            step = (time_us - self.prev_raw) & MASK32
            if step >= 0x80000000:     # the device's clock went back: a device restart
                self.reset()
            else:
                self.dev_us += step
        self.prev_raw = time_us
        offset = rx_us - self.dev_us
        floor = None if self.floor is None else self.floor + self.drift * (self.dev_us - self.floor_at)
        if floor is None or offset < floor:
            self.floor, self.floor_at, floor = offset, self.dev_us, offset
        return offset - floor


@dataclass(frozen=True)
class Finding:
    level: int          # WARN or ERROR
    kind: str           # 'lost', 'late', 'corrupt', 'refused', 'tx', 'watchdog', 'commands'
    what: str           # for /diagnostics and the log
    advice: str         # what to do (logged)


def _grown(before: Mapping, after: Mapping, key: str) -> int:
    return max(0, int(after.get(key, 0)) - int(before.get(key, 0)))


def _share_level(n: int, samples: int, error_share: float = ERROR_SHARE) -> int:
    return ERROR if n > error_share * max(samples, 1) else WARN


def assess(before: Mapping, after: Mapping, window_s: float, max_delay_ms: float = 0.0) -> list[Finding]:
    """Findings over the window between two counter snapshots (WARN or ERROR each; none: OK).
    ``max_delay_ms``: the largest sample delay in the window (DelayMeter)."""
    d = {k: _grown(before, after, k) for k in after if isinstance(after.get(k), int)}
    samples = d.get('samples', 0)
    w = f'in {window_s:.1f} s'
    out = []
    lost = d.get('samples_lost', 0)
    if lost or d.get('frames_lost', 0):
        out.append(Finding(_share_level(lost, samples), 'lost',
                           f'{lost} samples and {d.get("frames_lost", 0)} frames lost {w} (the device '
                           'dropped them: the driver did not read the port in time)', ADVICE_KEEP_UP))
    late = d.get('late_samples', 0)
    if late > LATE_WARN_SHARE * max(samples, 1):
        out.append(Finding(_share_level(late, samples, LATE_ERROR_SHARE), 'late',
                           f'{late} of {samples} samples taken more than one period late {w} '
                           f'(max {max_delay_ms:.1f} ms; {d.get("overruns", 0)} reads found a backlog)',
                           ADVICE_KEEP_UP))
    corrupt = sum(d.get(k, 0) for k in ('rx.bad_crc', 'rx.truncated', 'rx.bad_length', 'rx.unknown_type'))
    if corrupt:
        out.append(Finding(_share_level(corrupt, samples), 'corrupt',
                           f'{corrupt} corrupt frames from the device {w}', ADVICE_WIRE))
    refused = d.get('device_rx_bad', 0)
    if refused:
        out.append(Finding(_share_level(refused, samples), 'refused',
                           f'the device refused {refused} frames of the driver {w} (corrupted on the '
                           'way, or commands it could not take)', ADVICE_WIRE))
    tx = d.get('tx_dropped', 0)
    if tx:
        out.append(Finding(ERROR, 'tx', f'{tx} frames could not be written to the port {w}',
                           ADVICE_DEVICE_READS))
    if d.get('watchdog_trips', 0):
        out.append(Finding(WARN, 'watchdog', f'the device watchdog tripped {d["watchdog_trips"]} '
                                             f'time(s) {w}: motor at zero', ADVICE_CONTROLLER))
    old = d.get('old_commands', 0) + d.get('stale_commands', 0)
    if old:
        out.append(Finding(_share_level(old, samples, LATE_ERROR_SHARE), 'commands',
                           f'{old} commands refused as too old or superseded {w}', ADVICE_CONTROLLER))
    return out


def level_of(findings: list[Finding]) -> int:
    return max((f.level for f in findings), default=OK)


class Throttle:
    """One log line per finding kind at most every ``interval`` s (the first one at once)."""

    def __init__(self, interval: float = 10.0) -> None:
        self.interval = interval
        self.last: dict[str, float] = {}

    def due(self, findings: list[Finding], now: float) -> list[Finding]:
        out = []
        for f in findings:
            t = self.last.get(f.kind)
            if t is None or now - t >= self.interval:
                self.last[f.kind] = now
                out.append(f)
        return out


class Histogram:
    """Durations in fixed bins (``bin_ms`` wide, up to ``top_ms``; longer ones in the last bin,
    the maximum kept exactly), for percentiles of a long run in constant memory."""

    def __init__(self, bin_ms: float = 0.05, top_ms: float = 100.0) -> None:
        if not (bin_ms > 0 and top_ms > bin_ms):
            raise ValueError(f'need 0 < bin_ms < top_ms, got {bin_ms!r}, {top_ms!r}')
        self.bin = bin_ms
        self.bins = [0] * (int(round(top_ms / bin_ms)) + 1)
        self.n = 0
        self.max = 0.0

    def add(self, ms: float) -> None:
        self.bins[min(max(int(ms / self.bin), 0), len(self.bins) - 1)] += 1
        self.n += 1
        self.max = max(self.max, ms)

    def percentile(self, q: float) -> float:
        """The upper edge of the bin holding the q-th percentile (ms; 0 when empty)."""
        if not self.n:
            return 0.0
        need = q / 100.0 * self.n
        seen = 0
        for i, c in enumerate(self.bins):
            seen += c
            if seen >= need and c:
                return self.max if i == len(self.bins) - 1 else min((i + 1) * self.bin, self.max)
        return self.max

    def summary(self) -> dict:
        return {'n': self.n, 'p50_ms': round(self.percentile(50), 3), 'p99_ms': round(self.percentile(99), 3),
                'max_ms': round(self.max, 3)}
