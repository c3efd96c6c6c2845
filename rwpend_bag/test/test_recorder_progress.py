"""The recorder's lockstep progress (``rwpend record --progress``): every
RECORDER_PROGRESS_EVERY /clock messages taken, that /clock is published."""
from __future__ import annotations

import os

import pytest
import rclpy

from rwpend_ros.testenv import test_domain_id
from rwpend_ros.qos import RECORDER_PROGRESS_EVERY
from rwpend_ros.transport import apply_transport

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
    rclpy.init(domain_id=test_domain_id())
    node = Recorder(str(tmp_path / 'bag'), ['/nothing'], False, progress='/progress_test/progress')
    node.progress_pub = Published()
    yield node
    node.close()
    node.destroy_node()
    rclpy.shutdown()


def test_progress_is_reported_every_n_clocks(recorder):
    for i in range(3 * RECORDER_PROGRESS_EVERY):
        recorder._clock_taken(b'clock%d' % i)
    assert recorder.progress_pub == [b'clock%d' % (k * RECORDER_PROGRESS_EVERY - 1) for k in (1, 2, 3)]


def test_the_callback_hands_its_time_to_the_writer(recorder, monkeypatch):
    """The callback's clock may step back (NTP): the callback passes its time as it is, the
    bag writer keeps the file's log times non-decreasing and counts what it raised
    (test_logtime.py)."""
    times = iter([100, 90, 90, 200])
    monkeypatch.setattr('time.time_ns', lambda: next(times))
    got = []
    recorder.writer.put = lambda topic, data, t: got.append(t)
    receive = recorder._receiver('/x')
    for _ in range(4):
        receive(b'm')
    assert got == [100, 90, 90, 200]

