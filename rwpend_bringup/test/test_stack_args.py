"""``./rwpend up`` arguments -> node specs (no process started): priority and CPU affinity."""
from __future__ import annotations

import os

import pytest

from rwpend_bringup import stack
from rwpend_bringup.cli import Parser, add_stack_args, stack_from_args
from rwpend_bringup.stack import Stack, plan

#: a bag path that does not exist (plan refuses one that does)
NO_BAG = '/tmp/rwpend-test-no-such-bag'


def plan_of(*argv):
    p = Parser(prog='rwpend up')
    add_stack_args(p)
    return plan(stack_from_args(p.parse_args(list(argv))))


def specs_of(*argv):
    """The processes of ``up ARGV``, separate (``--composed none``) and at ordinary priority
    unless ARGV says otherwise."""
    argv = list(argv)
    if '--composed' not in argv:
        argv += ['--composed', 'none']
    if '--rt-priority' not in argv:
        argv += ['--rt-priority', '0']
    return {s.name: s for s in plan_of(*argv).specs}


def test_rt_priority_and_pins_go_to_the_environment():
    s = specs_of('--record', NO_BAG, '--rt-priority', '50', '--pin', 'sim=1', '--pin', 'recorder=0')
    assert s['sim'].env['RWPEND_RT_PRIORITY'] == '50' and s['recorder'].env['RWPEND_RT_PRIORITY'] == '40'
    assert s['sim'].env['RWPEND_CPUS'] == '1' and s['recorder'].env['RWPEND_CPUS'] == '0'
    assert 'RWPEND_CPUS' not in s['estimator'].env and 'RWPEND_CPUS' not in specs_of()['sim'].env
    # at no priority the recorder is told so (rwpend record alone would take 40 where permitted)
    none = specs_of('--record', NO_BAG)
    assert none['recorder'].env['RWPEND_RT_PRIORITY'] == '0' and 'RWPEND_RT_PRIORITY' not in none['sim'].env


def test_cpus_is_not_an_option(capsys):
    """CPU affinity of the whole stack bought nothing (PERFORMANCE.md, "Evaluated and not
    kept"): --pin sets it per process."""
    with pytest.raises(SystemExit):
        specs_of('--cpus', '0')
    assert 'unrecognized arguments' in capsys.readouterr().err


def test_composed_layouts():
    s = specs_of('--composed', '--record', NO_BAG, '--rt-priority', '50')
    assert list(s) == ['loop'] and s['loop'].args[:3] == ['sim', 'estimator', 'controller']
    assert s['loop'].module == 'rwpend_loop.host' and s['loop'].env['RWPEND_RT_PRIORITY'] == '50'
    c = specs_of('--composed', 'control', '--plant', 'serial:/dev/ttyUSB0', '--rt-priority', '50')
    assert list(c) == ['driver', 'control'] and c['control'].args == ['estimator', 'controller']
    assert c['control'].module == 'rwpend_loop.host'
    assert c['control'].stop_rank < c['driver'].stop_rank, 'the controller stops before the plant'
    assert set(c['control'].node_params) == {'estimator', 'controller'}
    assert c['driver'].env['RWPEND_RT_PRIORITY'] == c['control'].env['RWPEND_RT_PRIORITY'] == '50'
    e = specs_of('--composed', 'control', '--no-controller')
    assert list(e) == ['sim', 'control'] and e['control'].module == 'rwpend_estimation.estimator_node'


def test_control_layout_starts_the_lockstep_simulator_without_a_state_subscriber():
    """The controller of the control process takes the state inside it: the simulator must not
    wait for it to subscribe (it would wait for ever)."""
    loop = specs_of('--lockstep', '--composed', 'none')['sim'].params['start.state_subscribers']
    assert specs_of('--lockstep', '--composed', 'control')['sim'].params['start.state_subscribers'] == loop - 1


@pytest.mark.parametrize('gone', ['all', 'stack'])
def test_a_layout_that_is_not_one_is_refused(capsys, gone):
    with pytest.raises(SystemExit):
        specs_of('--composed', gone)
    assert 'invalid choice' in capsys.readouterr().err


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


@pytest.mark.parametrize('name, bad', [('RWPEND_TRANSPORT', 'tcp')])
def test_bad_environment_switch_refused_before_anything_starts(monkeypatch, name, bad):
    monkeypatch.setenv(name, bad)
    with pytest.raises(ValueError, match=name):
        specs_of('--record', NO_BAG)


def test_pin_sets_one_process():
    s = specs_of('--record', NO_BAG, '--pin', 'sim=0', '--pin', 'controller=1', '--pin', 'recorder=0,1')
    assert s['sim'].env['RWPEND_CPUS'] == '0' and s['controller'].env['RWPEND_CPUS'] == '1'
    assert 'RWPEND_CPUS' not in s['estimator'].env and s['recorder'].env['RWPEND_CPUS'] == '0,1'
    c = specs_of('--composed', 'control', '--pin', 'control=0')
    assert c['control'].env['RWPEND_CPUS'] == '0' and 'RWPEND_CPUS' not in c['sim'].env


@pytest.mark.parametrize('bad, reason', [
    ('sim', 'PROCESS=CPUS'), ('=0', 'PROCESS=CPUS'), ('sim=', 'PROCESS=CPUS'),
    ('recorder=0', "no process 'recorder'"), ('stack=0', "no process 'stack'"),
    (f'sim={os.cpu_count() or 1}', 'may use CPUs'), ('sim=0,,1', 'CPU numbers'), ('sim=a', 'CPU numbers'),
    ('sim=-1', 'CPU numbers')])
def test_bad_pin_refused_with_the_reason(bad, reason):
    with pytest.raises(ValueError, match=reason):
        specs_of('--pin', bad)


def test_pin_twice_refused():
    with pytest.raises(ValueError, match='twice'):
        specs_of('--pin', 'sim=0', '--pin', 'sim=1')


def test_pin_refuses_a_cpu_this_process_may_not_use(monkeypatch):
    monkeypatch.setattr(stack, 'usable_cpus', lambda: {2, 3})      # a container's cgroup
    with pytest.raises(ValueError, match='may use CPUs 2,3 only'):
        specs_of('--pin', 'sim=0')
    assert specs_of('--pin', 'sim=3')['sim'].env['RWPEND_CPUS'] == '3'


def test_set_and_params_keep_the_type_of_what_they_override(tmp_path):
    """rcl keeps the earlier value when a later params file gives another type: refused here."""
    from rwpend_bringup.stack import check_override_types
    check_override_types([], {'sim': {'lockstep_timeout': 2, 'start.delay': 'x'}}, {'rig.g': 10})
    for params, rig, text in (({'sim': {'lockstep_timeout': 'soon'}}, {}, '--set sim.lockstep_timeout:'),
                              ({'sim': {'publish_true_state': 1}}, {}, 'must be true or false'),
                              ({'controller': {'mode': 3}}, {}, 'mode must be a string'),
                              ({'sim': {}}, {'rig.g': 'abc'}, '--set rig.g: rig.g must be a number')):
        with pytest.raises(ValueError, match=text):
            check_override_types([], params, rig)
    f = tmp_path / 'p.yaml'
    f.write_text('/**/sim:\n  ros__parameters:\n    command_timeout_samples: 2.5\n')
    with pytest.raises(ValueError, match=r'p.yaml \(sim\): command_timeout_samples must be an integer'):
        check_override_types([f], {'sim': {}}, {})
    f.write_text('/**/sim:\n  ros__parameters:\n    command_timeout_samples: 5\n')
    check_override_types([f], {'sim': {'command_timeout_samples': 6}}, {})
    with pytest.raises(ValueError, match='-p lockstep_timeout:'):
        check_override_types([], {'sim': {'lockstep_timeout': [1]}}, {}, flag='-p')
    # --set controller.mode=off / -p mode:=off: YAML's false, written as the 'off' the node takes
    params = {'controller': {'mode': False, 'saturation_action': False}}
    check_override_types([], params, {})
    assert params == {'controller': {'mode': 'off', 'saturation_action': 'off'}}
    f.write_text('/**/controller:\n  ros__parameters:\n    mode: off\n')   # a file is not rewritten
    with pytest.raises(ValueError, match="quote the string, 'off'"):
        check_override_types([f], {'controller': {}}, {})


# ---------------------------------------------------------------- --rig / --plant-rig (plant truth apart from the model)
def _heavy(tmp_path, m_p=0.25):
    from rwpend_model.rig import default_rig_file
    f = tmp_path / 'heavy.yaml'
    f.write_text(default_rig_file().read_text().replace('m_p: 0.2164', f'm_p: {m_p}'))
    return f


def test_plant_rig_gives_the_simulator_its_own_truth(tmp_path):
    heavy = _heavy(tmp_path)
    run = plan(Stack(plant_rig=str(heavy), overrides={'rig': {'g': 9.91}}, layout='none'))
    specs, files = run.specs, run.files
    s = {x.name: x for x in specs}
    assert s['sim'].params['rig.m_p'] == 0.25 and s['sim'].params['model_rig.m_p'] == 0.2164
    assert s['sim'].params['rig.g'] == s['sim'].params['model_rig.g'] == 9.91, '--set rig.* goes to every node'
    assert 'rig.m_p' not in s['controller'].params and files[0].endswith('rwpend_model/config/rig.yaml')


def test_rig_file_is_what_every_node_reads(tmp_path):
    heavy = _heavy(tmp_path)
    run = plan(Stack(rig=str(heavy), layout='none'))
    specs, files = run.specs, run.files
    assert files[0] == str(heavy)
    assert {x.name: x for x in specs}['sim'].params['model_rig.m_p'] == 0.25


@pytest.mark.parametrize('args, match', [(['--rig', '/nonexistent.yaml'], '--rig: no such file'),
                                         (['--plant-rig', 'INCOMPLETE'], '--plant-rig: .*missing rig key'),
                                         (['--plant-rig', 'HEAVY', '--plant', 'serial:/dev/ttyUSB0'], 'need the simulator')])
def test_bad_rig_files_refused(tmp_path, args, match):
    heavy = _heavy(tmp_path)
    bad = tmp_path / 'incomplete.yaml'
    bad.write_text('/**:\n  ros__parameters:\n    rig:\n      m_p: 0.3\n')
    args = [str(heavy) if a == 'HEAVY' else str(bad) if a == 'INCOMPLETE' else a for a in args]
    with pytest.raises(ValueError, match=match):
        specs_of(*args)


def defaults_of(*argv):
    run = plan_of(*argv)
    return run.stack, {s.name: s for s in run.specs}, run.notes


def test_defaults_real_time_priority_where_permitted_and_the_layout_of_the_plant(monkeypatch):
    monkeypatch.setattr('rwpend_ros.sched.realtime_permitted', lambda prio: (True, ''))
    a, s, notes = defaults_of('--record', NO_BAG)
    assert a.rt_priority == stack.DEFAULT_RT_PRIORITY and s['loop'].env['RWPEND_RT_PRIORITY'] == '50'
    assert a.layout == stack.DEFAULT_LAYOUT['sim'] == 'loop' and 'loop' in s
    assert any('layout' in n for n in notes) and any('real-time priority: 50' in n for n in notes)
    monkeypatch.setattr('rwpend_ros.sched.realtime_permitted', lambda prio: (False, 'Operation not permitted'))
    a, s, notes = defaults_of()
    assert a.rt_priority == 0 and 'RWPEND_RT_PRIORITY' not in s['loop'].env
    assert any('not permitted here' in n for n in notes)


def test_defaults_lockstep_at_ordinary_priority_explicit_choices_kept(monkeypatch):
    monkeypatch.setattr('rwpend_ros.sched.realtime_permitted', lambda prio: (True, ''))
    a, s, _ = defaults_of('--lockstep')
    assert a.rt_priority == 0
    a, s, notes = defaults_of('--rt-priority', '0', '--composed', 'none')
    assert a.rt_priority == 0 and a.layout == 'none' and {'sim', 'estimator', 'controller'} <= set(s)
    assert not any('real-time priority' in n for n in notes)
    a, s, _ = defaults_of('--composed')
    assert a.layout == 'loop' and list(s) == ['loop']
    a, s, _ = defaults_of('--plant', 'serial:/dev/null')
    assert a.layout == 'loop' and list(s) == ['loop'] and s['loop'].args == ['driver', 'estimator', 'controller']


def test_realtime_permitted_answers_without_changing_this_thread():
    import os
    from rwpend_ros.sched import realtime_permitted
    before = os.sched_getscheduler(0)
    ok, why = realtime_permitted(1)
    assert isinstance(ok, bool) and (ok or why)
    assert os.sched_getscheduler(0) == before


def test_only_runs_a_part_with_the_parameters_of_the_whole_stack():
    whole = specs_of('--lockstep', '--record', NO_BAG)
    part = specs_of('--lockstep', '--record', NO_BAG, '--only', 'sim')
    assert list(part) == ['sim'] and part['sim'].params == whole['sim'].params
    assert part['sim'].params['start.encoders_subscribers'] == 2, 'it waits for the recorder elsewhere'
    two = specs_of('--composed', 'none', '--only', 'estimator,controller')
    assert list(two) == ['estimator', 'controller']
    assert list(specs_of('--composed', 'control', '--only', 'control')) == ['control']


@pytest.mark.parametrize('only', ['bogus', 'sim,bogus', '', 'estimator'])
def test_only_refuses_a_process_the_stack_has_not(only):
    with pytest.raises(ValueError, match='--only'):
        specs_of('--composed', 'control', '--only', only)   # the estimator is in 'control'


def test_only_without_the_recorder_does_not_look_at_the_bag_path(tmp_path):
    taken = tmp_path / 'bag'
    taken.mkdir()
    (taken / 'x').write_text('taken')
    assert list(specs_of('--record', str(taken), '--only', 'sim')) == ['sim']
    with pytest.raises(ValueError, match='already exists'):
        specs_of('--record', str(taken), '--only', 'recorder')


def test_lockstep_gives_the_controller_a_fixed_id():
    a = specs_of('--lockstep', '--composed', 'none')['controller'].params['controller_id']
    assert a == specs_of('--lockstep', '--composed', 'none')['controller'].params['controller_id'] > 0
    assert a < 2**63
    assert 'controller_id' not in specs_of('--composed', 'none')['controller'].params


def test_serial_duration_is_counted_by_the_driver():
    """With a serial plant --duration is the loop's time (the driver counts it from its first
    command), not the launcher's wall clock: a slow start-up does not shorten the run."""
    s = specs_of('--plant', 'serial:/dev/ttyUSB0', '--duration', '14')
    assert s['driver'].params['duration'] == 14.0 and s['driver'].params['port'] == '/dev/ttyUSB0'
    assert 'duration' not in specs_of('--plant', 'serial:/dev/ttyUSB0')['driver'].params


def test_the_loop_layout_is_the_default_on_the_simulator(monkeypatch, tmp_path):
    monkeypatch.setattr('rwpend_ros.sched.realtime_permitted', lambda prio: (True, ''))
    bag = str(tmp_path / 'bag')
    a, s, notes = defaults_of('--lockstep', '--record', bag, '--mode', 'auto')
    assert list(s) == ['loop'] and a.layout == 'loop'
    assert s['loop'].module == 'rwpend_loop.host'
    assert s['loop'].args == ['sim', 'estimator', 'controller', '--record', bag, '--sim-time']
    sim = s['loop'].node_params['sim']
    assert 'lockstep_recorder_window' not in sim and 'start.encoders_subscribers' not in sim
    assert sim['start.state_subscribers'] == 1, 'the controller; the recorder is in the process'
    assert s['loop'].node_params['controller']['mode'] == 'auto'
    # real time: the recorder in the loop's process too (its bag written by a child process
    # below the loop: rwpend_bag.procwriter), log times on the wall clock
    a, s, _ = defaults_of('--record', bag)
    assert list(s) == ['loop'] and s['loop'].args == ['sim', 'estimator', 'controller', '--record', bag]
    assert 'start.encoders_subscribers' not in s['loop'].node_params['sim']
    assert s['loop'].env['RWPEND_RT_PRIORITY'] == '50'
    # a split stack keeps its layout
    assert set(defaults_of('--only', 'sim')[1]) == {'sim'}


def test_the_loop_layout_is_the_default_on_the_rig(monkeypatch, tmp_path):
    """The driver is the loop's plant (rwpend_loop.rig); it counts the listeners of its process
    itself, so the recorder's start.encoders_subscribers stays."""
    monkeypatch.setattr('rwpend_ros.sched.realtime_permitted', lambda prio: (True, ''))
    bag = str(tmp_path / 'bag')
    a, s, notes = defaults_of('--plant', 'serial:/dev/null', '--record', bag)
    assert a.layout == 'loop' and list(s) == ['loop'] and s['loop'].module == 'rwpend_loop.host'
    assert s['loop'].args == ['driver', 'estimator', 'controller', '--record', bag]
    assert s['loop'].node_params['driver']['start.encoders_subscribers'] == 2
    assert s['loop'].node_params['driver']['port'] == '/dev/null'
    assert s['loop'].env['RWPEND_RT_PRIORITY'] == '50'
    # split across hosts, and the other layouts on request
    assert set(defaults_of('--plant', 'serial:/dev/null', '--only', 'driver')[1]) == {'driver'}
    assert defaults_of('--plant', 'serial:/dev/null', '--composed', 'control')[0].layout == 'control'


@pytest.mark.parametrize('plant', ['sim', 'serial:/dev/null'])
def test_a_plant_without_the_controller_waits_for_the_recorder_of_command(tmp_path, plant):
    """The controller in another process: the recorder subscribes to command only once it has
    seen the controller's publisher, which may be seconds after it subscribed to the samples (a
    bag whose commands began 2.9 s after its samples); the plant's first sample waits for it.
    The loop's own process records the commands it writes: nothing to wait for there."""
    bag = str(tmp_path / 'bag')
    name = 'sim' if plant == 'sim' else 'driver'
    for layout, n in (('control', 1), ('none', 2)):     # none: the estimator subscribes to command too
        s = specs_of('--plant', plant, '--composed', layout, '--record', bag)
        assert s[name].params['start.command_subscribers'] == n
        assert 'start.command_subscribers' not in specs_of('--plant', plant, '--composed', layout)[name].params
    assert 'start.command_subscribers' not in specs_of('--plant', plant, '--composed', 'control', '--record', bag,
                                                       '--no-controller')[name].params
    s = specs_of('--plant', plant, '--composed', 'loop', '--record', bag)
    assert 'start.command_subscribers' not in s['loop'].node_params[name]
