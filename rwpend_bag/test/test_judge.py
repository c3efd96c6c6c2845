"""rwpend_bag.judge: the verdict of a run from its bag, on synthetic runs (no ROS)."""
from __future__ import annotations

import numpy as np

from rwpend_bag.judge import judge, seq_gaps

H = 0.001


def run(theta, u=None, command_seq=None, drop=(), state_until=None):
    n = len(theta)
    seq = np.arange(n)
    t = seq * H
    u = np.concatenate([[0.0], np.ones(n - 1)]) if u is None else np.asarray(u, float)  # no command before 0
    truth = {'stamp': t + 100.0, 'seq': seq, 'theta': np.asarray(theta, float), 'u_commanded': u,
             'command_seq': seq - 1 if command_seq is None else np.asarray(command_seq),
             'command_timeout': np.zeros(n, bool)}
    keep = np.ones(n, bool)
    for a, b in drop:
        keep[a:b + 1] = False
    end = n if state_until is None else state_until
    state = {'stamp': (t + 100.0)[keep][:end], 'seq': seq[keep][:end], 'resyncs': np.zeros(keep.sum())[:end]}
    command = {'stamp': (t + 100.0)[keep], 'seq': seq[keep]}
    gaps = seq_gaps(seq[keep])
    missing = sum(b - a + 1 for a, b in gaps)
    report = {'topics': {'/r/state': {'gap_count': len(gaps), 'missing': missing}}}
    return {'truth': truth, 'state': state, 'command': command,
            'topics': {'truth': '/r/sim/true_state', 'state': '/r/state', 'command': '/r/command'},
            'report': report}


def up_then(n_up, n_after, after_theta):
    return np.concatenate([np.full(n_up, np.pi), np.full(n_after, after_theta)])


def test_balanced_to_the_end_is_alive():
    v = judge(run(np.full(10_000, np.pi + 0.05)))
    assert v.alive_at_end and v.catches == 1 and v.falls == 0 and not v.problems


def test_a_fall_then_a_recovery_is_counted_with_its_time():
    theta = np.concatenate([np.full(3000, np.pi), np.full(2000, 0.0), np.full(6000, np.pi)])
    v = judge(run(theta))
    assert v.falls == 1 and v.recoveries == 1 and v.recover_s == [2.0] and v.alive_at_end


def test_dead_at_the_end_and_a_latched_estimator():
    v = judge(run(up_then(5000, 5000, 0.0), state_until=5000))
    assert not v.alive_at_end and v.falls == 1 and v.recoveries == 0
    assert v.latched == ['state'] and any('state stopped' in p for p in v.problems)


def test_a_stale_command_driving_the_motor_is_unsafe():
    n = 5000
    cs = np.arange(n) - 1
    cs[2000:2010] = 1995                       # held a command 4..13 samples old, u != 0
    v = judge(run(np.full(n, np.pi), command_seq=cs))
    assert v.unsafe_samples == 10 and abs(v.first_unsafe_s - 2.000) < 1e-9
    u = np.ones(n)
    u[0] = 0.0
    u[2000:2010] = 0.0                         # ... at zero it is fine
    assert judge(run(np.full(n, np.pi), u=u, command_seq=cs)).unsafe_samples == 0


def test_gaps_must_be_those_the_report_lists():
    r = run(np.full(8000, np.pi), drop=[(1000, 1099), (5000, 5009)])
    v = judge(r)
    assert v.gaps['/r/state'] == {'seen': 2, 'missing': 110, 'reported': 2, 'reported_missing': 110}
    assert not v.unaccounted
    r['report']['topics']['/r/state']['missing'] = 100
    v = judge(r)
    assert v.unaccounted == ['/r/state'] and any('the report says' in p for p in v.problems)


def test_seq_gaps():
    assert seq_gaps([0, 1, 2, 5, 6, 9]) == [(3, 4), (7, 8)]
    assert seq_gaps([3, 3, 2, 4]) == []        # duplicates / a step back are no gaps
    assert seq_gaps([0, 5, 3, 4, 9]) == [(1, 4), (6, 8)]
    assert seq_gaps([]) == []


def test_timing_counts_late_and_zero_samples_from_the_first_command():
    n = 1000
    cs = np.arange(n) - 1
    cs[:5] = -1                                # before the first command: not counted
    cs[100:103] = 98                           # held the command of 98 over 3 intervals: 3 late
    cs[500:504] = -1                           # the timeout held the motor at 0
    u = np.ones(n)
    u[:5] = 0.0
    u[500:504] = 0.0
    v = judge(run(np.full(n, np.pi), u=u, command_seq=cs))
    assert v.samples == n and v.timed_samples == n - 5
    assert v.late_samples == 3 and v.zero_samples == 4
    assert 'late 3 = 0.302 %' in v.timing() and 'at zero 4' in v.timing()


def test_the_command_line_reads_bags_and_says_when_one_cannot_be_read(tmp_path, capsys):
    from rwpend_bag.judge import main
    assert main([str(tmp_path / 'no-such-bag')]) == 2
    assert 'cannot be read' in capsys.readouterr().err


def rig_run(theta, command_seq=None, u=None, state_every=1):
    """A rig run: no sim/true_state; the device's applied commands and the estimator's angle."""
    r = run(theta, u=u, command_seq=command_seq)
    truth = r.pop('truth')
    r['topics'].pop('truth')
    r['applied'] = {'stamp': truth['stamp'], 'seq': truth['seq'], 'command_seq': truth['command_seq'],
                    'u': truth['u_commanded']}
    keep = np.arange(len(theta)) % state_every == 0
    r['state'] = {'stamp': truth['stamp'][keep], 'seq': truth['seq'][keep],
                  'theta': truth['theta'][keep], 'resyncs': np.zeros(keep.sum())}
    r['command'] = {'stamp': truth['stamp'], 'seq': truth['seq']}
    return r


def test_a_rig_run_is_judged_from_the_device_and_the_estimate():
    n = 10_000
    cs = np.arange(n) - 1
    cs[5000:5010] -= 1                      # 10 commands that came one sample late
    v = judge(rig_run(np.full(n, np.pi + 0.05), command_seq=cs, state_every=3))
    assert v.source.startswith('applied') and v.samples == n and v.alive_at_end
    assert v.late_samples == 10 and v.zero_samples == 0 and v.unsafe_samples == 0
    v = judge(rig_run(up_then(5000, 5000, 0.0)))
    assert v.falls == 1 and not v.alive_at_end


def test_a_bag_without_the_plant_side_says_so():
    r = rig_run(np.full(100, np.pi))
    del r['applied']
    v = judge(r)
    assert v.problems == ['neither sim/true_state nor applied with state in the bag: nothing to judge']


def test_a_rosbag2_directory_named_like_a_ros1_bag_is_read(tmp_path):
    # rosbags' AnyReader takes any path ending in .bag for a ROS 1 bag; ``up --record run.bag``
    # writes a rosbag2 directory of that name
    import shutil
    from pathlib import Path

    from rwpend_bag.judge import read_run
    ref = Path(__file__).resolve().parents[2] / 'bags' / 'reference' / 'swingup_tap'
    named = tmp_path / 'run.bag'
    shutil.copytree(ref, named)
    a, b = read_run(ref), read_run(named)
    assert a['topics'] == b['topics'] and a['topics']
    for key in a['topics']:
        assert all(np.array_equal(a[key][f], b[key][f]) for f in a[key])
