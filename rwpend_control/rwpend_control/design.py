"""Gain design of the book by pole placement, and the stability check of a gain set.

Every function takes a :class:`rwpend_model.rig.Rig` (a, b_p, b_r, omega_p computed from it,
never retyped) and the pole specification.  omega values may be numbers (rad/s) or strings
such as ``'1.5wp'`` (a multiple of omega_p), see :func:`parse_omega`.

Upright designs are for the deviation x = theta - pi and give the book's negative gains, used as
``u = -kpp x - kdp theta' - kpr theta_r - kdr theta_r'`` (ERRATA conventions, E28).

Pure Python + numpy: no rclpy.
"""
from __future__ import annotations

import math
import re
from dataclasses import asdict, dataclass
from typing import Union

import numpy as np

Omega = Union[float, int, str]


@dataclass(frozen=True)
class Gains:
    """A state-feedback gain set for the upright pendulum (the book's signs: negative)."""

    kpp: float
    kdp: float
    kpr: float = 0.0
    kdr: float = 0.0

    def as_dict(self) -> dict[str, float]:
        return asdict(self)

    def vector(self) -> np.ndarray:
        """K of u = -K x with x = (theta - pi, theta', theta_r, theta_r') (4.8)."""
        return np.array([self.kpp, self.kdp, self.kpr, self.kdr], dtype=float)


@dataclass(frozen=True)
class WheelGains:
    """Wheel-loop gains of Chapter 3 (positive): kdr of (3.13)/(3.15), ki of (3.16), kpr of (3.18)."""

    kdr: float
    ki: float = 0.0
    kpr: float = 0.0

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


_OMEGA_RE = re.compile(r'^\s*([+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?)?\s*\*?\s*(wp|ω_?p|omega_?p)?\s*$')


def parse_omega(text: Omega, rig) -> float:
    """omega as rad/s from a number or a string: ``'20'``, ``'1.5wp'``, ``'1.5*wp'``, ``'wp'``.

    'wp' (also 'omega_p', 'ωp') is the rig's omega_p = sqrt(a).  Raises ValueError for anything
    that is not a finite positive frequency.
    """
    if isinstance(text, bool):
        raise ValueError(f'omega must be a number or like "1.5wp", got {text!r}')
    if isinstance(text, (int, float)):
        value = float(text)
    elif isinstance(text, str):
        m = _OMEGA_RE.match(text)
        if not m or (m.group(1) is None and m.group(2) is None):
            raise ValueError(f'omega must be a number (rad/s) or a multiple of omega_p like "1.5wp", got {text!r}')
        factor = float(m.group(1)) if m.group(1) is not None else 1.0
        value = factor * rig.omega_p if m.group(2) else factor
    else:
        raise ValueError(f'omega must be a number or like "1.5wp", got {text!r}')
    if not math.isfinite(value) or value <= 0.0:
        raise ValueError(f'omega must be finite and > 0 rad/s, got {text!r}')
    return value


def _positive(name: str, value: float, allow_zero: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f'{name} must be a number, got {value!r}')
    value = float(value)
    if not math.isfinite(value) or value < 0.0 or (value == 0.0 and not allow_zero):
        raise ValueError(f'{name} must be finite and {">=" if allow_zero else ">"} 0, got {value!r}')
    return value


# --------------------------------------------------------------------------- Chapter 3 (wheel)
def wheel_p(rig, kdr: float) -> WheelGains:
    """P wheel-speed control (3.13): the gain itself; closed-loop pole -kdr b_r, T = 1/(kdr b_r)."""
    return WheelGains(kdr=_positive('kdr', kdr))


def pi_control(rig, omega0: Omega, zeta: float = 1.0) -> WheelGains:
    """PI wheel-speed control (3.15)-(3.16): kdr = 2 zeta omega0 / b_r, ki = omega0^2 h / b_r.

    ki is the per-sample gain of the summed error (ERRATA E15: closed loop
    s^2 + b_r kdr s + b_r ki / h).
    """
    w0 = parse_omega(omega0, rig)
    zeta = _positive('zeta', zeta)
    return WheelGains(kdr=2.0 * zeta * w0 / rig.b_r, ki=w0 ** 2 * rig.sample_period / rig.b_r)


def wheel_pd(rig, omega0: Omega, zeta: float = 0.707) -> WheelGains:
    """Wheel-angle PD (3.18)/(3.19): kpr = omega0^2 / b_r, kdr = 2 zeta omega0 / b_r."""
    w0 = parse_omega(omega0, rig)
    zeta = _positive('zeta', zeta)
    return WheelGains(kdr=2.0 * zeta * w0 / rig.b_r, kpr=w0 ** 2 / rig.b_r)


# --------------------------------------------------------------------------- Chapter 4 (upright)
def pd_control(rig, omega0: Omega, zeta: float = 1.0) -> Gains:
    """Pendulum PD (4.2)-(4.3): kpp = -(omega0^2 + a)/b_p, kdp = -2 zeta omega0 / b_p (E17, E21).

    omega0 = omega_p, zeta = 1 gives Experiment 12's gains -145.2, -16.39 (ERRATA E18: the
    book prints them positive, which is unstable).  No wheel feedback: the wheel drifts (4.6).
    """
    w0 = parse_omega(omega0, rig)
    zeta = _positive('zeta', zeta)
    return Gains(kpp=-(w0 ** 2 + rig.a) / rig.b_p, kdp=-2.0 * zeta * w0 / rig.b_p)


def up_down(rig, gains: Gains) -> Gains:
    """Up-down transformation (Chapter 4, E21): gains to test an upright PD design hanging down.

    kpp_down = kpp_up + 2 a / b_p, kdp unchanged; use with x = wrap(theta) (see laws.PendulumPD).
    Exact for the PD (4.2) only (the wheel loop of the other designs sees kpp too).
    """
    return Gains(kpp=gains.kpp + 2.0 * rig.a / rig.b_p, kdp=gains.kdp, kpr=gains.kpr, kdr=gains.kdr)


def pddcontrol(rig, omega0: Omega, zeta: float = 0.707, alpha: float = 0.2) -> Gains:
    """Pendulum PD + wheel-rate feedback (4.9), poles (s + alpha omega0)(s^2 + 2 zeta omega0 s + omega0^2), (4.11).

    kpp = -((1 + 2 alpha zeta) omega0^2 + a)/b_p,  kdp = -((alpha + 2 zeta) omega0 a + alpha omega0^3)/(a b_p),
    kdr = -alpha omega0^3 / (a b_r).  The book's sets are at omega0 = 1.5, 2, 2.5 omega_p (E24).
    """
    w0 = parse_omega(omega0, rig)
    zeta = _positive('zeta', zeta)
    alpha = _positive('alpha', alpha)
    a, bp, br = rig.a, rig.b_p, rig.b_r
    return Gains(kpp=-((1.0 + 2.0 * alpha * zeta) * w0 ** 2 + a) / bp,
                 kdp=-((alpha + 2.0 * zeta) * w0 * a + alpha * w0 ** 3) / a / bp,
                 kpr=0.0,
                 kdr=-alpha * w0 ** 3 / a / br)


def pdpdcontrol(rig, omega1: Omega, zeta1: float, omega2: Omega, zeta2: float) -> Gains:
    """Pendulum PD + wheel-angle PD (4.13), poles (s^2 + 2 zeta1 w1 s + w1^2)(s^2 + 2 zeta2 w2 s + w2^2), (4.15).

    kdr = -2 (zeta1 w2 + zeta2 w1) w1 w2 / (a b_r) as in (4.15) -- NOT the listing's
    ``zeta1*w1`` (ERRATA E29; identical when w1 = w2).
    """
    w1 = parse_omega(omega1, rig)
    w2 = parse_omega(omega2, rig)
    z1 = _positive('zeta1', zeta1)
    z2 = _positive('zeta2', zeta2)
    a, bp, br = rig.a, rig.b_p, rig.b_r
    return Gains(kpp=-(a * (w1 ** 2 + 4.0 * z1 * z2 * w1 * w2 + w2 ** 2) + w1 ** 2 * w2 ** 2 + a ** 2) / a / bp,
                 kdp=-(2.0 * a * (z1 * w1 + z2 * w2) + 2.0 * (z1 * w2 + z2 * w1) * w1 * w2) / a / bp,
                 kpr=-w1 ** 2 * w2 ** 2 / a / br,
                 kdr=-2.0 * (z1 * w2 + z2 * w1) * w1 * w2 / a / br)


def acker_design(rig, poles) -> Gains:
    """State-feedback gains placing the poles of (4.8) exactly (Ackermann's formula, Section 4.7).

    ``poles``: 4 complex numbers (conjugate pairs).  Reproduces the book's acker K (E30).
    """
    p = np.asarray(poles, dtype=complex)
    if p.shape != (4,) or not np.all(np.isfinite(p)):
        raise ValueError('acker_design needs 4 finite poles')
    A, B = upright_model(rig)
    coeffs = np.real(np.poly(p))
    Wc = np.column_stack([B, A @ B, A @ A @ B, A @ A @ A @ B])
    phi = sum(c * np.linalg.matrix_power(A, 4 - i) for i, c in enumerate(coeffs))
    K = np.linalg.solve(Wc.T, np.array([0.0, 0.0, 0.0, 1.0])) @ phi
    return Gains(*(float(k) for k in K))


# --------------------------------------------------------------------------- Chapter 6 (patch)
def pddcontrolwpatch(rig, omega0: Omega, zeta: float = 0.707) -> Gains:
    """Stabilizer patched to the homoclinic orbit (Section 6.3, ERRATA E39/E40).

    kpp = -(omega0^2 + 2 zeta omega0 omega_p + omega_p^2)/b_p, kdp = kpp/omega_p,
    kdr = -omega0^2/(b_r omega_p): satisfies k_pp = +omega_p k_dp (E39, the printed (6.4) sign is
    wrong), closed-loop poles -omega_p and the roots of s^2 + 2 zeta omega0 s + omega0^2.
    """
    w0 = parse_omega(omega0, rig)
    zeta = _positive('zeta', zeta)
    wp = rig.omega_p
    n = w0 ** 2 + 2.0 * zeta * w0 * wp + wp ** 2
    return Gains(kpp=-n / rig.b_p, kdp=-n / rig.b_p / wp, kpr=0.0, kdr=-w0 ** 2 / rig.b_r / wp)


def swingup_gains(rig, k_e: float = 4000.0, k_v: float = 4.0, k_u: float = 0.4) -> tuple[float, float]:
    """(c_e, c_v) of ``u = sat(c_e (E - 2) theta' - c_v theta_r')`` with the scaled energy (6.2).

    Consistent reading of the Chapter 5 gains (ERRATA E34): E per unit inertia and k = b_p, so
    c_e = k_u k_e b_p a (= 1.356e5 for the book's data), c_v = k_u k_v (= 1.6).
    """
    for name, v in (('k_e', k_e), ('k_v', k_v), ('k_u', k_u)):
        _positive(name, v, allow_zero=(name == 'k_v'))
    return k_u * k_e * rig.b_p * rig.a, k_u * k_v


def switching_region_bound(rig) -> float:
    """Half-width b_p u_max / omega_p (rad/s) of the region (6.6) in xi = theta' + omega_p x (E41: upper bound)."""
    return rig.b_p * rig.u_max / rig.omega_p


def jump_at_catch(gains: Gains, x: float, theta_dot: float, wheel_rate: float = 0.0,
                  u_before: float = 0.0) -> float:
    """u of the stabilizer at the switching state minus the command just before (unsaturated)."""
    return (-gains.kpp * x - gains.kdp * theta_dot - gains.kdr * wheel_rate) - u_before


# --------------------------------------------------------------------------- analysis
def upright_model(rig) -> tuple[np.ndarray, np.ndarray]:
    """(A, B) of the upright linearization (4.8) (E22) in x = (theta - pi, theta', theta_r, theta_r')."""
    A = np.array([[0.0, 1.0, 0.0, 0.0],
                  [rig.a, 0.0, 0.0, 0.0],
                  [0.0, 0.0, 0.0, 1.0],
                  [0.0, 0.0, 0.0, 0.0]])
    B = np.array([0.0, -rig.b_p, 0.0, rig.b_r])
    return A, B


def _as_gains(gains) -> Gains:
    if isinstance(gains, Gains):
        return gains
    if isinstance(gains, dict):
        return Gains(**{k: float(v) for k, v in gains.items()})
    return Gains(*(float(v) for v in gains))


def closed_loop_poles(rig, gains) -> np.ndarray:
    """Eigenvalues of the linearized upright closed loop (4.8) with u = -K x.

    With kpr = 0 the wheel angle is not fed back and is a pure integrator of the wheel speed
    (an uncontrollable-by-design pole at 0 that does not matter); it is left out, so the result
    has 3 poles (the polynomial of (4.10)/Section 6.3).  With kpr != 0: 4 poles ((4.14)/(4.16)).
    Sorted by real part, largest (least stable) first.
    """
    g = _as_gains(gains)
    A, B = upright_model(rig)
    K = g.vector()
    if not np.all(np.isfinite(K)):
        raise ValueError('gains must be finite')
    Acl = A - np.outer(B, K)
    if g.kpr == 0.0:
        idx = [0, 1, 3]
        Acl = Acl[np.ix_(idx, idx)]
    ev = np.linalg.eigvals(Acl)
    return ev[np.argsort(-ev.real, kind='stable')]


def check_stable(rig, gains, allow_wheel_drift: bool = False, margin: float = 1e-9) -> tuple[bool, str]:
    """(ok, reason): is the linearized upright closed loop with these gains asymptotically stable?

    ``allow_wheel_drift``: accept a set without wheel feedback (kpr = kdr = 0, the PD of (4.2))
    whose only non-decaying pole is the wheel speed's pole at 0 (the drift of (4.6)).
    """
    g = _as_gains(gains)
    for name, v in g.as_dict().items():
        if not math.isfinite(v):
            return False, f'{name} = {v!r} is not finite'
    poles = closed_loop_poles(rig, g)
    bad = [p for p in poles if p.real >= -margin]
    text = ', '.join(_fmt_pole(p) for p in poles)
    if not bad:
        return True, f'stable: poles {text}'
    if allow_wheel_drift and g.kpr == 0.0 and g.kdr == 0.0 and all(abs(p) <= 1e-9 for p in bad):
        return True, f'pendulum stable, wheel speed drifts (pole at 0, (4.6)): poles {text}'
    worst = bad[0]
    return False, f'unstable closed loop: pole {_fmt_pole(worst)} has real part >= 0 (poles {text})'


def _fmt_pole(p: complex) -> str:
    if abs(p.imag) < 1e-5 * max(1.0, abs(p.real)):
        return f'{p.real:.4g}'
    return f'{p.real:.4g}{p.imag:+.4g}j'


DESIGNS = ('pd', 'pi', 'wheel_pd', 'pdd', 'pdpd', 'patch')
