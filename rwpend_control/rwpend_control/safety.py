"""Safety logic of the controller, pure Python (no rclpy): stale-state watchdog, wheel-speed limit,
wheel brake.  Used by :class:`rwpend_control.supervisor.Controller`; the controller node only
feeds it the clock.

Stale state (a dead or silent estimator, lost messages)
    The controller answers every state sample with a command (the loop of Section 3.1: one
    sample, one command).  When no *new* state has arrived for ``state_timeout_samples`` sampling
    periods h, measured on the controller's own clock (sim time in lockstep, so a stalled
    simulator is not a fault), the state is stale: the controller commands u = 0 once (as the
    answer to the next sample, seq + 1, so the plant applies it) and reports why; the plant's
    own command timeout keeps the motor at zero afterwards.  The first fresh state clears the
    fault and starts the configured mode afresh from the state (supervisor: ``auto`` swings
    up again if the pendulum fell, ``balance`` recaptures its wheel reference).
    A state whose seq does not increase is refused (out of order, duplicate) -- unless the
    stream was silent for longer than the timeout first, which is a restart (e.g. a restarted
    simulator starts again at seq 0).  The silence counts from the arrival of the last state on
    the controller's clock, or from its stamp when that is later (by at most
    :data:`MAX_STAMP_LEAD`): in lockstep the sample's stamp can run a sample or two ahead of the
    /clock the controller has received, and a late /clock must not fake a silence.

Wheel-speed limit
    The motor produces no torque in the direction of motion beyond the back-EMF cut-off
    omega_max = V_max / k_m = 828 rad/s of the rotor relative to the pendulum ((2.12)-(2.13),
    ERRATA E03): above it the wheel cannot be braked by the controller any more in the
    direction it spins.  The limit ``wheel_speed_limit`` (default 750 rad/s, below the cut-off
    and above the 610 rad/s the energy swing-up (6.1) reaches with the designed gains) is
    checked on w = theta_r' - theta' (the motor speed of (2.13)).  Above it the controller goes
    to mode ``off`` and either brakes the wheel (law ``brake``: the P wheel-speed law (3.13)
    with reference 0 on w, until |w| < :data:`BRAKE_DONE_SPEED`) or applies u = 0.  In mode
    ``auto`` it stays in ``auto`` (law ``brake`` or ``off``) and, once |w| < BRAKE_DONE_SPEED,
    swings up again: an overspeed costs a swing-up, never the loop.

Saturation in balance (Sections 4.3, 6.3)
    The linear balance design assumes |u| < u_max; a balance loop saturated for long has lost
    the pendulum or drives the wheel into the cut-off.  After ``max_saturation_time`` s of
    uninterrupted saturation in mode ``balance`` the controller falls back to
    ``saturation_action``: ``off``, ``swingup`` (energy control only) or ``auto`` (swing up
    and catch again, Chapter 6).
"""
from __future__ import annotations

import math

#: What to do when the wheel is faster than the limit.
WHEEL_SPEED_ACTIONS = ('brake', 'off')
#: Modes to fall back to when balance stays saturated.
SATURATION_ACTIONS = ('off', 'swingup', 'auto')
#: Braking ends (law ``off``) below this motor speed, rad/s (Coulomb friction, about 1 unit
#: (3.17), stops the rest).
BRAKE_DONE_SPEED = 5.0
#: A state stamp ahead of the controller's clock by more than this (s) is not trusted as the
#: time of the state (another clock, or garbage): its arrival time counts instead.
MAX_STAMP_LEAD = 1.0


def motor_speed(theta_dot: float, wheel_rate: float) -> float:
    """w = theta_r' - theta': speed of the rotor relative to the pendulum, the speed of the
    back-EMF limit (2.13)."""
    return wheel_rate - theta_dot


def brake(kp: float, w: float, u_max: float) -> float:
    """Wheel brake: the P law (3.13) with reference 0 on the motor speed w, saturated.

    u = -kp w drives w to 0 (theta_r'' = b_r (u - F), (2.15)); saturated it is the largest
    braking torque, which the back-EMF never removes (it only cuts torque *along* the motion).
    """
    u = -kp * w
    return u_max if u > u_max else (-u_max if u < -u_max else u)


class StateWatchdog:
    """Freshness of the state stream: seq order and silence on the controller's clock.

    ``admit(seq, now)`` for every arriving state, ``check(now)`` from a periodic timer; ``now``
    is the controller's clock in seconds (any origin, sim time in lockstep).
    """

    def __init__(self, timeout: float) -> None:
        if not (isinstance(timeout, (int, float)) and math.isfinite(timeout) and timeout > 0):
            raise ValueError(f'watchdog timeout must be > 0 s, got {timeout!r}')
        self.timeout = float(timeout)
        self.last_seq: int | None = None
        self.last_arrival: float | None = None   # controller's clock at the last accepted state
        self.last_time: float | None = None      # the later of that and the state's stamp
        self.stale = False
        self.resumed_after = 0.0
        self.episodes = 0        # times the stream went stale (seen by check())
        self.gaps = 0            # arrivals after a silence longer than the timeout
        self.restarts = 0        # seq went back after a silence: accepted as a restart
        self.out_of_order = 0    # refused: seq not newer, within the timeout

    def silence(self, now: float) -> float:
        """Seconds since the last accepted state (0 before the first)."""
        return 0.0 if self.last_time is None else now - self.last_time

    def admit(self, seq: int, now: float, stamp: float | None = None) -> tuple[bool, str]:
        """(accepted, note) for a state with ``seq`` (and ``stamp``, s, same clock as ``now``)
        arriving at ``now``.  Refused: note says why.  Accepted: note is non-empty when the
        stream recovers from stale or restarts."""
        last_time = self.last_time
        if (last_time is not None and not self.stale and seq > self.last_seq
                and now - last_time <= self.timeout and now >= self.last_arrival - self.timeout):
            # the next state of a live stream (every sample's path): what _admit_general does
            # when the seq is newer, there was no silence and the clock did not go back
            self.resumed_after = 0.0
            self.last_seq = int(seq)
            self.last_arrival = float(now)
            lead = stamp - now if stamp is not None else 0.0
            self.last_time = float(stamp) if 0.0 < lead <= MAX_STAMP_LEAD else float(now)
            return True, ''
        return self._admit_general(seq, now, stamp)

    def _admit_general(self, seq: int, now: float, stamp: float | None) -> tuple[bool, str]:
        """:meth:`admit` in every case (admit's first branch is this for the next state of a
        live stream)."""
        note = ''
        gap = self.silence(now)
        back = self.last_arrival is not None and now < self.last_arrival - self.timeout   # clock reset
        silent = self.last_time is not None and (gap > self.timeout or back)
        if self.last_seq is not None and seq <= self.last_seq:
            if not silent:
                self.out_of_order += 1
                return False, f'out-of-order state: seq {seq} <= last seq {self.last_seq}'
            self.restarts += 1
            note = f'state seq restarted at {seq} (was {self.last_seq})'
        if silent and gap > 0:
            self.gaps += 1
        #: s the stream was silent before this state, when it had gone stale (else 0)
        self.resumed_after = gap if self.stale else 0.0
        if self.stale:
            note = note or f'state resumed after {gap * 1e3:.1f} ms'
        self.stale = False
        self.last_seq = int(seq)
        self.last_arrival = float(now)
        lead = stamp - now if stamp is not None else 0.0
        self.last_time = float(stamp) if 0.0 < lead <= MAX_STAMP_LEAD else float(now)
        return True, note

    def check(self, now: float) -> bool:
        """True once, when the silence first exceeds the timeout (then stale until a state)."""
        if self.last_time is None or self.stale:
            return False
        if now < self.last_arrival:          # the clock went back (sim time reset): re-base
            self.last_arrival = self.last_time = now
            return False
        if now - self.last_time > self.timeout:
            self.stale = True
            self.episodes += 1
            return True
        return False
