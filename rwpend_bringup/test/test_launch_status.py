"""The launcher's exit status from its nodes' (rwpend_bringup.launch.run_status)."""
from __future__ import annotations

import signal

from rwpend_bringup.launch import EXIT_CONFIG, run_status


def test_every_node_well_or_stopped_by_us_is_0():
    assert run_status({'loop': 0, 'recorder': -signal.SIGINT, 'x': 130}) == (0, '')


def test_a_refused_configuration_is_2_and_said():
    status, said = run_status({'loop': 2, 'recorder': 0})
    assert status == EXIT_CONFIG == 2
    assert 'refused their configuration: loop (exit 2)' in said


def test_any_other_failure_is_1():
    assert run_status({'loop': 2, 'sim': 3})[0] == 1
    assert run_status({'sim': 1})[0] == 1
    assert 'ended with an error: sim (exit 1)' in run_status({'sim': 1})[1]
