"""The lab network, tested (issue 22): the stack split across hosts of a lab subnet, many rigs
on one network, one controller per rig -- with test hosts in network namespaces joined by a
switch (tests/support/netlab.py), ``ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET``, each host running
``./rwpend up`` with the same arguments and its own ``--only`` (tests/support/netrun.py).

Skipped, with the reason, where the namespaces cannot be made (not root). Nothing here asserts
timing: the latency and late fractions across the link are printed (``pytest -s``; the figures
measured are in PERFORMANCE.md, "The lab network"); what is asserted is what must hold on any machine -- the same bag,
the motor at zero when the link is cut, no unsafe sample, no message across rigs.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

from rwpend_bag.judge import judge, read_run
from rwpend_bag.reader import read_bag
from support.netrun import SplitRun
from rwpend_ros import wire

pytestmark = pytest.mark.network
ROOT = Path(__file__).resolve().parents[1]
RWPEND = str(ROOT / 'rwpend')
#: the loop's topics with a seq, and those without (compared whole)
SEQ_TOPICS = ('encoders', 'sim/true_state', 'state', 'command', 'controller/status')
OTHER_TOPICS = ('joint_states',)


def loop_messages(bag_dir, ns: str, samples: int) -> dict[str, list[bytes]]:
    """The wire bytes of the loop's messages of samples 0..samples-1, per topic, and /clock."""
    bag = read_bag(bag_dir)
    out = {'/clock': bag.topics['/clock'].datas}
    for name in SEQ_TOPICS:
        datas = bag.topics[f'{ns}/{name}'].datas
        out[name] = [d for d in datas if wire.message_seq_stamp(d)[0] < samples]
    for name in OTHER_TOPICS:
        out[name] = bag.topics[f'{ns}/{name}'].datas
    return out


def wait_balancing(run: SplitRun, i: int, hold: float, timeout: float, since: int = 0) -> bool:
    """True once the controller whose output is part ``i``'s log (from character ``since``) has
    balanced (auto/catch) for ``hold`` s with no switch since; False after ``timeout`` s, or when
    the plant has ended (at its ``--duration``) before."""
    end = time.monotonic() + timeout
    seen, caught_at = -1, None
    while time.monotonic() < end and all(p.proc.poll() is None for p in run.plant_parts()):
        switches = [ln.split(' -> ', 1)[1] for ln in run.log_text(i)[since:].splitlines()
                    if 'switch ' in ln and ' -> ' in ln]
        if len(switches) != seen:
            seen = len(switches)
            caught_at = time.monotonic() if switches and switches[-1].startswith('auto/catch') else None
        if caught_at is not None and time.monotonic() - caught_at >= hold:
            return True
        time.sleep(0.1)
    return False


def split_three(netlab):
    a, b, c = (netlab.add_host(n) for n in ('a', 'b', 'c'))
    return a, b, c, [(a, 'sim'), (b, 'control'), (c, 'recorder')]


@pytest.mark.timeout(1200)
def test_lockstep_split_across_three_hosts_gives_the_bag_of_one_host(tmp_path, ros_env, netlab, lab_env):
    """Plant on host A, estimator + controller on B, recorder on C: every message of the loop
    is the same, byte for byte, as in the run of the whole stack on one host. (A command later
    than ``lockstep_timeout`` would make the plant run on with u = 0, a different run: on a
    loaded machine a stall of 0.5 s happens, so the timeout is 30 s here.)"""
    args = ['--lockstep', '--duration', '4', '--mode', 'auto', '--ns', '/rig1',
            '--set', 'sim.lockstep_timeout=30']
    one = tmp_path / 'one_host'
    p = subprocess.run([RWPEND, 'up', *args, '--record', str(one)], env=ros_env, capture_output=True,
                       text=True, timeout=600)
    assert p.returncode == 0, p.stdout[-3000:] + p.stderr[-3000:]
    _, _, _, placement = split_three(netlab)
    run = SplitRun(netlab, lab_env, [*args, '--record', str(tmp_path / 'split')], placement, tmp_path)
    run.start()
    codes = run.finish(timeout=900)
    assert set(codes.values()) == {0}, (codes, [run.log_text(i)[-2000:] for i in range(3)])
    ref, got = loop_messages(one, '/rig1', 4000), loop_messages(tmp_path / 'split', '/rig1', 4000)
    for topic in ref:
        assert len(got[topic]) == len(ref[topic]), (topic, len(got[topic]), len(ref[topic]))
        differ = [i for i, (x, y) in enumerate(zip(ref[topic], got[topic])) if x != y]
        assert not differ, f'{topic}: {len(differ)} messages differ, the first at index {differ[0]}'
    assert len(ref['command']) == len(ref['encoders']) == 4000


@pytest.mark.timeout(600)
def test_realtime_split_swings_up_and_balances(tmp_path, netlab, lab_env):
    """Real time across the link: it swings up and balances; the motor is never driven by a
    stale command; every gap of the bag is in its report. Latency and late fractions printed."""
    from rwpend_bench.bench import bag_metrics
    _, _, _, placement = split_three(netlab)
    bag = tmp_path / 'rt'
    run = SplitRun(netlab, lab_env, ['--mode', 'auto', '--duration', '20', '--ns', '/rig1',
                                     '--record', str(bag)], placement, tmp_path)
    run.start()
    # --duration 20 is a bound: the run ends once the controller on B has balanced for 3 s (the
    # judge's catch is 1 s upright)
    wait_balancing(run, 1, hold=3.0, timeout=300)
    codes = run.end_now()
    # 4: the bag much shorter than the run, said by up on C (at load 16-20 the recorder across
    # the link once took 27 % of the samples); the gaps are then in its report, judged below
    assert codes['c'] in (0, 4), run.log_text(2)[-3000:]
    v = judge(read_run(bag))
    m = bag_metrics(bag, '/rig1', 0.001)
    print(json.dumps({'verdict': v.as_dict(), 'latency_us': m.get('latency_us'),
                      'late_fraction': m.get('late_fraction'),
                      'plant_late_fraction': m.get('plant_late_fraction'), 'dropped': m.get('dropped')},
                     indent=1, default=str))
    assert v.unsafe_samples == 0 and not v.latched and not v.unaccounted, v.problems
    assert v.catches >= 1, f'never balanced for 1 s across the link: {v.problems}'


# ------------------------------------------------------------------ link faults
def truth(bag_dir) -> dict:
    """sim/true_state as columns (stamp in s on the system clock, as the hosts share it)."""
    return read_run(bag_dir)['truth']


def window(t: dict, t0: float, t1: float) -> dict:
    i = (t['stamp'] >= t0) & (t['stamp'] < t1)
    return {k: v[i] for k, v in t.items()}


def segment_figures(t: dict) -> dict:
    """What the plant saw over a stretch of samples: the share of samples whose command was
    late (the command held before sample k+1 did not answer sample k), the share at zero by the
    command timeout, the share of time upright (|theta - pi| < 0.3)."""
    seq, cmd = t['seq'].astype(np.int64), t['command_seq'].astype(np.int64)
    x = np.abs(np.remainder(t['theta'], 2 * np.pi) - np.pi)
    n = max(len(seq), 1)
    return {'samples': int(len(seq)), 'late': round(float(np.sum(cmd != seq - 1)) / n, 4),
            'timeout': round(float(np.sum(t['command_timeout'])) / n, 4),
            'upright': round(float(np.sum(x < 0.3)) / n, 4)}


#: s after the port went down within which the motor is at zero for good (the last datagrams
#: in flight arrive, the command timeout runs out)
CUT_TAKES_S = 0.2


def cut_reaction(t: dict, t_pull: float, t_cut: float, t_restore: float) -> dict:
    """From the samples of the cut (the cable pulled at ``t_pull``, the port down at ``t_cut``,
    restored at ``t_restore``): the newest command the plant took before it went to zero
    (``last_command``: the sample it answers), the sample instant from which the motor was at
    zero by the command timeout (``zero_from``: the start of the timeout that lasts to the end of
    the cut; ``sim/true_state`` of sample k reports the command held over [t_k-1, t_k)), the
    samples between the two, and that start's time after the port went down (``cut_to_zero_s``:
    the motor stayed at zero from then until the restore; a command taken during the cut would
    put that start after it, beyond :data:`CUT_TAKES_S`)."""
    cut = window(t, t_pull, t_restore)
    if not cut['seq'].size or not cut['command_timeout'][-1]:
        return {'zero_from': None}
    # the timeout the cut's last sample is in, back to its start (on a loaded host the loop may
    # also time out for a moment of its own just before the cut takes effect)
    i = int(np.nonzero(t['seq'] == cut['seq'][-1])[0][0])
    while i > 0 and t['command_timeout'][i - 1]:
        i -= 1
    k0 = int(t['seq'][i])
    before = t['command_seq'][(t['seq'] <= k0)]
    last = int(before[before >= 0].max())
    out = {'last_command': last, 'zero_from': k0 - 1, 'samples_to_zero': k0 - 1 - last,
           'cut_to_zero_s': round(float(t['stamp'][i]) - t_cut, 3)}
    # after the restore: the first sample driven by a fresh command, and the first of 1 s upright
    later = t['stamp'] >= t_restore
    fresh = np.nonzero(later & ~t['command_timeout'].astype(bool))[0]
    up = np.abs(np.remainder(t['theta'], 2 * np.pi) - np.pi) < 0.3
    if fresh.size:
        out['fresh_after_restore_s'] = round(float(t['stamp'][fresh[0]] - t_restore), 3)
        n = int(round(1.0 / max(float(np.median(np.diff(t['stamp']))), 1e-6)))
        first_up = next((i for i in range(fresh[0], len(up) - n) if up[i:i + n].all()), None)
        if first_up is not None:
            out['upright_1s_after_restore_s'] = round(float(t['stamp'][first_up] - t_restore), 3)
    return out


@pytest.mark.timeout(600)
def test_link_cut_zeroes_the_motor_and_the_stack_recovers(tmp_path, netlab, lab_env):
    """While balancing, host B's cable (estimator + controller) is pulled for 4 s: the plant on
    A puts the motor at zero within command_timeout_samples of the last command and says so on
    /diagnostics (recorded on C, which still hears A); restored, the stack comes back without a
    restart and, in auto, swings up and balances again."""
    from test_safety_system import diagnostics
    a, b, c, placement = split_three(netlab)
    bag = tmp_path / 'cut'
    run = SplitRun(netlab, lab_env, ['--mode', 'auto', '--duration', '45', '--ns', '/rig1',
                                     '--record', str(bag)], placement, tmp_path)
    run.start()
    assert run.wait_for_log(1, 'auto/swingup -> auto/catch', timeout=120), run.log_text(1)[-3000:]
    time.sleep(3.0)
    t_pull = time.time()
    netlab.cut(b)
    t_cut = time.time()       # the port is down (starting the ip command takes its time on a loaded host)
    time.sleep(4.0)
    t_restore = time.time()
    since = len(run.log_text(1))
    netlab.restore(b)
    # --duration 45 is a bound: the run ends once the controller has balanced again for 6 s
    # after the restore (the checks below look at the last 2 s; with 3 s, 1 run in 10 at load 6.6
    # ended while the recorder's host was still reconnecting, and its up took > 30 s to exit)
    wait_balancing(run, 1, hold=6.0, timeout=300, since=since)
    codes = run.end_now()
    assert codes['c'] in (0, 4), run.log_text(2)[-3000:]      # 4: the bag misses B's cut seconds
    t = truth(bag)
    r = {**cut_reaction(t, t_pull, t_cut, t_restore), 'port_down_s': round(t_cut - t_pull, 3)}
    v = judge(read_run(bag))
    after = window(t, t_restore, t['stamp'][-1] + 1)
    print(json.dumps({'cut': r, 'before': segment_figures(window(t, t_pull - 3, t_pull)),
                      'cut_figures': segment_figures(window(t, t_pull, t_restore)),
                      'after': segment_figures(after), 'verdict': v.as_dict()}, indent=1, default=str))
    assert r['zero_from'] is not None, 'the motor was never at zero during the cut'
    assert r['samples_to_zero'] <= 3 and r['cut_to_zero_s'] <= CUT_TAKES_S, r
    assert v.unsafe_samples == 0, v.problems
    warned = [(ns, msg) for ns, name, level, msg, _ in diagnostics(bag)
              if name.endswith('/sim: plant') and level == 1 and 'command timeout' in msg
              and t_pull * 1e9 <= ns <= t_restore * 1e9 + 1e9]
    assert warned, 'no command-timeout warning of the plant on /diagnostics during the cut'
    # restored: fresh commands again, and (auto) up again after the fall. (Not "no timeout at
    # all in the last second": on a loaded machine a stall of a few ms puts a sample or two at
    # zero by the command timeout across the link as on one host.)
    # Alive, not a median: fresh commands in most of the last 2 s (0.889 was seen on a loaded
    # machine, the rest a few ms stalls at a time), a dead loop would have none
    fresh = ~after['command_timeout'][-2000:]
    assert fresh.size and fresh.mean() > 0.5, \
        f'no fresh commands after the link was restored ({fresh.mean():.3f} of the last 2000 samples)'
    up = np.abs(np.remainder(after['theta'], 2 * np.pi) - np.pi) < 0.3
    assert up[-2000:].all(), 'not balanced again at the end of the run (auto swings up again)'


#: s of each stretch of the delay-and-loss test (the figures printed per stretch; what is asserted
#: -- no stale command, the 5 ms stretch's commands refused -- holds from its first samples)
STRETCH_S = 4.0


@pytest.mark.timeout(600)
def test_delay_and_loss_are_reported_and_never_unsafe(tmp_path, netlab, lab_env):
    """Host B (estimator + controller) behind a delay line, with nftables loss: 4 s stretches of
    0 ms, 1 ms, 1 % loss, 5 ms each way, then 0 ms again (4000 samples each). Printed per
    stretch: late share, share at zero by the timeout, share upright. Asserted: no sample driven by a stale
    command, ever (5 ms each way makes every command 10+ samples old: the plant refuses them)."""
    from support.netlab import ensure_nft
    reason = ensure_nft()
    if reason is not None:
        pytest.skip(f'no packet loss without nftables: {reason}')
    a = netlab.add_host('a')
    b = netlab.add_host('b', delay_ms=0)
    c = netlab.add_host('c')
    bag = tmp_path / 'impaired'
    run = SplitRun(netlab, lab_env, ['--mode', 'auto', '--duration', '60', '--ns', '/rig1',
                                     '--record', str(bag)], [(a, 'sim'), (b, 'control'), (c, 'recorder')],
                   tmp_path)
    run.start()
    assert run.wait_for_log(1, 'auto/swingup -> auto/catch', timeout=120), run.log_text(1)[-3000:]
    time.sleep(1.0)         # the first stretch (0 ms) is the balance before the faults
    stretches, dropped = [], {}
    for name, delay, loss in (('0 ms', 0, 0), ('1 ms', 1, 0), ('1 % loss', 0, 1), ('5 ms', 5, 0),
                              ('0 ms again', 0, 0)):
        netlab.set_delay(b, delay)
        netlab.set_loss(b, loss)
        t0 = time.time()
        time.sleep(STRETCH_S)
        stretches.append((name, t0 + 0.5, time.time()))
        if loss:
            dropped[name] = netlab.loss_counters(b)     # datagrams dropped, each way
    netlab.set_loss(b, 0)
    run.end_now()           # --duration 60 is a bound: the stretches are over
    t = truth(bag)
    figures = {name: segment_figures(window(t, t0, t1)) for name, t0, t1 in stretches}
    v = judge(read_run(bag))
    print(json.dumps({'stretches': figures, 'nft_dropped': dropped,
                      'verdict': v.as_dict()}, indent=1, default=str))
    assert v.unsafe_samples == 0, v.problems
    assert figures['5 ms']['timeout'] > 0.5, 'commands 10+ samples old must not drive the motor'


# ------------------------------------------------------------------ many rigs
GLOBAL_TOPICS = ('/diagnostics', '/parameter_events', '/rosout', '/clock')


def start_rigs(netlab, tmp_path, rigs, duration: float = 300.0):
    """Each rig (namespace, domain id, initial theta): its simulator on host A, its estimator +
    controller on B, its recorder on C, until stopped (``duration`` is a bound). Returns
    (hosts, {ns: (run, env, bag)})."""
    from support.netrun import lab_env
    a, b, c, placement = split_three(netlab)
    out = {}
    for ns, domain, theta0 in rigs:
        env = lab_env(domain)
        bag = tmp_path / ns.strip('/')
        # ordinary scheduling: separation is the point, not timing, and six loop processes at
        # real-time priority on two CPUs starve the tools of the test (discovery took a minute)
        run = SplitRun(netlab, env, ['--mode', 'off', '--duration', f'{duration:g}', '--ns', ns,
                                     '--theta0', repr(theta0), '--record', str(bag), '--rt-priority', '0'],
                       placement, tmp_path, tag=ns.strip('/'))
        run.start()
        out[ns] = (run, env, bag)
    for ns, (run, _, _) in out.items():
        assert run.wait_for_log(0, 'rig claimed by controller', timeout=180), (ns, run.log_text(0)[-3000:])
    return (a, b, c), out


def stop_rigs(runs: dict) -> None:
    """Stop every rig's run at once (each in its own order: controllers first, the recorder
    last); the rigs share nothing, so one need not wait for another's processes to end."""
    from concurrent.futures import ThreadPoolExecutor
    with ThreadPoolExecutor(len(runs)) as pool:
        list(pool.map(lambda run: run.stop(), [run for run, _, _ in runs.values()]))


def graph_of(netlab, host, env) -> dict:
    p = netlab.run(host, [RWPEND, 'graph', '--json', '--settle', '5'], env=env, timeout=120)
    assert p.returncode == 0, p.stderr[-3000:]
    return json.loads(p.stdout)


def estop_states(bag_dir, ns: str) -> list[bool]:
    """The e-stop states of rig ``ns`` in its bag (its plant's ``estop/state``), in order."""
    from rwpend_bag.analysis import _decode
    return [bool(v) for v in _decode(read_bag(bag_dir), f'{ns}/estop/state')['data']]


def sim_status(bag_dir, ns: str) -> dict:
    return read_run(bag_dir)['diagnostics'][f'{ns}/sim: plant']


def first_pendulum_counts(bag_dir, ns: str) -> tuple[int, int]:
    """(seq, pendulum counts) of the first encoder sample in the bag."""
    from rwpend_bag.analysis import _decode
    enc = _decode(read_bag(bag_dir), f'{ns}/encoders')
    return int(enc['seq'][0]), int(enc['pendulum_counts'][0])


#: Seconds the rigs keep running after an e-stop before they are stopped: three heartbeats of
#: Fast DDS's reliable writers (every 3 s; after two, a slow host's three-rig run had recorded
#: only the first estop/state of the rig it stopped). A recorder on a loaded host drops datagrams
#: at its socket (these bags lose a third of the samples); a latched estop/state lost that way
#: is sent again only after a heartbeat, and never once its writer is gone. A CI run stopped the
#: rigs 1 s after the e-stop, and /rigb's bag held only its first estop/state (False), the likely
#: cause.
AFTER_ESTOP_S = 9.5


def estop(netlab, host, env, ns: str) -> str:
    p = netlab.run(host, [RWPEND, 'estop', '--ns', ns, '--timeout', '60'], env=env, timeout=180)
    assert p.returncode == 0 and 'raised' in p.stdout, p.stdout + p.stderr
    return p.stdout


def check_rig_heard_only_itself(bag_dir, ns: str, theta0: float, topics_of_others: bool) -> dict:
    """The bag of rig ``ns``: its loop ran on its own commands (one controller claimed it, the
    order gates of its command subscription saw one sender), its encoders are its own plant's
    (initial angle); without ``topics_of_others`` no topic or status of another rig is in it."""
    bag = read_bag(bag_dir)
    st = sim_status(bag_dir, ns)
    assert st['claims'] == '1' and st['refused_other_controller'] == '0', (ns, st)
    assert 'senders' not in st['command_order'], (ns, st['command_order'])
    seq0, counts0 = first_pendulum_counts(bag_dir, ns)
    # in one domain the other rig's recorder (record --all) subscribes to this rig's encoders
    # too, and the plant, which holds sample 0 until a recorder listens, may start before its
    # own recorder does: the first samples are then not in this bag
    assert seq0 == 0 or topics_of_others, (ns, seq0)
    if seq0 == 0:
        assert abs(counts0 - round(theta0 * 4000 / (2 * np.pi))) <= 1, (ns, counts0)
    if not topics_of_others:
        foreign = [t for t in bag.topics if t not in GLOBAL_TOPICS and not t.startswith(ns + '/')]
        assert not foreign, (ns, foreign)
        names = set(read_run(bag_dir)['diagnostics'])
        assert all(n.startswith(ns + '/') for n in names), (ns, names)
    return st


@pytest.mark.timeout(900)
def test_three_rigs_separated_by_domain_id_and_namespace(tmp_path, netlab):
    """Three rigs on one subnet, each its own domain id and namespace: every host sees only its
    rig's nodes in each domain, no node of a rig is reached by another rig's publisher, the bags
    hold nothing of the other rigs, and ./rwpend estop --ns /rig2 stops rig 2 only."""
    from rwpend_ros.testenv import test_domain_id
    domains = []
    while len(domains) < 3:
        d = test_domain_id()
        domains += [d] if d not in domains else []
    rigs = [(f'/rig{i}', d, 0.1 * i) for i, d in enumerate(domains, 1)]
    (a, b, c), runs = start_rigs(netlab, tmp_path, rigs)
    # the three domains' graphs seen from B at once (each takes --settle 5 s of discovery)
    from concurrent.futures import ThreadPoolExecutor
    with ThreadPoolExecutor(len(runs)) as pool:
        graphs = dict(zip(runs, pool.map(lambda env: graph_of(netlab, b, env), [e for _, e, _ in runs.values()])))
    for ns, g in graphs.items():
        assert {f'{ns}/sim', f'{ns}/estimator', f'{ns}/controller'} <= set(g), (ns, sorted(g))
        assert all(n.startswith(ns + '/') or n == '/recorder' for n in g), (ns, sorted(g))
    estop(netlab, c, runs['/rig2'][1], '/rig2')
    time.sleep(AFTER_ESTOP_S)
    stop_rigs(runs)
    for ns, domain, theta0 in rigs:
        check_rig_heard_only_itself(runs[ns][2], ns, theta0, topics_of_others=False)
        # the rig's e-stop as its plant latched it (estop/state: reliable and latched, sent again
        # to a recorder that dropped it while its writer lives, AFTER_ESTOP_S; the simulator's
        # last /diagnostics may predate the e-stop in a bag that lost most of its messages)
        states = estop_states(runs[ns][2], ns)
        assert states[-1] == (ns == '/rig2'), (ns, states)


@pytest.mark.timeout(900)
def test_two_rigs_in_one_domain_separated_by_namespace(tmp_path, netlab, lab_env):
    """Two rigs in the same domain, only their namespaces apart: no node of one takes a topic
    from the other (the graph, from every node's subscriptions), each plant obeys its own
    controller only, and ./rwpend estop --ns /rigb stops rig b only."""
    from rwpend_ros.tools import foreign_publishers
    domain = int(lab_env['ROS_DOMAIN_ID'])
    rigs = [('/riga', domain, 0.2), ('/rigb', domain, 0.4)]
    (a, b, c), runs = start_rigs(netlab, tmp_path, rigs)
    g = graph_of(netlab, a, lab_env)
    assert {'/riga/sim', '/rigb/sim', '/riga/controller', '/rigb/controller'} <= set(g), sorted(g)
    # the recorder (record --all) takes every topic of its domain by design: in one domain each
    # rig's bag holds the other rig's topics too (domain ids keep bags apart); no loop node
    # takes anything from the other rig
    loop = [line for line in foreign_publishers(g) if not line.startswith('/recorder <- ')]
    assert loop == [], loop
    estop(netlab, c, lab_env, '/rigb')
    time.sleep(AFTER_ESTOP_S)
    stop_rigs(runs)
    for ns, _, theta0 in rigs:
        check_rig_heard_only_itself(runs[ns][2], ns, theta0, topics_of_others=True)
        # as its plant latched it (estop/state; a fresh-clone run on a loaded host failed on the
        # simulator's last /diagnostics, from before the e-stop, in a bag that held 64 % of the
        # samples, while the latched state in both bags was True for /rigb)
        states = estop_states(runs[ns][2], ns)
        assert states[-1] == (ns == '/rigb'), (ns, states)


# ------------------------------------------------------------------ one controller per rig
@pytest.mark.timeout(900)
def test_two_controllers_on_one_rig_across_hosts(tmp_path, netlab, lab_env):
    """A second controller for the same rig on another host (a student with the wrong
    namespace): the plant obeys the controller that claimed the rig, refuses and counts the
    other's commands and names it on /diagnostics; when the holder stops (it releases the rig,
    or goes silent) the other takes over; ./rwpend estop is accepted from any host."""
    from rwpend_bench.soak import find_process
    # each controller on a host of its own (a controller that stops ends its host's ./rwpend up,
    # and with it whatever else that host ran: the estimator or the recorder)
    a, b, c, d = (netlab.add_host(n) for n in ('a', 'b', 'c', 'd'))
    bag = tmp_path / 'two'
    # --duration: a bound only (the test stops the run); at load 27 start-up and the hand-over
    # took more than 40 s and the plant had ended before the e-stop
    run = SplitRun(netlab, lab_env, ['--mode', 'auto', '--duration', '120', '--ns', '/rig1',
                                     '--composed', 'none', '--record', str(bag)],
                   [(a, 'sim,estimator'), (b, 'controller'), (c, 'controller'), (d, 'recorder')], tmp_path)
    run.start()
    assert run.wait_for_log(0, 'refused: the rig is claimed by', timeout=180), run.log_text(0)[-3000:]
    time.sleep(5.0)      # the claim may change hands while the start-up stalls a controller
    holder = run.log_text(0).split('rig claimed by controller ')[-1].split()[0]
    ids = {part.host.name: run.log_text(i).split('controller id ')[1].split()[0]
           for i, part in enumerate(run.parts) if part.only == 'controller'}
    holder_host = next(h for h, i in ids.items() if i == holder)
    other = next(i for h, i in ids.items() if h != holder_host)
    part = next(p for p in run.parts if p.host.name == holder_host)
    pid = find_process(part.proc.pid, 'rwpend_control.controller_node', timeout=10)
    assert pid is not None
    seen = len(run.log_text(0))
    os.kill(pid, signal.SIGINT)           # the holder stops: it releases the rig
    end = time.monotonic() + 60
    while f'rig claimed by controller {other}' not in run.log_text(0)[seen:] and time.monotonic() < end:
        time.sleep(0.1)
    after = run.log_text(0)[seen:]
    assert f'rig claimed by controller {other}' in after, after[-3000:]
    # handed over by the holder's release (at once) or by the lapse (claim_timeout_samples
    # without a command of the holder): in two runs with the machine at load 17-20 the other
    # claimed the rig by the lapse and no release was seen; not explained yet (a run at lower
    # load across hosts, sim + estimator on A and the controller on B, saw the release)
    released = f'rig released by controller {holder}' in after.split(f'rig claimed by controller {other}')[0]
    print(json.dumps({'handed_over_by': 'release' if released else 'lapse'}))
    estop(netlab, d, lab_env, '/rig1')
    time.sleep(AFTER_ESTOP_S)
    run.stop()
    st = sim_status(bag, '/rig1')
    assert int(st['refused_other_controller']) > 0, st
    assert int(st['releases'] if released else st['claim_lapses']) >= 1, st
    # the other stopped before the plant (run.stop: controllers first): it released the rig too
    assert st['claimed_by'] in (other, 'none') and st['estop'] == 'True', st
    from test_safety_system import diagnostics
    # the plant names the refused controller on /diagnostics: in its values while the holder
    # held the rig, and in the status message unless a graver state took the message (the loop
    # dead, a command timeout: a loaded host), which the failure then shows
    said = f'commands of controller {other} refused: the rig is claimed by {holder}'
    named = [(level, m) for _, name, level, m, v in diagnostics(bag)
             if name == '/rig1/sim: plant' and v.get('intruder') == other and v.get('claimed_by') == holder]
    assert named, f'no /diagnostics of the plant with intruder {other} while {holder} held the rig'
    graver = [m for level, m in named if level == 2 or m.startswith('command timeout')]
    assert any(level == 1 and m == said for level, m in named) or len(graver) == len(named), \
        (said, sorted({m for _, m in named}))


@pytest.mark.timeout(600)
def test_realtime_split_with_the_driver_and_the_emulated_rig(tmp_path, netlab, lab_env):
    """The rig PC (host A): the emulated rig's firmware on a pty and the driver; estimator +
    controller on B, recorder on C. The loop closes across the link: the driver takes the
    controller's commands (it claimed the rig) and the bag holds the driver's encoders and the
    commands; whether it swings up and balances is printed (the serial path has its own tests)."""
    from rwpend_bag.analysis import analyze
    a, b, c = (netlab.add_host(n) for n in ('a', 'b', 'c'))
    link = tmp_path / 'rig'
    emu_log = open(tmp_path / 'emulator.log', 'w')
    netlab.popen(a, [RWPEND, 'emulate', '--link', str(link), '--rt-priority', '60'], env=lab_env,
                 stdout=emu_log, stderr=subprocess.STDOUT)
    end = time.monotonic() + 30
    while not link.exists() and time.monotonic() < end:
        time.sleep(0.1)
    assert link.exists(), 'the emulator did not create its link'
    bag = tmp_path / 'serial_split'
    # --duration 12 (from the driver's first command): > 5000 samples asserted, the swing-up
    # (~4 s) printed
    run = SplitRun(netlab, lab_env, ['--plant', f'serial:{link}', '--mode', 'auto', '--duration', '12',
                                     '--ns', '/rig1', '--record', str(bag)],
                   [(a, 'driver'), (b, 'control'), (c, 'recorder')], tmp_path)
    run.start()
    codes = run.finish(timeout=300)
    emu_log.close()
    assert codes['c'] in (0, 4), run.log_text(2)[-3000:]
    status = read_run(bag)['diagnostics']['/rig1/driver: serial link']
    bagged = read_bag(bag)
    m = analyze(bag)
    print(json.dumps({'swing_up_time_s': m.get('swing_up_time_s'), 'driver': {
        k: status.get(k) for k in ('commands_sent', 'commands_refused', 'timeouts', 'claims',
                                   'refused_other_controller', 'samples', 'samples_lost')}}, indent=1))
    assert status['claims'] == '1' and int(status['commands_sent']) > 1000, status
    assert bagged.topics['/rig1/encoders'].count > 5000 and bagged.topics['/rig1/command'].count > 1000
