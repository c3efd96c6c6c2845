"""System tests of the composed mode (``./rwpend up --composed``): plant, estimator and controller
as nodes of one process on one executor, the recorder in its own process.

* a lockstep run swings up (theta reaches pi) and every node got its own overrides from the one
  params file of the process (``/**/<node>`` sections);
* the composed process gives the same bag as separate processes (lockstep is deterministic
  whatever the layout: rwpend_bag.sameness).
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
def test_composed_lockstep_swings_up(tmp_path, ros_env):
    bag = tmp_path / 'composed'
    p, _ = up(['--composed', '--lockstep', '--mode', 'auto', '--duration', '6', '--record', str(bag),
               '--set', 'estimator.publish_joint_states=false', '--set', 'controller.status_every=20'],
              ros_env)
    # one process holds the three nodes: their log lines carry its prefix, not theirs
    prefixes = {line.split(']', 1)[0].strip('[ ') for line in p.stdout.splitlines() if line.startswith('[')}
    assert prefixes == {'stack', 'recorder'}, prefixes
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
    # state reached the controller through the process's in-process bus
    from test_safety_system import diagnostics
    last = [values['state_order'] for _, name, _, _, values in diagnostics(bag)
            if 'state_order' in values][-1]
    assert 'in-process' in last and 'duplicates 0, stale 0' in last, last
    delivered = int(last.split('in-process ')[1].split()[0])
    assert delivered > 5000, last


@pytest.mark.timeout(90)
def test_composed_equals_separate_in_lockstep(tmp_path, ros_env):
    """Bit for bit, with the in-process bus (rwpend_ros.intra) carrying state and command
    between the composed nodes, and with estimator + controller composed, plant separate."""
    bags = {}
    layouts = {'composed': ['--composed'], 'control': ['--composed', 'control'], 'separate': ['--composed', 'none']}
    for layout, extra in layouts.items():
        bags[layout] = tmp_path / layout
        args = ['--lockstep', '--mode', 'auto', '--duration', '2', '--record', str(bags[layout])]
        up(args + extra, ros_env, timeout=28)
    for other in ('composed', 'control'):
        _same_run(read_bag(bags[other]), read_bag(bags['separate']))
        assert sameness.compare(bags[other], bags['separate']) == [], other


def _same_run(a, b):
    for topic, fields in (('/rwpend/sim/true_state', ('theta', 'theta_dot', 'wheel_angle', 'wheel_rate')),
                          ('/rwpend/state', ('theta', 'theta_dot', 'wheel_rate', 'friction')),
                          ('/rwpend/command', ('u',))):
        ca, cb = answers(_decode(a, topic)), answers(_decode(b, topic))
        assert np.array_equal(ca['seq'], cb['seq']) and len(ca['seq']) == 2000
        for f in fields:
            assert np.array_equal(ca[f], cb[f]), f'{topic}.{f}: composed and separate differ'
