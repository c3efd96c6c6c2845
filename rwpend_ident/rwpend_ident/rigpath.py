"""The identification on the rig (``--plant serial:PORT``): the same runs in real time through the
driver, the manual steps asked for on the terminal and detected from the encoders -- the lab's rig
path (:func:`rwpend_lab.rigrun.record_run`), shared, not copied.

Each run is the stack of ``./rwpend up --plant serial:PORT --record BAG --rig BASE`` with the run's
params file; its prompts are printed (hold the pendulum still; lift it and let go for the free
swing) and detected, and a procedure (mode ``law``) is switched on once the pendulum is at rest,
so it starts at once (its own rest wait is met). The run ends ``duration`` s after that (or after
the release of the free swing); the whole bag is fitted, as on the simulator. With ``./rwpend
emulate --hand`` the hand is a line on the emulator's stdin (``steady 0.5``, ``lift 20 1.5``).

The fits take the command the device held (the driver's ``applied``, from its SAMPLE frames), not
the commands sent: in real time a command may come too late for its sample or be refused as old.
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from rwpend_lab import runner
from rwpend_lab.data import load_run
from rwpend_lab.rigrun import record_run, run_facts

from .records import IdentError
from .session import check_run

#: wall seconds a procedure waits for rest on the rig (its rest_timeout there); the rest is
#: detected before it is switched on, so this only covers a pendulum that moves again
REST_S = 20.0


def rig_run(run):
    """The run as the rig does it: a procedure armed once its prompts (the rest) are seen."""
    return replace(run, arm_after=len(run.prompts)) if run.mode != 'off' and run.prompts else run


def run_plan(runs, rig, out: Path, a, log=print) -> tuple[dict, list]:
    """Every run of the plan on the rig, in order; ({run name: RunData}, run records)."""
    from rwpend_model.rig import default_rig_file
    base_file = Path(a.check or a.rig or default_rig_file())
    data, records = {}, []
    first = next((r.name for r in runs if r.name.startswith('pulse')), None)
    for i, run in enumerate(runs, 1):
        log(f'  run {i}/{len(runs)}: {run.name} -- {run.title}')
        stack = runner.base_stack(a.set, a.composed, error=IdentError, plant=a.plant, rig=str(base_file))
        r = record_run(rig_run(run), rig, out, stack, log=log, prog='rwpend identify', error=IdentError)
        data[run.name] = load_run(r.bag, rig.sample_period)
        records.append({**runner.run_record(run, r.bag, r.wall_s),
                        **run_facts(r, a.plant, r.steps.origin, rig.sample_period)})
        check_run(run, rig, data[run.name], run.name == first)
        log(f'      done in {r.wall_s:.1f} s')
    return data, records
