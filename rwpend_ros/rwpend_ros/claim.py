"""One controller per rig: the plant obeys the commands of one controller at a time. Pure: no
rclpy.

DDS here has no security (the Fast DDS of the wheels is built without it), so any process in the
rig's domain and namespace can publish ``command``: a student's laptop with the wrong domain id
or namespace, or a second controller started by mistake. Without a claim the plant would apply
whichever command came first for each sample and the two controllers would fight silently.
Like ros2_control, where one controller claims a command interface, the first controller whose
command the plant takes *claims* the rig (``MotorCommand.controller_id``, a random id each
controller draws at start-up); commands of any other controller are refused and counted, and
the intruder is reported. The rig is handed over only when the holder releases it (its last
command says ``release``: the controller is stopping) or has been silent -- no command at all
-- for ``timeout_samples`` samples of the plant; a free rig is claimed by the first command the
plant takes (one too old to act on claims nothing). A holder that keeps sending keeps the rig,
even while its commands come too late to be taken (the plant then holds the motor at zero, and
says why): like a claimed command interface, the rig is not taken from a live controller.

The timeout of the claim is not the plant's command timeout (3 samples, which zeroes the motor):
with two live controllers on one loaded 2-core machine, a hand-over after 3 samples gave the rig
to the other controller every few milliseconds to tens of milliseconds during the first seconds
(each stall of a controller's process) -- the fight the claim is there to stop. The plant nodes use
``claim_timeout_samples`` (default 500: 0.5 s at 1 kHz). The e-stop is not a command: it is
accepted from anyone.

    claim = CommandClaim(timeout_samples=500)
    taken = claim.admit(controller_id, k, lambda: plant.command(seq, u), release)
    # k: the plant's current sample index; claim.event: what changed ('claimed', 'released',
    # 'refused', or None), for the log
"""
from __future__ import annotations

from typing import Callable

#: the id of a sender that does not give one (a MotorCommand of an older or a hand-made
#: controller): such senders cannot be told apart from each other
ANONYMOUS = 0


class CommandClaim:
    """Which controller drives the rig (see the module doc)."""

    def __init__(self, timeout_samples: int) -> None:
        if isinstance(timeout_samples, bool) or not isinstance(timeout_samples, int) or timeout_samples < 1:
            raise ValueError(f'must be an integer >= 1 (samples), got {timeout_samples!r}')
        self.timeout_samples = int(timeout_samples)
        self.holder: int | None = None     # the controller_id that holds the rig
        self.last_k = 0                    # plant sample of the holder's newest command
        self.claims = 0                    # times a controller claimed a free rig
        self.releases = 0                  # the holder released it
        self.lapses = 0                    # the holder went silent and lost it
        self.refused = 0                   # commands of other controllers, refused
        self.intruder: int | None = None   # the newest controller refused
        self.intruder_k = -1               # plant sample of its newest refused command
        #: what the last admit() changed: 'claimed', 'released', 'refused' (first refusal of an
        #: intruder since the last change), or None
        self.event: str | None = None
        self._refusing: tuple[int, int | None] | None = None   # (intruder, holder) last said

    def admit(self, source: int, k: int, take: Callable[[], bool], release: bool = False) -> bool:
        """The command of controller ``source``, offered at plant sample ``k``: ``take()`` offers
        it to the plant (True: taken) when ``source`` may drive the rig -- it holds the rig, or
        the rig is free (no holder, or none of the holder's commands for ``timeout_samples``)
        and the plant takes this command, which claims it. ``release`` (from the holder): the
        rig is free, the command is not offered. Returns whether the command was taken;
        :attr:`event` says what changed."""
        self.event = None
        if source == self.holder:
            self.last_k = k                   # alive, whether or not the plant takes it
            if release:
                self.holder = None
                self.releases += 1
                self.event = 'released'
                return False
            return take()
        free = self.holder is None or k - self.last_k >= self.timeout_samples
        if free and not release:
            if not take():
                return False
            if self.holder is not None:
                self.lapses += 1              # the holder was silent for the timeout
            self.holder, self.last_k = source, k
            self.claims += 1
            self.event = 'claimed'
            return True
        if release:
            return False                      # an intruder's release changes nothing
        if (source, self.holder) != self._refusing:
            self.event = 'refused'            # said once per intruder and holder
            self._refusing = (source, self.holder)
        self.refused += 1
        self.intruder = source
        self.intruder_k = k
        return False

    def holder_alive(self, source: int, k: int) -> bool:
        """:meth:`admit`'s first step for a command that does not release, without the call of
        ``take``: True when ``source`` holds the rig -- then, as :meth:`admit` does, the holder
        is alive at ``k`` and :attr:`event` is None, and the caller offers the command to the
        plant (what :meth:`admit` would return is whether the plant takes it); False: nothing
        changed, :meth:`admit` decides."""
        if source != self.holder:
            return False
        self.event = None
        self.last_k = k
        return True

    def intruding(self, k: int, within: int) -> bool:
        """A command of another controller was refused within the last ``within`` samples
        before plant sample ``k``."""
        return self.intruder is not None and k - self.intruder_k < within

    def values(self) -> dict:
        """The claim's state for /diagnostics."""
        return {'claimed_by': format_id(self.holder), 'claims': self.claims, 'releases': self.releases,
                'claim_lapses': self.lapses, 'refused_other_controller': self.refused,
                'intruder': format_id(self.intruder)}


def format_id(source: int | None) -> str:
    """A controller id as the controller logs it (``0x`` + 16 hex digits), 'none' for None."""
    return 'none' if source is None else f'0x{source:016x}'
