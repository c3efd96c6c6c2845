"""Unit tests of the simulator's sample-by-sample core (rwpend_sim.sim_core.SimCore), no ROS.

What the rig's computer and amplifier do between two samples (Sections 2.5 and 3.1 of Block,
Astrom & Spong): the command u of the computer is held constant over the sampling period h
(zero-order hold) and realised by the amplifier saturated to |u| <= 10 (2.14); the encoders
are read at the sampling instants.  The simulator adds what the real stack needs around the
plant model (2.15): a command timeout, refusal of stale / future / non-finite commands, a
latched e-stop, and the disturbances of Experiment 13 (tapping the pendulum) and Experiment 15
(a disturbance torque on the pendulum, entering as +b_p d, ERRATA E20).
"""
from __future__ import annotations

import dataclasses
import math
import random

import pytest

from rwpend_model.rig import load_rig
from rwpend_sim.sim_core import MAX_DISTURBANCE, MAX_DURATION, MAX_TAP, SimCore

RIG = load_rig()
H = RIG.sample_period


def make(n_timeout: int = 3, **plant_kwargs) -> SimCore:
    return SimCore(RIG, command_timeout_samples=n_timeout, **plant_kwargs)


def tick(core: SimCore, u: float | None = None) -> float:
    """One sample: read the encoders (seq k), optionally answer seq k with u, integrate to k+1.
    Returns the command the amplifier held over [t_k, t_k+1)."""
    seq, _, _ = core.sample()
    if u is not None:
        ok, why = core.command(seq, u)
        assert ok, why
    return core.advance()


def record_step_inputs(core: SimCore) -> list[tuple[float, float, float]]:
    """Wrap plant.step to record (t, u, disturbance) of every integrated sample."""
    log: list[tuple[float, float, float]] = []
    step = core.plant.step

    def logged(u: float = 0.0) -> None:
        log.append((core.plant.t, u, core.plant.disturbance))
        step(u)
    core.plant.step = logged
    return log


# ----------------------------------------------------------------- command hold (ZOH)
def test_latest_command_is_held_zero_order():
    """Section 3.1 / (2.14): the amplifier holds the latest accepted command until the next one."""
    core = make(n_timeout=5)
    assert tick(core, 2.0) == 2.0
    assert core.plant.u_held == pytest.approx(2.0)
    assert tick(core) == 2.0 and tick(core) == 2.0           # no new command: held
    assert tick(core, -3.0) == -3.0
    assert core.plant.u_held == pytest.approx(-3.0)
    assert tick(core) == -3.0
    # two commands within one sample (the one for seq k-1 arriving late, then seq k's):
    # the newest one is held
    seq, _, _ = core.sample()
    assert core.command(seq - 1, 1.0) == (True, '')
    assert core.command(seq, 4.0) == (True, '')
    assert core.advance() == 4.0
    assert core.u_seq == seq and core.counters.commands == 4 and core.counters.samples == 6


def test_late_but_newer_command_is_accepted():
    """A command answering an older sample than the current one, but newer than the held one,
    is accepted (it is the best the controller has); it is held until the sample it answers is
    command_timeout_samples old."""
    core = make(n_timeout=3)
    tick(core, 1.0)                      # answers seq 0
    tick(core)
    seq, _, _ = core.sample()            # seq 2
    assert core.command(seq - 1, 2.5) == (True, '')
    assert core.advance() == 2.5 and core.held_seq == 1
    assert tick(core) == 2.5             # seq 3: 2 samples after seq 1
    assert tick(core) == 0.0             # seq 4: 3 samples after: timeout


# ----------------------------------------------------------------------- timeout
def test_command_timeout_zeroes_u_after_n_samples_and_counts_episodes():
    """No fresh command for N samples -> u = 0 (the stack's watchdog, issue 2 item 5)."""
    n = 3
    core = make(n_timeout=n)
    held = [tick(core, 5.0)] + [tick(core) for _ in range(5)]
    assert held == [5.0, 5.0, 5.0, 0.0, 0.0, 0.0]            # held N samples, then 0
    assert core.timed_out
    assert core.counters.timeouts == 1 and core.counters.timeout_samples == 3
    # a fresh command ends the episode; the next lapse is a second episode
    assert tick(core, -2.0) == -2.0 and not core.timed_out
    held = [tick(core) for _ in range(n + 2)]
    assert held == [-2.0] * (n - 1) + [0.0] * 3
    assert core.counters.timeouts == 2 and core.counters.timeout_samples == 6
    assert core.plant.u_held == 0.0


def test_no_command_yet_is_a_timeout():
    """Before the first command the amplifier holds 0 (reported as a timeout episode)."""
    core = make(n_timeout=3)
    assert [tick(core) for _ in range(4)] == [0.0] * 4
    assert core.timed_out and core.counters.timeouts == 1 and core.counters.timeout_samples == 4
    assert core.counters.commands == 0


def test_timeout_of_one_sample_needs_a_command_every_sample():
    core = make(n_timeout=1)
    assert tick(core, 3.0) == 3.0
    assert tick(core) == 0.0
    assert tick(core, 3.0) == 3.0
    assert core.counters.timeouts == 1
    with pytest.raises(ValueError):
        make(n_timeout=0)


def test_a_command_too_old_is_never_applied():
    """A command answering a sample command_timeout_samples or more old (a controller catching
    up on old states after a pause) is refused and counted: the motor stays at zero."""
    core = make(n_timeout=3)
    tick(core, 1.0)                                          # answers seq 0
    for _ in range(4):
        tick(core)                                           # seq 1..4: none; timed out
    seq, _, _ = core.sample()                                # seq 5
    ok, why = core.command(2, 7.0)                           # 3 samples old
    assert not ok and 'old command' in why and core.counters.old_commands == 1
    assert core.command(3, 6.0) == (True, '')                # 2 samples old: still applied
    assert core.advance() == 6.0 and core.held_seq == 3


def test_held_seq_says_which_command_is_held():
    core = make(n_timeout=3)
    assert core.held_seq == -1
    tick(core, 1.0)
    assert core.held_seq == 0
    tick(core)
    tick(core)
    assert core.held_seq == 0                                # held, 2 samples old
    tick(core)
    assert core.held_seq == -1 and core.timed_out            # timeout: u = 0, no command held
    core.estop = True
    tick(core, 2.0)
    assert core.held_seq == -1


# ------------------------------------------------------------ refused commands
def test_stale_commands_are_ignored_and_counted():
    """A command for a sample not newer than the held one (duplicate or reordered) is ignored:
    the held u stays, and it does not refresh the timeout."""
    core = make(n_timeout=3)
    tick(core)
    tick(core, 1.0)                                          # answers seq 1
    seq, _, _ = core.sample()
    ok, why = core.command(1, 9.0)                           # duplicate seq
    assert not ok and 'stale' in why
    ok, why = core.command(0, 9.0)                           # older seq
    assert not ok and 'stale' in why
    assert core.counters.stale_commands == 2 and core.counters.commands == 1
    assert core.u == 1.0 and core.u_seq == 1
    assert core.advance() == 1.0
    # stale commands every sample do not keep the held command alive
    held = []
    for _ in range(3):
        core.sample()
        assert not core.command(1, 9.0)[0]
        held.append(core.advance())
    assert held == [1.0, 0.0, 0.0] and core.counters.stale_commands == 5
    assert core.counters.rejected_commands == 0


@pytest.mark.parametrize('bad', [float('nan'), float('inf'), -float('inf'), None, 'x'])
def test_non_finite_command_is_rejected_with_reason(bad):
    core = make()
    tick(core, 2.0)
    seq, _, _ = core.sample()
    ok, why = core.command(seq, bad)
    assert not ok and 'non-finite' in why and str(seq) in why
    assert core.counters.rejected_commands == 1 and core.counters.last_reject_reason == why
    assert core.u == 2.0 and core.u_seq == 0
    assert core.advance() == 2.0
    assert core.command(seq, 1.0) == (True, '')             # the seq is still answerable


def test_command_for_a_future_sample_is_rejected_with_reason():
    core = make()
    tick(core, 2.0)
    seq, _, _ = core.sample()
    ok, why = core.command(seq + 1, 7.0)
    assert not ok and f'seq {seq + 1}' in why and f'newest sample is {seq}' in why
    assert core.counters.rejected_commands == 1 and core.counters.last_reject_reason == why
    assert core.u == 2.0 and core.u_seq == 0
    ok, _ = core.command(seq, 7.0)
    assert ok and core.advance() == 7.0


def test_saturated_command_is_applied_saturated_and_counted():
    """(2.14): |u| <= 10; a larger command is accepted, applied as +-10 and counted."""
    core = make(n_timeout=10)
    tick(core, 15.0)
    assert core.counters.saturated_commands == 1
    assert core.plant.u_held == RIG.u_max
    tick(core, -1e6)
    assert core.plant.u_held == -RIG.u_max
    tick(core, 10.0)                                         # exactly the limit: not counted
    tick(core, -9.99)
    assert core.counters.saturated_commands == 2 and core.counters.commands == 4


# ------------------------------------------------------------------------- e-stop
def test_estop_holds_zero_whatever_is_commanded_until_cleared():
    core = make(n_timeout=3)
    tick(core, 5.0)
    core.estop = True
    held = [tick(core, 10.0) for _ in range(50)]             # the controller keeps pushing
    assert held == [0.0] * 50
    assert core.counters.estop_samples == 50
    s = core.plant.state
    assert s.torque == pytest.approx(0.0, abs=1e-12) and core.plant.u_held == 0.0
    # released: a fresh command is applied again at once ...
    core.estop = False
    assert tick(core, 4.0) == 4.0
    assert core.counters.estop_samples == 50
    # ... but nothing older than the timeout survives the e-stop
    core.estop = True
    for _ in range(10):
        tick(core)
    core.estop = False
    assert tick(core) == 0.0 and core.timed_out


def test_estop_during_timeout_counts_as_estop():
    core = make(n_timeout=2)
    core.estop = True
    for _ in range(5):
        tick(core)
    assert core.counters.estop_samples == 5 and core.counters.timeout_samples == 0


# --------------------------------------------------------------------- disturbances
def test_tap_jumps_theta_dot_and_limits_are_refused_with_reason():
    """Experiment 13: tapping the pendulum = an impulse, theta' jumps by dv."""
    core = make()
    for _ in range(3):
        tick(core)
    before = core.plant.state
    ok, msg = core.tap(1.25)
    assert ok and '1.25' in msg
    after = core.plant.state
    assert after.theta_dot == before.theta_dot + 1.25
    assert after.theta == before.theta and after.wheel_rate == before.wheel_rate
    assert core.tap(MAX_TAP)[0] and core.tap(-MAX_TAP)[0]     # the limit itself is allowed
    for bad in (MAX_TAP * 1.01, -MAX_TAP - 1, float('nan'), float('inf')):
        state = core.plant.state
        ok, why = core.tap(bad)
        assert not ok and str(MAX_TAP) in why and 'tap' in why
        assert core.plant.state == state


def test_torque_disturbance_acts_for_its_duration_in_whole_samples():
    """Experiment 15: a constant torque d (control units) on the pendulum for a duration."""
    core = make(friction=False, pendulum_friction=False)
    log = record_step_inputs(core)
    for _ in range(12):                                      # start at an awkward sim time
        tick(core)
    ok, msg = core.torque(3.0, 5 * H)
    assert ok and 'torque 3' in msg
    for _ in range(10):
        tick(core)
    d = [entry[2] for entry in log[12:]]
    assert d == [3.0] * 5 + [0.0] * 5
    # the pendulum got the impulse b_p d T (+b_p d, ERRATA E20), less a little gravity
    assert core.plant.state.theta_dot == pytest.approx(RIG.b_p * 3.0 * 5 * H, rel=0.01)
    # shorter than a sample: acts for one sample
    core.torque(-2.0, 0.3 * H)
    for _ in range(3):
        tick(core)
    assert [entry[2] for entry in log[22:]] == [-2.0, 0.0, 0.0]


@pytest.mark.parametrize('d, duration', [(MAX_DISTURBANCE * 1.5, 1.0), (-MAX_DISTURBANCE - 1, 1.0),
                                         (float('nan'), 1.0), (1.0, 0.0), (1.0, -1.0),
                                         (1.0, MAX_DURATION * 2), (1.0, float('inf')),
                                         (1.0, float('nan'))])
def test_torque_disturbance_limits_are_refused_with_reason(d, duration):
    core = make()
    ok, why = core.torque(d, duration)
    assert not ok
    assert ('torque' in why and str(MAX_DISTURBANCE) in why) or \
           ('duration' in why and str(MAX_DURATION) in why)
    assert core.plant.disturbance == 0.0
    assert core.torque(MAX_DISTURBANCE, MAX_DURATION)[0]      # the limits themselves are allowed


def test_scheduled_taps_fire_at_their_sample():
    """Scripted taps: theta' += size at the first sample at or after each time (any order)."""
    core = make()
    fired: list[tuple[int, float]] = []
    tap = core.plant.tap

    def logged(dv: float) -> None:
        fired.append((core.k, dv))
        tap(dv)
    core.plant.tap = logged
    core.schedule_taps([0.020, 0.0105, 0.004], [-0.5, 1.0, 0.25])
    for _ in range(30):
        tick(core)
    assert fired == [(4, 0.25), (11, 1.0), (20, -0.5)]

    # the jump itself: from rest, theta' after the tapped sample is the tap (to friction/gravity)
    core = make()
    core.schedule_taps([0.0105], [1.0])
    rates = []
    for _ in range(12):
        tick(core)
        rates.append(core.plant.state.theta_dot)
    assert rates[:11] == [0.0] * 11
    assert rates[11] == pytest.approx(1.0, rel=0.01)


@pytest.mark.parametrize('times, sizes', [([0.1, 0.2], [1.0]), ([-0.1], [1.0]),
                                          ([float('nan')], [1.0]), ([0.1], [MAX_TAP + 1]),
                                          ([0.1], [float('inf')]), (['0.1'], [1.0])])
def test_bad_scheduled_taps_are_refused(times, sizes):
    core = make()
    with pytest.raises(ValueError):
        core.schedule_taps(times, sizes)


# -------------------------------------------------------------------- determinism
def drive(seed: int, n: int = 2000) -> tuple[SimCore, list]:
    """A busy, scripted session: commands with jitter, gaps, duplicates, NaN, future seqs,
    saturation, an e-stop, taps, scheduled taps and a torque disturbance."""
    rnd = random.Random(seed)
    core = make(n_timeout=3)
    core.schedule_taps([0.3, 1.2], [0.8, -1.5])
    out = []
    for k in range(n):
        seq, pc, mc = core.sample()
        r = rnd.random()
        if r < 0.05:
            pass                                            # lost command
        elif r < 0.07:
            core.command(seq, float('nan'))
        elif r < 0.09:
            core.command(seq + 1, 1.0)
        elif r < 0.11:
            core.command(max(seq - 2, 0), 1.0)
        else:
            core.command(seq, rnd.uniform(-12.0, 12.0) if r < 0.2 else 3 * math.sin(0.01 * k))
        if r < 0.01 and k > 100:
            for _ in range(8):                              # a burst of silence
                out.append(core.sample())
                core.advance()
        if k == 500:
            core.tap(0.7)
        if k == 800:
            core.torque(2.0, 0.25)
        if k == 1000:
            core.estop = True
        if k == 1100:
            core.estop = False
        u = core.advance()
        out.append((seq, pc, mc, u))
    return core, out


def test_identical_inputs_give_bit_identical_runs():
    a, out_a = drive(7)
    b, out_b = drive(7)
    assert out_a == out_b
    assert dataclasses.asdict(a.counters) == dataclasses.asdict(b.counters)
    assert a.plant.state == b.plant.state                   # exact float equality
    assert a.plant.t == b.plant.t and a.k == b.k
    c = a.counters                                           # the session did exercise it all
    assert min(c.commands, c.rejected_commands, c.stale_commands, c.saturated_commands,
               c.timeouts, c.timeout_samples, c.estop_samples) > 0
    # and a different session differs
    _, out_c = drive(8)
    assert out_c != out_a


def test_read_gives_the_plants_state_in_plain_frozen_dataclasses():
    """SimHardware.read (every sample) reads the plant through Plant.state_values and makes
    Truth and Reading with their own __init__ (the fields stored directly): the same fields,
    bit for bit, as Plant.state, the same dataclasses -- equality, repr, replace(), frozen."""
    from rwpend_model.plant import PlantState
    from rwpend_sim.sim_core import Reading, SimHardware, Truth
    core = make(theta=0.4, wheel_rate=30.0)
    hw = SimHardware(core)
    for k in range(400):
        hw.write(k, 4.0 if k < 150 else (-0.3 if k < 300 else 0.0))
        if k == 200:
            core.torque(2.0, 0.05)
        hw.advance()
        r = hw.read()
        plant = core.plant
        th, thd, thr, thrd = plant._x
        state = PlantState(theta=th, theta_dot=thd, wheel_angle=thr, wheel_rate=thrd,
                           torque=plant._torque_available(plant._tau, thrd - thd),
                           friction=plant._friction, stuck=plant._stuck)
        assert plant.state == state and plant.state_values() == dataclasses.astuple(state)
        want = dict(theta=th, theta_dot=thd, wheel_angle=thr, wheel_rate=thrd, u_applied=plant.u_held,
                    torque=state.torque, friction=state.friction, disturbance=plant.disturbance,
                    stuck=bool(state.stuck), timed_out=bool(core.timed_out), command_seq=core.held_seq)
        assert [(f.name, repr(getattr(r.truth, f.name))) for f in dataclasses.fields(Truth)] == \
            [(n, repr(v)) for n, v in want.items()]
        assert (r.seq, r.pendulum_counts, r.motor_counts) == (core.k, *plant.counts())
    assert [f.name for f in dataclasses.fields(Reading)] == list(vars(r))
    assert r == Reading(r.seq, r.pendulum_counts, r.motor_counts, r.u_prev, Truth(**vars(r.truth)))
    assert dataclasses.replace(r, seq=7) == Reading(7, r.pendulum_counts, r.motor_counts, r.u_prev, r.truth)
    assert Reading(1, 2, 3, 0.5).truth is None and repr(Reading(1, 2, 3, 0.5)).startswith('Reading(seq=1,')
    with pytest.raises(dataclasses.FrozenInstanceError):
        r.seq = 3
    with pytest.raises(dataclasses.FrozenInstanceError):
        r.truth.theta = 0.0
    assert hash(r.truth) == hash(Truth(**vars(r.truth)))
