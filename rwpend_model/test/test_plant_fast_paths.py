"""The plant's fast paths equal the general ones: Plant.step's written-out quantization
(quantize_command) and Plant.readout (counts and state_values)."""
import math
import random

from rwpend_model.plant import Plant
from rwpend_model.rig import load_rig

rig = load_rig()


class F(float):
    """A float that is not exactly a float: Plant.step takes it through quantize_command."""


def test_step_quantizes_as_quantize_command_and_readout_is_counts_and_state():
    r = random.Random(8)
    a, b = Plant(rig, theta=0.1), Plant(rig, theta=0.1)
    for _ in range(3000):
        x = r.random()
        u = (r.uniform(-rig.u_max, rig.u_max) if x < 0.8 else
             r.choice([rig.u_max, -rig.u_max, 12.0, -50.0, math.nan, math.inf, 0.0, -0.0]))
        a.step(u)
        b.step(F(u))
        assert repr((a._x, a._tau, a._friction, a._stuck, a.u_held)) == repr((b._x, b._tau, b._friction, b._stuck, b.u_held))
        assert a.readout() == (*b.counts(), *b.state_values())
