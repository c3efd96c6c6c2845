"""``./rwpend node X`` gives the node's ``thread_priority`` parameter the real-time priority
``./rwpend up`` gives its processes, unless the user set one or the simulator runs in lockstep."""
from __future__ import annotations

from rwpend_bringup.cli import node_thread_priority
from rwpend_bringup.stack import DEFAULT_RT_PRIORITY


def allowed(priority):
    return True, ''


def refused(priority):
    return False, 'RLIMIT_RTPRIO 0'


def test_real_time_by_default_where_permitted():
    for name in ('sim', 'estimator', 'controller', 'driver'):
        prio, why = node_thread_priority(name, {}, allowed)
        assert prio == DEFAULT_RT_PRIORITY and 'thread_priority:=0' in why


def test_what_the_user_gave_wins():
    assert node_thread_priority('controller', {'thread_priority': 0}, allowed)[0] is None
    assert node_thread_priority('sim', {'thread_priority': 70}, allowed) == (None, 'thread_priority 70 (given)')


def test_a_lockstep_simulator_stays_at_ordinary_priority():
    prio, why = node_thread_priority('sim', {'lockstep': True}, allowed)
    assert prio is None and 'lockstep' in why
    # lockstep is the simulator's parameter: the other nodes answer it and keep the default
    assert node_thread_priority('estimator', {'lockstep': True}, allowed)[0] == DEFAULT_RT_PRIORITY


def test_not_permitted_is_said_and_nothing_is_set():
    prio, why = node_thread_priority('sim', {}, refused)
    assert prio is None and 'not permitted' in why and 'RLIMIT_RTPRIO 0' in why
