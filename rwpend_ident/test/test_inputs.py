"""Bad input gets a clear error and changes nothing else: bags without the needed topics or not of
the identification, rig files with missing or unknown keys, options that do not go together, a
refused step; and the verdicts of --check (no ROS)."""
from __future__ import annotations

import re

import numpy as np
import pytest

from support import synth
from rwpend_ident import cli
from rwpend_ident.check import compare
from rwpend_ident.identify import Identification, check_runs
from rwpend_ident.models import IDENTIFIED, model_values
from rwpend_ident.plan import plan
from rwpend_ident.records import IdentError
from rwpend_ident.rigfile import example_rig_file
from rwpend_ident.session import load_bags
from rwpend_control.status_codes import FAULT_BAD_STATE, FAULT_LAW, FAULT_STALE_STATE
from rwpend_lab.data import RunData
from rwpend_model.rig import default_rig_file, load_rig, load_rig_file

BASE = load_rig()
RUNS = plan(BASE)


def _bag(path, topics):
    records = [r for r in synth.make_run(duration=1.0) if r[0] in topics]
    synth.write_ours(path, records)


def test_a_bag_without_commands_is_refused(tmp_path):
    _bag(tmp_path / 'swing', {'/rwpend/encoders'})
    with pytest.raises(IdentError, match='swing: no commands in the recording'):
        load_bags([tmp_path / 'swing'], RUNS, BASE)


def test_a_bag_without_encoders_is_refused(tmp_path):
    _bag(tmp_path / 'swing', {'/rwpend/command'})
    with pytest.raises(IdentError, match='no encoder samples .* needs the topics encoders and command'):
        load_bags([tmp_path / 'swing'], RUNS, BASE)


def test_a_bag_that_is_not_a_run_of_the_identification(tmp_path):
    _bag(tmp_path / 'demo', {'/rwpend/encoders', '/rwpend/command'})
    with pytest.raises(IdentError, match='demo: not a run of the identification'):
        load_bags([tmp_path / 'demo'], RUNS, BASE)
    with pytest.raises(IdentError, match='not a bag directory'):
        load_bags([tmp_path / 'nothing'], RUNS, BASE)


def test_missing_runs_are_named():
    with pytest.raises(IdentError, match='no data for the run.*swing'):
        check_runs(BASE, {}, [r.name for r in RUNS])


def test_a_refused_step_stops_with_its_reason():
    z = np.zeros(10)
    d = RunData(h=0.001, t=z, pc=z, mc=z, u=z, theta=z, theta_dot=z, wheel_angle=z, wheel_rate=z, friction=z,
                faults=[(1.5, FAULT_LAW, 'procedures.py: NotReady: pendulum not at rest: it moved 0.02 rad '
                                    '(waited 3 s)')])
    with pytest.raises(IdentError, match=r'pulse\+3: the step was refused at t = 1.50 s: pendulum not at rest'):
        check_runs(BASE, {'pulse+3': d}, ['pulse+3'])


@pytest.mark.parametrize('args, match', [
    (['--rig', 'INCOMPLETE'], 'missing rig key'),
    (['--plant-rig', 'UNKNOWN'], 'unknown key.*m_wheel'),
    (['--plant', 'serial:/dev/null', '--plant-rig', 'HEAVY'], '--plant-rig .* needs --plant sim'),
    (['--plant', 'usb'], "--plant must be 'sim' or 'serial:PORT'"),
    (['--from', 'NOWHERE'], 'not a bag directory'),
    (['--plant', 'serial:NOWHERE'], 'does not exist'),
    (['--set', 'kpp=3'], '--set: expected NODE.PARAM=VALUE'),
    (['--set', 'wheel.kpp=3'], "--set: unknown node 'wheel'"),
])
def test_cli_refuses_bad_input_and_writes_nothing(tmp_path, capsys, args, match):
    text = default_rig_file().read_text()
    (tmp_path / 'incomplete.yaml').write_text(text.replace('      friction_breakaway: 1.0', ''))
    (tmp_path / 'unknown.yaml').write_text(text + '      m_wheel: 0.1\n')
    subst = {'INCOMPLETE': tmp_path / 'incomplete.yaml', 'UNKNOWN': tmp_path / 'unknown.yaml',
             'HEAVY': example_rig_file(), 'NOWHERE': tmp_path / 'nowhere'}
    out = tmp_path / 'out'
    argv = [str(subst.get(a, a)) for a in args] + ['--out', str(out)]
    assert cli.main(argv) == 2
    assert re.search(match, capsys.readouterr().err)
    assert not out.exists()           # refused before anything ran: not even the directory


def test_cli_refuses_an_out_that_is_a_file(tmp_path, capsys):
    (tmp_path / 'f').write_text('mine')
    assert cli.main(['--out', str(tmp_path / 'f')]) == 2
    assert 'exists and is not a directory' in capsys.readouterr().err
    assert (tmp_path / 'f').read_text() == 'mine'


def test_cli_error_messages(tmp_path, capsys):
    text = default_rig_file().read_text()
    (tmp_path / 'incomplete.yaml').write_text(text.replace('      friction_breakaway: 1.0', ''))
    assert cli.main(['--rig', str(tmp_path / 'incomplete.yaml'), '--out', str(tmp_path / 'o')]) == 2
    err = capsys.readouterr().err
    assert 'rwpend identify: error:' in err and 'missing rig key(s) friction_breakaway' in err


def _ident(values: dict) -> Identification:
    return Identification(BASE, BASE, {k: (v, 0.001 * abs(v)) for k, v in values.items()}, {}, ())


def test_check_matches_its_own_rig_and_names_what_differs():
    heavy = load_rig_file(example_rig_file())
    same = compare(_ident({**model_values(heavy), 'omega_p': heavy.omega_p}), heavy)
    assert all(r['matches'] for r in same)
    rows = {r['name']: r for r in compare(_ident({**model_values(heavy), 'omega_p': heavy.omega_p}), BASE)}
    assert not rows['friction_coulomb_pos']['matches'] and not rows['b_p']['matches']
    assert rows['friction_coulomb_pos']['deviation_pct'] == pytest.approx(50.0)
    assert set(rows) <= set(IDENTIFIED) | {'omega_p'}


@pytest.mark.parametrize('reason, calls, match', [('duration', 2, 'still stalled'), ('signal', 1, r'\(signal\)'),
                                                  ('exited:estimator', 1, 'exited:estimator')])
def test_only_a_stalled_run_is_run_once_more(tmp_path, monkeypatch, reason, calls, match):
    """A stack that hit its wall bound (a stall on a loaded machine) is run once more, its bag kept
    aside; an interrupt (Ctrl-C) or a node that exited stops the identification at once."""
    from rwpend_ident import session
    from rwpend_lab.experiment import LabError
    seen = []

    def run_stack(run, out, stack, log=None):
        seen.append(run.name)
        (out / 'runs' / run.name).mkdir(parents=True, exist_ok=True)
        if len(seen) == 2:
            raise LabError(f'run {run.name}: still stalled')
        raise LabError(f'run {run.name}: the stack did not run to the end ({reason}); see the log')

    monkeypatch.setattr(session.runner, 'run_stack', run_stack)
    run = type('R', (), {'name': 'pulse+3'})()
    with pytest.raises(IdentError, match=match):
        session.run_once_more_if_stalled(run, tmp_path, session.Options(), lambda s: None)
    assert len(seen) == calls
    assert (tmp_path / 'runs' / 'pulse+3.stalled').is_dir() == (calls == 2)


def test_only_a_laws_fault_is_a_refusal_the_loops_are_not():
    """A stale or implausible state (the loop's faults, e.g. the estimator just after a hand
    moved the pendulum) does not stop the identification; a law's fault does, with its reason."""
    from types import SimpleNamespace
    from rwpend_ident.records import IdentError, refused
    refused('swing', SimpleNamespace(faults=[(0.0, FAULT_BAD_STATE, 'bad state: |theta_dot| = 285.9 > 200 rad/s'),
                                             (0.2, FAULT_STALE_STATE, 'stale state: 3 ms old'),
                                             # judged by the code (fault_code), not by the text
                                             (0.3, FAULT_STALE_STATE, 'law fault: NotReady: a text')]))
    with pytest.raises(IdentError, match=r'pulse\+: the step was refused at t = 0.50 s: rotor moving'):
        refused('pulse+', SimpleNamespace(faults=[(0.1, FAULT_BAD_STATE, 'bad state: |theta_dot| = 250 > 200 rad/s'),
                                                  (0.5, FAULT_LAW, 'law fault: NotReady: rotor moving')]))
