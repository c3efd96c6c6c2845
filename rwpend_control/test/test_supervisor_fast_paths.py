"""The controller's fast paths equal the general ones they stand for, on random inputs."""
import math
import random

from rwpend_control.safety import StateWatchdog
from rwpend_control.supervisor import Controller, plausible_state
from rwpend_model.rig import load_rig

rig = load_rig()

SPECIAL = [math.nan, math.inf, -math.inf, 0, 3, True, None, 1e7, -1e7, 1.0000001e7, 200.0, -200.0,
           200.00001, 100.0, -100.0000001, 2 * rig.omega_max, -2 * rig.omega_max * 1.0000001]


def _value(r: random.Random):
    if r.random() < 0.3:
        return r.choice(SPECIAL)
    return r.uniform(-1.0, 1.0) * 10 ** r.uniform(-3, 8)


def test_plausible_state_is_bad_state_empty():
    """plausible_state True -> _bad_state says ''; for floats also the converse."""
    c = Controller(rig)
    r = random.Random(1)
    seen = {True: 0, False: 0}
    for _ in range(20000):
        v = [_value(r) for _ in range(5)]
        fast = plausible_state(*v, c.max_wheel_rate)
        general = c._bad_state(*v) == ''
        seen[fast] += 1
        if fast:
            assert general, v
        if all(type(x) is float for x in v):
            assert fast == general, v
    assert min(seen.values()) > 1000


def _watch_state(w: StateWatchdog):
    return vars(w).copy()


def test_watchdog_admit_is_its_general_path():
    r = random.Random(2)
    for trial in range(200):
        a, b = StateWatchdog(0.0105), StateWatchdog(0.0105)
        seq, now = 0, r.uniform(-1, 1)
        for _ in range(60):
            x = r.random()
            seq += 1 if x < 0.7 else r.choice([0, -1, -5, 2, 10])
            now += 0.001 if x < 0.6 else r.choice([0.0, 0.02, -0.05, 0.0104, 0.0106, 2.0, math.nan])
            stamp = r.choice([None, now, now + 0.002, now - 0.003, now + 2.0])
            if r.random() < 0.05:
                assert a.check(now) == b.check(now)
            assert a.admit(seq, now, stamp) == b._admit_general(seq, now, stamp)
            assert repr(_watch_state(a)) == repr(_watch_state(b))
