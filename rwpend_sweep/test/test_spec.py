"""The spec of a study: what it accepts, what it refuses (with the key and the reason)."""
import pytest

from rwpend_sweep.build import prepare
from rwpend_sweep.cli import main
from rwpend_sweep.spec import SpecError, study_from_dict

BASE = {'scenario': {'mode': 'auto', 'duration': 2.0}}


def study(**kw):
    return study_from_dict({**BASE, **kw})


def test_grid_and_distributions_enumerate_runs():
    s = study(axes={'initial.theta': [3.0, 3.1], 'initial.theta_dot': [0.0, 1.0, 2.0],
                    'plant.m_p': {'factor': [0.9, 1.1]}}, samples=4, seed=3)
    assert s.runs == 2 * 3 * 4
    v = [s.run_values(i) for i in range(s.runs)]
    assert v[0]['initial.theta'] == 3.0 and v[0]['initial.theta_dot'] == 0.0
    assert v[4]['initial.theta_dot'] == 1.0          # the last grid axis varies fastest
    assert v[12]['initial.theta'] == 3.1
    # a run's draw depends on the seed and its index only
    assert s.run_values(7) == study(axes={'initial.theta': [3.0, 3.1], 'initial.theta_dot': [0.0, 1.0, 2.0],
                                          'plant.m_p': {'factor': [0.9, 1.1]}}, samples=4, seed=3).run_values(7)
    rows, setups = prepare(s)
    m = [r['plant.m_p'] for r in rows]
    assert all(0.9 * 0.2164 <= x <= 1.1 * 0.2164 for x in m)
    assert setups[5].truth.m_p == rows[5]['plant.m_p']
    assert setups[5].model.m_p == 0.2164               # the estimator and controller keep the rig YAML


@pytest.mark.parametrize('doc, words', [
    ({'axes': {'plant.nope': [1]}}, ['axes.plant.nope', 'unknown axis', 'rig key']),
    ({'axes': {'bogus': [1]}}, ['axes.bogus', 'unknown axis']),
    ({'axes': {'initial.theta': []}}, ['axes.initial.theta', 'empty list']),
    ({'axes': {'initial.theta': {'uniform': [2, 1]}}, 'samples': 3}, ['uniform', 'empty range']),
    ({'axes': {'initial.theta': {'normal': [2, 0]}}, 'samples': 3}, ['standard deviation']),
    ({'axes': {'initial.theta': {'uniform': [1, 2]}}}, ['samples']),
    ({'axes': {'plant.m_p': [0.2, -0.1]}}, ['axes.plant.m_p', '-0.1', 'm_p must be > 0']),
    ({'axes': {'controller.theta_s': [0.5, 5.0]}}, ['controller.theta_s', '5.0', 'theta_s']),
    ({'axes': {'estimator.omega0': [100, 1e9]}}, ['estimator.omega0', 'omega0']),
    ({'axes': {'command.delay_samples': {'uniform': [0, 3]}}, 'samples': 2}, ['integer axis']),
    ({'axes': {'encoder.counts_per_rev': [4000, 0]}}, ['counts_per_rev']),
    ({'scenario': {'mode': 'fly', 'duration': 1}}, ['scenario.mode']),
    ({'scenario': {'duration': -1}}, ['scenario.duration']),
    ({'scenario': {'duration': 1, 'initial': {'phi': 1}}}, ['scenario.initial', 'phi']),
    ({'scenario': {'duration': 1, 'success': {'tolerance': 0}}}, ['scenario.success.tolerance']),
    ({'scenario': {'duration': 1, 'taps': [{'t': 1}]}}, ['scenario.taps[0]', 'missing dv']),
    ({'extra': 1}, ['unknown key', 'extra']),
])
def test_refused_with_the_key_and_reason(doc, words):
    with pytest.raises(SpecError) as e:
        s = study_from_dict({**BASE, **doc})
        prepare(s)
    for w in words:
        assert w in str(e.value), (w, str(e.value))


def test_cli_refuses_before_running(tmp_path, capsys):
    spec = tmp_path / 's.yaml'
    spec.write_text('scenario: {duration: 1}\naxes: {plant.m_p: {uniform: [0.3, 0.1]}}\nsamples: 2\n')
    out = tmp_path / 'out'
    assert main([str(spec), '--out', str(out)]) == 2
    err = capsys.readouterr().err
    assert 'axes.plant.m_p.uniform' in err and 'empty range' in err
    assert not out.exists()
    assert main([str(tmp_path / 'missing.yaml'), '--out', str(out)]) == 2
    spec.write_text('scenario: {duration: 1}\naxes: {initial.theta: [3.1]}\n')
    assert main([str(spec), '--out', str(out), '--workers', '0']) == 2
    assert main([str(spec), '--out', str(out), '--compare', str(tmp_path / 'none.yaml')]) == 2
    bad = tmp_path / 'g.yaml'
    bad.write_text('balance.kpq: 1\n')
    assert main([str(spec), '--out', str(out), '--compare', str(bad)]) == 2
    assert 'balance.kpq' in capsys.readouterr().err
    assert not out.exists()
