"""Device emulator: the rig's microcontroller on a pseudo-terminal, driving the plant model in real time.

    ./rwpend emulate [--link PATH] [--watchdog-ms N] [--theta RAD] [--json] [--status-period S]

Opens a pty (os.openpty), prints the slave device path (and makes PATH a symlink to it with
``--link``), then every h sends one SAMPLE frame and applies the latest valid COMMAND with
zero-order hold (device logic: :mod:`rwpend_driver.device`).

Signals emulate the cable: SIGUSR1 = unplug (the pty is closed, the link removed; the device
keeps running, so its watchdog zeroes the motor), SIGUSR2 = replug (a new pty, the link
re-pointed).  SIGINT/SIGTERM stop it.  With ``--json`` every output line is a JSON event.
"""
from __future__ import annotations

import argparse
import errno
import json
import math
import os
import select
import signal
import sys
import time
import tty
from typing import Optional

from rwpend_model.plant import Plant
from rwpend_model.rig import load_rig

from . import protocol as P
from .device import DEFAULT_WATCHDOG_MS, DeviceCore


class Pty:
    """One 'cable': a pty pair; the emulator holds the master and keeps a slave fd open."""

    def __init__(self, link: Optional[str]) -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        os.set_blocking(self.master, False)
        self.path = os.ttyname(self.slave)
        self.link = link
        if link:
            tmp = f'{link}.tmp{os.getpid()}'
            try:
                os.unlink(tmp)
            except FileNotFoundError:
                pass
            os.symlink(self.path, tmp)
            os.replace(tmp, link)          # atomic: the path never points nowhere

    def close(self) -> None:
        if self.link:
            try:
                if os.path.islink(self.link) and os.readlink(self.link) == self.path:
                    os.unlink(self.link)
            except OSError:
                pass
        for fd in (self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass


def parse_args(argv):
    ap = argparse.ArgumentParser(prog='rwpend emulate', description=__doc__.split('\n\n')[0])
    ap.add_argument('--link', help='create this symlink to the pty slave (replaced atomically)')
    ap.add_argument('--watchdog-ms', type=int, default=DEFAULT_WATCHDOG_MS,
                    help=f'initial watchdog period, ms ({P.WATCHDOG_MIN_MS}..{P.WATCHDOG_MAX_MS}; '
                         'the host sets it with SET_WATCHDOG)')
    ap.add_argument('--theta', type=float, default=0.0, help='initial pendulum angle (rad from hanging)')
    ap.add_argument('--duration', type=float, default=0.0, help='stop after S seconds (0 = run until stopped)')
    ap.add_argument('--status-period', type=float, default=0.0, help='print a status line every S s (0 = off)')
    ap.add_argument('--json', action='store_true', help='print JSON lines (events) instead of text')
    ap.add_argument('--unplug-after', type=float, default=0.0, help='unplug S seconds after start (test aid)')
    ap.add_argument('--replug-after', type=float, default=0.0,
                    help='replug S seconds after an unplug (test aid)')
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
    if a.link and os.path.exists(a.link) and not os.path.islink(a.link):
        ap.error(f'--link {a.link}: exists and is not a symlink; refusing to replace it')
    return a


class Emulator:
    def __init__(self, args) -> None:
        self.args = args
        self.rig = load_rig()
        self.t0 = time.monotonic()
        self.core = DeviceCore(self.rig, Plant(self.rig, theta=args.theta), watchdog_ms=args.watchdog_ms,
                               now=0.0, on_event=self.on_core_event)
        self.pty: Optional[Pty] = None
        self.unplugged_at: Optional[float] = None
        self.want_unplug = False
        self.want_replug = False
        self.stop = False
        self.dropped_tx = 0
        self.overruns = 0

    def now(self) -> float:
        return time.monotonic() - self.t0

    def emit(self, event: str, **data) -> None:
        data = {'event': event, 't': round(self.now(), 6), **data}
        if self.args.json:
            print(json.dumps(data), flush=True)
        else:
            rest = ' '.join(f'{k}={v}' for k, v in data.items() if k not in ('event', 't'))
            print(f'[{data["t"]:10.3f}] {event} {rest}', flush=True)

    def on_core_event(self, name: str, data: dict) -> None:
        if name == 'watchdog_trip' and self.unplugged_at is not None:
            data = dict(data, since_unplug=data['t'] - self.unplugged_at)
        self.emit(name, **data)

    def plug(self) -> None:
        self.pty = Pty(self.args.link)
        self.unplugged_at = None
        self.emit('plugged', pty=self.pty.path, link=self.args.link or '')

    def unplug(self) -> None:
        if self.pty is not None:
            self.pty.close()
            self.pty = None
            self.unplugged_at = self.now()
            self.emit('unplugged', enabled=self.core.enabled, u=self.core.held_command())

    def write(self, data: bytes) -> None:
        if not data or self.pty is None:
            return
        try:
            n = os.write(self.pty.master, data)
            if n < len(data):
                self.dropped_tx += len(data) - n
        except BlockingIOError:
            self.dropped_tx += len(data)      # nobody reads the port: the UART drops bytes
        except OSError as exc:
            if exc.errno not in (errno.EIO, errno.EAGAIN):
                raise
            self.dropped_tx += len(data)

    def read(self) -> None:
        if self.pty is None:
            return
        while True:
            try:
                data = os.read(self.pty.master, 4096)
            except (BlockingIOError, InterruptedError):
                return
            except OSError as exc:
                if exc.errno == errno.EIO:
                    return
                raise
            if not data:
                return
            self.write(self.core.receive(data, self.now()))

    def status(self) -> None:
        c, s = self.core, self.core.plant.state
        pc, mc = c.counts()
        self.emit('status', sample=c.k, enabled=c.enabled, tripped=c.tripped, u_applied=c.u_applied_milli / P.U_SCALE,
                  cmd_sample=c.cmd_sample, commands=c.counters.commands, pendulum_counts=pc, motor_counts=mc,
                  theta=round(s.theta, 6), wheel_rate=round(s.wheel_rate, 4), rx_bad=c.rx_bad,
                  rx_stats=c.parser.stats.as_dict(), overruns=self.overruns, dropped_tx=self.dropped_tx,
                  connected=self.pty is not None)

    def run(self) -> int:
        a = self.args
        h = self.rig.sample_period
        self.plug()
        self.emit('ready', pty=self.pty.path, link=a.link or '', h=h, watchdog_ms=self.core.watchdog_ms,
                  counts_per_rev=self.rig.counts_per_rev)
        k = 0
        next_status = a.status_period if a.status_period > 0 else math.inf
        unplug_at = a.unplug_after if a.unplug_after > 0 else math.inf
        start = time.monotonic()
        self.t0 = start
        self.core.t0 = 0.0
        self.core.last_command_time = 0.0
        try:
            while not self.stop:
                if self.want_unplug or self.now() >= unplug_at:
                    self.want_unplug, unplug_at = False, math.inf
                    self.unplug()
                if self.want_replug or (a.replug_after > 0 and self.unplugged_at is not None
                                        and self.now() >= self.unplugged_at + a.replug_after):
                    self.want_replug = False
                    if self.pty is None:
                        self.plug()
                deadline = start + (k + 1) * h
                # wait for bytes until the next sample instant
                while True:
                    delay = deadline - time.monotonic()
                    if delay <= 0:
                        break
                    if self.pty is None:
                        time.sleep(delay)
                        break
                    try:
                        r, _, _ = select.select([self.pty.master], [], [], delay)
                    except InterruptedError:
                        continue
                    if r:
                        self.read()
                    if self.stop or self.want_unplug:
                        break
                if self.stop:
                    break
                late = time.monotonic() - deadline
                if late > h:
                    self.overruns += 1
                k += 1
                self.read()
                self.write(self.core.tick(self.now()))
                if self.now() >= next_status:
                    next_status += a.status_period
                    self.status()
                if a.duration > 0 and k * h >= a.duration:
                    break
        finally:
            self.status()
            if self.pty is not None:
                self.pty.close()
            self.emit('exit', samples=self.core.counters.samples)
        return 0


def main(argv=None) -> int:
    args = parse_args(sys.argv[1:] if argv is None else argv)
    if args.rt_priority:
        from rwpend_ros.sched import apply_scheduling
        apply_scheduling({**os.environ, 'RWPEND_RT_PRIORITY': str(args.rt_priority)})
    emu = Emulator(args)

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
