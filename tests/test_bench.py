"""``./rwpend bench`` runs end to end and writes its JSON (a tiny run: no timing is asserted --
timing goals are never pass/fail, the figures depend on the machine and its load)."""
from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
RWPEND = str(ROOT / 'rwpend')


@pytest.mark.timeout(150)
def test_bench_runs_and_writes_json(tmp_path, ros_env):
    out = tmp_path / 'bench'
    p = subprocess.run([RWPEND, 'bench', '--duration', '1', '--lockstep-duration', '1', '--h', '0.001',
                        '--layout', 'separate', '--scale-max', '1', '--scale-duration', '1', '-o', str(out)],
                       env=ros_env, capture_output=True,
                       text=True, timeout=140)
    assert p.returncode == 0, f'{p.stdout[-3000:]}\n{p.stderr[-3000:]}'
    assert 'real time' in p.stdout and 'lockstep' in p.stdout and 'bag decode' in p.stdout, p.stdout
    res = json.loads((out / 'bench.json').read_text())
    for key in ('started', 'finished', 'machine', 'settings', 'realtime', 'lockstep', 'decode'):
        assert key in res, key
    for key in ('cpus', 'cpu_model', 'python', 'rmw', 'transport', 'loadavg_start', 'loadavg_end'):
        assert key in res['machine'], key
    assert res['machine']['transport'] == 'udp'
    assert res['settings']['periods_s'] == [0.001] and res['settings']['layouts'] == ['separate']

    assert [r['layout'] for r in res['realtime']] == ['separate', 'rig']
    rt = res['realtime'][0]
    # the independent reader's verdict, per sample (rwpend_bag.judge)
    assert rt['judged']['timed_samples'] > 0 and rt['judged']['source'].startswith('sim/true_state'), rt['judged']
    # the rig through the emulator: judged from the device's applied commands
    rig = res['realtime'][1]
    assert rig['judged']['source'].startswith('applied'), rig.get('judged') or rig.get('error')
    assert rig['judged']['timed_samples'] > 0 and rig['emulator_status'], rig
    assert {'loop', 'loop/rwpend-bag'} <= set(rig['cpu_cores']), rig['cpu_cores']
    for key in ('layout', 'h_s', 'rate_hz', 'samples', 'latency_us', 'late_fraction',
                'plant_late_fraction', 'jitter_us', 'period_us', 'dropped', 'cpu_cores',
                'cpu_cores_total', 'other_cpu_cores', 'loadavg_before', 'exit_codes',
                'host_steal_pct', 'cpu_latency_request'):
        assert key in rt, key
    assert rt['samples'] > 0 and rt['rate_hz'] == 1000
    for key in ('p50', 'p99', 'p99.9', 'max'):
        assert key in rt['latency_us'], key
    assert set(rt['cpu_cores']) == {'sim', 'estimator', 'controller', 'recorder'}
    assert set(rt['dropped']) >= {'/bench/encoders', '/bench/command'}
    assert all(c in (0, -2, 130) for c in rt['exit_codes'].values()), rt['exit_codes']

    # the default request (idle CPUs poll during a run); made where permitted, else reported
    assert res['settings']['cpu_latency_us'] == 0
    assert rt['cpu_latency_request'].startswith(('0 µs', 'not made')), rt['cpu_latency_request']
    assert [r['recorder'] for r in res['lockstep']] == [False, True]
    for r in res['lockstep']:
        for key in ('simulated_s', 'wall_s', 'sim_per_wall', 'cpu_s_per_simulated_s'):
            assert r.get(key) is not None, (key, r)
        assert r['simulated_s'] == pytest.approx(1.0, abs=1e-6)
    # lockstep keeps pace with its recorder (the simulator's lockstep_recorder_window): nothing lost
    dropped = res['lockstep'][1]['dropped']
    assert dropped and all(v == 0 for v in dropped.values()), dropped

    # the scale run, one step of one rig (a full one adds rigs up to 8, 20 s each: make bench)
    sc = res['scale']
    assert sc['max_rigs'] == 1 and [s['rigs'] for s in sc['steps']] == [1], sc
    d = res['decode']
    assert d['messages'] > 0 and d['msgs_per_s'] > 0
    # bags are deleted unless --keep-bags; logs stay
    assert not any(x.is_dir() for x in out.iterdir()), sorted(out.iterdir())
    assert list(out.glob('*.log'))


@pytest.mark.timeout(150)
def test_bench_control_layout_in_real_time_reports_every_loss(tmp_path, ros_env):
    """The control layout in real time (the only run that exercises it there): the estimator
    and the controller as the loop of their process, one step per ``encoders`` message
    (rwpend_loop.control), the plant in its own. It answers its samples, and its bag tells the
    truth: every gap of the bag is in the recording report (read with rosbags, rwpend_bag.judge).
    How much the recorder keeps in real time is a figure of the host (make bench, PERFORMANCE.md):
    a loss above the target (0.1 %) is an expected failure that says it, not a pass."""
    from rwpend_bag.judge import judge, read_run
    out = tmp_path / 'bench'
    p = subprocess.run([RWPEND, 'bench', '--duration', '3', '--h', '0.001', '--no-lockstep', '--no-decode', '--no-scale',
                        '--no-rig', '--layout', 'control', '--keep-bags', '-o', str(out)], env=ros_env,
                       capture_output=True, text=True, timeout=140)
    assert p.returncode == 0, f'{p.stdout[-3000:]}\n{p.stderr[-3000:]}'
    res = json.loads((out / 'bench.json').read_text())
    assert [r['layout'] for r in res['realtime']] == ['control']
    rt = res['realtime'][0]
    assert rt['samples'] > 1000, rt
    assert all(c in (0, -2, 130) for c in rt['exit_codes'].values()), rt['exit_codes']
    # commands answer the samples (the latency is measured from the seq echo)
    assert rt['latency_us']['p50'] is not None and rt['latency_us']['p50'] > 0, rt['latency_us']
    v = judge(read_run(rt['bag']))
    assert v.samples > 1000 and not v.unaccounted and v.unsafe_samples == 0, v.problems
    lost = {t: n for t, n in rt['dropped'].items() if not t.endswith('/command')}
    assert lost and all(n is not None for n in lost.values()), rt['dropped']
    published = v.samples + max(lost.values())
    worst = max(lost.values()) / published
    if worst > 0.001:
        where = {t: g for t, g in v.gaps.items() if g['missing']}
        pytest.xfail(f'the recorder fell behind on this host: {rt["dropped"]} samples lost of '
                     f'{published} ({100 * worst:.1f} %), every gap reported: {where}')
