"""SimCore.command's fast path equals its general path (_command_checked) on random commands."""
import math
import random

from rwpend_model.rig import load_rig
from rwpend_sim.sim_core import SimCore

rig = load_rig()


def test_command_is_the_checked_command():
    r = random.Random(4)
    a, b = SimCore(rig), SimCore(rig)
    for _ in range(20000):
        k = a.k
        seq = k if r.random() < 0.7 else max(0, k + r.choice([-1, -3, 1, -10]))
        x = r.random()
        u = (r.uniform(-rig.u_max, rig.u_max) if x < 0.6 else
             r.choice([rig.u_max, -rig.u_max, 10.5, -30.0, math.nan, math.inf, 3, True, 0]))
        assert a.command(seq, u) == b._command_checked(seq, u)
        assert (a.u, type(a.u), a.u_seq, a.last_command_k, vars(a.counters)) == \
            (b.u, type(b.u), b.u_seq, b.last_command_k, vars(b.counters))
        if r.random() < 0.8:
            assert a.advance() == b.advance()
