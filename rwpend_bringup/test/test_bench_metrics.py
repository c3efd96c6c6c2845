"""Pure helpers of the benchmark (no process started)."""
from __future__ import annotations

from rwpend_bringup.bench import cpu_times, steal_percent


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
