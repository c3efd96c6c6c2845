"""Which encoder samples an estimator takes: seq gaps, duplicates, plant restarts, refused
samples and re-synchronisation.  Pure Python, no rclpy.

Every encoder sample carries the plant's sample counter ``seq`` (EncoderCounts.msg: +1 every h).
The estimators of :mod:`rwpend_estimation.estimators` compare each sample with the last one
they *took* (the reference) and ask :class:`GapTracker` for a :class:`Verdict`:

``first``      the first sample: the estimate starts from its counts.
``take``       a plausible sample ``gap`` = seq - seq_ref samples after the reference; the
               ``gap - 1`` samples in between are missing (``missed``).  Plausible means that no
               encoder moved faster than ``max_rate`` over the whole gap (Section 3.1: the counts
               are the angles, one count = Delta):
                   |delta counts| <= gap * max_rate * h / Delta         on both encoders.
               At most ``max_bridge`` missing samples are bridged (the estimator steps its
               recursion through them); longer gaps re-synchronise.
``resync``     re-synchronise on this sample: the estimator re-initialises its state from the
               counts.  Reasons: a gap longer than ``max_bridge`` samples; a seq that goes back
               (the plant restarted its counter: ``absolute``, the counts start again from the
               plant's zero); or refused samples -- the sample is implausible against the
               reference but plausible against the newest refused sample (the refused samples
               were right and the reference was stale), or :data:`MAX_REFUSED` samples in a row
               were refused already.
``refuse``     implausible against the reference (a glitch, if the next sample contradicts it).
``duplicate``  the same seq and counts as the reference again: nothing new, ignored.

No latch, by construction: of any ``MAX_REFUSED + 1`` consecutive samples that are not exact
repeats of the reference, at least one is taken (``take``, ``resync``); the reference never
stays behind the samples for longer than that, whatever the input.  A late sample (older seq)
is dropped before the estimator by the subscription's order gate (rwpend_ros.order), which tells
a restart from a late message by its stamp; here, without stamps, any seq that goes back is a
restart -- a late sample costs one re-synchronisation, never a latch.

``seq=None`` (no counter known) counts every sample as the next one (gap 1).
The raw counters are int32: differences are taken modulo 2**32 (multi-turn counting never
wraps, see estimators.py).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

#: At most this many consecutive samples are refused: the next implausible one re-synchronises.
#: 2 lets a glitch (one bad sample) and a double glitch be refused and bridged, while a stale
#: reference costs one refused sample (the second sample agrees with the first).
MAX_REFUSED = 2

_TWO32 = 1 << 32
_TWO31 = 1 << 31

FIRST, TAKE, RESYNC, REFUSE, DUPLICATE = 'first', 'take', 'resync', 'refuse', 'duplicate'


def count_step(new: int, old: int) -> int:
    """new - old of two int32 counter readings, modulo 2**32 (in [-2**31, 2**31))."""
    return ((new - old + _TWO31) % _TWO32) - _TWO31


class Verdict(NamedTuple):
    """What to do with one sample (see the module doc)."""

    kind: str
    dp: int = 0             # pendulum counts since the reference (take, resync unless absolute)
    dm: int = 0             # motor counts since the reference
    gap: int = 1            # seq steps since the reference (1: the next sample)
    missed: int = 0         # samples without an estimate just before this one
    absolute: bool = False  # resync on the absolute counts (the plant restarted)
    reason: str = ''        # resync: why; refuse / duplicate: the message


@dataclass
class GapStats:
    """Counters of a :class:`GapTracker` since it was created (for /diagnostics)."""

    taken: int = 0          # samples taken (first, take, resync)
    refused: int = 0        # implausible samples refused
    duplicates: int = 0     # repeats of the reference ignored
    gaps: int = 0           # samples taken after missing ones
    missed: int = 0         # missing samples in those gaps (refused ones included)
    bridged: int = 0        # missing samples bridged (take)
    longest_gap: int = 0    # most samples missing before one taken sample
    resyncs: int = 0        # re-synchronisations (and re-zeroings by rebase)
    last_resync: str = ''   # the reason of the last one
    last_resync_seq: int | None = None


class GapTracker:
    """The reference sample, the run of refused samples and the counters (module doc).

    ``max_step``: counts per sample an encoder may move at most (max_rate h / Delta);
    ``max_bridge``: most missing samples bridged.
    """

    def __init__(self, max_step: float, max_bridge: int) -> None:
        self.max_step = float(max_step)
        self.max_bridge = int(max_bridge)
        self.stats = GapStats()
        self._ref: tuple[int | None, int, int] | None = None      # (seq, pc, mc) last taken
        self._newest: tuple[int | None, int, int] | None = None   # last received
        self._refused: list[tuple[int | None, int, int]] = []     # refused since the reference

    def with_limits(self, max_step: float, max_bridge: int) -> 'GapTracker':
        """A copy with other limits that continues from this one (reference, counters)."""
        new = GapTracker(max_step, max_bridge)
        new.stats = GapStats(**vars(self.stats))
        new._ref, new._newest, new._refused = self._ref, self._newest, list(self._refused)
        return new

    @property
    def reference(self) -> tuple[int | None, int, int] | None:
        """(seq, pendulum_counts, motor_counts) of the last sample taken."""
        return self._ref

    @property
    def newest(self) -> tuple[int | None, int, int] | None:
        """(seq, pendulum_counts, motor_counts) of the last sample received (taken or not)."""
        return self._newest

    def adopt(self, seq: int | None, pc: int, mc: int) -> None:
        """Make (seq, pc, mc) the reference without a verdict (an estimator continuing from
        another one's estimate of that sample)."""
        self._ref = self._newest = (seq, int(pc), int(mc))
        self._refused.clear()

    def rebase(self, reason: str) -> tuple[int | None, int, int] | None:
        """The newest sample received becomes the reference (a re-zeroing, e.g. ~/reset);
        counted as a re-synchronisation.  Returns it (None before the first sample)."""
        if self._newest is None:
            return None
        self._ref = self._newest
        self._refused.clear()
        self._count_resync(self._newest[0], reason)
        return self._ref

    # ------------------------------------------------------------------ the verdict
    def take_next(self, seq: int, pc: int, mc: int) -> tuple[int, int] | None:
        """:meth:`judge` for the sample right after the reference (seq one newer, no refused
        sample pending) when it is plausible -- every sample's case: its verdict TAKE as
        (dp, dm), with judge's bookkeeping, without the Verdict.  None: another case, nothing
        changed (ask :meth:`judge`)."""
        ref = self._ref
        if ref is None or seq is None or ref[0] is None or seq != ref[0] + 1 or self._refused:
            return None
        dp = ((pc - ref[1] + _TWO31) % _TWO32) - _TWO31
        dm = ((mc - ref[2] + _TWO31) % _TWO32) - _TWO31
        limit = self.max_step              # gap 1: judge's limit 1 * max_step is max_step
        if not (-limit <= dp <= limit and -limit <= dm <= limit):
            return None
        self._newest = self._ref = (seq, pc, mc)
        self.stats.taken += 1
        return dp, dm

    def judge(self, seq: int | None, pc: int, mc: int) -> Verdict:
        """The verdict for a sample (ints; seq >= 0 or None) -- and its bookkeeping."""
        sample = (seq, pc, mc)
        self._newest = sample
        ref = self._ref
        if ref is None:
            return self._take(sample, Verdict(FIRST, absolute=True))
        rseq = ref[0]
        if seq is not None and rseq is not None and seq <= rseq:
            if seq == rseq and pc == ref[1] and mc == ref[2]:
                self.stats.duplicates += 1
                return Verdict(DUPLICATE, reason=f'seq {seq} again (same counts): ignored')
            return self._resync(sample, Verdict(RESYNC, absolute=True, reason=(
                f'plant restarted: seq {seq} after {rseq}')))
        gap = 1 if seq is None or rseq is None else seq - rseq
        # count_step and _plausible written out: this is every sample's path
        dp = ((pc - ref[1] + _TWO31) % _TWO32) - _TWO31
        dm = ((mc - ref[2] + _TWO31) % _TWO32) - _TWO31
        limit = gap * self.max_step
        if -limit <= dp <= limit and -limit <= dm <= limit:
            missed = gap - 1
            if missed > self.max_bridge:
                return self._resync(sample, Verdict(RESYNC, dp, dm, gap, missed, reason=(
                    f'gap of {missed} samples > max_bridge = {self.max_bridge}')))
            if not missed and not self._refused:      # the next sample: _take written out
                self._ref = sample
                self.stats.taken += 1
                return Verdict(TAKE, dp, dm)
            self.stats.bridged += missed
            return self._take(sample, Verdict(TAKE, dp, dm, gap, missed))
        return self._implausible(sample, dp, dm, gap)

    def _implausible(self, sample, dp: int, dm: int, gap: int) -> Verdict:
        seq, pc, mc = sample
        if self._refused:
            r = self._refused[-1]
            g = 1 if seq is None or r[0] is None else seq - r[0]
            if g >= 1 and self._plausible(count_step(pc, r[1]), count_step(mc, r[2]), g):
                return self._resync(sample, Verdict(RESYNC, dp, dm, gap, gap - 1, reason=(
                    f'stale reference: seq {seq} agrees with the refused seq {r[0]}')))
        if len(self._refused) >= MAX_REFUSED:
            return self._resync(sample, Verdict(RESYNC, dp, dm, gap, gap - 1, reason=(
                f'{len(self._refused) + 1} implausible samples in a row')))
        self._refused.append(sample)
        self.stats.refused += 1
        return Verdict(REFUSE, dp, dm, gap, reason=(
            f'encoder jump of {dp} pendulum / {dm} motor counts over {gap} sample(s) exceeds the '
            f'{gap * self.max_step:.0f} counts max_rate allows; sample refused'))

    def _plausible(self, dp: int, dm: int, gap: int) -> bool:
        limit = gap * self.max_step
        return -limit <= dp <= limit and -limit <= dm <= limit

    def _take(self, sample, v: Verdict) -> Verdict:
        self._ref = sample
        self._refused.clear()
        s = self.stats
        s.taken += 1
        if v.missed > 0:
            s.gaps += 1
            s.missed += v.missed
            s.longest_gap = max(s.longest_gap, v.missed)
        return v

    def _resync(self, sample, v: Verdict) -> Verdict:
        self._count_resync(sample[0], v.reason)
        return self._take(sample, v)

    def _count_resync(self, seq: int | None, reason: str) -> None:
        self.stats.resyncs += 1
        self.stats.last_resync = reason
        self.stats.last_resync_seq = seq
