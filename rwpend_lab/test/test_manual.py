"""Detectors of the student's manual steps on the rig, on encoder counts of the plant model."""
from __future__ import annotations

import math

import numpy as np

from rwpend_lab import manual
from rwpend_model.plant import Plant
from rwpend_model.rig import load_rig

RIG = load_rig()


def counts(plant, n, u=0.0):
    pc, mc = [], []
    for _ in range(n):
        p, m = plant.counts()
        pc.append(p)
        mc.append(m)
        plant.step(u)
    return np.array(pc), np.array(mc)


def test_held_then_released():
    th0 = math.radians(20)
    held = np.full(600, round(th0 / RIG.count_angle))
    assert manual.held_at(RIG, held, 0 * held, th0, math.radians(8), 0.5)
    assert not manual.released(RIG, held, 0 * held)
    pc, mc = counts(Plant(RIG, theta=th0, wheel_angle=th0), 300)
    assert manual.released(RIG, pc[:100], mc[:100])
    assert not manual.held_at(RIG, pc, mc, th0, math.radians(8), 0.2)


def test_still_upright_spun_bracket_tap():
    pc, mc = counts(Plant(RIG), 1200)
    assert manual.still(RIG, pc, mc, 1.0) and not manual.upright(RIG, pc, mc, 0.05)
    up = np.full(10, 2000)
    assert manual.upright(RIG, up, 0 * up, 0.05)
    pc, mc = counts(Plant(RIG, bracket=True, wheel_rate=200.0), 1100)
    assert manual.bracket(RIG, pc, mc) and manual.spun(RIG, pc[:50], mc[:50], 200.0)
    pc, mc = counts(Plant(RIG), 1100)
    assert not manual.tap(RIG, pc, mc)
    assert set(manual.DETECTORS) >= {'held_at', 'released', 'still', 'upright', 'spun', 'bracket', 'tap', 'torque'}


# ------------------------------------------------------------------ the live sequence of a rig run
from rwpend_lab.data import RunData, first_command, trim          # noqa: E402
from rwpend_lab.experiment import Prompt                          # noqa: E402


def feed_all(steps, pcs, mcs, seq0=1000):
    events = []
    for i, (p, m) in enumerate(zip(pcs, mcs)):
        events += [(e.kind, e.seq, e.index) for e in steps.feed(seq0 + i, int(p), int(m))]
        if steps.finished:
            break
    return events


def test_sequence_origin_at_the_last_step_less_its_simulated_time():
    """Still, then a tap 2 s after it that the simulator gives at 2 s: the origin is 2 s before
    the tap; the run is done duration + tail after the origin; nothing is armed (arm_after 0)."""
    h = RIG.sample_period
    still = Prompt('hang still', 'still', {'still_s': 0.5})
    tap = Prompt('tap', 'tap', {}, wait_s=2.0, at=2.0)
    steps = manual.StepSequence(RIG, [still, tap], 0, duration=3.0, tail_s=0.5)
    n_rest = 3000                                    # 3 s at rest, then a tap, then at rest again
    pc = np.zeros(n_rest + 6000, int)
    pc[n_rest:] = 20
    ev = feed_all(steps, pc, 0 * pc)
    kinds = [e[0] for e in ev]
    assert kinds == ['show', 'detected', 'show', 'detected', 'done'], ev
    shown_tap = ev[2][1]
    assert shown_tap - ev[1][1] == round(2.0 / h)    # shown wait_s after the still was seen
    tap_seen = ev[3][1]
    assert 1000 + n_rest <= tap_seen <= 1000 + n_rest + 10
    assert steps.origin == tap_seen - round(2.0 / h)
    assert ev[4][1] == steps.origin + round(3.5 / h) and steps.armed_at is None


def test_sequence_arms_after_its_steps_and_times_out_with_the_prompt():
    steps = manual.StepSequence(RIG, [Prompt('hang still', 'still', {'still_s': 0.2})], 1, duration=1.0)
    ev = feed_all(steps, np.zeros(2000, int), np.zeros(2000, int))
    assert [e[0] for e in ev][:3] == ['show', 'detected', 'arm']
    assert steps.armed_at == steps.origin == ev[1][1]
    moving = manual.StepSequence(RIG, [Prompt('hang still', 'still', {'still_s': 0.2})], 0, duration=1.0,
                                 timeout_s=1.0)
    ev = feed_all(moving, np.arange(3000) % 7, np.zeros(3000, int))
    assert ev[-1][0] == 'timeout' and moving.finished and 'hang still' in moving.failed


def test_sequence_refuses_a_bad_plan():
    for prompts, arm in (([Prompt('x', 'nope', {})], 0), ([], 1)):
        try:
            manual.StepSequence(RIG, prompts, arm, duration=1.0)
        except ValueError:
            continue
        raise AssertionError(f'accepted {prompts} arm_after={arm}')


def test_trim_and_first_command():
    h, n = 0.001, 1000
    z = np.zeros(n)
    u = z.copy()
    u[305:] = 5.0
    d = RunData(h=h, t=np.arange(n) * h, pc=np.arange(n, dtype=float), mc=z, u=u, theta=z, theta_dot=z,
                wheel_angle=z, wheel_rate=z, friction=z, switches=[(0.3, 'law', 'law', 'set')], seq0=500)
    assert first_command(d, 800) == 805 and first_command(d, 500 + 400) == 900
    assert first_command(d, 5000) == 5000
    c = trim(d, 805, 0.2)
    assert c.n == 200 and c.t[0] == 0.0 and c.pc[0] == 305 and c.mc[0] == 0.0 and c.u[0] == 5.0 and c.seq0 == 805
    assert abs(c.switches[0][0] + 0.005) < 1e-9
    try:
        trim(d, 100, 0.2)
    except ValueError as exc:
        assert 'origin 100' in str(exc)
    else:
        raise AssertionError('trim outside the bag accepted')


def test_sequence_judges_time_spans_when_samples_are_missed():
    """A monitor that gets one sample in four still sees a 0.5 s hold: the missed samples count
    with the counts before them; duplicates change nothing."""
    steps = manual.StepSequence(RIG, [Prompt('hold', 'held_at', {'angle': 0.35, 'tol': 0.14, 'still_s': 0.5})],
                                0, duration=1.0)
    held = round(0.35 / RIG.count_angle)
    ev = []
    for seq in range(0, 1000, 4):
        ev += [e.kind for e in steps.feed(seq, held, 0)]
        ev += [e.kind for e in steps.feed(seq, held + 50, 0)]      # a duplicate: ignored
    assert ev[:2] == ['show', 'detected'], ev
