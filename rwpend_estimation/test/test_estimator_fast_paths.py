"""The estimator's fast path (the next sample, gaps.GapTracker.take_next) equals the general one
(judge's verdict), bit for bit, on random sample streams with gaps, jumps and repeats."""
import random

import pytest

from rwpend_estimation.estimators import ESTIMATORS, EstimatorConfig, make_estimator
from rwpend_estimation.gaps import TAKE, GapTracker
from rwpend_model.rig import load_rig

rig = load_rig()


def _stream(r: random.Random, n: int):
    seq, pc, mc = r.randrange(0, 5), r.randrange(-3000, 3000), r.randrange(-10**6, 10**6)
    for _ in range(n):
        x = r.random()
        if x < 0.8:
            seq += 1
        elif x < 0.9:
            seq += r.choice([0, 2, 5, 30, -3])
        pc += r.choice([0, 1, -1, 2, 30]) if r.random() < 0.97 else r.choice([400, -5000, 2**32 - 1])
        mc += r.randrange(-20, 21) if r.random() < 0.97 else r.choice([3000, -2**31])
        pc = ((pc + 2**31) % 2**32) - 2**31
        mc = ((mc + 2**31) % 2**32) - 2**31
        yield seq, pc, mc, r.uniform(-10.0, 10.0)


def test_take_next_is_judges_take():
    r = random.Random(3)
    a, b = GapTracker(40.0, 20), GapTracker(40.0, 20)
    hits = 0
    for seq, pc, mc, _ in _stream(r, 20000):
        nxt = a.take_next(seq, pc, mc)
        if nxt is None:
            a.judge(seq, pc, mc)
            b.judge(seq, pc, mc)
        else:
            hits += 1
            v = b.judge(seq, pc, mc)
            assert v.kind == TAKE and (v.dp, v.dm, v.gap, v.missed) == (nxt[0], nxt[1], 1, 0)
        assert (a._ref, a._newest, a._refused, vars(a.stats)) == (b._ref, b._newest, b._refused, vars(b.stats))
    assert hits > 10000


@pytest.mark.parametrize('name', ESTIMATORS)
@pytest.mark.parametrize('source', ['observer', 'model', 'none'])
def test_step_is_the_judged_step_bit_for_bit(name, source):
    cfg = EstimatorConfig(estimator=name, friction_source=source)
    fast, general = make_estimator(None, rig, cfg), make_estimator(None, rig, cfg)
    r = random.Random(f'{name} {source}')
    for seq, pc, mc, u in _stream(r, 1500):
        try:
            e1 = fast.step(pc, mc, u, seq)
        except ValueError as exc:
            e1 = type(exc)
        try:
            e2 = general._step_judged(*general._checked(pc, mc, u, seq))
        except ValueError as exc:
            e2 = type(exc)
        assert repr(e1) == repr(e2)
        assert _state(fast) == _state(general)


def _state(est) -> str:
    """The estimator's numbers (its recursion's states, the last estimate) and its tracker's."""
    t = est._track
    plain = {k: v for k, v in vars(est).items() if isinstance(v, (int, float, list, tuple, type(None)))}
    return repr((plain, est.last, t._ref, t._newest, t._refused, vars(t.stats)))
