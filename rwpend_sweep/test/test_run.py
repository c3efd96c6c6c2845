"""Runs: deterministic, independent of the number of workers, resumable; the metrics."""
import csv
import math

import numpy as np
import pytest

from rwpend_sweep.build import prepare
from rwpend_sweep.cli import main
from rwpend_sweep.execute import study_fingerprint
from rwpend_sweep.run import run_one, samples_of
from rwpend_sweep.spec import study_from_dict
from rwpend_sweep.study import run_study

pytestmark = pytest.mark.loop    # each run is the stack's loop in lockstep

DOC = {'scenario': {'mode': 'auto', 'duration': 0.6, 'success': {'last': 0.3}},
       'axes': {'initial.theta': [3.1, 3.3], 'plant.m_p': {'factor': [0.9, 1.1]},
                'sensor.noise_counts': [0.0, 1.0]},
       'samples': 2, 'seed': 5}


def test_catch_from_near_upright_succeeds_and_far_fails():
    s = study_from_dict({'scenario': {'mode': 'auto', 'duration': 1.0, 'success': {'last': 0.5, 'never_beyond': 0.8}},
                         'axes': {'initial.theta': [math.pi, math.pi - 0.3]}})
    _, setups = prepare(s)
    ok = run_one(setups[0], s.scenario.success)
    bad = run_one(setups[1], s.scenario.success)
    assert ok['success'] and ok['time_to_balance'] == 0.0 and ok['reason'] == ''
    assert ok['balance_rms'] < 0.01 and 0 <= ok['saturation_share'] <= 1
    assert not bad['success'] and 'left |theta-pi| <= 0.8' in bad['reason']
    assert math.isnan(bad['time_to_balance'])


def test_runs_are_deterministic_and_noise_seeded_per_run():
    s = study_from_dict(DOC)
    _, setups = prepare(s)
    a, b = samples_of(setups[2]), samples_of(setups[2])
    assert np.array_equal(a.pendulum_counts, b.pendulum_counts) and np.array_equal(a.u, b.u)
    assert len(a.seq) == 600 and a.seq[-1] == 599
    noisy = [i for i, r in enumerate(prepare(s)[0]) if r['sensor.noise_counts'] == 1.0]
    x, y = samples_of(setups[noisy[0]]), samples_of(setups[noisy[1]])
    assert not np.array_equal(x.pendulum_counts - np.round(x.theta / (2 * math.pi / 4000)),
                              y.pendulum_counts - np.round(y.theta / (2 * math.pi / 4000)))


def test_delay_holds_each_command_d_samples():
    s = study_from_dict({'scenario': {'mode': 'swingup', 'duration': 0.05, 'success': {'last': 0.01}},
                         'axes': {'command.delay_samples': [0, 2]}})
    _, setups = prepare(s)
    from rwpend_sweep.run import build_loop
    loops = [build_loop(x) for x in setups]
    ticks = [[lp.step(t=k * 1e-3) for k in range(20)] for lp in loops]
    u0 = [t.u for t in ticks[0]]
    applied = [t.reading.truth.u_applied for t in ticks[1]]
    # the plant applies the swing-up's kick 2 samples later than without the delay
    first0 = next(k for k, t in enumerate(ticks[0]) if t.reading.truth.u_applied != 0)
    first1 = next(k for k, a in enumerate(applied) if a != 0)
    assert first1 == first0 + 2 and u0[0] != 0


def _rows(path):
    with open(path) as fh:
        return list(csv.DictReader(fh))


def test_workers_do_not_change_the_rows_and_a_study_resumes(tmp_path):
    s = study_from_dict(DOC)
    fp = study_fingerprint(DOC, {})
    one = run_study(s, tmp_path / 'one', fp, workers=1)
    two = run_study(s, tmp_path / 'two', fp, workers=2)
    strip = lambda rows: [{k: v for k, v in r.items() if k != 'cpu_s'} for r in rows]  # noqa: E731
    assert strip(_rows(tmp_path / 'one' / 'results.csv')) == strip(_rows(tmp_path / 'two' / 'results.csv'))
    assert len(one) == s.runs == 8
    assert [r["run"] for r in one] == list(range(8))
    # interrupted after 5 rows (and a torn line): the rest is run, the rows are the same
    part = tmp_path / 'two' / 'partial.csv'
    lines = part.read_text().splitlines(keepends=True)
    part.write_text(''.join(lines[:6]) + lines[6][:10])
    (tmp_path / 'two' / 'results.csv').unlink()
    again = run_study(s, tmp_path / 'two', fp, workers=1)
    assert strip(_rows(tmp_path / 'two' / 'results.csv')) == strip(_rows(tmp_path / 'one' / 'results.csv'))
    assert len(again) == 8
    # another study in the same directory is refused
    with pytest.raises(ValueError, match='another study'):
        run_study(s, tmp_path / 'two', fp + 'x', workers=1)


def test_cli_page_and_compare(tmp_path, capsys):
    spec = tmp_path / 'basin.yaml'
    spec.write_text('scenario: {mode: auto, duration: 0.4, success: {last: 0.2, never_beyond: 0.8}}\n'
                    'axes:\n  initial.theta: [3.04, 3.14, 3.24]\n  initial.theta_dot: [-3.0, -1.0, 0.0, 1.0, 3.0]\n')
    gains = tmp_path / 'fast.yaml'
    gains.write_text('patch:\n  design:\n    omega0: 2wp\n')
    law = tmp_path / 'mylaw.py'
    law.write_text('def control(state, params):\n    return 0.0\n')
    out = tmp_path / 'out'
    assert main([str(spec), '--out', str(out), '--workers', '1', '--quiet',
                 '--compare', 'default', str(gains), str(law)]) == 0
    text = capsys.readouterr().out
    assert '#1 ' in text and 'mylaw' in text
    page = (out / 'index.html').read_text()
    assert 'Ranking' in page and 'success_map.png' in page and (out / 'results.parquet').is_file()
    rows = _rows(out / 'results.csv')
    assert len(rows) == 45 and {r['controller'] for r in rows} == {'default', 'fast', 'mylaw'}
    # u = 0 holds only the runs that start at rest upright: the law ranks last
    import json
    ranking = json.loads((out / 'ranking.json').read_text())
    assert ranking[-1]['controller'] == 'mylaw'
    assert sum(r['success'] == 'True' for r in rows if r['controller'] == 'mylaw') <= 1
    import pyarrow.parquet as pq
    t = pq.read_table(out / 'results.parquet')
    assert t.num_rows == 45 and 'initial.theta_dot' in t.column_names
