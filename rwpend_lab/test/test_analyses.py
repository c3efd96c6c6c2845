"""Every experiment's analysis on synthetic data: the pure twin of the loop (rwpend_lab.twin: the
simulator core, the estimators and the controller in one process, as in lockstep) runs each
experiment's runs; every quantity must pass.  And the analyses must notice wrong data."""
from __future__ import annotations

import json

import numpy as np
import pytest

from rwpend_lab import report, twin
from rwpend_lab.experiment import Options
from rwpend_lab.registry import EXPERIMENTS
from rwpend_model.rig import load_rig

pytestmark = pytest.mark.loop    # the twin: the stack's loop in lockstep in the test's process

RIG = load_rig()
_CACHE: dict = {}


def data_of(n: int) -> dict:
    e = EXPERIMENTS[n]
    out = {}
    for r in e.plan(RIG, Options()):
        key = (r.name, r.title, r.duration, repr(sorted(r.sim.items())), r.law, repr(r.law_params),
               repr(sorted(r.controller.items())), repr(sorted(r.estimator.items())), r.mode)
        if key not in _CACHE:
            _CACHE[key] = twin.simulate(RIG, r)
        out[r.name] = _CACHE[key]
    return out


@pytest.mark.timeout(600)
@pytest.mark.parametrize('n', list(range(1, 21)))
def test_every_quantity_passes_on_the_twin(n):
    a = EXPERIMENTS[n].analyze(RIG, data_of(n))
    assert a.quantities and a.figures
    failed = [(q.name, q.measured, q.theory, q.tolerance) for q in a.quantities if not q.passed]
    assert not failed, failed
    for f in a.figures:
        assert f.png[:8] == b'\x89PNG\r\n\x1a\n'


def test_a_wrong_rig_fails_the_frequency_of_experiment_1():
    """Data of a rig with a 10 % longer pendulum, judged against the shipped rig: omega_p' fails."""
    other = RIG.replace(l_p=RIG.l_p * 1.1)
    runs = EXPERIMENTS[1].plan(other, Options())
    d = twin.simulate(other, runs[0], duration=8.0)
    q = EXPERIMENTS[1].analyze(RIG, {'swing': d}).quantities[0]
    assert not q.passed and q.measured < q.theory


def test_a_friction_free_wheel_fails_the_friction_curve():
    rig0 = RIG.replace(friction_coulomb_pos=0.5)
    run = EXPERIMENTS[9].plan(rig0, Options())[0]
    d = twin.simulate(rig0, run)
    qs = EXPERIMENTS[9].analyze(RIG, {'curve': d}).quantities
    assert not qs[0].passed and qs[0].measured == pytest.approx(0.5, abs=0.05)


def test_results_json_and_a_self_contained_report(tmp_path):
    e = EXPERIMENTS[2]
    a = e.analyze(RIG, data_of(2))
    res = report.write(tmp_path / 'e2', e, a, [{'name': 'meter', 'title': 't', 'duration': 10.25}],
                       {'plant': 'sim', 'rig': RIG.as_params()})
    on_disk = json.loads((tmp_path / 'e2' / 'results.json').read_text())
    assert on_disk == json.loads(json.dumps(res))
    for q in on_disk['quantities']:
        assert {'experiment', 'name', 'unit', 'measured', 'theory', 'tolerance', 'pass'} <= set(q)
    html = (tmp_path / 'e2' / 'report.html').read_text()
    assert html.count('data:image/png;base64,') == len(a.figures)
    assert 'src="http' not in html and 'Questions for the student' in html
    index = report.course([tmp_path / 'e2'], tmp_path / 'course')
    assert 'exp02.html' in index.read_text() and (tmp_path / 'course' / 'exp02.html').is_file()
    with pytest.raises(FileNotFoundError):
        report.course([tmp_path], tmp_path / 'c2')
    assert np.isfinite(on_disk['quantities'][0]['measured'])
