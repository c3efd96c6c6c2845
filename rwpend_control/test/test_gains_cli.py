"""rwpend gains CLI."""
import json

import pytest

from rwpend_control.gains_cli import main


def run(capsys, *argv):
    code = main(list(argv))
    out = capsys.readouterr()
    return code, out.out, out.err


def test_pdd_book(capsys):
    code, out, _ = run(capsys, 'pdd', '--book-g', '--json')
    assert code == 0
    d = json.loads(out)
    assert d['params']['balance.kpp'] == pytest.approx(-282.06, abs=0.01)
    assert d['params']['balance.kdp'] == pytest.approx(-25.37, abs=0.01)
    assert d['params']['balance.kdr'] == pytest.approx(-0.0302, abs=1e-4)
    assert d['stable'] and len(d['poles']) == 3


def test_text_output_names_node_params(capsys):
    code, out, _ = run(capsys, 'patch', '--w0', '2wp', '--book-g')
    assert code == 0
    assert 'patch.kpp = -568.1' in out and 'patch.kdr = -0.1789' in out
    assert 'closed-loop poles: -8.856' in out
    code, out, _ = run(capsys, 'pdpd', '--w0', 'wp', '--zeta', '1', '--w2', '0.5wp', '--zeta2', '0.707', '--book-g')
    assert code == 0 and 'balance.kdr = -0.05398' in out       # E29
    code, out, _ = run(capsys, 'pi', '--w0', '20')
    assert code == 0 and 'wheel.kp = 0.20' in out and 'wheel.ki = 0.0020' in out
    code, out, _ = run(capsys, 'pd', '--book-g', '--down')
    assert code == 0 and 'balance.kpp = -145.15' in out and 'allow_wheel_drift' in out


@pytest.mark.parametrize('argv', [
    ['bogus'], [], ['pdd', '--w0', 'fast'], ['pdd', '--w0', '-3'], ['pdd', '--zeta', 'x'],
    ['pdd', '--zeta', 'nan'], ['pdd', '--alpha', '-1'], ['pdd', '--rig', '/nonexistent.yaml'],
    ['pdpd', '--w2', '0'],
])
def test_bad_args_exit_2(capsys, argv):
    with pytest.raises(SystemExit) as exc:
        raise SystemExit(main(argv))
    assert exc.value.code == 2
    assert 'error' in capsys.readouterr().err


def test_gains_for_another_rig_are_the_controllers_defaults_for_it(capsys):
    """Issue 24 item 6: ``gains ... --rig FILE`` designs for that rig, and the controller's default
    gain sets (designed from the rig YAML it reads) are the same numbers."""
    from rwpend_control.supervisor import ControllerConfig
    from rwpend_ident.rigfile import example_rig_file
    from rwpend_model.rig import load_rig, load_rig_file
    heavy = example_rig_file()
    cfg = ControllerConfig.designed(load_rig_file(heavy))
    shipped = ControllerConfig.designed(load_rig())
    for design_, names in (('pdd', ('kpp', 'kdp', 'kdr')), ('patch', ('kpp', 'kdp', 'kdr'))):
        code, out, _ = run(capsys, design_, '--rig', str(heavy), '--json')
        assert code == 0
        params = json.loads(out)['params']
        group = 'balance' if design_ == 'pdd' else 'patch'
        for n in names:
            assert params[f'{group}.{n}'] == pytest.approx(getattr(cfg, f'{group}_{n}'), rel=1e-9)
    assert cfg.balance_kpp != pytest.approx(shipped.balance_kpp, rel=0.01), 'the heavy rig needs other gains'


def test_an_incomplete_rig_file_is_refused_with_the_missing_keys(capsys, tmp_path):
    bad = tmp_path / 'rig.yaml'
    bad.write_text('/**:\n  ros__parameters:\n    rig:\n      m_p: 0.3\n')
    code, _, err = run(capsys, 'pdd', '--rig', str(bad))
    assert code == 2 and 'missing rig key(s)' in err and 'l_p' in err
    code, _, err = run(capsys, 'pdd', '--rig', str(bad), '--book-g')
    assert code == 2 and 'excludes --rig' in err
