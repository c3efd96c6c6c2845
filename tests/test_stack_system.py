"""System tests of the whole stack: real node processes started by ./rwpend, DDS on localhost.

* the simulator in real time publishes every sample, with continuous seq, at the rate of h;
* lockstep runs swing up, catch and balance, and two runs give the same bag (determinism);
* the estimator fed the recorded encoder + command stream reproduces its live estimates;
* the param tool, mode service, gains --apply, tap and e-stop against a running stack.
"""
from __future__ import annotations

import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

from rwpend_bag.analysis import _decode
from rwpend_bag.reader import read_bag

ROOT = Path(__file__).resolve().parents[1]
RWPEND = str(ROOT / 'rwpend')


def run(args, env, timeout=120, check=True):
    p = subprocess.run([RWPEND, *args], env=env, capture_output=True, text=True, timeout=timeout)
    if check and p.returncode != 0:
        raise AssertionError(f'./rwpend {" ".join(args)} -> {p.returncode}\n{p.stdout[-3000:]}\n{p.stderr[-3000:]}')
    return p


def series(bag_dir, topic):
    bag = read_bag(bag_dir)
    assert topic in bag.topics, sorted(bag.topics)
    return _decode(bag, topic)


def test_realtime_sim_publishes_every_sample(tmp_path, ros_env):
    bag = tmp_path / 'rt'
    run(['up', '--no-controller', '--duration', '4', '--record', str(bag)], ros_env)
    enc = series(bag, '/rwpend/encoders')
    seq = enc['seq'].astype(np.int64)
    assert seq[0] == 0, 'the simulator holds sample 0 until estimator and recorder listen'
    assert np.all(np.diff(seq) == 1), 'seq continuous, nothing lost'
    assert len(seq) > 2500
    stamps = enc['_stamp_ns']
    assert np.median(np.diff(stamps)) == 1_000_000        # h = 1 ms on the header stamps
    # without a controller the plant holds u = 0 (command timeout) and the pendulum hangs still
    truth = series(bag, '/rwpend/sim/true_state')
    assert np.all(truth['u_applied'] == 0.0)
    assert np.all(enc['pendulum_counts'] == 0)
    st = series(bag, '/rwpend/state')   # the estimator stops before the plant: a shorter stream
    assert st['seq'][0] == 0 and np.all(np.diff(st['seq'].astype(np.int64)) == 1) and len(st['seq']) > 2000


@pytest.fixture(scope='module')
def lockstep_bags(tmp_path_factory):
    """Two identical lockstep runs: auto mode from hanging, a tap at 7 s."""
    import os
    import random
    out = []
    for i in range(2):
        env = dict(os.environ, ROS_DOMAIN_ID=str(random.SystemRandom().randint(100, 230)),
                   ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
        bag = tmp_path_factory.mktemp('lockstep') / f'run{i}'
        t0 = time.monotonic()
        run(['up', '--lockstep', '--duration', '10', '--mode', 'auto', '--tap', '7:0.4',
             '--record', str(bag)], env, timeout=150)
        out.append((bag, time.monotonic() - t0))
    return out


def test_lockstep_swings_up_catches_and_balances(lockstep_bags):
    bag, wall = lockstep_bags[0]
    truth = series(bag, '/rwpend/sim/true_state')
    assert len(truth['seq']) == 10000 and np.all(np.diff(truth['seq']) == 1)
    x = np.remainder(truth['theta'] - np.pi + np.pi, 2 * np.pi) - np.pi
    t = truth['seq'] * 1e-3
    caught = np.nonzero(np.abs(x) < 0.1)[0]
    assert caught.size and t[caught[0]] < 6.0, 'swung up within 6 s'
    assert np.all(np.abs(x[(t > 5.5) & (t < 7.0)]) < 0.1), 'balanced before the tap'
    assert np.all(np.abs(x[t > 8.5]) < 0.1), 'balanced again after the tap'
    cmd = series(bag, '/rwpend/command')
    assert np.all(np.abs(cmd['u']) <= 10.0) and np.all(np.isfinite(cmd['u']))
    assert np.array_equal(cmd['seq'], np.arange(10000)), 'one command answering every sample'
    status = series(bag, '/rwpend/controller/status')
    assert status['seq'].size > 900


def test_lockstep_is_deterministic(lockstep_bags):
    (a, _), (b, _) = lockstep_bags
    for topic, fields in (('/rwpend/sim/true_state', ('theta', 'theta_dot', 'wheel_angle', 'wheel_rate', 'u_applied')),
                          ('/rwpend/state', ('theta', 'theta_dot', 'wheel_rate', 'friction')),
                          ('/rwpend/command', ('u',))):
        sa, sb = series(a, topic), series(b, topic)
        assert np.array_equal(sa['seq'], sb['seq'])
        for f in fields:
            assert np.array_equal(sa[f], sb[f]), f'{topic}.{f} differs between identical lockstep runs'


def test_offline_reestimation_matches_live(lockstep_bags, tmp_path, ros_env):
    """Replay encoders + command into a second estimator (namespace /offline), record its state."""
    bag, _ = lockstep_bags[0]
    out = tmp_path / 'offline'
    log = open(tmp_path / 'nodes.log', 'w')   # a file, not a pipe nobody reads (it would fill)
    est = subprocess.Popen([RWPEND, 'node', 'estimator', '--ros-args', '-r', '__ns:=/offline'],
                           env=ros_env, stdout=log, stderr=subprocess.STDOUT)
    rec = subprocess.Popen([RWPEND, 'record', '-o', str(out), '/offline/state'], env=ros_env,
                           stdout=log, stderr=subprocess.STDOUT)
    try:
        time.sleep(3.0)
        run(['play', str(bag), '--topics', '/rwpend/encoders', '/rwpend/command', '--start', '0',
             '--rate', '0.5', '--remap', '/rwpend/encoders:=/offline/encoders',
             '--remap', '/rwpend/command:=/offline/command', '--wait', '10'], ros_env, timeout=120)
        time.sleep(1.0)
    finally:
        rec.send_signal(2)
        rec.wait(timeout=20)
        est.send_signal(2)
        est.wait(timeout=20)
    live = series(bag, '/rwpend/state')
    off = series(out, '/offline/state')
    n = len(off['seq'])
    assert n == len(live['seq']), (n, len(live['seq']))
    assert np.array_equal(off['seq'], live['seq'])
    for f in ('theta', 'theta_dot', 'wheel_angle', 'wheel_rate', 'friction', 'energy'):
        assert np.max(np.abs(off[f] - live[f])) < 1e-9, f


def test_separate_processes_take_the_same_host_fast_path(lockstep_bags):
    """The loop's messages between the processes of a lockstep run went through the fast path
    (rwpend_ros.hostbus), each delivered once: the nodes' /diagnostics count them."""
    from test_safety_system import diagnostics
    last = {}
    for _, name, _, _, values in diagnostics(lockstep_bags[0][0]):
        for key, value in values.items():
            if key.startswith('fast_path '):
                last[(name, key)] = dict(kv.split(' ') for kv in value.split(', '))
    seen = {key for _, key in last}
    assert {'fast_path /rwpend/encoders', 'fast_path /rwpend/command', 'fast_path /rwpend/state'} <= seen, seen
    for (name, key), c in last.items():
        fast, dds, dup = int(c['fast']), int(c['dds']), int(c['duplicates'])
        assert fast > 0.5 * (fast + dds), (name, key, c)     # most of them fast
        assert dup <= fast, (name, key, c)                   # only copies of fast ones dropped


def test_live_tools_against_a_running_stack(ros_env):
    log_path = Path(ros_env.get('TMPDIR', '/tmp')) / f'rwpend_stack_{ros_env["ROS_DOMAIN_ID"]}.log'
    log = open(log_path, 'w')
    stack = subprocess.Popen([RWPEND, 'up', '--duration', '60'], env=ros_env, stdout=log,
                             stderr=subprocess.STDOUT, text=True)
    try:
        time.sleep(3.0)
        p = run(['param', 'get', 'controller', 'mode', 'balance.kpp'], ros_env)
        assert 'mode: off' in p.stdout
        kpp = float(p.stdout.split('balance.kpp:')[1].split()[0])
        # invalid values are refused with the reason, and change nothing
        p = run(['param', 'set', 'controller', 'balance.kpp', '.nan'], ros_env, check=False)
        assert p.returncode == 1 and 'finite' in p.stderr
        p = run(['param', 'set', 'controller', 'balance.kpp', '50.0'], ros_env, check=False)
        assert p.returncode == 1 and 'unstable' in p.stderr
        p = run(['param', 'set', 'controller', 'mode', 'bogus'], ros_env, check=False)
        assert p.returncode == 1 and 'mode' in p.stderr
        assert f'balance.kpp: {kpp!r}' in run(['param', 'get', 'controller', 'balance.kpp'], ros_env).stdout
        # a designed gain set applied as a whole
        run(['gains', 'pdd', '--w0', '2wp', '--apply'], ros_env)
        p = run(['param', 'get', 'controller', 'balance.kpp'], ros_env)
        assert float(p.stdout.split(':')[1]) == pytest.approx(-440.49, abs=0.1)
        # balance refused while hanging; tap limits; e-stop raise / clear
        p = run(['mode', 'balance'], ros_env, check=False)
        assert p.returncode == 1 and 'theta_0' in p.stderr
        assert run(['mode', 'swingup'], ros_env).returncode == 0
        assert run(['tap', '500'], ros_env, check=False).returncode == 1
        assert 'raised' in run(['estop'], ros_env).stdout
        assert 'cleared' in run(['estop', '--clear'], ros_env).stdout
        dump = run(['param', 'dump', 'controller'], ros_env).stdout
        assert dump.startswith('/rwpend/controller:') and 'ros__parameters' in dump
    finally:
        stack.send_signal(2)
        stack.wait(timeout=30)
        log.close()
    out = log_path.read_text()
    assert stack.returncode == 0, out[-3000:]
    assert 'Traceback' not in out, out[-3000:]


def test_bad_cli_input_is_refused(tmp_path, ros_env):
    for args, text in ((['up', '--plant', 'usb'], "--plant must be 'sim' or 'serial:PORT'"),
                       (['up', '--set', 'rig.g=-1'], 'rig.g must be > 0'),
                       (['up', '--set', 'nonsense'], 'NODE.PARAM=VALUE'),
                       (['up', '--set', 'sim.lockstep_timeout=soon'], 'lockstep_timeout must be a number'),
                       (['up', '--set', 'sim.command_timeout_samples=2.5'], 'must be an integer'),
                       (['up', '--tap', 'x'], 'T:DV'),
                       (['up', '--duration', '-1'], '--duration'),
                       (['up', '--params', str(tmp_path / 'missing.yaml')], 'does not exist'),
                       (['up', '--ns', 'bad ns'], 'invalid namespace'),
                       (['nosuchcommand'], 'unknown command')):
        p = run(args, ros_env, check=False, timeout=30)
        assert p.returncode == 2, (args, p.stdout, p.stderr)
        assert text in p.stderr, (args, p.stderr)


def test_set_takes_an_integer_for_a_float_and_refuses_a_wrong_type(ros_env):
    """``--set sim.lockstep_timeout=2`` (YAML reads an integer where stack.yaml has 0.5) runs; a
    string for a number the node alone declares stops the stack with the parameter named, not
    a traceback from rclpy's type check (one stack.yaml sets is refused by ``up`` itself:
    test_bad_cli_input_is_refused)."""
    p = run(['up', '--lockstep', '--duration', '0.2', '--set', 'sim.lockstep_timeout=2',
             '--set', 'sim.start.delay=0', '--set', 'sim.taps.times=[0]', '--set', 'sim.taps.sizes=[1]'],
            ros_env, timeout=90)
    assert 'duration reached' in p.stdout + p.stderr
    p = run(['up', '--lockstep', '--duration', '0.2', '--set', 'sim.start.delay=soon'], ros_env,
            check=False, timeout=90)
    out = p.stdout + p.stderr
    assert p.returncode != 0 and 'start.delay must be a number' in out, out[-2000:]
    assert 'Traceback' not in out, out[-3000:]


@pytest.mark.parametrize('fast', ['1', '0'], ids=['recorder_fast_path', 'recorder_on_dds'])
def test_lockstep_recorder_records_everything_either_way(tmp_path, ros_env, fast):
    """The recorder takes the loop's topics through the fast path (the default) or through DDS
    (RWPEND_RECORDER_FAST_PATH=0): every message recorded once, in order. On the fast path the
    loop's publishers leave DDS out (a DDS write or two each, at the start; a subscriber a
    reading of the graph at start-up missed gets DDS until the next reading, 0.25 s later: seen
    once, 186 writes of 4000) and few DDS copies reach the nodes."""
    from test_safety_system import diagnostics
    bag = tmp_path / 'rec'
    env = dict(ros_env, RWPEND_RECORDER_FAST_PATH=fast)
    run(['up', '--lockstep', '--duration', '4', '--mode', 'auto', '--record', str(bag)], env, timeout=150)
    for topic in ('/rwpend/encoders', '/rwpend/state', '/rwpend/command', '/rwpend/sim/true_state'):
        seq = series(bag, topic)['seq'].astype(np.int64)
        assert np.array_equal(seq, np.arange(4000)), topic
    last, out = {}, {}
    for _, name, _, _, values in diagnostics(bag):
        for key, value in values.items():
            if key.startswith('fast_path '):
                last[(name, key)] = dict(kv.split(' ') for kv in value.split(', '))
            elif key.startswith('fast_path_out '):
                out[(name, key)] = dict(kv.rsplit(' ', 1) for kv in value.split(', '))
    assert len(last) >= 4 and len(out) >= 5, (last, out)
    if fast == '1':
        for (name, key), c in last.items():
            assert int(c['duplicates']) <= 0.5 * int(c['fast']), (name, key, c)
        for (name, key), c in out.items():
            assert int(c['dds writes']) <= 400 and int(c['failed']) == 0, (name, key, c)
    else:
        for (name, key), c in out.items():     # the recorder reads DDS: every message goes there
            assert int(c['dds writes']) >= 0.9 * int(c['sent']) / 2, (name, key, c)
