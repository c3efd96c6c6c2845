"""The rig run's arming call and end, on a wall clock of our own (no ROS)."""
from __future__ import annotations

from rwpend_lab.arming import Arming


def test_armed_run_lasts_its_duration_from_the_answer_and_waits_for_the_last_sample():
    a = Arming(2.0)
    a.ask(1000, now=10.0)
    assert not a.unanswered(10.4)
    assert a.answered(True, '', 'balance', now=10.6) == 'armed'
    assert a.armed_seq == 1000 and a.end_wall == 12.6
    a.steps_done(12.0)
    assert not a.over(12.5, command_seq=4000, end_seq=3000)     # the run's time is not over
    assert not a.over(12.7, command_seq=2999, end_seq=3000)     # the controller lags the plant
    assert a.over(12.7, command_seq=3000, end_seq=3000)
    assert a.over(17.1, command_seq=10, end_seq=3000)           # waited CATCH_UP_S for it


def test_an_unanswered_call_is_made_again_every_resend_s():
    a = Arming(1.0)
    a.ask(5, now=0.0)
    assert [a.unanswered(t) for t in (0.3, 0.51, 0.8, 1.02)] == [False, True, False, True]
    assert a.retries == 2
    a.steps_done(0.5)
    assert not a.over(9.0, 10, 1)        # a call pending: not over


def test_a_refusal_is_retried_for_retry_s_then_is_the_error():
    a = Arming(1.0)
    a.ask(5, now=0.0)
    assert a.answered(False, 'not upright', 'balance', now=0.2) == 'again'
    assert a.answered(False, 'not upright', 'balance', now=0.9) == 'again'
    assert a.answered(False, 'not upright', 'balance', now=1.1) == 'refused'
    assert a.error == "the controller refused mode 'balance': not upright"
    assert a.retries == 2 and a.end_wall is None
    a.steps_done(1.2)
    assert not a.over(100.0, 10, 1)      # a refused run is not "over": it failed


def test_a_run_without_arming_ends_with_its_steps():
    a = Arming(1.0)
    assert not a.over(0.0, 0, 10)
    a.steps_done(1.0)
    a.steps_done(3.0)                    # the first time counts
    assert a.steps_done_at == 1.0
    assert a.over(1.1, 10, 10) and not a.over(1.1, 9, 10) and a.over(6.1, 9, 10)
