"""Closed-loop simulation of a :class:`Controller` on the :class:`rwpend_model.plant.Plant` (pure).

Test support for the controller's unit tests (the stack's loop is rwpend_loop.loop; this one
feeds the controller alone, without the estimator's code): one ``Plant.step`` per sample with the
command computed from either the true plant state or a state built from the quantized encoder
counts with the filtered difference of Section 3.3, ``y_f(t) = T/(T+h) y_f(t-h) + (y(t) - y(t-h))/(T+h)``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable


class CountsState:
    """State from the encoder counts: angles count * delta, rates by the filtered difference (3.3)."""

    def __init__(self, rig, pendulum_counts: int, motor_counts: int, T: float = 0.01) -> None:
        h = rig.sample_period
        self.delta = rig.count_angle
        self.a1 = T / (T + h)
        self.b1 = 1.0 / (T + h)
        self.theta = pendulum_counts * self.delta
        self.wheel_angle = (pendulum_counts + motor_counts) * self.delta
        self.theta_dot = 0.0
        self.wheel_rate = 0.0

    def update(self, pendulum_counts: int, motor_counts: int) -> tuple[float, float, float, float]:
        th = pendulum_counts * self.delta
        thr = (pendulum_counts + motor_counts) * self.delta
        self.theta_dot = self.a1 * self.theta_dot + self.b1 * (th - self.theta)
        self.wheel_rate = self.a1 * self.wheel_rate + self.b1 * (thr - self.wheel_angle)
        self.theta, self.wheel_angle = th, thr
        return th, self.theta_dot, thr, self.wheel_rate


@dataclass
class Trace:
    """Sampled signals of a run (true plant state, the state fed to the controller, u, law)."""

    t: list = field(default_factory=list)
    theta: list = field(default_factory=list)
    theta_dot: list = field(default_factory=list)
    wheel_angle: list = field(default_factory=list)
    wheel_rate: list = field(default_factory=list)
    u: list = field(default_factory=list)
    law: list = field(default_factory=list)
    events: list = field(default_factory=list)      # (index, SwitchEvent, status, fed state)


def simulate(controller, plant, duration: float, feed: str = 'counts', T: float = 0.01,
             before_step: Callable[[int, object], None] | None = None, seq0: int = 0) -> Trace:
    """Run ``duration`` seconds; ``feed`` = 'counts' (quantized, filtered) or 'true'.

    ``before_step(k, plant)`` is called before sample k (e.g. to tap the pendulum).
    """
    if feed not in ('counts', 'true'):
        raise ValueError(f"feed must be 'counts' or 'true', got {feed!r}")
    n = int(round(duration / plant.h))
    tr = Trace()
    cs = CountsState(plant.rig, *plant.counts(), T=T) if feed == 'counts' else None
    if cs is not None:      # start the filters at the true rates (no start-up transient)
        s = plant.state
        cs.theta_dot, cs.wheel_rate = s.theta_dot, s.wheel_rate
    for k in range(n):
        if before_step is not None:
            before_step(k, plant)
        s = plant.state
        if cs is not None:
            th, thd, thr, wr = cs.update(*plant.counts())
        else:
            th, thd, thr, wr = s.theta, s.theta_dot, s.wheel_angle, s.wheel_rate
        # the true friction stands in for an estimator's friction estimate
        u, st = controller.update(plant.t, seq0 + k, th, thd, thr, wr, s.friction)
        if st.event is not None:
            tr.events.append((k, st.event, st, (th, thd, thr, wr)))
        tr.t.append(plant.t)
        tr.theta.append(s.theta)
        tr.theta_dot.append(s.theta_dot)
        tr.wheel_angle.append(s.wheel_angle)
        tr.wheel_rate.append(s.wheel_rate)
        tr.u.append(u)
        tr.law.append(st.law)
        plant.step(u)
    return tr


def balanced_since(trace: Trace, tol: float = 0.05, hold: float = 5.0) -> float | None:
    """First time from which |wrap(theta - pi)| < tol holds for ``hold`` seconds (None if never)."""
    start = None
    for t, th in zip(trace.t, trace.theta):
        x = math.remainder(th - math.pi, 2.0 * math.pi)
        if abs(x) < tol:
            if start is None:
                start = t
            if t - start >= hold:
                return start
        else:
            start = None
    return None
