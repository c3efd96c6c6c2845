"""SlackTimer (rwpend_ros.nodes): periodic work of a loop node runs in the loop's slack."""
from __future__ import annotations

from rwpend_ros.intra import LocalBus
from rwpend_ros.nodes import SlackTimer


class FakeNode:
    def __init__(self, bus=None):
        self.timers = []
        self.bus = bus

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


def test_while_the_loop_runs_it_waits_for_the_end_of_the_next_sample():
    BUS = LocalBus()
    node, runs = FakeNode(BUS), []
    t = SlackTimer(node, 1.0, lambda: runs.append('diag'))
    tick = node.timers[0][1]

    def sample(k):
        runs.append(f'sample {k}')
        t.sample_done()
        runs.append(f'sample {k} end')
    owner = object()
    BUS.call(owner, sample, 0)
    tick()                                   # a sample came since the last tick: due, not run
    assert runs == ['sample 0', 'sample 0 end']
    BUS.call(owner, sample, 1)               # runs after the callback, not inside it
    BUS.call(owner, sample, 2)
    assert runs == ['sample 0', 'sample 0 end', 'sample 1', 'sample 1 end', 'diag',
                    'sample 2', 'sample 2 end']
    assert t.in_slack == 1 and t.at_tick == 0
    tick()                                   # due again (samples came) ...
    tick()                                   # ... but none since: run at the tick
    assert runs[-1] == 'diag' and t.at_tick == 1 and not t.due
    BUS.call(owner, sample, 3)
    assert runs[-1] == 'sample 3 end'        # nothing due


def test_without_a_bus_it_runs_at_the_end_of_the_next_sample():
    node, runs = FakeNode(), []
    t = SlackTimer(node, 1.0, lambda: runs.append('diag'))
    tick = node.timers[0][1]
    t.sample_done()
    tick()
    runs.append('sample')
    t.sample_done()
    assert runs == ['sample', 'diag'] and t.in_slack == 1
