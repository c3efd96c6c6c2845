"""The lab's own procedures as laws of mode ``law`` (rwpend_control.user_law): inputs that follow a
schedule in time, evaluated by the controller node on every sample's time, so a lockstep run is
reproducible.  Loaded as ``rwpend_lab.procedures:Name`` with the schedule in ``law.params``.

They reuse the controller's own laws (rwpend_control.laws); only the schedule is added.
"""
from __future__ import annotations

import bisect

from rwpend_control.laws import Balance, WheelVelocityPI


class _Schedule:
    """Piecewise constant value: values[i] from times[i] on (0 before times[0])."""

    def __init__(self, times, values) -> None:
        times, values = [float(t) for t in times], [float(v) for v in values]
        if len(times) != len(values) or not times or times != sorted(times):
            raise ValueError('schedule: times must be sorted and as many as values')
        self.times, self.values = times, values

    def __call__(self, t: float) -> float:
        i = bisect.bisect_right(self.times, t) - 1
        return self.values[i] if i >= 0 else 0.0


class OpenLoop:
    """u(t) from a schedule: ``{"times": [...], "values": [...]}`` (control units; Exp. 2-6)."""

    def __init__(self, params) -> None:
        self.u = _Schedule(params['times'], params['values'])

    def __call__(self, s) -> float:
        return self.u(s.t)


class WheelSpeedSteps:
    """PI wheel-speed control (3.14)-(3.16) to a reference that steps at given times (Exp. 8-9):
    ``{"kdr": .., "ki": .., "times": [...], "refs": [...]}``; ki = 0: the P law (3.13)."""

    def __init__(self, params) -> None:
        self.ref = _Schedule(params['times'], params['refs'])
        self.pi = WheelVelocityPI(params['kdr'], params.get('ki', 0.0), i_max=params['u_max'])

    def __call__(self, s) -> float:
        self.pi.ref = self.ref(s.t)
        return self.pi(s.wheel_rate)


class BalanceWheelSteps:
    """Upright state feedback (4.13) with a wheel-angle reference that steps at given times
    (Exp. 14): ``{"kpp", "kdp", "kpr", "kdr", "times": [...], "refs": [...]}`` (refs relative to
    the wheel angle at the start)."""

    def __init__(self, params) -> None:
        self.ref = _Schedule(params['times'], params['refs'])
        self.law = Balance(params['kpp'], params['kdp'], params['kpr'], params['kdr'])
        self.start = None

    def __call__(self, s) -> float:
        if self.start is None:
            self.start = s.wheel_angle
        self.law.wheel_ref = self.start + self.ref(s.t)
        return self.law(s.theta, s.theta_dot, s.wheel_angle, s.wheel_rate)
