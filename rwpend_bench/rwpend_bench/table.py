"""The benchmark's figures (``bench.json``) as the Markdown tables of PERFORMANCE.md (pure).

``./rwpend bench --performance PERFORMANCE.md`` writes :func:`markdown_tables` of its results
between the document's two marker lines (:data:`BEGIN`, :data:`END`);
``./rwpend bench --tables-from bench_out/bench.json --performance PERFORMANCE.md`` does it again
from a saved result, without running anything.  Nothing else of the document is touched.
"""
from __future__ import annotations

import time

#: the marker lines of the region the benchmark writes
BEGIN = '<!-- ./rwpend bench writes the tables below, from its bench.json; edit them there -->'
END = '<!-- end of the tables written by ./rwpend bench -->'
#: the name of each real-time run's layout in the tables
LAYOUT_NAMES = {'loop': 'loop (default)', 'control': 'control (`--composed control`)',
                'separate': 'separate (`--composed none`)', 'rig': 'the rig through the emulator'}


def _pct(fraction, nd: int = 3) -> str:
    return 'n/a' if fraction is None else f'{100 * fraction:.{nd}f} %'


def _num(v, nd: int = 0) -> str:
    return 'n/a' if v is None else f'{v:.{nd}f}'


def _cpu(cores: dict | None) -> str:
    if not cores:
        return 'n/a'
    return ', '.join(f'{name} {v:.2f}' for name, v in cores.items() if v is not None) or 'n/a'


def realtime_rows(runs: list[dict]) -> list[str]:
    """One row per real-time run: judged from its bag (late, at zero, falls), the latency at the
    recorder, the CPU of each process, the host's steal."""
    rows = ['| run (real time, recorder of every topic) | h | late | at zero | falls | samples judged '
            '| latency p50 / p99 (µs) | CPU (cores) | steal |',
            '|---|---|---|---|---|---|---|---|---|']
    for r in runs:
        j = r.get('judged') or {}
        lat = r.get('latency_us') or {}
        name = LAYOUT_NAMES.get(r['layout'], r['layout'])
        if r.get('error') or 'late_fraction' not in j:
            why = r.get('error') or j.get('error') or 'no verdict'
            rows.append(f"| {name} | {r['h_s'] * 1e3:g} ms | {why} | | | | | | |")
            continue
        rows.append(f"| {name} | {r['h_s'] * 1e3:g} ms | {_pct(j['late_fraction'])} | "
                    f"{_pct(j['zero_fraction'])} | {j['falls']} | {j['timed_samples']} | "
                    f"{_num(lat.get('p50'))} / {_num(lat.get('p99'))} | {_cpu(r.get('cpu_cores'))} | "
                    f"{_num(r.get('host_steal_pct'), 1)} % |")
    return rows


def lockstep_rows(runs: list[dict]) -> list[str]:
    """One row per lockstep run: simulated seconds per wall second of the loop and of the whole
    command (start-up and shutdown included)."""
    rows = ['| lockstep run | recorder | simulated | the loop | the whole command | CPU s per simulated s |',
            '|---|---|---|---|---|---|']
    for r in runs:
        sim, wall, total = r.get('simulated_s'), r.get('wall_s'), r.get('total_wall_s')
        loop = 'n/a' if not (sim and wall) else f'{wall:.2f} s ({sim / wall:.1f}x)'
        whole = 'n/a' if not (sim and total) else f'{total:.2f} s ({sim / total:.1f}x)'
        rows.append(f"| {LAYOUT_NAMES.get(r['layout'], r['layout'])}, h = {r['h_s'] * 1e3:g} ms | "
                    f"{'yes' if r['recorder'] else 'no'} | {_num(sim, 1)} s | {loop} | {whole} | "
                    f"{_num(r.get('cpu_s_per_simulated_s'), 2)} |")
    return rows


def sweep_line(sweep: dict | None) -> list[str]:
    """The robustness study's speed (rwpend_sweep.bench), one sentence."""
    if not sweep:
        return []
    p, s = sweep['pure_core'], sweep['sweep']
    return [f"Robustness study ({s['study']}, {s['duration_s']:g} s runs): {s['runs_per_s_per_core']:.2f} "
            f"runs/s per core, 1000 runs = {s['study_1000_runs_s_per_core']:.0f} core-s; the pure core "
            f"{p['us_per_sample']:.1f} µs of CPU per sample."]


def markdown_tables(res: dict) -> str:
    """The figures of one benchmark (``bench.json`` as a dict) as Markdown: what ran, where, the
    real-time table, the lockstep table, the study's speed."""
    m, st = res['machine'], res['settings']
    when = time.strftime('%Y-%m-%d %H:%M', time.localtime(res['started']))
    parts = [f"`./{st.get('command', 'rwpend bench')}` on {when}: {m['cpus']} CPU ({m['cpu_model']}), "
             f"Python {m['python']}, {m['rmw']}; load average {m.get('loadavg_start')} -> "
             f"{m.get('loadavg_end')}; {st['duration_s']:g} s real-time runs, "
             f"{st['lockstep_duration_s']:g} s lockstep runs."]
    if res.get('realtime'):
        parts += [''] + realtime_rows(res['realtime'])
    if res.get('lockstep'):
        parts += [''] + lockstep_rows(res['lockstep'])
    line = sweep_line(res.get('sweep'))
    if line:
        parts += [''] + line
    return '\n'.join(parts)


def replace_region(document: str, tables: str) -> str:
    """``document`` with the text between its :data:`BEGIN` and :data:`END` lines replaced by
    ``tables``; ValueError when the markers are missing, repeated or out of order."""
    lines = document.split('\n')
    begins = [i for i, ln in enumerate(lines) if ln.strip() == BEGIN]
    ends = [i for i, ln in enumerate(lines) if ln.strip() == END]
    if len(begins) != 1 or len(ends) != 1 or ends[0] < begins[0]:
        raise ValueError(f'the document needs one line {BEGIN!r} and, after it, one line {END!r} '
                         f'(found {len(begins)} and {len(ends)})')
    return '\n'.join(lines[:begins[0] + 1] + [tables] + lines[ends[0]:])
