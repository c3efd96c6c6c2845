"""The gate's and the loop health's fast paths equal their general paths on random sequences."""
import random

from rwpend_ros.claim import CommandClaim
from rwpend_ros.gate import CommandGate
from rwpend_ros.health import LoopHealth


class FakeHardware:
    """k, write (refuses some commands), advance, timed_out, no_command."""

    def __init__(self, seed: int) -> None:
        self.r = random.Random(seed)
        self.k = 0
        self.timed_out = False
        self.log = []

    def write(self, seq, u):
        ok = self.r.random() < 0.8
        self.log.append(('write', seq, u, ok))
        return ok, '' if ok else 'refused'

    def advance(self):
        self.k += 1
        self.timed_out = self.r.random() < 0.1
        return 0.0

    def no_command(self):
        self.log.append(('zero', self.k))


def _gate(seed):
    return CommandGate(FakeHardware(seed), CommandClaim(5), LoopHealth(0.001, dead_after_s=0.004, check_after_s=0.05))


def _state(g):
    return repr((vars(g.claim), vars(g.health), g.event, g.last_reason, g.hardware.log[-1:], len(g.hardware.log), g.hardware.k))


def test_offer_is_the_claimed_offer():
    r = random.Random(5)
    a, b = _gate(6), _gate(6)
    for _ in range(20000):
        source = r.choice([1, 1, 1, 1, 2, 0])
        release = r.random() < 0.03
        u = r.uniform(-10, 10)
        assert a.offer(source, a.hardware.k, u, release) == b._offer_claimed(source, b.hardware.k, u, release)
        assert _state(a) == _state(b)
        if r.random() < 0.9:
            late = r.random() < 0.05
            assert a.interval(late) == b.interval(late)


def test_health_sample_is_its_general_path():
    r = random.Random(7)
    a, b = LoopHealth(0.001, dead_after_s=0.004, check_after_s=0.05), LoopHealth(0.001, dead_after_s=0.004, check_after_s=0.05)
    for _ in range(20000):
        if r.random() < 0.7:
            assert a.command() == b.command()
        late, timed_out = r.random() < 0.05, r.random() < 0.2
        got = a.sample(late, timed_out)
        want = b._sample_general(late, timed_out) if b.commands else b.sample(late, timed_out)
        assert got == want and vars(a) == vars(b)
