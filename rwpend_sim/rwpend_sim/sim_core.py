"""Sample-by-sample logic of the simulated rig, without ROS: command hold, timeout, disturbances.

The node (sim_node.py) only moves messages and time in and out of :class:`SimCore`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Optional

from rwpend_model.plant import Plant
from rwpend_model.rig import Rig

#: Largest disturbance torque accepted by the disturb service (control units).
MAX_DISTURBANCE = 100.0
#: Largest tap accepted (rad/s).
MAX_TAP = 100.0
#: Longest torque disturbance accepted (s).
MAX_DURATION = 3600.0


@dataclass
class SimCounters:
    samples: int = 0
    commands: int = 0            # accepted commands
    rejected_commands: int = 0   # non-finite u, or answering a future sample
    stale_commands: int = 0      # answering an older sample than the last accepted one
    old_commands: int = 0        # answering a sample command_timeout_samples or more old
    saturated_commands: int = 0  # |u| > u_max (applied saturated)
    timeout_samples: int = 0     # samples integrated with u = 0 because of the command timeout
    timeouts: int = 0            # timeout episodes
    estop_samples: int = 0       # samples held at zero by the e-stop
    late_commands: int = 0       # lockstep: commands that did not arrive in time
    last_reject_reason: str = ''
    extra: dict = field(default_factory=dict)


class SimCore:
    """One simulated rig: plant + amplifier command hold + command timeout + disturbances.

    Per sample k: :meth:`sample` returns the encoder counts at t_k (published with seq k);
    then :meth:`advance` integrates to t_{k+1} with the command held (the latest accepted one,
    or 0 after ``command_timeout_samples`` samples without a fresh command, or under e-stop).
    A command is accepted, and held, only while the sample it answers is less than
    ``command_timeout_samples`` old: a controller that acts on old states (catching up after a
    pause) never moves the motor, and the motor is at zero within that many samples of the
    sample the last command answered (``held_seq``).
    """

    def __init__(self, rig: Rig, *, command_timeout_samples: int = 3, **plant_kwargs) -> None:
        if int(command_timeout_samples) < 1:
            raise ValueError('command_timeout_samples must be >= 1')
        self.rig = rig
        self.plant = Plant(rig, **plant_kwargs)
        self.timeout_samples = int(command_timeout_samples)
        self._umax = rig.u_max
        self.k = 0                       # seq of the next sample to publish
        self.u = 0.0                     # latest accepted command (before saturation)
        self.u_seq = -1                  # seq that the latest accepted command answered
        self.last_command_k = None       # sample index when the latest command was accepted
        self._zero_next = False          # the next sample is held at zero (lockstep: no command)
        self.timed_out = False
        self.estop = False
        #: seq the command held over the last interval answers (-1: u = 0 by timeout / e-stop)
        self.held_seq = -1
        self._torque_until = -1.0
        self._taps: list[tuple[float, float]] = []
        self._torques: list[tuple[float, float, float]] = []
        self.counters = SimCounters()

    def schedule_taps(self, times, sizes) -> None:
        """Taps at given simulated times (s): theta_dot += size (rad/s) at the first sample at or
        after each time -- scripted, so a lockstep run with taps is reproducible."""
        times, sizes = list(times), list(sizes)
        if len(times) != len(sizes):
            raise ValueError(f'taps: {len(times)} times but {len(sizes)} sizes')
        for t, dv in zip(times, sizes):
            if not (isinstance(t, (int, float)) and math.isfinite(t) and t >= 0):
                raise ValueError(f'tap time must be finite and >= 0, got {t!r}')
            if not (isinstance(dv, (int, float)) and math.isfinite(dv) and abs(dv) <= MAX_TAP):
                raise ValueError(f'tap size must be finite and |size| <= {MAX_TAP} rad/s, got {dv!r}')
        self._taps = sorted((float(t), float(dv)) for t, dv in zip(times, sizes))

    def schedule_torques(self, times, sizes, durations) -> None:
        """Torques on the pendulum at given simulated times (s): ``size`` control units for
        ``duration`` s from the first sample at or after each time (a rubber band, Experiment 15)
        -- scripted like the taps, so a lockstep run with them is reproducible."""
        times, sizes, durations = list(times), list(sizes), list(durations)
        if not len(times) == len(sizes) == len(durations):
            raise ValueError(f'torques: {len(times)} times, {len(sizes)} sizes, {len(durations)} durations')
        for t, d, dur in zip(times, sizes, durations):
            if not (isinstance(t, (int, float)) and math.isfinite(t) and t >= 0):
                raise ValueError(f'torque time must be finite and >= 0, got {t!r}')
            if not (isinstance(d, (int, float)) and math.isfinite(d) and abs(d) <= MAX_DISTURBANCE):
                raise ValueError(f'torque size must be finite and |size| <= {MAX_DISTURBANCE} units, got {d!r}')
            if not (isinstance(dur, (int, float)) and math.isfinite(dur) and 0 < dur <= MAX_DURATION):
                raise ValueError(f'torque duration must be in (0, {MAX_DURATION}] s, got {dur!r}')
        self._torques = sorted((float(t), float(d), float(dur)) for t, d, dur in zip(times, sizes, durations))

    # ------------------------------------------------------------- inputs
    def command(self, seq: int, u: float) -> tuple[bool, str]:
        """Offer a MotorCommand; returns (accepted, reason when refused)."""
        if type(u) is float and type(seq) is int and self.u_seq < seq == self.k and -self._umax <= u <= self._umax:
            # the command answering the newest sample, within |u| <= u_max (every sample's path
            # in lockstep): what _command_checked accepts, as it stores it (float, int: the same)
            self.u = u
            self.u_seq = seq
            self.last_command_k = seq
            self.counters.commands += 1
            return True, ''
        return self._command_checked(seq, u)

    def _command_checked(self, seq: int, u: float) -> tuple[bool, str]:
        """:meth:`command` in every case (its first branch is this for a command answering the
        newest sample within |u| <= u_max)."""
        c = self.counters
        if not isinstance(u, (int, float)) or not math.isfinite(u):
            c.rejected_commands += 1
            c.last_reject_reason = f'non-finite u ({u!r}) for seq {seq}'
            return False, c.last_reject_reason
        if seq > self.k:
            c.rejected_commands += 1
            c.last_reject_reason = f'command answers seq {seq}, but the newest sample is {self.k}'
            return False, c.last_reject_reason
        if seq <= self.u_seq:
            c.stale_commands += 1
            return False, f'stale command for seq {seq} (already have {self.u_seq})'
        if self.k - seq >= self.timeout_samples:
            # computed from a state that is too old to act on (a controller catching up after a
            # pause): never applied, so the motor is at zero within the timeout whatever comes
            c.old_commands += 1
            return False, (f'old command for seq {seq}: {self.k - seq} samples old at sample '
                           f'{self.k} (>= command_timeout_samples {self.timeout_samples})')
        if abs(u) > self.rig.u_max:
            c.saturated_commands += 1
        self.u = float(u)
        self.u_seq = int(seq)
        self.last_command_k = self.k
        c.commands += 1
        return True, ''

    def tap(self, dv: float) -> tuple[bool, str]:
        if not math.isfinite(dv) or abs(dv) > MAX_TAP:
            return False, f'tap must be finite and |tap| <= {MAX_TAP} rad/s, got {dv!r}'
        self.plant.tap(dv)
        return True, f'tapped the pendulum: theta_dot += {dv:g} rad/s'

    def torque(self, d: float, duration: float) -> tuple[bool, str]:
        if not math.isfinite(d) or abs(d) > MAX_DISTURBANCE:
            return False, f'torque must be finite and |torque| <= {MAX_DISTURBANCE} units, got {d!r}'
        if not math.isfinite(duration) or not 0.0 < duration <= MAX_DURATION:
            return False, f'duration must be in (0, {MAX_DURATION}] s, got {duration!r}'
        self.plant.disturbance = float(d)
        self._torque_until = self.plant.t + duration
        return True, f'torque {d:g} units on the pendulum for {duration:g} s'

    # ------------------------------------------------------------- loop
    def sample(self) -> tuple[int, int, int]:
        """(seq, pendulum_counts, motor_counts) of the current sample t_k."""
        pc, mc = self.plant.counts()
        return self.k, pc, mc

    def held_command(self) -> float:
        """The command the amplifier holds over [t_k, t_k+1): 0 on timeout or e-stop."""
        self.held_seq = -1
        if self.estop:
            self.counters.estop_samples += 1
            return 0.0
        # fresh while the sample the command answers is less than timeout_samples old: a command
        # computed from sample j drives the motor over [t_j, t_j+N) at most
        fresh = self.u_seq >= 0 and self.k - self.u_seq < self.timeout_samples and not self._zero_next
        self._zero_next = False
        if not fresh:
            if not self.timed_out:
                self.counters.timeouts += 1
            self.timed_out = True
            self.counters.timeout_samples += 1
            return 0.0
        self.timed_out = False
        self.held_seq = self.u_seq
        return self.u

    def no_command(self) -> None:
        """The command of the current sample will not come (lockstep gave up waiting for it): the
        next :meth:`advance` holds u = 0, whatever was held before."""
        self._zero_next = True

    def advance(self) -> float:
        """Integrate [t_k, t_k+1) and move to sample k+1; returns the command held."""
        u = self.held_command()
        while self._taps and self._taps[0][0] <= self.plant.t + 1e-9:
            self.plant.tap(self._taps.pop(0)[1])
        while self._torques and self._torques[0][0] <= self.plant.t + 1e-9:
            _, d, dur = self._torques.pop(0)
            self.torque(d, dur)
        if self._torque_until >= 0.0 and self.plant.t >= self._torque_until - 1e-12:
            self.plant.disturbance = 0.0
            self._torque_until = -1.0
        self.plant.step(u)
        self.k += 1
        self.counters.samples += 1
        return u


@dataclass(frozen=True)
class Truth:
    """The simulated plant at t_k (sim/true_state): angles, rates, the command held over
    [t_k-1, t_k) and the seq it answered (-1: zero by timeout or e-stop)."""

    theta: float
    theta_dot: float
    wheel_angle: float
    wheel_rate: float
    u_applied: float
    torque: float
    friction: float
    disturbance: float
    stuck: bool
    timed_out: bool
    command_seq: int

    def __init__(self, theta: float, theta_dot: float, wheel_angle: float, wheel_rate: float,
                 u_applied: float, torque: float, friction: float, disturbance: float, stuck: bool,
                 timed_out: bool, command_seq: int) -> None:
        # the generated __init__ of a frozen dataclass sets each field through object.__setattr__
        # (twice the time); made every sample (SimHardware.read)
        d = self.__dict__
        d['theta'], d['theta_dot'], d['wheel_angle'], d['wheel_rate'] = theta, theta_dot, wheel_angle, wheel_rate
        d['u_applied'], d['torque'], d['friction'], d['disturbance'] = u_applied, torque, friction, disturbance
        d['stuck'], d['timed_out'], d['command_seq'] = stuck, timed_out, command_seq


@dataclass(frozen=True)
class Reading:
    """What :meth:`SimHardware.read` gives for sample ``seq``."""

    seq: int
    pendulum_counts: int
    motor_counts: int
    #: the command held over [t_k-1, t_k), saturated: the u of the observers (3.5)/(7.1)
    u_prev: float
    truth: Optional[Truth] = None

    def __init__(self, seq: int, pendulum_counts: int, motor_counts: int, u_prev: float,
                 truth: Optional[Truth] = None) -> None:
        # as Truth.__init__: the fields stored directly, made every sample
        d = self.__dict__
        d['seq'], d['pendulum_counts'], d['motor_counts'], d['u_prev'], d['truth'] = \
            seq, pendulum_counts, motor_counts, u_prev, truth


class SimHardware:
    """The simulated rig (:class:`rwpend_sim.sim_core.SimCore`) as the loop's hardware.

    ``read`` gives sample k; ``write`` offers the command answering it (the core's freshness
    rule: refused when ``command_timeout_samples`` old, non-finite or for a future sample);
    ``advance`` integrates [t_k, t_k+1) with the command held then (zero on timeout or e-stop).
    ``truth`` False: the readings carry no :class:`Truth` (a study's batch keeps the plant's
    truth itself, rwpend_sweep.batch)."""

    def __init__(self, core: SimCore, truth: bool = True) -> None:
        self.core = core
        self.u_max = core.rig.u_max
        self._u_prev = 0.0
        self.truth = bool(truth)

    @property
    def k(self) -> int:
        return self.core.k

    def read(self) -> Reading:
        """Sample k: the core's :meth:`SimCore.sample` and the plant's truth (one call of
        :meth:`Plant.readout` for both)."""
        core = self.core
        plant = core.plant
        if not self.truth:
            pc, mc = plant.counts()
            return Reading(core.k, pc, mc, self._u_prev)
        pc, mc, th, thd, thr, thrd, torque, friction, stuck = plant.readout()
        truth = Truth(th, thd, thr, thrd, plant.u_held, torque, friction, plant.disturbance, bool(stuck),
                      bool(core.timed_out), core.held_seq)
        return Reading(core.k, pc, mc, self._u_prev, truth)

    def write(self, seq: int, u: float) -> tuple[bool, str]:
        return self.core.command(seq, u)

    @property
    def timed_out(self) -> bool:
        return self.core.timed_out

    def no_command(self) -> None:
        """Zero over the current interval whatever was held (a controller released the rig)."""
        self.core.no_command()

    def advance(self) -> float:
        """Integrate the current interval; returns the command held over it."""
        u = self.core.advance()
        m = self.u_max
        self._u_prev = m if u > m else (-m if u < -m else u)
        return u
