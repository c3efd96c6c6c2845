"""The priority ``rwpend record`` takes (rwpend_bag.cli.recorder_priority): pure, the permission
given as a function."""
from __future__ import annotations

from rwpend_bag.cli import recorder_priority


def permitted(prio):
    return True, ''


def refused(prio):
    return False, 'Operation not permitted'


def test_alone_in_real_time_it_takes_ten_below_the_nodes():
    prio, why = recorder_priority(None, None, False, permitted)
    assert prio == 40 and 'SCHED_FIFO 40' in why and '--rt-priority 0' in why


def test_where_not_permitted_it_says_so_and_stays_ordinary():
    prio, why = recorder_priority(None, '', False, refused)
    assert prio is None and 'not permitted here (Operation not permitted)' in why


def test_given_or_set_by_the_launcher_or_lockstep_wins():
    assert recorder_priority(30, '40', False, refused) == (30, 'SCHED_FIFO 30 (--rt-priority)')
    assert recorder_priority(0, None, False, permitted)[0] == 0
    prio, why = recorder_priority(None, '0', False, permitted)          # ./rwpend up at no priority
    assert prio is None and 'RWPEND_RT_PRIORITY=0' in why
    prio, why = recorder_priority(None, None, True, permitted)          # --sim-time: lockstep
    assert prio is None and 'ordinary' in why
