"""System tests of the layouts of ``./rwpend up --composed``: the control process (estimator and
controller as the nodes of one loop process fed by the ``encoders`` topic, rwpend_loop.control),
the plant and the recorder in processes of their own; and the loop layout, the default.

* a lockstep run of the control layout swings up (theta reaches pi) and every node got its own
  overrides from the one params file of the process (``/**/<node>`` sections);
* every layout gives the same bag (lockstep is deterministic whatever the layout:
  rwpend_bag.sameness).
"""
from __future__ import annotations

import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

from rwpend_bag import sameness
from rwpend_bag.analysis import _decode
from rwpend_bag.reader import read_bag
from test_stack_system import answers

#: its outcome does not depend on the host keeping a sample rate: make test runs it beside another
pytestmark = pytest.mark.parallel

ROOT = Path(__file__).resolve().parents[1]
RWPEND = str(ROOT / 'rwpend')


def up(args, env, timeout=55):
    t0 = time.monotonic()
    p = subprocess.run([RWPEND, 'up', *args], env=env, capture_output=True, text=True, timeout=timeout)
    assert p.returncode == 0, f'./rwpend up {" ".join(args)} -> {p.returncode}\n{p.stdout[-3000:]}\n{p.stderr[-3000:]}'
    return p, time.monotonic() - t0


def wrapped(theta):
    """theta - pi wrapped into [-pi, pi): 0 = upright."""
    return np.remainder(theta, 2 * np.pi) - np.pi


@pytest.mark.timeout(60)
def test_control_layout_lockstep_swings_up(tmp_path, ros_env):
    bag = tmp_path / 'control'
    p, _ = up(['--composed', 'control', '--lockstep', '--mode', 'auto', '--duration', '6', '--record', str(bag),
               '--set', 'estimator.publish_joint_states=false', '--set', 'controller.status_every=20'],
              ros_env)
    # one process holds the estimator and the controller: their log lines carry its prefix
    prefixes = {line.split(']', 1)[0].strip('[ ') for line in p.stdout.splitlines() if line.startswith('[')}
    assert prefixes == {'sim', 'control', 'recorder'}, prefixes
    for name in ('rwpend.sim', 'rwpend.estimator', 'rwpend.controller'):
        assert f'[{name}]' in p.stdout, f'node {name} not running under its own name'
    b = read_bag(bag)
    truth = _decode(b, '/rwpend/sim/true_state')
    # sim's overrides (lockstep, duration from sample 0): exactly 6 s of samples, none lost
    assert np.array_equal(truth['seq'], np.arange(6000))
    # estimator's override: no joint_states published (the topic exists, with no message)
    assert '/rwpend/joint_states' not in b.topics or b.topics['/rwpend/joint_states'].count == 0
    state = _decode(b, '/rwpend/state')
    assert np.array_equal(state['seq'], np.arange(6000))
    # controller's overrides: mode auto (it swings up), status every 20 samples (+ switch events)
    cmd = answers(_decode(b, '/rwpend/command'))
    assert np.array_equal(cmd['seq'], np.arange(6000)), 'one command answering every sample'
    status = _decode(b, '/rwpend/controller/status')
    assert 250 <= len(status["seq"]) <= 400, len(status["seq"])
    x = wrapped(truth['theta'])
    assert np.abs(x).min() < 0.05, f'never near upright: min |theta - pi| = {np.abs(x).min():.3f}'
    assert np.all(np.abs(cmd['u']) <= 10.0) and np.all(np.isfinite(cmd['u']))
    # the samples came through the control process's order gate, the state stayed inside it
    from test_safety_system import diagnostics
    values = [v for _, name, _, _, v in diagnostics(bag) if 'encoders_order' in v][-1]
    assert 'duplicates 0, stale 0' in values['encoders_order'], values
    last = [v['state_order'] for _, name, _, _, v in diagnostics(bag) if 'state_order' in v][-1]
    assert last == 'in the loop', last


@pytest.mark.timeout(90)
def test_every_layout_gives_the_same_bag_in_lockstep(tmp_path, ros_env):
    """Bit for bit, a tap included: the loop in one process (the default), estimator +
    controller in one loop process with the plant separate, and every node a process of its
    own."""
    bags = {}
    layouts = {'loop': [], 'control': ['--composed', 'control'], 'separate': ['--composed', 'none']}
    for layout, extra in layouts.items():
        bags[layout] = tmp_path / layout
        args = ['--lockstep', '--mode', 'auto', '--duration', '2', '--tap', '1.5:0.5', '--record', str(bags[layout])]
        up(args + extra, ros_env, timeout=28)
    for other in ('loop', 'control'):
        _same_run(read_bag(bags[other]), read_bag(bags['separate']))
        assert sameness.compare(bags[other], bags['separate']) == [], other


def _same_run(a, b):
    for topic, fields in (('/rwpend/sim/true_state', ('theta', 'theta_dot', 'wheel_angle', 'wheel_rate')),
                          ('/rwpend/state', ('theta', 'theta_dot', 'wheel_rate', 'friction')),
                          ('/rwpend/command', ('u',))):
        ca, cb = answers(_decode(a, topic)), answers(_decode(b, topic))
        assert np.array_equal(ca['seq'], cb['seq']) and len(ca['seq']) == 2000
        for f in fields:
            assert np.array_equal(ca[f], cb[f]), f'{topic}.{f}: the layouts differ'
