"""``./rwpend up`` arguments -> node specs (no process started): priority and CPU affinity."""
from __future__ import annotations

import os

import pytest

from rwpend_bringup.cli import Parser, add_stack_args, build_stack


def specs_of(*argv):
    p = Parser(prog='rwpend up')
    add_stack_args(p)
    specs, _ = build_stack(p.parse_args(list(argv)), p.prog)
    return {s.name: s for s in specs}


def test_rt_priority_and_cpus_go_to_the_environment():
    s = specs_of('--record', '/tmp/x', '--rt-priority', '50', '--cpus', '1:0')
    assert s['sim'].env['RWPEND_RT_PRIORITY'] == '50' and s['recorder'].env['RWPEND_RT_PRIORITY'] == '40'
    assert {s[n].env['RWPEND_CPUS'] for n in ('sim', 'estimator', 'controller')} == {'1'}
    assert s['recorder'].env['RWPEND_CPUS'] == '0'


def test_cpus_without_recorder_part_leaves_the_recorder_free():
    s = specs_of('--record', '/tmp/x', '--cpus', '0')
    assert s['sim'].env['RWPEND_CPUS'] == '0' and 'RWPEND_CPUS' not in s['recorder'].env
    assert 'RWPEND_CPUS' not in specs_of()['sim'].env


def test_cpus_composed():
    s = specs_of('--composed', '--cpus', '0')
    assert s['stack'].env['RWPEND_CPUS'] == '0'


@pytest.mark.parametrize('bad', ['x', ':0', '1:y', str(os.cpu_count() or 1), '0,,1', '-1'])
def test_bad_cpus_refused(bad):
    with pytest.raises(ValueError, match='--cpus'):
        specs_of('--cpus', bad)


def test_composed_layouts():
    s = specs_of('--composed', 'all', '--record', '/tmp/x', '--rt-priority', '50')
    assert list(s) == ['stack', 'recorder'] and s['stack'].args == ['sim', 'estimator', 'controller']
    assert s['stack'].env['RWPEND_RT_PRIORITY'] == '50'
    c = specs_of('--composed', 'control', '--plant', 'serial:/dev/ttyUSB0', '--rt-priority', '50')
    assert list(c) == ['driver', 'control'] and c['control'].args == ['estimator', 'controller']
    assert c['control'].stop_rank < c['driver'].stop_rank, 'the controller stops before the plant'
    assert set(c['control'].node_params) == {'estimator', 'controller'}
    assert c['driver'].env['RWPEND_RT_PRIORITY'] == c['control'].env['RWPEND_RT_PRIORITY'] == '50'
    assert list(specs_of('--composed', 'control', '--no-controller')) == ['sim', 'control']


def test_composed_all_refuses_the_driver():
    with pytest.raises(ValueError, match='--composed control'):
        specs_of('--composed', '--plant', 'serial:/dev/ttyUSB0')


def test_bad_composed_value_refused(capsys):
    with pytest.raises(SystemExit):
        specs_of('--composed', 'everything')
    assert 'invalid choice' in capsys.readouterr().err


def test_cpu_latency_is_validated_before_anything_starts():
    with pytest.raises(ValueError, match='--cpu-latency'):
        specs_of('--cpu-latency', '-1')
    specs_of('--cpu-latency', '0')      # accepted (the request itself is made by run_stack)


def test_cpu_latency_must_be_an_integer(capsys):
    p = Parser(prog='rwpend up')
    add_stack_args(p)
    with pytest.raises(SystemExit) as e:
        p.parse_args(['--cpu-latency', 'fast'])
    assert e.value.code == 2 and '--cpu-latency' in capsys.readouterr().err


@pytest.mark.parametrize('name, bad', [('RWPEND_TRANSPORT', 'tcp'), ('RWPEND_HOST_BUS', 'off'),
                                       ('RWPEND_RECORDER_FAST_PATH', 'yes')])
def test_bad_environment_switch_refused_before_anything_starts(monkeypatch, name, bad):
    monkeypatch.setenv(name, bad)
    with pytest.raises(ValueError, match=name):
        specs_of('--record', '/tmp/x')
