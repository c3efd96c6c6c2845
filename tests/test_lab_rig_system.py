"""The lab's rig path through the emulator (issue "The lab"): ``./rwpend lab run N --plant
serial:LINK`` against ``./rwpend emulate --hand``, the student's hand played by this test from
the prompts the lab prints (``>>> ...``): Experiments 3 (three runs, each after the pendulum hangs
still) and 16 (the controller armed after the steps) run in real time through the driver, the
steps are detected from the encoders, the controller armed when they say, and each report is
written. The procedures of Experiments 1 and 13 (lift and let go; raise upright, arm, tap) are fed
the same hand in one process (tests/test_lab_procedures.py), their measurements judged in lockstep
(rwpend_lab/test/test_analyses.py). Real time on a shared machine: the assertions are about
the procedure (prompts, detection, arming, the cut bag), the pass/fail of each quantity is
printed, not asserted (the simulator's lockstep runs assert those)."""
from __future__ import annotations

import json

import pytest

from emulated_hand import run_with_hand

#: the student's hand: prompt text (its start) -> the emulator's hand action
HAND = {'Lift the pendulum to about 20 degrees': 'lift 20 1.5',
        'Let go of the pendulum now': '',           # the lift lets go by itself after 1.5 s
        'Let the pendulum hang still': 'steady 0.5',
        'Raise the pendulum upright by hand': 'lift 180 1.0',
        'Tap the pendulum lightly': 'tap 0.8',
        'Give the pendulum a slight push': 'tap 0.9'}


@pytest.mark.timeout(420)
@pytest.mark.parametrize('n, runs', [(3, ['pulse+5', 'pulse-5', 'pulse+10']), (16, ['swingup'])])
def test_lab_on_the_emulated_rig(tmp_path, ros_env, n, runs):
    out = tmp_path / 'lab'
    status, lines, hands, link = run_with_hand(tmp_path, ros_env, ['lab', 'run', str(n), '--plant', 'serial:{link}',
                                                                   '--out', str(out)], HAND, timeout=400)
    text = ''.join(lines)
    print(text[-6000:])
    assert status in (0, 1), text[-4000:]          # 1: a quantity failed (printed), not the procedure
    prompts = [ln for ln in lines if '>>>' in ln]
    assert prompts and len(hands) == len(prompts), (prompts, hands)
    res = json.loads((out / 'results.json').read_text())
    assert [r['name'] for r in res['runs']] == runs
    for r in res['runs']:
        assert r['plant'] == f'serial:{link}' and r['origin_seq'] > 0
        assert len(r["steps_s"]) == len(prompts) // len(runs)
    assert res['quantities']            # measured or None (a fall on a busy machine): printed below
    assert (out / 'report.html').exists()
    print('measured:', json.dumps({q['name']: [q['measured'], q['theory'], q['pass']] for q in res['quantities']}))
