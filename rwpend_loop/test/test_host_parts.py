"""The host's plain parts (no rclpy): the loop lock, the recording publisher, the arguments."""
import pytest

from rwpend_loop.host import LoopLock, RecordingPublisher, parse_args, wire_bytes


class FakePub:
    topic_name = '/rwpend/encoders'

    def __init__(self, subscribers=0):
        self.sent = []
        self.subscribers = subscribers

    def publish(self, data):
        self.sent.append(data)

    def get_subscription_count(self):
        return self.subscribers


def test_recording_publisher_records_every_message_and_publishes_while_subscribed():
    pub = FakePub(subscribers=0)
    put = []
    rp = RecordingPublisher(pub, lambda topic, data, t: put.append((topic, data)))
    for i in range(RecordingPublisher.LOOK_EVERY + 10):
        rp.publish(bytes([i % 256]))
    assert len(put) == RecordingPublisher.LOOK_EVERY + 10 and put[0] == ('/rwpend/encoders', b'\x00\0\0\0')
    # published until it looked and found nobody, then not
    assert len(pub.sent) == RecordingPublisher.LOOK_EVERY - 1
    pub.subscribers = 1
    for i in range(RecordingPublisher.LOOK_EVERY):
        rp.publish(b'x')
    assert pub.sent[-1] == b'x', 'a subscriber that came gets the messages from the next look on'
    rp.publish(object())            # a message object: always published, never recorded
    assert len(put) == 2 * RecordingPublisher.LOOK_EVERY + 10
    # the rest is the rclpy publisher's (a node asks its publisher for its subscribers)
    assert rp.get_subscription_count() == 1 and rp.topic_name == '/rwpend/encoders'


def test_loop_lock_runs_callbacks_holding_it():
    lock = LoopLock()
    seen = []
    assert lock.call(lambda x: seen.append(lock.lock._is_owned()) or x, 5) == 5
    assert seen == [True]


def test_arguments():
    a, ros = parse_args(['sim', 'estimator', '--record', 'B', '--ros-args', '-r', '__ns:=/x'])
    assert a.nodes == ['sim', 'estimator'] and a.record == 'B' and ros == ['--ros-args', '-r', '__ns:=/x']
    assert parse_args([])[0].nodes == ['sim', 'estimator', 'controller']
    for bad in (['estimator'], ['sim', 'sim'], ['sim', 'bogus'], ['sim', 'controller'], ['controller'],
                ['estimator', 'controller', '--record', 'B'], ['estimator', 'controller', '--sim-time']):
        with pytest.raises(SystemExit):
            parse_args(bad)
    assert parse_args(['estimator', 'controller'])[0].nodes == ['estimator', 'controller']   # rwpend_loop.control


def test_recorded_bytes_are_padded_as_dds_delivers_them():
    assert wire_bytes(b'abcdef') == b'abcdef\0\0' and wire_bytes(b'abcd') == b'abcd'
    assert wire_bytes(bytearray(b'a')) == b'a\0\0\0'
