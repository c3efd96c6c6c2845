"""Sample/command alignment of the estimator node (pure, no ROS)."""
import math

import pytest

from rwpend_estimation.alignment import CommandAlignment


def present():
    return True


def absent():
    return False


def test_sample_waits_for_the_command_of_the_sample_before():
    a = CommandAlignment(10.0)
    assert a.sample(0, 's0', present) == [(0, 's0')]        # nothing answered yet: seq 0 goes
    assert a.input_for(0) == 0.0
    assert a.sample(1, 's1', present) == []                  # a controller publishes: waits
    assert a.command(0, 2.5) == (1, 's1')                    # command 0 releases sample 1
    assert a.input_for(1) == 2.5
    assert a.sample(2, 's2', present) == []
    assert a.sample(3, 's3', present) == [(2, 's2')]         # sample 3 came first: 2 goes, 3 waits
    assert a.input_for(2) == 2.5                             # held: no command answered 1
    assert a.command(2, -1.0) == (3, 's3') and a.input_for(3) == -1.0
    assert a.deferred == 3


def test_no_wait_without_a_controller_or_far_behind():
    a = CommandAlignment(10.0)
    calls = []

    def nobody():
        calls.append(1)
        return False
    assert a.sample(1, 's1', nobody) == [(1, 's1')] and calls == [1]
    a.command(1, 1.0)
    assert a.sample(10, 's10', nobody) == [(10, 's10')]      # 8 samples behind: no wait
    assert calls == [1]                                       # asked only before the first command
    assert a.sample(3, 's3', present) == []                  # within 3 of the newest answer: waits
    assert a.deferred == 1


def test_command_for_picks_by_seq_not_arrival():
    a = CommandAlignment(10.0)
    for seq, u in ((5, 5.0), (3, 3.0), (4, 4.0)):
        a.command(seq, u)
    assert a.command_for(5) == 4.0 and a.command_for(6) == 5.0 and a.command_for(4) == 3.0
    assert a.command_for(9) == 5.0                            # held by the amplifier
    assert a.command_for(3) == 0.0                            # nothing answered an earlier sample


def test_commands_clamped_refused_and_bounded():
    a = CommandAlignment(10.0, keep=8)
    a.command(0, 25.0)
    assert a.u == 10.0 and a.command_for(1) == 10.0
    a.command(1, -1e9)
    assert a.command_for(2) == -10.0
    with pytest.raises(ValueError, match='non-finite'):
        a.command(2, math.nan)
    assert 2 not in a.commands and a.u_seq == 1
    for k in range(100):
        a.command(k, 0.1)
    assert len(a.commands) == 8


def test_restart_clears_the_old_commands():
    a = CommandAlignment(10.0)
    for k in range(100, 110):
        a.sample(k, k, absent)
        a.input_for(k)
        a.command(k, 7.0)
    assert a.sample(0, 'restart', present) == [(0, 'restart')]   # newer commands: no wait
    assert a.input_for(0) == 0.0 and a.restarts == 1 and a.u_seq == -1 and not a.commands
    assert a.sample(1, 's1', present) == []                      # waits for the new command 0


def test_invalid_settings_refused():
    for args in ((0.0,), (math.nan,), (10.0, -1), (10.0, 3, 0)):
        with pytest.raises(ValueError):
            CommandAlignment(*args)
