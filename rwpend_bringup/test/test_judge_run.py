"""The verdict of ``up`` on its bag (rwpend_bringup.cli.judge_run) where the loop's process
ended before it recorded: said at once, not after waiting for a bag writer that never started."""
from __future__ import annotations

import time
from types import SimpleNamespace

from rwpend_bringup.cli import WRITER_FINISH_S, judge_run
from rwpend_bringup.verdict import EXIT_SHORT_BAG


def test_no_bag_when_the_loop_ended_before_recording(tmp_path, capsys):
    a = SimpleNamespace(record=str(tmp_path / 'never'), duration=10.0, lockstep=True)
    t0 = time.monotonic()
    status = judge_run(a, [SimpleNamespace(name='loop', params={})], {'loop': 2}, 1, 0.5)
    assert time.monotonic() - t0 < WRITER_FINISH_S / 10
    assert status == 1
    assert 'no bag: the loop ended before it opened' in capsys.readouterr().err
    assert not (tmp_path / 'never').exists()
    assert judge_run(a, [SimpleNamespace(name='loop', params={})], {'loop': 0}, 0, 0.5) == EXIT_SHORT_BAG
