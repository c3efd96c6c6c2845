"""The lab's experiments started from the page: ``rwpend lab run N --out DIR/expNN_<time>``, a
process of its own (never the console's or the loop's), one at a time, at ordinary priority.

Files only here (no rclpy): the runs are the ``expNN_*`` directories of the lab folder
(``--lab``, default ``lab_out`` as ``./rwpend lab run`` uses), each with the lab's
``results.json`` and self-contained ``report.html`` when it is done and ``console.log`` (what
the lab runner printed) from the console.

A run from the page gets a domain of its own (``--lab-domain``; by default one the console
does not watch) and stays on this host (``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``): the lab
runs a lockstep stack in the namespace ``/rwpend`` and records every topic it sees, so on a
watched rig's domain it would take that rig's topics and the rig its.
"""
from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

from .jobs import batch_priority, ordinary_priority

LOG = 'console.log'
RESULTS = 'results.json'
REPORT = 'report.html'
_RUN_RE = re.compile(r'exp(\d{2})_\d{8}_\d{6}(?:_\d+)?')
#: seconds a lab run gets to stop its stack after SIGINT before SIGTERM
STOP_GRACE_S = 30.0
#: the characters of a run's log shown on the page
LOG_TAIL = 1500


def experiments() -> list[dict]:
    """The book's experiments as the page lists them (those the simulator can run). Imports
    the lab's analyses (matplotlib, python-control: tens of seconds of CPU on a busy machine):
    the console asks a child process for it (:meth:`LabRuns.experiments`)."""
    from rwpend_lab.experiment import NEEDS
    from rwpend_lab.registry import EXPERIMENTS
    return [{'number': n, 'title': e.title, 'section': e.section, 'figures': list(e.figures),
             'needs': [NEEDS.get(k, k) for k in e.needs], 'template': bool(e.template)}
            for n, e in EXPERIMENTS.items() if 'sim' in e.needs]


def check_run_name(name) -> str:
    """A run's directory name, ``expNN_YYYYmmdd_HHMMSS``; ValueError otherwise."""
    if not isinstance(name, str) or not _RUN_RE.fullmatch(name):
        raise ValueError(f'a lab run is named expNN_YYYYmmdd_HHMMSS, got {name!r}')
    return name


def lab_domain(watched, given: int | None = None) -> int:
    """The domain of the page's lab runs: ``given``, else the first domain after the watched
    ones that the console does not watch. ValueError if ``given`` is watched."""
    watched = sorted(set(watched))
    if given is not None:
        if given in watched:
            raise ValueError(f'--lab-domain {given} is a domain the console watches: a lab run there '
                             'would record that rig (choose another)')
        return given
    d = (watched[-1] + 1) % 233 if watched else 1
    while d in watched:
        d = (d + 1) % 233
    return d


def describe_run(path: Path, running: bool = False, exit_code: int | None = None) -> dict:
    """What the page shows of one run directory."""
    out = {'name': path.name, 'experiment': int(_RUN_RE.fullmatch(path.name).group(1)), 'running': running,
           'exit': exit_code, 'report': (path / REPORT).is_file(), 'passed': None, 'quantities': [], 'log': ''}
    try:
        res = json.loads((path / RESULTS).read_text())
        out['passed'] = bool(res.get('passed'))
        out['quantities'] = [{'name': q.get('name'), 'pass': bool(q.get('pass'))} for q in res.get('quantities', [])]
    except FileNotFoundError:
        pass
    except (ValueError, OSError, AttributeError, TypeError) as exc:
        out['error'] = f'{RESULTS} unreadable: {exc}'
    try:
        with open(path / LOG, 'rb') as f:
            f.seek(0, os.SEEK_END)
            f.seek(max(0, f.tell() - LOG_TAIL))
            out['log'] = f.read().decode(errors='replace')
    except OSError:
        pass
    return out


class LabRuns:
    """The lab folder and the one run the console may have going in it."""

    def __init__(self, folder: Path, domain: int, command: list[str] | None = None) -> None:
        self.folder = Path(folder)
        self.domain = domain
        #: the lab runner (``... run N --out DIR`` is added); tests put a stand-in here
        self.command = command or [sys.executable, '-u', '-m', 'rwpend_lab.cli']
        self.lock = threading.Lock()
        self.proc: subprocess.Popen | None = None
        self.current: Path | None = None
        self.exits: dict[str, int] = {}
        self._experiments: list[dict] | None = None
        self._experiments_error = ''
        self._loader = threading.Thread(target=self._load_experiments, name='lab-list', daemon=True)
        self._loader.start()

    def _load_experiments(self) -> None:
        """The list of experiments from a child process at batch priority (the console keeps
        neither the CPU time nor the memory of the lab's imports)."""
        code = 'import json; from rwpend_console.labruns import experiments; print(json.dumps(experiments()))'
        try:
            p = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=300,
                               stdin=subprocess.DEVNULL, preexec_fn=batch_priority)
            if p.returncode:
                self._experiments_error = (p.stderr.strip().splitlines() or ['failed'])[-1]
            else:
                self._experiments = json.loads(p.stdout)
        except (OSError, ValueError, subprocess.TimeoutExpired) as exc:
            self._experiments_error = str(exc)

    def experiments(self, wait: float = 0.0) -> list[dict] | None:
        """The experiments (None while the list is loading); ValueError if it could not be had."""
        self._loader.join(wait)
        if self._experiments_error:
            raise ValueError(f'the lab\'s experiments could not be listed: {self._experiments_error}')
        return self._experiments

    def _poll(self) -> None:
        if self.proc is not None and self.proc.poll() is not None:
            self.exits[self.current.name] = self.proc.returncode
            self.proc, self.current = None, None

    def start(self, number: int) -> dict:
        """Start experiment ``number``; ValueError with the reason when it cannot be."""
        exps = self.experiments(wait=300.0)
        if exps is None:
            raise ValueError('the list of experiments is still loading: try again in a moment')
        known = {e['number'] for e in exps}
        if number not in known:
            raise ValueError(f'no experiment {number} the simulator runs (those: '
                             f'{", ".join(map(str, sorted(known)))})')
        with self.lock:
            self._poll()
            if self.proc is not None:
                raise ValueError(f'{self.current.name} is running: one experiment at a time')
            self.folder.mkdir(parents=True, exist_ok=True)
            base = f'exp{number:02d}_{time.strftime("%Y%m%d_%H%M%S")}'
            out, k = self.folder / base, 1
            while out.exists():
                out, k = self.folder / f'{base}_{k}', k + 1
            out.mkdir()
            env = dict(os.environ, ROS_DOMAIN_ID=str(self.domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
                       PYTHONUNBUFFERED='1')
            env.pop('RWPEND_RT_PRIORITY', None)
            with open(out / LOG, 'wb') as log:
                self.proc = subprocess.Popen([*self.command, 'run', str(number), '--out', str(out)], env=env, stdin=subprocess.DEVNULL, stdout=log,
                                             stderr=subprocess.STDOUT, start_new_session=True,
                                             preexec_fn=ordinary_priority)
            self.current = out
            return {'ok': True, 'run': out.name, 'domain': self.domain}

    def stop(self, name) -> dict:
        """Stop the run ``name`` (its whole process group: the lab runner and its stack)."""
        check_run_name(name)
        with self.lock:
            self._poll()
            if self.proc is None or self.current.name != name:
                raise ValueError(f'{name} is not running')
            proc = self.proc
        try:
            os.killpg(proc.pid, signal.SIGINT)
            proc.wait(timeout=STOP_GRACE_S)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGTERM)
            proc.wait(timeout=10.0)
        except ProcessLookupError:
            pass
        with self.lock:
            self._poll()
        return {'ok': True, 'run': name, 'exit': proc.returncode}

    def report(self, name) -> Path:
        """The report.html of run ``name``; ValueError when there is none (yet)."""
        path = self.folder / check_run_name(name) / REPORT
        if not path.is_file():
            raise ValueError(f'{name} has no report (yet)')
        return path

    def state(self) -> dict:
        with self.lock:
            self._poll()
            current = self.current.name if self.current is not None else None
            exits = dict(self.exits)
        runs = []
        if self.folder.is_dir():
            for p in sorted(self.folder.iterdir(), reverse=True):
                if p.is_dir() and _RUN_RE.fullmatch(p.name):
                    runs.append(describe_run(p, p.name == current, exits.get(p.name)))
        return {'folder': str(self.folder), 'domain': self.domain, 'running': current, 'runs': runs}

    def close(self) -> None:
        with self.lock:
            self._poll()
            name = self.current.name if self.current is not None else None
        if name is not None:
            self.stop(name)
