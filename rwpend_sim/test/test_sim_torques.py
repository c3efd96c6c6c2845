"""Scripted torques on the pendulum (torques.times/sizes/durations of the sim node)."""
from __future__ import annotations

import pytest

from rwpend_model.rig import load_rig
from rwpend_sim.sim_core import SimCore

RIG = load_rig()


def test_scheduled_torque_is_applied_for_its_duration():
    core = SimCore(RIG, command_timeout_samples=3)
    core.schedule_torques([0.01], [2.0], [0.005])
    seen = []
    for k in range(20):
        core.command(k, 0.0)
        core.advance()
        seen.append(core.plant.disturbance)
    # applied from the sample at t = 10 ms for 5 ms, then removed
    assert seen[:10] == [0.0] * 10
    assert seen[10:15] == [2.0] * 5
    assert seen[16:] == [0.0] * 4


@pytest.mark.parametrize('times, sizes, durs', [([0.0], [1.0], []), ([-1.0], [1.0], [1.0]),
                                                 ([0.0], [1e9], [1.0]), ([0.0], [1.0], [0.0])])
def test_bad_torque_schedules_are_refused(times, sizes, durs):
    with pytest.raises(ValueError):
        SimCore(RIG).schedule_torques(times, sizes, durs)
