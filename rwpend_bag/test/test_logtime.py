"""Pure tests of log times and write order (rwpend_bag.logtime), of the rosbag2 metadata the
writer puts in the MCAP file, and of "the same bag" (rwpend_bag.sameness). No rclpy.

File order is read back with the ``mcap`` library's stream reader, not with our reader."""
from __future__ import annotations

import random
import struct

import pytest
import yaml
from mcap.records import Channel, Header, Message, Metadata
from mcap.stream_reader import StreamReader

from rwpend_bag import logtime, msgdefs, sameness
from support import synth
from rwpend_bag.logtime import (STAMP_CLOCK, STAMP_HEADER, STAMP_NONE, ArrivalOrder, LogTimeGuard,
                                SimTimeOrder, leading_time_ns, stamp_kind)
from rwpend_bag.writer import METADATA_KEY, METADATA_RECORD, BagWriter, ThreadedBagWriter, default_qos

MS = 1_000_000


def stamped(t_ns: int, payload: bytes = b'', big_endian: bool = False) -> bytes:
    """CDR bytes of a message that starts with a Time (a Header's stamp, a Clock)."""
    sec, nsec = divmod(t_ns, 1_000_000_000)
    if big_endian:
        return b'\x00\x00\x00\x00' + struct.pack('>iI', sec, nsec) + payload
    return b'\x00\x01\x00\x00' + struct.pack('<iI', sec, nsec) + payload


def records(path):
    with open(path, 'rb') as f:
        return list(StreamReader(f).records)


def file_log_times(path):
    return [r.log_time for r in records(path) if isinstance(r, Message)]


# ------------------------------------------------------------------ stamps
def test_leading_time_both_byte_orders_and_short_data():
    assert leading_time_ns(stamped(12_345_678_901)) == 12_345_678_901
    assert leading_time_ns(stamped(12_345_678_901, big_endian=True)) == 12_345_678_901
    assert leading_time_ns(b'\x00\x01\x00\x00\x01') is None
    assert leading_time_ns(b'\x00\x01\x00\x00' + struct.pack('<iI', -1, 0)) is None


@pytest.mark.parametrize('type_name, kind', [
    ('rosgraph_msgs/msg/Clock', STAMP_CLOCK),
    ('rwpend_msgs/msg/EncoderCounts', STAMP_HEADER),
    ('diagnostic_msgs/msg/DiagnosticArray', STAMP_HEADER),
    ('sensor_msgs/msg/JointState', STAMP_HEADER),
    ('rcl_interfaces/msg/Log', STAMP_NONE),            # a stamp, but not a Header: wall time
    ('rcl_interfaces/msg/ParameterEvent', STAMP_NONE),
])
def test_stamp_kind(type_name, kind):
    assert stamp_kind(type_name, msgdefs.joined_definition(type_name)) == kind


# ------------------------------------------------------------------ the writer's guarantee
def test_guard_raises_older_log_times_and_counts_them():
    g = LogTimeGuard()
    assert [g.admit('/x', t) for t in (100, 90, 90, 200, 150)] == [100, 100, 100, 200, 200]
    r = g.report()
    assert r['raised'] == 3 and r['topics']['/x'] == {'raised': 3, 'max_raise_ns': 50}


def test_bag_writer_writes_log_time_order_whatever_the_caller_gives(tmp_path):
    w = BagWriter(tmp_path / 'b')
    w.add_topic('/a', 'rwpend_msgs/msg/MotorCommand', default_qos())
    w.add_topic('/b', 'rwpend_msgs/msg/MotorCommand', default_qos())
    asked = [('/a', 100), ('/b', 90), ('/a', 300), ('/b', 200), ('/b', 300), ('/a', 50)]
    for topic, t in asked:
        w.write(topic, stamped(t), t)
    w.close()
    msgs = [r for r in records(w.mcap_path) if isinstance(r, Message)]
    assert [m.log_time for m in msgs] == [100, 100, 300, 300, 300, 300]
    assert [m.publish_time for m in msgs] == [t for _, t in asked]    # their own time is kept
    assert w.guard.report()['raised'] == 3
    assert w.guard.report()['topics'] == {'/a': {'raised': 1, 'max_raise_ns': 250},
                                          '/b': {'raised': 2, 'max_raise_ns': 100}}


def test_chunks_end_between_two_log_times(tmp_path):
    """Many messages per log time (lockstep): no two chunks' time ranges overlap."""
    from mcap.records import Chunk
    w = BagWriter(tmp_path / 'c', chunk_bytes=2000)
    w.add_topic('/a', 'rwpend_msgs/msg/MotorCommand', default_qos())
    for k in range(60):
        for _ in range(25):
            w.write('/a', stamped(k * MS, b'x' * 40), k * MS)
    w.close()
    with open(w.mcap_path, 'rb') as f:
        chunks = [r for r in StreamReader(f, emit_chunks=True).records if isinstance(r, Chunk)]
    assert len(chunks) > 10
    assert all(a.message_end_time < b.message_start_time for a, b in zip(chunks, chunks[1:]))
    assert file_log_times(w.mcap_path) == [k * MS for k in range(60) for _ in range(25)]


# ------------------------------------------------------------------ rosbag2 metadata in the MCAP
def test_mcap_carries_the_rosbag2_metadata_record_as_jazzy_writes_it(tmp_path):
    w = BagWriter(tmp_path / 'm')
    w.add_topic('/rwpend/command', 'rwpend_msgs/msg/MotorCommand', [default_qos(depth=10, history='keep_last')])
    w.write('/rwpend/command', stamped(5 * MS), 5 * MS)
    w.write('/rwpend/command', stamped(7 * MS), 7 * MS)
    w.close({'k': 'v'})
    recs = records(w.mcap_path)
    header = next(r for r in recs if isinstance(r, Header))
    assert header.profile == 'ros2' and header.library.startswith('rwpend_bag ')
    metas = [r for r in recs if isinstance(r, Metadata)]
    assert [m.name for m in metas] == [METADATA_RECORD, METADATA_RECORD] == ['rosbag2', 'rosbag2']
    assert all(set(m.metadata) == {METADATA_KEY} == {'serialized_metadata'} for m in metas)
    first, last = (yaml.safe_load(m.metadata['serialized_metadata']) for m in metas)
    # written at open, before anything was recorded (as Jazzy's SequentialWriter::open)
    assert first['message_count'] == 0 and first['topics_with_message_count'] == []
    assert first['starting_time'] == {'nanoseconds_since_epoch': 2 ** 63 - 1}
    # the final one is metadata.yaml's content, keys in Jazzy's order
    on_disk = yaml.safe_load((tmp_path / 'm' / 'metadata.yaml').read_text())
    assert last == on_disk['rosbag2_bagfile_information']
    assert list(last) == ['version', 'storage_identifier', 'duration', 'starting_time', 'message_count',
                          'topics_with_message_count', 'compression_format', 'compression_mode',
                          'relative_file_paths', 'files', 'custom_data', 'ros_distro']
    assert last['version'] == 9 and last['storage_identifier'] == 'mcap' and last['ros_distro'] == 'jazzy'
    assert last['message_count'] == 2 and last['duration'] == {'nanoseconds': 2 * MS}
    assert last['relative_file_paths'] == ['m_0.mcap'] and last['custom_data'] == {'k': 'v'}
    tm = last['topics_with_message_count'][0]['topic_metadata']
    assert tm['offered_qos_profiles'][0]['history'] == 'keep_last'
    assert tm['type_description_hash'].startswith('RIHS01_')
    ch = next(r for r in recs if isinstance(r, Channel))
    assert set(ch.metadata) == {'offered_qos_profiles', 'topic_type_hash'}
    assert ch.metadata['topic_type_hash'] == tm['type_description_hash']
    assert yaml.safe_load(ch.metadata['offered_qos_profiles']) == tm['offered_qos_profiles']


def test_rosbags_reads_our_serialized_metadata(tmp_path):
    """rosbags' MCAP reader takes the topics' QoS and hash from our file."""
    from rosbags.rosbag2 import Reader
    recs = synth.make_run(duration=0.2)
    w = synth.write_ours(tmp_path / 'r', recs)
    with Reader(tmp_path / 'r') as r:
        conns = {c.topic: c for c in r.connections}
        assert set(conns) == set(synth.TYPES)
        assert conns['/rwpend/encoders'].digest == w.topics['/rwpend/encoders']['hash']
        assert r.message_count == len(recs)


# ------------------------------------------------------------------ lockstep order
LOOP = (('/rwpend/encoders', STAMP_HEADER), ('/clock', STAMP_CLOCK), ('/rwpend/sim/true_state', STAMP_HEADER),
        ('/rwpend/state', STAMP_HEADER), ('/rwpend/joint_states', STAMP_HEADER),
        ('/rwpend/command', STAMP_HEADER), ('/rwpend/controller/status', STAMP_HEADER))


def lockstep_stream(n, h_ns=MS):
    """The messages of n lockstep samples in publish order: per sample the loop topics (status
    every 10th), /diagnostics (stamped) now and then, /rosout (no Header)."""
    out = []
    for k in range(n):
        t = k * h_ns
        for topic, _ in LOOP:
            if topic.endswith('status') and k % 10:
                continue
            out.append((topic, stamped(t, topic.encode() + k.to_bytes(4, 'little'))))
        if k % 97 == 5:
            out.append(('/diagnostics', stamped(t, b'diag%d' % k)))
        if k % 211 == 3:
            out.append(('/rosout', b'log%d' % k))
    return out


def arrive(stream, seed, max_lag):
    """The same messages as a recorder may take them: each topic in its own order (one DDS
    reader each), topics interleaved differently, any topic up to ``max_lag`` messages late."""
    rng = random.Random(seed)
    last: dict[str, float] = {}
    keyed = []
    for i, (topic, data) in enumerate(stream):
        at = max(last.get(topic, -1.0) + 1e-6, i + rng.uniform(0, max_lag))
        last[topic] = at
        keyed.append((at, topic, data))
    keyed.sort(key=lambda x: x[0])
    return [(topic, data) for _, topic, data in keyed]


def run_order(arrivals, **kw):
    order = SimTimeOrder(**kw)
    for topic, kind in LOOP + (('/diagnostics', STAMP_HEADER), ('/rosout', STAMP_NONE)):
        order.add_topic(topic, kind)
    out = []
    for topic, data in arrivals:
        out += order.push(topic, data, arrival_ns=random.getrandbits(40))
    out += order.flush()
    return out, order


def test_sim_time_order_is_the_same_whatever_the_arrival_order():
    stream = lockstep_stream(2000)
    loop = {t for t, _ in LOOP}
    outs = []
    for seed in (1, 2, 3):
        out, order = run_order(arrive(stream, seed, max_lag=300))
        rep = order.report()
        assert rep['late'] == 0 and rep['forced'] == 0 and rep['deterministic_order'], rep
        assert len(out) == len(stream)
        times = [e.log_ns for e in out]
        assert times == sorted(times), 'log times non-decreasing in write order'
        outs.append([(e.topic, e.log_ns, e.publish_ns, e.data) for e in out if e.topic in loop])
    assert outs[0] == outs[1] == outs[2]
    # sorted by (sim time, topic, arrival within topic); stamps are the log times
    assert outs[0][:7] == sorted(outs[0][:7], key=lambda e: e[0])
    assert all(e[1] == leading_time_ns(e[3]) for e in outs[0])
    assert rep['topics']['/rosout']['at_sim_time'] == len([s for s in stream if s[0] == '/rosout'])
    assert order.peak_held <= 7 * (logtime.HOLD_CLOCKS + 60)


def test_sim_time_order_holds_a_bounded_number():
    out, order = run_order(arrive(lockstep_stream(3000), 7, max_lag=50), hold_clocks=100)
    # ~hold_clocks samples of 6-7 messages, plus the lag of the arrivals
    assert order.peak_held <= 7 * (100 + 10)
    assert order.report()['late'] == 0


def test_a_message_later_than_the_hold_is_written_at_once_and_counted():
    order = SimTimeOrder(hold_clocks=2)
    order.add_topic('/clock', STAMP_CLOCK)
    order.add_topic('/s', STAMP_HEADER)
    out = []
    for k in range(6):
        out += order.push('/clock', stamped(k * MS))
    out += order.push('/s', stamped(1 * MS, b'late'))      # the order up to 3 ms is written
    out += order.flush()
    assert [e.log_ns for e in out] == sorted(e.log_ns for e in out)
    late = [e for e in out if e.topic == '/s']
    assert late[0].log_ns == 3 * MS and late[0].publish_ns == 1 * MS
    rep = order.report()
    assert rep['late'] == 1 and rep['topics']['/s']['max_late_ns'] == 2 * MS
    assert not rep['deterministic_order']
    assert any('LATE: /s: 1 message(s)' in line for line in logtime.describe(rep))


def test_a_full_buffer_releases_its_oldest_counted():
    order = SimTimeOrder(hold_clocks=5, max_held=3)
    order.add_topic('/s', STAMP_HEADER)                    # no /clock at all
    out = []
    for k in (5, 1, 4, 2, 3, 9, 0):
        out += order.push('/s', stamped(k * MS))
    out += order.flush()
    assert [e.log_ns for e in out] == sorted(e.log_ns for e in out)
    assert len(out) == 7
    rep = order.report()
    assert rep['forced'] == 3 and rep['late'] == 1 and not rep['deterministic_order']


def test_stamps_off_the_sim_clock_and_unstamped_messages_take_the_newest_clock():
    order = SimTimeOrder(hold_clocks=1)
    for topic, kind in (('/clock', STAMP_CLOCK), ('/s', STAMP_HEADER), ('/rosout', STAMP_NONE)):
        order.add_topic(topic, kind)
    out = order.push('/clock', stamped(2 * MS))
    out += order.push('/s', stamped(1_790_000_000 * 10 ** 9))   # a wall-clock stamp
    out += order.push('/rosout', b'text')
    out += order.push('/clock', stamped(3 * MS))
    out += order.push('/clock', stamped(4 * MS))
    out += order.flush()
    by = {e.topic: e.log_ns for e in out}
    assert by['/s'] == 2 * MS and by['/rosout'] == 2 * MS
    c = order.report()['topics']
    assert c['/s']['off_clock'] == 1 and c['/rosout']['at_sim_time'] == 1


def test_arrival_order_logs_at_the_time_given():
    o = ArrivalOrder()
    assert o.push('/x', b'd', 42) == [logtime.Entry('/x', b'd', 42, 42)] and o.flush() == []


def test_threaded_writer_in_sim_time(tmp_path):
    """End to end: the recorder's writer with SimTimeOrder writes sim-time log times in order
    and says so in the report and the metadata."""
    w = ThreadedBagWriter(tmp_path / 'ls', order=SimTimeOrder(hold_clocks=3))
    w.add_topic('/clock', 'rosgraph_msgs/msg/Clock', default_qos())
    w.add_topic('/rwpend/command', 'rwpend_msgs/msg/MotorCommand', default_qos())
    cmd = lambda k: stamped(k * MS, struct.pack('<I', 0) + b'\0' * 4 + struct.pack('<Qd', k, 0.5))  # noqa: E731
    puts = []
    for k in range(20):
        puts.append(('/clock', stamped(k * MS)))
        if k >= 2:
            puts.append(('/rwpend/command', cmd(k - 2)))      # the commands run 2 samples behind
    for i, (topic, data) in enumerate(puts):
        w.put(topic, data, 10 ** 18 - i)                     # wall times: ignored (and backwards)
    rep = w.close()
    assert rep['log_times']['deterministic_order'] and rep['log_times']['written']['raised'] == 0
    msgs = [r for r in records(w.bag.mcap_path) if isinstance(r, Message)]
    times = [m.log_time for m in msgs]
    assert times == sorted(times) and max(times) == 19 * MS and len(msgs) == len(puts)
    meta = yaml.safe_load((tmp_path / 'ls' / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert meta['custom_data']['rwpend.log_time'] == 'sim'
    assert meta['starting_time'] == {'nanoseconds_since_epoch': 0}


# ------------------------------------------------------------------ the same bag
def _loop_bag(path, arrivals):
    types = {'/clock': 'rosgraph_msgs/msg/Clock', '/rwpend/command': 'rwpend_msgs/msg/MotorCommand',
             '/diagnostics': 'diagnostic_msgs/msg/DiagnosticArray'}
    w = ThreadedBagWriter(path, order=SimTimeOrder(hold_clocks=5))
    for t, typ in types.items():
        w.add_topic(t, typ, default_qos())
    for topic, data in arrivals:
        w.put(topic, data, 0)
    w.close()


def test_same_bag_compares_loop_topics_only(tmp_path):
    stream = []
    for k in range(300):
        stream.append(('/clock', stamped(k * MS)))
        stream.append(('/rwpend/command', stamped(k * MS, b'u%d' % k)))
        if k % 50 == 0:     # a non-loop topic whose content differs from run to run
            stream.append(('/diagnostics', stamped(k * MS, b'wall %f' % random.random())))
    _loop_bag(tmp_path / 'a', arrive(stream, 1, max_lag=4))
    _loop_bag(tmp_path / 'b', arrive(stream, 2, max_lag=4))
    assert sameness.compare(tmp_path / 'a', tmp_path / 'b') == []
    other = [(t, d.replace(b'u7', b'u8') if t == '/rwpend/command' else d) for t, d in stream]
    _loop_bag(tmp_path / 'c', other)
    diffs = sameness.compare(tmp_path / 'a', tmp_path / 'c')
    assert diffs and 'data' in diffs[0], diffs
    _loop_bag(tmp_path / 'd', [s for s in stream if s[1] != stamped(5 * MS, b'u5')])
    assert any('300 vs 299 messages' in d for d in sameness.compare(tmp_path / 'a', tmp_path / 'd'))


def test_order_faults_name_the_loop_topics_only():
    lt = {'hold_clocks': 10, 'topics': {'/diagnostics': {'late': 3}, '/rwpend/state': {'late': 1},
                                        '/clock': {'forced': 2}, '/rwpend/command': {}}}
    assert sameness.order_faults(lt) == {'/clock': {'forced': 2}, '/rwpend/state': {'late': 1}}
    assert sameness.order_faults({'hold_clocks': 10, 'topics': {'/diagnostics': {'late': 3}}}) == {}
    assert '*' in sameness.order_faults(ArrivalOrder().report())
