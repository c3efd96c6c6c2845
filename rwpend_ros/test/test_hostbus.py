"""The same-host fast path (rwpend_ros.hostbus): pure, no rclpy. Real Unix sockets."""
from __future__ import annotations

import os
import random
import threading
import time

import pytest

from rwpend_ros import hostbus
from rwpend_ros.hostbus import CALLBACK_LOCK, KEEP, Merge, Receiver, Sender, address, pad4


def unique_addr(tag: str) -> bytes:
    return address(os.getpid() % 200, f'/hostbus_test/{tag}', f'/t/{random.random()}')


def wait_for(cond, timeout=3.0):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if cond():
            return True
        time.sleep(0.002)
    return cond()


def test_address_is_abstract_short_and_distinct():
    a = address(7, '/r/state', '/r/controller')
    assert a == address(7, '/r/state', '/r/controller')
    assert a.startswith(b'\0') and len(a) < 108
    assert len({a, address(8, '/r/state', '/r/controller'), address(7, '/r/command', '/r/controller'),
                address(7, '/r/state', '/s/controller')}) == 4
    assert hostbus.node_fqn('/', 'sim') == '/sim' and hostbus.node_fqn('/rig1', 'sim') == '/rig1/sim'


def test_pad4_matches_the_payload_across_processes():
    assert pad4(b'') == b'' and pad4(b'abcd') == b'abcd'
    assert pad4(b'abcde') == b'abcde\0\0\0' and pad4(b'ab') == b'ab\0\0'


def test_merge_syncs_then_delivers_fast_and_drops_the_dds_copies():
    got = []
    m = Merge(got.append)
    m.from_fast(b'1')               # syncing: remembered, not delivered
    assert got == [] and not m.fast_mode
    m.from_dds(b'1')                # the paths meet: DDS delivered it, fast from now on
    assert got == [b'1'] and m.fast_mode
    m.from_fast(b'2')
    m.from_fast(b'3')
    m.from_dds(b'2')
    m.from_dds(b'3')
    assert got == [b'1', b'2', b'3']
    assert m.counters() == {'fast': 2, 'dds': 1, 'duplicates': 2, 'skipped': 0, 'resyncs': 0}


def test_merge_goes_back_to_dds_for_a_message_the_fast_path_missed():
    got = []
    m = Merge(got.append)
    m.from_fast(b'1'); m.from_dds(b'1'); m.from_fast(b'2')
    m.from_dds(b'3')                # 3 not sent fast (sender dropped us): delivered, resync
    assert got == [b'1', b'2', b'3'] and not m.fast_mode and m.resyncs == 1
    m.from_dds(b'2')                # a late copy of 2 after the resync would be... not possible:
    # DDS keeps order, 2's copy came before 3's. A message from another publisher: delivered
    assert got[-1] == b'2'
    m.from_fast(b'4'); m.from_dds(b'4'); m.from_fast(b'5')
    assert got[-2:] == [b'4', b'5'] and m.fast_mode


def test_merge_keep_last_skips_are_not_delivered_by_dds_either():
    got = []
    m = Merge(got.append)
    m.from_fast(b'0'); m.from_dds(b'0')
    m.from_fast(b'1', deliver=False)
    m.from_fast(b'2')
    m.from_dds(b'1'); m.from_dds(b'2')
    assert got == [b'0', b'2'] and m.skipped == 1 and m.duplicates == 2 and m.fast_mode


def test_merge_copies_dropped_by_a_keep_last_reader_are_forgotten():
    got = []
    m = Merge(got.append)
    m.from_fast(b'0'); m.from_dds(b'0')
    for i in range(1, 4):
        m.from_fast(bytes([i]))
    m.from_dds(bytes([3]))          # copies of 1 and 2 never came
    assert not m.pending and m.fast_mode
    for i in range(KEEP + 10):      # copies that never come at all: bounded
        m.from_fast(b'x%d' % i)
    assert len(m.pending) == KEEP


@pytest.mark.parametrize('seed', range(40))
def test_merge_random_interleavings_deliver_each_message_once_in_order(seed):
    """Publisher sends 0..N-1; the fast path carries them with random delays (FIFO) and
    occasional gaps (sender dropped the target; resumed later), DDS carries all of them, some
    dropped by a keep-last reader. Delivered: strictly increasing, nothing DDS carried is lost."""
    rng = random.Random(seed)
    n = 400
    events = []
    t_fast = t_dds = 0.0
    stopped = False          # the sender dropped this target
    resume_after = None      # ... and sends again once DDS delivered the messages it skipped
    dds_carried = set()
    for i in range(n):
        t = i * 1.0          # publish instants; delays up to 2.5 periods, each path FIFO
        if not stopped and rng.random() < 0.02:
            stopped = True
        elif stopped and rng.random() < 0.3:
            stopped, resume_after = False, t_dds
        if not stopped and (resume_after is None or t > resume_after):
            t_fast = max(t_fast, t + rng.uniform(0.0, 2.5))
            events.append((t_fast, 0, i))
        if rng.random() > 0.05:                    # else: dropped by a keep-last DDS reader
            t_dds = max(t_dds, t + rng.uniform(0.0, 2.5))
            events.append((t_dds, 1, i))
            dds_carried.add(i)
    events.sort()
    got = []
    m = Merge(lambda d: got.append(int(d)))
    for _, path, i in events:
        (m.from_dds if path else m.from_fast)(str(i).encode())
    assert got == sorted(set(got)), 'once each, in order'
    assert dds_carried <= set(got), 'nothing DDS carried is lost'


def test_sender_and_receiver_deliver_on_the_receiving_thread_holding_the_lock():
    got = []

    def deliver(data):
        got.append((data, threading.get_ident(), CALLBACK_LOCK._is_owned()))
    m = Merge(deliver)
    addr = unique_addr('rx')
    idents = []
    r = Receiver(addr, m, depth=1000, on_start=idents.append)
    s = Sender()
    try:
        s.targets = (addr,)       # set_targets skips this process's receivers (tested below)
        s.send(b'a')
        assert wait_for(lambda: m.newest_fast == b'a')     # syncing
        with CALLBACK_LOCK:
            m.from_dds(b'a')                              # met: fast from now on
        s.send(b'b')
        assert wait_for(lambda: len(got) == 2)
        assert got[0][0] == b'a' and got[0][1] == threading.get_ident()   # DDS: this thread
        assert got[1][0] == b'b' and got[1][1] == idents[0] != threading.get_ident() and got[1][2]
        # keep-last: of a backlog only the newest `depth` -- here the receiver keeps all
        with CALLBACK_LOCK:
            for x in (b'c', b'd', b'e'):
                s.send(x)
            time.sleep(0.05)
        assert wait_for(lambda: len(got) == 5)
        assert [g[0] for g in got] == [b'a', b'b', b'c', b'd', b'e']
    finally:
        r.close()
        s.close()
    assert addr not in hostbus._LOCAL


@pytest.fixture
def fast_pair():
    """make(tag, depth) -> (delivered list, merge in fast mode, receiver, sender aimed at it);
    closed after the test."""
    made = []

    def make(tag, depth=10):
        got = []
        m = Merge(got.append)
        m.fast_mode = True
        addr = unique_addr(tag)
        r = Receiver(addr, m, depth=depth)
        s = Sender()
        s.targets = (addr,)       # set_targets skips this process's receivers
        made.append((r, s))
        return got, m, r, s
    yield make
    for r, s in made:
        r.close()
        s.close()


def test_receiver_keeps_the_newest_depth_of_a_backlog(fast_pair):
    got, m, _, s = fast_pair('depth', depth=2)
    with CALLBACK_LOCK:           # the receiving thread waits: a backlog of 5
        for x in (b'1', b'2', b'3', b'4', b'5'):
            s.send(x)
        time.sleep(0.05)
    assert wait_for(lambda: got == [b'4', b'5'])
    assert m.skipped == 3 and list(m.pending) == [b'1', b'2', b'3', b'4', b'5']


def test_sender_forgets_absent_receivers_and_skips_its_own_process():
    s = Sender()
    missing = unique_addr('nobody')
    m = Merge(lambda d: None)
    own = unique_addr('own')
    r = Receiver(own, m, depth=10)
    try:
        s.set_targets([missing, own, missing])
        assert s.targets == (missing,)           # own process: intra / DDS serve it
        s.send(b'x')                             # nobody bound: absent, not a failure
        assert s.targets == () and s.failed == 0 and not s.dropped
    finally:
        r.close()
        s.close()


def test_a_message_too_big_for_one_datagram_is_left_to_dds(fast_pair):
    got, _, r, s = fast_pair('big')
    s.send(bytes(hostbus.MAX_DATAGRAM + 4))
    s.send(b'small')
    assert wait_for(lambda: got == [b'small'])
    assert s.too_big == 1 and s.targets == (r.addr,)


def test_a_second_receiver_on_one_address_is_refused():
    addr = unique_addr('twice')
    r = Receiver(addr, Merge(lambda d: None), depth=10)
    try:
        with pytest.raises(OSError):
            Receiver(addr, Merge(lambda d: None), depth=10)
    finally:
        r.close()


def test_a_failing_callback_is_reported_and_stops_the_thread(fast_pair):
    errors = []
    _, m, r, s = fast_pair('err')
    r.on_error = errors.append

    def boom(data):
        raise RuntimeError('law failed')
    m.deliver = boom
    s.send(b'x')
    assert wait_for(lambda: errors) and isinstance(errors[0], RuntimeError)
    r.thread.join(2.0)
    assert not r.thread.is_alive()


def test_raise_priority_is_harmless_without_real_time_scheduling():
    before = os.sched_getscheduler(0)
    t = threading.Thread(target=hostbus.raise_priority)
    t.start()
    t.join()
    assert os.sched_getscheduler(0) == before


def test_enabled_by_environment():
    assert hostbus.enabled({}) and hostbus.enabled({'RWPEND_HOST_BUS': '1'})
    assert hostbus.enabled({'RWPEND_HOST_BUS': ''})
    assert not hostbus.enabled({'RWPEND_HOST_BUS': ' 0 '})
    for bad in ('off', 'yes', '2'):
        with pytest.raises(ValueError, match='RWPEND_HOST_BUS'):
            hostbus.enabled({'RWPEND_HOST_BUS': bad})
