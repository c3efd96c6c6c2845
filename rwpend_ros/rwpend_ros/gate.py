"""The one way to the plant for a command (pure: no rclpy): the claim (one controller per rig,
:mod:`rwpend_ros.claim`), the plant's own rule (freshness, |u|, e-stop: the hardware's
``write``) and the loop's health (:mod:`rwpend_ros.health`), for the loop's own controller and
for a command from the ``command`` topic alike.

The hardware is any object with ``k`` (the sample it is at), ``write(seq, u) -> (taken,
reason)``, ``advance() -> u held``, ``timed_out`` and ``no_command()``: the simulator's
(:class:`rwpend_sim.sim_core.SimHardware`).
"""
from __future__ import annotations

from typing import Optional

from rwpend_ros.claim import CommandClaim
from rwpend_ros.health import LoopHealth


class CommandGate:
    """The one way to the hardware for a command: the claim (one controller per rig,
    :class:`rwpend_ros.claim.CommandClaim`), the hardware's own rule (freshness, |u|, e-stop:
    :meth:`SimHardware.write`) and the loop's health (:class:`rwpend_ros.health.LoopHealth`),
    for the loop's own controller and for a command from the topic alike."""

    def __init__(self, hardware, claim: CommandClaim, health: LoopHealth) -> None:
        self.hardware = hardware
        self.claim = claim
        self.health = health
        #: the newest health event ('dead', 'alive', 'slow') not yet reported, else None
        self.event: Optional[str] = None
        self.last_reason = ''

    def offer(self, source: int, seq: int, u: float, release: bool = False) -> bool:
        """The command of controller ``source``; True when the hardware took it. :attr:`claim`
        ``.event`` says what changed in the claim (a release zeroes the motor now)."""
        hw = self.hardware
        if not release and self.claim.holder_alive(source, hw.k):
            # the holder's command (every sample's path): what admit gives it, without the closure
            taken, self.last_reason = hw.write(seq, u)
            if taken:
                self.event = self.health.command() or self.event
            return taken
        return self._offer_claimed(source, seq, u, release)

    def _offer_claimed(self, source: int, seq: int, u: float, release: bool) -> bool:
        """:meth:`offer` in every case, through :meth:`CommandClaim.admit` (offer's first branch
        is this for the holder's command)."""
        reason = ['']

        def take() -> bool:
            ok, why = self.hardware.write(seq, u)
            reason[0] = why
            return ok
        taken = self.claim.admit(source, self.hardware.k, take, release)
        self.last_reason = reason[0]
        if self.claim.event == 'released':
            self.hardware.no_command()
        if taken:
            self.event = self.health.command() or self.event
        return taken

    def interval(self, late: bool) -> float:
        """The hardware integrates the current interval (``late``: its command did not come
        before the next instant); returns the command held."""
        u = self.hardware.advance()
        self.event = self.health.sample(late, self.hardware.timed_out) or self.event
        return u

    def take_event(self) -> Optional[str]:
        event, self.event = self.event, None
        return event
