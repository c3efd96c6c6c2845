"""rwpend_ros.health.LoopHealth: the plant's verdicts on the loop (dead, alive, slow)."""
from __future__ import annotations

import pytest

from rwpend_ros.health import LoopHealth


def test_no_verdict_before_the_first_command():
    h = LoopHealth(0.001, dead_after_s=0.01, check_after_s=0.01)
    assert all(h.sample(late=True, timed_out=True) is None for _ in range(100))
    assert not h.dead and h.samples == 0


def test_dead_after_the_timeout_held_then_alive_again():
    h = LoopHealth(0.001, dead_after_s=0.005, check_after_s=1.0)
    h.command()
    events = [h.sample(False, True) for _ in range(10)]
    assert events.count('dead') == 1 and events.index('dead') == 4 and h.dead
    assert 'no fresh command for' in h.dead_reason()
    assert h.command() == 'alive' and not h.dead
    assert [h.sample(False, False) for _ in range(3)] == [None] * 3
    assert h.deaths == 1 and h.longest_dead_s == pytest.approx(0.010)


def test_a_short_timeout_is_not_death():
    h = LoopHealth(0.001, dead_after_s=0.005, check_after_s=1.0)
    h.command()
    for _ in range(4):
        assert h.sample(False, True) is None
    assert h.command() is None and not h.dead


def test_first_window_verdict_slow_or_not():
    ok = LoopHealth(0.001, check_after_s=0.1, late_limit=0.01)
    ok.command()
    assert [ok.sample(k == 50, False) for k in range(100)].count('slow') == 0   # 1 % late: fine
    assert ok.checked and '1.00 %' in ok.verdict
    slow = LoopHealth(0.001, check_after_s=0.1, late_limit=0.01)
    slow.command()
    events = [slow.sample(k % 10 == 0, False) for k in range(200)]
    assert events.count('slow') == 1 and events.index('slow') == 99            # once, at the end of the window
    assert slow.values()['loop_late_percent'] == '10.000'


def test_bad_settings_refused():
    with pytest.raises(ValueError):
        LoopHealth(0.0)
    with pytest.raises(ValueError):
        LoopHealth(0.001, late_limit=2.0)


def test_a_sample_on_another_clock_is_said_with_what_to_do():
    from rwpend_ros.health import other_clock
    wall = 1_796_660_000.0
    assert other_clock(wall - 0.004, wall) is None and other_clock(wall + 30.0, wall) is None
    why = other_clock(12.345, wall)                   # a lockstep simulator's sim time
    assert why.startswith('samples are stamped 12.345 s, 1796659988 s behind this node\'s clock')
    assert 'use_sim_time:=true' in why
    assert 'ahead of' in other_clock(wall + 120.0, wall)
    # a node on sim time (no /clock yet: its time 0) beside a plant on the wall clock
    why = other_clock(wall, 0.0, sim_time=True)
    assert 'ahead of' in why and 'without use_sim_time' in why


def test_lockstep_dead_span_is_said_in_samples_and_simulated_seconds():
    # lockstep: h is lockstep_timeout (the wall time a sample without a command may cost), but a
    # run whose controller is gone does not wait: the span is said on the simulated clock
    h = LoopHealth(0.5, dead_after_s=2.0, check_after_s=100.0)
    h.command()
    for _ in range(1500):
        h.sample(True, True)
    assert h.dead and '1500 samples (1.500 s simulated)' in h.dead_reason(lockstep_h=0.001)
    assert h.values(lockstep_h=0.001)['loop_longest_dead_s'] == '1.500'
    assert h.values()['loop_longest_dead_s'] == '750.000' and '750.0 s' in h.dead_reason()
