"""The loop of the rig, one sample as plain calls (pure: no rclpy).

Like ros2_control's controller manager, which runs hardware ``read()`` -> the controllers'
``update()`` -> hardware ``write()`` in one thread, one sample k here is

    hardware.read()             encoder counts of t_k (and the command held over [t_k-1, t_k))
    -> estimator.estimate()     state estimate of sample k (Chapters 3 and 7)
    -> controller.control()     command u_k (modes, switching, limits; rwpend_control.supervisor)
    -> gate.offer()             one controller (claim), freshness, e-stop, |u| <= u_max, loop health
    -> hardware.write()         u_k held over [t_k, t_k+1) (the simulator integrates the interval)

in one thread, in that order, without a message between the stages. The nodes publish what the
sample produced (encoders, state, command, status ...) for observers, after the command is
written (:class:`Tick`): a topic is never on the sample's path.

Two ways to run it, one implementation: :func:`run_lockstep` (a plain loop: as fast as the CPU
goes, the same samples every run) and, in real time, a :class:`rwpend_loop.pacer.Pacer` that
calls :meth:`Loop.step` at absolute deadlines and tells it when the computation of sample k
ended after t_k+1 (``late``): the plant then integrated [t_k, t_k+1) with the command it held
before, exactly as a rig whose PC answered late, and the sample is counted late.

A stage may also be outside the loop (a controller of one's own, another host): ``controller``
None -- the loop then stops after the estimate (the node publishes ``state``) and the command
comes back through the gate from the ``command`` topic (:meth:`CommandGate.offer`), in time for
the next instant or not (then the plant holds the previous command, or zero after
``command_timeout_samples``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Optional

from rwpend_ros.gate import CommandGate
from rwpend_sim.sim_core import Reading, SimHardware
from rwpend_estimation.estimators import DuplicateSampleError, Estimate


class EstimatorStage:
    """The estimator in the loop: ``est`` (rwpend_estimation.estimators; the node swaps it when
    its parameters change) stepped once per sample; a refused sample gives no estimate (the
    controller is then not run for it and the plant's command timeout holds)."""

    def __init__(self, est) -> None:
        self.est = est
        self.samples = 0
        self.errors = 0
        self.last_error = ''

    def estimate(self, seq: int, pendulum_counts: int, motor_counts: int, u: float) -> Optional[Estimate]:
        try:
            e = self.est.step(pendulum_counts, motor_counts, u, seq)
        except DuplicateSampleError:
            return None                         # counted in gap_stats
        except ValueError as exc:
            self.errors += 1
            self.last_error = f'seq {seq}: {exc}'
            return None
        self.samples += 1
        return e


class ControllerStage:
    """The controller in the loop: ``ctrl`` (rwpend_control.supervisor.Controller) with the
    id it claims the rig with. An error inside a law gives u = 0 and a status that says so."""

    def __init__(self, ctrl, controller_id: int) -> None:
        self.ctrl = ctrl
        self.controller_id = controller_id
        self.law_errors = 0

    def control(self, t: float, seq: int, e: Estimate, now: float):
        ctrl = self.ctrl
        try:
            u, st = ctrl.update(t, seq, e.theta, e.theta_dot, e.wheel_angle, e.wheel_rate, e.friction,
                                now, e.resyncs)
        except Exception as exc:  # noqa: BLE001 - a fault in a law: zero torque, reported
            self.law_errors += 1
            u, st = 0.0, ctrl.internal_error(t, seq, exc)
        if not math.isfinite(u) or abs(u) > ctrl.u_max:   # pragma: no cover - saturated by update
            u = 0.0
        return u, st


@dataclass(slots=True)
class Tick:
    """What one sample produced, for the nodes to publish after the write (made every sample:
    slots, and :meth:`Loop.step` gives the fields by position)."""

    reading: Reading
    t: float
    estimate: Optional[Estimate] = None
    u: Optional[float] = None           # the command computed (None: no controller in the loop, or no estimate)
    status: object = None               # rwpend_control.supervisor.Status of the controller
    taken: bool = False                 # the gate took u
    late: bool = False                  # u was computed after the next instant


class Loop:
    """One sample = read -> estimate -> control -> gate -> write (module doc). ``estimator`` and
    ``controller`` may be None (that stage runs elsewhere and talks through its topic)."""

    def __init__(self, hardware: SimHardware, gate: CommandGate, estimator: Optional[EstimatorStage],
                 controller: Optional[ControllerStage], h: float) -> None:
        if controller is not None and estimator is None:
            raise ValueError('a controller in the loop needs the estimator in the loop')
        self.hardware = hardware
        self.gate = gate
        self.estimator = estimator
        self.controller = controller
        self.h = h
        self._advanced = True           # the interval before the next sample is integrated
        self.samples = 0
        self.late = 0                   # samples whose command was computed after the next instant

    def step(self, behind: Callable[[], bool] | None = None, now: float | None = None,
             t: float | None = None) -> Tick:
        """Sample k: the interval before it is integrated first (with the command the gate
        holds: the loop's own, or one that came through the topic). ``behind()`` (real time):
        True when the next instant has passed -- then the plant integrates [t_k, t_k+1) before
        the command is offered (it held the previous one, the sample is late). ``now``: the
        wall time for the controller's watchdog (None: the sample time); ``t``: the sample's
        time (s; None: seq h)."""
        if not self._advanced:
            self.gate.interval(False)
        self._advanced = False
        r = self.hardware.read()
        if t is None:
            t = r.seq * self.h
        if self.estimator is None:
            return Tick(r, t)
        e = self.estimator.estimate(r.seq, r.pendulum_counts, r.motor_counts, r.u_prev)
        if self.controller is None or e is None:
            return Tick(r, t, e)
        u, st = self.controller.control(t, r.seq, e, t if now is None else now)
        if not st.answer:
            return Tick(r, t, e, None, st)
        late = False if behind is None else bool(behind())
        if late:
            self.late += 1
            self.gate.interval(True)
            self._advanced = True
        taken = self.gate.offer(self.controller.controller_id, r.seq, u)
        self.samples += 1
        return Tick(r, t, e, u, st, taken, late)

    def finish_interval(self, late: bool = False) -> None:
        """Integrate the interval after the newest sample (the end of a run, or a loop that
        waits for an external command in lockstep)."""
        if not self._advanced:
            self.gate.interval(late=late)
            self._advanced = True

    @property
    def interval_pending(self) -> bool:
        return not self._advanced


def run_lockstep(loop: Loop, samples: int, on_tick: Callable[[Tick], None] | None = None) -> int:
    """Run ``samples`` samples as fast as the CPU goes (deterministic: nothing depends on the
    wall clock); ``on_tick`` gets each sample's :class:`Tick` after its command is written.
    Returns the samples run."""
    for _ in range(samples):
        tick = loop.step()
        if on_tick is not None:
            on_tick(tick)
    loop.finish_interval()
    return samples
