"""wire.pack_diagnostic_array against rclpy's serializer and decoder."""
import random

import pytest
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.serialization import deserialize_message, serialize_message

from rwpend_ros import wire


def objects(sec, nanosec, statuses, frame_id=''):
    arr = DiagnosticArray()
    arr.header.stamp.sec, arr.header.stamp.nanosec = sec, nanosec
    arr.header.frame_id = frame_id
    for level, name, message, hw, values in statuses:
        arr.status.append(DiagnosticStatus(
            level=level if isinstance(level, bytes) else bytes([level]), name=name, message=message,
            hardware_id=hw, values=[KeyValue(key=str(k), value=str(v)) for k, v in dict(values).items()]))
    return arr


@pytest.mark.parametrize('seed', range(40))
def test_same_bytes_as_rclpy(seed):
    rnd = random.Random(seed)
    alphabet = 'abcxyz_/: 0123456789éü→'

    def text():
        return ''.join(rnd.choice(alphabet) for _ in range(rnd.randrange(0, 13)))
    statuses = []
    for _ in range(rnd.randrange(0, 4)):
        values = {f'k{i}{text()}': rnd.choice([text(), rnd.randrange(-10**6, 10**6), rnd.random(), True, None])
                  for i in range(rnd.randrange(0, 30))}
        statuses.append((rnd.choice([0, 1, 2, 3, DiagnosticStatus.WARN]), text(), text(), text(), values))
    sec, nanosec = rnd.randrange(0, 2**31), rnd.randrange(0, 10**9)
    frame = text()
    data = wire.pack_diagnostic_array(sec, nanosec, statuses, frame)
    ref = objects(sec, nanosec, statuses, frame)
    # rclpy's serializer leaves the alignment padding as it finds it (not zeroed), so the
    # bytes are compared through the decoder, and the length (the padding included) exactly
    assert len(data) == len(serialize_message(ref))
    assert deserialize_message(data, DiagnosticArray) == ref
    assert wire.pack_diagnostic_array(sec, nanosec, statuses, frame) == data    # deterministic


def test_values_as_pairs_and_the_status_levels():
    data = wire.pack_diagnostic_array(1, 2, [(DiagnosticStatus.ERROR, '/r/sim', 'stale', 'hw', [('a', 1), ('b', 'x')])])
    msg = deserialize_message(data, DiagnosticArray)
    st, = msg.status
    assert st.level == DiagnosticStatus.ERROR and [(kv.key, kv.value) for kv in st.values] == [('a', '1'), ('b', 'x')]
