"""The pieces of the recorded runs the fits use, each checked first (numpy, no rclpy).

A run's data is a :class:`rwpend_lab.data.RunData` (from its bag, or the lab's pure twin).  Every
function here refuses with :class:`IdentError` and the reason when the data cannot be what the
step needed: a procedure that refused (its fault in ``controller/status``), a bag without the
commands, a pendulum that was not at rest before a pulse, encoders counting the wrong way.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from rwpend_control.status_codes import LOOP_FAULTS
from rwpend_model.plant import Plant

from .checks import delivery_problem, Rest, direction_problem, late_commands_problem, rest_problem


#: a ramp's rotor that turns before the command reached this many amplifier steps (u_max/pwm_steps,
#: Section 2.5) was not stuck when the ramp began (``ramps``)
STUCK_STEPS = 3
#: the window before a procedure's refusal whose commands must have reached the motor for the
#: verdict to be the rig's: the longest a procedure judges (the saturation's 0.3 s) and more
REFUSAL_WINDOW_S = 0.5


def amplifier_step(rig) -> float:
    """The amplifier's command step u_max / pwm_steps (Section 2.5); 0 without quantization."""
    return rig.u_max / rig.pwm_steps if rig.pwm_steps else 0.0


class IdentError(Exception):
    """The identification cannot go on: the reason (for the student), nothing else is changed."""


@dataclass
class Record:
    """One stretch of a run: the commands and the counts of samples k0..k1-1 (t = 0 at k0)."""

    run: str
    k0: int
    u: np.ndarray
    pc: np.ndarray
    mc: np.ndarray
    pre: np.ndarray = field(default_factory=lambda: np.zeros(0))   # pendulum counts of the rest before k0
    theta0: float = 0.0        # pendulum state at k0 (rotor stuck), from ``pre`` (estimate.with_initial_state)
    theta_dot0: float = 0.0

    @property
    def n(self) -> int:
        return len(self.u)


def refused(name: str, d) -> None:
    """IdentError with the procedure's reason when it refused or stopped the step (a law fault on
    controller/status). The loop's faults -- a state a few ms late, on the rig in real time; a
    state refused as implausible, e.g. the estimator's first samples after a hand moved the
    pendulum between two runs -- are reported by the loop and do not stop the identification
    (what they did to the data, the identification's own checks judge). A refusal judged while
    the plant did not hold the commands (:func:`_late_before`) says that first: the PC fell
    behind, the verdict is not the rig's."""
    faults = [(t, f) for t, code, f in d.faults if code not in LOOP_FAULTS]
    if faults:
        t, fault = faults[0]
        reason = fault.split('NotReady: ', 1)[-1]
        late = _late_before(d, t)
        if late:
            raise IdentError(f'{name}: {late} (the procedure refused the step at t = {t:.2f} s: {reason})')
        raise IdentError(f'{name}: the step was refused at t = {t:.2f} s: {reason}')


def _late_before(d, t: float, window: float = REFUSAL_WINDOW_S) -> str | None:
    """:func:`~rwpend_ident.checks.late_commands_problem` over the ``window`` s before a refusal
    at ``t`` (None when the bag has no report of what the plant held)."""
    held = getattr(d, 'u_held', None)
    if held is None or np.all(np.isnan(held)):
        return None
    sl = d.window(t - window, t)
    return late_commands_problem(list(d.u[sl]), list(held[sl]))


def commands(name: str, d) -> np.ndarray:
    """The command the plant held over each sample (IdentError when the bag has none: no command
    topic).  The plant reports it with the next sample (``RunData.u_held``: the simulator's
    sim/true_state u_commanded, the rig's ``applied`` from the device): it differs from the
    recorded command where a command came too late for its sample (lockstep_timeout, a command
    refused as old, a command timeout), and then what the plant did is what counts.  Where the
    bag has no report: the recorded command."""
    if np.all(np.isnan(d.u)):
        raise IdentError(f'{name}: no commands in the recording (the identification needs the topics '
                         'encoders and command of the stack)')
    if np.any(np.isnan(d.pc)) or np.any(np.isnan(d.mc)):
        raise IdentError(f'{name}: {int(np.isnan(d.pc).sum())} encoder samples missing in the recording')
    held = getattr(d, 'u_held', None)
    if held is None or np.all(np.isnan(held)):
        return np.nan_to_num(d.u)
    return np.where(np.isnan(held), np.nan_to_num(d.u), held)


def first_input(name: str, d) -> int:
    """Index of the first sample with u != 0 (the step starts there)."""
    k = np.nonzero(np.abs(commands(name, d)) > 0)[0]
    if not k.size:
        raise IdentError(f'{name}: the command stayed 0 (the step never started)')
    return int(k[0])


def check_rest_before(name: str, rig, d, k: int, rest: Rest = Rest()) -> None:
    """IdentError unless the pendulum was at rest hanging with the rotor still before sample k."""
    n = max(2, int(round(rest.still_s / rig.sample_period))) - 1   # the procedure starts on the n-th sample
    if k < n:
        raise IdentError(f'{name}: less than {rest.still_s:g} s recorded before the step; the rest cannot be checked')
    dl = rig.count_angle
    why = rest_problem(list(d.pc[k - n:k] * dl), list(d.mc[k - n:k] * dl), rest)
    if why:
        raise IdentError(f'{name}: {why} (before the step at t = {k * rig.sample_period:.2f} s)')


def check_directions(name: str, rig, d, k0: int, u0: float) -> None:
    """The encoder and motor directions from the first pulse (rwpend_ident.checks)."""
    dl = rig.count_angle
    seg = slice(k0, min(d.n, k0 + int(round(0.3 / rig.sample_period))))
    dp = d.pc[seg] - d.pc[k0]
    dm = d.mc[seg] - d.mc[k0]
    held = getattr(d, 'u_held', None)
    if held is not None and not np.all(np.isnan(held)):
        # the controller's commands from the first it sent for the pulse, against what was held
        c = np.nan_to_num(d.u)
        first = np.nonzero(np.abs(c) > 0)[0]
        if first.size:
            k1 = int(first[0])
            why = delivery_problem(list(c[k1:seg.stop]), list(np.nan_to_num(held[k1:seg.stop])),
                                   pendulum_counts=float(np.max(np.abs(dp))) if dp.size else None)
            if why:
                raise IdentError(f'{name}: {why}')
    why = direction_problem(u0, float(dp[np.argmax(np.abs(dp))]) * dl, float(dm[np.argmax(np.abs(dm))]) * dl, dl)
    if why:
        raise IdentError(f'{name}: {why}')


def response(name: str, rig, d, k0: int, before: float = 0.02, after: float = 0.6) -> Record:
    """The samples from ``before`` s ahead of sample k0 until ``after`` s after the rotor re-stuck
    (its counts stop changing for good), or the end of the recording when that comes first (at
    least 30 ms after).  The swing of pendulum and rotor together once the rotor sticks carries the
    pendulum's share of the momentum, rho = b_p/b_r: on the heavy example rig 50 ms of it left
    b_p 0.7 % off (just outside its interval), 150 ms +0.30 % (the simulator) and +0.30 to +0.44 %
    (3 runs through the emulator; one outside its interval of 0.33 %), 600 ms -0.04 % and -0.04
    to -0.19 % (intervals 0.21-0.25 %: every parameter of the 4 inside its interval; the re-fit
    10-11 s instead of 7 s)."""
    h = rig.sample_period
    u = commands(name, d)
    moving = np.nonzero(np.diff(d.mc[k0:]) != 0)[0]
    if not moving.size:
        raise IdentError(f'{name}: the rotor did not turn')
    stop = k0 + int(moving[-1]) + 1
    if stop + int(round(0.03 / h)) >= d.n:
        raise IdentError(f'{name}: the rotor was still turning at the end of the recording')
    end = min(d.n, stop + int(round(after / h)))
    start = max(0, k0 - int(round(before / h)))
    pre = d.pc[max(0, k0 - int(round(Rest().still_s / h))):start].copy()
    return Record(name, start, u[start:end].copy(), d.pc[start:end].copy(), d.mc[start:end].copy(), pre)


def ramps(name: str, rig, d, gap: float = 0.2, after: float = 0.1, lead: float = 0.15,
          log=lambda s: None) -> list[Record]:
    """The torque ramps of the stiction run (stretches of nonzero command separated by at least
    ``gap`` s of u = 0), each checked to start from rest, each from ``lead`` s before the rotor first
    moved until ``after`` s after the command went back to 0; ``pre``: the pendulum counts from the
    rest window to the record start (while the rotor sticks the motor torque is internal: the
    pendulum just swings freely).  A ramp whose rotor count changed before the command reached
    ``STUCK_STEPS`` amplifier steps was not a break-away from stuck (the rotor was creeping, or a
    count flickered): it is left out and said through ``log``; IdentError when no ramp is left."""
    u = commands(name, d)
    h = rig.sample_period
    q = amplifier_step(rig) or 0.01
    on = np.nonzero(u != 0)[0]
    if not on.size:
        raise IdentError(f'{name}: the command stayed 0 (the step never started)')
    breaks = np.nonzero(np.diff(on) > gap / h)[0]
    out, early = [], []
    for a, b in zip(np.r_[on[0], on[breaks + 1]], np.r_[on[breaks], on[-1]] + 1):
        check_rest_before(name, rig, d, int(a))
        moved = np.nonzero(d.mc[a:b] != d.mc[a])[0]
        if not moved.size:
            raise IdentError(f'{name}: the rotor did not break away during the ramp at t = {a * h:.2f} s')
        at = abs(float(u[a + moved[0]]))
        if at < STUCK_STEPS * q:
            early.append(f't = {a * h:.2f} s (|u| = {at:.3g})')
            continue
        s0 = max(int(a) - int(round(0.02 / h)), int(a + moved[0]) - int(round(lead / h)))
        s1 = min(d.n, int(b) + int(round(after / h)))
        pre = d.pc[max(0, int(a) - int(round(Rest().still_s / h))):s0].copy()
        out.append(Record(name, s0, u[s0:s1].copy(), d.pc[s0:s1].copy(), d.mc[s0:s1].copy(), pre))
    if early:
        why = (f'the rotor count changed before the torque reached {STUCK_STEPS} amplifier steps in the '
               f'ramp at {", ".join(early)}: the rotor was not stuck when it began')
        if not out:
            raise IdentError(f'{name}: {why}')
        log(f'  {name}: {len(early)} of {len(early) + len(out)} ramps left out, {why}')
    return out


def applied(rig, u: np.ndarray) -> np.ndarray:
    """The torque the amplifier realises for the commands u: saturated and PWM-quantized
    (Section 2.5, the plant model's amplifier)."""
    q = np.vectorize(Plant(rig).quantize_command, otypes=[float])
    return q(np.asarray(u, float)) if len(u) else np.asarray(u, float)


def hold_means(name: str, rig, d, windows, batches: int = 5) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(mean rotor speed relative to the pendulum, mean applied torque, its standard error) of every
    window (start, end, level) of the friction run (Experiment 9: the control signal that holds a
    speed is the friction (3.17)).  The speed is the rotor count difference over the window (exact,
    whatever the pendulum does); the standard error from ``batches`` batch means.  The torque is
    corrected for what the rotor gained in speed over the window, theta_r'' = b_r (u - F) (2.15)
    with the base rig's b_r: a hold that ends 0.05 rad/s faster than it started puts 0.0003 units
    into the mean (twice the interval of a Coulomb level; a b_r 10 % off leaves a tenth of that).
    IdentError when the speed was not steady (the two halves differ by more than 3 %) or far from
    the level."""
    u = applied(rig, commands(name, d))
    h, dl = rig.sample_period, rig.count_angle
    t0 = first_input(name, d) * h
    rotor = d.mc + d.pc                       # the rotor's absolute angle (2.15), counts
    m = int(round(0.025 / h))

    def speed(k):                             # the absolute rotor speed at sample k, rad/s
        return (rotor[min(k + m, d.n - 1)] - rotor[max(k - m, 0)]) * dl / ((min(k + m, d.n - 1) - max(k - m, 0)) * h)
    ws, us, ss = [], [], []
    for a, b, level in windows:
        k0, k1 = int(round((t0 + a) / h)), int(round((t0 + b) / h))
        if k1 >= d.n:
            raise IdentError(f'{name}: the recording ended before the hold at {level:g} rad/s')
        km = (k0 + k1) // 2
        w = (d.mc[k1] - d.mc[k0]) * dl / ((k1 - k0) * h)
        w1, w2 = ((d.mc[km] - d.mc[k0]) * dl / ((km - k0) * h), (d.mc[k1] - d.mc[km]) * dl / ((k1 - km) * h))
        if abs(w1 - w2) > 0.03 * abs(w) or abs(w - level) > 0.1 * abs(level) + 2.0:
            raise IdentError(f'{name}: the wheel did not hold {level:g} rad/s (measured {w1:.1f} then {w2:.1f} '
                             'rad/s): tune the PI speed loop or lengthen the holds')
        parts = np.array_split(u[k0:k1], batches)
        means = np.array([p.mean() for p in parts])
        ws.append(w)
        gained = speed(k1) - speed(k0)
        us.append(float(u[k0:k1].mean()) - gained / (rig.b_r * (k1 - k0) * h))
        ss.append(max(float(means.std(ddof=1)) / np.sqrt(batches), 1e-4))
    return np.array(ws), np.array(us), np.array(ss)
