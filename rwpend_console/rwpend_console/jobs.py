"""The console's child processes: recordings (``rwpend record``) and analyses (``rwpend
analyze``), each a process of its own, so neither ever runs in the console's process (or the
loop's). One recording per rig; one analysis per bag at a time, at nice 10.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

from .bags import METRICS, PLOT

#: seconds a recorder gets to close its bag after SIGINT before SIGTERM
RECORDER_GRACE_S = 15.0


def default_sigint() -> None:  # pragma: no cover - runs in the child
    """SIGINT at its default in the child, as from a shell: a console started with SIGINT
    ignored (a background job of a script, ``./rwpend console &``) would pass that on, and a
    Python child that starts with SIGINT ignored never raises KeyboardInterrupt -- the lab run
    stopped by SIGINT to its group then ran on until the SIGTERM after STOP_GRACE_S."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def ordinary_priority() -> None:  # pragma: no cover - runs in the child
    """A stack of its own (a lab run) is no batch work: ordinary scheduling, as from a shell
    (not the console's real-time priority; at nice 10 a lab run's recorder fell behind on a
    loaded host and the experiment's quantities came out wrong); SIGINT at its default."""
    default_sigint()
    try:
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except (OSError, AttributeError):
        pass


def batch_priority() -> None:  # pragma: no cover - runs in the child
    """An analysis is batch work: ordinary scheduling (not the console's real-time priority), nice
    10; SIGINT at its default."""
    default_sigint()
    try:
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except (OSError, AttributeError):
        pass
    os.nice(10)


class Recording:
    """``rwpend record -o PATH TOPICS...`` on ``domain``."""

    def __init__(self, path: Path, topics: list[str], domain: int) -> None:
        self.path = Path(path)
        self.started = time.time()
        env = dict(os.environ, ROS_DOMAIN_ID=str(domain), PYTHONUNBUFFERED='1')
        self.log = open(self.path.parent / f'.{self.path.name}.record.log', 'wb')
        self.proc = subprocess.Popen([sys.executable, '-u', '-m', 'rwpend_bag.cli', 'record', '-o',
                                      str(self.path), *topics], env=env, stdin=subprocess.DEVNULL,
                                     stdout=self.log, stderr=subprocess.STDOUT)

    @property
    def running(self) -> bool:
        return self.proc.poll() is None

    def stop(self) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout=RECORDER_GRACE_S)
            except subprocess.TimeoutExpired:
                self.proc.terminate()
                self.proc.wait(timeout=5.0)
        self.log.close()
        return self.proc.returncode

    def as_dict(self) -> dict:
        return {'bag': self.path.name, 'running': self.running, 'seconds': round(time.time() - self.started, 1),
                'exit': self.proc.returncode}


class Analyses:
    """``rwpend analyze BAG --plot BAG/analysis.png --json`` -> BAG/metrics.json, in the background."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.running: dict[str, subprocess.Popen] = {}
        self.errors: dict[str, str] = {}

    def start(self, bag: Path) -> bool:
        """False when an analysis of this bag is already running."""
        with self.lock:
            if bag.name in self.running:
                return False
            proc = subprocess.Popen([sys.executable, '-m', 'rwpend_bag.cli', 'analyze', str(bag), '--plot',
                                     str(bag / PLOT), '--json'], stdin=subprocess.DEVNULL,
                                    stdout=subprocess.PIPE, stderr=subprocess.PIPE, preexec_fn=batch_priority)
            self.running[bag.name] = proc
            self.errors.pop(bag.name, None)
        threading.Thread(target=self._finish, args=(bag, proc), daemon=True).start()
        return True

    def _finish(self, bag: Path, proc: subprocess.Popen) -> None:
        out, err = proc.communicate()
        try:
            metrics = json.loads(out)
            (bag / METRICS).write_text(json.dumps(metrics, indent=2) + '\n')
            if proc.returncode:
                self._error(bag.name, metrics.get('error') or err.decode(errors='replace')[-500:])
        except (ValueError, OSError) as exc:
            self._error(bag.name, f'{exc}: {err.decode(errors="replace")[-500:]}')
        with self.lock:
            self.running.pop(bag.name, None)

    def _error(self, name: str, text: str) -> None:
        with self.lock:
            self.errors[name] = text.strip() or 'the analysis failed'

    def state(self) -> dict:
        with self.lock:
            return {'running': sorted(self.running), 'errors': dict(self.errors)}
