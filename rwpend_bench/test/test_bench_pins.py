"""The benchmark's CPU pinning of its real-time runs (no process started)."""
import pytest


def test_bench_pins_of_the_real_time_runs(monkeypatch):
    from rwpend_bench import bench
    from rwpend_bringup import stack as cli
    monkeypatch.setattr(cli, 'usable_cpus', lambda: {0, 1})
    assert bench.realtime_pins(None, ['separate', 'control']) == {'separate': ('sim=0', 'estimator=0', 'controller=1')}
    assert bench.realtime_pins(['none'], ['separate']) == {}
    assert bench.realtime_pins(['sim=1', 'loop=0'], ['separate', 'control', 'loop']) == {
        'separate': ('sim=1',), 'control': ('sim=1',), 'loop': ('loop=0',)}
    with pytest.raises(ValueError, match="no process 'loop'"):
        bench.realtime_pins(['loop=0'], ['separate'])
    monkeypatch.setattr(cli, 'usable_cpus', lambda: {0})          # one CPU: nothing pinned
    assert bench.realtime_pins(None, ['separate']) == {}
    monkeypatch.setattr(cli, 'usable_cpus', lambda: {2, 3})       # not CPUs 0 and 1: nothing either
    assert bench.realtime_pins(None, ['separate']) == {}
