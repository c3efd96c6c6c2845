"""rwpend_bench.table: the benchmark's results as PERFORMANCE.md's tables, and the region of the
document they are written into (nothing else of it changes)."""
from __future__ import annotations

import json

import pytest

from rwpend_bench import bench
from rwpend_bench.table import BEGIN, END, markdown_tables, replace_region

RES = {
    'started': 0.0,
    'machine': {'cpus': 2, 'cpu_model': 'EPYC', 'python': '3.11.7', 'rmw': 'rmw_fastrtps_cpp',
                'loadavg_start': [0.1, 0.1, 0.1], 'loadavg_end': [0.5, 0.2, 0.1]},
    'settings': {'duration_s': 60.0, 'lockstep_duration_s': 12.0, 'command': 'rwpend bench --quick'},
    'realtime': [
        {'layout': 'loop', 'h_s': 0.001, 'latency_us': {'p50': 151.2, 'p99': 402.9}, 'host_steal_pct': 0.31,
         'cpu_cores': {'loop': 0.151, 'loop/rwpend-bag': 0.082},
         'judged': {'late_fraction': 0.00012, 'zero_fraction': 0.0, 'falls': 0, 'timed_samples': 59990}},
        {'layout': 'rig', 'h_s': 0.001, 'error': 'the emulator did not start (its log: x)'},
    ],
    'lockstep': [{'layout': 'loop', 'h_s': 0.001, 'recorder': False, 'simulated_s': 12.0, 'wall_s': 0.6,
                  'total_wall_s': 1.2, 'cpu_s_per_simulated_s': 0.05}],
    'sweep': {'pure_core': {'us_per_sample': 30.0},
              'sweep': {'study': 'mc', 'duration_s': 10.0, 'runs_per_s_per_core': 3.1,
                        'study_1000_runs_s_per_core': 322.0}},
}


def test_the_tables_give_each_run_judged_from_its_bag():
    text = markdown_tables(RES)
    assert '| loop (default) | 1 ms | 0.012 % | 0.000 % | 0 | 59990 | 151 / 403 | loop 0.15, loop/rwpend-bag 0.08 | 0.3 % |' in text
    assert '| the rig through the emulator | 1 ms | the emulator did not start (its log: x) |' in text
    assert '| loop (default), h = 1 ms | no | 12.0 s | 0.60 s (20.0x) | 1.20 s (10.0x) | 0.05 |' in text
    assert '3.10 runs/s per core, 1000 runs = 322 core-s; the pure core 30.0 µs' in text


def test_only_the_marked_region_changes():
    doc = f'# P\n\nbefore\n{BEGIN}\nold table\n{END}\nafter\n'
    assert replace_region(doc, 'new') == f'# P\n\nbefore\n{BEGIN}\nnew\n{END}\nafter\n'


@pytest.mark.parametrize('doc', ['no markers', f'{END}\n{BEGIN}\n', f'{BEGIN}\n{BEGIN}\n{END}\n'])
def test_a_document_without_one_ordered_pair_of_markers_is_refused(doc):
    with pytest.raises(ValueError, match='needs one line'):
        replace_region(doc, 'x')


def test_tables_from_a_saved_result_written_into_the_document(tmp_path, capsys):
    saved = tmp_path / 'bench.json'
    saved.write_text(json.dumps(RES))
    doc = tmp_path / 'PERF.md'
    doc.write_text(f'intro\n{BEGIN}\n{END}\nrest\n')
    assert bench.main(['--tables-from', str(saved), '--performance', str(doc)]) == 0
    text = doc.read_text()
    assert text.startswith(f'intro\n{BEGIN}\n`./rwpend bench --quick`') and text.endswith(f'{END}\nrest\n')


def test_bad_inputs_are_refused_and_change_nothing(tmp_path, capsys):
    doc = tmp_path / 'PERF.md'
    doc.write_text('no markers here\n')
    saved = tmp_path / 'bench.json'
    saved.write_text(json.dumps(RES))
    assert bench.main(['--tables-from', str(saved), '--performance', str(doc)]) == 2
    assert doc.read_text() == 'no markers here\n'
    assert bench.main(['--performance', str(doc), '--no-realtime', '--no-lockstep']) == 2
    assert 'needs one line' in capsys.readouterr().err
    (tmp_path / 'bad.json').write_text('{not json')
    assert bench.main(['--tables-from', str(tmp_path / 'bad.json')]) == 2
    assert bench.main(['--tables-from', str(tmp_path / 'missing.json')]) == 2
    assert doc.read_text() == 'no markers here\n'


def test_performance_md_has_the_region():
    from pathlib import Path
    doc = Path(__file__).resolve().parents[2] / 'PERFORMANCE.md'
    replace_region(doc.read_text(encoding='utf-8'), 'x')
