"""The loop's health as the plant sees it, sample by sample (pure: no rclpy).

The plant (simulator or driver) is the one place that sees the whole loop end to end: every
sample goes out from it and every command comes back to it. :class:`LoopHealth` turns what it
sees into three verdicts a user must hear about:

* **dead**: the command timeout has held for ``dead_after`` samples in a row after the loop had
  been running (a command had come): nothing answers any more -- an estimator or controller that
  died or latched, a cut link. Reported once when it happens, again when the loop comes back,
  and as the node's exit status when it is still dead at the end (``./rwpend up`` then fails).
* **slow**: over the first ``check_window`` samples after the first command (the "first
  seconds"), more than ``late_limit`` of the commands came after the next sample instant, or
  the command timeout struck: this machine does not keep the sample rate with this layout --
  the advice says what to do.
* the counts for /diagnostics: late commands (all and over the last window), timeouts, deaths.
"""
from __future__ import annotations

#: exit status of a node process whose loop was dead at the end (no fresh command for long
#: before it stopped): ./rwpend up reports it and fails
EXIT_LOOP_DEAD = 3

#: advice printed with a "slow" verdict
SLOW_ADVICE = ('give the loop real-time priority (--rt-priority 50, as root or with an rtprio limit), '
               'keep other programs off the machine, run the loop in one process (--composed loop, '
               'the default of ./rwpend up on the simulator), or sample more slowly (--h 0.002)')


class LoopHealth:
    """Call :meth:`command` for every command the plant accepts and :meth:`sample` once per
    sample; each returns an event to report (``'dead'``, ``'alive'``, ``'slow'``) or None."""

    def __init__(self, h: float, dead_after_s: float = 2.0, check_after_s: float = 5.0,
                 late_limit: float = 0.01) -> None:
        if not (h > 0 and dead_after_s > 0 and check_after_s > 0 and 0 <= late_limit <= 1):
            raise ValueError('LoopHealth: h, dead_after_s and check_after_s must be > 0, '
                             f'late_limit in [0, 1] (got {h}, {dead_after_s}, {check_after_s}, {late_limit})')
        self.h = h
        self.dead_after = max(1, round(dead_after_s / h))
        self.check_window = max(1, round(check_after_s / h))
        self.late_limit = late_limit
        self.commands = 0          # commands accepted
        self.samples = 0           # samples since the first command
        self.late = 0              # samples whose command came after the next instant
        self.timeouts = 0          # samples held at zero by the command timeout (after the first command)
        self.timeout_run = 0       # consecutive such samples now
        self.dead = False
        self.deaths = 0            # times the loop was declared dead
        self.longest_dead_samples = 0   # the longest run of such samples
        self.checked = False       # the first-window verdict was given
        self.window_late = 0
        self.window_timeouts = 0
        self.verdict = ''          # the first-window verdict, for the start-up line and diagnostics

    def command(self) -> str | None:
        """A command was accepted: 'alive' when the loop was dead."""
        self.commands += 1
        self.timeout_run = 0
        if self.dead:
            self.dead = False
            return 'alive'
        return None

    def sample(self, late: bool, timed_out: bool) -> str | None:
        """One sample: ``late`` -- its command did not come before this instant; ``timed_out`` --
        the command timeout holds the motor at zero over it."""
        if not self.commands:
            return None            # no loop yet: a plant alone, or still starting
        if self.checked and not timed_out:
            # after the first window, a sample with a fresh command (every sample's path): what
            # _sample_general does then
            self.samples += 1
            self.late += bool(late)
            self.timeout_run = 0
            return None
        return self._sample_general(late, timed_out)

    def _sample_general(self, late: bool, timed_out: bool) -> str | None:
        """:meth:`sample` in every case once a command has come (sample's first branch is this
        after the first window, without the command timeout)."""
        self.samples += 1
        self.late += bool(late)
        event = None
        if timed_out:
            self.timeouts += 1
            self.timeout_run += 1
            self.longest_dead_samples = max(self.longest_dead_samples, self.timeout_run)
            if not self.dead and self.timeout_run >= self.dead_after:
                self.dead = True
                self.deaths += 1
                event = 'dead'
        else:
            self.timeout_run = 0
        if not self.checked:
            self.window_late += bool(late)
            self.window_timeouts += bool(timed_out)
            if self.samples >= self.check_window:
                self.checked = True
                frac = self.window_late / self.samples
                self.verdict = (f'first {self.samples * self.h:.0f} s of the loop: {100 * frac:.2f} % of '
                                f'the commands late, {self.window_timeouts} samples at zero by the '
                                f'command timeout')
                if frac > self.late_limit or self.window_timeouts:
                    event = event or 'slow'
        return event

    @property
    def longest_dead_s(self) -> float:
        return self.longest_dead_samples * self.h

    def dead_reason(self, lockstep_h: float | None = None) -> str:
        """Why the loop is dead. ``lockstep_h``: the sample period of a lockstep run, whose
        samples without a command need not each have cost ``h`` of wall time (the simulator runs
        on without waiting when no controller is left): said in samples and simulated s."""
        if lockstep_h is not None:
            span = f'{self.timeout_run} samples ({self.timeout_run * lockstep_h:.3f} s simulated)'
        else:
            span = f'{self.timeout_run * self.h:.1f} s'
        return (f'the loop is dead: no fresh command for {span} (the estimator or the controller '
                'does not answer); the motor is held at zero')

    def values(self, lockstep_h: float | None = None) -> dict[str, str]:
        """Key-values for /diagnostics (``lockstep_h``: as in :meth:`dead_reason`, the longest
        dead span in simulated s)."""
        frac = self.late / self.samples if self.samples else 0.0
        longest = self.longest_dead_s if lockstep_h is None else self.longest_dead_samples * lockstep_h
        return {'loop_late_commands': str(self.late), 'loop_late_percent': f'{100 * frac:.3f}',
                'loop_timeout_samples': str(self.timeouts), 'loop_dead': str(self.dead),
                'loop_deaths': str(self.deaths), 'loop_longest_dead_s': f'{longest:.3f}',
                'loop_first_check': self.verdict or 'pending'}


#: a sample stamped further than this from a node's clock is on another clock (s)
OTHER_CLOCK_S = 60.0


def other_clock(stamp_s: float, now_s: float, sim_time: bool = False,
                limit_s: float = OTHER_CLOCK_S) -> str | None:
    """Why a sample stamped ``stamp_s`` is not on the clock of the node that took it at
    ``now_s`` (both in s; ``sim_time``: the node has ``use_sim_time``), or None. A node on the
    wall clock beside a lockstep simulator (its stamps: the sim time) runs its watchdogs on the
    wall clock: a controller started one by one without ``use_sim_time`` declared a stale state
    at most samples of such a run, and the run crawled (docs/architecture.md, "Lockstep and
    time"); a node on sim time beside a plant on the wall clock has no time until a ``/clock``."""
    off = now_s - stamp_s
    if abs(off) <= limit_s:
        return None
    where = 'behind' if off > 0 else 'ahead of'
    head = f'samples are stamped {stamp_s:.3f} s, {abs(off):.0f} s {where} this node\'s clock: '
    if sim_time:
        cause = ('this node is on sim time (use_sim_time) and the plant is not (start this node without '
                 'use_sim_time, or the simulator with lockstep:=true)')
    else:
        cause = ('a lockstep simulator\'s sim time (start this node with -p use_sim_time:=true, as ./rwpend up '
                 '--lockstep does)')
    return head + cause + ' or another host\'s clock out of step; this node\'s watchdogs run on its own clock'
