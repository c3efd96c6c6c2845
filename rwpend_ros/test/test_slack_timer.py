"""SlackTimer (rwpend_ros.nodes): periodic work of a loop node runs in the loop's slack."""
from __future__ import annotations

from rwpend_ros.nodes import SlackTimer


class FakeNode:
    def __init__(self):
        self.timers = []

    def create_timer(self, period, callback):
        self.timers.append((period, callback))


def test_runs_at_the_tick_while_no_sample_comes():
    node, runs = FakeNode(), []
    t = SlackTimer(node, 1.0, lambda: runs.append('diag'))
    (period, tick), = node.timers
    assert period == 1.0
    tick()
    tick()
    assert runs == ['diag', 'diag'] and t.at_tick == 2 and t.in_slack == 0


def test_while_samples_come_it_runs_at_the_end_of_the_next_sample():
    node, runs = FakeNode(), []
    t = SlackTimer(node, 1.0, lambda: runs.append('diag'))
    tick = node.timers[0][1]
    t.sample_done()
    tick()
    runs.append('sample')
    t.sample_done()
    assert runs == ['sample', 'diag'] and t.in_slack == 1
