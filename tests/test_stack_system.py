"""System tests of the whole stack: real node processes started by ./rwpend, DDS on localhost.

* lockstep runs swing up, catch and balance, and two runs give the same bag (determinism,
  rwpend_bag.sameness), every bag in log-time order (the MCAP rule, tests/mcap_rules.py);
* the estimator fed the recorded encoder + command stream reproduces its live estimates;
* wrong command-line input refused with the reason (the param tool, mode service, gains --apply,
  tap and e-stop against a running stack: test_param_services_system, on its stack).

The simulator's real-time stream under ``up`` is in test_sim_system (it keeps a sample rate; this
module's tests do not, and run beside another one: the marker ``parallel``).
"""
from __future__ import annotations

import json
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

from mcap_rules import assert_log_time_order
from rwpend_ros.testenv import test_domain_id
from rwpend_bag import sameness
from rwpend_bag.logtime import leading_time_ns
from rwpend_bag.analysis import _decode
from rwpend_bag.reader import read_bag

#: its outcome does not depend on the host keeping a sample rate: make test runs it beside another
pytestmark = pytest.mark.parallel

ROOT = Path(__file__).resolve().parents[1]
RWPEND = str(ROOT / 'rwpend')


def run(args, env, timeout=120, check=True):
    p = subprocess.run([RWPEND, *args], env=env, capture_output=True, text=True, timeout=timeout)
    if check and p.returncode != 0:
        raise AssertionError(f'./rwpend {" ".join(args)} -> {p.returncode}\n{p.stdout[-3000:]}\n{p.stderr[-3000:]}')
    return p


def series(bag_dir, topic, releases=False):
    """The columns of ``topic`` in the bag; of a MotorCommand topic without the controller's
    release (its last message when it stops: u = 0, flagged ``release``, answering the sample
    after its newest state -- no sample's answer) unless ``releases``."""
    bag = read_bag(bag_dir)
    assert topic in bag.topics, sorted(bag.topics)
    d = _decode(bag, topic)
    return d if releases else answers(d)


def answers(d: dict) -> dict:
    """Decoded MotorCommand columns without the release messages (other topics unchanged)."""
    if 'release' not in d or not np.any(d['release']):
        return d
    keep = ~np.asarray(d['release'], dtype=bool)
    return {k: (v[keep] if hasattr(v, '__len__') and len(v) == len(keep) else v) for k, v in d.items()}


@pytest.fixture(scope='module')
def lockstep_bags(tmp_path_factory):
    """Two identical lockstep runs: auto mode from hanging, a tap at 7 s."""
    import os
    out = []
    for i in range(2):
        env = dict(os.environ, ROS_DOMAIN_ID=str(test_domain_id()),
                   ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
        bag = tmp_path_factory.mktemp('lockstep') / f'run{i}'
        t0 = time.monotonic()
        # lockstep_timeout 5 s (default 0.5): a host stall longer than that makes the simulator
        # run on without the command (counted late_commands), and the run is then not the same
        # run -- on a shared 2-core VM under load, stalls of more than 0.5 s were seen
        run(['up', '--lockstep', '--duration', '10', '--mode', 'auto', '--tap', '7:0.4',
             '--set', 'sim.lockstep_timeout=5', '--record', str(bag)], env, timeout=150)
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


def test_two_lockstep_runs_give_the_same_bag(lockstep_bags):
    """The loop topics of two runs: byte-identical messages with identical log times, in the
    same order (rwpend_bag.sameness says what is and is not compared)."""
    (a, _), (b, _) = lockstep_bags
    from test_safety_system import diagnostics
    late = [[v.get('late_commands') for _, name, _, _, v in diagnostics(bag) if name.endswith('sim: plant')][-1]
            for bag in (a, b)]
    # (a sample whose command did not come within lockstep_timeout makes a run of its own)
    assert sameness.compare(a, b) == [], f'late commands at the simulator: {late}'
    for bag in (a, b):
        report = json.loads((bag / 'recording_report.json').read_text())
        lt = report['log_times']
        assert sameness.order_faults(lt) == {} and lt['written']['raised'] == 0, lt
        assert read_bag(bag).metadata['custom_data']['rwpend.log_time'] == 'sim'


def test_lockstep_bags_follow_the_mcap_ordering_rule_on_the_sim_clock(lockstep_bags):
    for bag, _ in lockstep_bags:
        assert assert_log_time_order(bag) == read_bag(bag).message_count
        # log time = sim time: the header stamp (t_k = k h), /clock's value
        enc = series(bag, '/rwpend/encoders')
        assert np.array_equal(enc['_log_ns'], enc['seq'].astype(np.int64) * 1_000_000)
        assert np.array_equal(enc['_log_ns'], enc['_stamp_ns'])
        clock = read_bag(bag).topics['/clock']
        assert np.array_equal(clock.log_ns(), np.arange(10000) * 1_000_000)
        # /diagnostics of every node on the one simulated clock (header stamp = log time)
        from test_safety_system import diagnostics
        names = {d[1].split(':')[0] for d in diagnostics(bag)}
        assert {'/rwpend/sim', '/rwpend/estimator', '/rwpend/controller'} <= names, names
        diag = read_bag(bag).topics['/diagnostics']
        stamps = [leading_time_ns(d) for d in diag.datas]
        assert stamps == list(diag.log_ns()) and max(stamps) <= 10_000_000_000


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
        # the player waits for the estimator (--wait), not for the recorder behind it: start once
        # the recorder has subscribed to the estimator's state (a lockstep bag plays at its sim
        # time, 1 ms per sample: 10 s for this bag, the estimator's own rate live)
        end = time.monotonic() + 60
        while 'recording /offline/state' not in (tmp_path / 'nodes.log').read_text():
            assert time.monotonic() < end and rec.poll() is None and est.poll() is None, \
                (tmp_path / 'nodes.log').read_text()[-3000:]
            time.sleep(0.1)
        run(['play', str(bag), '--topics', '/rwpend/encoders', '/rwpend/command', '--start', '0',
             '--rate', '1.0', '--remap', '/rwpend/encoders:=/offline/encoders',
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


def test_lockstep_recorder_records_everything(tmp_path, ros_env):
    """Every message of the loop recorded once, in order; the order gates of the nodes stopped
    nothing (DDS delivers each writer's messages once and in order)."""
    from test_safety_system import diagnostics
    bag = tmp_path / 'rec'
    run(['up', '--lockstep', '--duration', '4', '--mode', 'auto', '--record', str(bag)], ros_env, timeout=150)
    for topic in ('/rwpend/encoders', '/rwpend/state', '/rwpend/command', '/rwpend/sim/true_state'):
        seq = series(bag, topic)['seq'].astype(np.int64)
        assert np.array_equal(seq, np.arange(4000)), topic
    orders = {}
    for _, name, _, _, values in diagnostics(bag):
        for key, value in values.items():
            if key.endswith('_order'):
                orders[(name, key)] = value
    assert len(orders) >= 4, orders
    for key, value in orders.items():   # the loop's own stages take no topic: nothing to gate
        assert value == 'in the loop' or 'duplicates 0, stale 0' in value, (key, value)
