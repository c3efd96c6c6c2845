"""The recorder's lockstep progress (``rwpend record --progress``) is held back while a fast
topic waits for DDS: a message its publisher wrote to DDS alone (the merge holds the fast
ones after it), or fast messages DDS has not brought yet (syncing). Otherwise a recorder whose
DDS reader lags far behind the fast path would let the run go on and deliver those messages
late, out of order (PERFORMANCE.md, 17.)."""
from __future__ import annotations

import os
import random
import time

import pytest
import rclpy

from rwpend_ros import hostbus
from rwpend_ros.common import RECORDER_PROGRESS_EVERY
from rwpend_ros.transport import apply_transport

from rwpend_bag import recorder_node
from rwpend_bag.recorder_node import Recorder


class Published(list):
    def publish(self, data):
        self.append(data)


@pytest.fixture
def recorder(tmp_path, monkeypatch):
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    apply_transport(env)
    for k, v in env.items():
        monkeypatch.setenv(k, v)
    rclpy.init(domain_id=random.SystemRandom().randint(100, 230))
    node = Recorder(str(tmp_path / 'bag'), ['/nothing'], False, progress='/progress_test/progress')
    node.progress_pub = Published()
    yield node
    node.close()
    node.destroy_node()
    hostbus.close_all()
    rclpy.shutdown()


def clocks(node, n, start=0):
    for i in range(start, start + n):
        node._clock_taken(b'clock%d' % i)


def test_progress_is_reported_every_n_clocks(recorder):
    clocks(recorder, 3 * RECORDER_PROGRESS_EVERY)
    assert recorder.progress_pub == [b'clock%d' % (k * RECORDER_PROGRESS_EVERY - 1) for k in (1, 2, 3)]
    assert recorder.progress_held == 0


def test_progress_waits_for_a_message_written_to_dds_alone(recorder):
    got = []
    merge = hostbus.Merge(got.append, hold=hostbus.KEEP, keep=hostbus.KEEP_POLLED)
    recorder.hostbus_merges = {'/command': merge}
    merge.from_dds(b'c0')                             # DDS first, then fast only after c1
    merge.from_fast(b'c2', fast_only=True, marker=b'c1')  # c1 went to DDS alone: not here yet
    assert merge.held
    clocks(recorder, 2 * RECORDER_PROGRESS_EVERY)
    assert recorder.progress_pub == [] and recorder.progress_held == 2
    recorder.poll_fast()                              # still waiting: still held back
    assert recorder.progress_pub == []
    merge.from_dds(b'c1')                             # DDS brings it: c1, c2 in order
    assert got == [b'c0', b'c1', b'c2'] and not merge.held
    recorder.poll_fast()                              # the newest due is reported, once
    assert recorder.progress_pub == [b'clock%d' % (2 * RECORDER_PROGRESS_EVERY - 1)]
    recorder.poll_fast()
    assert len(recorder.progress_pub) == 1


def test_progress_waits_while_dds_is_behind_the_fast_path(recorder):
    got = []
    merge = hostbus.Merge(got.append, hold=hostbus.KEEP, keep=hostbus.KEEP_POLLED)
    recorder.hostbus_merges = {'/state': merge}
    merge.from_fast(b's0')                            # written to DDS too: DDS delivers it
    clocks(recorder, RECORDER_PROGRESS_EVERY)
    assert recorder.progress_pub == []
    merge.from_dds(b's0')
    assert got == [b's0'] and merge.fast_mode
    recorder.poll_fast()
    assert recorder.progress_pub == [b'clock%d' % (RECORDER_PROGRESS_EVERY - 1)]


def test_progress_is_held_back_for_a_bounded_time(recorder, monkeypatch):
    """A DDS copy that never comes (its publisher died before DDS sent it) does not stop a
    lockstep run: after PROGRESS_DDS_WAIT_S the progress goes on (with a warning)."""
    monkeypatch.setattr(recorder_node, 'PROGRESS_DDS_WAIT_S', 0.05)
    merge = hostbus.Merge(lambda data: None, hold=hostbus.KEEP, keep=hostbus.KEEP_POLLED)
    recorder.hostbus_merges = {'/state': merge}
    merge.from_fast(b's0')                            # its DDS copy never comes
    clocks(recorder, RECORDER_PROGRESS_EVERY)
    assert recorder.progress_pub == []
    time.sleep(0.06)
    recorder.poll_fast()
    assert recorder.progress_pub == [b'clock%d' % (RECORDER_PROGRESS_EVERY - 1)]
    clocks(recorder, RECORDER_PROGRESS_EVERY, start=RECORDER_PROGRESS_EVERY)   # still waiting:
    assert len(recorder.progress_pub) == 2            # not held again in the same episode
