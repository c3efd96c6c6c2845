"""The batched plant (rwpend_sweep.batch) is the scalar plant, bit for bit, and a batched study's
rows are those of its runs alone (rwpend_sweep.run.run_one)."""
import math
import random

import numpy as np
import pytest

from rwpend_model.plant import Plant
from rwpend_model.rig import load_rig
from rwpend_sweep.batch import BatchPlant, run_batch, simulate_batch
from rwpend_sweep.build import prepare
from rwpend_sweep.run import run_one, samples_of
from rwpend_sweep.spec import study_from_dict


def _bits(values) -> list:
    """Floats as their exact bits (float.hex tells -0.0 from 0.0, which == does not)."""
    return [v.hex() if isinstance(v, float) else v for v in values]


def test_numpy_sin_is_math_sin():
    """The premise of the batch: numpy.sin gives math.sin's bits (the angles of a run)."""
    rnd = np.random.default_rng(1)
    x = np.concatenate([rnd.uniform(-40, 40, 200_000), rnd.normal(0, 1e-3, 20_000),
                        rnd.uniform(-1e4, 1e4, 20_000), [0.0, -0.0, math.pi, -math.pi, 2 * math.pi]])
    assert np.sin(x).tolist() == [math.sin(v) for v in x.tolist()]


def _rigs(rnd: random.Random, n: int):
    """n rigs around the rig YAML: masses, friction, breakaway, lag, PWM, encoder per rig."""
    base = load_rig()
    out = []
    for j in range(n):
        f = lambda: rnd.uniform(0.8, 1.2)   # noqa: E731
        out.append(base.replace(
            m_p=base.m_p * f(), m_r=base.m_r * f(),
            friction_coulomb_pos=base.friction_coulomb_pos * f(), friction_viscous_pos=base.friction_viscous_pos * f(),
            friction_coulomb_neg=base.friction_coulomb_neg * f(), friction_viscous_neg=base.friction_viscous_neg * f(),
            friction_breakaway=base.friction_breakaway * rnd.choice([1.0, 3.0, 0.5]),
            motor_time_constant=0.0 if j % 7 == 3 else base.motor_time_constant * f(),
            pwm_steps=0 if j % 5 == 2 else base.pwm_steps, counts_per_rev=rnd.choice([4000, 1024])))
    return out


def _initial(rnd: random.Random, j: int) -> dict:
    if j % 4 == 0:      # hanging at rest, the rotor stuck
        return dict(theta=rnd.uniform(-0.05, 0.05))
    thd = rnd.uniform(-3, 3)
    wr = thd if j % 4 == 1 else rnd.uniform(-300, 300)
    return dict(theta=rnd.uniform(-4, 4), theta_dot=thd, wheel_angle=rnd.uniform(-9, 9), wheel_rate=wr)


@pytest.mark.parametrize('seed, h', [(1, 0.001), (2, 0.001), (3, 0.0025)])
def test_batch_plant_steps_as_the_plant_bit_for_bit(seed, h):
    """BatchPlant.step of N plants (different masses, friction, breakaway, lag, PWM, encoder;
    random states, commands within and beyond u_max and not finite, taps, torque pulses) gives
    each plant's readout, held command and time of Plant.step, bit for bit, sample for sample;
    runs leave the batch at different times and the others go on unchanged. Stick and slip
    (3.17) both happen."""
    rnd = random.Random(seed)
    n = 40
    rigs = [r.replace(sample_period=h) for r in _rigs(rnd, n)]
    inits = [_initial(rnd, j) for j in range(n)]
    ref = [Plant(r, **x) for r, x in zip(rigs, inits)]
    batch = BatchPlant([Plant(r, **x) for r, x in zip(rigs, inits)])
    lanes = list(batch.lanes)
    pairs = list(zip(ref, lanes))
    stuck_seen, slip_seen = 0, 0
    for k in range(700):
        for p, ln in pairs:
            assert _bits(ln.readout()) == _bits(p.readout())
            assert _bits([ln.u_held, ln.t]) == _bits([p.u_held, p.t])
            x = rnd.random()
            if x < 0.01:
                dv = rnd.uniform(-2, 2)
                p.tap(dv)
                ln.tap(dv)
            elif x < 0.02:
                p.disturbance = ln.disturbance = rnd.choice([0.0, rnd.uniform(-3, 3)])
            y = rnd.random()
            u = (rnd.uniform(-0.8, 0.8) if y < 0.4 else rnd.uniform(-10, 10) if y < 0.9 else
                 rnd.choice([0.0, -0.0, 10.0, -10.0, 11.5, -30.0, math.nan, math.inf, -math.inf]))
            p.step(u)
            ln.step(u)
        assert batch.step().all()
        stuck_seen += sum(p._stuck for p, _ in pairs)
        slip_seen += sum(not p._stuck for p, _ in pairs)
        if k in (150, 400, 600):        # some runs end here
            pairs = [pr for pr in pairs if rnd.random() < 0.7]
            batch.keep([ln for _, ln in pairs])
    for p, ln in pairs:
        assert _bits(ln.readout()) == _bits(p.readout())
    assert len(pairs) >= 5
    assert stuck_seen > 100 and slip_seen > 100


def test_batch_plant_reports_a_plant_that_is_no_longer_finite():
    rig = load_rig()
    batch = BatchPlant([Plant(rig, theta=0.3), Plant(rig, theta=0.2)])
    batch.th[1] = math.inf
    for ln in batch.lanes:
        ln.step(1.0)
    assert batch.step().tolist() == [True, False]


DOC = {'scenario': {'mode': 'auto', 'duration': 0.5, 'initial': {'theta': 3.0},
                    'taps': [{'t': 0.1, 'dv': 0.4}], 'torques': [{'t': 0.2, 'size': 1.5, 'duration': 0.05}],
                    'success': {'last': 0.2}},
       'axes': {'plant.m_p': {'factor': [0.9, 1.1]}, 'plant.friction_coulomb_pos': {'factor': [0.5, 1.5]},
                'plant.motor_time_constant': {'factor': [0.5, 2.0]},
                'initial.theta_dot': {'normal': [0.0, 0.5]}, 'sensor.noise_counts': [0.0, 2.0],
                'command.delay_samples': [0, 2], 'sample_period': [0.001, 0.002],
                'encoder.counts_per_rev': [4000, 1000]},
       'samples': 2, 'seed': 4}


def _row(r: dict) -> dict:
    return {k: (v.hex() if isinstance(v, float) else v) for k, v in r.items() if k != 'cpu_s'}


def test_batched_rows_are_the_rows_of_each_run_alone():
    """run_batch (the plants of a chunk's runs one BatchPlant, grouped by the sample period) gives
    each run the row of run_one, every metric bit for bit: per-run plant parameters, encoder
    resolution, sensor noise, command delay, taps and torque pulses, two sample periods."""
    s = study_from_dict(DOC)
    _, setups = prepare(s)
    items = [(i, x, s.scenario.success) for i, x in enumerate(setups)]
    rnd = random.Random(2)
    items = rnd.sample(items, 24)
    got = run_batch(items)
    assert [i for i, _ in got] == [i for i, _, _ in items]
    for (i, row), (_, setup, success) in zip(got, items):
        assert _row(row) == _row(run_one(setup, success)), f'run {i}'
    assert {x.model.sample_period for _, x, _ in items} == {0.001, 0.002}


def test_batched_rows_of_runs_of_different_lengths():
    """Runs that end at different times in one batch (their durations differ) keep their rows."""
    from dataclasses import replace
    s = study_from_dict(DOC)
    _, setups = prepare(s)
    setups = [replace(x, duration=d) for x, d in zip(setups[:6], (0.3, 0.5, 0.2, 0.45, 0.5, 0.25))]
    items = [(i, x, s.scenario.success) for i, x in enumerate(setups)]
    got = dict(run_batch(items))
    for i, setup, success in items:
        assert _row(got[i]) == _row(run_one(setup, success)), f'run {i}'


def test_batched_samples_are_the_samples_of_each_run_alone():
    """Sample for sample: the truth (theta, theta', theta_r'), the command and the saturation of
    each batched run are those of rwpend_sweep.run.simulate of the run alone."""
    s = study_from_dict(DOC)
    _, setups = prepare(s)
    items = [(i, x, s.scenario.success) for i, x in enumerate(setups) if x.model.sample_period == 0.001][:10]
    traces = {}
    simulate_batch(items, traces)
    assert sorted(traces) == [i for i, _, _ in items]
    for i, setup, _ in items:
        want, got = samples_of(setup), traces[i]
        for name in ('theta', 'theta_dot', 'wheel_rate', 'u', 'saturated'):
            a, b = getattr(want, name), getattr(got, name)
            assert a.dtype == b.dtype and a.tobytes() == b.tobytes(), (i, name)


def test_readings_without_the_truth_are_the_readings_with_it():
    """SimHardware(truth=False) (the batch's runs: the truth is the batch's arrays) reads the same
    sample, counts and previous command, without the Truth."""
    from rwpend_sim.sim_core import SimCore, SimHardware
    rig = load_rig()
    a, b = SimHardware(SimCore(rig, theta=0.4)), SimHardware(SimCore(rig, theta=0.4), truth=False)
    for k in range(300):
        ra, rb = a.read(), b.read()
        assert rb.truth is None and ra.truth is not None
        assert (ra.seq, ra.pendulum_counts, ra.motor_counts, ra.u_prev) == (rb.seq, rb.pendulum_counts, rb.motor_counts, rb.u_prev)
        for hw in (a, b):
            hw.write(k, 3.0 if k < 100 else -12.0)
            hw.advance()


def test_a_failing_run_and_a_plant_no_longer_finite_give_the_rows_of_the_runs_alone(monkeypatch):
    """A run that fails to build is its error row; a run whose batched plant leaves the finite
    numbers is run again alone (its row is then the scalar one, whatever it is); the others go on."""
    from dataclasses import replace
    from rwpend_sweep import batch as B
    from rwpend_sweep import run as R
    s = study_from_dict(DOC)
    _, setups = prepare(s)
    setups = [x for x in setups if x.model.sample_period == 0.001][:4]
    setups[1] = replace(setups[1], mode='no such mode')
    items = [(i, x, s.scenario.success) for i, x in enumerate(setups)]
    step, calls, alone = B.BatchPlant.step, [0], []

    def step_losing_lane_1(self):
        finite = step(self)
        calls[0] += 1
        if calls[0] == 100:         # the second lane's plant (run 2) is no longer finite
            finite = finite.copy()
            finite[1] = False
        return finite
    run_one_ = R.run_one

    def counted(setup, success):
        alone.append(setup)
        return run_one_(setup, success)
    monkeypatch.setattr(B.BatchPlant, 'step', step_losing_lane_1)
    monkeypatch.setattr(R, 'run_one', counted)
    got = dict(run_batch(items))
    assert alone == [setups[2]] and calls[0] > 100
    assert got[1]['reason'].startswith('error:') and not got[1]['success']
    for i, setup, success in items:
        assert _row(got[i]) == _row(run_one_(setup, success)), f'run {i}'


def test_task_size_two_tasks_a_worker_within_the_batch_bounds():
    from rwpend_sweep.execute import BATCH, BATCH_LEAST, task_size
    assert task_size(1000, 2) == 250                 # four tasks: the progress moves
    assert task_size(120, 2) == 60                   # a worker's whole share when it is small
    assert task_size(10_000, 2) == BATCH
    assert task_size(1, 4) == 1
    assert all(min(BATCH_LEAST, -(-n // w)) <= task_size(n, w) <= BATCH
               for n in (1, 7, 250, 999, 1000, 4321) for w in (1, 2, 3, 8))
