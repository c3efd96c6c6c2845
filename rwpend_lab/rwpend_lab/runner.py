"""Runs an experiment through the real stack: the nodes, topics and parameters of ``./rwpend up``.

For every :class:`Run` the runner writes the run's parameters as a ROS 2 params file, builds the
stack with rwpend_bringup's ``build_stack`` (the arguments of ``up --lockstep --record BAG
--duration S --params FILE [--set ...]``) and starts it with the launcher; the nodes' output goes
to ``DIR/runs/<run>.log``.  On the simulator the manual steps are done by the simulator (initial
state, taps, torques); the rig path (``--plant serial:PORT``) is :mod:`rwpend_lab.rigrun`.
"""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

from .data import load_run
from .experiment import LabError, Run


def node_params(run: Run, plant: str) -> dict[str, dict]:
    """{node: parameters} of a run (the controller's mode and law included)."""
    ctrl = dict(run.controller)
    ctrl['mode'] = run.mode
    if run.law:
        ctrl['law.file'] = run.law
        ctrl['law.params'] = json.dumps(dict(run.law_params))
    out = {'estimator': dict(run.estimator), 'controller': ctrl}
    if plant == 'sim':
        out['sim'] = dict(run.sim)
    return out


def params_file(run: Run, path: Path, plant: str) -> Path:
    from rwpend_bringup.launch import params_file_text
    path.write_text(params_file_text({node: p for node, p in node_params(run, plant).items() if p}))
    return path


def stack_args(run: Run, bag: Path, pfile: Path, sets, composed: str | None, extra=()) -> list[str]:
    """The ``up`` arguments of a run (``extra``: more of them, e.g. ``--rig FILE --plant-rig FILE``)."""
    args = ['--lockstep', '--duration', repr(float(run.duration)), '--record', str(bag), '--params', str(pfile),
            *extra]
    for s in sets:
        args += ['--set', s]
    if composed:
        args += ['--composed', composed]
    return args


def run_stack(run: Run, out: Path, sets, composed: str | None = None, log=None, extra=()) -> float:
    """One run of the stack in lockstep on the simulator; returns the wall time (s)."""
    from rwpend_bringup import cli
    from rwpend_bringup.launch import Launcher
    runs_dir = out / 'runs'
    runs_dir.mkdir(parents=True, exist_ok=True)
    bag = runs_dir / run.name
    if bag.exists():
        raise LabError(f'{bag} exists already (choose a new --out directory)')
    pfile = params_file(run, runs_dir / f'{run.name}.params.yaml', 'sim')
    p = cli.Parser(prog='rwpend lab')
    cli.add_stack_args(p)
    a = p.parse_args(stack_args(run, bag, pfile, sets, composed, extra))
    try:
        cli.choose_defaults(a)          # the layout of up (the loop on the simulator)
        specs, files = cli.build_stack(a, 'rwpend lab')
    except ValueError as exc:
        raise LabError(str(exc)) from None
    t0 = time.monotonic()
    with open(runs_dir / f'{run.name}.log', 'w') as fh:
        launcher = Launcher(specs, namespace=a.ns, params_files=files, out=fh)
        status = launcher.run(120.0 + 20.0 * run.duration, until=_ticker(log, t0))
    plant = 'loop' if a.composed == 'loop' else 'sim'    # the process the simulator runs in
    if status != 0 or launcher.reason != f'exited:{plant}':
        raise LabError(f'run {run.name}: the stack did not run to the end ({launcher.reason}); '
                       f'see {runs_dir / (run.name + ".log")}')
    return time.monotonic() - t0


def _ticker(log, t0: float, every: float = 15.0):
    """``until`` callback of the launcher: a line every ``every`` s of wall time while it runs."""
    state = {'next': t0 + every}

    def tick() -> bool:
        now = time.monotonic()
        if log is not None and now >= state['next']:
            state['next'] = now + every
            log(f'      ... {now - t0:.0f} s wall')
        return False
    return tick


def run_all(exp, rig, runs: list[Run], out: Path, sets, composed=None, log=print) -> tuple[dict, list[dict]]:
    """Every run of an experiment; (data by run name, run records for results.json)."""
    data, records = {}, []
    total = sum(r.duration for r in runs)
    for i, run in enumerate(runs, 1):
        log(f'  run {i}/{len(runs)}: {run.name} -- {run.title} ({run.duration:g} s simulated; '
            f'{total:g} s in all)')
        wall = run_stack(run, out, sets, composed, log)
        data[run.name] = load_run(out / 'runs' / run.name, rig.sample_period)
        log(f'      done: {run.duration:g} s simulated in {wall:.1f} s wall')
        records.append(run_record(run, out / 'runs' / run.name, wall))
        sys.stdout.flush()
    return data, records


def run_record(run: Run, bag: Path, wall: float) -> dict:
    return {'name': run.name, 'title': run.title, 'duration': run.duration, 'mode': run.mode,
            'sim': dict(run.sim), 'estimator': dict(run.estimator), 'controller': dict(run.controller),
            'law': run.law, 'law_params': dict(run.law_params), 'bag': str(bag), 'wall_s': round(wall, 2)}
