"""Mode and law switching of the controller (Chapter 6), pure Python (no rclpy).

Modes:

* ``off``: u = 0.
* ``wheel_velocity``: PI wheel-speed control (3.13)-(3.16) to ``wheel.ref`` (rad/s).
* ``wheel_angle``: wheel-angle PD (3.18) to ``wheel_angle.ref`` (rad).
* ``balance``: the upright state feedback ``balance.*`` ((4.9) when kpr = 0, (4.13)/E28 with the
  wheel-angle reference taken at the moment balance starts).  Falling beyond theta_0 turns the
  controller ``off`` (the pendulum cannot be caught again without a swing-up).
* ``swingup``: energy control (6.1)/(6.2) with the signs of ERRATA E35 only (no catch).
* ``law``: a law of one's own (:mod:`rwpend_control.user_law`, the lab's ``--law FILE.py``), given
  to the Controller at construction; an exception or a non-finite output turns the controller
  ``off`` with the reason (u = 0 on that sample, the fault in the status).
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

Every change of mode or law, and every fresh start of one, is a :class:`SwitchEvent`
(t, from, to, reason, code). What a status says for people (``reason``, ``fault``) it says for
programs as a code (``switch_code``: SWITCH_*, ``fault_code``: FAULT_*, the constants of
ControllerStatus, :mod:`rwpend_control.status_codes`), set together.

Fresh start (issue 21: gaps are survived).  A state estimate with a new re-synchronisation of
the estimator (``StateEstimate.resyncs`` changed: its state was re-initialised from the counts
after a long gap, a plant restart or refused samples) and a state stream that resumes after it
was stale for :data:`FRESH_START_GAP` (50 ms) or more (or restarts its seq) start the current
mode afresh (a shorter stale episode is answered with u = 0 and the law goes on), as if it had just been set, from
the state now -- not from what the controller remembers of the state before the gap:

* ``auto`` picks its law from the state: ``catch`` inside theta_s (6.5) (and the region (6.6)
  with ``catch_region``), else ``swingup`` -- so a pendulum that fell during the gap is swung
  up again; a wheel being stopped after an overspeed goes on being stopped;
* ``balance`` recaptures its wheel-angle reference (4.13)/E28 at the current wheel angle, or
  goes ``off`` with the reason "fell: ..." beyond theta_0;
* ``wheel_velocity`` resets the integrator of its PI law (3.14) (E15);
* ``swingup`` and ``wheel_angle`` carry no memory; the event is reported all the same.
* ``law`` (a law of one's own, :mod:`rwpend_control.user_law`) keeps whatever memory it has;
  the event is reported all the same.

Each fresh start is a SwitchEvent with the reason "fresh start of MODE: why" (in
controller/status and the log) and is counted (``fresh_starts``, /diagnostics); ``off`` has
nothing to start.

Safety (:mod:`rwpend_control.safety`; every transition is a SwitchEvent or a ``fault``, so it
shows in ControllerStatus and /diagnostics):

* stale state: no new state for ``state_timeout_samples`` h on the controller's clock -> u = 0
  once (answering seq + 1) and ``fault`` "stale state: ..." (FAULT_STALE_STATE; :meth:`Controller.check_stale`,
  called by the node's timer); the first fresh state clears it and starts the mode afresh
  (Fresh start, above).
  States with a seq that does not increase are refused (not answered, counted; FAULT_OUT_OF_ORDER).
* bad state (non-finite or implausible fields): refused, counted, u = 0 for that sample (it
  does not count as a fresh state for the watchdog; FAULT_BAD_STATE).
* wheel faster than ``wheel_speed_limit`` (motor speed, below the cut-off of (2.13)) in any
  mode but ``off`` -> mode ``off``, law ``brake`` (or ``off``), reason "overspeed: ..." (SWITCH_OVERSPEED);
  in ``auto`` the mode stays ``auto``: law ``brake`` (or ``off``: u = 0, the wheel coasts)
  until |w| < BRAKE_DONE_SPEED, then a fresh law from the state (swing-up, or catch if
  inside theta_s), reason "wheel stopped: ..." (SWITCH_WHEEL_STOPPED).  ``auto`` never ends by itself: a fall swings
  up again, an overspeed brakes and swings up again, a gap starts it afresh.
* ``balance`` saturated for longer than ``max_saturation_time`` -> ``saturation_action``
  (off, swingup or auto), reason "saturated: ..." (SWITCH_SATURATED).
* ``balance`` with the pendulum beyond theta_0 (out of the region where it can be caught)
  -> ``off``, reason "fell: ..." (SWITCH_FELL; ``auto`` swings up again instead, SWITCH_FALL).
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, replace
from typing import Any, Mapping

from . import design
from .design import Gains
from .laws import (Balance, EnergySwingUp, FrictionCompensation, WheelAnglePD, WheelVelocityPI,
                   upright_deviation)
from .parameters import (BY_NAME, CONFIG_PARAMS, DESIGN_DEFAULTS, DESIGN_GROUPS, MAX_ANGLE, MODES,
                         PARAM_FIELDS, lumped_lag, range_refusal, type_refusal)
from .user_law import LawError, LawState
from .safety import BRAKE_DONE_SPEED, StateWatchdog, brake, motor_speed
from .status_codes import (FAULT_BAD_STATE, FAULT_INTERNAL, FAULT_LAW, FAULT_NONE, FAULT_OUT_OF_ORDER,
                           FAULT_STALE_STATE, SWITCH_CATCH, SWITCH_ESTOP_CLEARED, SWITCH_ESTOP_RAISED,
                           SWITCH_FALL, SWITCH_FELL, SWITCH_FRESH_START, SWITCH_LAW_FAULT, SWITCH_OVERSPEED,
                           SWITCH_SATURATED, SWITCH_SET_MODE, SWITCH_START, SWITCH_WHEEL_BRAKED,
                           SWITCH_WHEEL_STOPPED)

#: how the text of a stale state's fault begins (for people: programs read FAULT_STALE_STATE)
STALE_FAULT = 'stale state'
#: how the text of a refused state's fault begins (for people: programs read FAULT_BAD_STATE)
BAD_STATE_FAULT = 'bad state'

#: s of silence of the state stream after which its return starts the mode afresh (module doc);
#: shorter stale episodes are answered with u = 0 and the law goes on
FRESH_START_GAP = 0.05
LAWS = ('off', 'wheel_velocity', 'wheel_angle', 'balance', 'swingup', 'catch', 'brake', 'law')

#: Limits of a sane state estimate; beyond them the sample is refused (u = 0, fault).
MAX_THETA_DOT = 200.0       # rad/s (a fall from upright reaches 2 omega_p = 18 rad/s)
MAX_FRICTION = 100.0        # control units
MAX_SEQ = 2**64 - 1         # seq is a uint64


#: the reasons of the switches to off when the plant's e-stop is raised and cleared
ESTOP_RAISED = 'e-stop raised: off (zero torque) until a mode is set after it is cleared'
ESTOP_CLEARED = 'e-stop cleared: off (zero torque) until a mode is set'


@dataclass(frozen=True)

class SwitchEvent:
    """A change of mode or law: at time t, from ``from_`` to ``to`` (``mode/law``), and why
    (``reason`` for people, ``code`` one of ControllerStatus's SWITCH_*)."""

    t: float
    from_: str
    to: str
    reason: str
    code: int = SWITCH_START


@dataclass
class Status:
    """What the controller did on the last sample (fields of ControllerStatus).
    :meth:`Controller.update` gives the fields by position: a new field goes last."""

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
    switch_code: int = SWITCH_START    # why the last switch happened (SWITCH_*), as reason says
    fault_code: int = FAULT_NONE       # what forces u = 0 (FAULT_*), as fault says
    event: SwitchEvent | None = None   # set on the sample on which a switch happened
    answer: bool = True    # False: the state was refused (out of order), publish no command
    note: str = ''         # the state stream recovered / restarted on this sample


def _table_fields(cls):
    """``cls`` with one field per configuration row of the parameter table
    (:data:`rwpend_control.parameters.CONFIG_PARAMS`), its default the row's; then @dataclass."""
    cls.__annotations__ = {p.field: type(p.default).__name__ for p in CONFIG_PARAMS}
    for p in CONFIG_PARAMS:
        setattr(cls, p.field, p.default)
    return cls


@dataclass(frozen=True)
@_table_fields
class ControllerConfig:
    """Every tunable of the controller: one field per row of the parameter table with ``config``
    (:mod:`rwpend_control.parameters`; ``balance.kpp`` <-> ``balance_kpp``), its default the row's."""

    @classmethod
    def designed(cls, rig, **overrides: Any) -> 'ControllerConfig':
        """The default configuration designed for ``rig`` (then ``overrides`` by field name): each
        design group from the defaults of its design parameters (the table's): balance =
        pddcontrol(1.5 omega_p, 0.707, 0.2) (4.11); patch = pddcontrolwpatch(1.5 omega_p, 0.707)
        (Section 6.3, the gains of Fig. 6.3); swing-up c_e, c_v from k_e = 4000, k_v = 4, k_u = 0.4
        (E34); wheel PI omega0 = 20 rad/s, zeta = 1 (3.15-3.16); wheel-angle PD omega0 = 10 rad/s,
        zeta = 0.707 (3.18); the swing-up's kick u_max.
        """
        gains: dict[str, float] = {}
        for group in DESIGN_GROUPS:
            gains.update(gains_from_design(rig, group, {}))
        base = config_with(cls(swingup_kick=rig.u_max), gains)
        return replace(base, **overrides) if overrides else base

    @property
    def balance_gains(self) -> Gains:
        return Gains(self.balance_kpp, self.balance_kdp, self.balance_kpr, self.balance_kdr)

    @property
    def patch_gains(self) -> Gains:
        return Gains(self.patch_kpp, self.patch_kdp, 0.0, self.patch_kdr)


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
    """Reasons why ``cfg`` is unacceptable for ``rig`` (empty when fine): first each value's type,
    then its range (its row of :data:`rwpend_control.parameters.PARAMS`), then what joins values."""
    values = [(p, getattr(cfg, p.field)) for p in CONFIG_PARAMS]
    errors = [e for e in (type_refusal(p, v) for p, v in values) if e]
    if errors:
        return errors
    errors = [e for e in (range_refusal(p, v, rig) for p, v in values) if e]
    if errors:
        return errors
    t_e = lumped_lag(rig)
    if abs(cfg.wheel_ref) >= cfg.wheel_speed_limit:
        errors.append(f'wheel.ref = {cfg.wheel_ref:g} rad/s must stay below wheel_speed_limit = '
                      f'{cfg.wheel_speed_limit:g} rad/s')
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
    """``cfg`` with values given by parameter name (``balance.kpp``) or field name; ValueError on
    unknown. An integer given for a number (a double row) is taken as a float."""
    changes = {}
    rows = {p.field: p for p in CONFIG_PARAMS}
    for key, v in values.items():
        row = BY_NAME.get(key) if key in PARAM_FIELDS else rows.get(key)
        if row is None:
            raise ValueError(f'unknown controller parameter {key!r}')
        if row.kind == 'double' and isinstance(v, int) and not isinstance(v, bool):
            v = float(v)
        changes[row.field] = v
    return replace(cfg, **changes)


def plausible_state(theta, theta_dot, wheel_angle, wheel_rate, friction, max_wheel_rate: float) -> bool:
    """True when :meth:`Controller._bad_state` finds nothing wrong with these fields, by the
    test every sample passes: each a float (not an int, a bool or anything else) within its
    limit -- the chained comparisons are False for nan and +-inf, as the general checks refuse
    them.  False: not decided here (an int field is sane), :meth:`Controller._bad_state` says."""
    return (type(theta) is float and type(theta_dot) is float and type(wheel_angle) is float
            and type(wheel_rate) is float and type(friction) is float
            and -MAX_ANGLE <= theta <= MAX_ANGLE and -MAX_ANGLE <= wheel_angle <= MAX_ANGLE
            and -MAX_THETA_DOT <= theta_dot <= MAX_THETA_DOT
            and -max_wheel_rate <= wheel_rate <= max_wheel_rate
            and -MAX_FRICTION <= friction <= MAX_FRICTION)


class Controller:
    """Mode switching + control laws + saturation + friction compensation + safety checks.

    ``update(t, seq, theta, theta_dot, wheel_angle, wheel_rate, friction, now) -> (u, status)``,
    theta from hanging (rad), rates rad/s, friction estimate in control units; t is the state's
    stamp and ``now`` the controller's clock at its arrival (s; default t).  ``check_stale(now)``
    from a periodic timer: the status of the zero command to send when the state went stale.
    """

    def __init__(self, rig, config: ControllerConfig | None = None, mode: str = 'off',
                 max_events: int = 200, user_law=None) -> None:
        """``user_law``: the law of mode ``law`` (a :class:`rwpend_control.user_law.UserLaw`)."""
        self.user_law = user_law
        self._law_t0: float | None = None     # state time when mode law started
        self._law_fault = ''
        self._friction_in = 0.0               # the state's friction estimate (for the law)
        self.rig = rig
        self.u_max = float(rig.u_max)
        self.omega_p = rig.omega_p
        self.h = rig.sample_period
        self.max_wheel_rate = 2.0 * rig.omega_max
        cfg = config if config is not None else ControllerConfig.designed(rig)
        errors = validate_config(cfg, rig)
        if errors:
            raise ValueError('invalid controller configuration: ' + '; '.join(errors))
        self.config = cfg
        self.watchdog = StateWatchdog(self._stale_after(cfg))
        self._build_laws()
        self.mode = 'off'
        self.law = 'off'
        self.t = 0.0
        self.last_switch = 0.0
        self.switch_count = 0
        self.reason = 'start'
        self.switch_code = SWITCH_START
        #: the plant's e-stop is raised (:meth:`estop`): no mode but off until it is cleared
        self.estopped = False
        self.bad_state_count = 0
        self.overspeed_trips = 0
        self.saturation_trips = 0
        self.fall_trips = 0
        self.fresh_starts = 0
        self._resyncs: int | None = None           # the estimator's resyncs of the last state
        self.events: deque[SwitchEvent] = deque(maxlen=max_events)
        self._pending: SwitchEvent | None = None
        self._last_x: float | None = None          # last upright deviation seen
        self._capture_ref = False
        self._sat_since: float | None = None       # balance saturated since (state time)
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
        self.watchdog.timeout = self._stale_after(c)

    def _stale_after(self, cfg: ControllerConfig) -> float:
        """Silence (s) after which the state is stale: state_timeout_samples h, plus h/2 so that
        the last of those samples is really missing and not just being delivered (and a silence
        of exactly N h in float arithmetic does not count)."""
        return (cfg.state_timeout_samples + 0.5) * self.h

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
    def _switch(self, t: float, mode: str, law: str, reason: str, code: int) -> None:
        """Change to ``mode``/``law`` at ``t``, why: ``reason`` (text) and ``code`` (SWITCH_*)."""
        ev = SwitchEvent(t, f'{self.mode}/{self.law}', f'{mode}/{law}', reason, code)
        self.mode, self.law = mode, law
        self.last_switch = t
        self.switch_count += 1
        self.reason = reason
        self.switch_code = code
        self.events.append(ev)
        self._pending = ev
        self._sat_since = None

    def estop(self, raised: bool, t: float | None = None) -> bool:
        """The plant's e-stop was raised or cleared. Raised: mode off (a switch, reason
        :data:`ESTOP_RAISED`), and no other mode until it is cleared. Cleared: the controller
        stays off -- zero torque -- until a mode is set again, as a hardware watchdog stays latched
        until re-armed (reason :data:`ESTOP_CLEARED`). Returns whether anything changed."""
        t = self.t if t is None else t
        if raised:
            if self.estopped:
                return False
            self.estopped = True
            self._switch(t, 'off', 'off', ESTOP_RAISED, SWITCH_ESTOP_RAISED)
            return True
        if not self.estopped:
            return False
        self.estopped = False
        self._switch(t, 'off', 'off', ESTOP_CLEARED, SWITCH_ESTOP_CLEARED)
        return True

    def set_mode(self, mode: str, t: float | None = None) -> tuple[bool, str]:
        """Request a mode; (ok, message).  Unknown modes, and ``balance`` with the pendulum
        farther than theta_0 from upright, are refused (nothing changes).  ``off`` also stops
        a wheel brake in progress."""
        if mode not in MODES:
            return False, f'unknown mode {mode!r} (one of {", ".join(MODES)})'
        if self.estopped and mode != 'off':
            return False, f'mode {mode} refused: the e-stop is raised (clear it first: ./rwpend estop --clear)'
        t = self.t if t is None else t
        if mode == self.mode and not (mode == 'off' and self.law != 'off'):
            return True, f'already in {mode}'
        x = self._last_x
        if mode == 'law':
            if self.user_law is None:
                return False, 'mode law refused: no law loaded (controller parameter law.file)'
            self._law_t0 = None
        if mode == 'balance':
            if x is not None and abs(x) > self.config.theta_0:
                return False, (f'balance refused: |theta-pi| = {abs(x):.3g} > theta_0 = '
                               f'{self.config.theta_0:g} (use auto to swing up)')
            self._capture_ref = True     # wheel-angle reference := wheel angle at the start
        if mode == 'wheel_velocity':
            self._wheel_pi.reset()
        law = {'auto': self._auto_law(x, None) if x is not None else 'swingup'}.get(mode, mode)
        self._switch(t, mode, law, f'set_mode {mode}', SWITCH_SET_MODE)
        return True, f'mode {mode}'

    def _auto_law(self, x: float, theta_dot: float | None) -> str:
        """The law of ``auto`` for this state: a catch holds until theta_0 (hysteresis)."""
        if self.law == 'catch':
            return 'swingup' if abs(x) > self.config.theta_0 else 'catch'
        return self._start_law(x, theta_dot)

    def _start_law(self, x: float, theta_dot: float | None) -> str:
        """The law ``auto`` starts with: catch inside theta_s (6.5) (and the region (6.6) with
        catch_region), else swing-up."""
        c = self.config
        if abs(x) < c.theta_s and (not c.catch_region or theta_dot is None
                                   or abs(theta_dot + self.omega_p * x) < design.switching_region_bound(self.rig)):
            return 'catch'
        return 'swingup'

    def _fresh_reason(self, note: str, resyncs: int | None) -> str:
        """Why this state starts the mode afresh ('' if it does not): a new re-synchronisation
        of the estimator, or the watchdog's note (stream resumed after stale / restarted)."""
        why = []
        if resyncs is not None:
            if self._resyncs is not None and resyncs != self._resyncs:
                why.append(f'estimator re-synchronised (resyncs {self._resyncs} -> {resyncs})')
            self._resyncs = resyncs
        # a stream silent for a few samples (a late state, a dropped one) resumes the law where it
        # was: a fresh start of a catch that is holding would itself throw the pendulum off
        short = note.startswith('state resumed') and self.watchdog.resumed_after < FRESH_START_GAP
        if note and not short:
            why.append(note)
        return '; '.join(why)

    def _fresh_start(self, t: float, x: float, theta_dot: float, why: str) -> None:
        """Start the current mode afresh from this state (module doc), reported."""
        mode = self.mode
        if mode == 'off':
            return
        self.fresh_starts += 1
        law = mode
        if mode == 'auto':
            law = self.law if self.law in ('brake', 'off') else self._start_law(x, theta_dot)
        elif mode == 'balance':
            if abs(x) > self.config.theta_0:
                self.fall_trips += 1
                self._switch(t, 'off', 'off', f'fell: |theta-pi|={abs(x):.3f}>{self.config.theta_0:g} '
                                              f'at a fresh start of balance ({why})', SWITCH_FELL)
                return
            self._capture_ref = True
        elif mode == 'wheel_velocity':
            self._wheel_pi.reset()
        self._switch(t, mode, law, f'fresh start of {mode}: {why}', SWITCH_FRESH_START)

    def pop_events(self) -> list[SwitchEvent]:
        out = list(self.events)
        self.events.clear()
        return out

    # ------------------------------------------------------------------ per sample
    def _bad_state(self, theta, theta_dot, wheel_angle, wheel_rate, friction) -> str:
        """Why the state is refused ('' when it is sane): a field not a finite number, an angle
        beyond MAX_ANGLE, a rate or the friction beyond its limit."""
        for name, v in (('theta', theta), ('theta_dot', theta_dot), ('wheel_angle', wheel_angle),
                        ('wheel_rate', wheel_rate), ('friction', friction)):
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                return f'{BAD_STATE_FAULT}: {name} = {v!r}'
        if abs(theta) > MAX_ANGLE or abs(wheel_angle) > MAX_ANGLE:
            return f'{BAD_STATE_FAULT}: angle beyond 1e7 rad'
        if abs(theta_dot) > MAX_THETA_DOT:
            return f'{BAD_STATE_FAULT}: |theta_dot| = {abs(theta_dot):.4g} > {MAX_THETA_DOT:g} rad/s'
        if abs(wheel_rate) > self.max_wheel_rate:
            return f'{BAD_STATE_FAULT}: |wheel_rate| = {abs(wheel_rate):.4g} > {self.max_wheel_rate:.4g} rad/s'
        if abs(friction) > MAX_FRICTION:
            return f'{BAD_STATE_FAULT}: |friction| = {abs(friction):.4g} > {MAX_FRICTION:g}'
        return ''

    def _law_output(self, t, x, theta, theta_dot, wheel_angle, wheel_rate) -> float:
        """u of the current mode/law (unsaturated, without friction compensation); switches
        law in ``auto`` and turns ``balance`` off beyond theta_0."""
        mode = self.mode
        if mode == 'auto':
            if self.law in ('brake', 'off'):
                return self._auto_stop_wheel(t, x, theta, theta_dot, wheel_angle, wheel_rate)
            law = self._auto_law(x, theta_dot)
            if law != self.law:
                if law == 'catch':
                    why, code = f'catch: |theta-pi|={abs(x):.3f}<{self.config.theta_s:g}', SWITCH_CATCH
                else:
                    why, code = f'fall: |theta-pi|={abs(x):.3f}>{self.config.theta_0:g}', SWITCH_FALL
                self._switch(t, 'auto', law, why, code)
            if law == 'catch':
                return self._patch(theta, theta_dot, wheel_angle, wheel_rate)
            return self._swing(theta, theta_dot, wheel_rate)
        if mode == 'balance':
            if abs(x) > self.config.theta_0:
                # out of the region where balance can catch it (Section 6.4): off, reported
                self.fall_trips += 1
                self._switch(t, 'off', 'off', f'fell: |theta-pi|={abs(x):.3f}>{self.config.theta_0:g}',
                             SWITCH_FELL)
                return 0.0
            if self._capture_ref:
                self._capture_ref = False
                self._balance.wheel_ref = self._balance_wheel_ref = wheel_angle
            return self._balance(theta, theta_dot, wheel_angle, wheel_rate)
        if mode == 'swingup':
            return self._swing(theta, theta_dot, wheel_rate)
        if mode == 'law':
            return self._user_law_output(t, theta, theta_dot, wheel_angle, wheel_rate)
        if mode == 'wheel_velocity':
            return self._wheel_pi(wheel_rate)
        if mode == 'wheel_angle':
            return self._wheel_pd(wheel_angle, wheel_rate)
        if self.law == 'brake':
            w = motor_speed(theta_dot, wheel_rate)
            if abs(w) < BRAKE_DONE_SPEED:
                self._switch(t, 'off', 'off', f'wheel braked: |w| = {abs(w):.1f} < {BRAKE_DONE_SPEED:g} rad/s',
                             SWITCH_WHEEL_BRAKED)
                return 0.0
            return brake(self.config.wheel_kp, w, self.u_max)
        return 0.0

    def _auto_stop_wheel(self, t, x, theta, theta_dot, wheel_angle, wheel_rate) -> float:
        """``auto`` after an overspeed: brake (or coast, law off) until |w| < BRAKE_DONE_SPEED,
        then start afresh from the state (swing-up, or catch inside theta_s)."""
        w = motor_speed(theta_dot, wheel_rate)
        if abs(w) >= BRAKE_DONE_SPEED:
            return brake(self.config.wheel_kp, w, self.u_max) if self.law == 'brake' else 0.0
        law = self._start_law(x, theta_dot)
        self._switch(t, 'auto', law, f'wheel stopped: |w| = {abs(w):.1f} < {BRAKE_DONE_SPEED:g} rad/s: '
                                     f'auto {law} again', SWITCH_WHEEL_STOPPED)
        if law == 'catch':
            return self._patch(theta, theta_dot, wheel_angle, wheel_rate)
        return self._swing(theta, theta_dot, wheel_rate)

    def _user_law_output(self, t, theta, theta_dot, wheel_angle, wheel_rate) -> float:
        """u of the user's law; a faulted law: u = 0, mode off with the reason (the fault goes
        into this sample's status)."""
        if self._law_t0 is None:
            self._law_t0 = t
        state = LawState(t - self._law_t0, theta, theta_dot, wheel_angle, wheel_rate, self._friction_in)
        try:
            return self.user_law(state)
        except LawError as exc:
            self._law_fault = f'law fault: {exc}'
            self._switch(t, 'off', 'off', self._law_fault, SWITCH_LAW_FAULT)
            return 0.0

    def _check_wheel_speed(self, t: float, theta_dot: float, wheel_rate: float) -> None:
        """Overspeed (motor speed beyond ``wheel_speed_limit``, below the cut-off (2.13)) while
        the controller drives the wheel: brake or zero torque, reported; mode off, except in
        ``auto``, which swings up again once the wheel has stopped."""
        if self.mode == 'off' or self.law in ('brake', 'off'):     # nothing driven / stopping
            return
        w = motor_speed(theta_dot, wheel_rate)
        limit = self.config.wheel_speed_limit
        if abs(w) > limit:
            self.overspeed_trips += 1
            law = 'brake' if self.config.wheel_speed_action == 'brake' else 'off'
            mode = 'auto' if self.mode == 'auto' else 'off'
            then = (f', then auto again below {BRAKE_DONE_SPEED:g} rad/s' if mode == 'auto' else '')
            self._switch(t, mode, law, f'overspeed: |w| = {abs(w):.0f} > wheel_speed_limit = {limit:g} rad/s '
                                       f'in {self.mode}/{self.law}: '
                                       + ('braking' if law == 'brake' else 'u = 0') + then, SWITCH_OVERSPEED)

    def _check_saturation(self, t: float, saturated: bool, x: float) -> bool:
        """``balance`` saturated for longer than max_saturation_time -> saturation_action;
        True when it switched."""
        if self.mode != 'balance' or not saturated:
            self._sat_since = None
            return False
        if self._sat_since is None or t < self._sat_since:
            self._sat_since = t
            return False
        held = t - self._sat_since
        c = self.config
        if held <= c.max_saturation_time:
            return False
        self.saturation_trips += 1
        action = c.saturation_action
        why = f'saturated: |u| at {self.u_max:g} for {held:.3f} s > max_saturation_time = {c.max_saturation_time:g} s'
        if action == 'auto':
            self._switch(t, 'auto', 'catch' if abs(x) <= c.theta_0 else 'swingup', why + ': auto',
                         SWITCH_SATURATED)
        else:
            self._switch(t, action, action, why + f': {action}', SWITCH_SATURATED)
        return True

    def update(self, t: float, seq: int, theta: float, theta_dot: float, wheel_angle: float,
               wheel_rate: float, friction: float = 0.0, now: float | None = None,
               resyncs: int | None = None) -> tuple[float, Status]:
        """One sample: the command u (saturated) and the status.  ``resyncs``: the estimator's
        count of re-synchronisations (StateEstimate.resyncs; None: not known); a change starts
        the mode afresh, as does a stream that resumes after stale (module doc)."""
        now = t if now is None else now
        # a bad state is answered with u = 0 but is no fresh state for the watchdog
        if plausible_state(theta, theta_dot, wheel_angle, wheel_rate, friction, self.max_wheel_rate):
            fault = ''
        else:
            fault = self._bad_state(theta, theta_dot, wheel_angle, wheel_rate, friction)
        fault_code = FAULT_BAD_STATE if fault else FAULT_NONE
        note = ''
        if not fault:
            ok, note = self.watchdog.admit(seq, now, t)
            if not ok:
                return 0.0, self._status(self.t, seq, fault=note, fault_code=FAULT_OUT_OF_ORDER, answer=False)
        self.t = t
        u_law = 0.0
        fc = 0.0
        if fault:
            self.bad_state_count += 1
        else:
            x = upright_deviation(theta)
            self._last_x = x
            self._friction_in = friction
            # (_fresh_reason is '' without a note and a change of resyncs: the path of every sample)
            fresh = self._fresh_reason(note, resyncs) if note or resyncs != self._resyncs else ''
            if fresh:
                self._fresh_start(t, x, theta_dot, fresh)
            limit = self.config.wheel_speed_limit        # (_check_wheel_speed does nothing within it)
            if not -limit <= wheel_rate - theta_dot <= limit:
                self._check_wheel_speed(t, theta_dot, wheel_rate)
            u_law = self._law_output(t, x, theta, theta_dot, wheel_angle, wheel_rate)
            if self.mode != 'off':
                fc = self._friction(theta_dot, wheel_rate, friction)
            # (_check_saturation only clears _sat_since outside balance: the path of every sample)
            if (self.mode == 'balance' or self._sat_since is not None) and \
                    self._check_saturation(t, abs(u_law + fc) > self.u_max, x):
                u_law = self._law_output(t, x, theta, theta_dot, wheel_angle, wheel_rate)
                fc = self._friction(theta_dot, wheel_rate, friction) if self.mode != 'off' else 0.0
        u_uns = u_law + fc
        umax = self.u_max
        u = umax if u_uns > umax else (-umax if u_uns < -umax else u_uns)
        ev, self._pending = self._pending, None
        if self._law_fault:
            fault, fault_code, self._law_fault = self._law_fault, FAULT_LAW, ''
        # (built here, not by _status, its fields by position in Status's order: every sample)
        status = Status(t, seq, self.mode, self.law, u, u_uns, fc, abs(u_uns) > umax, self.last_switch,
                        self.switch_count, self.reason, fault, self.switch_code, fault_code, ev, True, note)
        return u, status

    def _status(self, t: float, seq: int, **kw: Any) -> Status:
        """The status at ``t`` answering ``seq``: the mode, law and last switch now, and ``kw``."""
        return Status(t=t, seq=seq, mode=self.mode, law=self.law, last_switch=self.last_switch,
                      switch_count=self.switch_count, reason=self.reason, switch_code=self.switch_code, **kw)

    def internal_error(self, t: float, seq: int, exc: BaseException) -> Status:
        """The status of a sample on which ``update`` raised ``exc`` (u = 0, fault FAULT_INTERNAL)."""
        return self._status(t, seq, fault=f'internal error: {type(exc).__name__}: {exc}',
                            fault_code=FAULT_INTERNAL)

    def check_stale(self, now: float) -> Status | None:
        """From a periodic timer: when the state has just gone stale (no new state for
        ``state_timeout_samples`` h), the status of the zero command to publish (answering
        seq + 1 of the last state, so the plant applies it); None otherwise."""
        if not self.watchdog.check(now):
            return None
        self._sat_since = None
        wd = self.watchdog
        n = self.config.state_timeout_samples
        fault = (f'{STALE_FAULT}: no new state for {wd.silence(now) * 1e3:.1f} ms (> {n} samples of '
                 f'{self.h * 1e3:g} ms) after seq {wd.last_seq}; u = 0')
        return self._status(now, min(wd.last_seq + 1, MAX_SEQ), fault=fault, fault_code=FAULT_STALE_STATE)

    @property
    def stale(self) -> bool:
        return self.watchdog.stale

    @property
    def estimator_resyncs(self) -> int | None:
        """The estimator's re-synchronisation count of the last state taken (None: not known)."""
        return self._resyncs
