"""Getting the data of an identification: running its plan through the stack, or reading the bags
of an earlier one.  The runs go through the lab's runner (rwpend_lab.runner: a params file per
run, ``build_stack`` + the launcher, lockstep on the simulator) and the lab's bag reader
(rwpend_lab.data); each run is checked as soon as it is in, so a plant that is not where the
next step needs it stops the identification with the reason before anything else runs.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rwpend_bag.reader import BagReadError
from rwpend_lab import runner
from rwpend_lab.data import load_run
from rwpend_lab.experiment import LabError

from .checks import Rest, rest_problem
from .records import IdentError, check_directions, commands, first_input, refused


@dataclass(frozen=True)
class Options:
    """How to run: the stack of every run (:func:`rwpend_lab.runner.base_stack`: ``--rig``,
    ``--plant-rig``, the ``--set`` values, the layout), and the run records as they come."""

    stack: object = None
    records: list = field(default_factory=list)


def check_run(run, rig, d, first_pulse: bool) -> None:
    """A run just recorded: refused by its procedure? the directions (the first pulse)?"""
    refused(run.name, d)
    if getattr(run, 'mode', 'law') == 'law' and not np.any(np.abs(commands(run.name, d)) > 0):
        # the run ended inside the procedure's wait for rest (shorter than its rest_timeout)
        dl = rig.count_angle
        k = max(1, int(round(Rest().still_s / rig.sample_period)))
        why = rest_problem(list(d.pc[-k:] * dl), list(d.mc[-k:] * dl), Rest())
        raise IdentError(f'{run.name}: the step never started: ' + (why or 'the command stayed 0')
                         + ' (at the end of the run)')
    if first_pulse:
        k = first_input(run.name, d)
        check_directions(run.name, rig, d, k, float(commands(run.name, d)[k]))


def run_plan(runs, rig, out: Path, options: Options, log=print) -> dict:
    """Every run of the plan on the simulator, in order; {run name: RunData}."""
    data = {}
    total = sum(r.duration for r in runs)
    first = next((r.name for r in runs if r.name.startswith('pulse')), None)
    for i, run in enumerate(runs, 1):
        log(f'  run {i}/{len(runs)}: {run.name} -- {run.title} ({run.duration:g} s simulated of {total:g})')
        wall = run_once_more_if_stalled(run, out, options, log)
        data[run.name] = load_run(out / 'runs' / run.name, rig.sample_period)
        options.records.append(runner.run_record(run, out / 'runs' / run.name, wall))
        check_run(run, rig, data[run.name], run.name == first)
        log(f'      done in {wall:.1f} s wall')
    return data


def run_once_more_if_stalled(run, out: Path, options: Options, log) -> float:
    """A run through the lab's runner; a stack that did not run to the end in its wall bound (it
    stalled: on a loaded machine a DDS process can stop for minutes) is run once more, its bag and log kept aside as
    ``<run>.stalled``; IdentError when that fails too."""
    def once() -> float:
        return runner.run_stack(run, out, options.stack, log)
    try:
        return once()
    except LabError as exc:
        # only the wall bound (a stall) is worth another run; a signal (Ctrl-C) or a node that
        # exited is the answer
        if 'did not run to the end (duration)' not in str(exc):
            raise IdentError(str(exc)) from None
        log(f'      {exc}; running it once more')
    runs = out / 'runs'
    for f in (runs / run.name, runs / f'{run.name}.log'):
        if f.exists():
            f.rename(f.with_name(f.name + '.stalled'))
    try:
        return once()
    except LabError as exc:
        raise IdentError(str(exc)) from None


def bag_paths(paths) -> list[Path]:
    """The bags of ``--from``: bag directories, or the output directory of an identification
    (its runs/ directory)."""
    out = []
    for p in map(Path, paths):
        if (p / 'runs').is_dir():
            out += sorted(b for b in (p / 'runs').iterdir() if b.is_dir() and not b.name.endswith('.stalled'))
        elif p.is_dir():
            out.append(p)
        else:
            raise IdentError(f'{p}: not a bag directory (nor an identification directory with runs/)')
    return out


def load_bags(paths, runs, rig) -> dict:
    """{run name: RunData} of recorded bags, named after the runs of the plan (IdentError for a
    bag that is not one of them or lacks the topics the fits need)."""
    names = {r.name for r in runs}
    data = {}
    for bag in bag_paths(paths):
        if bag.name not in names:
            raise IdentError(f'{bag}: not a run of the identification (bags are named after the runs: '
                             f'{", ".join(r.name for r in runs)})')
        try:
            d = load_run(bag, rig.sample_period)
        except (BagReadError, ValueError, OSError, KeyError) as exc:
            raise IdentError(f'{bag}: {exc} (the identification needs the topics encoders and command)') from None
        commands(bag.name, d)
        data[bag.name] = d
    return data
