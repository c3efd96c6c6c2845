"""System tests of issue 7 (safety and fault tolerance): real node processes, DDS on localhost.

Each test starts the nodes it needs as separate processes (``./rwpend node ...``, the recorder,
helper nodes written below), injects one fault, and checks the record (bag) or the helpers'
counts.  Every test prints a ``measured:`` line with its figures (fault -> zero torque in
samples and ms, fuzz counts, loss/delay survived).

* dead controller (SIGKILL mid-balance) -> the plant applies u = 0 at once, /diagnostics of the
  simulator says "command timeout"; a restarted controller (auto) swings up and catches again;
* dead estimator -> the controller reports "stale state" and commands 0; a restarted estimator
  recovers the loop;
* a relay dropping 10 % of ``state`` (lockstep: balance must hold), and one delaying it by 5 ms
  and dropping 10 % in real time (balance holds or fails safe): never |u| > 10 or NaN;
* fuzz: >= 10 000 random messages into every subscriber and random requests to every service
  of controller, estimator and simulator: nodes alive, refusals counted, commands bounded;
* e-stop raised / cleared with ``./rwpend estop``: u = 0 on the plant whatever the controller
  sends, on the simulator and through the serial driver (emulator).

Lockstep runs use ``lockstep_timeout`` = 5 ms, so a dead loop costs 5 ms of wall time per
simulated sample (the pendulum can fall in a few seconds) instead of 0.5 s; the relay's, whose
loop stays alive, 30 ms (RELAY_LOCKSTEP_TIMEOUT).
"""
from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from rwpend_bag.analysis import _decode
from test_stack_system import answers
from rwpend_bag.reader import read_bag
from rwpend_bringup.launch import NodeSpec, overrides_yaml
from rwpend_ros.health import EXIT_LOOP_DEAD
from rwpend_ros.testenv import test_domain_id

ROOT = Path(__file__).resolve().parents[1]
RWPEND = str(ROOT / 'rwpend')
PY = str(ROOT / '.venv' / 'bin' / 'python') if (ROOT / '.venv' / 'bin' / 'python').exists() else sys.executable
H = 0.001
NS = '/rwpend'
LOCKSTEP_TIMEOUT = 0.005
#: the relay's lockstep runs wait longer: the loop is alive, a dropped state costs one timeout, and
#: a command that comes back across four processes after the timeout is answered too late -- with
#: 5 ms, a slow 2-core host timed out most samples (6 s took 27 s, 27 % at zero, the pendulum
#: fell): the outcome was the host's, not the loop's
RELAY_LOCKSTEP_TIMEOUT = 0.03


# ---------------------------------------------------------------------------------- helpers
class Procs:
    """Processes of one test: started with logs in files, stopped by pid in a given order."""

    def __init__(self, tmp: Path, env: dict) -> None:
        self.tmp, self.env = tmp, env
        self.procs: dict[str, subprocess.Popen] = {}
        self.logs: dict[str, Path] = {}
        self.n = 0

    def start(self, tag: str, argv: list[str]) -> subprocess.Popen:
        log = self.tmp / f'{tag}.log'
        self.logs[tag] = log
        p = subprocess.Popen(argv, env=self.env, stdout=open(log, 'w'), stderr=subprocess.STDOUT,
                             stdin=subprocess.DEVNULL, start_new_session=True)
        self.procs[tag] = p
        return p

    def node(self, tag: str, name: str, params: dict, ros: tuple = ()) -> subprocess.Popen:
        """``./rwpend node NAME`` with ``params`` in a last params file (wins over stack.yaml)."""
        self.n += 1
        pf = self.tmp / f'{tag}_{self.n}.yaml'
        pf.write_text(overrides_yaml(NodeSpec(name, '', params)))
        return self.start(tag, [RWPEND, 'node', name, '--ros-args', '--params-file', str(pf), *ros])

    def log(self, tag: str) -> str:
        return self.logs[tag].read_text(errors='replace')

    def wait_log(self, tag: str, text: str, timeout: float) -> None:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if text in self.log(tag):
                return
            p = self.procs[tag]
            assert p.poll() is None, f'{tag} exited ({p.returncode}):\n{self.log(tag)[-3000:]}'
            time.sleep(0.05)
        raise AssertionError(f'{text!r} not in the log of {tag} within {timeout} s:\n{self.log(tag)[-3000:]}')

    def wait_recording(self, topics, timeout: float = 60.0) -> None:
        """Until the recorder (``record --all``, started as 'recorder') records every one of
        ``topics`` (names under NS): it finds a topic by polling the graph, which a loaded host
        makes slow (a fresh-clone run found the controller's topics 3.4 s after the controller
        caught the pendulum, after the kill whose status the test looks for)."""
        for topic in topics:
            self.wait_log('recorder', f'recording {NS}/{topic} [', timeout)

    def kill(self, tag: str) -> int:
        """SIGKILL (a crash); returns the wall time of the kill (ns)."""
        p = self.procs[tag]
        t = time.time_ns()
        p.send_signal(signal.SIGKILL)
        p.wait(timeout=10)
        return t

    def stop(self, tag: str, timeout: float = 15.0) -> int | None:
        p = self.procs.get(tag)
        if p is None or p.poll() is not None:
            return None if p is None else p.returncode
        p.send_signal(signal.SIGINT)
        try:
            return p.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            p.send_signal(signal.SIGKILL)
            return p.wait(timeout=5)

    def stop_all(self, order: list[str]) -> None:
        for tag in order + [t for t in self.procs if t not in order]:
            self.stop(tag)


class DiagWatch:
    """The simulator's /diagnostics as they come, received in a thread of the test's process (own
    context, the test's domain): the waits for simulated time in lockstep, where a wall-clock
    pause is far too long on an idle machine and may be too short on a loaded one."""

    def __init__(self, env: dict, name: str = NS + '/sim: plant') -> None:
        import threading
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.executors import SingleThreadedExecutor
        from rwpend_ros.qos import QOS_STATUS
        self.name, self.seen, self.cv = name, [], threading.Condition()
        self._range = os.environ.get('ROS_AUTOMATIC_DISCOVERY_RANGE')
        os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = env.get('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
        self.ctx = rclpy.Context()
        rclpy.init(context=self.ctx, domain_id=int(env['ROS_DOMAIN_ID']))
        self.node = rclpy.create_node('diag_watch', context=self.ctx, start_parameter_services=False)
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on, QOS_STATUS)
        self.ex = SingleThreadedExecutor(context=self.ctx)
        self.ex.add_node(self.node)
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self) -> None:
        while self.ctx.ok():
            try:
                self.ex.spin_once(timeout_sec=0.05)
            except Exception:  # noqa: BLE001 - the context shut down under it
                return

    def _on(self, a) -> None:
        for st in a.status:
            if st.name == self.name:
                with self.cv:
                    self.seen.append({kv.key: kv.value for kv in st.values})
                    self.cv.notify_all()

    def wait(self, cond, timeout: float, what: str) -> dict:
        """The first diagnostics values received after this call (in order) for which
        ``cond(values)`` holds: a report that came before it (e.g. ``estop`` False before the
        e-stop was raised) never answers a later wait."""
        end = time.monotonic() + timeout
        with self.cv:
            i = len(self.seen)
            while True:
                for v in self.seen[i:]:
                    if cond(v):
                        return v
                i = len(self.seen)
                left = end - time.monotonic()
                assert left > 0, f'{what}: not within {timeout} s; last: {self.seen[-1:]}'
                self.cv.wait(min(left, 0.2))

    def latest(self) -> dict:
        with self.cv:
            return self.seen[-1] if self.seen else {}

    def close(self) -> None:
        import rclpy
        rclpy.shutdown(context=self.ctx)
        self.thread.join(timeout=5)
        self.node.destroy_node()
        if self._range is None:
            os.environ.pop('ROS_AUTOMATIC_DISCOVERY_RANGE', None)
        else:
            os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = self._range


def rwpend(args, env, timeout=60, check=True):
    p = subprocess.run([RWPEND, *args], env=env, capture_output=True, text=True, timeout=timeout)
    if check and p.returncode != 0:
        raise AssertionError(f'./rwpend {" ".join(args)} -> {p.returncode}\n{p.stdout[-2000:]}\n{p.stderr[-2000:]}')
    return p


def series(bag_dir, topic):
    """The columns of ``topic``; of ``command`` without the controller's release (test_stack_system.answers)."""
    bag = read_bag(bag_dir)
    assert topic in bag.topics, sorted(bag.topics)
    return answers(_decode(bag, topic))


def strings(bag_dir, topic, field_names):
    """String fields of every message of ``topic`` (decoded one by one) and the log times."""
    from mcap.records import Schema
    from mcap_ros2.decoder import DecoderFactory
    t = read_bag(bag_dir).topics[topic]
    dec = DecoderFactory().decoder_for('cdr', Schema(id=1, name=t.type, encoding='ros2msg', data=t.schema.encode()))
    out = []
    for log_ns, d in zip(t.log_ns(), t.datas):
        m = dec(d)
        out.append((int(log_ns), *(getattr(m, f) for f in field_names)))
    return out


def diagnostics(bag_dir):
    """[(log_ns, name, level, message, {key: value})] of /diagnostics in a bag."""
    from mcap.records import Schema
    from mcap_ros2.decoder import DecoderFactory
    t = read_bag(bag_dir).topics['/diagnostics']
    dec = DecoderFactory().decoder_for('cdr', Schema(id=1, name=t.type, encoding='ros2msg', data=t.schema.encode()))
    out = []
    for log_ns, d in zip(t.log_ns(), t.datas):
        for s in dec(d).status:
            level = s.level[0] if isinstance(s.level, (bytes, bytearray)) else int(s.level)
            out.append((int(log_ns), s.name, level, s.message, {kv.key: kv.value for kv in s.values}))
    return out


def rosout(bag_dir):
    """[(log_ns, stamp_ns, logger name, text)] of /rosout in a bag (Log.stamp: wall time)."""
    from mcap.records import Schema
    from mcap_ros2.decoder import DecoderFactory
    t = read_bag(bag_dir).topics['/rosout']
    dec = DecoderFactory().decoder_for('cdr', Schema(id=1, name=t.type, encoding='ros2msg', data=t.schema.encode()))
    out = []
    for log_ns, d in zip(t.log_ns(), t.datas):
        m = dec(d)
        out.append((int(log_ns), m.stamp.sec * 1_000_000_000 + m.stamp.nanosec, m.name, m.msg))
    return out


def deviation(theta):
    return np.remainder(np.asarray(theta) - np.pi + np.pi, 2 * np.pi) - np.pi


def longest_run(mask) -> int:
    best = run = 0
    for m in mask:
        run = run + 1 if m else 0
        best = max(best, run)
    return best


def assert_commands_sane(bag, topic=NS + '/command'):
    cmd = series(bag, topic)
    u = cmd['u']
    assert np.all(np.isfinite(u)) and np.all(np.abs(u) <= 10.0), 'a command outside |u| <= 10 or not finite'
    truth = series(bag, NS + '/sim/true_state')
    assert np.all(np.isfinite(truth['u_applied'])) and np.all(np.abs(truth['u_applied']) <= 10.0)
    return cmd, truth


def last_before_longest_gap(seqs) -> int:
    """The seq just before the longest run of missing seqs: the last message of a node that was
    killed and later restarted (found by seq, not by the recorder's receive times)."""
    s = np.unique(np.asarray(seqs, dtype=np.int64))
    return int(s[np.argmax(np.diff(s))])


def no_tracebacks(procs: Procs, tags) -> None:
    for tag in tags:
        text = procs.log(tag)
        assert 'Traceback' not in text, f'{tag}:\n{text[-3000:]}'


def loop_params(lockstep: bool, **sim):
    """Params of sim / estimator / controller for a loop recorded by a separate recorder."""
    s = {'start.encoders_subscribers': 2, 'start.true_state_subscribers': 1}
    e, c = {}, {}
    if lockstep:
        s.update({'lockstep': True, 'lockstep_timeout': LOCKSTEP_TIMEOUT})
        e['use_sim_time'] = True
        c['use_sim_time'] = True
    s.update(sim)
    return s, e, c


UPRIGHT = math.pi + 0.05   # start near upright: auto catches at once (saves the first swing-up)


# ------------------------------------------------------------------ 1. dead controller
@pytest.mark.timeout(120)
def test_dead_controller_plant_zeroes_and_restart_swings_up_again(tmp_path, ros_env):
    bag = tmp_path / 'bag'
    P = Procs(tmp_path, ros_env)
    sim, est, ctl = loop_params(True, **{'initial.theta': UPRIGHT})
    try:
        P.start('recorder', [RWPEND, 'record', '-o', str(bag), '--all'])
        P.node('sim', 'sim', sim)
        P.node('estimator', 'estimator', est)
        P.node('ctl1', 'controller', {**ctl, 'mode': 'auto'})
        P.wait_log('ctl1', 'auto/catch', 60)
        P.wait_recording(['command', 'controller/status', 'state', 'sim/true_state'])
        time.sleep(2.0)                                  # balancing
        kill_ns = P.kill('ctl1')
        rwpend(['tap', '1.5'], ros_env)                  # push it over while nobody controls it
        time.sleep(2.0)
        restart_ns = time.time_ns()
        P.node('ctl2', 'controller', {**ctl, 'mode': 'auto'})
        P.wait_log('ctl2', 'auto/catch', 60)
        time.sleep(6.0)                                  # >= 1 s of balance, also under load
    finally:
        P.stop_all(['ctl2', 'estimator', 'sim', 'recorder'])
    no_tracebacks(P, ['sim', 'estimator', 'ctl2'])
    cmd, truth = assert_commands_sane(bag)
    m = {}
    # the dead controller's last command answered seq s1; the plant's zero starts at s1 + n.
    # s1 is the command before the longest run of samples without a command (the dead time),
    # found by seq, not by the recorder's receive time: when a process is SIGKILLed, Fast DDS
    # (shared-memory transport) can block other participants' sends to it for 1-3 s, the
    # recorder's included, so commands sent before the kill may be logged seconds after it.
    s1 = last_before_longest_gap(cmd['seq'])
    seq = truth['seq'].astype(np.int64)
    after = seq > s1 + 1
    # true_state k shows the command held over [t_k-1, t_k): zero from sample s1 + n
    j = np.nonzero(after & (truth['u_commanded'] == 0.0))[0][0]
    m['controller_kill_to_zero_samples'] = int(seq[j] - 1 - s1)
    m['controller_kill_to_zero_ms_sim'] = m['controller_kill_to_zero_samples'] * H * 1e3
    m['controller_kill_to_zero_ms_wall'] = round((int(truth['_log_ns'][j]) - kill_ns) / 1e6, 1)
    jj = np.nonzero(after & (np.abs(truth['u_applied']) < 0.05))[0][0]
    m['controller_kill_to_motor_torque_below_0.05_samples'] = int(seq[jj] - 1 - s1)
    assert m['controller_kill_to_zero_samples'] <= 3, m
    # zero from then on until the restart (from j: the recorder may have missed the dead
    # controller's very last command, which the plant did get -- killed while sending it)
    assert np.all(truth['u_commanded'][(seq >= seq[j]) & (truth['_log_ns'] < restart_ns)] == 0.0)
    # /diagnostics of the simulator says why
    diag = [d for d in diagnostics(bag) if d[1].endswith('sim: plant') and d[0] > kill_ns - 10_000_000]
    why = next(d for d in diag if 'command timeout' in d[3])
    m['sim_diagnostics_after_kill_ms_wall'] = round((why[0] - kill_ns) / 1e6, 1)
    assert why[0] - kill_ns < 5e9, m      # ~6 ms; up to 3 s when Fast DDS stalls (above)
    # the pendulum fell, and the restarted controller swung it up and caught it again
    x = deviation(truth['theta'])
    dead = (truth['_log_ns'] > kill_ns) & (truth['_log_ns'] < restart_ns)
    assert np.max(np.abs(x[dead])) > 1.0
    st = strings(bag, NS + '/controller/status', ['law', 'fault'])
    laws2 = [s[1] for s in st if s[0] > restart_ns]
    # auto again: swing-up then catch -- or a direct catch when the restarted controller finds
    # the falling pendulum passing through the catch region (depends on the wall-clock timing)
    assert 'catch' in laws2 and set(laws2) <= {'swingup', 'catch'}, sorted(set(laws2))
    m['balanced_after_restart_samples'] = longest_run(np.abs(x[truth['_log_ns'] > restart_ns]) < 0.1)
    print('measured:', json.dumps(m))
    assert m['balanced_after_restart_samples'] > 1000, (m, laws2)


# ------------------------------------------------------------------ 2. dead estimator
@pytest.mark.timeout(120)
def test_dead_estimator_controller_reports_stale_and_zeroes(tmp_path, ros_env):
    bag = tmp_path / 'bag'
    P = Procs(tmp_path, ros_env)
    sim, est, ctl = loop_params(True, **{'initial.theta': UPRIGHT})
    try:
        P.start('recorder', [RWPEND, 'record', '-o', str(bag), '--all'])
        P.node('sim', 'sim', sim)
        P.node('est1', 'estimator', est)
        P.node('controller', 'controller', {**ctl, 'mode': 'auto'})
        P.wait_log('controller', 'auto/catch', 60)
        P.wait_recording(['command', 'controller/status', 'state', 'sim/true_state'])
        time.sleep(1.5)
        kill_ns = P.kill('est1')
        P.wait_log('controller', 'stale state', 20)
        time.sleep(1.0)
        restart_ns = time.time_ns()
        P.node('est2', 'estimator', est)
        P.wait_log('controller', 'state resumed', 30)
        time.sleep(2.0)
    finally:
        P.stop_all(['controller', 'est2', 'sim', 'recorder'])
    no_tracebacks(P, ['sim', 'controller', 'est2'])
    cmd, truth = assert_commands_sane(bag)
    m = {}
    state = series(bag, NS + '/state')
    # the last state before the longest run without one (by seq, not receive time: see test 1)
    before = state['seq'].astype(np.int64) <= last_before_longest_gap(state['seq'])
    s_last = int(state['seq'][before].max())
    t_last = int(state['_stamp_ns'][before][np.argmax(state['seq'][before])])
    st = series(bag, NS + '/controller/status')
    faults = strings(bag, NS + '/controller/status', ['fault', 'seq'])
    # the stale state the kill caused: the first after the last state before the gap (a loaded
    # host may add short stale episodes of its own before it, reported as well, whose status the
    # recorder can take late: one after seq 1286 was logged after the kill of a gap at 1938)
    import re

    def after_seq(text: str) -> int:
        return int(re.search(r'after seq (\d+)', text).group(1))
    i = next(k for k, f in enumerate(faults) if f[1].startswith('stale state') and f[0] > kill_ns - 100_000_000
             and after_seq(f[1]) >= s_last)
    # the last state the controller got; the recorder may have missed the very last one
    # (the estimator was killed while delivering it)
    s_ctl = after_seq(faults[i][1])
    assert s_last <= s_ctl <= s_last + 2 and faults[i][2] == s_ctl + 1, (faults[i], s_last)
    t_last += int(round((s_ctl - s_last) * H * 1e9))
    s_last = s_ctl
    m['estimator_kill_to_stale_ms_sim'] = round((int(st['_stamp_ns'][i]) - t_last) / 1e6, 3)
    m['estimator_kill_to_stale_samples'] = round(m['estimator_kill_to_stale_ms_sim'] / (H * 1e3))
    m['estimator_kill_to_stale_ms_wall'] = round((faults[i][0] - kill_ns) / 1e6, 1)
    # the controller checks for a stale state every WATCHDOG_PERIOD (steady clock): it notices
    # within state_timeout_samples h + that period (controller_node), plus the timer's own
    # wake-up delay on a loaded machine (2 samples here; ~1 in 20 runs took 9 samples under
    # load, which the earlier bound of 6 failed although the design allows 8)
    from rwpend_control.controller_node import WATCHDOG_PERIOD
    from rwpend_control.supervisor import ControllerConfig
    timeout = ControllerConfig().state_timeout_samples
    assert timeout <= m['estimator_kill_to_stale_samples'] <= timeout + math.ceil(WATCHDOG_PERIOD / H) + 2, m
    # the zero command answering the next sample, applied by the plant
    zero = (cmd['seq'] == s_last + 1) & (cmd['u'] == 0.0)
    assert zero.any(), 'no zero command after the state went stale'
    seq = truth['seq'].astype(np.int64)
    j = np.nonzero((seq > s_last + 1) & (truth['u_commanded'] == 0.0))[0][0]
    m['estimator_kill_to_plant_zero_samples'] = int(seq[j] - 1 - s_last)
    assert m['estimator_kill_to_plant_zero_samples'] <= 3
    # reported on /diagnostics with the reason
    diag = [d for d in diagnostics(bag) if d[1].endswith('/controller') and d[0] > kill_ns]
    assert any(d[2] == 2 and d[3].startswith('stale state') for d in diag), diag[:5]
    # recovery: fault cleared, commands flow again
    assert any(f[1] == '' for f in faults[i:] if f[0] > restart_ns)
    # (lockstep across processes: 2 s of wall time is what the host makes of it; a fresh-clone
    # run on a host twice as slow recorded 477 commands after the restart, 200 are 0.2 s of loop)
    assert (cmd['seq'] > s_last + 1).any() and (cmd['_log_ns'] > restart_ns).sum() > 200
    print('measured:', json.dumps(m))


# ------------------------------------------------------------------ 3. loss and delay
RELAY = textwrap.dedent('''
    import collections, json, random, sys, threading, time
    import rclpy
    from rclpy.node import Node
    from rwpend_msgs.msg import StateEstimate
    from rwpend_ros.qos import QOS_CONTROL
    from rwpend_ros.runner import make_executor, spin_executor
    out, drop, delay, seed = sys.argv[1], float(sys.argv[2]), float(sys.argv[3]), int(sys.argv[4])
    rclpy.init()
    node = Node('relay', namespace='/rwpend')
    pub = node.create_publisher(StateEstimate, 'state_relayed', QOS_CONTROL)
    rnd = random.Random(seed)
    n = {'in': 0, 'dropped': 0, 'out': 0}
    q = collections.deque()
    cv = threading.Condition()
    stop = threading.Event()
    def on_state(m):
        n['in'] += 1
        if rnd.random() < drop:
            n['dropped'] += 1
            return
        if delay <= 0:
            pub.publish(m)
            n['out'] += 1
            return
        with cv:
            q.append((time.monotonic() + delay, m))
            cv.notify()
    def delayer():
        while not stop.is_set():
            with cv:
                while not q and not stop.is_set():
                    cv.wait(0.1)
                if stop.is_set():
                    return
                due, m = q[0]
            wait = due - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            with cv:
                q.popleft()
            try:
                pub.publish(m)
            except Exception:
                if rclpy.ok():
                    raise
                return              # Ctrl-C shut the context down under this thread's publish
            n['out'] += 1
    node.create_subscription(StateEstimate, 'state', on_state, QOS_CONTROL)
    threading.Thread(target=delayer, daemon=True).start()
    ex = make_executor()
    ex.add_node(node)
    print('relay ready', flush=True)
    try:
        spin_executor(ex)
    except KeyboardInterrupt:
        pass
    finally:
        stop.set()
        json.dump(n, open(out, 'w'))
''')


def relay_run(tmp_path, env, lockstep, drop, delay, duration, sim_exits=(0,)):
    bag = tmp_path / 'bag'
    P = Procs(tmp_path, env)
    extra = {'lockstep_timeout': RELAY_LOCKSTEP_TIMEOUT} if lockstep else {}
    sim, est, ctl = loop_params(lockstep, **{'initial.theta': UPRIGHT, 'duration': duration, **extra})
    counts = tmp_path / 'relay.json'
    try:
        P.start('recorder', [RWPEND, 'record', '-o', str(bag), '--all'])
        P.start('relay', [PY, '-u', '-c', RELAY, str(counts), str(drop), str(delay), '11'])
        P.node('estimator', 'estimator', est)
        P.node('controller', 'controller', {**ctl, 'mode': 'auto'}, ros=('-r', 'state:=state_relayed'))
        P.wait_log('relay', 'relay ready', 30)
        P.node('sim', 'sim', sim)
        # lockstep across five processes: the wall time is the host's (37 s did not suffice for
        # 6 s simulated on a slow, loaded 2-core host), plus a lockstep timeout per dropped
        # state; only a run that never ends fails here
        waits = drop * duration / H * RELAY_LOCKSTEP_TIMEOUT
        end = time.monotonic() + 25 + (8 * duration + waits if lockstep else duration)
        while P.procs['sim'].poll() is None and time.monotonic() < end:   # the sim stops at duration
            time.sleep(0.2)
        sim_exit = P.procs['sim'].poll()
        assert sim_exit in sim_exits, P.log('sim')[-2000:]
        for tag in ('controller', 'estimator', 'relay'):
            assert P.procs[tag].poll() is None, f'{tag} died:\n{P.log(tag)[-2000:]}'
    finally:
        P.stop_all(['controller', 'relay', 'estimator', 'sim', 'recorder'])
    no_tracebacks(P, ['controller', 'estimator', 'relay', 'sim'])
    cmd, truth = assert_commands_sane(bag)
    n = json.loads(counts.read_text())
    x = deviation(truth['theta'])
    t = truth['seq'] * H
    ctl_diag = [d for d in diagnostics(bag) if d[1].endswith('/controller')]
    m = {'sim_exit': sim_exit, 'relay_in': n['in'], 'relay_dropped': n['dropped'], 'drop_fraction': round(n['dropped'] / max(n['in'], 1), 4),
         'delay_ms': delay * 1e3, 'samples': int(len(t)), 'commands': int(len(cmd['u'])),
         'max_abs_u': float(np.max(np.abs(cmd['u']))),
         'balanced_fraction_after_1s': float(np.mean(np.abs(x[t > 1.0]) < 0.1)),
         'max_abs_deviation_after_1s': float(np.max(np.abs(x[t > 1.0]))),
         'controller_stale_episodes': int(ctl_diag[-1][4].get('stale_episodes', -1)) if ctl_diag else None}
    return m, truth, cmd


@pytest.mark.timeout(200)
def test_lockstep_relay_dropping_10_percent_of_state_balance_holds(tmp_path, ros_env):
    m, truth, cmd = relay_run(tmp_path, ros_env, lockstep=True, drop=0.10, delay=0.0, duration=6.0)
    print('measured:', json.dumps(m))
    assert 0.07 < m['drop_fraction'] < 0.13 and m['relay_in'] > 5000
    assert m['balanced_fraction_after_1s'] == 1.0, m     # every sample within 0.1 rad of upright


@pytest.mark.timeout(150)
def test_realtime_relay_delay_5ms_and_drops_balance_holds_or_fails_safe(tmp_path, ros_env):
    """Real time on a shared machine: the loop may lose the pendulum (reported), but every command
    stays finite and |u| <= 10, and no node dies. A state 5 ms late makes every command answer a
    sample 5 or more samples old, which the plant refuses (command_timeout_samples 3): the motor
    is held at zero and the simulator ends with the loop-dead status, said in its log -- the safe
    failure."""
    m, truth, cmd = relay_run(tmp_path, ros_env, lockstep=False, drop=0.10, delay=0.005, duration=6.0,
                              sim_exits=(0, EXIT_LOOP_DEAD))
    m['balance_held'] = m['balanced_fraction_after_1s'] == 1.0
    print('measured:', json.dumps(m))
    assert m['relay_in'] > 1000
    # the plant never held a command command_timeout_samples (3) or more samples old: the true state
    # at seq k reports the command held over [t_k-1, t_k), late by k - 1 - command_seq samples
    # (PlantState.msg); where none was fresh, command_seq is -1 and the motor command zero
    seq, cseq = np.asarray(truth['seq'], np.int64), np.asarray(truth['command_seq'], np.int64)
    u = np.asarray(truth['u_commanded'])
    held = cseq >= 0
    assert np.all(seq[held] - 1 - cseq[held] < 3), np.max(seq[held] - 1 - cseq[held])
    assert np.all(u[~held] == 0.0)


# ------------------------------------------------------------------ 4. fuzz
FUZZER = textwrap.dedent('''
    import json, math, random, sys, time
    import rclpy
    from rclpy.node import Node
    from diagnostic_msgs.msg import DiagnosticArray
    from rcl_interfaces.msg import Parameter as PMsg, ParameterType, ParameterValue
    from rcl_interfaces.srv import SetParameters
    from std_srvs.srv import SetBool, Trigger
    from rwpend_msgs.msg import EncoderCounts, MotorCommand, PlantState, StateEstimate
    from rwpend_msgs.srv import Disturb, SetMode
    from rwpend_ros.qos import QOS_CONTROL, QOS_STATUS
    out, n_msgs, n_srv, seed = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
    rnd = random.Random(seed)
    rclpy.init()
    node = Node('fuzzer')
    # one executor for the whole run: rclpy.spin_once(node) adds and removes the node at every
    # call, which rebuilds the wait set each time (most of the run's wall time, one response a call)
    from rclpy.executors import SingleThreadedExecutor
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    SPECIAL = [math.nan, math.inf, -math.inf, 1e308, -1e308, 1e12, -1e12, 0.0, -0.0, 5e-324, -1.0, 1e-300]
    def f():
        r = rnd.random()
        return rnd.choice(SPECIAL) if r < 0.35 else (rnd.uniform(-1e4, 1e4) if r < 0.6 else rnd.gauss(0, 3))
    def i32():
        return rnd.choice([0, -1, 1, 2**31 - 1, -2**31, rnd.randint(-2**31, 2**31 - 1), rnd.randint(-3, 3)])
    def u64(k):
        return rnd.choice([k, k, k + 1, 0, 2**64 - 1, rnd.randrange(2**64), max(k - 5, 0)])
    def stamp(m):
        if rnd.random() < 0.5:
            m.header.stamp = node.get_clock().now().to_msg()
        else:
            m.header.stamp.sec = rnd.randint(-2**31, 2**31 - 1)
            m.header.stamp.nanosec = rnd.randint(0, 2**32 - 1)
    pubs = {
        'state': node.create_publisher(StateEstimate, '/fz_c/state', QOS_CONTROL),
        'encoders': node.create_publisher(EncoderCounts, '/fz_e/encoders', QOS_CONTROL),
        'est_command': node.create_publisher(MotorCommand, '/fz_e/command', QOS_CONTROL),
        'sim_command': node.create_publisher(MotorCommand, '/fz_s/command', QOS_CONTROL),
    }
    seen = {'commands': 0, 'bad_commands': 0, 'states': 0, 'bad_states': 0, 'truth': 0, 'bad_truth': 0}
    def on_cmd(m):
        seen['commands'] += 1
        if not (math.isfinite(m.u) and abs(m.u) <= 10.0):
            seen['bad_commands'] += 1
    def on_state(m):
        seen['states'] += 1
        if not all(math.isfinite(v) for v in (m.theta, m.theta_dot, m.wheel_angle, m.wheel_rate, m.friction, m.energy)):
            seen['bad_states'] += 1
    sim_seq = [0]
    def on_truth(m):
        seen['truth'] += 1
        sim_seq[0] = m.seq
        if not (math.isfinite(m.u_applied) and abs(m.u_applied) <= 10.0 and math.isfinite(m.u_commanded)
                and abs(m.u_commanded) <= 10.0):
            seen['bad_truth'] += 1
    diags = {}
    rounds = {}     # /diagnostics received per status name
    def on_diag(a):
        for s in a.status:
            diags[s.name] = (s.message, {kv.key: kv.value for kv in s.values})
            rounds[s.name] = rounds.get(s.name, 0) + 1
    node.create_subscription(MotorCommand, '/fz_c/command', on_cmd, QOS_CONTROL)
    node.create_subscription(StateEstimate, '/fz_e/state', on_state, QOS_CONTROL)
    node.create_subscription(PlantState, '/fz_s/sim/true_state', on_truth, QOS_CONTROL)
    node.create_subscription(DiagnosticArray, '/diagnostics', on_diag, QOS_STATUS)
    def spin(s):
        end = time.monotonic() + s
        while time.monotonic() < end:
            ex.spin_once(timeout_sec=0.005)
    end = time.monotonic() + 30
    while time.monotonic() < end and not all(p.get_subscription_count() > 0 for p in pubs.values()):
        spin(0.1)
    sent = {k: 0 for k in pubs}
    t0 = time.monotonic()
    for k in range(n_msgs):
        m = StateEstimate(); stamp(m); m.seq = u64(k)
        m.theta, m.theta_dot, m.wheel_angle, m.wheel_rate, m.friction, m.energy = f(), f(), f(), f(), f(), f()
        m.estimator = rnd.choice(['', 'x' * 300, 'nonlinear', '\\u00e9\\u4e2d'])
        pubs['state'].publish(m); sent['state'] += 1
        e = EncoderCounts(); stamp(e); e.seq = u64(k)
        wild = k > 10 and rnd.random() < 0.2     # else plausible counts near 0, so estimates come out
        e.pendulum_counts, e.motor_counts = (i32(), i32()) if wild else (rnd.randint(-3, 3), rnd.randint(-40, 40))
        pubs['encoders'].publish(e); sent['encoders'] += 1
        for key in ('est_command', 'sim_command'):
            c = MotorCommand(); stamp(c); c.u = f()
            # the simulator accepts answers to its current samples: mostly those, some garbage
            c.seq = u64(k) if key == 'est_command' or rnd.random() < 0.3 else max(sim_seq[0] - rnd.randrange(3), 0)
            pubs[key].publish(c); sent[key] += 1
        if k % 50 == 7:
            # truncated wire bytes (a raw publisher can send anything): counted and dropped
            for key in pubs:
                pubs[key].publish(b'\\x00\\x01\\x00\\x00' + bytes(rnd.randrange(0, 24))); sent[key] += 1
        if k % 100 == 99:
            # pace by the controller's and the estimator's answers (out-of-order states get none,
            # refused encoder samples neither): at most a few hundred messages in flight, far
            # below the depth of 1000 of the reliable QoS, so every message is delivered
            # (or until nothing more comes for 50 ms: the order gates drop what is out of order,
            # the estimator re-synchronises, so not every message gets an answer)
            end = time.monotonic() + 2.0
            last, quiet = (seen['commands'], seen['states']), time.monotonic()
            while time.monotonic() < end and (seen['commands'] < 0.9 * sent['state'] - 300
                                              or seen['states'] < 0.6 * sent['encoders'] - 300):
                ex.spin_once(timeout_sec=0.005)
                if (seen['commands'], seen['states']) != last:
                    last, quiet = (seen['commands'], seen['states']), time.monotonic()
                elif time.monotonic() - quiet > 0.05:
                    break
            spin(0.002)
    t_msgs = time.monotonic() - t0
    print(f'messages sent in {t_msgs:.1f} s', flush=True)
    # a clean tail (seq on from the fuzz, stamps now, counts at rest, 3 s): the gates and the
    # estimator take the stream again -- nothing the fuzz sent latched them. Judged by the
    # controller's commands the fuzzer receives and by the estimator's own sample count on
    # /diagnostics (the fuzzer's reader of the estimator's state was seen to stop receiving
    # after a few dozen states in two loaded runs, while the estimator published on)
    spin(1.2)
    def est_samples():
        v = next((v for k, (_, v) in diags.items() if k.endswith('/fz_e/estimator')), {})
        return int(v.get('samples', 0))
    before = (seen['commands'], seen['states'], est_samples())
    n_tail = 1500
    for k in range(n_msgs + 1000, n_msgs + 1000 + n_tail):
        m = StateEstimate(); m.header.stamp = node.get_clock().now().to_msg(); m.seq = k
        m.estimator = 'nonlinear'
        pubs['state'].publish(m)
        e = EncoderCounts(); e.header.stamp = node.get_clock().now().to_msg(); e.seq = k
        pubs['encoders'].publish(e)
        spin(0.002)
    spin(0.2)
    tail = {'sent': n_tail, 'commands': seen['commands'] - before[0], 'states': seen['states'] - before[1],
            'estimator_samples': est_samples() - before[2]}
    print(f'clean tail: {tail}', flush=True)
    if n_msgs and n_srv:
        # both parts in one run: the nodes' counters as the messages left them (one more round of
        # /diagnostics), before the services below reset or re-set anything
        spin(2.5)
    diags_msgs = json.loads(json.dumps(diags))
    # ------------------------------------------------ services
    def pvalue():
        pv = ParameterValue()
        kind = rnd.randrange(6)
        if kind == 0:
            pv.type, pv.double_value = ParameterType.PARAMETER_DOUBLE, f()
        elif kind == 1:
            pv.type, pv.integer_value = ParameterType.PARAMETER_INTEGER, rnd.choice([0, -1, 3, 2**63 - 1, -2**63])
        elif kind == 2:
            pv.type, pv.bool_value = ParameterType.PARAMETER_BOOL, rnd.random() < 0.5
        elif kind == 3:
            pv.type, pv.string_value = ParameterType.PARAMETER_STRING, rnd.choice(
                ['', 'auto', 'balance', 'off', 'brake', 'nonlinear', 'observer3', '1.5wp', 'nan', 'x' * 1000])
        elif kind == 4:
            pv.type, pv.double_array_value = ParameterType.PARAMETER_DOUBLE_ARRAY, [f() for _ in range(rnd.randrange(4))]
        else:
            pv.type = ParameterType.PARAMETER_NOT_SET
        return pv
    CTL = ['mode', 'balance.kpp', 'balance.kdp', 'balance.kdr', 'patch.kpp', 'swingup.c_e', 'theta_s', 'theta_0',
           'wheel.ref', 'wheel.kp', 'status_every', 'state_timeout_samples', 'wheel_speed_limit',
           'wheel_speed_action', 'max_saturation_time', 'saturation_action', 'friction_compensation',
           'balance.design.omega0', 'balance.design.kind', 'swingup.design.k_e', 'rig.g', 'nonexistent', '']
    EST = ['estimator', 'omega0', 'zeta', 'alpha', 'T', 'pendulum_omega0', 'friction_source', 'theta_offset',
           'max_rate', 'publish_joint_states', 'diagnostics_period', 'rig.j_p', 'bogus']
    SIM = ['lockstep', 'duration', 'initial.theta', 'command_timeout_samples', 'rig.g', 'zzz']
    def set_params_req(names):
        return SetParameters.Request(parameters=[PMsg(name=rnd.choice(names), value=pvalue())
                                                 for _ in range(rnd.randint(1, 3))])
    clients = {
        'ctl_set_mode': (node.create_client(SetMode, '/fz_c/controller/set_mode'), lambda: SetMode.Request(
            mode=rnd.choice(['auto', 'balance', 'off', 'swingup', 'wheel_velocity', 'wheel_angle', '', 'AUTO', 'x' * 500]))),
        'ctl_set_parameters': (node.create_client(SetParameters, '/fz_c/controller/set_parameters'),
                               lambda: set_params_req(CTL)),
        'est_set_parameters': (node.create_client(SetParameters, '/fz_e/estimator/set_parameters'),
                               lambda: set_params_req(EST)),
        'est_reset': (node.create_client(Trigger, '/fz_e/estimator/reset'), lambda: Trigger.Request()),
        'sim_disturb': (node.create_client(Disturb, '/fz_s/sim/disturb'), lambda: Disturb.Request(
            kind=rnd.randrange(256) if rnd.random() < 0.2 else rnd.randrange(2), magnitude=f(), duration=f())),
        'sim_estop': (node.create_client(SetBool, '/fz_s/sim/estop'), lambda: SetBool.Request(data=rnd.random() < 0.5)),
        'sim_set_parameters': (node.create_client(SetParameters, '/fz_s/sim/set_parameters'),
                               lambda: set_params_req(SIM)),
    }
    srv = {}
    t1 = time.monotonic()
    WINDOW = 8     # outstanding requests (the services' request queues keep the last 10)
    def tally(done, p):
        r = p.result()
        done['answered'] += 1
        ok = getattr(r, 'success', None)
        if ok is None and hasattr(r, 'results'):
            ok = all(x.successful for x in r.results)
        done['ok' if ok else 'refused'] += 1
    # all services at once, each with its own window of outstanding requests
    for name, (cli, make) in clients.items():
        assert cli.wait_for_service(timeout_sec=20), name
    srv = {name: {'ok': 0, 'refused': 0, 'answered': 0, 'lost': 0} for name in clients}
    issued = {name: 0 for name in clients}
    pending = {name: [] for name in clients}
    # every request answered is the test; how fast is the host's (150 s left 788 of 10 000
    # unanswered per service on a slow, loaded 2-core host)
    deadline = time.monotonic() + 300
    while any(issued[n] < n_srv or pending[n] for n in clients) and time.monotonic() < deadline:
        for name, (cli, make) in clients.items():
            while issued[name] < n_srv and len(pending[name]) < WINDOW:
                pending[name].append((time.monotonic(), cli.call_async(make())))
                issued[name] += 1
        ex.spin_once(timeout_sec=0.01)
        for name, (cli, make) in clients.items():
            keep = []
            for t_sent, p in pending[name]:
                if p.done():
                    tally(srv[name], p)
                elif time.monotonic() - t_sent > 10.0:
                    srv[name]['lost'] += 1
                    cli.remove_pending_request(p)
                else:
                    keep.append((t_sent, p))
            pending[name] = keep
    for name in clients:
        srv[name]['lost'] += len(pending[name]) + (n_srv - issued[name])
    print(f'services: {srv} after {time.monotonic() - t1:.1f} s', flush=True)
    # leave the e-stop cleared, then the final word: every node still answers
    clients['sim_estop'][0].call_async(SetBool.Request(data=False))
    fut = clients['ctl_set_mode'][0].call_async(SetMode.Request(mode='off'))
    end = time.monotonic() + 10
    while not fut.done() and time.monotonic() < end:
        ex.spin_once(timeout_sec=0.01)
    alive = fut.done() and fut.result().success
    # one more round of the controller's /diagnostics (its counts after the services: printed)
    ctl_rounds = rounds.get('/fz_c/controller', 0)
    end = time.monotonic() + 2.5
    while rounds.get('/fz_c/controller', 0) <= ctl_rounds and time.monotonic() < end:
        ex.spin_once(timeout_sec=0.01)
    json.dump({'sent': sent, 'seen': seen, 'tail': tail, 'services': srv, 'diags': diags,
               'diags_msgs': diags_msgs if n_srv else diags, 'alive': alive,
               't_msgs': t_msgs, 't_services': time.monotonic() - t1}, open(out, 'w'))
    print('fuzz done', flush=True)
''')


def run_fuzz(tmp_path, env, n_msgs, n_srv):
    P = Procs(tmp_path, env)
    out = tmp_path / 'fuzz.json'
    try:
        # a deep state queue: every fuzzed state is processed (the default of 5 drops a backlog)
        P.node('controller', 'controller', {'mode': 'auto', 'state_queue_depth': 1000},
               ros=('-r', '__ns:=/fz_c'))
        P.node('estimator', 'estimator', {}, ros=('-r', '__ns:=/fz_e'))
        # the simulator has no loop here (no controller in its namespace): a fuzzed command it
        # happens to accept would start one that "dies" after the fuzz and fail the process (exit 3)
        P.node('sim', 'sim', {'start.encoders_subscribers': 0, 'loop_dead_after': 1e6},
               ros=('-r', '__ns:=/fz_s'))
        t0 = time.monotonic()
        script = tmp_path / 'fuzzer.py'
        script.write_text(FUZZER)
        P.start('fuzzer', [PY, '-u', str(script), str(out), str(n_msgs), str(n_srv), '5'])
        P.procs['fuzzer'].wait(timeout=480)
        wall = time.monotonic() - t0
        assert P.procs['fuzzer'].returncode == 0, P.log('fuzzer')[-3000:]
        for tag in ('controller', 'estimator', 'sim'):
            assert P.procs[tag].poll() is None, f'{tag} died:\n{P.log(tag)[-3000:]}'
    finally:
        P.stop_all(['controller', 'estimator', 'sim'])
    for tag in ('controller', 'estimator', 'sim'):
        assert P.procs[tag].returncode == 0, (tag, P.log(tag)[-3000:])
    no_tracebacks(P, ['controller', 'estimator', 'sim', 'fuzzer'])
    r = json.loads(out.read_text())
    assert r['alive'], 'the controller did not answer after the fuzz'
    d = r['diags']
    r['ctl'] = d['/fz_c/controller'][1]
    r['est'] = d['/fz_e/estimator'][1]
    r['sim'] = next(v for k, v in d.items() if k.startswith('/fz_s/sim'))[1]
    dm = r['diags_msgs']
    r['msgs'] = {'ctl': dm['/fz_c/controller'][1], 'est': dm['/fz_e/estimator'][1],
                 'sim': next(v for k, v in dm.items() if k.startswith('/fz_s/sim'))[1]}
    r['wall'] = round(wall, 1)
    return r


@pytest.fixture(scope='module')
def fuzzed(tmp_path_factory):
    """One fuzz of the three nodes for both fuzz tests: the messages (then a clean tail, the
    nodes' counters taken), then the services -- one start of the nodes, not two (the tests only
    read what the run left); (messages, requests per service, the run's figures)."""
    env = dict(os.environ, ROS_DOMAIN_ID=str(test_domain_id()), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               PYTHONUNBUFFERED='1')
    env['RMW_IMPLEMENTATION'] = env.get('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp')
    n = int(os.environ.get('RWPEND_FUZZ_MESSAGES', '10000'))
    n_srv = int(os.environ.get('RWPEND_FUZZ_REQUESTS', '10000'))
    return n, n_srv, run_fuzz(tmp_path_factory.mktemp('fuzz'), env, n, n_srv)


@pytest.mark.timeout(600)       # the shared fuzz run (both parts) is set up in this test
def test_fuzz_every_subscriber(fuzzed):
    """>= 10 000 random messages into controller ``state``, estimator ``encoders`` and
    ``command``, simulator ``command``: nothing dies, refusals counted, every command published
    by the controller finite with |u| <= 10, every estimate and plant state finite (the nodes'
    counters as the messages left them, before the services of the same run)."""
    n, _, r = fuzzed
    seen, (ctl, est, sim) = r['seen'], (r['msgs'][k] for k in ('ctl', 'est', 'sim'))
    # what the order gates stopped (rwpend_ros.order: duplicates, older messages, too short)
    gate = {name: gate_dropped(d[key]) for name, d, key in (
        ('ctl', ctl, 'state_order'), ('est', est, 'encoders_order'), ('est_cmd', est, 'command_order'),
        ('sim', sim, 'command_order'))}
    ctl_in = int(ctl['samples']) + int(ctl['out_of_order_states']) + gate['ctl']
    est_in = (int(est['samples']) + int(est['refused_samples']) + int(est['duplicate_samples'])
              + int(est['malformed_samples']) + gate['est'])
    sim_in = (int(sim['commands']) + int(sim['rejected_commands']) + int(sim['stale_commands'])
              + int(sim['old_commands']) + gate['sim'])
    m = {'sent_per_topic': r['sent'], 'clean_tail': r['tail'], 'wall_s': r['wall'], 'send_s': round(r['t_msgs'], 1),
         'controller_states_received': ctl_in,
         'controller': {k: int(ctl[k]) for k in ('bad_states', 'out_of_order_states', 'stale_episodes',
                                                 'overspeed_trips', 'law_errors')},
         'controller_commands_seen': seen['commands'], 'bad_commands': seen['bad_commands'],
         'estimator_encoders_received': est_in,
         'estimator': {k: int(est[k]) for k in ('samples', 'refused_samples', 'refused_commands', 'seq_gaps',
                                                'resyncs', 'longest_gap')},
         'estimates_seen': seen['states'], 'bad_estimates': seen['bad_states'],
         'sim_commands_received': sim_in,
         'sim': {k: int(sim[k]) for k in ('commands', 'rejected_commands', 'stale_commands', 'old_commands',
                                          'saturated_commands')},
         'order_gates_dropped': gate,
         'true_states_seen': seen['truth'], 'bad_true_states': seen['bad_truth']}
    print('measured:', json.dumps(m))
    assert all(v >= n for v in r['sent'].values())
    assert ctl_in >= 0.95 * n and est_in >= 0.95 * n and sim_in >= 0.95 * n, m
    # most fuzzed states are refused (half the stamps are random: the controller's order gate
    # drops what is older than the last it took); the clean tail afterwards is answered
    tail = r['tail']
    assert seen['bad_commands'] == 0 and seen['commands'] > 0
    # the controller answered the clean tail; the estimator processed it (its /diagnostics come
    # once a second, after a sample: the last one may be up to 1 s before the tail's end)
    assert tail['commands'] >= 0.8 * tail['sent'], tail
    assert tail['estimator_samples'] >= 0.4 * tail['sent'], tail
    assert seen['bad_states'] == 0 and seen['bad_truth'] == 0
    # refused and counted: most fuzzed messages by the order gates (random stamps: older than the
    # last one taken), what passes them by the nodes' own checks
    assert int(ctl['bad_states']) > 0 and int(ctl['bad_states']) + gate['ctl'] > n // 10
    assert int(ctl['malformed_states']) + gate['ctl'] > 0 and int(sim['malformed_commands']) + gate['sim'] > 0
    assert int(est['refused_samples']) > 0 and int(est['refused_samples']) + gate['est'] > n // 20
    assert int(est['refused_commands']) > 0 and int(est['refused_commands']) + gate['est_cmd'] > n // 20
    assert int(sim['rejected_commands']) + int(sim['old_commands']) + gate['sim'] > n // 20
    # (saturation of an accepted command is tested in rwpend_sim/test/test_sim_core.py: the
    # fuzzed commands reach the simulator too late to be taken)


def gate_dropped(summary: str) -> int:
    """Messages an order gate's /diagnostics line says it dropped (duplicates, stale, malformed)."""
    head = summary.split(';')[0]
    counts = dict(kv.split(' ')[:2] for kv in head.split(', ') if kv)
    return sum(int(counts.get(k, 0)) for k in ('duplicates', 'stale', 'malformed'))


@pytest.mark.timeout(600)       # the shared fuzz run, when this test runs alone
def test_fuzz_every_service(fuzzed):
    """Random requests to set_mode, set_parameters (controller, estimator, simulator), reset,
    disturb and estop, all at once: every request answered, malformed ones refused, nothing dies
    (after the fuzzed messages of the same run: the nodes have taken those too)."""
    _, n, r = fuzzed
    m = {'requests_per_service': n, 'services': r['services'], 'wall_s': r['wall'],
         'services_s': round(r['t_services'], 1), 'controller_param_errors': int(r['ctl']['param_errors'])}
    print('measured:', json.dumps(m))
    for name, s in r['services'].items():
        assert s['answered'] == n and s['lost'] == 0, (name, s)
    sv = r['services']
    assert sv['ctl_set_mode']['refused'] > 0 and sv['sim_disturb']['refused'] > 0
    assert sv['ctl_set_parameters']['refused'] > n // 2 and sv['est_set_parameters']['refused'] > n // 2
    assert sv['sim_set_parameters']['ok'] == 0           # every simulator parameter is read-only


# ------------------------------------------------------------------ 5. e-stop
@pytest.mark.timeout(120)
def test_estop_holds_the_plant_at_zero_until_cleared(tmp_path, ros_env):
    bag = tmp_path / 'bag'
    log = tmp_path / 'stack.log'
    stack = subprocess.Popen([RWPEND, 'up', '--lockstep', '--mode', 'auto', '--theta0', str(UPRIGHT),
                              '--record', str(bag), '--set', f'sim.lockstep_timeout={LOCKSTEP_TIMEOUT}'],
                             env=ros_env, stdout=open(log, 'w'), stderr=subprocess.STDOUT, start_new_session=True)
    watch = DiagWatch(ros_env)
    try:
        end = time.monotonic() + 60
        while 'auto/catch' not in log.read_text() and time.monotonic() < end:
            assert stack.poll() is None, log.read_text()[-3000:]
            time.sleep(0.1)
        # waits in simulated time (the simulator's /diagnostics: one a simulated second): 1.5 s
        # balancing; then 2 more reports under the e-stop (the bag's 'held' is between the first
        # report of it and the first after the clear: >= 1 s); then 1 s after the first report
        # of the clear
        watch.wait(lambda v: int(v['samples']) >= 1500, 60, 'balancing')
        t_raise = time.time_ns()
        assert 'raised' in rwpend(['estop'], ros_env).stdout
        t_raised = time.time_ns()
        on = watch.wait(lambda v: v['estop'] == 'True', 30, 'the e-stop reported')
        watch.wait(lambda v: v['estop'] == 'True' and int(v['samples']) >= int(on['samples']) + 1000, 30,
                   '1 s under the e-stop')
        t_clear = time.time_ns()
        assert 'cleared' in rwpend(['estop', '--clear'], ros_env).stdout
        t_cleared = time.time_ns()
        off = watch.wait(lambda v: v['estop'] == 'False' and int(v['samples']) > int(on['samples']), 30,
                         'the clear reported')
        watch.wait(lambda v: int(v['samples']) >= int(off['samples']) + 1000, 30, '1 s after the clear')
    finally:
        watch.close()
        stack.send_signal(signal.SIGINT)
        stack.wait(timeout=40)
    out = log.read_text()
    assert stack.returncode == 0 and 'Traceback' not in out, out[-3000:]
    cmd, truth = assert_commands_sane(bag)
    # lockstep: the bag's log times and the /diagnostics stamps are sim time; when the e-stop
    # took effect on the wall clock is the stamp of the simulator's log line (/rosout)
    logs = rosout(bag)
    raised = next(stamp for _, stamp, name, msg in logs if name == 'rwpend.sim' and 'E-STOP raised' in msg)
    cleared = next(stamp for _, stamp, name, msg in logs if name == 'rwpend.sim' and 'e-stop cleared' in msg)
    assert t_raise < raised < t_raised + 1e9 and t_clear < cleared < t_cleared + 1e9
    diag = [d for d in diagnostics(bag) if d[1].endswith('sim: plant')]
    on = next(d for d in diag if d[4].get('estop') == 'True')
    off = next(d for d in diag if d[4].get('estop') == 'False' and d[0] > on[0])
    seq = truth['seq'].astype(np.int64)
    log_ns = truth['_log_ns']
    # the first sample published after the e-stop took effect shows zero
    k_on = int(np.nonzero(log_ns > on[0])[0][0])
    j = k_on + int(np.nonzero(truth['u_commanded'][k_on:] == 0.0)[0][0])
    m = {'estop_to_zero_samples': int(j - k_on), 'estop_to_zero_ms_sim': round((int(log_ns[j]) - on[0]) / 1e6, 2)}
    assert m['estop_to_zero_samples'] <= 2, m
    # 20 ms (of sim time: 20 samples) off either end
    held = (log_ns > on[0] + 20_000_000) & (log_ns < off[0] - 20_000_000)
    m['samples_held'] = int(held.sum())
    assert m['samples_held'] > 200, m
    assert np.all(truth['u_commanded'][held] == 0.0)
    jj = np.nonzero(held)[0]
    assert np.all(np.abs(truth['u_applied'][jj[5:]]) < 0.05)    # motor lag T_e = 0.5 ms
    # the controller switched off when the e-stop was raised (its estop/state), and stays off
    # after the clear until a mode is set (test_user_trips_system goes on from there)
    sent = (cmd['_log_ns'] > on[0] + 20_000_000) & (cmd['_log_ns'] < off[0])
    m['commands_during_estop'] = int(sent.sum())
    assert np.all(cmd['u'][sent] == 0.0)
    m['estop_samples'] = int(diag[-1][4]['estop_samples'])
    after = log_ns > off[0] + 20_000_000
    m['samples_after_clear'] = int(after.sum())
    assert m['samples_after_clear'] > 200 and np.all(truth['u_commanded'][after] == 0.0), m
    print('measured:', json.dumps(m), 'seq', int(seq[k_on]))


DRIVER_CMD_NODE = textwrap.dedent('''
    import json, sys, time
    import rclpy
    from rwpend_msgs.msg import EncoderCounts, MotorCommand
    from rwpend_ros.qos import QOS_CONTROL
    from rwpend_ros.runner import make_executor, spin_executor
    from rwpend_ros.sched import apply_scheduling
    u = float(sys.argv[1])
    apply_scheduling()     # as the stack's controller: the driver refuses commands 3 samples old
    rclpy.init()
    node = rclpy.create_node('constant_command')
    pub = node.create_publisher(MotorCommand, 'command', QOS_CONTROL)
    cmd = MotorCommand()
    n = [0]
    def on_enc(m):
        cmd.header.stamp, cmd.seq, cmd.u = m.header.stamp, m.seq, u
        pub.publish(cmd)
        n[0] += 1
        if n[0] == 1:
            print('streaming', flush=True)
    node.create_subscription(EncoderCounts, 'encoders', on_enc, QOS_CONTROL)
    ex = make_executor()
    ex.add_node(node)
    try:
        spin_executor(ex)
    except KeyboardInterrupt:
        pass
''')


def emulator_events(P: Procs) -> list[dict]:
    """The emulator's JSON lines so far."""
    ev = []
    for line in P.log('emulator').splitlines():
        try:
            ev.append(json.loads(line))
        except ValueError:
            pass
    return ev


def disable_index(ev) -> int | None:
    """The device's disable after it applied u = 2 (the e-stop), or None."""
    return next((i for i, e in enumerate(ev) if e['event'] == 'disable' and i > 0
                 and any(x['event'] == 'status' and x['u_applied'] == 2.0 for x in ev[:i])), None)


def zero_after_disable(ev) -> list[dict]:
    """The status lines after the e-stop's disable (until an enable)."""
    dis = disable_index(ev)
    if dis is None:
        return []
    out = []
    for e in ev[dis + 1:]:
        if e['event'] == 'enable':
            break
        if e['event'] == 'status':
            out.append(e)
    return out


def applied_after_enable(ev) -> bool:
    """u = 2 applied and the amplifier on again after the enable that follows the disable."""
    dis = disable_index(ev)
    ena = None if dis is None else next((i for i, e in enumerate(ev) if e['event'] == 'enable' and i > dis), None)
    return ena is not None and any(e['event'] == 'status' and e['u_applied'] == 2.0 and e['enabled']
                                   for e in ev[ena:])


def wait_events(P: Procs, cond, timeout: float) -> None:
    """Until ``cond`` holds on the emulator's events (polled; AssertionError after ``timeout`` s)."""
    end = time.monotonic() + timeout
    while not cond(emulator_events(P)):
        assert time.monotonic() < end, P.log('emulator')[-3000:]
        assert P.procs['emulator'].poll() is None, P.log('emulator')[-3000:]
        time.sleep(0.05)


@pytest.mark.timeout(90)
def test_driver_estop_zeroes_the_device_until_cleared(tmp_path, ros_env):
    """Through the serial driver: the emulated device's applied torque is 0 and its amplifier
    off from the e-stop to the clear, while a node keeps commanding u = 2."""
    P = Procs(tmp_path, {**ros_env, 'RWPEND_RT_PRIORITY': '50'})     # as on the rig (docs/rig.md)
    link = str(tmp_path / 'rig')
    try:
        P.start('emulator', [PY, '-u', '-m', 'rwpend_driver.emulator', '--link', link, '--json',
                             '--status-period', '0.05', '--rt-priority', '60'])
        P.wait_log('emulator', '"ready"', 20)
        P.start('driver', [PY, '-u', '-m', 'rwpend_driver.driver_node', '--ros-args', '-p', f'port:={link}'])
        P.start('commander', [PY, '-u', '-c', DRIVER_CMD_NODE, '2.0'])
        P.wait_log('commander', 'streaming', 30)
        # the device applies the commander's u = 2 before the e-stop (on a loaded machine the
        # first commands may take longer than a fixed pause)
        P.wait_log('emulator', '"u_applied": 2.0', 30)
        assert 'raised' in rwpend(['estop', '--ns', '/'], ros_env).stdout
        # the device's status lines (every 50 ms) as they come: 20 at zero after the disable,
        # then the u = 2 applied again after the enable
        wait_events(P, lambda ev: len(zero_after_disable(ev)) >= 20, 30)
        assert 'cleared' in rwpend(['estop', '--ns', '/', '--clear'], ros_env).stdout
        wait_events(P, lambda ev: applied_after_enable(ev), 30)
    finally:
        P.stop_all(['commander', 'driver', 'emulator'])
    no_tracebacks(P, ['driver', 'commander'])
    ev = emulator_events(P)
    dis = next(i for i, e in enumerate(ev) if e['event'] == 'disable' and i > 0
               and any(x['event'] == 'status' and x['u_applied'] == 2.0 for x in ev[:i]))
    ena = next(i for i, e in enumerate(ev) if e['event'] == 'enable' and i > dis)
    during = [e for e in ev[dis + 1:ena] if e['event'] == 'status']
    assert len(during) > 10 and all(e['u_applied'] == 0.0 and not e['enabled'] for e in during), during[:3]
    after = [e for e in ev[ena:] if e['event'] == 'status']
    assert any(e['u_applied'] == 2.0 and e['enabled'] for e in after), after[-3:]
    m = {'driver_estop_disabled_s': round(ev[ena]['t'] - ev[dis]['t'], 2), 'status_samples_at_zero': len(during)}
    print('measured:', json.dumps(m))
