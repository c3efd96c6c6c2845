"""Sample/command alignment of the estimator: which u each encoder sample is estimated with, and
when a sample waits for it.  Pure Python, no rclpy (the estimator node feeds it).

The observers (3.5)/(3.9)/(7.1)/(7.3) estimate sample k with the command held over
[t_{k-1}, t_k): the command that answered sample k-1 (MotorCommand.seq = k - 1).  Samples and
commands come on different topics from different processes, in either order::

    align = CommandAlignment(u_max=10.0)
    for s in align.sample(seq, sample, controller_present):   # encoder sample k arrived
        process(s, align.input_for(s_seq))                     # in this order
    released = align.command(seq, u)                           # a command arrived
    if released is not None: process(released, align.input_for(...))

Rules
    * While the controller is answering (its newest command answers one of the ``wait``
      samples before k - 1), sample k waits for command k - 1 -- until that command or sample
      k + 1 arrives, whichever is first.  With no command yet (start, plant restarted) the
      controller counts as having answered seq -1 when ``controller_present()`` says one
      publishes: samples 1-3 then wait for the first commands too (sample 1 can come before
      command 0 on another topic).  So a lockstep run gives the same estimates every time.
    * :meth:`command_for` picks by seq, not by arrival order: the command answering k - 1, else
      the newest answering an earlier sample (the amplifier holds it), else 0.  A replayed
      stream gives the live estimates whatever the interleaving of the two topics.
    * A sample whose seq goes back (the plant restarted its counter: driver reconnect,
      simulator restart) clears the commands: they answer the old run's samples.
    * Commands are clamped to |u| <= u_max; a non-finite u is refused (ValueError) and changes
      nothing.  The ``keep`` newest commands are kept.
"""
from __future__ import annotations

import math
from typing import Callable, Generic, TypeVar

S = TypeVar('S')


class CommandAlignment(Generic[S]):
    """The commands by seq, the sample waiting for its command, restart detection."""

    def __init__(self, u_max: float, wait: int = 3, keep: int = 64) -> None:
        if not (math.isfinite(u_max) and u_max > 0) or wait < 0 or keep < 1:
            raise ValueError(f'u_max > 0, wait >= 0, keep >= 1 needed, got {u_max!r}, {wait!r}, {keep!r}')
        self.u_max = float(u_max)
        self.wait = int(wait)
        self.keep = int(keep)
        self.commands: dict[int, float] = {}   # recent commands by the seq they answer
        self.u = 0.0                           # latest command received (clamped)
        self.u_seq = -1                        # newest seq answered (-1: none since the start)
        self.pending: tuple[int, S] | None = None
        self.deferred = 0                      # samples that waited for their command
        self.restarts = 0                      # seq went back: commands cleared
        self.last_seq: int | None = None       # seq of the last sample processed

    def command(self, seq: int, u: float) -> tuple[int, S] | None:
        """A command answering sample ``seq``: stored; returns the waiting (seq, sample) it
        releases -- process it now -- else None.  ValueError for a non-finite u."""
        if not math.isfinite(u):
            raise ValueError(f'non-finite command u={u!r} ignored')
        um = self.u_max
        self.u = um if u > um else (-um if u < -um else float(u))
        self.commands[seq] = self.u
        if len(self.commands) > self.keep:
            del self.commands[next(iter(self.commands))]
        self.u_seq = max(self.u_seq, seq)
        p = self.pending
        if p is not None and self.u_seq >= p[0] - 1:
            self.pending = None
            return p
        return None

    def sample(self, seq: int, sample: S, controller_present: Callable[[], bool]) -> list[tuple[int, S]]:
        """Sample ``seq`` arrived: the (seq, sample) pairs to process now, in order (the one that
        waited first); empty when this one waits for its command."""
        out = []
        if self.pending is not None:
            out.append(self.pending)
            self.pending = None
        useq = self.u_seq
        if useq < seq - 1 and useq >= seq - 1 - self.wait and (useq >= 0 or controller_present()):
            self.pending = (seq, sample)
            self.deferred += 1
            return out
        out.append((seq, sample))
        return out

    def input_for(self, seq: int) -> float:
        """The u to estimate sample ``seq`` with, called once per sample processed, in
        processing order (detects a restart of the plant's counter)."""
        if self.last_seq is not None and seq < self.last_seq:
            self.commands.clear()
            self.u_seq = -1
            self.restarts += 1
        self.last_seq = seq
        return self.command_for(seq)

    def command_for(self, k: int) -> float:
        """The u held over [t_{k-1}, t_k): the command answering sample k-1, else the newest one
        answering an earlier sample (the amplifier holds it), else 0."""
        u = self.commands.get(k - 1)
        if u is not None:
            return u
        older = [s for s in self.commands if s < k]
        return self.commands[max(older)] if older else 0.0
