"""rwpend_ros.trace (the loop's timing trace) and the bench's reading of it: pure, no ROS."""
from __future__ import annotations

from rwpend_ros import trace


def test_off_without_environment():
    assert trace.tracer('sim', environ={}) is None
    assert trace.tracer('sim', environ={'RWPEND_TRACE': '  '}) is None


def _write_run(tmp_path, samples=5, late=(3,), lost=(4,)):
    """A synthetic run: h = 1 ms; every hop 100 us; command k of `late` arrives after sample
    k+1, commands of `lost` never."""
    sim = trace.tracer('sim', environ={'RWPEND_TRACE': str(tmp_path)})
    est = trace.tracer('estimator', environ={'RWPEND_TRACE': str(tmp_path)})
    ctl = trace.tracer('controller', environ={'RWPEND_TRACE': str(tmp_path)})
    for k in range(samples):
        t = 1_000_000_000 + k * 1_000_000
        sim('sim.tick', k, t)
        sim('sim.pub', k, t + 50_000)
        est('est.rx', k, t + 150_000)
        est('est.pub', k, t + 170_000)
        ctl('ctl.rx', k, t + 270_000)
        ctl('ctl.pub', k, t + 300_000)
        if k not in lost:
            sim('sim.rx', k, t + (1_400_000 if k in late else 400_000))
    for tr in (sim, est, ctl):
        tr.dump()


def test_dump_load_stages(tmp_path):
    _write_run(tmp_path)
    assert len(list(tmp_path.glob('*.trace'))) == 3
    marks = trace.load(tmp_path)
    assert set(marks) - {'gc.start', 'gc.stop'} == set(trace.ORDER)   # a collection may come too
    st = trace.stages(marks, seqs=[0, 1, 2])
    assert st['sim.tick -> sim.pub'] == [50.0] * 3
    assert st['sim.pub -> est.rx'] == [100.0] * 3
    assert st['ctl.pub -> sim.rx'] == [100.0] * 3
    assert st['total'] == [400.0] * 3
    assert len(trace.stages(marks)['total']) == 4          # seq 4 has no sim.rx


def test_bench_trace_metrics(tmp_path):
    from rwpend_bench.bench import trace_metrics
    _write_run(tmp_path, samples=6, late=(3,), lost=(4,))
    m = trace_metrics(tmp_path)
    # samples 0..4 have a successor; 3 is late, 4 lost
    assert m['plant_traced_samples'] == 5
    assert m['plant_rx_late_samples'] == 2
    assert m['plant_latency_us']['n'] == 4 and m['plant_latency_us']['max'] == 1400.0
    assert m['plant_latency_us']['p50'] == 400.0
    assert m['step_us']['p50'] == 1000.0
    assert m['stages_us']['sim.pub -> est.rx']['p50'] == 100.0
    assert trace_metrics(tmp_path, window_seq=[0, 1])['plant_rx_late_samples'] == 0
    assert 'trace_error' in trace_metrics(tmp_path / 'nothing')


def test_stages_in_the_order_they_happen():
    """In one loop the command is written (sim.rx) before the sample is published: the stages
    follow the times, not the DDS relay's order."""
    marks = {'sim.tick': {0: 0, 1: 1_000_000}, 'sim.rx': {0: 80_000, 1: 1_070_000},
             'sim.pub': {0: 100_000, 1: 1_090_000}, 'est.pub': {0: 110_000, 1: 1_100_000},
             'ctl.pub': {0: 120_000, 1: 1_110_000}}
    st = trace.stages(marks)
    assert list(st) == ['sim.tick -> sim.rx', 'sim.rx -> sim.pub', 'sim.pub -> est.pub', 'est.pub -> ctl.pub',
                        'total']
    assert st['sim.tick -> sim.rx'] == [80.0, 70.0] and st['total'] == [120.0, 110.0]
