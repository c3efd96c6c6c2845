"""The identification experiments: which runs, with which signals (pure Python, no rclpy).

Each run is a :class:`rwpend_lab.experiment.Run` of the lab, run by the lab's runner through the
stack.  In the order they run (the pendulum at rest first, the free swing last, when it may swing):

* ``pulse+3`` ... ``pulse-6``: torque pulses of two amplitudes and both signs from rest
  (Experiment 3, Section 2.6) -> b_r, b_p (ERRATA E06: from the whole response, not from the
  20 ms of the pulse), the friction; the first one also checks the encoder and motor directions.
* ``step+10``, ``step-10``: a step of the command to +-u_max held 40 ms -> the motor lag T_e.
* ``stiction``: slow torque ramps of both signs until the rotor breaks away -> the static friction.
* ``friction``: the wheel held by PI control (3.14)-(3.16) at a series of speeds of both signs,
  reached along ramps so the pendulum hardly swings (Experiments 8-9) -> the friction curve (3.17).
* ``validation``: a torque sequence not used in the fit (held out) -> the identified model's fit.
* ``swing``: the free swing from 20 degrees, rotor stuck (Experiment 1) -> omega_p', pendulum damping.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from rwpend_control import design
from rwpend_lab.experiment import Prompt, Run

PROC = 'rwpend_ident.procedures:'
#: The estimator of every run: the filtered difference (3.3) needs no model of the rig. No
#: joint_states (a display topic, not fitted): on a 2-core PC with the emulator the 1 kHz loop of
#: a rig run kept the rate better without it (0.18-0.24 % of the samples taken late instead of
#: 0.61-1.31 %, the friction run, 2 runs each)
ESTIMATOR = {'estimator': 'filtered', 'T': 0.005, 'publish_joint_states': False}
#: The simulator of every run: in lockstep a command may take up to 5 s of wall time (a loaded
#: machine) before its sample is taken with u = 0 (the fits use what the plant applied anyway)
SIM = {'lockstep_timeout': 5.0}
STILL = Prompt('Let the pendulum hang still (hold it if it swings); the step starts when it is at rest.',
               'still', {'still_s': 1.0})
#: pulses (u0, width s) and steps of the command (u_max, width s)
PULSES = ((3.0, 0.05), (-3.0, 0.05), (6.0, 0.03), (-6.0, 0.03))
STEPS = ((10.0, 0.04), (-10.0, 0.04))
PULSE_RUN_S = 1.1
SWING_DEG = 20.0


@dataclass(frozen=True)
class Speeds:
    """The friction-curve schedule: levels (rad/s) reached along ramps of ``ramp`` rad/s^2 (in
    steps of ``step`` rad/s, the lab's WheelSpeedSteps) and held ``hold`` s; the last ``window`` s
    of each hold are averaged."""

    levels: tuple = (40.0, 80.0, 150.0, 250.0, 400.0, -40.0, -80.0, -150.0, -250.0, -400.0)
    ramp: float = 200.0
    step: float = 10.0
    hold: float = 1.5
    window: float = 1.0

    def schedule(self) -> tuple[list[float], list[float], list[tuple[float, float, float]]]:
        """(times, refs) of the reference staircase, and (start, end, level) of each averaging window."""
        times, refs, windows = [], [], []
        t, ref = 0.0, 0.0
        dt = self.step / self.ramp
        for level in self.levels:
            n = max(1, int(math.ceil(abs(level - ref) / self.step)))
            for i in range(1, n + 1):
                times.append(round(t, 6))
                refs.append(ref + (level - ref) * i / n)
                t += dt
            ref = level
            t += self.hold
            windows.append((round(t - self.window, 6), round(t, 6), level))
        return times, refs, windows

    @property
    def duration(self) -> float:
        return self.schedule()[2][-1][1]


FULL_SPEEDS = Speeds()
CHECK_SPEEDS = Speeds(levels=(60.0, 150.0, 300.0, -60.0, -150.0, -300.0), hold=1.2, window=0.8)
#: the held-out validation input: (time after rest s, u) -- wheel spun up both ways, a short kick
VALIDATION = ((0.0, 3.0), (1.0, 0.0), (2.5, -5.0), (2.9, 0.0), (4.0, 8.0), (4.06, 0.0))


def pulse_name(u0: float, step: bool = False) -> str:
    return f'{"step" if step else "pulse"}{u0:+g}'


def _pulse_run(u0: float, width: float, step: bool, rest_timeout: float) -> Run:
    kind = 'step of the command' if step else 'torque pulse'
    return Run(pulse_name(u0, step), f'{kind} u = {u0:+g} for {width * 1e3:g} ms from rest', PULSE_RUN_S,
               mode='law', law=PROC + 'Pulses', estimator=ESTIMATOR, sim=SIM,
               law_params={'times': [0.0, width], 'values': [u0, 0.0], 'rest_timeout': rest_timeout},
               prompts=(STILL,))


def stiction_run(rest_timeout: float) -> Run:
    return Run('stiction', 'slow torque ramps (2 units/s) of both signs until the rotor breaks away', 6.0,
               mode='law', law=PROC + 'BreakawayRamps', estimator=ESTIMATOR, sim=SIM,
               law_params={'signs': [1.0, -1.0], 'rate': 2.0, 'slip_speed': 5.0, 'u_limit': 4.0,
                           'rest_timeout': rest_timeout}, prompts=(STILL,))


def friction_run(rig, speeds: Speeds, rest_timeout: float) -> Run:
    g = design.pi_control(rig, 20.0, 1.0)
    times, refs, _ = speeds.schedule()
    levels = ', '.join(f'{w:+g}' for w in speeds.levels)
    return Run('friction', f'PI speed control (3.14)-(3.16) at {levels} rad/s, {speeds.hold:g} s each',
               speeds.duration + 0.8, mode='law', law=PROC + 'WheelSpeeds', estimator=ESTIMATOR, sim=SIM,
               law_params={'kdr': g.kdr, 'ki': g.ki, 'times': times, 'refs': refs, 'rest_timeout': rest_timeout},
               prompts=(STILL,))


def validation_run(rest_timeout: float) -> Run:
    times, values = [t for t, _ in VALIDATION], [u for _, u in VALIDATION]
    return Run('validation', 'held-out torque sequence for the validation of the identified model', 6.2,
               mode='law', law=PROC + 'Pulses', estimator=ESTIMATOR, sim=SIM,
               law_params={'times': times, 'values': values, 'rest_timeout': rest_timeout}, prompts=(STILL,))


def swing_run(duration: float) -> Run:
    th0 = math.radians(SWING_DEG)
    return Run('swing', f'free swing from {SWING_DEG:g} deg, no control', duration, mode='off',
               estimator=ESTIMATOR,
               # the encoders were zeroed hanging at rest; raised by hand, the rotor came along
               sim={**SIM, 'initial.theta': th0, 'initial.wheel_angle': th0},
               prompts=(Prompt(f'Lift the pendulum to about {SWING_DEG:g} degrees and hold it still.', 'held_at',
                               {'angle': th0, 'tol': math.radians(8), 'still_s': 0.5}),
                        Prompt('Let go of the pendulum now (do not push it).', 'released', {})))


def plan(rig, check: bool = False, rest_timeout: float = 3.0) -> list[Run]:
    """The runs of ``./rwpend identify`` (``check``: the short re-measurement of ``--check``)."""
    if check:
        runs = [_pulse_run(u, w, False, rest_timeout) for u, w in PULSES[2:]]
        runs += [_pulse_run(u, w, True, rest_timeout) for u, w in STEPS]
        return runs + [stiction_run(rest_timeout), friction_run(rig, CHECK_SPEEDS, rest_timeout), swing_run(10.0)]
    runs = [_pulse_run(u, w, False, rest_timeout) for u, w in PULSES]
    runs += [_pulse_run(u, w, True, rest_timeout) for u, w in STEPS]
    return runs + [stiction_run(rest_timeout), friction_run(rig, FULL_SPEEDS, rest_timeout),
                   validation_run(rest_timeout), swing_run(20.0)]
