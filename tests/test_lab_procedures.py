"""The lab's rig procedure of the experiments tests/test_lab_rig_system.py no longer runs through
the emulator (Experiments 1 and 13; 3 and 16 still do), in one process: each run's
:class:`rwpend_lab.manual.StepSequence` (what the rig path's monitor feeds, rwpend_lab.rigrun)
is fed the encoder counts of the plant model, and each prompt it shows is answered by the hand
the system test plays (tests/test_lab_rig_system.py HAND) as ``./rwpend emulate --hand`` applies
it (hold the pendulum at an angle for S s, then let go). Asserted: every prompt shown and
detected in order, the controller armed after ``arm_after`` prompts, the run done -- the
procedure; each experiment's measurement is judged in lockstep by
rwpend_lab/test/test_analyses.py::test_every_quantity_passes_on_the_twin."""
from __future__ import annotations

import math

import pytest

from rwpend_lab.experiment import Options
from rwpend_lab.manual import StepSequence
from rwpend_lab.registry import EXPERIMENTS
from rwpend_model.plant import Plant
from rwpend_model.rig import load_rig

from test_lab_rig_system import HAND

RIG = load_rig()


class Hand:
    """The emulator's hand (rwpend_driver.emulator: ``steady [S]``, ``lift DEG [S]``, ``tap DV``)
    on the plant model: held at the angle from this sample for S s, then let go."""

    def __init__(self, plant: Plant) -> None:
        self.plant, self.holding = plant, None
        self.balancing = None       # the armed controller's stand-in: the angle it keeps
        self.free = 0               # samples the stand-in lets a tap move the pendulum

    def act(self, line: str) -> None:
        words = line.split()
        nums = [float(w) for w in words[1:]]
        if words[0] == 'tap':
            self.plant.tap(nums[0])
            self.free = int(round(0.1 / RIG.sample_period))
            return
        angle = 0.0 if words[0] == 'steady' else math.radians(nums[0])
        secs = (nums[1:] if words[0] == 'lift' else nums)[:1] or [0.0]
        self.plant.hold(angle)
        n = int(round(secs[0] / RIG.sample_period))
        self.holding = (angle, n) if n > 0 else None

    def keep_holding(self) -> None:
        if self.free:
            self.free -= 1
        elif self.balancing is not None and self.holding is None:
            self.plant.hold(self.balancing)
        if self.holding is not None:
            angle, left = self.holding
            self.plant.hold(angle)
            self.holding = (angle, left - 1) if left > 1 else None


def action_for(text: str) -> str:
    """The system test's hand action for a prompt (its start)."""
    return next(action for start, action in HAND.items() if text.startswith(start))


def run_procedure(run, seq0: int = 1000, limit_s: float = 300.0):
    """One rig run's steps on the plant model with the hand; (events, sequence). Once armed the
    controller's part is played by holding the pendulum where it is, but for 0.1 s after a tap
    (the procedure only detects the steps and counts the samples of the run from there)."""
    steps = StepSequence(RIG, run.prompts, run.arm_after, run.duration)
    plant = Plant(RIG)
    hand = Hand(plant)
    events = []
    for i in range(int(limit_s / RIG.sample_period)):
        hand.keep_holding()
        pc, mc = plant.counts()
        for e in steps.feed(seq0 + i, pc, mc):
            events.append(e)
            if e.kind == 'show' and action_for(e.text):
                hand.act(action_for(e.text))
            elif e.kind == 'arm':
                hand.balancing = plant.state.theta
        if steps.finished:
            break
        plant.step(0.0)
    return events, steps


@pytest.mark.parametrize('n, runs', [(1, ['swing']), (13, ['w0_1.5wp', 'w0_2wp', 'w0_2.5wp'])])
def test_rig_procedure_with_the_emulators_hand(n, runs):
    plan = EXPERIMENTS[n].plan(RIG, Options())
    assert [r.name for r in plan] == runs
    for run in plan:
        events, steps = run_procedure(run)
        kinds = [e.kind for e in events]
        assert not steps.failed and kinds[-1] == 'done', (run.name, steps.failed, kinds)
        shown = [e.index for e in events if e.kind == 'show']
        detected = [e.index for e in events if e.kind == 'detected']
        assert shown == detected == list(range(len(run.prompts))), (run.name, kinds)
        armed = [e for e in events if e.kind == 'arm']
        assert len(armed) == (1 if run.arm_after else 0), (run.name, kinds)
        if run.arm_after:
            assert armed[0].index == run.arm_after - 1 and steps.armed_at == armed[0].seq
        assert steps.end - steps.origin == steps.duration_n
