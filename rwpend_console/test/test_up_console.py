"""``./rwpend up --console``: the console as a process of the stack (no process started)."""
import pytest

from rwpend_bringup.cli import Parser, add_stack_args, stack_from_args
from rwpend_bringup.stack import plan


def specs_of(*argv):
    """The processes of ``up ARGV``, separate (``--composed none``) and at ordinary priority
    unless ARGV says otherwise."""
    argv = list(argv)
    if '--composed' not in argv:
        argv += ['--composed', 'none']
    if '--rt-priority' not in argv:
        argv += ['--rt-priority', '0']
    p = Parser(prog='rwpend up')
    add_stack_args(p)
    return {s.name: s for s in plan(stack_from_args(p.parse_args(argv))).specs}


def test_the_console_is_a_process_of_the_stack_not_of_the_loop():
    s = specs_of('--console', '--rt-priority', '50', '--pin', 'sim=0')
    c = s['console']
    assert c.module == 'rwpend_console.console' and not c.ros_args
    assert c.args == ['--ns', '/rwpend', '--listen', '127.0.0.1', '--port', '8080']
    assert c.env == {'RWPEND_RT_PRIORITY': '10'}, 'below the loop (50) and the recorder (40); no pinning'
    assert not c.required, 'in real time a console that fails leaves the rig running'
    assert 'console' not in specs_of()


def test_in_lockstep_the_run_waits_for_the_page():
    without = specs_of('--lockstep')['sim'].params['start.state_subscribers']
    s = specs_of('--lockstep', '--console', '0.0.0.0:9000', '--ns', '/rig2')
    assert s['sim'].params['start.state_subscribers'] == without + 1
    assert s['console'].required and s['console'].args == ['--ns', '/rig2', '--listen', '0.0.0.0', '--port', '9000']
    assert s['console'].env == {'RWPEND_RT_PRIORITY': '0'}, 'lockstep: ordinary priority'
    composed = specs_of('--lockstep', '--composed', '--console')
    assert composed['loop'].node_params['sim']['start.state_subscribers'] == without + 1


@pytest.mark.parametrize('bad', ['port', '0.0.0.0:', '1.2.3.4.5:80', '70000'])
def test_bad_console_addresses_are_refused(bad):
    with pytest.raises(ValueError, match='--console'):
        specs_of('--console', bad)


def test_pin_does_not_know_the_console():
    with pytest.raises(ValueError, match='no process'):
        specs_of('--console', '--pin', 'console=0')
