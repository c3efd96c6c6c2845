"""When a rig run switches its controller on and when it is over: the lab monitor's decisions,
on wall time, without ROS (the monitor, :class:`rwpend_lab.rigrun.Monitor`, makes the calls).

A run whose steps arm the controller asks it for the run's mode with one ``set_parameters``
call. The call may go unanswered (a response lost while discovery settles): the same request is
made again after ``resend_s`` (setting a mode is idempotent). The controller may refuse the mode
for a moment (it judges the mode on its state, a few samples behind the counts the steps were
seen on): asked again every ``retry_pause_s`` until ``retry_s`` after the first asking, then the
refusal is the run's error. Once the mode is accepted the run lasts ``duration_s`` of wall time.
The run is over when the steps are done, no call is pending, its wall time has passed, and the
controller has answered the run's last sample -- or ``catch_up_s`` after the steps were done,
for a loop that lags the plant.
"""
from __future__ import annotations

from dataclasses import dataclass

#: s without an answer after which the arming call is made again
RESEND_S = 0.5
#: s a refusal of the run's mode is retried (the controller's state catching up)
RETRY_S = 1.0
#: s between a refusal and the next asking
RETRY_PAUSE_S = 0.05
#: s the end of a run waits for a controller that lags the plant to answer its last sample
CATCH_UP_S = 5.0


@dataclass
class Call:
    """The arming call in flight: the sample it was asked on, when to ask again unanswered, until
    when a refusal is retried."""

    seq: int
    resend_at: float
    retry_until: float


class Arming:
    """The arming call and the end of one rig run (times: a monotonic wall clock, s)."""

    def __init__(self, duration_s: float, resend_s: float = RESEND_S, retry_s: float = RETRY_S,
                 retry_pause_s: float = RETRY_PAUSE_S, catch_up_s: float = CATCH_UP_S) -> None:
        self.duration_s = duration_s
        self.resend_s, self.retry_s = resend_s, retry_s
        self.retry_pause_s, self.catch_up_s = retry_pause_s, catch_up_s
        self.call: Call | None = None
        self.retries = 0               # calls made again (unanswered or refused)
        self.armed_seq: int | None = None
        self.end_wall: float | None = None   # when the run ends, once the mode was accepted
        self.steps_done_at: float | None = None
        self.error = ''

    def ask(self, seq: int, now: float) -> None:
        """The steps say: arm now (seen on sample ``seq``); the caller makes the call."""
        self.call = Call(seq, now + self.resend_s, now + self.retry_s)

    def unanswered(self, now: float) -> bool:
        """Make the same call again? (no answer within ``resend_s``)"""
        if self.call is None or now <= self.call.resend_at:
            return False
        self.retries += 1
        self.call.resend_at = now + self.resend_s
        return True

    def answered(self, ok: bool, why: str, mode: str, now: float) -> str:
        """The controller's answer: 'armed' (the run's time starts now), 'again' (refused for
        now: ask again after ``retry_pause_s``), or 'refused' (``error`` says why). Only
        while a call is pending (after :meth:`ask`)."""
        call = self.call
        if ok:
            self.call = None
            self.armed_seq = call.seq
            self.end_wall = now + self.duration_s
            return 'armed'
        if now < call.retry_until:
            self.retries += 1
            call.resend_at = now + self.retry_pause_s + self.resend_s
            return 'again'
        self.call = None
        self.error = f'the controller refused mode {mode!r}: {why}'
        return 'refused'

    def steps_done(self, now: float) -> None:
        """The steps of the run are all done (the last sample of the run was seen)."""
        if self.steps_done_at is None:
            self.steps_done_at = now

    def over(self, now: float, command_seq: int, end_seq: int | None) -> bool:
        """Is the run over? ``command_seq``: the newest sample the controller answered;
        ``end_seq``: the run's last sample (None: not known)."""
        if self.steps_done_at is None or self.call is not None or self.error:
            return False
        if self.end_wall is not None and now < self.end_wall:
            return False
        return command_seq >= (end_seq or 0) or now - self.steps_done_at > self.catch_up_s
