"""The simulator alone as a process (`./rwpend sim -p ...`), driven by a test node through
`encoders`/`command` like any user's controller: the encoder stream's rate and seq continuity in
real time, and lockstep determinism (two identical runs give identical counts); and under
``./rwpend up`` without a controller, every sample in the bag, at the rate of h."""
from __future__ import annotations

import json
import time
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np

from mcap_rules import assert_log_time_order
from rwpend_bag.reader import read_bag
from test_stack_system import run, series

ROOT = Path(__file__).resolve().parents[1]
RWPEND = str(ROOT / 'rwpend')
PY = str(ROOT / '.venv' / 'bin' / 'python') if (ROOT / '.venv' / 'bin' / 'python').exists() else sys.executable

#: answers every sample k with u = 6 sin(2 pi k h) (a user's controller, in a few lines)
DRIVER = textwrap.dedent('''
    import json, math, sys, time
    import rclpy
    from rwpend_msgs.msg import EncoderCounts, MotorCommand
    from rwpend_ros.qos import QOS_CONTROL
    out, n = sys.argv[1], int(sys.argv[2])
    rclpy.init()
    node = rclpy.create_node('user_controller', namespace='/rwpend')
    pub = node.create_publisher(MotorCommand, 'command', QOS_CONTROL)
    rows, t0 = [], []
    def on_enc(m):
        stamp = m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
        t0.append(stamp) if not t0 else None
        rows.append((time.monotonic(), m.seq, m.pendulum_counts, m.motor_counts, stamp - t0[0]))
        c = MotorCommand(seq=m.seq, u=6.0 * math.sin(2 * math.pi * m.seq * 1e-3))
        c.header.stamp = m.header.stamp
        pub.publish(c)
    node.create_subscription(EncoderCounts, 'encoders', on_enc, QOS_CONTROL)
    end = time.monotonic() + 60
    while rclpy.ok() and len(rows) < n and time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.1)
    json.dump(rows, open(out, 'w'))
''')


def _run(tmp_path, env, params, n, tag):
    out = tmp_path / f'{tag}.json'
    log = open(tmp_path / f'{tag}_sim.log', 'w')
    sim = subprocess.Popen([RWPEND, 'sim', *params, '-p', 'start.encoders_subscribers:=1'],
                           env=env, stdout=log, stderr=subprocess.STDOUT)
    try:
        subprocess.run([PY, '-c', DRIVER, str(out), str(n)], env=env, timeout=90, check=True)
    finally:
        sim.terminate()
        sim.wait(timeout=15)
        log.close()
    return np.array(json.loads(out.read_text()), dtype=float)


def test_realtime_stream_rate_and_seq(tmp_path, ros_env):
    # a Python client that falls behind the 1 kHz stream on a loaded host (810 Hz in one CI run)
    # answers samples more than 3 old, which the rig's command timeout refuses (u = 0: its safety
    # rule, tested in the loop tier); here the timeout is long so that the test asks only whether
    # the stream is paced, complete and in order, and whether commands reach the wheel
    rows = _run(tmp_path, ros_env, ['-p', 'command_timeout_samples:=100000'], 3000, 'rt')
    seq = rows[:, 1].astype(np.int64)
    assert seq[0] == 0 and np.all(np.diff(seq) == 1), 'every sample, in order'
    assert np.all(np.diff(rows[:, 4]) == 1_000_000), 'stamps on the h = 1 ms grid'
    rate = (len(seq) - 1) / (rows[-1, 0] - rows[0, 0])
    print(f'real-time sample rate received: {rate:.1f} Hz')
    # paced by the wall clock: never faster than 1 kHz. How close to 1 kHz this Python client
    # keeps up is a timing figure of the host (866 Hz on a loaded run), not asserted here: the
    # loop's rate is judged per sample from the bags by the benchmark (PERFORMANCE.md)
    assert rate < 1100
    assert np.any(rows[:, 3] != 0), 'the commands moved the wheel'


def test_lockstep_runs_are_identical(tmp_path, ros_env):
    a = _run(tmp_path, ros_env, ['-p', 'lockstep:=true'], 2000, 'a')
    b = _run(tmp_path, ros_env, ['-p', 'lockstep:=true'], 2000, 'b')
    assert a.shape == b.shape == (2000, 5)
    assert np.array_equal(a[:, 1:], b[:, 1:]), 'identical seq, counts and stamps'
    assert np.abs(a[:, 2]).max() > 10 and np.abs(a[:, 3]).max() > 100


def test_lockstep_runs_on_when_its_controller_is_gone(tmp_path, ros_env):
    """A lockstep simulator whose external controller ended: after the loop is declared dead
    and no node publishes ``command`` any more, the samples no longer wait ``lockstep_timeout``
    (0.5 s of wall time each: a 5 s run would take 33 min); the run ends at u = 0, the loop
    reported dead (exit status 3)."""
    from rwpend_ros.health import EXIT_LOOP_DEAD
    log = tmp_path / 'sim.log'
    t0 = time.monotonic()
    with open(log, 'w') as f:
        sim = subprocess.Popen([RWPEND, 'sim', '-p', 'lockstep:=true', '-p', 'duration:=5.0',
                                '-p', 'start.encoders_subscribers:=1'], env=ros_env, stdout=f, stderr=subprocess.STDOUT)
        try:
            subprocess.run([PY, '-c', DRIVER, str(tmp_path / 'rows.json'), '1000'], env=ros_env,
                           timeout=90, check=True)
            code = sim.wait(timeout=120)
        finally:
            if sim.poll() is None:
                sim.kill()
    wall = time.monotonic() - t0
    text = log.read_text()
    print(f'measured: 5 s lockstep run, controller gone after 1 s: {wall:.1f} s of wall time')
    assert code == EXIT_LOOP_DEAD, text[-3000:]
    assert 'no node publishes command any more' in text and 'the loop is dead' in text, text[-3000:]


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
    # real time: logged at the recorder's receive times, in log-time order in the file
    assert assert_log_time_order(bag) == read_bag(bag).message_count
    assert np.all(enc['_log_ns'] >= enc['_stamp_ns'])
