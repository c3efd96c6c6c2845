"""Pure helpers of the benchmark (no process started)."""
from __future__ import annotations

from rwpend_bench.bench import cpu_times, steal_percent


def test_steal_percent():
    before = [100, 0, 50, 800, 0, 0, 0, 50, 0, 0]
    after = [200, 0, 100, 1500, 0, 0, 0, 150, 0, 0]     # +100 +50 +700 idle +100 steal
    assert steal_percent(before, after) == round(100 * 100 / 950, 2)
    assert steal_percent(before, before) is None         # no time passed
    assert steal_percent(None, after) is None
    assert steal_percent([1, 2, 3, 4], [2, 3, 4, 5]) is None   # no steal counter


def test_cpu_times_reads_proc_stat():
    t = cpu_times()
    assert t is None or (len(t) >= 4 and all(isinstance(x, int) for x in t))


def test_scale_carried_is_the_last_step_within_the_limit():
    from rwpend_bench.bench import scale_carried
    steps = [{'rigs': 1, 'late_fraction': 0.0}, {'rigs': 3, 'late_fraction': 0.002},
             {'rigs': 2, 'late_fraction': 0.001}]
    assert scale_carried(steps) == 2                   # 0.1 % itself is within the limit
    assert scale_carried([{'rigs': 1, 'late_fraction': 0.01}]) == 0
    assert scale_carried([{'rigs': 1, 'late_fraction': 0.0}, {'rigs': 2, 'late_fraction': None},
                          {'rigs': 3, 'late_fraction': 0.0}]) == 1     # no figure: failed
    assert scale_carried([]) == 0


def test_scale_step_figures_pool_the_rigs_samples():
    from rwpend_bench.bench import scale_step_figures
    rigs = [{'plant_rx_late_samples': 1, 'plant_traced_samples': 1000, 'plant_rx_late_fraction': 0.001,
             'plant_latency_us': {'p50': 300.0}},
            {'plant_rx_late_samples': 5, 'plant_traced_samples': 1000, 'plant_rx_late_fraction': 0.005,
             'plant_latency_us': {'p50': 500.0}}]
    f = scale_step_figures(rigs)
    assert f['late_fraction'] == 6 / 2000 and f['worst_rig_late_fraction'] == 0.005
    assert f['worst_rig_latency_us'] == {'p50': 500.0}
    assert scale_step_figures([{'plant_traced_samples': 0}])['late_fraction'] is None


def test_window_seqs_from_the_ticks(tmp_path):
    from rwpend_bench.bench import window_seqs
    (tmp_path / 'sim-1.trace').write_text(''.join(f'sim.tick {k} {1000 + 10 * k}\n' for k in range(10)))
    assert window_seqs(tmp_path, 1020, 1060) == (2, 5)
    assert window_seqs(tmp_path, 0, 10) is None
