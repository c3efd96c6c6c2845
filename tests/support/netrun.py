"""The stack split across the hosts of a lab network (:mod:`tests/support/netlab.py`): each host
runs ``./rwpend up`` with the same arguments and its own ``--only``, as a lab would (the rig PC
``--only sim``, a student's laptop ``--only control``, a console ``--only recorder``). Used by the
network tests (tests/test_network_system.py). Pure Python (subprocess), no rclpy.

    run = SplitRun(lab, env, ['--mode', 'auto', '--duration', '20', '--record', bag],
                   [(a, 'sim'), (b, 'control'), (c, 'recorder')], out_dir)
    run.start()
    run.wait_for_log(1, 'auto/swingup -> auto/catch', timeout=60)
    ...
    codes = run.finish(timeout=120)     # the plant ends at --duration, then the others stop
    # or, once the test has seen what it needs (--duration a bound):
    codes = run.end_now()               # Ctrl-C to the plant, then to the others
"""
from __future__ import annotations

import os
import signal
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

from .netlab import Host, NetLab

ROOT = Path(__file__).resolve().parents[2]
RWPEND = str(ROOT / 'rwpend')
#: the names of ``--only`` that run the plant (they end by themselves at ``--duration``)
PLANT_PROCESSES = ('sim', 'driver', 'loop')


def lab_env(domain_id: int, base: dict | None = None) -> dict:
    """Environment of the processes on the lab's hosts: one domain, discovery on the subnet."""
    env = dict(os.environ if base is None else base)
    env.update({'ROS_DOMAIN_ID': str(domain_id), 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SUBNET',
                'PYTHONUNBUFFERED': '1'})
    for var in ('ROS_STATIC_PEERS', 'FASTRTPS_DEFAULT_PROFILES_FILE', 'FASTDDS_DEFAULT_PROFILES_FILE',
                'FASTDDS_BUILTIN_TRANSPORTS', 'RWPEND_DISCOVERY_RANGE'):
        env.pop(var, None)
    return env


@dataclass
class Part:
    """One host's share of the stack: ``only`` None = the whole stack on that host."""

    host: Host
    only: str | None
    log: Path
    proc: subprocess.Popen | None = None

    def runs(self, name: str) -> bool:
        return self.only is None or name in self.only.split(',')


class SplitRun:
    """``./rwpend up UP_ARGS --only ...`` on several hosts of ``lab`` (see the module doc)."""

    def __init__(self, lab: NetLab, env: dict, up_args: Sequence[str],
                 placement: Sequence[tuple[Host, str | None]], out: Path, tag: str = 'run') -> None:
        self.lab = lab
        self.env = env
        self.up_args = [str(x) for x in up_args]
        out.mkdir(parents=True, exist_ok=True)
        self.parts = [Part(host, only, out / f'{tag}_{host.name}.log') for host, only in placement]
        self.t_start = 0.0

    def start(self) -> None:
        self.t_start = time.monotonic()
        for part in self.parts:
            args = [RWPEND, 'up', *self.up_args] + (['--only', part.only] if part.only else [])
            with open(part.log, 'w') as log:
                part.proc = self.lab.popen(part.host, args, env=self.env, stdout=log,
                                           stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)

    def log_text(self, i: int) -> str:
        try:
            return self.parts[i].log.read_text(errors='replace')
        except OSError:
            return ''

    def wait_for_log(self, i: int, text: str, timeout: float) -> bool:
        """True once ``text`` is in part ``i``'s output (False after ``timeout`` s, or when that
        part has ended without it)."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if text in self.log_text(i):
                return True
            if self.parts[i].proc.poll() is not None:
                return text in self.log_text(i)
            time.sleep(0.1)
        return False

    def plant_parts(self) -> list[Part]:
        return [p for p in self.parts if any(p.runs(n) for n in PLANT_PROCESSES)]

    def finish(self, timeout: float, settle: float = 2.0) -> dict[str, int | None]:
        """Wait until the plant's hosts are done (``--duration``), at most ``timeout`` s, then
        stop the others (controllers first, the recorder last, ``settle`` s after the plant
        so that it has taken everything); {host: exit status} (None: had to be killed)."""
        end = time.monotonic() + timeout
        for part in self.plant_parts():
            try:
                part.proc.wait(timeout=max(0.1, end - time.monotonic()))
            except subprocess.TimeoutExpired:
                pass
        time.sleep(settle)
        return self.stop()

    def end_now(self, settle: float = 2.0) -> dict[str, int | None]:
        """End the run before its ``--duration`` (a bound, once the test has seen what it needs):
        Ctrl-C to the plant's hosts, then, ``settle`` s later, to the others as :meth:`finish`
        does -- the plant ends first, as at its duration, so the others answer its last samples
        and the recorder takes them; {host: exit status}."""
        for part in self.plant_parts():
            _interrupt(part.proc)
        time.sleep(settle)
        return self.stop()

    def stop(self) -> dict[str, int | None]:
        """Ctrl-C to every host still running, the recorder's last; their exit statuses."""
        order = sorted(self.parts, key=lambda p: (p.runs('recorder'), any(p.runs(n) for n in PLANT_PROCESSES)))
        codes: dict[str, int | None] = {}
        for part in order:
            codes[part.host.name] = _interrupt(part.proc)
        return codes

    def statuses(self) -> dict[str, int | None]:
        return {p.host.name: (p.proc.poll() if p.proc else None) for p in self.parts}


def _interrupt(proc: subprocess.Popen, grace: float = 30.0) -> int | None:
    """SIGINT to ``proc``'s process group (``./rwpend up`` then stops its nodes in order), then
    SIGKILL after ``grace`` s; its exit status (None when it had to be killed)."""
    if proc.poll() is None:
        try:
            os.killpg(proc.pid, signal.SIGINT)
        except ProcessLookupError:
            pass
    try:
        return proc.wait(timeout=grace)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=10)
        return None
