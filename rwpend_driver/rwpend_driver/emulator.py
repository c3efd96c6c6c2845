"""Device emulator: the rig's microcontroller on a pseudo-terminal, driving the plant model in real time.

    ./rwpend emulate [--link PATH] [--h S] [--watchdog-ms N] [--theta RAD] [--rig FILE] [--hand] [--json]
                     [--status-period S] [--rt-priority N]

Opens a pty (os.openpty), prints the slave device path (and makes PATH a symlink to it with
``--link``), then every h sends one SAMPLE frame and applies the latest valid COMMAND with
zero-order hold.  The device logic is the rig's firmware itself: the portable core of
``firmware/core`` (C99, the code the STM32 board runs) built for this PC and called through
ctypes (:mod:`rwpend_driver.firmware`); this module is its HAL -- the pty its UART, the plant
model (:class:`rwpend_model.plant.Plant`) its motor and encoders, the sample clock this loop.
The ready, status and exit lines name the firmware's version (``fw``).

Signals emulate the cable: SIGUSR1 = unplug (the pty is closed, the link removed; the device
keeps running, so its watchdog zeroes the motor), SIGUSR2 = replug (a new pty, the link
re-pointed).  SIGINT/SIGTERM stop it.  With ``--json`` every output line is a JSON event.
``--rig FILE``: the emulated rig's physical truth (default the shipped rig.yaml).  ``--hand``: lines
on stdin are a hand on the pendulum -- ``steady [S]`` holds it still hanging, ``lift DEG [S]``
holds it still at DEG degrees (180: upright), for S seconds (default 0: one sample), then lets
go; ``tap DV`` taps it (theta' += DV rad/s) -- what the student does in ``./rwpend identify``
and ``./rwpend lab run N --plant serial:``; each is applied from the next sample instant.

What it could not do in time is counted and printed in every status line (``--status-period``)
and at exit: ``overruns`` (sample instants served more than h late: the OS did not run the
emulator in time; ``stalls`` episodes, ``max_late_ms``), ``dropped_tx`` (bytes a host with the
port open did not take: the PC side does not keep up), ``unheard_tx`` (bytes sent while no host
had the port open: they go nowhere, as on a UART with nothing connected), and the device's own
``rx_bad`` (frames it refused: ``refused`` of them well-formed but not acceptable), its
``watchdog_trips`` and ``hold_expired`` (commands zeroed by the hold limit: too old to drive the
motor). A host opening or closing the port is an event (``host``). ``cmd_latency``
(p50/p99/max) is the whole PC side's loop as the device sees it: from a SAMPLE sent to the
first command answering it; ``late_commands`` came after the next SAMPLE had gone out.
"""
from __future__ import annotations

import argparse
import errno
import json
import math
import os
import queue
import select
import signal
import sys
import threading
import time
import tty
from dataclasses import dataclass
from typing import Optional

from rwpend_model.plant import Plant
from rwpend_model.rig import load_rig, load_rig_file
from rwpend_ros.trace import tracer

from . import protocol as P
from .firmware import FirmwareCore, FirmwareError
from .link_health import Histogram


class Pty:
    """One 'cable': a pty pair. The emulator holds the master only, so it can tell whether a host
    has the port (the slave) open: the master then polls without POLLHUP. Bytes sent while no
    host has it open go nowhere, as on a UART with nothing connected."""

    def __init__(self, link: Optional[str]) -> None:
        self.master, slave = os.openpty()
        tty.setraw(slave)                  # kept by the pty while the master is open
        self.path = os.ttyname(slave)
        os.close(slave)
        os.set_blocking(self.master, False)
        self.poller = select.poll()
        self.poller.register(self.master, select.POLLIN)
        self.link = link
        if link:
            tmp = f'{link}.tmp{os.getpid()}'
            try:
                os.unlink(tmp)
            except FileNotFoundError:
                pass
            os.symlink(self.path, tmp)
            os.replace(tmp, link)          # atomic: the path never points nowhere

    def poll(self, timeout: float) -> int:
        """The master's events after at most ``timeout`` s (0: none). The wait is select()'s,
        to the microsecond: poll() counts whole milliseconds, rounded up, so a wait for the
        next sample instant 0.3 ms away lasted 1 ms -- the SAMPLE went out 0.7 ms late and the
        answer to it came after the next instant (16 % of the samples through the emulator)."""
        try:
            if timeout > 0:
                select.select([self.master], [], [], timeout)   # readable on data and on hang-up
            ev = self.poller.poll(0)
        except InterruptedError:
            return 0
        return ev[0][1] if ev else 0

    def host_present(self) -> bool:
        """A host has the port open (no hang-up on the master)."""
        return not self.poll(0.0) & select.POLLHUP

    def close(self) -> None:
        if self.link:
            try:
                if os.path.islink(self.link) and os.readlink(self.link) == self.path:
                    os.unlink(self.link)
            except OSError:
                pass
        try:
            os.close(self.master)
        except OSError:
            pass


def parse_args(argv):
    ap = argparse.ArgumentParser(prog='rwpend emulate', description=__doc__.split('\n\n')[0])
    ap.add_argument('--link', help='create this symlink to the pty slave (replaced atomically)')
    ap.add_argument('--watchdog-ms', type=int, default=P.DEFAULT_WATCHDOG_MS,
                    help=f'initial watchdog period, ms ({P.WATCHDOG_MIN_MS}..{P.WATCHDOG_MAX_MS}; '
                         'the host sets it with SET_WATCHDOG)')
    ap.add_argument('--theta', type=float, default=0.0, help='initial pendulum angle (rad from hanging)')
    ap.add_argument('--rig', default=None, help="the emulated rig's physical truth, a complete rig file "
                    '(default: the shipped rwpend_model/config/rig.yaml)')
    ap.add_argument('--hand', action='store_true', help='read hand actions from stdin: "steady [S]" (hold the '
                    'pendulum still hanging for S s, let go), "lift DEG [S]" (hold it at DEG degrees for S s, '
                    'let go), "tap DV" (theta\' += DV rad/s)')
    ap.add_argument('--duration', type=float, default=0.0, help='stop after S seconds (0 = run until stopped)')
    ap.add_argument('--status-period', type=float, default=0.0, help='print a status line every S s (0 = off)')
    ap.add_argument('--json', action='store_true', help='print JSON lines (events) instead of text')
    ap.add_argument('--unplug-after', type=float, default=0.0, help='unplug S seconds after start (test aid)')
    ap.add_argument('--replug-after', type=float, default=0.0,
                    help='replug S seconds after an unplug (test aid)')
    ap.add_argument('--h', type=float, default=None, metavar='S',
                    help='sample period, s (default: rig.sample_period of the rig YAML); the stack '
                         'must run with the same one (./rwpend up --h S): the driver checks it')
    ap.add_argument('--rt-priority', type=int, default=0, metavar='N',
                    help='SCHED_FIFO priority N (1-99) for the emulated firmware, as for the real '
                         'rig\'s microcontroller; nice -10 where not permitted (default 0: '
                         'ordinary scheduling)')
    a = ap.parse_args(argv)
    if not 0 <= a.rt_priority <= 99:
        ap.error(f'--rt-priority must be in 0..99, got {a.rt_priority}')
    if not P.WATCHDOG_MIN_MS <= a.watchdog_ms <= P.WATCHDOG_MAX_MS:
        ap.error(f'--watchdog-ms must be in {P.WATCHDOG_MIN_MS}..{P.WATCHDOG_MAX_MS}, got {a.watchdog_ms}')
    for name in ('theta', 'duration', 'status_period', 'unplug_after', 'replug_after'):
        v = getattr(a, name)
        if not math.isfinite(v) or (name != 'theta' and v < 0):
            ap.error(f'--{name.replace("_", "-")} must be finite' + (' and >= 0' if name != 'theta' else ''))
    if a.h is not None:
        try:
            load_rig(overrides={'rig.sample_period': a.h})
        except ValueError as exc:
            ap.error(f'--h: {exc}')
    if a.rig:
        try:
            load_rig_file(a.rig)
        except (ValueError, OSError) as exc:
            ap.error(f'--rig: {exc}')
    if a.link and os.path.exists(a.link) and not os.path.islink(a.link):
        ap.error(f'--link {a.link}: exists and is not a symlink; refusing to replace it')
    if a.link and not os.path.isdir(os.path.dirname(os.path.abspath(a.link))):
        ap.error(f'--link {a.link}: the directory {os.path.dirname(os.path.abspath(a.link))} does not exist')
    return a


class Output:
    """Lines to stdout from a thread of their own: a write that blocks (a busy disk, a pipe
    nobody empties) holds up that thread, never the sample clock."""

    def __init__(self) -> None:
        self.queue: queue.SimpleQueue = queue.SimpleQueue()
        self.thread = threading.Thread(target=self._run, name='emulator-output', daemon=True)
        self.thread.start()

    def line(self, text: str) -> None:
        self.queue.put(text)

    def _run(self) -> None:
        while True:
            text = self.queue.get()
            if text is None:
                return
            sys.stdout.write(text + '\n')
            sys.stdout.flush()

    def close(self, timeout: float = 5.0) -> None:
        """Write what is queued, then stop."""
        self.queue.put(None)
        self.thread.join(timeout)


@dataclass
class EmulatorCounters:
    """What the emulated firmware could not do in time, or could not send."""
    overruns: int = 0          # sample instants served more than h late (the OS stalled it)
    stalls: int = 0            # ... episodes (consecutive late instants count once)
    max_late_ms: float = 0.0   # the latest sample instant, ms after its time
    dropped_tx: int = 0        # bytes a host with the port open did not take (its buffer full)
    unheard_tx: int = 0        # bytes sent while no host had the port open (they go nowhere)
    host_opens: int = 0        # times a host opened the port
    late_commands: int = 0     # commands that came after the next sample had been sent


#: samples whose send times are kept, to time the commands answering them
SENT_RING = 4096


class Emulator:
    def __init__(self, args) -> None:
        self.args = args
        # --rig is a complete file (checked in parse_args); --h overrides its sample period
        self.rig = load_rig(args.rig, overrides=None if args.h is None else {'rig.sample_period': args.h})
        self.t0 = time.monotonic()
        self.plant = Plant(self.rig, theta=args.theta)      # the rig on the other side of the HAL
        # the firmware's core (FirmwareError when it cannot be built or loaded); the emulator steps the
        # plant between its tick_begin and tick_end
        self.core = FirmwareCore(self.rig, watchdog_ms=args.watchdog_ms, on_event=self.on_core_event)
        self.pty: Optional[Pty] = None
        self.host = False
        self.hands: queue.Queue = queue.Queue()
        self.holding: tuple[float, int] | None = None   # (angle, samples left) of a hand holding it
        if args.hand:
            threading.Thread(target=self.read_hands, name='emulator-hand', daemon=True).start()
        self.unplugged_at: Optional[float] = None
        self.want_unplug = False
        self.want_replug = False
        self.stop = False
        self.counters = EmulatorCounters()
        self.was_late = False
        self.sent = [0.0] * SENT_RING        # monotonic send time of sample k at k % SENT_RING
        #: sample sent -> command answering it received: the whole PC side's loop, as the
        #: device sees it
        self.latency = Histogram(bin_ms=0.05, top_ms=200.0)
        self.trace = tracer('emulator')     # None unless RWPEND_TRACE is set (profiling)
        self.output = Output()

    def now(self) -> float:
        return time.monotonic() - self.t0

    def emit(self, event: str, **data) -> None:
        data = {'event': event, 't': round(self.now(), 6), **data}
        if self.args.json:
            self.output.line(json.dumps(data))
        else:
            rest = ' '.join(f'{k}={v}' for k, v in data.items() if k not in ('event', 't'))
            self.output.line(f'[{data["t"]:10.3f}] {event} {rest}')

    def on_core_event(self, name: str, data: dict) -> None:
        if name == 'hold_expired':          # one per late command: counted in the status line
            return
        if name == 'watchdog_trip' and self.unplugged_at is not None:
            data = dict(data, since_unplug=data['t'] - self.unplugged_at)
        self.emit(name, **data)

    def plug(self) -> None:
        self.pty = Pty(self.args.link)
        self.unplugged_at = None
        self.host = False
        self.emit('plugged', pty=self.pty.path, link=self.args.link or '')

    def unplug(self) -> None:
        if self.pty is not None:
            self.pty.close()
            self.pty = None
            self.set_host(False)
            self.unplugged_at = self.now()
            self.emit('unplugged', enabled=self.core.enabled, u=self.core.held_command())

    def set_host(self, present: bool) -> None:
        if present != self.host:
            self.host = present
            self.counters.host_opens += present
            self.emit('host', present=present)

    def write(self, data: bytes) -> None:
        """To the host; nowhere when none has the port open; what it does not take is dropped."""
        if not data or self.pty is None:
            return
        c = self.counters
        if not self.host:
            c.unheard_tx += len(data)
            return
        try:
            n = os.write(self.pty.master, data)
        except BlockingIOError:
            n = 0                       # the host does not read: the UART drops bytes
        except OSError as exc:
            if exc.errno != errno.EIO:
                raise
            c.unheard_tx += len(data)   # the host closed the port meanwhile
            return
        c.dropped_tx += len(data) - n

    def read(self) -> None:
        if self.pty is None or not self.host:
            return
        while True:
            try:
                data = os.read(self.pty.master, 4096)
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:
                if exc.errno == errno.EIO:      # the host closed the port
                    return
                raise
            if not data:
                return
            held = self.core.cmd_sample
            self.write(self.core.receive(data, self.now()))
            if self.core.cmd_sample not in (held, P.NO_SAMPLE):
                self.command_taken(self.core.cmd_sample)

    def command_taken(self, sample: int) -> None:
        """A new command answering ``sample`` is held: its latency since the sample went out."""
        age = (self.core.k - sample) & 0xFFFFFFFF
        if age < SENT_RING:
            self.latency.add((time.monotonic() - self.sent[sample % SENT_RING]) * 1e3)
            self.counters.late_commands += age > 0
        if self.trace is not None:
            self.trace('dev.rx', sample)

    def read_hands(self) -> None:
        """The hand's thread: lines of stdin queued for the sample loop (which applies them)."""
        for line in sys.stdin:
            self.hands.put(line)

    def hand(self, line: str) -> None:
        """One hand action on the pendulum (``steady [S]``, ``lift DEG [S]``, ``tap DV``), from
        this sample instant; a malformed one is refused (said as an event), nothing changes."""
        words = line.split()
        try:
            nums = [float(w) for w in words[1:]]
            if not all(math.isfinite(v) for v in nums):
                raise ValueError('numbers must be finite')
            if words[:1] == ['steady'] and len(nums) <= 1:
                angle, secs = 0.0, (nums or [0.0])[0]
            elif words[:1] == ['lift'] and 1 <= len(nums) <= 2:
                angle, secs = math.radians(nums[0]), (nums[1:] or [0.0])[0]
            elif words[:1] == ['tap'] and len(nums) == 1:
                self.plant.tap(nums[0])
                self.emit('hand', action=line.strip())
                return
            else:
                raise ValueError('expected "steady [S]", "lift DEG [S]" or "tap DV"')
            if not 0.0 <= secs <= 60.0:
                raise ValueError(f'hold time must be in 0..60 s, got {secs:g}')
            self.plant.hold(angle)
        except ValueError as exc:
            self.emit('hand_refused', line=line.strip(), reason=str(exc))
            return
        self.holding = (angle, int(round(secs / self.rig.sample_period))) if secs > 0 else None
        self.emit('hand', action=line.strip())

    def keep_holding(self) -> None:
        """A hand still holding the pendulum: held again at this sample instant, let go at the end."""
        if self.holding is None:
            return
        angle, left = self.holding
        self.plant.hold(angle)
        self.holding = (angle, left - 1) if left > 1 else None
        if self.holding is None:
            self.emit('hand', action='let go')

    def status(self) -> None:
        c, s = self.core, self.plant.state
        pc, mc = c.counts()
        e = self.counters
        self.emit('status', fw=c.version, sample=c.k, enabled=c.enabled, tripped=c.tripped, u_applied=c.u_applied_milli / P.U_SCALE,
                  cmd_sample=c.cmd_sample, commands=c.counters.commands, pendulum_counts=pc, motor_counts=mc,
                  theta=round(s.theta, 6), wheel_rate=round(s.wheel_rate, 4), rx_bad=c.rx_bad,
                  refused=c.counters.refused, ignored=c.counters.ignored_commands,
                  watchdog_trips=c.counters.watchdog_trips, hold_expired=c.counters.hold_expired,
                  rx_stats=c.rx_stats(),
                  overruns=e.overruns, stalls=e.stalls, max_late_ms=round(e.max_late_ms, 3),
                  dropped_tx=e.dropped_tx, unheard_tx=e.unheard_tx, host=self.host,
                  connected=self.pty is not None, late_commands=e.late_commands,
                  cmd_latency=self.latency.summary())

    def serve_until(self, deadline: float) -> None:
        """Take the host's bytes (commands) until the sample instant ``deadline`` (monotonic)."""
        while not (self.stop or self.want_unplug):
            delay = deadline - time.monotonic()
            if delay <= 0:
                return
            if self.pty is None or not self.host:
                time.sleep(delay)           # nothing to serve (a master without a host polls
                return                      # ready at once: no busy loop at real-time priority)
            ev = self.pty.poll(delay)
            if ev & select.POLLIN:
                self.read()
            if ev & ~select.POLLIN:         # hang-up or error: the host is gone (never spin on it)
                self.set_host(False)

    def sample(self, deadline: float) -> None:
        """The sample instant: late-instant accounting, the host's bytes, one SAMPLE."""
        late = time.monotonic() - deadline
        e = self.counters
        h = self.rig.sample_period
        if late > h:
            e.overruns += 1
            e.stalls += not self.was_late
            e.max_late_ms = max(e.max_late_ms, late * 1e3)
        self.was_late = late > h
        if self.pty is not None:
            self.set_host(self.pty.host_present())
        self.read()
        # PROTOCOL.md, "Device behaviour", the order within a sample period: watchdog check ->
        # the held command drives the plant over the period -> the encoders are read -> SAMPLE
        now = self.now()
        u_milli = self.core.tick_begin(now)
        self.plant.step(u_milli / P.U_SCALE)
        data = self.core.tick_end(now, *self.plant.counts())
        self.sent[self.core.k % SENT_RING] = time.monotonic()
        if self.trace is not None:
            self.trace('dev.tx', self.core.k)
        self.write(data)

    def cable(self, unplug_at: float) -> float:
        """SIGUSR1/SIGUSR2 (or the test aids' times): unplug, replug. Returns the next unplug time."""
        a = self.args
        if self.want_unplug or self.now() >= unplug_at:
            self.want_unplug, unplug_at = False, math.inf
            self.unplug()
        if self.want_replug or (a.replug_after > 0 and self.unplugged_at is not None
                                and self.now() >= self.unplugged_at + a.replug_after):
            self.want_replug = False
            if self.pty is None:
                self.plug()
        return unplug_at

    def run(self) -> int:
        a = self.args
        h = self.rig.sample_period
        self.plug()
        start = time.monotonic()
        self.t0 = start
        # every event's t is CLOCK_MONOTONIC - clock_origin (one clock for the host's processes)
        self.emit('ready', pty=self.pty.path, link=a.link or '', h=h, watchdog_ms=self.core.watchdog_ms,
                  counts_per_rev=self.rig.counts_per_rev, clock_origin=start, fw=self.core.version)
        k = 0
        next_status = a.status_period if a.status_period > 0 else math.inf
        unplug_at = a.unplug_after if a.unplug_after > 0 else math.inf
        try:
            while not self.stop:
                unplug_at = self.cable(unplug_at)
                deadline = start + (k + 1) * h
                self.serve_until(deadline)
                if self.stop:
                    break
                if self.want_unplug:
                    continue
                k += 1
                self.keep_holding()
                while not self.hands.empty():
                    self.hand(self.hands.get_nowait())
                self.sample(deadline)
                if self.now() >= next_status:
                    next_status += a.status_period
                    self.status()
                if a.duration > 0 and k * h >= a.duration:
                    break
        finally:
            self.status()
            if self.pty is not None:
                self.pty.close()
            if self.trace is not None:
                self.trace.dump()
            self.emit('exit', samples=self.core.counters.samples, fw=self.core.version)
            self.output.close()
        return 0


def main(argv=None) -> int:
    args = parse_args(sys.argv[1:] if argv is None else argv)
    if args.rt_priority:
        from rwpend_ros.sched import apply_scheduling
        apply_scheduling({**os.environ, 'RWPEND_RT_PRIORITY': str(args.rt_priority)})
    try:
        emu = Emulator(args)
    except FirmwareError as exc:
        print(f'rwpend emulate: {exc}', file=sys.stderr)
        return 2

    def on_stop(signum, frame):
        emu.stop = True

    def on_unplug(signum, frame):
        emu.want_unplug = True

    def on_replug(signum, frame):
        emu.want_replug = True

    signal.signal(signal.SIGINT, on_stop)
    signal.signal(signal.SIGTERM, on_stop)
    signal.signal(signal.SIGUSR1, on_unplug)
    signal.signal(signal.SIGUSR2, on_replug)
    return emu.run()


if __name__ == '__main__':
    raise SystemExit(main())
