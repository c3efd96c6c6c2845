"""The in-process bus (rwpend_ros.intra): pure, no rclpy."""
from __future__ import annotations

import threading

import pytest

from rwpend_ros.intra import KEEP, LocalBus


def make_bus():
    bus = LocalBus()
    bus.thread = threading.get_ident()
    return bus


def test_local_delivery_runs_before_the_dds_write_and_the_dds_copy_is_dropped():
    bus = make_bus()
    order = []
    sub = bus.subscribe('/r/state', lambda d: order.append(('local', d)))
    bus.publish('/r/state', b'a', lambda d: order.append(('dds', d)))
    assert order == [('local', b'a'), ('dds', b'a')]
    sub.from_dds(b'a')                         # its DDS copy: not delivered again
    assert order == [('local', b'a'), ('dds', b'a')] and sub.duplicates == 1 and sub.delivered == 1
    sub.from_dds(b'x')                         # from another process: delivered
    assert order[-1] == ('local', b'x')


def test_dropped_copies_are_forgotten_in_order():
    bus = make_bus()
    got = []
    sub = bus.subscribe('/t', got.append)
    for m in (b'1', b'2', b'3'):
        bus.publish('/t', m, lambda d: None)
    sub.from_dds(b'3')            # the copies of 1 and 2 were dropped by a keep-last reader
    assert not sub.pending
    sub.from_dds(b'1')            # a remote message equal to an old one: delivered
    assert got == [b'1', b'2', b'3', b'1']
    for i in range(KEEP + 10):    # copies that never come: bounded
        bus.publish('/t', str(i).encode(), lambda d: None)
    assert len(sub.pending) == KEEP


def test_off_outside_the_executor_thread():
    bus = LocalBus()                      # thread unset: the executor does not spin yet
    got, dds = [], []
    bus.subscribe('/t', got.append, owner='n')
    bus.publish('/t', b'm', dds.append)
    assert got == [] and dds == [b'm']
    bus = make_bus()
    got, dds = [], []
    bus.subscribe('/t', got.append)
    t = threading.Thread(target=bus.publish, args=('/t', b'm', dds.append))
    t.start()
    t.join()
    assert got == [] and dds == [b'm'], 'another thread (the sample loop) goes through DDS'


def test_a_running_callback_is_not_entered_again_the_message_waits_until_it_returns():
    bus = make_bus()
    got = []

    def cb(d):
        got.append(('in', d))
        if d == b'first':
            bus.publish('/t', b'nested', lambda _: None)   # would re-enter cb: deferred
        got.append(('out', d))
    sub = bus.subscribe('/t', cb)
    bus.publish('/t', b'first', lambda _: None)
    assert got == [('in', b'first'), ('out', b'first'), ('in', b'nested'), ('out', b'nested')]
    assert sub.deferred == 1 and not bus.deferred and not bus.busy and bus.depth == 0
    sub.from_dds(b'nested')       # its DDS copy (if written) is dropped
    assert len(got) == 4 and sub.duplicates == 1


def test_a_busy_node_gets_the_messages_of_its_other_subscriptions_after_its_callback():
    """The composed estimator: while its encoder callback publishes the state, the controller
    of its process answers with a command; the estimator takes it after that callback, before
    anything else, in publishing order; the controller's own subscription is not deferred."""
    bus = make_bus()
    est, order = object(), []

    def controller(d):
        order.append(('ctl', d))
        bus.publish('/cmd', b'u' + d[1:], lambda _: order.append(('dds', b'u' + d[1:])))
    bus.subscribe('/state', controller)
    bus.subscribe('/cmd', lambda d: order.append(('est.cmd', d)), owner=est)

    def on_encoders(d):
        order.append(('est.enc', d))
        bus.publish('/state', b's' + d[1:], lambda _: None)
        order.append(('est.enc done', d))
    bus.call(est, on_encoders, b'e1')
    assert order == [('est.enc', b'e1'), ('ctl', b's1'), ('dds', b'u1'), ('est.enc done', b'e1'),
                     ('est.cmd', b'u1')]
    order.clear()
    bus.publish('/cmd', b'u2', lambda _: None)   # est not busy: delivered at once
    assert order == [('est.cmd', b'u2')]


def test_deferred_messages_wait_for_the_next_call_when_the_callback_raised():
    bus = make_bus()
    owner, got = object(), []
    bus.subscribe('/t', got.append, owner=owner)

    def bad(_):
        bus.publish('/t', b'm', lambda _: None)
        raise RuntimeError('fault')
    with pytest.raises(RuntimeError):
        bus.call(owner, bad, b'x')
    assert got == [] and list(bus.deferred) and not bus.busy and bus.depth == 0
    bus.call(object(), lambda _: None, b'y')   # the next callback to return delivers it
    assert got == [b'm'] and not bus.deferred


def test_the_dds_write_happens_even_when_a_local_callback_raises():
    bus = make_bus()
    dds = []

    def bad(_):
        raise RuntimeError('law fault')
    sub = bus.subscribe('/t', bad)
    with pytest.raises(RuntimeError):
        bus.publish('/t', b'm', dds.append)
    assert dds == [b"m"] and sub.owner not in bus.busy


def test_topics_are_separate_and_unsubscribe():
    bus = make_bus()
    a, b = [], []
    sa = bus.subscribe('/ns1/state', a.append)
    bus.subscribe('/ns2/state', b.append)
    bus.publish('/ns1/state', b'1', lambda _: None)
    assert a == [b'1'] and b == []
    bus.unsubscribe('/ns1/state', sa)
    bus.publish('/ns1/state', b'2', lambda _: None)
    assert a == [b'1']
    bus.close()
    assert bus.thread is None and not bus.topics


def test_after_dds_subscribers_run_after_the_write():
    bus = make_bus()
    order = []
    bus.subscribe('/t', lambda d: order.append('after'), before_dds=False)
    bus.subscribe('/t', lambda d: order.append('before'))
    bus.publish('/t', b'm', lambda d: order.append('dds'))
    assert order == ['before', 'dds', 'after']


def test_after_dds_subscriber_gets_the_dds_copy_when_a_callback_raised():
    bus = make_bus()
    got = []
    late = bus.subscribe('/t', got.append, before_dds=False)

    def bad(_):
        raise RuntimeError('fault')
    bus.subscribe('/t', bad)
    with pytest.raises(RuntimeError):
        bus.publish('/t', b'm', lambda d: None)
    late.from_dds(b'm')           # not delivered locally: its DDS copy is not dropped
    assert got == [b'm']


def test_slack_work_runs_after_the_outermost_callback_and_its_deferred_messages():
    """LocalBus.after: the job waits for the whole chain of one sample (composed: the estimator
    and the controller nested in the simulator's tick, the command deferred to its end)."""
    bus = make_bus()
    order = []
    sim, est = object(), object()
    bus.subscribe('/r/command', lambda d: order.append(('sim.command', d)), owner=sim)

    def est_callback():
        order.append('est')
        bus.after(lambda: order.append('est.diagnostics'))
        bus.publish('/r/command', b'u', lambda d: order.append(('dds', d)))   # sim busy: deferred
        order.append('est.end')

    bus.call(sim, lambda: bus.call(est, est_callback))
    assert order == ['est', ('dds', b'u'), 'est.end', ('sim.command', b'u'), 'est.diagnostics']
    assert bus.slack_jobs == 1 and not bus.slack


def test_slack_work_runs_now_outside_a_callback_one_job_per_return_and_never_twice():
    bus = make_bus()
    order = []
    bus.after(lambda: order.append('now'))
    assert order == ['now'] and bus.slack_jobs == 0
    a, b = (lambda: order.append('a')), (lambda: order.append('b'))

    def queue():
        bus.after(a)
        bus.after(a)           # already waiting: not twice
        bus.after(b)
    bus.call('n', queue)
    assert order == ['now', 'a']               # one job per outermost return
    bus.call('n', lambda: None)
    assert order == ['now', 'a', 'b'] and not bus.slack
    bus.call('n', lambda: None)
    assert order == ['now', 'a', 'b']


def test_a_slack_job_that_raises_propagates_and_the_bus_stays_usable():
    bus = make_bus()

    def boom():
        raise RuntimeError('diagnostics failed')
    with pytest.raises(RuntimeError, match='diagnostics failed'):
        bus.call('n', lambda: bus.after(boom))
    assert bus.depth == 0 and not bus.busy and not bus.slack
    seen = []
    bus.call('n', lambda: seen.append(1))
    assert seen == [1]
