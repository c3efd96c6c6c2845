"""rwpend_ros.wire against rclpy's own CDR (de)serializer: bytes we publish raw decode to the same
message, and raw bytes rclpy produces decode with our unpackers."""
from __future__ import annotations

import pytest
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import JointState

from rosgraph_msgs.msg import Clock

from rwpend_msgs.msg import EncoderCounts, MotorCommand, PlantState, StateEstimate
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
    assert wire.unpack_command_sender(serialize_message(m)) == (77, -3.25, 0, False)
    back = deserialize_message(wire.pack_command(wire.pack_header(12, 345_678_901, frame), 77, -3.25),
                               MotorCommand)
    assert back == m


COUNTERS = [(0, 0), (1, 0), (7, 412), (2**32 - 1, 2**32 - 1)]


@pytest.mark.parametrize('frame', FRAMES)
@pytest.mark.parametrize('source, release', [(1, False), (2**64 - 1, True), (0x1234_5678_9abc_def0, False)])
def test_command_sender_roundtrip(frame, source, release):
    m = header(MotorCommand(), frame)
    m.seq, m.u, m.controller_id, m.release = 9, 1.5, source, release
    data = serialize_message(m)
    assert wire.unpack_command_sender(data) == (9, 1.5, source, release)
    assert wire.command_sender(data) == source
    ours = wire.pack_command(wire.pack_header(12, 345_678_901, frame), 9, 1.5, source, release)
    assert deserialize_message(ours, MotorCommand) == m
    assert len(ours) == len(data)


def test_command_of_the_earlier_layout_is_anonymous():
    """A MotorCommand recorded before controller_id existed (header, seq, u) reads as id 0."""
    old = wire.pack_command(wire.pack_header(1, 2, 'rwpend'), 5, 0.5)[:-9]   # without id, release
    assert wire.unpack_command_sender(old) == (5, 0.5, 0, False)


@pytest.mark.parametrize('frame', FRAMES)
@pytest.mark.parametrize('name', ['', 'nonlinear', 'observer3'])
@pytest.mark.parametrize('resyncs, missed', COUNTERS)
def test_state_pack(frame, name, resyncs, missed):
    p = wire.StatePacker(name)
    data = p.pack(wire.pack_header(12, 345_678_901, frame), 5, 0.1, -0.2, 3.0, -4.5, 0.01, 1e-3,
                  resyncs, missed)
    m = deserialize_message(data, StateEstimate)
    assert m.header.frame_id == frame and m.header.stamp.sec == 12 and m.header.stamp.nanosec == 345_678_901
    assert (m.seq, m.theta, m.theta_dot, m.wheel_angle, m.wheel_rate, m.friction, m.energy) == \
        (5, 0.1, -0.2, 3.0, -4.5, 0.01, 1e-3)
    assert (m.resyncs, m.missed) == (resyncs, missed)
    assert m.estimator == name
    ref = header(StateEstimate(), frame)
    ref.seq, ref.theta, ref.theta_dot, ref.wheel_angle, ref.wheel_rate, ref.friction, ref.energy = \
        5, 0.1, -0.2, 3.0, -4.5, 0.01, 1e-3
    ref.resyncs, ref.missed, ref.estimator = resyncs, missed, name
    assert len(data) == len(serialize_message(ref))


def test_state_pack_counters_stay_uint32():
    """resyncs wraps (a controller compares it for a change), missed saturates."""
    data = wire.StatePacker('x').pack(wire.pack_header(0, 0, ''), 1, 0, 0, 0, 0, 0, 0, 2**32 + 3, 2**40)
    m = deserialize_message(data, StateEstimate)
    assert (m.resyncs, m.missed) == (3, 2**32 - 1)


@pytest.mark.parametrize('frame', FRAMES)
@pytest.mark.parametrize('names', [('pendulum', 'wheel'), ('a', 'bcdefgh'), ('abc', 'd')])
def test_joint_state_pack(frame, names):
    p = wire.JointStatePacker(names)
    data = p.pack(wire.pack_header(1, 2, frame), 1.5, -2.5, 3.5, -4.5)
    m = deserialize_message(data, JointState)
    assert m.header.frame_id == frame and list(m.name) == list(names)
    assert list(m.position) == [1.5, -2.5] and list(m.velocity) == [3.5, -4.5] and len(m.effort) == 0


@pytest.mark.parametrize('frame', FRAMES)
@pytest.mark.parametrize('name', ['', 'observer2'])
@pytest.mark.parametrize('resyncs, missed', COUNTERS)
def test_state_unpack(frame, name, resyncs, missed):
    m = header(StateEstimate(), frame)
    m.seq, m.theta, m.theta_dot, m.wheel_angle, m.wheel_rate, m.friction, m.energy = \
        2**33 + 1, 3.1, -0.5, 12.0, -300.25, 0.125, -1e-9
    m.resyncs, m.missed = resyncs, missed
    m.estimator = name
    h, *rest = wire.unpack_state(serialize_message(m))
    assert tuple(rest) == (m.seq, m.theta, m.theta_dot, m.wheel_angle, m.wheel_rate, m.friction, m.energy,
                           resyncs, missed)
    assert h == wire.pack_header(12, 345_678_901, frame)


@pytest.mark.parametrize('frame', FRAMES)
@pytest.mark.parametrize('flags', [(False, False), (True, False), (False, True), (True, True)])
def test_plant_state_pack(frame, flags):
    data = wire.pack_plant_state(wire.pack_header(12, 345_678_901, frame), 9, -1, 0.1, 0.2, 0.3, 0.4,
                                 -10.0, -9.5, 0.7, 1.5, *flags)
    m = deserialize_message(data, PlantState)
    ref = header(PlantState(), frame)
    ref.seq, ref.command_seq, ref.theta, ref.theta_dot, ref.wheel_angle, ref.wheel_rate = 9, -1, 0.1, 0.2, 0.3, 0.4
    ref.u_commanded, ref.u_applied, ref.friction, ref.disturbance = -10.0, -9.5, 0.7, 1.5
    ref.stuck, ref.command_timeout = flags
    assert m == ref    # (not byte-equal: rclpy leaves its padding bytes uninitialised)


@pytest.mark.parametrize('frame', FRAMES)
def test_applied_command_pack(frame):
    from rwpend_msgs.msg import AppliedCommand
    data = wire.pack_applied(wire.pack_header(12, 345_678_901, frame), 2**40 + 3, -1, -9.999)
    m = deserialize_message(data, AppliedCommand)
    ref = header(AppliedCommand(), frame)
    ref.seq, ref.command_seq, ref.u = 2**40 + 3, -1, -9.999
    assert m == ref


def test_clock_pack():
    c = Clock()
    c.clock.sec, c.clock.nanosec = 5, 999_000_000
    assert wire.pack_clock(5, 999_000_000) == serialize_message(c)


@pytest.mark.parametrize('unpack', [wire.unpack_encoders, wire.unpack_command, wire.unpack_state])
@pytest.mark.parametrize('data', [b'', b'\x00\x01\x00\x00', b'\x00\x01\x00\x00' + b'\xff' * 12])
def test_truncated_raises_struct_error(unpack, data):
    """Malformed bytes raise struct.error, which the nodes' raw callbacks count and drop."""
    import struct
    with pytest.raises(struct.error):
        unpack(data)


@pytest.mark.parametrize('frame', FRAMES)
@pytest.mark.parametrize('mode,law,reason,fault', [('auto', 'catch', 'catch: |theta-pi|=0.496<0.5', ''),
                                                   ('off', 'off', '', 'stale state: 12 ms old'),
                                                   ('balance', 'balance', 'x' * 7, 'y' * 5)])
@pytest.mark.parametrize('switch_code,fault_code', [(0, 0), (2, 1), (12, 255)])
def test_controller_status_pack(frame, mode, law, reason, fault, switch_code, fault_code):
    """Decodes to the message rclpy builds, as long as its serialization, padding zeros."""
    from rwpend_msgs.msg import ControllerStatus
    data = wire.pack_controller_status(wire.pack_header(12, 345_678_901, frame), 3989, mode, law, -0.8, -12.5,
                                       0.25, True, (3, 500_000_000), 4, switch_code, reason, fault_code, fault)
    ref = header(ControllerStatus(), frame)
    ref.seq, ref.mode, ref.law, ref.u, ref.u_unsaturated = 3989, mode, law, -0.8, -12.5
    ref.friction_compensation, ref.saturated, ref.switch_count = 0.25, True, 4
    ref.last_switch.sec, ref.last_switch.nanosec = 3, 500_000_000
    ref.reason, ref.fault = reason, fault
    ref.switch_code, ref.fault_code = switch_code, fault_code
    assert deserialize_message(data, ControllerStatus) == ref
    assert len(data) == len(serialize_message(ref))
