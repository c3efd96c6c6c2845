"""Runs an experiment through the real stack: the nodes, topics and parameters of ``./rwpend up``.

For every :class:`Run` the runner writes the run's parameters as a ROS 2 params file, describes
the stack (:class:`rwpend_bringup.stack.Stack`: that of ``up --lockstep --record BAG --duration S
--params FILE [--set ...]``), plans it and starts it with the launcher; the nodes' output goes to
``DIR/runs/<run>.log``.  On the simulator the manual steps are done by the simulator (initial
state, taps, torques); the rig path (``--plant serial:PORT``) is :mod:`rwpend_lab.rigrun`.
"""
from __future__ import annotations

import json
import sys
import time
from dataclasses import replace
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


def base_stack(sets=(), layout: str | None = None, error=LabError, **fields):
    """The stack the runs of a study share (:class:`rwpend_bringup.stack.Stack`): ``up``'s, with
    the ``--set NODE.PARAM=VALUE`` overrides ``sets``, the layout and more fields (``rig``,
    ``plant_rig``, ``plant``...); ``error`` with the reason for a bad ``--set``."""
    from rwpend_bringup.stack import Stack, overrides_from
    try:
        return Stack(overrides=overrides_from(sets), layout=layout, **fields)
    except ValueError as exc:
        raise error(f'--set: {exc}') from None


def run_stack(run: Run, out: Path, stack, log=None):
    """One run of ``stack`` (:func:`base_stack`) in lockstep on the simulator, recorded to
    ``out/runs/<run>``; returns the wall time (s)."""
    from rwpend_bringup.launch import Launcher
    from rwpend_bringup.stack import plan
    runs_dir = out / 'runs'
    runs_dir.mkdir(parents=True, exist_ok=True)
    bag = runs_dir / run.name
    if bag.exists():
        raise LabError(f'{bag} exists already (choose a new --out directory)')
    pfile = params_file(run, runs_dir / f'{run.name}.params.yaml', 'sim')
    try:
        p = plan(replace(stack, lockstep=True, duration=float(run.duration), record=str(bag),
                         params_files=(*stack.params_files, str(pfile))))
    except ValueError as exc:
        raise LabError(str(exc)) from None
    t0 = time.monotonic()
    with open(runs_dir / f'{run.name}.log', 'w') as fh:
        launcher = Launcher(p.specs, namespace=p.stack.ns, params_files=p.files, out=fh)
        status = launcher.run(120.0 + 20.0 * run.duration, until=_ticker(log, t0))
    if status != 0 or launcher.reason != f'exited:{p.stack.loop_process}':
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


def run_all(exp, rig, runs: list[Run], out: Path, stack, log=print) -> tuple[dict, list[dict]]:
    """Every run of an experiment with ``stack`` (:func:`base_stack`); (data by run name, run
    records for results.json)."""
    data, records = {}, []
    total = sum(r.duration for r in runs)
    for i, run in enumerate(runs, 1):
        log(f'  run {i}/{len(runs)}: {run.name} -- {run.title} ({run.duration:g} s simulated; '
            f'{total:g} s in all)')
        wall = run_stack(run, out, stack, log)
        data[run.name] = load_run(out / 'runs' / run.name, rig.sample_period)
        log(f'      done: {run.duration:g} s simulated in {wall:.1f} s wall')
        records.append(run_record(run, out / 'runs' / run.name, wall))
        sys.stdout.flush()
    return data, records


def run_record(run: Run, bag: Path, wall: float) -> dict:
    return {'name': run.name, 'title': run.title, 'duration': run.duration, 'mode': run.mode,
            'sim': dict(run.sim), 'estimator': dict(run.estimator), 'controller': dict(run.controller),
            'law': run.law, 'law_params': dict(run.law_params), 'bag': str(bag), 'wall_s': round(wall, 2)}
