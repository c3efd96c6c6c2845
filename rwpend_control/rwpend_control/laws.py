"""Control laws of the book, evaluated once per sample (pure Python, no rclpy, no numpy).

Conventions (Block, Astrom & Spong; ERRATA "Conventions"):

* theta is measured from **hanging** (0) as in (2.15); upright is pi.  The upright laws use
  the deviation ``x = wrap(theta - pi)`` in (-pi, pi] (ERRATA E38) and the book's negative
  gains: ``u = -kpp x - kdp theta' - kpr (theta_r - theta_rref) - kdr theta_r'`` (E28).
* u is in control units (1 unit = k_u = 0.00494 Nm, (2.14)); saturation to |u| <= u_max is
  done by the caller (:mod:`rwpend_control.supervisor`), the laws return the unsaturated value.
* F (friction) is in control units of the relative rotor speed ``w_rel = theta_r' - theta'``
  (3.17, E46).

Every ``__call__`` takes plain floats and does a handful of float operations, so a law costs
about a microsecond per sample.
"""
from __future__ import annotations

import math

_PI = math.pi
_TWO_PI = 2.0 * math.pi


def wrap(angle: float) -> float:
    """Angle wrapped to (-pi, pi] (used as ``wrap(theta - pi)``, ERRATA E38)."""
    y = math.fmod(angle + _PI, _TWO_PI)
    if y <= 0.0:
        y += _TWO_PI
    return y - _PI


def upright_deviation(theta: float) -> float:
    """x = wrap(theta - pi): deviation from upright, theta measured from hanging (E38) (the
    body of :func:`wrap` written out: every sample's path)."""
    y = math.fmod((theta - _PI) + _PI, _TWO_PI)
    if y <= 0.0:
        y += _TWO_PI
    return y - _PI


def scaled_energy(theta: float, theta_dot: float, omega_p: float) -> float:
    """Scaled pendulum energy (6.2): E = 1 - cos(theta) + (theta'/omega_p)^2 / 2 (0 down, 2 up)."""
    r = theta_dot / omega_p
    return 1.0 - math.cos(theta) + 0.5 * r * r


def saturate(u: float, u_max: float) -> float:
    """sat(u) = max(-u_max, min(u_max, u))."""
    if u > u_max:
        return u_max
    if u < -u_max:
        return -u_max
    return u


# --------------------------------------------------------------------------- wheel (Chapter 3)
class WheelVelocityPI:
    """Wheel velocity control, P (3.13) and PI (3.14)-(3.16).

    ``u = kdr (omega_ref - omega) + I``, ``I += ki (omega_ref - omega)`` once per sample
    (ERRATA E15: k_i is the per-sample gain of the summed error, k_i = omega0^2 h / b_r).
    ki = 0 gives the P law (3.13).  The integral is clamped to +-i_max (anti-windup), and it
    is only advanced while the output is not saturated in the direction of the error.
    """

    __slots__ = ('kdr', 'ki', 'ref', 'i_max', 'integral')

    def __init__(self, kdr: float, ki: float = 0.0, ref: float = 0.0, i_max: float = 10.0) -> None:
        self.kdr = float(kdr)
        self.ki = float(ki)
        self.ref = float(ref)
        self.i_max = float(i_max)
        self.integral = 0.0

    def reset(self) -> None:
        self.integral = 0.0

    def __call__(self, wheel_rate: float) -> float:
        e = self.ref - wheel_rate
        i = self.integral + self.ki * e
        lim = self.i_max
        if i > lim:
            i = lim
        elif i < -lim:
            i = -lim
        self.integral = i
        return self.kdr * e + i


class WheelAnglePD:
    """Wheel angle control (3.18): ``u = kpr (theta_ref - theta_r) - kdr theta_r'`` (kpr, kdr > 0)."""

    __slots__ = ('kpr', 'kdr', 'ref')

    def __init__(self, kpr: float, kdr: float, ref: float = 0.0) -> None:
        self.kpr = float(kpr)
        self.kdr = float(kdr)
        self.ref = float(ref)

    def __call__(self, wheel_angle: float, wheel_rate: float) -> float:
        return self.kpr * (self.ref - wheel_angle) - self.kdr * wheel_rate


# --------------------------------------------------------------------------- pendulum (Chapter 4)
class PendulumPD:
    """Pendulum PD (4.2): ``u = -kpp x - kdp theta'`` with the up-design gains (4.3).

    ``down=True`` runs the same design on the hanging pendulum with the up-down transformation
    (Chapter 4, ERRATA E21): x = wrap(theta), ``kpp_down = kpp_up + 2 a / b_p``, kdp unchanged,
    which gives the hanging pendulum exactly the deviation dynamics of the upright design.
    """

    __slots__ = ('kpp', 'kdp', 'down', '_kpp_eff')

    def __init__(self, kpp: float, kdp: float, down: bool = False, a: float = 0.0,
                 b_p: float = 1.0) -> None:
        self.kpp = float(kpp)
        self.kdp = float(kdp)
        self.down = bool(down)
        self._kpp_eff = self.kpp + (2.0 * a / b_p if down else 0.0)

    def __call__(self, theta: float, theta_dot: float) -> float:
        x = wrap(theta) if self.down else wrap(theta - _PI)
        return -self._kpp_eff * x - self.kdp * theta_dot


class Balance:
    """Upright state feedback: (4.9) with wheel rate, (4.13) with wheel angle, and the patched
    stabilizer of Section 6.3 (kpr = 0, kpp = +omega_p kdp, ERRATA E39).

    ``u = -kpp x - kdp theta' - kpr (theta_r - wheel_ref) - kdr (theta_r' - rate_ref)``,
    x = wrap(theta - pi).  With kpr = 0 and rate_ref = omega_ref this is (4.9)
    ``u = -kpp x - kdp theta' + kdr (omega_ref - omega)``; with kpr != 0 it is the consistent
    form of (4.13) with a wheel-angle reference (E28).  Gains are the book's negative numbers.
    """

    __slots__ = ('kpp', 'kdp', 'kpr', 'kdr', 'wheel_ref', 'rate_ref')

    def __init__(self, kpp: float, kdp: float, kpr: float = 0.0, kdr: float = 0.0,
                 wheel_ref: float = 0.0, rate_ref: float = 0.0) -> None:
        self.kpp = float(kpp)
        self.kdp = float(kdp)
        self.kpr = float(kpr)
        self.kdr = float(kdr)
        self.wheel_ref = float(wheel_ref)
        self.rate_ref = float(rate_ref)

    def __call__(self, theta: float, theta_dot: float, wheel_angle: float, wheel_rate: float) -> float:
        x = upright_deviation(theta)
        return (-self.kpp * x - self.kdp * theta_dot
                - self.kpr * (wheel_angle - self.wheel_ref) - self.kdr * (wheel_rate - self.rate_ref))


# --------------------------------------------------------------------------- swing-up (Ch. 5, 6)
class EnergySwingUp:
    """Energy swing-up (6.1) with the scaled energy (6.2), sign per ERRATA E35, units per E34.

    ``u = c_e (E - e_ref) theta' - c_v theta_r'`` (unsaturated; the caller saturates):
    the consistent reading of (5.18)/(6.1) ``u = sat(k_u (k_e theta' (E - E_ref) - k_v theta_r'))``
    with c_e = k_u k_e b_p a and c_v = k_u k_v (E34; the book's k_e = 4000, k_v = 4, k_u = 0.4
    give c_e = 1.356e5, c_v = 1.6, an essentially bang-bang pump).  Pumping needs u theta' < 0
    because dE/dt = -(b_p/a) u theta' (E35).

    From rest (theta' = 0 and E < ``kick_energy``) the law gives u = 0 for ever; it then applies
    ``kick`` units in the direction that starts a pumping swing (sign of theta, + at theta = 0):
    gravity then moves the pendulum towards -sign(theta), so u theta' < 0 as required.
    """

    __slots__ = ('c_e', 'c_v', 'e_ref', 'omega_p', 'kick', 'kick_energy', 'kick_rate')

    def __init__(self, c_e: float, c_v: float, omega_p: float, e_ref: float = 2.0,
                 kick: float = 10.0, kick_energy: float = 1e-3, kick_rate: float = 0.05) -> None:
        self.c_e = float(c_e)
        self.c_v = float(c_v)
        self.omega_p = float(omega_p)
        self.e_ref = float(e_ref)
        self.kick = float(kick)
        self.kick_energy = float(kick_energy)
        self.kick_rate = float(kick_rate)

    def __call__(self, theta: float, theta_dot: float, wheel_rate: float) -> float:
        r = theta_dot / self.omega_p
        e = 1.0 - math.cos(theta) + 0.5 * r * r
        if e < self.kick_energy and -self.kick_rate < theta_dot < self.kick_rate:
            return -self.kick if wrap(theta) < 0.0 else self.kick
        return self.c_e * (e - self.e_ref) * theta_dot - self.c_v * wheel_rate


# --------------------------------------------------------------------------- friction (3.17, 3.8)
FRICTION_MODES = ('off', 'model', 'estimate')


class FrictionCompensation:
    """Friction compensation (Section 3.8): the term added to u so that u - F ~ u_law.

    * ``off``: 0.
    * ``model``: F of (3.17) at the estimated relative rotor speed w_rel = theta_r' - theta'
      (E46); 0 inside +-``deadband`` rad/s, where the sign of the estimated speed is noise.
    * ``estimate``: the estimator's friction estimate F_hat (StateEstimate.friction).
    """

    __slots__ = ('mode', 'deadband', '_cp', '_vp', '_cn', '_vn')

    def __init__(self, mode: str, rig=None, deadband: float = 1.0) -> None:
        if mode not in FRICTION_MODES:
            raise ValueError(f'friction_compensation must be one of {FRICTION_MODES}, got {mode!r}')
        self.mode = mode
        self.deadband = float(deadband)
        if rig is not None:
            self._cp, self._vp = rig.friction_coulomb_pos, rig.friction_viscous_pos
            self._cn, self._vn = rig.friction_coulomb_neg, rig.friction_viscous_neg
        else:
            self._cp = self._vp = self._cn = self._vn = 0.0

    def __call__(self, theta_dot: float, wheel_rate: float, friction_estimate: float) -> float:
        mode = self.mode
        if mode == 'off':
            return 0.0
        if mode == 'estimate':
            return friction_estimate
        w = wheel_rate - theta_dot
        if w > self.deadband:
            return self._cp + self._vp * w
        if w < -self.deadband:
            return -self._cn + self._vn * w
        return 0.0
