"""The bag writer in a child process (rwpend_bag.procwriter): the same bag as the threaded
writer, refusals before anything starts, and a child or a parent that dies."""
from __future__ import annotations

import json
import multiprocessing
import pickle
import threading

import pytest

from rwpend_bag import sameness
from support import synth
from rwpend_bag.logtime import SimTimeOrder
from rwpend_bag.procwriter import DIED_WITHOUT_CLOSE, ProcessBagWriter, serve, start_process
from rwpend_bag.reader import read_bag
from rwpend_bag.writer import BagError, ThreadedBagWriter, default_qos

TYPES = {'/clock': 'rosgraph_msgs/msg/Clock', '/rwpend/encoders': 'rwpend_msgs/msg/EncoderCounts',
         '/rwpend/command': 'rwpend_msgs/msg/MotorCommand'}


@pytest.fixture(scope='module')
def records():
    return [r for r in synth.make_run(duration=2.0) if r[0] in TYPES]


def _write(writer, records):
    for name, typ in TYPES.items():
        writer.add_topic(name, typ, default_qos())
    for topic, ns, data in records:
        writer.put(topic, data, ns)
    return writer.close()


def test_the_same_bag_as_the_threaded_writer(tmp_path, records):
    a = _write(ThreadedBagWriter(tmp_path / 'thread', order=SimTimeOrder()), records)
    b = _write(ProcessBagWriter(tmp_path / 'process', order=SimTimeOrder()), records)
    assert sameness.compare(tmp_path / 'thread', tmp_path / 'process') == []
    assert b['message_count'] == a['message_count'] == len(records)
    assert b['topics'] == a['topics'] and 'writer_error' not in b
    assert json.loads((tmp_path / 'process' / 'recording_report.json').read_text())['message_count'] == len(records)
    assert read_bag(tmp_path / 'process').metadata['custom_data']['rwpend.log_time'] == 'sim'


def test_a_process_started_ahead_writes_the_same_bag(tmp_path, records):
    """The loop's process starts its writer before its own imports (rwpend_loop.host), and
    tells it the bag later: the bag is the one a writer started at once writes."""
    ahead = start_process()
    a = _write(ProcessBagWriter(tmp_path / 'now', order=SimTimeOrder()), records)
    b = _write(ProcessBagWriter(tmp_path / 'ahead', order=SimTimeOrder(), process=ahead), records)
    assert sameness.compare(tmp_path / 'now', tmp_path / 'ahead') == []
    assert b['message_count'] == a['message_count'] == len(records)


def test_a_process_started_ahead_and_never_told_writes_nothing(tmp_path):
    """A loop's process that ends before it records (a refused parameter) closes the pipe: the
    child ends at once, with no bag directory made."""
    ahead = start_process()
    ahead.conn.close()
    ahead.proc.join(timeout=30)
    assert ahead.proc.exitcode == 0
    assert list(tmp_path.iterdir()) == []


def test_an_existing_bag_is_refused_before_a_process_starts(tmp_path):
    (tmp_path / 'old').mkdir()
    (tmp_path / 'old' / 'x').write_text('x')
    before = multiprocessing.active_children()
    with pytest.raises(BagError, match='already exists'):
        ProcessBagWriter(tmp_path / 'old')
    assert multiprocessing.active_children() == before


def test_a_dead_child_is_reported_and_the_report_written(tmp_path, records):
    w = ProcessBagWriter(tmp_path / 'b')
    w._proc.kill()
    w._proc.join()
    rep = _write(w, records)
    assert 'gone' in rep['writer_error'] and 'not handed over' in rep['writer_error']
    assert w.lost > 0
    assert json.loads((tmp_path / 'b' / 'recording_report.json').read_text())['writer_error'] == rep['writer_error']


def test_a_parent_that_dies_leaves_a_finished_bag(tmp_path, records):
    """The pipe closes without a stop (the loop's process was killed): the child finishes the
    bag with every message it got, and the report says how it ended."""
    parent, child = multiprocessing.Pipe(duplex=True)
    t = threading.Thread(target=serve, args=(child, str(tmp_path / 'b'), None, {}, False))
    t.start()
    assert parent.recv() == ('ready', None)
    items = [('topic', n, typ, default_qos()) for n, typ in TYPES.items()]
    items += [('msg', topic, data, ns) for topic, ns, data in records]
    parent.send_bytes(pickle.dumps(items))
    parent.close()
    t.join(timeout=30)
    assert not t.is_alive()
    rep = json.loads((tmp_path / 'b' / 'recording_report.json').read_text())
    assert rep['writer_error'] == DIED_WITHOUT_CLOSE and rep['message_count'] == len(records)
    assert (tmp_path / 'b' / 'metadata.yaml').exists()
