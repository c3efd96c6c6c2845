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
    assert m.counters() == {'fast': 2, 'dds': 1, 'duplicates': 2, 'skipped': 0, 'resyncs': 0, 'recovered': 0}


def test_merge_goes_back_to_dds_for_a_message_the_fast_path_missed():
    got = []
    m = Merge(got.append)
    m.from_fast(b'1'); m.from_dds(b'1'); m.from_fast(b'2')
    m.from_dds(b'3')                # 3 not sent fast (sender dropped us): delivered, resync
    assert got == [b'1', b'2', b'3'] and not m.fast_mode and m.resyncs == 1
    m.from_dds(b'2')                # a copy of 2 after 3 (DDS keeps a publisher's order: another
    assert got[-1] == b'3'          # publisher's identical bytes): a duplicate, dropped
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


@pytest.mark.parametrize('seed', range(int(os.environ.get('HOSTBUS_SEEDS', '40'))))
def test_merge_random_interleavings_deliver_each_message_once_in_order(seed):
    """Publisher sends 0..N-1, each to DDS and (unless stopped) fast first, each carrying its
    marker (the message before it: every one goes to DDS here); the fast path carries them with
    random delays (FIFO) and occasional gaps (sender dropped the target; resumed later), DDS
    carries them with other delays, some dropped by a keep-last reader. A DDS copy drains the
    datagrams sent before it (Merge.drain). Delivered: each once, nothing lost that either path
    carried (one the fast path brought and DDS dropped is recovered), in order -- but for one
    recovered late because DDS dropped its marker too (then the merge cannot tell it is older
    than what DDS brings meanwhile)."""
    rng = random.Random(seed)
    n = 400
    events = []
    t_fast = t_dds = 0.0
    stopped = False          # the sender dropped this target
    resume_after = None      # ... and sends again once DDS delivered the messages it skipped
    carried = set()
    dds_lost = set()
    for i in range(n):
        t = i * 1.0          # publish instants; delays up to 2.5 periods, each path FIFO
        if not stopped and rng.random() < 0.02:
            stopped = True
        elif stopped and rng.random() < 0.3:
            stopped, resume_after = False, t_dds
        if not stopped and (resume_after is None or t > resume_after):
            t_fast = max(t_fast, t + rng.uniform(0.0, 2.5))
            events.append((t_fast, 0, i))
            carried.add(i)
        if rng.random() > 0.05:                    # else: dropped by a keep-last DDS reader
            t_dds = max(t_dds, t + rng.uniform(0.0, 2.5))
            events.append((t_dds, 1, i))
            carried.add(i)
        else:
            dds_lost.add(i)
    events.sort()
    queue = [i for _, path, i in events if path == 0]    # datagrams, in the order sent
    got = []
    m = Merge(lambda d: got.append(int(d)))

    def take(upto):          # the receiving thread / Merge.drain: datagrams of messages <= upto
        while queue and queue[0] <= upto:
            j = queue.pop(0)
            m.from_fast(str(j).encode(), marker=str(j - 1).encode() if j else None)
    m.drain = lambda: None
    for _, path, i in events:
        take(i)
        if path:
            m.from_dds(str(i).encode())
    take(n)
    m.finish()                                   # the end: DDS brings nothing more
    assert len(got) == len(set(got)), 'once each'
    assert carried <= set(got), 'nothing lost that either path carried'
    for a, b in zip(got, got[1:]):
        assert b > a or b - 1 in dds_lost, (a, b)


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


def test_recorder_fast_path_is_on_unless_turned_off():
    assert hostbus.recorder_enabled({}) and hostbus.recorder_enabled({'RWPEND_RECORDER_FAST_PATH': '1'})
    assert not hostbus.recorder_enabled({'RWPEND_RECORDER_FAST_PATH': '0'})
    assert not hostbus.recorder_enabled({'RWPEND_HOST_BUS': '0'})
    assert not hostbus.recorder_enabled({'RWPEND_RECORDER_FAST_PATH': '1', 'RWPEND_HOST_BUS': '0'})
    with pytest.raises(ValueError, match='RWPEND_RECORDER_FAST_PATH'):
        hostbus.recorder_enabled({'RWPEND_RECORDER_FAST_PATH': 'yes'})


def test_enabled_by_environment():
    assert hostbus.enabled({}) and hostbus.enabled({'RWPEND_HOST_BUS': '1'})
    assert hostbus.enabled({'RWPEND_HOST_BUS': ''})
    assert not hostbus.enabled({'RWPEND_HOST_BUS': ' 0 '})
    for bad in ('off', 'yes', '2'):
        with pytest.raises(ValueError, match='RWPEND_HOST_BUS'):
            hostbus.enabled({'RWPEND_HOST_BUS': bad})


def test_pack_unpack_and_foreign_datagrams():
    assert hostbus.unpack(hostbus.pack(b'abcd')) == (b'abcd', False, None)
    assert hostbus.unpack(hostbus.pack(b'abcd', True)) == (b'abcd', True, None)
    assert hostbus.unpack(hostbus.pack(b'abcd', True, b'mark')) == (b'abcd', True, b'mark')
    assert hostbus.unpack(hostbus.pack(b'', True, b'')) == (b'', True, b'')
    assert hostbus.unpack(hostbus.pack(b'abcd', False, b'mk')) == (b'abcd', False, b'mk')
    for foreign in (b'', b'\x07abc', b'\x02\xff\xff\x00\x00ab', b'\x02ab'):
        assert hostbus.unpack(foreign) is None


def test_merge_fast_only_in_fast_mode_is_delivered_at_once():
    got = []
    m = Merge(got.append)
    m.from_fast(b'1'); m.from_dds(b'1')
    for i in range(2, KEEP + 50):       # DDS carries none of them
        m.from_fast(b'%d' % i, fast_only=True, marker=b'1')
    assert got == [b'%d' % i for i in range(1, KEEP + 50)] and m.fast_mode
    assert len(m.pending) == KEEP and m.dds == 1 and m.fast == KEEP + 48


def test_merge_fast_only_syncs_on_its_marker():
    got = []
    m = Merge(got.append)
    m.from_dds(b'1')                    # the publisher's last DDS write is already here
    m.from_fast(b'2', fast_only=True, marker=b'1')
    assert got == [b'1', b'2'] and m.fast_mode
    got.clear()
    m = Merge(got.append)               # a publisher that never wrote to DDS
    m.from_fast(b'1', fast_only=True)
    assert got == [b'1'] and m.fast_mode


def test_merge_holds_fast_only_messages_until_dds_brings_the_marker():
    got = []
    m = Merge(got.append)
    m.from_fast(b'5')                   # both ways: remembered
    m.from_fast(b'6', fast_only=True, marker=b'5')
    m.from_fast(b'7')                   # held behind 6 (both ways: its DDS copy comes later)
    m.from_fast(b'8', fast_only=True, marker=b'7')
    assert got == [] and len(m.held) == 3
    m.from_dds(b'5')                    # the marker: 5 from DDS, then the held ones
    assert got == [b'5', b'6', b'7', b'8'] and m.fast_mode and not m.held
    m.from_dds(b'7')                    # 7's DDS copy: a duplicate
    assert got == [b'5', b'6', b'7', b'8'] and m.duplicates == 1 and m.fast_mode


def test_merge_held_messages_go_when_the_marker_is_lost():
    got = []
    m = Merge(got.append)
    m.from_fast(b'6', fast_only=True, marker=b'5')
    m.from_fast(b'7')
    m.from_dds(b'7')                    # DDS lost 5 but brings 7, which is held: all go
    assert got == [b'6', b'7'] and m.fast_mode and m.duplicates == 1
    got.clear()
    m = Merge(got.append)
    m.from_fast(b'6', fast_only=True, marker=b'5')
    m.flush_held()                      # the receiving thread's timeout
    m.from_dds(b'5')                    # too late: delivered after 6 -- late, never lost
    assert got == [b'6', b'5']
    got.clear()
    m = Merge(got.append)
    for i in range(hostbus.HOLD):       # a bounded hold
        m.from_fast(b'%d' % i, fast_only=True, marker=b'x')
    assert len(got) == hostbus.HOLD and not m.held


def test_merge_holds_what_follows_a_message_the_publisher_wrote_to_dds_alone():
    """In fast mode: a send to this subscriber failed (5 went to DDS alone); 6 comes fast,
    before DDS brings 5: 6 waits for 5 -- not delivered before it, nor twice."""
    got = []
    m = Merge(got.append)
    m.from_fast(b'4'); m.from_dds(b'4')           # fast mode
    m.from_fast(b'6', marker=b'5')                # 5 went to DDS alone
    assert got == [b'4'] and m.held
    m.from_dds(b'5')
    assert got == [b'4', b'5', b'6'] and m.fast_mode
    m.from_dds(b'6')                              # 6's copy: dropped
    m.from_fast(b'7', marker=b'6'); m.from_dds(b'7')
    assert got == [b'4', b'5', b'6', b'7'] and m.duplicates == 2


def test_merge_a_marker_later_than_the_hold_is_delivered_and_nothing_doubles():
    """The recorder's case (make bench, control layout, a burst after a 10 ms stall): 5 went to
    DDS alone (its socket was full), DDS brings it later than HOLD fast messages after it. 5 is
    delivered late -- it was lost when the flush took it for a duplicate -- and the DDS copies
    of the fast ones are still dropped."""
    got = []
    m = Merge(got.append)
    m.from_fast(b'4'); m.from_dds(b'4')
    later = [b'x%d' % i for i in range(hostbus.HOLD)]
    for i, x in enumerate(later):
        m.from_fast(x, marker=b'5' if i == 0 else later[i - 1])
    assert got == [b'4'] + later                  # the hold ran over: delivered
    m.from_dds(b'5')
    for x in later:
        m.from_dds(x)
    assert got == [b"4"] + later + [b"5"] and m.duplicates == len(later)


def test_merge_double_fault_breaks_order_once_loses_nothing():
    """The known limit: 5 went to DDS alone (a failed send) AND a keep-last DDS reader lost it,
    then 7 goes to DDS alone too. 6 (held for 5) cannot be told from a message older than 5:
    7 is delivered first, 6 when the hold times out -- out of order once, nothing lost or
    doubled."""
    got = []
    m = Merge(got.append)
    m.from_fast(b'4'); m.from_dds(b'4')
    m.from_fast(b'6', marker=b'5')
    m.from_dds(b'7')
    m.flush_held()
    assert sorted(got) == [b'4', b'6', b'7'] and len(got) == 3


def test_merge_keep_last_skips_while_holding():
    got = []
    m = Merge(got.append)
    m.from_fast(b'1', deliver=False, fast_only=True, marker=b'0')
    m.from_fast(b'2', fast_only=True, marker=b'0')
    m.from_dds(b'0')
    assert got == [b'0', b'2'] and m.skipped == 1


@pytest.mark.parametrize('seed', range(int(os.environ.get('HOSTBUS_SEEDS', '100'))))
def test_merge_random_interleavings_with_fast_only_phases(seed):
    """The publisher as LocalPublisher: every datagram carries its marker (the last DDS write
    before it); it leaves DDS out (fast only) in some phases (no other subscriber), the first
    message after a change of targets going both ways; a send to this subscriber fails now and
    then (that message goes to DDS alone) and the sender resumes at any time. The receiving
    thread takes datagrams at random instants; a DDS copy first drains the datagrams sent
    before it (Merge.drain); the hold timeout is modelled. Delivered: strictly increasing,
    nothing lost that DDS carried or the fast path carried alone; the order broken only right
    after a message a keep-last DDS reader lost."""
    rng = random.Random(seed)
    n = 400
    hold_timeout = 6.0
    events = []
    t_fast = t_dds = 0.0
    stopped = False
    fresh = True
    only_phase = False
    marker = None
    must_arrive = set()
    dds_lost = set()
    for i in range(n):
        t = i * 1.0
        if rng.random() < 0.03:
            only_phase = not only_phase          # a recorder left / joined
        if not stopped and rng.random() < 0.03:
            stopped = True                       # a send failed: DDS alone until the next refresh
        elif stopped and rng.random() < 0.3:
            stopped, fresh = False, True
        fast_only = not stopped and only_phase and not fresh
        if not stopped:
            t_fast = max(t_fast, t + rng.uniform(0.0, 2.5))
            events.append((t_fast, 0, i, fast_only, marker))
            must_arrive.add(i)                   # one DDS drops is recovered from the fast path
        if fast_only:
            continue
        marker, fresh = str(i).encode(), False
        if rng.random() > 0.03:
            t_dds = max(t_dds, t + rng.uniform(0.0, 4.0))
            events.append((t_dds, 1, i, False, None))
            must_arrive.add(i)
        else:                                    # dropped by a keep-last DDS reader
            dds_lost.add(i)
    events.sort(key=lambda e: e[:2])
    socket_queue = [e for e in events if e[1] == 0]     # datagrams, in the order sent
    got = []
    m = Merge(lambda d: got.append(int(d)))
    held_since = None

    def take(upto):          # the receiving thread / Merge.drain: datagrams of messages <= upto
        nonlocal held_since
        while socket_queue and socket_queue[0][2] <= upto:
            t, _, i, fast_only, mark = socket_queue.pop(0)
            was_holding = bool(m.held)
            m.from_fast(str(i).encode(), fast_only=fast_only, marker=mark)
            if m.held and not was_holding:
                held_since = t
    m.drain = lambda: None
    for t, path, i, _, _ in events:
        if m.held and held_since is not None and t > held_since + hold_timeout:
            m.flush_held()
        take(i)                                  # sent before the DDS write of i
        if path:
            was_holding = bool(m.held)
            m.from_dds(str(i).encode())          # syncing may end in a hold (Merge._sync)
            if m.held and not was_holding:
                held_since = t
    m.finish()                                   # the end: DDS brings nothing more
    assert len(got) == len(set(got)), 'once each'
    assert must_arrive <= set(got), 'nothing lost that either path carried'
    for a, b in zip(got, got[1:]):    # order breaks only after a marker DDS lost (the double
        assert b > a or any(b - 10 <= d <= a for d in dds_lost), (a, b)   # fault, above)


def test_receiver_delivers_held_messages_when_the_marker_does_not_come(fast_pair):
    got, m, r, s = fast_pair('hold')
    m.fast_mode = False                  # syncing, and DDS never brings the marker
    s.send(b'a', fast_only=True, marker=b'never')
    time.sleep(hostbus.HOLD_S / 2)
    assert got == []
    assert wait_for(lambda: got == [b'a'])
    assert m.fast_mode


def test_sender_reports_whether_every_target_got_it(fast_pair):
    got, m, r, s = fast_pair('ok')
    assert s.send(b'1', fast_only=True)
    s.targets = s.targets + (unique_addr('gone'),)
    assert not s.send(b'2', fast_only=True) and s.targets == (r.addr,)
    assert wait_for(lambda: got == [b'1', b'2'])
    s.set_targets([r.addr])
    assert s.fresh is True or s.targets == (r.addr,)


def polled_pair(tag):
    """(delivered [(data, delivery_stamp)], merge in fast mode, polled receiver, sender connected
    to it as set_targets connects to a receiver of another process)."""
    got = []
    m = Merge(lambda d: got.append((d, hostbus.delivery_stamp())), hold=KEEP)
    m.fast_mode = True
    addr = unique_addr(tag)
    r = Receiver(addr, m, depth=1 << 30, polled=True)
    s = Sender()
    hostbus._LOCAL.discard(addr)       # as if it were bound by another process
    try:
        s.set_targets([addr])
    finally:
        hostbus._LOCAL.add(addr)
    assert s.targets == (addr,) and addr in s.conns, 'a polled receiver is reached by a connection'
    return got, m, r, s


def test_a_polled_receiver_holds_hundreds_with_their_arrival_times():
    """A datagram socket holds 10 messages (net.unix.max_dgram_qlen); a polled receiver's
    connection holds what the publisher's send buffer does: a recorder may drain seldom."""
    got, m, r, s = polled_pair('polled')
    try:
        with CALLBACK_LOCK:
            assert r.drain() == 0                # accepts the connection
        t0 = time.time_ns()
        for i in range(500):
            assert s.send(b'%04d' % i)
        t1 = time.time_ns()
        with CALLBACK_LOCK:
            assert r.drain() == 500
        assert [d for d, _ in got] == [b'%04d' % i for i in range(500)]
        stamps = [t for _, t in got]
        assert stamps == sorted(stamps) and t0 <= stamps[0] and stamps[-1] <= t1
        assert s.failed == 0 and hostbus.delivery_stamp() == 0
    finally:
        r.close()
        s.close()


def test_a_full_polled_receiver_is_dropped_and_a_gone_one_is_absent():
    got, m, r, s = polled_pair('polled_full')
    try:
        n = 0
        while s.send(bytes(1000)):
            n += 1
            assert n < 1_000_000
        assert n > 10 and s.failed == 1 and s.dropped and s.targets == ()
        with CALLBACK_LOCK:
            assert r.drain() == n                # nothing lost before the full one
    finally:
        r.close()
    s2 = polled_pair('polled_gone')
    _, _, r2, s2 = s2
    r2.close()
    assert not s2.send(b'x')                     # the receiver went away: absent, not a failure
    assert s2.failed == 0 and not s2.dropped and s2.targets == ()
    hostbus._LOCAL.discard(r2.addr)
    s2.set_targets([r2.addr])                    # nobody listens there now: no connection
    assert r2.addr not in s2.conns
    s2.send(b'y')
    assert s2.targets == () and s2.failed == 0
    s2.close()
    s.close()


def test_a_polled_receiver_drains_on_any_thread():
    """The recorder drains on a thread of its own (the arrival time is thread-local)."""
    got, m, r, s = polled_pair('polled_thread')
    errors = []

    def drain():
        try:
            with CALLBACK_LOCK:
                r.drain()
        except BaseException as exc:  # noqa: BLE001
            errors.append(exc)
    try:
        t = threading.Thread(target=drain)
        t.start()
        t.join()
        s.send(b'a')
        t = threading.Thread(target=drain)
        t.start()
        t.join()
        assert not errors and [d for d, _ in got] == [b'a'] and got[0][1] > 0
    finally:
        r.close()
        s.close()


def test_a_dds_message_keeps_its_reception_time_after_the_drain_before_it():
    """from_dds drains the fast messages first (each with its arrival time); the DDS message is
    then delivered with the time set for it (local_subscription's dds_info), not with 0."""
    got = []
    m = Merge(lambda d: got.append((d, hostbus.delivery_stamp())), hold=KEEP)
    m.fast_mode = True
    m.drain = lambda: m.from_fast(b'fast', stamp=111)
    before = hostbus.set_stamp(222)
    try:
        m.from_dds(b'dds')
    finally:
        hostbus.set_stamp(before)
    assert got == [(b'fast', 111), (b'dds', 222)]


def test_merge_syncs_on_any_fast_message_dds_brings_not_only_the_newest():
    """A DDS reader that lags (a busy recorder) never brings the newest fast message while it is
    the newest: the merge goes fast as soon as DDS brings one the fast path brought, and the
    fast messages after it are delivered at once (their DDS copies dropped)."""
    got = []
    m = Merge(got.append)
    m.from_fast(b'1', marker=None)
    m.from_fast(b'2', marker=b'1')
    m.from_fast(b'3', marker=b'2')
    assert got == [] and not m.fast_mode
    m.from_dds(b'1')
    assert got == [b'1', b'2', b'3'] and m.fast_mode
    m.from_fast(b'4', marker=b'3')
    for d in (b'2', b'3', b'4'):
        m.from_dds(d)
    assert got == [b'1', b'2', b'3', b'4'] and m.duplicates == 3 and m.resyncs == 0
    # a message written to DDS alone between them: the fast ones after it wait for it
    m2, got2 = None, []
    m2 = Merge(got2.append)
    m2.from_fast(b'a', marker=None)
    m2.from_fast(b'c', marker=b'b')          # b went to DDS alone
    m2.from_dds(b'a')
    assert got2 == [b'a'] and m2.held
    m2.from_dds(b'b')
    assert got2 == [b'a', b'b', b'c']


def test_merge_recovers_what_dds_skipped_before_its_reader_matched():
    """The CI failure (lockstep, recorder on the fast path): the controller's first command
    reached the recorder by the fast path, not by DDS (its writer had not matched the recorder's
    reader yet). It was dropped when DDS brought a later one; it is delivered now, first."""
    got = []
    m = Merge(got.append)
    m.from_fast(b'c0')                          # both ways, DDS skips it
    m.from_fast(b'c1', marker=b'c0')
    m.from_dds(b'c1')
    assert got == [b'c0', b'c1'] and m.recovered == 1 and m.fast_mode
    m.from_fast(b'c2', fast_only=True, marker=b'c1')
    assert got == [b'c0', b'c1', b'c2']
    # the same with fast-only messages held behind the first (their marker is c0)
    got.clear()
    m = Merge(got.append, hold=hostbus.KEEP)
    m.from_fast(b'c0')
    m.from_fast(b'c1', fast_only=True, marker=b'c0')
    m.from_fast(b'c2', marker=b'c1')
    assert got == [] and m.held
    m.from_dds(b'c2')                           # a held one: the marker is not coming
    assert got == [b'c0', b'c1', b'c2'] and m.recovered == 1
    got.clear()
    m = Merge(got.append)
    m.from_fast(b'c0')
    m.from_fast(b'c1', fast_only=True, marker=b'c0')
    m.flush_held()                              # the receiving thread's timeout
    assert got == [b'c0', b'c1']


def test_merge_recovers_down_the_chain_of_markers():
    """DDS drops 5 (keep-last) and the publisher writes 6 to DDS alone (a failed send): 6's DDS
    copy comes right after 4's, and 5's marker is 4 -- 5 was skipped: delivered before 6."""
    got = []
    m = Merge(got.append)
    m.from_dds(b'3')
    m.from_fast(b'4', marker=b'3')
    m.from_fast(b'5', marker=b'4')
    assert got == [b'3']                        # syncing: 4 and 5 wait for DDS
    m.from_dds(b'4')
    assert got == [b'3', b'4', b'5'] and m.fast_mode
    got.clear()
    m = Merge(got.append)
    m.from_fast(b'4', marker=b'3')
    m.from_dds(b'3')                            # not the one before 4: nothing to recover
    assert got == [b'3'] and m.syncing
    m.from_dds(b'6')                            # right after 3 came 6: 4 was skipped
    assert got == [b'3', b'4', b'6'] and m.recovered == 1 and not m.syncing


def test_merge_finish_delivers_what_waits_for_dds():
    got = []
    m = Merge(got.append)
    m.from_fast(b'1')
    m.from_fast(b'2', marker=b'1')
    m.finish()
    assert got == [b'1', b'2']
    got.clear()
    m = Merge(got.append)
    m.from_fast(b'1')
    m.from_fast(b'2', fast_only=True, marker=b'1')
    m.finish()
    assert got == [b'1', b'2'] and not m.held and not m.syncing
