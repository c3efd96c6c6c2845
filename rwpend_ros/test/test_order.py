"""rwpend_ros.order.OrderGate: a subscriber never takes a message older than one it took, nor one
twice -- over long randomized interleavings of two paths (two publishers, or a replay beside
DDS), with delays, drops, duplicates and publisher restarts."""
from __future__ import annotations

import heapq
import random

import pytest

from rwpend_ros.order import RESTART_SILENCE, OrderGate


def test_rules_one_by_one():
    g = OrderGate()
    assert g.admit(5, 100, now=1.0) and g.admit(6, 101, now=1.001)
    assert not g.admit(6, 101, now=1.002) and g.duplicates == 1          # the same message again
    assert not g.admit(4, 99, now=1.003) and g.stale == 1                # older
    assert not g.admit(6, 50, now=1.004) and g.stale == 2                # same seq, older stamp
    assert not g.admit(0, 0, now=1.005) and g.stale == 3                 # a late copy of seq 0
    assert g.admit(9, 104, now=1.006) and (g.gaps, g.missing) == (1, 2)  # 7, 8 missing
    assert g.admit(0, 0, now=3.0) and g.restarts == 1                    # lockstep restart: silence
    assert g.admit(1, 1, now=3.001)
    assert not g.admit(0, 0, now=3.002)                                  # its late copy: stale
    assert g.admit(0, 10**12, now=3.003) and g.restarts == 2             # wall-clock restart: newer stamp
    assert g.taken == 6 and 'duplicates 1, stale 4' in g.summary()


@pytest.mark.parametrize('seed', range(20))
def test_randomized_two_paths_never_older_never_twice(seed):
    rnd = random.Random(seed)
    events = []                       # (arrival time, order, seq, stamp)
    n_msgs, order = 0, 0
    stamp = 1_000
    for run in range(3):              # the publisher restarts twice (seq from 0, newer stamps)
        for seq in range(rnd.randint(2_000, 5_000)):
            stamp += 1_000_000
            n_msgs += 1
            t = stamp
            copies = []
            if rnd.random() > 0.02:                          # bus path (sometimes missing)
                copies.append(t + rnd.randint(0, 50_000))
            if rnd.random() > 0.05:                          # DDS path: later, jittered, 5 % dropped
                copies.append(t + rnd.randint(0, 3_000_000))
            if rnd.random() < 0.01:                          # a duplicate, much later
                copies.append(t + rnd.randint(0, 20_000_000))
            for a in copies:
                order += 1
                heapq.heappush(events, (a, order, run, seq, stamp))
    g = OrderGate()
    taken = []
    while events:
        arrival, _, run, seq, st = heapq.heappop(events)
        if g.admit(seq, st, now=arrival * 1e-9):
            taken.append((run, seq, st))
    assert len(set(taken)) == len(taken), 'a message taken twice'
    for (r0, s0, t0), (r1, s1, t1) in zip(taken, taken[1:]):
        assert t1 > t0, 'a message older than one already taken'
        assert r1 > r0 or s1 > s0, 'seq went back within one run of the publisher'
    assert g.taken == len(taken) and g.taken > 0.5 * n_msgs


def test_one_message_far_ahead_stops_the_stream_until_a_silence():
    """A message with a stamp far ahead (corrupt, a clock that jumped) is taken; what follows is
    stale until RESTART_SILENCE without a message taken. (A run of stale messages in order is not
    followed: in a composed process the DDS copies of the in-process messages are such a run.)
    A seq far ahead with a normal stamp is a restart at once (lower seq, newer stamp)."""
    g = OrderGate()
    for k in range(10):
        assert g.admit(k, 100 + k, now=1.0 + 0.001 * k)
    assert g.admit(11, 10**18, now=1.011)
    assert not any(g.admit(k, 200 + k, now=1.0 + 0.001 * k) for k in range(12, 40))
    assert g.admit(40, 240, now=1.011 + RESTART_SILENCE) and g.restarts == 1
    g = OrderGate()
    assert g.admit(5, 100, now=1.0) and g.admit(2**64 - 1, 101, now=1.001)
    assert g.admit(6, 102, now=1.002) and g.restarts == 1


def test_late_copies_in_order_stay_stale():
    """A second path that lags (the DDS copies in a composed process): its copies come in order,
    all older than the last message taken, and none is taken."""
    g = OrderGate()
    for k in range(100):
        assert g.admit(k, 1000 + k, now=1.0 + 0.001 * k)
    assert not any(g.admit(k, 1000 + k, now=1.1 + 0.0001 * k) for k in range(50, 100))
    assert g.restarts == 0 and g.stale == 49 and g.duplicates == 1


def test_a_stale_run_out_of_order_among_itself_stays_stale():
    g = OrderGate()
    assert g.admit(100, 1000, now=1.0)
    for i in range(50):      # late copies, older than the last taken and not in order: dropped
        assert not g.admit(50 - (i % 7), 500, now=1.0 + 0.001 * i)
    assert g.restarts == 0 and g.taken == 1
