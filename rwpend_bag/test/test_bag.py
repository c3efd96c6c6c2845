"""Pure tests of the bag package (no rclpy): writer, reader, recovery, decoding, info, analysis."""
from __future__ import annotations

import json
import math
import shutil

import numpy as np
import pytest

from rwpend_bag import analysis, cdr, cli, msgdefs
from support import synth
from rwpend_bag.info import bag_info
from rwpend_bag.reader import read_bag
from rwpend_bag.seqtrack import SeqTracker
from rwpend_bag.writer import BagError, BagWriter, ThreadedBagWriter, default_qos


@pytest.fixture(scope='module')
def records():
    return synth.make_run(duration=12.0, drop_command={100, 101, 102})


@pytest.fixture(scope='module')
def ours(tmp_path_factory, records):
    p = tmp_path_factory.mktemp('b') / 'ours'
    synth.write_ours(p, records)
    return p


@pytest.fixture(scope='module')
def theirs(tmp_path_factory, records):
    p = tmp_path_factory.mktemp('b') / 'theirs'
    synth.write_rosbags(p, records)
    return p


def _counts(records):
    out = {}
    for topic, _, _ in records:
        out[topic] = out.get(topic, 0) + 1
    return out


def test_joined_definition_and_hash():
    text = msgdefs.joined_definition('rwpend_msgs/msg/EncoderCounts')
    assert text.startswith(msgdefs.msg_text('rwpend_msgs/msg/EncoderCounts').rstrip('\n'))
    assert '=' * 80 + '\nMSG: std_msgs/Header\n' in text
    assert '\nMSG: builtin_interfaces/Time\n' in text
    # equal to rosidl's hash (rwpend_msgs/msg/EncoderCounts.json written by the rosidl build)
    ref = json.loads((msgdefs.share_dirs()[0] / 'rwpend_msgs/msg/EncoderCounts.json').read_text()) \
        if (msgdefs.share_dirs()[0] / 'rwpend_msgs/msg/EncoderCounts.json').exists() else None
    h = msgdefs.type_hash('rwpend_msgs/msg/EncoderCounts')
    assert h.startswith('RIHS01_')
    if ref:
        assert h == ref['type_hashes'][0]['hash_string']


def test_round_trip_ours(ours, records):
    bag = read_bag(ours)
    assert bag.complete and not bag.warnings
    assert {n: t.count for n, t in bag.topics.items()} == _counts(records)
    meta = bag.metadata
    assert meta['version'] == 9 and meta['storage_identifier'] == 'mcap'
    assert meta['relative_file_paths'] == ['ours_0.mcap']
    assert meta['message_count'] == len(records)
    tm = meta['topics_with_message_count'][0]['topic_metadata']
    assert isinstance(tm['offered_qos_profiles'], list)
    assert tm['type_description_hash'].startswith('RIHS01_')
    # bytes untouched, in order
    enc = [d for t, _, d in records if t == '/rwpend/encoders']
    assert bag.topics['/rwpend/encoders'].datas == enc


def test_ours_read_by_rosbags_and_mcap_ros2(ours, records):
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore
    with AnyReader([ours], default_typestore=get_typestore(Stores.EMPTY)) as r:
        n = 0
        seqs = []
        for conn, t, raw in r.messages():
            n += 1
            if conn.topic == '/rwpend/encoders':
                seqs.append(r.deserialize(raw, conn.msgtype).seq)
        assert n == len(records)
        assert seqs == list(range(len(seqs)))
        qos = [c.ext.offered_qos_profiles for c in r.connections]
        assert all(q and q[0].depth == 10 for q in qos)
    from mcap_ros2.reader import read_ros2_messages
    got = [(m.channel.topic, m.ros_msg) for m in read_ros2_messages(str(ours / 'ours_0.mcap'))]
    assert len(got) == len(records)
    st = [m for t, m in got if t == '/rwpend/controller/status']
    assert st[-1].law == 'balance' and st[0].header.frame_id == 'rig'


def test_rosbags_bag_read_by_our_tools(theirs, records, tmp_path, capsys):
    info = bag_info(theirs)
    assert info['message_count'] == len(records)
    cmd = info['topics']['/rwpend/command']
    assert cmd['seq']['missing'] == 3 and cmd['seq']['gaps'] == [[100, 102]]
    assert info['topics']['/rwpend/encoders']['seq']['missing'] == 0
    assert abs(info['topics']['/rwpend/encoders']['rate_hz'] - 1000) < 1
    assert cli.info_main([str(theirs)]) == 0
    assert 'MISSING 3' in capsys.readouterr().out
    png = tmp_path / 'run.png'
    assert cli.analyze_main([str(theirs), '--json', '--plot', str(png)]) == 0
    m = json.loads(capsys.readouterr().out)
    assert m['theta_source'] == '/rwpend/sim/true_state'
    assert png.stat().st_size > 10000


def test_decode_matches_rosbags(ours):
    store = synth.typestore()
    bag = read_bag(ours)
    for name, t in bag.topics.items():
        cols, bulk = cdr.decode(t.type, t.schema, t.datas)
        assert bulk, name
        for i in (0, 1, len(t.datas) // 2, len(t.datas) - 1):
            msg = store.deserialize_cdr(t.datas[i], t.type)
            for path, col in cols.items():
                v = msg
                for part in path.split('.'):
                    v = getattr(v, part)
                assert col[i] == v, (name, path, i)


def test_fallback_decoder_for_sequences():
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore
    typ = 'sensor_msgs/msg/JointState'
    text = msgdefs.joined_definition(typ)
    store = get_typestore(Stores.EMPTY)
    store.register(get_types_from_msg(text, typ))
    JS, H, T = (store.types[x] for x in (typ, 'std_msgs/msg/Header', 'builtin_interfaces/msg/Time'))
    datas = [bytes(store.serialize_cdr(JS(header=H(stamp=T(sec=1, nanosec=k), frame_id='r'),
                                          name=['pendulum', 'wheel'][:1 + k % 2],
                                          position=np.arange(1 + k % 2, dtype=float),
                                          velocity=np.zeros(0), effort=np.zeros(0)), typ))
             for k in range(20)]
    cols, bulk = cdr.decode(typ, text, datas)
    assert not bulk
    assert list(cols['header.stamp.nanosec']) == list(range(20))


def test_seq_of_and_tracker(records):
    enc = [d for t, _, d in records if t == '/rwpend/encoders'][:50]
    assert [cdr.seq_of(d) for d in enc] == list(range(50))
    tr = SeqTracker()
    tr.register('/e', 'rwpend_msgs/msg/EncoderCounts')
    for i, d in enumerate(enc):
        if i not in (5, 6, 20):
            tr.add('/e', d)
    r = tr.report()['/e']
    assert r['received'] == 47 and r['missing'] == 3 and r['gaps'] == [[5, 6], [20, 20]]
    assert 'missed 3 in 2 gap(s)' in r['text']
    tr2 = SeqTracker()
    tr2.register('/e', 'rwpend_msgs/msg/EncoderCounts')
    for d in enc:
        tr2.add('/e', d)
    assert tr2.report()['/e']['text'].startswith('recorded 50 of 50 (no gaps)')


def test_tracker_late_messages_fill_their_gaps_restarts_do_not():
    tr = SeqTracker()
    # 0..9, then 15..19, then 10..14 late (a DDS copy behind the fast path), then 20..24
    for s in [*range(10), *range(15, 20), 12, 10, 14, 11, 13, *range(20, 25)]:
        tr.add_seq_array('/e', [s])
    r = tr.report()['/e']
    assert r['received'] == 25 and r['missing'] == 0 and r['gaps'] == []
    assert r['out_of_order'] == 5 and r['late'] == 5 and r['seq']['last'] == 24
    assert 'no gaps' in r['text'] and '5 came late' in r['text'] and 'went back' not in r['text']
    # a gap left partly open: the rest is still missing
    tr = SeqTracker()
    for s in [0, 1, 5, 3, 6]:
        tr.add_seq_array('/e', [s])
    r = tr.report()['/e']
    assert r['missing'] == 2 and r['gaps'] == [[2, 2], [4, 4]] and r['late'] == 1
    # a publisher restart (seq from 0 again) is not a late message: the first run's gap stays
    # missing, a late message of the new run fills the new run's gap only
    tr = SeqTracker()
    for s in [0, 1, 2, 4, 5, 0, 1, 3, 4, 2]:
        tr.add_seq_array('/e', [s])
    r = tr.report()['/e']
    assert r['missing'] == 1 and r['gaps'] == [[3, 3]]
    assert r['out_of_order'] == 2 and r['late'] == 1 and r['duplicates'] == 0
    assert '1 came late' in r['text'] and '1 went back' in r['text']


def test_threaded_writer_report(tmp_path, records):
    w = ThreadedBagWriter(tmp_path / 'tw')
    w.add_topic('/rwpend/encoders', 'rwpend_msgs/msg/EncoderCounts', default_qos())
    enc = [(d, ns) for t, ns, d in records if t == '/rwpend/encoders']
    for d, ns in enc:
        w.put('/rwpend/encoders', d, ns)
    rep = w.close()
    assert rep['topics']['/rwpend/encoders']['missing'] == 0
    assert rep['topics']['/rwpend/encoders']['received'] == len(enc)
    assert json.loads((tmp_path / 'tw' / 'recording_report.json').read_text())['message_count'] == len(enc)
    meta = read_bag(tmp_path / 'tw').metadata
    assert 'rwpend.recording_report' in meta['custom_data']


def test_writer_refuses_existing_bag(ours):
    with pytest.raises(BagError):
        BagWriter(ours)


def test_truncated_bag_recovers_completed_chunks(tmp_path, records):
    """SIGKILL while writing: a copy of the unfinished file reads up to its last complete chunk."""
    w = BagWriter(tmp_path / 'live', chunk_bytes=64 * 1024)
    for t, typ in synth.TYPES.items():
        w.add_topic(t, typ, default_qos())
    half = len(records) // 2
    for topic, ns, data in records[:half]:
        w.write(topic, data, ns)
    w._stream.flush()
    live = tmp_path / 'live' / 'live_0.mcap'
    crash = tmp_path / 'crash'
    crash.mkdir()
    shutil.copy(live, crash / 'crash_0.mcap')       # as a SIGKILL would leave it
    w.close()
    bag = read_bag(crash)
    assert not bag.complete and bag.warnings
    n = bag.message_count
    assert 0 < n <= half and n > half - 20000   # all but the open chunk
    enc = bag.topics['/rwpend/encoders']
    assert [cdr.seq_of(d) for d in enc.datas] == list(range(enc.count))
    # cut the file in the middle of a chunk: everything before it is still read
    data = (crash / 'crash_0.mcap').read_bytes()
    for cut in (len(data) - 1, len(data) // 2, len(data) // 3 + 7):
        (crash / 'crash_0.mcap').write_bytes(data[:cut])
        b = read_bag(crash)
        assert b.message_count <= n
        e = b.topics.get('/rwpend/encoders')
        if e:
            assert [cdr.seq_of(d) for d in e.datas] == list(range(e.count))
        assert cli.info_main([str(crash)]) == 0


def test_analysis_metrics(ours):
    m = analysis.analyze(ours)
    # synth: theta = pi (t/3)^2 reaches pi - 0.5 at t = 3 sqrt(1 - 0.5/pi)
    assert m['swing_up_time_s'] == pytest.approx(3 * math.sqrt(1 - 0.5 / math.pi), abs=2e-3)
    assert m['time_to_catch_s'] == pytest.approx(3.0, abs=0.011)
    assert m['mode_switches'] == 2
    assert m['limit_cycle']['period_s'] == pytest.approx(2.0, rel=0.01)
    assert m['limit_cycle']['amplitude_rad'] == pytest.approx(0.5, rel=0.02)
    assert m['balance_rms_rad'] == pytest.approx(0.01 / math.sqrt(2), rel=0.02)
    assert m['saturation_fraction'] == pytest.approx(3.0 / 12.0, abs=0.005)
    lat = m['loop_latency_ms']
    assert lat['p50'] == pytest.approx(0.4) and lat['matched'] == 12000 - 3
    assert m['estimator_gaps'] == {'resyncs': 1, 'missed': 40, 'longest_gap': 40, 'gaps': 1}
    assert 'estimator gaps:       1 re-synchronisations, 40 samples missed' in analysis.format_metrics(m)


def test_bench_decode(ours):
    b = analysis.bench_decode(ours, repeat=1)
    assert b['messages'] > 40000 and all(v['bulk'] for v in b['topics'].values())
    print(f"decode {b['msgs_per_s']:.0f} msgs/s, read {b['read_msgs_per_s']:.0f} msgs/s")
    # the rate is a benchmark figure (make bench, PERFORMANCE.md), not a pass/fail bound


def test_cli_usage_errors(tmp_path, ours, capsys):
    assert cli.info_main([str(tmp_path / 'missing')]) == 2
    assert cli.info_main([]) == 2
    assert cli.analyze_main([str(ours), '--plot', str(tmp_path / 'x.jpg')]) == 2
    assert cli.record_main(['-o', str(tmp_path / 'r')]) == 2
    assert cli.record_main(['-o', str(ours), '--all']) == 2
    assert cli.play_main([str(ours), '--rate', '0']) == 2
    assert cli.play_main([str(ours), '--remap', 'bad']) == 2
    assert cli.play_main([str(ours), '--topics', '/nope']) == 2
    (tmp_path / 'empty').mkdir()
    assert cli.analyze_main([str(tmp_path / 'empty')]) == 2
    (tmp_path / 'junk').mkdir()
    (tmp_path / 'junk' / 'junk_0.mcap').write_bytes(b'not an mcap file')
    assert cli.info_main([str(tmp_path / 'junk')]) == 2
    assert not (tmp_path / 'r').exists()


def test_player_schedule(ours):
    from rwpend_bag.player_core import schedule
    bag = read_bag(ours)
    s = schedule(bag, ['/rwpend/encoders', '/rwpend/command'], {'/rwpend/command': '/x/cmd'}, 2.0)
    assert {t.out_name for t in s.topics} == {'/rwpend/encoders', '/x/cmd'}
    assert np.all(np.diff(s.log_ns) >= 0) and s.rel_ns[0] == 0
    assert len(s) == pytest.approx(2 * 10000 - 3 + 3, abs=3)
