"""Nonlinear model of the Reaction Wheel Pendulum, as the simulator and the device emulator run it.

Equations (2.11) in the normalized form (2.15), theta measured from hanging (Section 2.1):

    theta''   = -a sin(theta) - b_p (tau - F) + b_p d - c_p theta'
    theta_r'' =  b_r (tau - F)

* tau: motor torque actually applied, in control units (1 unit = k_u Nm, (2.14)):
  the command u held over the sample (zero-order hold), saturated to |u| <= u_max,
  optionally quantized to the PWM duty resolution (Section 2.5), filtered by the current
  loop's first-order lag T_e = 0.5 ms (Section 2.4) and cut to zero by the back-EMF limit
  (2.13) when the rotor turns faster than V_max/k_m relative to the pendulum in the
  direction of the torque.
* F: rotor friction in control units as a function of the relative speed
  w_rel = theta_r' - theta' (3.17, ERRATA E46), with stiction: while the rotor turns with
  the pendulum (w_rel = 0) it stays stuck as long as the friction needed to hold it is below
  the breakaway level (the free swing of Experiment 1, Fig. 2.2).  Stuck, both bodies move as
  one: (J + J_r) theta'' = -m g l sin(theta) + ..., i.e. frequency omega_p' (Section 2.3).
* c_p: viscous pendulum-axis friction, 1 / (energy time constant), Fig. 2.3 (~1 min).
* d: external torque on the pendulum in control units, entering as +b_p d (ERRATA E20).

Chapter 3 configuration (``bracket``, Fig. 3.1): the motor and wheel on the fixed bracket, the
pendulum locked hanging (theta = theta' = 0 for ever, taps and d do nothing); only the wheel
moves, theta_r'' = b_r (tau - F(theta_r')) (3.1) with the same friction and stiction (at rest the
bearing holds up to the breakaway level).  ``rotor_locked`` (with ``bracket``) holds the wheel
by a torque meter (Experiment 2, Fig. 2.4): the wheel never turns, the bearing takes what it can
of the torque (``friction`` = tau clamped to +-breakaway) and the meter the rest, k_u (tau - F).

Integration: classical Runge-Kutta 4 on sub-steps of at most 0.2 ms (the motor lag is the
exact exponential response inside a sample), with event handling of the stick/slip
transitions at the sub-step boundaries.  Energy drift with friction and input off:
< 1e-9 relative over 60 s (tested).

Encoders (Section 3.1): round(theta / delta), round((theta_r - theta) / delta),
delta = 2 pi / 4000; the simulated encoders were zeroed with the pendulum hanging at rest,
whatever the initial state, so counts are absolute angles from hanging.

Pure Python (math only, no numpy in the per-sample path): no rclpy.  The equations are written
once, as functions of the plant's constants and state that take floats or numpy arrays alike
(:func:`free_derivative`, :func:`free_substep`, :func:`stuck_substep` ...): :class:`Plant` steps
one rig with them, rwpend_sweep.batch many rigs at once, bit for bit the same.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from .rig import Rig

#: Longest integration sub-step (s).
MAX_SUBSTEP = 0.0002


@dataclass
class PlantState:
    """Ground truth of the simulated rig (angles from hanging, rad and rad/s; torques in units)."""

    theta: float = 0.0
    theta_dot: float = 0.0
    wheel_angle: float = 0.0
    wheel_rate: float = 0.0
    torque: float = 0.0        # applied motor torque (control units), after lag and cut-off
    friction: float = 0.0      # rotor friction acting (control units)
    stuck: bool = False        # rotor stuck to the pendulum


# ---------------------------------------------------------------------- the model, written once
# The functions below are the plant's equations for one rig (a :class:`Plant`, plain floats) or
# for many at once (rwpend_sweep.batch: one numpy array per constant and per state variable, a
# rig per element). ``p`` holds the constants under the names Plant gives them (_na = -a, _bp,
# _br, _cp, _stuck_gain, _wmax, _nwmax = -omega_max, _cpos, _vpos, _ncneg = -c_neg, _vneg, _dt,
# _decay, _half_decay, the flags friction_on and back_emf, and _push = b_p d of the disturbance
# d); ``sin`` is math.sin or numpy.sin and ``where(c, a, b)`` is :func:`pick` or numpy.where -- a
# branch only where the scalar model branches, both sides computed (no side effects). Elementwise
# + - * / and the comparisons are the same IEEE operations for floats and float64 arrays, and the
# operations come in the same order: the two give the same bits (rwpend_sweep/test/test_batch.py).


def pick(c, a, b):
    """``where`` of plain floats: a if c else b."""
    return a if c else b


def pwm_quantize(p, u, floor=math.floor):
    """The command u (|u| <= u_max) at the PWM duty resolution (Section 2.5): the nearest
    multiple of u_max / pwm_steps (``p._pwm_q``, not zero)."""
    return floor(u / p._pwm_q + 0.5) * p._pwm_q


def kinetic_friction(p, w, where=pick):
    """Rotor friction F (control units) while the rotor slips at relative speed w = w_rel
    (3.17, ERRATA E46): c+ + v+ w above zero, -c- + v- w below, zero at zero."""
    return where(w > 0.0, p._cpos + p._vpos * w, where(w < 0.0, p._ncneg + p._vneg * w, 0.0))


def torque_available(p, tau, w, where=pick):
    """Back-EMF cut-off (2.13): no torque in the direction of motion beyond V_max/k (w: the
    rotor's speed relative to the pendulum)."""
    return where(p.back_emf and (((tau > 0.0) & (w > p._wmax)) | ((tau < 0.0) & (w < p._nwmax))), 0.0, tau)


def free_derivative(p, th, thd, thrd, tau, sin=math.sin, where=pick):
    """(theta'', theta_r'', F) of (2.15) with the rotor turning freely: theta'' = -a sin(theta)
    + b_p d - c_p theta' - b_p (tau - F), theta_r'' = b_r (tau - F), tau after the back-EMF
    cut-off (2.13), F the kinetic friction (3.17) (zero with friction off)."""
    w = thrd - thd
    tau = torque_available(p, tau, w, where)
    f = kinetic_friction(p, w, where) if p.friction_on else 0.0
    grav = p._na * sin(th) + p._push - p._cp * thd
    g = tau - f
    return grav - p._bp * g, p._br * g, f


def stuck_acceleration(p, th, thd, sin=math.sin):
    """theta'' = theta_r'' with the rotor stuck to the pendulum, one rigid body (Section 2.3):
    J / (J + J_r) (-a sin(theta) + b_p d - c_p theta')."""
    return (p._na * sin(th) + p._push - p._cp * thd) * p._stuck_gain


def stuck_derivative(p, th, thd, thrd, tau, sin=math.sin, where=pick):
    """(theta'', theta_r'', F) with the rotor stuck to the pendulum (:func:`stuck_acceleration`),
    F the friction the bearing must supply to hold the rotor, tau - theta_r'' / b_r."""
    tau = torque_available(p, tau, thrd - thd, where)
    acc = stuck_acceleration(p, th, thd, sin)
    return acc, acc, tau - acc / p._br


def lag_response(p, tau0, u):
    """The current loop's first-order lag T_e (Section 2.4), its exact response to the held
    command u over a sub-step from the torque tau0: (torque at the middle, at the end)."""
    return u + (tau0 - u) * p._half_decay, u + (tau0 - u) * p._decay


def free_substep(p, deriv, th, thd, thr, thrd, tau0, tau_mid, tau1):
    """One classical RK4 sub-step of dt = p._dt of the rotor turning freely: (theta, theta',
    theta_r, theta_r') after it. ``deriv(theta, theta', theta_r', tau)`` gives (theta'',
    theta_r''); the motor torque is tau0, tau_mid, tau1 at the sub-step's start, middle, end."""
    dt = p._dt
    a1, r1 = deriv(th, thd, thrd, tau0)
    a2, r2 = deriv(th + 0.5 * dt * thd, thd + 0.5 * dt * a1, thrd + 0.5 * dt * r1, tau_mid)
    a3, r3 = deriv(th + 0.5 * dt * thd + 0.25 * dt * dt * a1, thd + 0.5 * dt * a2,
                   thrd + 0.5 * dt * r2, tau_mid)
    a4, r4 = deriv(th + dt * thd + 0.5 * dt * dt * a2, thd + dt * a3, thrd + dt * r3, tau1)
    th = th + dt * (thd + dt / 6.0 * (a1 + a2 + a3))
    thr = thr + dt * (thrd + dt / 6.0 * (r1 + r2 + r3))
    thd = thd + dt / 6.0 * (a1 + 2 * a2 + 2 * a3 + a4)
    thrd = thrd + dt / 6.0 * (r1 + 2 * r2 + 2 * r3 + r4)
    return th, thd, thr, thrd


def stuck_substep(p, acc, th, thd, thr, tau0, u):
    """One RK4 sub-step of the rotor stuck to the pendulum, one rigid body (Section 2.3): theta
    integrated, the rotor follows; (theta, theta', theta_r, theta_r', tau) after it.
    ``acc(theta, theta', theta_r', tau)`` gives theta'' (:func:`stuck_acceleration`)."""
    dt = p._dt
    tau_mid, tau1 = lag_response(p, tau0, u)
    k1 = acc(th, thd, thd, tau0)
    k2 = acc(th + 0.5 * dt * thd, thd + 0.5 * dt * k1, 0.0, tau_mid)
    k3 = acc(th + 0.5 * dt * (thd + 0.5 * dt * k1), thd + 0.5 * dt * k2, 0.0, tau_mid)
    k4 = acc(th + dt * (thd + 0.5 * dt * k2), thd + dt * k3, 0.0, tau1)
    dth = dt * (thd + dt / 6.0 * (k1 + k2 + k3))
    thd_new = thd + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)
    return th + dth, thd_new, thr + dth, thd_new, tau1


def crossed_zero(w0, w1):
    """The relative speed reached or crossed zero over a sub-step (w0 before, w1 after): the
    rotor may stick (3.17)."""
    return (w0 == 0.0) | (w1 == 0.0) | ((w0 > 0.0) != (w1 > 0.0))


def stick_velocity(j_ratio, thd, thrd):
    """The common speed of pendulum and rotor when the rotor sticks, momentum-conserving:
    j theta' + (1 - j) theta_r', j = J / (J + J_r)."""
    return j_ratio * thd + (1.0 - j_ratio) * thrd


class Plant:
    """The reaction wheel pendulum (2.11)/(2.15) with friction, amplifier and encoders.

    ``step(u)`` advances one sample period h with u held; ``counts()`` reads the encoders.
    """

    def __init__(self, rig: Rig, *, theta: float = 0.0, theta_dot: float = 0.0,
                 wheel_angle: float = 0.0, wheel_rate: float = 0.0, friction: bool = True,
                 pendulum_friction: bool | None = None, motor_lag: bool = True,
                 pwm: bool = True, back_emf: bool = True, bracket: bool = False,
                 rotor_locked: bool = False) -> None:
        if rotor_locked and not bracket:
            raise ValueError('rotor_locked (the torque meter of Experiment 2) needs bracket')
        if bracket and (theta != 0.0 or theta_dot != 0.0):
            raise ValueError('bracket: the pendulum is locked hanging, theta and theta_dot must be 0')
        if rotor_locked and wheel_rate != 0.0:
            raise ValueError('rotor_locked: the wheel is held, wheel_rate must be 0')
        for name, v in (('theta', theta), ('theta_dot', theta_dot), ('wheel_angle', wheel_angle),
                        ('wheel_rate', wheel_rate)):
            if not math.isfinite(v):
                raise ValueError(f'initial {name} must be finite, got {v!r}')
        self.rig = rig
        self.friction_on = bool(friction)
        self.pendulum_friction_on = self.friction_on if pendulum_friction is None else bool(pendulum_friction)
        self.motor_lag = bool(motor_lag) and rig.motor_time_constant > 0
        self.pwm = bool(pwm) and rig.pwm_steps > 0
        self.back_emf = bool(back_emf)
        self.bracket = bool(bracket)
        self.rotor_locked = bool(rotor_locked)
        self.h = rig.sample_period
        n = max(1, math.ceil(self.h / MAX_SUBSTEP - 1e-9))
        self._n = n
        self._dt = self.h / n
        # model constants
        self._a = rig.a
        self._na = -self._a
        self._bp = rig.b_p
        self._br = rig.b_r
        self._cp = rig.pendulum_damping if self.pendulum_friction_on else 0.0
        self._stuck_gain = rig.b_r / (rig.b_r + rig.b_p)     # J / (J + J_r)
        self._wmax = rig.omega_max
        self._nwmax = -self._wmax
        self._umax = rig.u_max
        self._pwm_q = rig.u_max / rig.pwm_steps if self.pwm else 0.0
        self._te = rig.motor_time_constant if self.motor_lag else 0.0
        te, dt = self._te, self._dt
        # the motor lag's exact response over a sub-step and half of one (the same for every sample)
        self._decay = math.exp(-dt / te) if te > 0 else 0.0
        self._half_decay = math.exp(-0.5 * dt / te) if te > 0 else 0.0
        self._cpos, self._vpos = rig.friction_coulomb_pos, rig.friction_viscous_pos
        self._cneg, self._vneg = rig.friction_coulomb_neg, rig.friction_viscous_neg
        self._ncneg = -self._cneg
        self._fbreak = rig.friction_breakaway
        self._delta = rig.count_angle
        # state
        self._x = [float(theta), float(theta_dot), float(wheel_angle), float(wheel_rate)]
        self._tau = 0.0
        self._stuck = self.friction_on and wheel_rate == theta_dot
        self._friction = 0.0
        self.disturbance = 0.0
        self.t = 0.0
        self.u_held = 0.0
        self._free = None               # the sub-steps of free motion (_free_run) ...
        self._free_for = None           # ... made for this disturbance

    @property
    def _push(self) -> float:
        """b_p d: the disturbance d on the pendulum in (2.15) (ERRATA E20)."""
        return self._bp * self.disturbance

    # ------------------------------------------------------------------ inputs
    def quantize_command(self, u: float) -> float:
        """The command the amplifier realises: 0 if not finite, saturated, PWM-quantized (2.14)."""
        if not math.isfinite(u):
            return 0.0
        umax = self._umax
        u = umax if u > umax else (-umax if u < -umax else u)
        if self._pwm_q:
            u = pwm_quantize(self, u)
        return u

    def tap(self, dv: float) -> None:
        """Impulsive tap on the pendulum: theta' jumps by dv (rad/s); the rotor slips."""
        if not math.isfinite(dv):
            raise ValueError(f'tap must be finite, got {dv!r}')
        if self.bracket:
            raise ValueError('bracket: the pendulum is locked, it cannot be tapped')
        self._x[1] += dv
        if dv != 0.0:
            self._stuck = False

    def hold(self, theta: float) -> None:
        """A hand holds the pendulum still at ``theta`` (rad from hanging) and lets go -- the
        student steadying it between steps, or lifting it for the free swing of Experiment 1: the
        rotor comes to rest with it, its angle relative to the pendulum kept, stuck again."""
        if not math.isfinite(theta):
            raise ValueError(f'hold angle must be finite, got {theta!r}')
        if self.bracket:
            raise ValueError('bracket: the pendulum is locked, it cannot be held elsewhere')
        th, _, thr, _ = self._x
        self._x = [float(theta), 0.0, thr - th + float(theta), 0.0]
        self._stuck = self.friction_on

    # ------------------------------------------------------------------ model
    def _kinetic_friction(self, w: float) -> float:
        """:func:`kinetic_friction` (3.17) of this rig."""
        return kinetic_friction(self, w)

    def _torque_available(self, tau: float, w: float) -> float:
        """:func:`torque_available`: the back-EMF cut-off (2.13) of this rig."""
        return torque_available(self, tau, w)

    def _deriv(self, th, thd, thrd, tau, stuck):
        """(theta'', theta_r'', F) for the given state and applied torque: (2.15) through
        :func:`free_derivative` or :func:`stuck_derivative`, or the bracket's wheel alone."""
        if self.bracket:   # Fig. 3.1: pendulum locked, theta'' = 0; the wheel alone (3.1)
            w = thrd - thd
            tau = self._torque_available(tau, w)
            if stuck:
                return 0.0, 0.0, tau
            f = self._kinetic_friction(w) if self.friction_on else 0.0
            return 0.0, self._br * (tau - f), f
        return (stuck_derivative if stuck else free_derivative)(self, th, thd, thrd, tau)

    def _free_substep_plain(self, th, thd, thr, thrd, tau0, tau_mid, tau1):
        """One RK4 sub-step of dt of the rotor turning freely (not stuck): (theta, theta',
        theta_r, theta_r') after it, with the motor torque tau0, tau_mid, tau1 at its start,
        middle and end (the lag's exact response).  The plain form, :func:`free_substep`
        through :meth:`_deriv` (2.15); :meth:`_free_run` does the same arithmetic without the
        calls."""
        def d(th, thd, thrd, tau):
            return self._deriv(th, thd, thrd, tau, False)[:2]
        return free_substep(self, d, th, thd, thr, thrd, tau0, tau_mid, tau1)

    def _free_run_plain(self, th, thd, thr, thrd, tau0, u, n):
        """Up to ``n`` sub-steps of free motion from the motor torque tau0 with the command u
        held: (theta, theta', theta_r, theta_r', tau, sub-steps done, crossed).  Stops after a
        sub-step in which the relative speed w_rel reached or crossed zero with friction on
        (crossed: the caller decides whether the rotor sticks, (3.17)).  The plain form,
        through :meth:`_free_substep_plain`; :meth:`_free_run` is the same arithmetic."""
        for j in range(1, n + 1):
            # motor current lag: exact exponential response to the held command
            tau_mid, tau1 = lag_response(self, tau0, u)
            w0 = thrd - thd
            th, thd, thr, thrd = self._free_substep_plain(th, thd, thr, thrd, tau0, tau_mid, tau1)
            tau0 = tau1
            w1 = thrd - thd
            if self.friction_on and crossed_zero(w0, w1):
                return th, thd, thr, thrd, tau0, j, True
        return th, thd, thr, thrd, tau0, n, False

    def _free_run(self):
        """:meth:`_free_run_plain` with the rig's constants and this sample's disturbance bound
        and the sub-step written out, its derivative (2.15) at each of the four RK4 stages:
        the same arithmetic in the same order, bit for bit (tests compare them), without a call,
        4 calls of _deriv, 5 tuples and ~40 attribute look-ups per sub-step (the integrator's
        hot path: 5 sub-steps a sample at h = 1 ms).  The products of constants (0.5 dt, dt/6
        ...) are those the plain form computes first (a * b * c is (a * b) * c).  Each stage:
        the back-EMF cut-off (2.13), the friction (3.17) at w_rel, then (2.15).  (Bit for bit
        too: tau0 - u computed once, 2.0 * a for 2 * a (the int is converted exactly), the
        cut-off's comparisons in another order, none with a side effect.)"""
        if self.bracket:
            return self._free_run_plain
        sin = math.sin
        na, bp, cp, br = -self._a, self._bp, self._cp, self._br
        push = bp * self.disturbance
        emf, wmax, nwmax = self.back_emf, self._wmax, -self._wmax
        fr = self.friction_on
        cpos, vpos, ncneg, vneg = self._cpos, self._vpos, -self._cneg, self._vneg
        dt, decay, half_decay = self._dt, self._decay, self._half_decay
        hdt, qdt2, hdt2, dt6 = 0.5 * dt, 0.25 * dt * dt, 0.5 * dt * dt, dt / 6.0

        def run(th, thd, thr, thrd, tau0, u, n):
            for j in range(1, n + 1):
                d = tau0 - u
                tau_mid = u + d * half_decay
                tau1 = u + d * decay
                w0 = w = thrd - thd
                g = ((0.0 if emf and ((w > wmax and tau0 > 0.0) or (w < nwmax and tau0 < 0.0)) else tau0)
                     - ((cpos + vpos * w if w > 0.0 else (ncneg + vneg * w if w < 0.0 else 0.0)) if fr else 0.0))
                a1, r1 = na * sin(th) + push - cp * thd - bp * g, br * g
                x, v, wr = th + hdt * thd, thd + hdt * a1, thrd + hdt * r1
                w = wr - v
                g = ((0.0 if emf and ((w > wmax and tau_mid > 0.0) or (w < nwmax and tau_mid < 0.0)) else tau_mid)
                     - ((cpos + vpos * w if w > 0.0 else (ncneg + vneg * w if w < 0.0 else 0.0)) if fr else 0.0))
                a2, r2 = na * sin(x) + push - cp * v - bp * g, br * g
                x, v, wr = x + qdt2 * a1, thd + hdt * a2, thrd + hdt * r2
                w = wr - v
                g = ((0.0 if emf and ((w > wmax and tau_mid > 0.0) or (w < nwmax and tau_mid < 0.0)) else tau_mid)
                     - ((cpos + vpos * w if w > 0.0 else (ncneg + vneg * w if w < 0.0 else 0.0)) if fr else 0.0))
                a3, r3 = na * sin(x) + push - cp * v - bp * g, br * g
                x, v, wr = th + dt * thd + hdt2 * a2, thd + dt * a3, thrd + dt * r3
                w = wr - v
                g = ((0.0 if emf and ((w > wmax and tau1 > 0.0) or (w < nwmax and tau1 < 0.0)) else tau1)
                     - ((cpos + vpos * w if w > 0.0 else (ncneg + vneg * w if w < 0.0 else 0.0)) if fr else 0.0))
                a4, r4 = na * sin(x) + push - cp * v - bp * g, br * g
                th, thd, thr, thrd = (th + dt * (thd + dt6 * (a1 + a2 + a3)),
                                      thd + dt6 * (a1 + 2.0 * a2 + 2.0 * a3 + a4),
                                      thr + dt * (thrd + dt6 * (r1 + r2 + r3)),
                                      thrd + dt6 * (r1 + 2.0 * r2 + 2.0 * r3 + r4))
                tau0 = tau1
                w = thrd - thd
                if fr and (w0 == 0.0 or w == 0.0 or (w0 > 0.0) != (w > 0.0)):
                    return th, thd, thr, thrd, tau0, j, True
            return th, thd, thr, thrd, tau0, n, False
        return run

    def _stuck_substep(self, th, thd, thr, tau0, u):
        """One RK4 sub-step of the rotor stuck to the pendulum, one rigid body (Section 2.3):
        theta integrated, the rotor follows; (theta, theta', theta_r, theta_r', tau) after it
        (:func:`stuck_substep` through :meth:`_deriv`)."""
        def acc(th, thd, thrd, tau):
            return self._deriv(th, thd, thrd, tau, True)[0]
        return stuck_substep(self, acc, th, thd, thr, tau0, u)

    def _required_friction(self, th, thd, tau):
        """Friction (units) the bearing must supply to keep the rotor stuck."""
        return self._deriv(th, thd, thd, tau, True)[2]

    def step(self, u: float = 0.0) -> None:
        """Advance one sample period h with the command u held (ZOH): sub-steps of RK4 stuck
        (:meth:`_stuck_substep`) or free (:meth:`_free_run`), switching between them at the
        sub-step boundaries (stick/slip events)."""
        umax, q = self._umax, self._pwm_q
        if type(u) is float and -umax <= u <= umax:
            # quantize_command of a command within the limits, pwm_quantize written out (every
            # sample's path)
            if q:
                u = math.floor(u / q + 0.5) * q
        else:
            u = self.quantize_command(u)
        self.u_held = u
        if self.rotor_locked:
            self._step_locked(u)
            return
        th, thd, thr, thrd = self._x
        # with the lag the torque is continuous; without it the ZOH torque jumps to u at t_k
        # (starting from the previous sample's torque would lose 1/6 of the first sub-step)
        tau0 = self._tau if self._te > 0 else u
        stuck = self._stuck
        fb = self._fbreak
        n, k = self._n, 0
        while k < n:
            if stuck and abs(self._required_friction(th, thd, tau0)) > fb:
                stuck = False
            if stuck:
                th, thd, thr, thrd, tau0 = self._stuck_substep(th, thd, thr, tau0, u)
                k += 1
                continue
            free = self._free if self._free_for is self.disturbance else self._free_motion()
            th, thd, thr, thrd, tau0, done, crossed = free(th, thd, thr, thrd, tau0, u, n - k)
            k += done
            # relative speed crossed zero: stick if the bearing can hold the rotor
            if crossed and abs(self._required_friction(th, thd, tau0)) <= fb:
                j_ratio = 1.0 if self.bracket else self._stuck_gain   # J / (J + J_r)
                thd = thrd = stick_velocity(j_ratio, thd, thrd)   # momentum-conserving
                stuck = True
        self._x = [th, thd, thr, thrd]
        self._tau = tau0
        self._stuck = stuck
        if stuck:
            self._friction = self._required_friction(th, thd, tau0)
        else:
            self._friction = self._kinetic_friction(thrd - thd) if self.friction_on else 0.0
        self.t += self.h

    def _free_motion(self):
        """:meth:`_free_run` for the current disturbance, made once for each value it takes
        (a torque pulse changes it; the rig's constants do not change)."""
        if self._free is None or self._free_for is not self.disturbance:
            self._free = self._free_run()
            self._free_for = self.disturbance
        return self._free

    def _step_locked(self, u: float) -> None:
        """One sample with the wheel held by the torque meter: only the current lag moves."""
        te = self._te
        tau = u + (self._tau - u) * math.exp(-self.h / te) if te > 0 else u
        fb = self._fbreak if self.friction_on else 0.0
        self._tau = tau
        self._friction = max(-fb, min(fb, tau))
        self._stuck = True
        self.t += self.h

    def meter_torque(self) -> float:
        """What the torque meter of ``rotor_locked`` reads (Nm): k_u (tau - F) (Experiment 2)."""
        return self.rig.k_u * (self._tau - self._friction) if self.rotor_locked else 0.0

    # ------------------------------------------------------------------ outputs
    @property
    def state(self) -> PlantState:
        return PlantState(*self.state_values())

    def state_values(self) -> tuple[float, float, float, float, float, float, bool]:
        """The fields of :attr:`state` in its order (theta, theta_dot, wheel_angle, wheel_rate,
        torque, friction, stuck), without the object (the simulator reads them every sample)."""
        th, thd, thr, thrd = self._x
        return th, thd, thr, thrd, self._torque_available(self._tau, thrd - thd), self._friction, self._stuck

    def readout(self) -> tuple[int, int, float, float, float, float, float, float, bool]:
        """:meth:`counts` and :meth:`state_values` in one tuple (pendulum_counts, motor_counts,
        theta, theta_dot, wheel_angle, wheel_rate, torque, friction, stuck): what the simulator
        reads every sample, in one call."""
        th, thd, thr, thrd = self._x
        dl = self._delta
        return (math.floor(th / dl + 0.5), math.floor((thr - th) / dl + 0.5), th, thd, thr, thrd,
                self._torque_available(self._tau, thrd - thd), self._friction, self._stuck)

    def counts(self) -> tuple[int, int]:
        """Encoder readings (pendulum_counts, motor_counts) (2.1)-(2.2), rounded to a count."""
        th, _, thr, _ = self._x
        dl = self._delta
        return math.floor(th / dl + 0.5), math.floor((thr - th) / dl + 0.5)

    def energy(self) -> float:
        """Scaled pendulum energy (6.2) of the true state."""
        return self.rig.energy(self._x[0], self._x[1])

    def total_energy(self) -> float:
        """Mechanical energy of pendulum + rotor (J): (2.4) + (2.5)."""
        th, thd, _, thrd = self._x
        r = self.rig
        return 0.5 * r.J * thd ** 2 + 0.5 * r.j_r * thrd ** 2 + r.mgl * (1.0 - math.cos(th))
