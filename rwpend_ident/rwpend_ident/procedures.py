"""The identification's procedures, as laws of the controller's mode ``law`` (rwpend_control.user_law).

Each waits until the plant is at rest hanging (:func:`rwpend_ident.checks.rest_problem`) and then
runs its input from that moment; it refuses (raises :class:`~rwpend_ident.checks.NotReady`, the
controller turns off with the reason in ``controller/status``) when the plant is not at rest within
``rest_timeout`` s, when the speed loop saturates, or when the wheel does not break away.

The inputs themselves are the lab's procedures (rwpend_lab.procedures: ``OpenLoop`` for the
pulses of Experiment 3, ``WheelSpeedSteps`` for the PI speed control of Experiments 8-9), so the
lab and the identification run the same code.  Loaded as ``rwpend_ident.procedures:Name`` with
the parameters in ``law.params``.
"""
from __future__ import annotations

import dataclasses
from collections import deque

from rwpend_lab.procedures import OpenLoop, WheelSpeedSteps

from .checks import NotReady, Rest, rest_problem, saturation_problem


def rest_from(params) -> Rest:
    """The rest tolerances of a procedure's parameters (``still_s``, ``rest_tol``, ``hang_tol``,
    ``rest_timeout``; defaults of :class:`Rest`)."""
    d = Rest()
    return Rest(still_s=float(params.get('still_s', d.still_s)), tol=float(params.get('rest_tol', d.tol)),
                hang=float(params.get('hang_tol', d.hang)), timeout=float(params.get('rest_timeout', d.timeout)))


class RestWatch:
    """Says when the plant has been at rest for ``still_s``; NotReady after ``timeout`` s."""

    def __init__(self, rest: Rest, h: float) -> None:
        self.rest = rest
        n = max(2, int(round(rest.still_s / h)))
        self.theta: deque = deque(maxlen=n)
        self.rel: deque = deque(maxlen=n)
        self.since: float | None = None

    def at_rest(self, s) -> bool:
        if self.since is None:
            self.since = s.t
            self.theta.clear()
            self.rel.clear()
        self.theta.append(s.theta)
        self.rel.append(s.wheel_angle - s.theta)
        if len(self.theta) < self.theta.maxlen:
            return False
        why = rest_problem(list(self.theta), list(self.rel), self.rest)
        if why is None:
            self.since = None
            return True
        if s.t - self.since > self.rest.timeout:
            raise NotReady(f'{why} (waited {self.rest.timeout:g} s)')
        return False


class _AfterRest:
    """Wait for rest, then ``inner`` with its time counted from that moment."""

    def __init__(self, params, inner) -> None:
        self.watch = RestWatch(rest_from(params), float(params['h']))
        self.inner = inner
        self.t0: float | None = None

    def __call__(self, s) -> float:
        if self.t0 is None:
            if not self.watch.at_rest(s):
                return 0.0
            self.t0 = s.t
        return self.inner(dataclasses.replace(s, t=s.t - self.t0))


class Pulses(_AfterRest):
    """Torque pulses (Experiment 3) from rest: ``{"times": [...], "values": [...]}`` (s after the
    rest was found, control units), as the lab's OpenLoop."""

    def __init__(self, params) -> None:
        super().__init__(params, OpenLoop(params))


class WheelSpeeds(_AfterRest):
    """PI wheel-speed control (3.14)-(3.16) through a schedule of references from rest
    (Experiments 8-9, the lab's WheelSpeedSteps: ``kdr``, ``ki``, ``times``, ``refs``); refuses when
    |u| has stayed at u_max for ``max_saturation_s`` (0.3 s) while the wheel sped up in the
    direction of u by less than ``min_acceleration`` (30 rad/s^2) -- the friction takes all the
    amplifier gives.
    A saturated command that still accelerates the wheel is a catch-up (after a ramp, or after
    samples the motor held at 0 on a late loop), not a refusal."""

    def __init__(self, params) -> None:
        super().__init__(params, WheelSpeedSteps(params))
        self.u_max = float(params['u_max'])
        self.limit = float(params.get('max_saturation_s', 0.3))
        self.min_gain = float(params.get('min_acceleration', 30.0)) * self.limit
        self.h = float(params['h'])
        #: the wheel speed in the direction of u over the last ``limit`` s of saturation
        self.speeds: deque = deque(maxlen=max(2, int(round(self.limit / self.h)) + 1))

    def __call__(self, s) -> float:
        u = super().__call__(s)
        if abs(u) < self.u_max:
            self.speeds.clear()
            return u
        self.speeds.append(s.wheel_rate if u > 0 else -s.wheel_rate)
        if len(self.speeds) == self.speeds.maxlen:
            why = saturation_problem(self.speeds[-1] - self.speeds[0], self.min_gain, self.limit,
                                     f'at a wheel speed of {s.wheel_rate:.0f} rad/s')
            if why:
                raise NotReady(why)
        return u


class BreakawayRamps:
    """Slow torque ramps from rest, one per sign in ``signs``, at ``rate`` units/s: each stops
    (u = 0) as soon as the rotor turns relative to the pendulum faster than ``slip_speed`` rad/s --
    the static friction (stiction) is the torque at which it broke away.  Refuses when it does not
    break away below ``u_limit``."""

    def __init__(self, params) -> None:
        self.rest = rest_from(params)
        self.h = float(params['h'])
        self.signs = [1.0 if float(x) > 0 else -1.0 for x in params.get('signs', [1, -1])]
        self.rate = float(params.get('rate', 1.0))
        self.slip = float(params.get('slip_speed', 5.0))
        self.u_limit = float(params.get('u_limit', 5.0))
        self.watch = RestWatch(self.rest, self.h)
        self.t0: float | None = None

    def __call__(self, s) -> float:
        if not self.signs:
            return 0.0
        if self.t0 is None:
            if self.watch.at_rest(s):
                self.t0 = s.t
            return 0.0
        u = self.signs[0] * self.rate * (s.t - self.t0)
        if abs(s.wheel_rate - s.theta_dot) > self.slip:
            self.signs.pop(0)
            self.t0 = None
            return 0.0
        if abs(u) > self.u_limit:
            raise NotReady(f'the wheel did not break away up to |u| = {self.u_limit:g}: is it blocked?')
        return u
