"""One run of a study: the loop of :mod:`rwpend_loop.loop` in lockstep, then its metrics (pure).

The loop is built from the same classes the loop's process (:mod:`rwpend_loop.host`) builds
from the nodes' parameters -- the simulator's :class:`SimCore` and :class:`SimHardware`, the
:class:`CommandGate` with its claim and loop health, the estimator of
:func:`make_estimator`, the supervisor :class:`Controller` -- and it is stepped as the host's
lockstep loop steps it (sample k at t = k * period_ns * 1e-9, the interval after a sample
integrated before the next, until the simulator's ``duration``): the samples are those of
``./rwpend up --lockstep --duration D --mode M`` (a test compares them with its bag).

Two perturbations the simulator does not have sit between the plant and the loop, only when
asked: :class:`PerturbedHardware` adds Gaussian noise to the encoder counts
(``sensor.noise_counts``) and applies each command ``command.delay_samples`` samples late.

:func:`run_one` runs one run alone; :func:`run_many` (a worker's task) steps its runs together,
their plants one numpy batch (:mod:`rwpend_sweep.batch`), each row the one :func:`run_one` gives.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace
import numpy as np

from rwpend_control.supervisor import Controller
from rwpend_estimation.estimators import make_estimator
from rwpend_loop.loop import ControllerStage, EstimatorStage, Loop
from rwpend_ros.claim import CommandClaim
from rwpend_ros.gate import CommandGate
from rwpend_ros.health import LoopHealth
from rwpend_sim.sim_core import SimCore, SimHardware

from .build import RunSetup
from .metrics import metrics

#: the metric columns of a row, in order (rwpend_sweep.metrics)
METRICS = ('success', 'time_to_balance', 'balance_rms', 'control_rms', 'saturation_share',
           'max_wheel_speed', 'reason')


class PerturbedHardware:
    """The simulated rig behind sensor noise and a command delay (the loop's hardware interface:
    ``k``, ``read``, ``write``, ``advance``, ``timed_out``, ``no_command``, ``u_max``).

    Noise: each encoder reading plus round(N(0, sd)) counts. Delay d: the command answering
    sample k is handed to the plant at sample k + d as fresh (so the plant's freshness rule does
    not refuse it); the estimator is told the command the controller sent last (it does not know
    of the delay), as on a rig whose amplifier answers late."""

    def __init__(self, hw: SimHardware, noise_counts: float, delay: int, seed) -> None:
        self.hw = hw
        self.core = hw.core
        self.u_max = hw.u_max
        self.sd = float(noise_counts)
        self.delay = int(delay)
        self.rng = np.random.default_rng(list(seed))
        self._pending: list[tuple[int, float]] = []
        self._sent = 0.0

    @property
    def k(self) -> int:
        return self.hw.k

    @property
    def timed_out(self) -> bool:
        return self.hw.timed_out

    def read(self):
        r = self.hw.read()
        if self.sd > 0:
            dp, dm = np.rint(self.rng.normal(0.0, self.sd, 2)).astype(int)
            r = replace(r, pendulum_counts=r.pendulum_counts + int(dp), motor_counts=r.motor_counts + int(dm))
        if self.delay:
            r = replace(r, u_prev=self._sent)
        return r

    def write(self, seq: int, u: float):
        if not self.delay:
            return self.hw.write(seq, u)
        if not math.isfinite(u):
            return self.hw.write(seq, u)          # refused by the plant, with its reason
        m = self.u_max
        self._pending.append((seq, u))
        self._sent = m if u > m else (-m if u < -m else u)
        return True, ''

    def advance(self) -> float:
        if self.delay:
            k = self.hw.k
            due = None
            while self._pending and self._pending[0][0] <= k - self.delay:
                due = self._pending.pop(0)
            if due is not None:
                self.hw.write(k, due[1])          # fresh for the plant: it answers "now"
        return self.hw.advance()

    def no_command(self) -> None:
        self._pending.clear()
        self.hw.no_command()


def build_loop(setup: RunSetup, truth: bool = True) -> Loop:
    """The loop of one run (as rwpend_loop.host builds it from the nodes); ``truth`` False: its
    readings without the plant's truth (SimHardware's ``truth``)."""
    s = setup
    ini = s.initial
    core = SimCore(s.truth, command_timeout_samples=s.sim['command_timeout_samples'],
                   theta=ini['theta'], theta_dot=ini['theta_dot'], wheel_angle=ini['wheel_angle'],
                   wheel_rate=ini['wheel_rate'])
    if s.taps:
        core.schedule_taps([t for t, _ in s.taps], [dv for _, dv in s.taps])
    if s.torques:
        core.schedule_torques([t for t, _, _ in s.torques], [d for _, d, _ in s.torques],
                              [dur for _, _, dur in s.torques])
    hw = SimHardware(core, truth=truth)
    if s.noise_counts > 0 or s.delay:
        hw = PerturbedHardware(hw, s.noise_counts, s.delay, s.noise_seed)
    # in lockstep the simulator's loop health counts in units of its lockstep_timeout
    gate = CommandGate(hw, CommandClaim(s.sim['claim_timeout_samples']),
                       LoopHealth(s.sim['lockstep_timeout'], dead_after_s=s.sim['loop_dead_after']))
    est = EstimatorStage(make_estimator(None, s.model, s.estimator))
    user_law = _law(s.law, s.model) if s.law else None
    ctrl = Controller(s.model, s.controller, user_law=user_law)
    ok, msg = ctrl.set_mode(s.mode)
    if not ok:
        raise ValueError(msg)
    return Loop(hw, gate, est, ControllerStage(ctrl, s.controller_id), s.model.sample_period)


def _law(law: tuple, rig):
    from rwpend_control.user_law import load_law
    # a fresh instance per run (a Law class keeps state), loaded from its file in this process
    return load_law(law[0], law[1], rig)


@dataclass
class Trace:
    """Per-sample record of a run (what the bag of the same run has: the encoder counts and the
    command of every sample, and the plant's truth)."""

    seq: np.ndarray
    pendulum_counts: np.ndarray
    motor_counts: np.ndarray
    u: np.ndarray              # the command of the sample (nan: none)
    theta: np.ndarray          # truth at t_k
    theta_dot: np.ndarray
    wheel_rate: np.ndarray
    saturated: np.ndarray


def simulate(setup: RunSetup, trace: bool = False):
    """Run the loop for the scenario's duration; returns (arrays, loop)."""
    loop = build_loop(setup)
    core = loop.hardware.core
    h = setup.truth.sample_period
    period_ns = int(round(h * 1e9))
    duration = setup.duration
    th, thd, wr, us, sat = [], [], [], [], []
    seqs, pcs, mcs = [], [], []
    k = 0
    step, finish = loop.step, loop.finish_interval    # finish: integrates the interval if pending
    plant = core.plant
    end = duration - 1e-9
    th_, thd_, wr_, us_, sat_ = th.append, thd.append, wr.append, us.append, sat.append
    while True:
        finish()
        if plant.t >= end:                    # the simulator's done()
            break
        tick = step(None, None, k * period_ns * 1e-9)       # t: the sample's time
        tr = tick.reading.truth
        th_(tr.theta)
        thd_(tr.theta_dot)
        wr_(tr.wheel_rate)
        u = tick.u
        us_(u if u is not None else 0.0)
        st = tick.status
        sat_(st is not None and st.saturated)
        if trace:
            r = tick.reading
            seqs.append(r.seq)
            pcs.append(r.pendulum_counts)
            mcs.append(r.motor_counts)
        k += 1
    arrays = Trace(np.asarray(seqs, dtype=np.int64), np.asarray(pcs, dtype=np.int64),
                   np.asarray(mcs, dtype=np.int64), np.asarray(us), np.asarray(th), np.asarray(thd),
                   np.asarray(wr), np.asarray(sat, dtype=bool))
    return arrays, loop


def run_one(setup: RunSetup, success) -> dict:
    """The metrics of one run (``success``: rwpend_sweep.spec.Success); an exception in the run
    is a failed run with the error as its reason."""
    t0 = time.process_time()
    try:
        arrays, loop = simulate(setup)
    except Exception as exc:  # noqa: BLE001 - one run's error is that run's result
        row = {m: float('nan') for m in METRICS}
        row.update(success=False, reason=f'error: {type(exc).__name__}: {exc}')
        row['cpu_s'] = time.process_time() - t0
        return row
    row = metrics(arrays, loop.controller.ctrl, setup, success)
    row['cpu_s'] = time.process_time() - t0
    return row


def run_many(items: list) -> list[tuple[int, dict]]:
    """[(index, setup, success), ...] -> [(index, row), ...] (one task of a pool or a cluster):
    the rows of :func:`run_one`, the runs' plants stepped together (:mod:`rwpend_sweep.batch`)."""
    from .batch import run_batch
    return run_batch(items)


def samples_of(setup: RunSetup) -> Trace:
    """The per-sample trace of a run (for comparison with a bag of the same run)."""
    return simulate(setup, trace=True)[0]
