"""The loop without ROS: one sample as plain calls, lockstep and late samples."""
import math
import threading

import pytest

from rwpend_control.supervisor import Controller, ControllerConfig
from rwpend_estimation.estimators import EstimatorConfig, make_estimator
from rwpend_model.rig import load_rig
from rwpend_ros.claim import CommandClaim
from rwpend_ros.health import LoopHealth
from rwpend_sim.sim_core import SimCore

from rwpend_ros.gate import CommandGate
from rwpend_sim.sim_core import SimHardware
from rwpend_loop.loop import (ControllerStage, EstimatorStage, Loop,
                              run_lockstep)
from rwpend_loop.pacer import Pacer

pytestmark = pytest.mark.loop    # the loop in lockstep in the test's process

ID = 0x1234


@pytest.fixture(scope='module')
def rig():
    return load_rig()


def make_loop(rig, mode='auto', controller=True, theta=0.0, **core_kwargs):
    core = SimCore(rig, command_timeout_samples=3, theta=theta, **core_kwargs)
    hw = SimHardware(core)
    gate = CommandGate(hw, CommandClaim(500), LoopHealth(rig.sample_period))
    est = EstimatorStage(make_estimator(None, rig, EstimatorConfig.from_values({}, rig=rig)))
    ctrl = ControllerStage(Controller(rig, ControllerConfig.designed(rig), mode=mode), ID) if controller else None
    return Loop(hw, gate, est, ctrl, rig.sample_period)


def test_lockstep_swings_up_and_balances(rig):
    loop = make_loop(rig)
    ticks = []
    run_lockstep(loop, 8000, ticks.append)
    assert len(ticks) == 8000
    # every command answers its own sample and drives the next interval: never late
    held = [t.reading.truth.command_seq for t in ticks[1:]]
    assert held == [t.reading.seq - 1 for t in ticks[1:]]
    last = ticks[-1].reading.truth
    assert abs(math.remainder(last.theta - math.pi, 2 * math.pi)) < 0.05
    assert loop.gate.claim.holder == ID


def test_lockstep_is_deterministic(rig):
    a, b = [], []
    run_lockstep(make_loop(rig), 3000, lambda t: a.append((t.reading.pendulum_counts, t.u)))
    run_lockstep(make_loop(rig), 3000, lambda t: b.append((t.reading.pendulum_counts, t.u)))
    assert a == b


def test_late_sample_holds_the_previous_command(rig):
    """A command computed after the next instant does not drive the interval it answers: the
    plant held the previous one (command_seq two behind), as on a rig."""
    loop = make_loop(rig, mode='swingup')
    ticks = [loop.step() for _ in range(10)]
    ticks.append(loop.step(behind=lambda: True))          # sample 10 late
    ticks.append(loop.step())
    ticks.append(loop.step())
    assert ticks[10].late and loop.late == 1
    assert ticks[11].reading.truth.command_seq == 9         # [t10, t11) held command 9: late
    assert ticks[12].reading.truth.command_seq == 11        # on time again
    assert loop.gate.health.late == 1


def test_external_controller_through_the_gate(rig):
    """No controller in the loop: the command comes through the gate (the topic), claimed."""
    loop = make_loop(rig, controller=False)
    t0 = loop.step()
    assert t0.estimate is not None and t0.u is None
    assert loop.gate.offer(7, 0, 1.0)
    assert not loop.gate.offer(8, 0, 2.0)                  # another controller: refused
    t1 = loop.step()
    assert t1.reading.truth.command_seq == 0
    assert t1.reading.u_prev == 1.0
    assert loop.gate.claim.refused == 1


def test_timeout_zeroes_the_motor(rig):
    loop = make_loop(rig, controller=False)
    loop.step()
    loop.gate.offer(7, 0, 5.0)
    seqs = [loop.step().reading.truth.command_seq for _ in range(5)]
    assert seqs == [0, 0, 0, -1, -1]


def test_estop_holds_zero(rig):
    loop = make_loop(rig, mode='swingup')
    loop.hardware.core.estop = True
    ticks = []
    run_lockstep(loop, 50, ticks.append)
    assert all(t.reading.truth.u_applied == 0.0 for t in ticks)
    assert all(t.reading.truth.command_seq == -1 for t in ticks[1:])


def test_a_controller_needs_the_estimator(rig):
    core = SimCore(rig)
    hw = SimHardware(core)
    gate = CommandGate(hw, CommandClaim(500), LoopHealth(rig.sample_period))
    ctrl = ControllerStage(Controller(rig, ControllerConfig.designed(rig)), ID)
    with pytest.raises(ValueError, match='needs the estimator'):
        Loop(hw, gate, None, ctrl, rig.sample_period)


def test_law_error_gives_zero(rig):
    loop = make_loop(rig, mode='swingup')

    def boom(*a, **k):
        raise RuntimeError('bad law')
    loop.controller.ctrl.update = boom
    t = loop.step()
    assert t.u == 0.0 and 'internal error' in t.status.fault and loop.controller.law_errors == 1


class FakeClock:
    def __init__(self):
        self.ns = 0
        self.sleeps = []

    def clock(self):
        return self.ns

    def sleep(self, s):
        self.sleeps.append(s)
        self.ns += int(round(s * 1e9))


def test_pacer_absolute_deadlines():
    fc = FakeClock()
    p = Pacer(1_000_000, fc.clock, fc.sleep)
    starts = []

    def tick(k):
        starts.append(fc.ns)
        fc.ns += 300_000 if k != 3 else 2_500_000     # sample 3 overruns by 1.8 periods
        return k < 7
    n = p.run(tick, threading.Event(), t0_ns=0)
    assert n == 7
    # samples 4 and 5 start at once (catching up), then on the grid again
    assert starts == [0, 1_000_000, 2_000_000, 3_000_000, 5_500_000, 5_800_000, 6_100_000, 7_000_000]
    assert p.overruns == 1 and p.max_lag_ns == 1_500_000


def test_pacer_behind():
    fc = FakeClock()
    p = Pacer(1_000_000, fc.clock, fc.sleep)
    seen = []

    def tick(k):
        fc.ns += 1_200_000 if k == 1 else 100_000
        seen.append(p.behind())
        return k < 2
    p.run(tick, threading.Event(), t0_ns=0)
    assert seen == [False, True, False]


def test_pacer_refuses_bad_period():
    with pytest.raises(ValueError):
        Pacer(0)
    with pytest.raises(ValueError):
        Pacer(1.5)


def test_pacer_stops():
    stop = threading.Event()
    fc = FakeClock()
    p = Pacer(1_000_000, fc.clock, fc.sleep)

    def tick(k):
        if k == 4:
            stop.set()
        return True
    assert p.run(tick, stop, t0_ns=0) == 5


def test_the_rig_loop_steps_on_each_sample_the_device_sends(rig):
    """The driver's side (rwpend_loop.rig): the device is the sample clock; each sample read is
    one step, the command goes to the driver's claim at once; the u the estimator takes is the
    one the device says it held. A simulated device here, stepped as the firmware does."""
    from rwpend_loop.rig import DriverGate, LinkReading

    class Driver:                       # the one way to the device: DriverNode._offer
        def __init__(self):
            self.core = SimCore(rig, command_timeout_samples=3)
            self.sent = []

        def _offer(self, source, seq, u, release=False):
            self.sent.append((source, seq))
            return self.core.command(seq, u)[0]

    drv = Driver()
    hw = LinkReading()
    est = EstimatorStage(make_estimator(None, rig, EstimatorConfig.from_values({}, rig=rig)))
    ctrl = ControllerStage(Controller(rig, ControllerConfig.designed(rig), mode='auto'), ID)
    loop = Loop(hw, DriverGate(drv), est, ctrl, rig.sample_period)
    u_held = 0.0
    for _ in range(8000):
        seq, pc, mc = drv.core.sample()
        hw.set(seq, pc, mc, u_held)
        tick = loop.step(t=seq * rig.sample_period)
        assert tick.taken and drv.sent[-1] == (ID, seq)
        u_held = drv.core.advance()
    s = drv.core.plant.state
    assert abs(math.remainder(s.theta - math.pi, 2 * math.pi)) < 0.05, 'swung up and balanced'
    assert loop.gate.interval(False) == 0.0 and loop.gate.take_event() is None


def test_the_loop_fed_by_the_encoders_topic_gives_the_commands_of_the_plants_own_loop(rig):
    """rwpend_loop.control: the estimator and the controller as a loop whose hardware is the
    ``encoders`` topic (the plant elsewhere takes the commands through its own gate) answer
    every sample with the command the loop with the plant's own hardware gives -- the u of
    each sample taken from the commands this side sent (CommandAlignment)."""
    from rwpend_estimation.alignment import CommandAlignment
    from rwpend_loop.control import TopicGate, TopicReading
    ref = []
    run_lockstep(make_loop(rig), 3000, lambda t: ref.append((t.reading.seq, t.u)))
    # the plant: its own loop without estimator and controller, taking commands as from the topic
    plant = make_loop(rig, controller=False)
    plant.estimator = None
    align = CommandAlignment(rig.u_max)
    reading = TopicReading(align)
    est = EstimatorStage(make_estimator(None, rig, EstimatorConfig.from_values({}, rig=rig)))
    ctrl = ControllerStage(Controller(rig, ControllerConfig.designed(rig), mode='auto'), ID)
    side = Loop(reading, TopicGate(), est, ctrl, rig.sample_period)
    got = []
    for _ in range(3000):
        sample = plant.step().reading                      # encoders k out
        reading.set(sample.seq, sample.pendulum_counts, sample.motor_counts)
        tick = side.step()                                 # the other process: estimate, control
        if tick.u is not None:
            align.command(sample.seq, tick.u)              # ... and the command back on the topic
            plant.gate.offer(ID, sample.seq, tick.u)
        got.append((sample.seq, tick.u))
    assert got == ref
    assert reading.read().u_prev == align.command_for(2999)
