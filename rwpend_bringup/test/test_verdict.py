"""rwpend_bringup.verdict: a run whose loop died or whose bag is much shorter fails, with the reason."""
from __future__ import annotations

from rwpend_bringup.verdict import EXIT_LOOP_DEAD, dead_nodes, expected_samples, recording_problems


def report(received, missing=0, gaps=0, **extra):
    return {'topics': {'/rwpend/encoders': {'received': received, 'missing': 0},
                       '/rwpend/state': {'received': received, 'missing': missing, 'gap_count': gaps},
                       '/diagnostics': {'received': 3}}, **extra}


def test_dead_nodes_are_those_with_the_loop_dead_status():
    assert dead_nodes({'sim': EXIT_LOOP_DEAD, 'controller': 0, 'recorder': 1}) == ['sim']
    assert dead_nodes({'sim': 0}) == []


def test_a_bag_much_shorter_than_the_run_is_a_problem():
    problems, warnings = recording_problems(report(710), 14000)
    assert len(problems) == 1 and '710 of the run\'s 14000 samples' in problems[0] and not warnings
    assert recording_problems(report(13990), 14000) == ([], [])
    assert recording_problems(report(10), None) == ([], [])          # not judged


def test_missing_messages_are_warned_and_a_writer_error_is_a_problem():
    problems, warnings = recording_problems(report(14000, missing=12, gaps=2, writer_error='disk full'), 14000)
    assert problems == ['the bag writer failed: disk full']
    assert warnings == ['/rwpend/state: 12 message(s) missing in 2 gap(s)']


def test_expected_samples_follow_the_duration_unless_the_run_was_stopped():
    assert expected_samples(0.001, 40.0, True, 30.0) == 40000            # lockstep, ran to the end
    assert expected_samples(0.001, 40.0, True, 12.0, interrupted=True) is None
    assert expected_samples(0.001, None, True, 50.0) is None
    assert expected_samples(0.001, 40.0, False, 46.0) == 40000           # real time, ran to the end
    assert expected_samples(0.001, 40.0, False, 25.0, interrupted=True) == 20000   # Ctrl-C at 25 s
    assert expected_samples(0.001, None, False, 25.0) == 20000
    assert expected_samples(0.001, None, False, 8.0) is None              # too short to judge
