"""The registry of the book's 20 experiments, the CLI's input checks, the procedures."""
from __future__ import annotations

from pathlib import Path

import pytest

from rwpend_control.user_law import LawState, load_law
from rwpend_lab.cli import main, parse_numbers
from rwpend_lab.experiment import NEEDS, LabError, Options
from rwpend_lab.procedures import OpenLoop, WheelSpeedSteps
from rwpend_lab.registry import EXPERIMENTS
from rwpend_model.rig import load_rig

RIG = load_rig()
TEMPLATES = Path(__file__).resolve().parents[1] / 'rwpend_lab' / 'templates'


def test_twenty_experiments_in_the_books_order_each_with_runs():
    assert list(EXPERIMENTS) == list(range(1, 21))
    for n, e in EXPERIMENTS.items():
        runs = e.plan(RIG, Options())
        assert runs and len({r.name for r in runs}) == len(runs), n
        assert all(r.duration > 0 for r in runs)
        assert set(e.needs) <= set(NEEDS), n
        assert e.title and e.section and e.questions, n


def test_law_experiments_have_a_template_and_a_student_run():
    with_law = [n for n, e in EXPERIMENTS.items() if e.template]
    assert {7, 8, 10, 11, 12, 13, 16} <= set(with_law)
    for n in with_law:
        e = EXPERIMENTS[n]
        assert (TEMPLATES / e.template).is_file()
        runs = e.plan(RIG, Options(law='/tmp/mylaw.py'))
        assert any(r.law == '/tmp/mylaw.py' and r.mode == 'law' for r in runs), n


def test_templates_load_and_say_what_to_write():
    for f in TEMPLATES.glob('*.py'):
        law = load_law(str(f), {'kpp': -145.0, 'kdp': -16.0, 'kdr': 0.1, 'ki': 0.0, 'times': [0.0],
                                'refs': [0.0], 'c_e': 1.0, 'c_v': 1.0, 'e_ref': 2.0, 'kpr': 1.0, 'ref': 0.0}, RIG)
        with pytest.raises(Exception, match='write|return'):
            law(LawState(0.0, 3.14, 0.0, 0.0, 0.0, 0.0))


def test_bad_experiment_numbers_and_options_are_refused():
    assert parse_numbers('4-6') == [4, 5, 6] and parse_numbers('all') == list(range(1, 21))
    for bad in ('0', '21', 'x', '7-30', '5-4'):
        with pytest.raises(LabError):
            parse_numbers(bad)
    with pytest.raises(LabError, match='no law of your own'):
        EXPERIMENTS[1].plan(RIG, Options(law='/tmp/x.py'))


def test_cli_errors_are_clear(capsys, tmp_path):
    assert main(['run', '42']) == 2
    assert 'no experiment 42' in capsys.readouterr().err
    assert main(['run', '1', '--set', 'nonsense']) == 2
    assert 'NODE.PARAM=VALUE' in capsys.readouterr().err
    assert main(['run', '1', '--set', 'rig.g=-1']) == 2
    assert 'rig.g' in capsys.readouterr().err
    assert main(['run', '12', '--law', str(tmp_path / 'none.py')]) == 2
    assert 'no such file' in capsys.readouterr().err
    bad = tmp_path / 'bad.py'
    bad.write_text('def control(state, params)\n    return 0\n')
    assert main(['run', '12', '--law', str(bad), '--out', str(tmp_path / 'o')]) == 2
    assert 'SyntaxError' in capsys.readouterr().err
    assert main(['run', '1', '--plant', 'usb']) == 2
    assert main(['list']) == 0 and 'Friction compensation' in capsys.readouterr().out
    assert main(['template', '1']) == 2
    (tmp_path / 'file').write_text('mine')
    assert main(['run', '1', '--out', str(tmp_path / 'file')]) == 2
    assert 'exists and is not a directory' in capsys.readouterr().err
    assert (tmp_path / 'file').read_text() == 'mine'


def test_procedures_follow_their_schedules():
    ol = OpenLoop({'times': [0.0, 0.02], 'values': [5.0, 0.0]})
    assert [ol(LawState(t, 0, 0, 0, 0, 0)) for t in (0.0, 0.019, 0.02, 1.0)] == [5.0, 5.0, 0.0, 0.0]
    pi = WheelSpeedSteps({'kdr': 0.1, 'ki': 0.0, 'times': [0.0, 1.0], 'refs': [10.0, 20.0], 'u_max': 10.0})
    assert pi(LawState(0.5, 0, 0, 0, 0.0, 0)) == pytest.approx(1.0)
    assert pi(LawState(1.5, 0, 0, 0, 0.0, 0)) == pytest.approx(2.0)


def test_every_prompt_has_a_detector():
    from rwpend_lab.manual import DETECTORS
    for n, e in EXPERIMENTS.items():
        for r in e.plan(RIG, Options()):
            for p in r.prompts:
                assert p.detect in DETECTORS, (n, r.name, p.detect)


def test_the_rig_path_refuses_a_port_that_is_not_there(tmp_path, capsys):
    assert main(['run', '1', '--plant', f'serial:{tmp_path}/no_tty', '--out', str(tmp_path / 'r')]) == 2
    assert 'no_tty does not exist' in capsys.readouterr().err
    assert not (tmp_path / 'r' / 'runs').exists()
