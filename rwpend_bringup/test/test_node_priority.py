"""``./rwpend node X`` gives the node's ``thread_priority`` parameter the real-time priority
``./rwpend up`` gives its processes, unless the user set one or the simulator runs in lockstep."""
from __future__ import annotations

from rwpend_bringup.cli import node_thread_priority, ros_param_overrides, ros_params_files
from rwpend_ros.sched import DEFAULT_RT_PRIORITY


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


def test_lockstep_stays_at_ordinary_priority():
    """A lockstep run goes as fast as its nodes answer: at real-time priority they would take
    both CPUs from everything else."""
    prio, why = node_thread_priority('sim', {'lockstep': True}, allowed)
    assert prio is None and 'lockstep' in why
    assert node_thread_priority('estimator', {'use_sim_time': True}, allowed)[0] is None
    assert node_thread_priority('controller', {'use_sim_time': False}, allowed)[0] == DEFAULT_RT_PRIORITY


def test_parameters_given_after_ros_args_count(tmp_path):
    f = tmp_path / 'p.yaml'
    f.write_text('/**/sim:\n  ros__parameters:\n    lockstep: true\n')
    ros = ['--params-file', str(f), '-p', 'use_sim_time:=true', '-r', '__ns:=/x']
    assert ros_params_files(ros) == [str(f)]
    assert ros_param_overrides(ros) == {'use_sim_time': True}


def test_not_permitted_is_said_and_nothing_is_set():
    prio, why = node_thread_priority('sim', {}, refused)
    assert prio is None and 'not permitted' in why and 'RLIMIT_RTPRIO 0' in why
