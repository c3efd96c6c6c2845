"""Mode and law switching of the controller (Chapter 6), pure Python (no rclpy).

Modes:

* ``off``: u = 0.
* ``wheel_velocity``: PI wheel-speed control (3.13)-(3.16) to ``wheel.ref`` (rad/s).
* ``wheel_angle``: wheel-angle PD (3.18) to ``wheel_angle.ref`` (rad).
* ``balance``: the upright state feedback ``balance.*`` ((4.9) when kpr = 0, (4.13)/E28 with the
  wheel-angle reference taken at the moment balance starts).  Falling beyond theta_0 turns the
  controller ``off`` (the pendulum cannot be caught again without a swing-up).
* ``swingup``: energy control (6.1)/(6.2) with the signs of ERRATA E35 only (no catch).
* ``auto``: Section 6: law ``swingup`` until |wrap(theta - pi)| < theta_s (6.5) (and, if
  ``catch_region``, the state is inside the region (6.6)); then law ``catch`` = the patched
  stabilizer ``patch.*`` (Section 6.3, E39); back to ``swingup`` when |wrap(theta - pi)| > theta_0.

Choice of theta_0 (Section 6.4): the book switches back at 0.5 rad = theta_s, i.e. without
hysteresis.  Beyond |x| ~ b_p u_max / a = 0.14 rad at rest the pendulum cannot be held anyway
((6.6) with theta' = 0), so theta_0 does not decide what is recoverable; it only has to be far
enough above theta_s that a catch entering at theta_s along the homoclinic orbit (whose state
points inwards) and the velocity noise of a one-count jump never chatter across the boundary.
The default theta_0 = 0.8 rad gives 0.3 rad of hysteresis; a falling pendulum reaches it about
0.1 s after leaving theta_s, before the swing-up has lost anything.

Every change of mode or law is a :class:`SwitchEvent` (t, from, to, reason).
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, fields, replace
from typing import Any, Mapping

from . import design
from .design import Gains
from .laws import (FRICTION_MODES, Balance, EnergySwingUp, FrictionCompensation, WheelAnglePD,
                   WheelVelocityPI, upright_deviation)

MODES = ('off', 'wheel_velocity', 'wheel_angle', 'balance', 'swingup', 'auto')
LAWS = ('off', 'wheel_velocity', 'wheel_angle', 'balance', 'swingup', 'catch')

#: Limits of a sane state estimate; beyond them the sample is refused (u = 0, fault).
MAX_THETA_DOT = 200.0       # rad/s (a fall from upright reaches 2 omega_p = 18 rad/s)
MAX_ANGLE = 1e7             # rad, multi-turn angles
MAX_FRICTION = 100.0        # control units


@dataclass(frozen=True)
class SwitchEvent:
    """A change of mode or law: at time t, from ``from_`` to ``to`` (``mode/law``), and why."""

    t: float
    from_: str
    to: str
    reason: str


@dataclass
class Status:
    """What the controller did on the last sample (fields of ControllerStatus)."""

    t: float = 0.0
    seq: int = 0
    mode: str = 'off'
    law: str = 'off'
    u: float = 0.0
    u_unsaturated: float = 0.0
    friction_compensation: float = 0.0
    saturated: bool = False
    last_switch: float = 0.0
    switch_count: int = 0
    reason: str = ''
    fault: str = ''
    event: SwitchEvent | None = None   # set on the sample on which a switch happened


@dataclass(frozen=True)
class ControllerConfig:
    """Every tunable of the controller; the field names map to the node's parameters
    (``balance_kpp`` <-> ``balance.kpp``, see :data:`PARAM_FIELDS`)."""

    balance_kpp: float = -282.0
    balance_kdp: float = -25.4
    balance_kpr: float = 0.0
    balance_kdr: float = -0.0302
    balance_rate_ref: float = 0.0
    patch_kpp: float = -389.8
    patch_kdp: float = -44.0
    patch_kdr: float = -0.1006
    swingup_c_e: float = 1.356e5
    swingup_c_v: float = 1.6
    swingup_kick: float = 10.0
    wheel_kp: float = 0.2
    wheel_ki: float = 0.002
    wheel_ref: float = 0.0
    wheel_angle_kpr: float = 0.5
    wheel_angle_kdr: float = 0.07
    wheel_angle_ref: float = 0.0
    theta_s: float = 0.5
    theta_0: float = 0.8
    catch_region: bool = False
    friction_compensation: str = 'off'
    friction_deadband: float = 1.0
    allow_wheel_drift: bool = False

    @classmethod
    def designed(cls, rig, **overrides: Any) -> 'ControllerConfig':
        """The default configuration designed for ``rig`` (then ``overrides`` by field name).

        balance = pddcontrol(1.5 omega_p, 0.707, 0.2) (4.11); patch = pddcontrolwpatch(1.5 omega_p,
        0.707) (Section 6.3, the gains of Fig. 6.3); swing-up c_e, c_v from k_e = 4000, k_v = 4,
        k_u = 0.4 (E34); wheel PI omega0 = 20 rad/s, zeta = 1 (3.15-3.16); wheel-angle PD
        omega0 = 10 rad/s, zeta = 0.707 (3.18).
        """
        b = design.pddcontrol(rig, '1.5wp', 0.707, 0.2)
        p = design.pddcontrolwpatch(rig, '1.5wp', 0.707)
        c_e, c_v = design.swingup_gains(rig)
        pi = design.pi_control(rig, 20.0, 1.0)
        wa = design.wheel_pd(rig, 10.0, 0.707)
        base = cls(balance_kpp=b.kpp, balance_kdp=b.kdp, balance_kpr=b.kpr, balance_kdr=b.kdr,
                   patch_kpp=p.kpp, patch_kdp=p.kdp, patch_kdr=p.kdr,
                   swingup_c_e=c_e, swingup_c_v=c_v, swingup_kick=rig.u_max,
                   wheel_kp=pi.kdr, wheel_ki=pi.ki, wheel_angle_kpr=wa.kpr, wheel_angle_kdr=wa.kdr)
        return replace(base, **overrides) if overrides else base

    @property
    def balance_gains(self) -> Gains:
        return Gains(self.balance_kpp, self.balance_kdp, self.balance_kpr, self.balance_kdr)

    @property
    def patch_gains(self) -> Gains:
        return Gains(self.patch_kpp, self.patch_kdp, 0.0, self.patch_kdr)


#: Node parameter name -> ControllerConfig field.
PARAM_FIELDS: dict[str, str] = {
    'balance.kpp': 'balance_kpp', 'balance.kdp': 'balance_kdp', 'balance.kpr': 'balance_kpr',
    'balance.kdr': 'balance_kdr', 'balance.rate_ref': 'balance_rate_ref',
    'patch.kpp': 'patch_kpp', 'patch.kdp': 'patch_kdp', 'patch.kdr': 'patch_kdr',
    'swingup.c_e': 'swingup_c_e', 'swingup.c_v': 'swingup_c_v', 'swingup.kick': 'swingup_kick',
    'wheel.kp': 'wheel_kp', 'wheel.ki': 'wheel_ki', 'wheel.ref': 'wheel_ref',
    'wheel_angle.kpr': 'wheel_angle_kpr', 'wheel_angle.kdr': 'wheel_angle_kdr',
    'wheel_angle.ref': 'wheel_angle_ref',
    'theta_s': 'theta_s', 'theta_0': 'theta_0', 'catch_region': 'catch_region',
    'friction_compensation': 'friction_compensation', 'friction_deadband': 'friction_deadband',
    'allow_wheel_drift': 'allow_wheel_drift',
}
FIELD_PARAMS = {v: k for k, v in PARAM_FIELDS.items()}
_BOOL_FIELDS = {'catch_region', 'allow_wheel_drift'}
_STR_FIELDS = {'friction_compensation'}


def _num(name: str, v: Any) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)):
        raise ValueError(f'{name} must be a number, got {v!r}')
    v = float(v)
    if not math.isfinite(v):
        raise ValueError(f'{name} must be finite, got {v!r}')
    return v


#: Design parameters (node parameter name -> default) used when the gains are not given.
DESIGN_DEFAULTS: dict[str, Any] = {
    'balance.design.kind': 'pdd',        # pdd (4.11), pdpd (4.15), pd (4.3), patch (6.3)
    'balance.design.omega0': '1.5wp',
    'balance.design.zeta': 0.707,
    'balance.design.alpha': 0.2,         # pdd only
    'balance.design.omega2': 'wp',       # pdpd only: the second pole pair
    'balance.design.zeta2': 1.0,
    'patch.design.omega0': '1.5wp',
    'patch.design.zeta': 0.707,
    'swingup.design.k_e': 4000.0,        # Section 5.3.1, read per ERRATA E34
    'swingup.design.k_v': 4.0,
    'swingup.design.k_u': 0.4,
    'wheel.design.omega0': 20.0,         # PI (3.15)-(3.16)
    'wheel.design.zeta': 1.0,
    'wheel_angle.design.omega0': 10.0,   # PD (3.18)
    'wheel_angle.design.zeta': 0.707,
}
#: Gain parameters computed by each design group.
DESIGN_GROUPS: dict[str, tuple[str, ...]] = {
    'balance': ('balance.kpp', 'balance.kdp', 'balance.kpr', 'balance.kdr'),
    'patch': ('patch.kpp', 'patch.kdp', 'patch.kdr'),
    'swingup': ('swingup.c_e', 'swingup.c_v'),
    'wheel': ('wheel.kp', 'wheel.ki'),
    'wheel_angle': ('wheel_angle.kpr', 'wheel_angle.kdr'),
}


def design_group(name: str) -> str | None:
    """The design group a design parameter belongs to (``balance.design.zeta`` -> ``balance``)."""
    if name in DESIGN_DEFAULTS:
        return name.split('.design.', 1)[0]
    return None


def gains_from_design(rig, group: str, spec: Mapping[str, Any]) -> dict[str, float]:
    """The gain parameters of ``group`` designed from ``spec`` (keys as in DESIGN_DEFAULTS without
    the ``<group>.design.`` prefix, missing keys take the defaults).  ValueError with the reason."""
    prefix = f'{group}.design.'
    s = {k[len(prefix):]: v for k, v in DESIGN_DEFAULTS.items() if k.startswith(prefix)}
    s.update(spec)
    if group == 'balance':
        kind = s['kind']
        if kind == 'pdd':
            g = design.pddcontrol(rig, s['omega0'], s['zeta'], s['alpha'])
        elif kind == 'pdpd':
            g = design.pdpdcontrol(rig, s['omega0'], s['zeta'], s['omega2'], s['zeta2'])
        elif kind == 'pd':
            g = design.pd_control(rig, s['omega0'], s['zeta'])
        elif kind == 'patch':
            g = design.pddcontrolwpatch(rig, s['omega0'], s['zeta'])
        else:
            raise ValueError(f'balance.design.kind must be pdd, pdpd, pd or patch, got {kind!r}')
        return {'balance.kpp': g.kpp, 'balance.kdp': g.kdp, 'balance.kpr': g.kpr, 'balance.kdr': g.kdr}
    if group == 'patch':
        g = design.pddcontrolwpatch(rig, s['omega0'], s['zeta'])
        return {'patch.kpp': g.kpp, 'patch.kdp': g.kdp, 'patch.kdr': g.kdr}
    if group == 'swingup':
        c_e, c_v = design.swingup_gains(rig, s['k_e'], s['k_v'], s['k_u'])
        return {'swingup.c_e': c_e, 'swingup.c_v': c_v}
    if group == 'wheel':
        w = design.pi_control(rig, s['omega0'], s['zeta'])
        return {'wheel.kp': w.kdr, 'wheel.ki': w.ki}
    if group == 'wheel_angle':
        w = design.wheel_pd(rig, s['omega0'], s['zeta'])
        return {'wheel_angle.kpr': w.kpr, 'wheel_angle.kdr': w.kdr}
    raise ValueError(f'unknown design group {group!r}')


def validate_config(cfg: ControllerConfig, rig) -> list[str]:
    """Reasons why ``cfg`` is unacceptable for ``rig`` (empty when fine)."""
    errors: list[str] = []
    p = FIELD_PARAMS
    for f in fields(cfg):
        v = getattr(cfg, f.name)
        if f.name in _BOOL_FIELDS:
            if not isinstance(v, bool):
                errors.append(f'{p[f.name]} must be a bool, got {v!r}')
        elif f.name in _STR_FIELDS:
            if v not in FRICTION_MODES:
                errors.append(f'{p[f.name]} must be one of {", ".join(FRICTION_MODES)}, got {v!r}')
        else:
            try:
                _num(p[f.name], v)
            except ValueError as exc:
                errors.append(str(exc))
    if errors:
        return errors

    def rng(name: str, lo: float, hi: float) -> None:
        v = getattr(cfg, name)
        if not lo <= v <= hi:
            errors.append(f'{p[name]} = {v:g} out of range [{lo:g}, {hi:g}]')

    for g in ('balance', 'patch'):
        rng(f'{g}_kpp', -1e4, 1e4)
        rng(f'{g}_kdp', -1e3, 1e3)
        rng(f'{g}_kdr', -100.0, 100.0)
    rng('balance_kpr', -100.0, 100.0)
    rng('balance_rate_ref', -rig.omega_max, rig.omega_max)
    rng('swingup_c_e', 0.0, 1e8)
    rng('swingup_c_v', 0.0, 100.0)
    rng('swingup_kick', 0.0, rig.u_max)
    # wheel loops: lumped lag T_e = motor lag + h/2 (Section 3.5); refuse zeta < 0.5 of the
    # P loop, kdr b_r T_e > 1 (E14: the sampled loop goes unstable a few times above)
    t_e = rig.motor_time_constant + 0.5 * rig.sample_period
    kd_max = 1.0 / (rig.b_r * t_e)
    rng('wheel_kp', 0.0, kd_max)
    rng('wheel_ki', 0.0, 1.0)
    rng('wheel_ref', -0.9 * rig.omega_max, 0.9 * rig.omega_max)
    rng('wheel_angle_kpr', 0.0, 100.0)
    rng('wheel_angle_kdr', 0.0, kd_max)
    rng('wheel_angle_ref', -MAX_ANGLE, MAX_ANGLE)
    rng('theta_s', 1e-3, math.pi)
    rng('theta_0', 1e-3, math.pi)
    rng('friction_deadband', 0.0, 100.0)
    if errors:
        return errors
    if cfg.theta_0 < cfg.theta_s:
        errors.append(f'theta_0 = {cfg.theta_0:g} must be >= theta_s = {cfg.theta_s:g} (hysteresis)')
    # third-order wheel loops with the lag: Routh conditions
    if cfg.wheel_ki > 0.0 and not cfg.wheel_kp * rig.sample_period > t_e * cfg.wheel_ki:
        errors.append(f'wheel PI unstable with the lag T_e = {t_e * 1e3:g} ms: need wheel.kp > '
                      f'T_e wheel.ki / h = {t_e * cfg.wheel_ki / rig.sample_period:g}')
    if cfg.wheel_angle_kpr > 0.0 and not cfg.wheel_angle_kdr > t_e * cfg.wheel_angle_kpr:
        errors.append(f'wheel-angle PD unstable with the lag T_e = {t_e * 1e3:g} ms: need '
                      f'wheel_angle.kdr > {t_e * cfg.wheel_angle_kpr:g}')
    ok, why = design.check_stable(rig, cfg.balance_gains, allow_wheel_drift=cfg.allow_wheel_drift)
    if not ok:
        errors.append(f'balance gains refused: {why}')
    ok, why = design.check_stable(rig, cfg.patch_gains)
    if not ok:
        errors.append(f'patch gains refused: {why}')
    return errors


def config_with(cfg: ControllerConfig, values: Mapping[str, Any]) -> ControllerConfig:
    """``cfg`` with values given by parameter name (``balance.kpp``) or field name; ValueError on unknown."""
    changes = {}
    names = {f.name for f in fields(cfg)}
    for key, v in values.items():
        name = PARAM_FIELDS.get(key, key)
        if name not in names:
            raise ValueError(f'unknown controller parameter {key!r}')
        if name not in _BOOL_FIELDS and name not in _STR_FIELDS and isinstance(v, int) \
                and not isinstance(v, bool):
            v = float(v)
        changes[name] = v
    return replace(cfg, **changes)


class Controller:
    """Mode switching + control laws + saturation + friction compensation.

    ``update(t, seq, theta, theta_dot, wheel_angle, wheel_rate, friction) -> (u, status)``,
    theta from hanging (rad), rates rad/s, friction estimate in control units.
    """

    def __init__(self, rig, config: ControllerConfig | None = None, mode: str = 'off',
                 max_events: int = 200) -> None:
        self.rig = rig
        self.u_max = float(rig.u_max)
        self.omega_p = rig.omega_p
        self.max_wheel_rate = 2.0 * rig.omega_max
        cfg = config if config is not None else ControllerConfig.designed(rig)
        errors = validate_config(cfg, rig)
        if errors:
            raise ValueError('invalid controller configuration: ' + '; '.join(errors))
        self.config = cfg
        self._build_laws()
        self.mode = 'off'
        self.law = 'off'
        self.t = 0.0
        self.last_switch = 0.0
        self.switch_count = 0
        self.reason = 'start'
        self.bad_state_count = 0
        self.events: deque[SwitchEvent] = deque(maxlen=max_events)
        self._pending: SwitchEvent | None = None
        self._last_x: float | None = None          # last upright deviation seen
        self._capture_ref = False
        if mode != 'off':
            ok, msg = self.set_mode(mode)
            if not ok:
                raise ValueError(msg)

    # ------------------------------------------------------------------ configuration
    def _build_laws(self) -> None:
        c = self.config
        integral = getattr(self, '_wheel_pi', None)
        self._balance = Balance(c.balance_kpp, c.balance_kdp, c.balance_kpr, c.balance_kdr,
                                wheel_ref=getattr(self, '_balance_wheel_ref', 0.0), rate_ref=c.balance_rate_ref)
        self._patch = Balance(c.patch_kpp, c.patch_kdp, 0.0, c.patch_kdr)
        self._swing = EnergySwingUp(c.swingup_c_e, c.swingup_c_v, self.omega_p, kick=c.swingup_kick)
        self._wheel_pi = WheelVelocityPI(c.wheel_kp, c.wheel_ki, c.wheel_ref, i_max=self.u_max)
        if integral is not None:
            self._wheel_pi.integral = integral.integral
        self._wheel_pd = WheelAnglePD(c.wheel_angle_kpr, c.wheel_angle_kdr, c.wheel_angle_ref)
        self._friction = FrictionCompensation(c.friction_compensation, self.rig, c.friction_deadband)

    def check_params(self, values: Mapping[str, Any]) -> tuple[bool, str, ControllerConfig | None]:
        """Dry run of :meth:`set_params`: (ok, reason, the new config)."""
        try:
            cfg = config_with(self.config, values)
        except (ValueError, TypeError) as exc:
            return False, str(exc), None
        errors = validate_config(cfg, self.rig)
        if errors:
            return False, '; '.join(errors), None
        return True, 'ok', cfg

    def set_params(self, values: Mapping[str, Any]) -> tuple[bool, str]:
        """Change parameters (by node parameter name, e.g. ``{'balance.kpp': -300}``) atomically.

        Refused with the reason (and nothing changed) when a value is not finite, out of range,
        or makes the linearized balance/patch closed loop unstable.
        """
        ok, reason, cfg = self.check_params(values)
        if ok:
            self.config = cfg
            self._build_laws()
        return ok, reason

    def set_gains(self, group: str, **gains: float) -> tuple[bool, str]:
        """``set_gains('balance', kpp=.., kdp=.., kpr=.., kdr=..)`` (also 'patch', 'swingup', 'wheel', 'wheel_angle')."""
        if group not in ('balance', 'patch', 'swingup', 'wheel', 'wheel_angle'):
            return False, f'unknown gain group {group!r}'
        return self.set_params({f'{group}.{k}': v for k, v in gains.items()})

    # ------------------------------------------------------------------ switching
    def _switch(self, t: float, mode: str, law: str, reason: str) -> None:
        ev = SwitchEvent(t, f'{self.mode}/{self.law}', f'{mode}/{law}', reason)
        self.mode, self.law = mode, law
        self.last_switch = t
        self.switch_count += 1
        self.reason = reason
        self.events.append(ev)
        self._pending = ev

    def set_mode(self, mode: str, t: float | None = None) -> tuple[bool, str]:
        """Request a mode; (ok, message).  Unknown modes, and ``balance`` with the pendulum
        farther than theta_0 from upright, are refused (nothing changes)."""
        if mode not in MODES:
            return False, f'unknown mode {mode!r} (one of {", ".join(MODES)})'
        t = self.t if t is None else t
        if mode == self.mode:
            return True, f'already in {mode}'
        x = self._last_x
        if mode == 'balance':
            if x is not None and abs(x) > self.config.theta_0:
                return False, (f'balance refused: |theta-pi| = {abs(x):.3g} > theta_0 = '
                               f'{self.config.theta_0:g} (use auto to swing up)')
            self._capture_ref = True     # wheel-angle reference := wheel angle at the start
        if mode == 'wheel_velocity':
            self._wheel_pi.reset()
        law = {'auto': self._auto_law(x, None) if x is not None else 'swingup'}.get(mode, mode)
        self._switch(t, mode, law, f'set_mode {mode}')
        return True, f'mode {mode}'

    def _auto_law(self, x: float, theta_dot: float | None) -> str:
        c = self.config
        if self.law == 'catch':
            return 'swingup' if abs(x) > c.theta_0 else 'catch'
        if abs(x) < c.theta_s and (not c.catch_region or theta_dot is None
                                   or abs(theta_dot + self.omega_p * x) < design.switching_region_bound(self.rig)):
            return 'catch'
        return 'swingup'

    def pop_events(self) -> list[SwitchEvent]:
        out = list(self.events)
        self.events.clear()
        return out

    # ------------------------------------------------------------------ per sample
    def _bad_state(self, theta, theta_dot, wheel_angle, wheel_rate, friction) -> str:
        for name, v in (('theta', theta), ('theta_dot', theta_dot), ('wheel_angle', wheel_angle),
                        ('wheel_rate', wheel_rate), ('friction', friction)):
            if not isinstance(v, (int, float)) or not math.isfinite(v):
                return f'bad state: {name} = {v!r}'
        if abs(theta) > MAX_ANGLE or abs(wheel_angle) > MAX_ANGLE:
            return 'bad state: angle beyond 1e7 rad'
        if abs(theta_dot) > MAX_THETA_DOT:
            return f'bad state: |theta_dot| = {abs(theta_dot):.4g} > {MAX_THETA_DOT:g} rad/s'
        if abs(wheel_rate) > self.max_wheel_rate:
            return f'bad state: |wheel_rate| = {abs(wheel_rate):.4g} > {self.max_wheel_rate:.4g} rad/s'
        if abs(friction) > MAX_FRICTION:
            return f'bad state: |friction| = {abs(friction):.4g} > {MAX_FRICTION:g}'
        return ''

    def update(self, t: float, seq: int, theta: float, theta_dot: float, wheel_angle: float,
               wheel_rate: float, friction: float = 0.0) -> tuple[float, Status]:
        """One sample: the command u (saturated) and the status."""
        self.t = t
        fault = self._bad_state(theta, theta_dot, wheel_angle, wheel_rate, friction)
        u_law = 0.0
        fc = 0.0
        if fault:
            self.bad_state_count += 1
        else:
            x = upright_deviation(theta)
            self._last_x = x
            mode = self.mode
            if mode == 'auto':
                law = self._auto_law(x, theta_dot)
                if law != self.law:
                    if law == 'catch':
                        why = f'catch: |theta-pi|={abs(x):.3f}<{self.config.theta_s:g}'
                    else:
                        why = f'fall: |theta-pi|={abs(x):.3f}>{self.config.theta_0:g}'
                    self._switch(t, 'auto', law, why)
                if law == 'catch':
                    u_law = self._patch(theta, theta_dot, wheel_angle, wheel_rate)
                else:
                    u_law = self._swing(theta, theta_dot, wheel_rate)
            elif mode == 'balance':
                if abs(x) > self.config.theta_0:
                    self._switch(t, 'off', 'off', f'fell: |theta-pi|={abs(x):.3f}>{self.config.theta_0:g}')
                else:
                    if self._capture_ref:
                        self._capture_ref = False
                        self._balance.wheel_ref = self._balance_wheel_ref = wheel_angle
                    u_law = self._balance(theta, theta_dot, wheel_angle, wheel_rate)
            elif mode == 'swingup':
                u_law = self._swing(theta, theta_dot, wheel_rate)
            elif mode == 'wheel_velocity':
                u_law = self._wheel_pi(wheel_rate)
            elif mode == 'wheel_angle':
                u_law = self._wheel_pd(wheel_angle, wheel_rate)
            if self.mode != 'off':
                fc = self._friction(theta_dot, wheel_rate, friction)
        u_uns = u_law + fc
        umax = self.u_max
        u = umax if u_uns > umax else (-umax if u_uns < -umax else u_uns)
        ev, self._pending = self._pending, None
        status = Status(t=t, seq=seq, mode=self.mode, law=self.law, u=u, u_unsaturated=u_uns,
                        friction_compensation=fc, saturated=abs(u_uns) > umax,
                        last_switch=self.last_switch, switch_count=self.switch_count,
                        reason=self.reason, fault=fault, event=ev)
        return u, status
