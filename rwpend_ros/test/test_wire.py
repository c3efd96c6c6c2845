"""rwpend_ros.wire against rclpy's own CDR (de)serializer: bytes we publish raw decode to the same
message, and raw bytes rclpy produces decode with our unpackers."""
from __future__ import annotations

import pytest
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import JointState

from rwpend_msgs.msg import EncoderCounts, MotorCommand, StateEstimate
from rwpend_ros import wire

FRAMES = ['', 'a', 'rwpend', 'rig_2', 'abcdefgh', 'x' * 13]


def header(msg, frame, sec=12, nanosec=345_678_901):
    msg.header.frame_id = frame
    msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
    return msg


@pytest.mark.parametrize('frame', FRAMES)
def test_encoders_roundtrip(frame):
    m = header(EncoderCounts(), frame)
    m.seq, m.pendulum_counts, m.motor_counts = 2**40 + 3, -1234, 987654
    h, seq, pc, mc = wire.unpack_encoders(serialize_message(m))
    assert (seq, pc, mc) == (m.seq, m.pendulum_counts, m.motor_counts)
    assert wire.header_stamp(h) == (12, 345_678_901) and wire.header_frame_id(h) == frame
    assert h == wire.pack_header(12, 345_678_901, frame)
    back = deserialize_message(wire.pack_encoders(h, seq, pc, mc), EncoderCounts)
    assert back == m


@pytest.mark.parametrize('frame', FRAMES)
def test_command_roundtrip(frame):
    m = header(MotorCommand(), frame)
    m.seq, m.u = 77, -3.25
    assert wire.unpack_command(serialize_message(m)) == (77, -3.25)
    back = deserialize_message(wire.pack_command(wire.pack_header(12, 345_678_901, frame), 77, -3.25),
                               MotorCommand)
    assert back == m


@pytest.mark.parametrize('frame', FRAMES)
@pytest.mark.parametrize('name', ['', 'nonlinear', 'observer3'])
def test_state_pack(frame, name):
    p = wire.StatePacker(name)
    data = p.pack(wire.pack_header(12, 345_678_901, frame), 5, 0.1, -0.2, 3.0, -4.5, 0.01, 1e-3)
    m = deserialize_message(data, StateEstimate)
    assert m.header.frame_id == frame and m.header.stamp.sec == 12 and m.header.stamp.nanosec == 345_678_901
    assert (m.seq, m.theta, m.theta_dot, m.wheel_angle, m.wheel_rate, m.friction, m.energy) == \
        (5, 0.1, -0.2, 3.0, -4.5, 0.01, 1e-3)
    assert m.estimator == name


@pytest.mark.parametrize('frame', FRAMES)
@pytest.mark.parametrize('names', [('pendulum', 'wheel'), ('a', 'bcdefgh'), ('abc', 'd')])
def test_joint_state_pack(frame, names):
    p = wire.JointStatePacker(names)
    data = p.pack(wire.pack_header(1, 2, frame), 1.5, -2.5, 3.5, -4.5)
    m = deserialize_message(data, JointState)
    assert m.header.frame_id == frame and list(m.name) == list(names)
    assert list(m.position) == [1.5, -2.5] and list(m.velocity) == [3.5, -4.5] and len(m.effort) == 0
