"""The control path's messages as CDR wire bytes, for raw subscriptions and raw publishing.

Taking a message as a Python object costs rclpy a constructor call per nested message (e.g.
EncoderCounts -> Header -> Time) and a ``getattr`` by name per field; publishing one costs the
reverse. With ``create_subscription(..., raw=True)`` and ``publisher.publish(bytes)`` the
per-sample path does a ``struct.unpack_from`` / ``pack_into`` instead: measured on the project's
2-core machine, one in-process StateEstimate delivery (publish + take + callback) costs
23 us of CPU as objects and 8 us as bytes (PERFORMANCE.md).

Layout: XCDR1, little endian (what rmw_fastrtps puts on the wire): a 4-byte encapsulation
header, then the fields, each aligned to its size (8 at most) counted from the end of the
encapsulation header; a string is a uint32 length (NUL included), the bytes and the NUL.
The header of an incoming sample is kept as its wire bytes and copied into the messages that
carry it on (state, joint_states), so frame_id is never decoded.

Pure Python (struct), no rclpy: tested against rclpy's serializer in the unit tests.
"""
from __future__ import annotations

import struct

ENCAPSULATION = b'\x00\x01\x00\x00'   # CDR little endian, no options

_HEAD = struct.Struct('<iII')          # stamp.sec, stamp.nanosec, frame_id length
_ENC_TAIL = struct.Struct('<Qii')      # seq, pendulum_counts, motor_counts
_CMD_TAIL = struct.Struct('<Qd')       # seq, u
_CMD_SENDER = struct.Struct('<Q?')     # controller_id, release (after seq, u)
_STATE_TAIL = struct.Struct('<Q6d3I')  # seq, theta ... energy, resyncs, missed, estimator length
_STATE_FIELDS = struct.Struct('<Q6d2I')  # seq, theta ... energy, resyncs, missed (not the name)
_PLANT_TAIL = struct.Struct('<Qq8d2?')  # seq, command_seq, theta ... disturbance, stuck, command_timeout
_APPLIED_TAIL = struct.Struct('<Qqd')   # seq, command_seq, u
_CLOCK = struct.Struct('<iI')          # rosgraph_msgs/Clock: builtin_interfaces/Time
_U32 = struct.Struct('<I')
_U32_MAX = 0xFFFF_FFFF
_2D = struct.Struct('<2d')


def _pad8(n: int) -> int:
    return (-n) % 8


def _pad4(n: int) -> int:
    return (-n) % 4


def header_end(data: bytes) -> int:
    """Offset (in ``data``, encapsulation included) just after the std_msgs/Header."""
    return 4 + 12 + _HEAD.unpack_from(data, 4)[2]


def message_stamp_ns(data: bytes) -> int:
    """header.stamp in ns of a message (encapsulation included) that starts with a Header."""
    sec, nanosec, _ = _HEAD.unpack_from(data, 4)
    return sec * 1_000_000_000 + nanosec


def header_bytes(data: bytes) -> bytes:
    """The wire bytes of the std_msgs/Header at the start of a message (no encapsulation)."""
    return bytes(data[4:header_end(data)])


def pack_header(sec: int, nanosec: int, frame_id: str) -> bytes:
    """A std_msgs/Header as wire bytes (no encapsulation)."""
    f = frame_id.encode() + b'\x00'
    return _HEAD.pack(sec, nanosec, len(f)) + f


def header_stamp(header: bytes) -> tuple[int, int]:
    sec, nanosec, _ = _HEAD.unpack_from(header, 0)
    return sec, nanosec


def header_frame_id(header: bytes) -> str:
    n = _HEAD.unpack_from(header, 0)[2]
    return header[12:12 + n - 1].decode(errors='replace')


def _after_header(data: bytes) -> int:
    """Offset of the first field after the header when that field is 8-aligned."""
    end = header_end(data) - 4
    return 4 + end + _pad8(end)


_SEQ = struct.Struct('<Q')


def message_seq_stamp(data: bytes) -> tuple[int, int]:
    """(seq, header.stamp in ns) of a loop message (EncoderCounts, MotorCommand, StateEstimate,
    PlantState: a Header, then the uint64 seq); struct.error when too short."""
    sec, nanosec, n = _HEAD.unpack_from(data, 4)
    end = 12 + n
    return _SEQ.unpack_from(data, 4 + end + _pad8(end))[0], sec * 1_000_000_000 + nanosec


def unpack_encoders(data: bytes) -> tuple[bytes, int, int, int]:
    """rwpend_msgs/EncoderCounts -> (header bytes, seq, pendulum_counts, motor_counts)."""
    end = header_end(data)
    rel = end - 4
    seq, pc, mc = _ENC_TAIL.unpack_from(data, end + _pad8(rel))
    return bytes(data[4:end]), seq, pc, mc


def unpack_command(data: bytes) -> tuple[int, float]:
    """rwpend_msgs/MotorCommand -> (seq, u) (the header is not needed by its readers)."""
    return _CMD_TAIL.unpack_from(data, _after_header(data))


def unpack_command_sender(data: bytes) -> tuple[int, float, int, bool]:
    """rwpend_msgs/MotorCommand -> (seq, u, controller_id, release). A command of the layout
    before ``controller_id`` (a bag recorded earlier, played back) ends after ``u``: it comes
    from an anonymous sender (id 0, no release)."""
    at = _after_header(data)
    seq, u = _CMD_TAIL.unpack_from(data, at)
    at += _CMD_TAIL.size
    if len(data) < at + _CMD_SENDER.size:
        return seq, u, 0, False
    source, release = _CMD_SENDER.unpack_from(data, at)
    return seq, u, source, release


def command_sender(data: bytes) -> int:
    """The ``controller_id`` of a MotorCommand's wire bytes (0 for the earlier layout)."""
    return unpack_command_sender(data)[2]


def unpack_state(data: bytes) -> tuple:
    """rwpend_msgs/StateEstimate -> (header bytes, seq, theta, theta_dot, wheel_angle,
    wheel_rate, friction, energy, resyncs, missed); the estimator's name is not decoded."""
    end = header_end(data)
    return (bytes(data[4:end]),) + _STATE_FIELDS.unpack_from(data, end + _pad8(end - 4))


def pack_plant_state(header: bytes, seq: int, command_seq: int, theta: float, theta_dot: float,
                     wheel_angle: float, wheel_rate: float, u_commanded: float, u_applied: float,
                     friction: float, disturbance: float, stuck: bool, command_timeout: bool) -> bytes:
    """rwpend_msgs/PlantState (the simulator's sim/true_state)."""
    return (ENCAPSULATION + header + bytes(_pad8(len(header)))
            + _PLANT_TAIL.pack(seq, command_seq, theta, theta_dot, wheel_angle, wheel_rate, u_commanded,
                               u_applied, friction, disturbance, stuck, command_timeout))


def pack_clock(sec: int, nanosec: int) -> bytes:
    """rosgraph_msgs/Clock."""
    return ENCAPSULATION + _CLOCK.pack(sec, nanosec)


def unpack_clock_ns(data: bytes) -> int:
    """rosgraph_msgs/Clock (wire bytes, either byte order) -> its time in ns; struct.error when
    too short, ValueError for a negative time."""
    fmt = '<iI' if data[1:2] != b'\x00' else '>iI'
    sec, nanosec = struct.unpack_from(fmt, data, 4)
    if sec < 0:
        raise ValueError(f'negative clock: {sec} s')
    return sec * 1_000_000_000 + nanosec


def pack_encoders(header: bytes, seq: int, pendulum_counts: int, motor_counts: int) -> bytes:
    return (ENCAPSULATION + header + bytes(_pad8(len(header)))
            + _ENC_TAIL.pack(seq, pendulum_counts, motor_counts))


def pack_applied(header: bytes, seq: int, command_seq: int, u: float) -> bytes:
    """rwpend_msgs/AppliedCommand as CDR bytes."""
    return ENCAPSULATION + header + bytes(_pad8(len(header))) + _APPLIED_TAIL.pack(seq, command_seq, u)


def pack_command(header: bytes, seq: int, u: float, controller_id: int = 0, release: bool = False) -> bytes:
    return (ENCAPSULATION + header + bytes(_pad8(len(header))) + _CMD_TAIL.pack(seq, u)
            + _CMD_SENDER.pack(controller_id, release))


class StatePacker:
    """rwpend_msgs/StateEstimate as wire bytes; the estimator's name is encoded once."""

    def __init__(self, estimator: str = '') -> None:
        self.set_estimator(estimator)

    def set_estimator(self, estimator: str) -> None:
        self.estimator = estimator
        self._name = estimator.encode() + b'\x00'

    def pack(self, header: bytes, seq: int, theta: float, theta_dot: float, wheel_angle: float,
             wheel_rate: float, friction: float, energy: float, resyncs: int = 0,
             missed: int = 0) -> bytes:
        """uint32 counters: resyncs modulo 2**32, missed saturated at 2**32 - 1."""
        return b''.join((ENCAPSULATION, header, bytes(_pad8(len(header))),
                         _STATE_TAIL.pack(seq, theta, theta_dot, wheel_angle, wheel_rate, friction,
                                          energy, resyncs & _U32_MAX, min(missed, _U32_MAX),
                                          len(self._name)),
                         self._name))


class JointStatePacker:
    """sensor_msgs/JointState with fixed joint names, 2 positions, 2 velocities, no effort."""

    def __init__(self, names: tuple[str, ...] = ('pendulum', 'wheel')) -> None:
        if len(names) != 2:
            raise ValueError('two joints')
        self.names = tuple(names)
        parts = [_U32.pack(len(names))]
        off = 4                                     # relative to the start of the names sequence
        for n in names:
            b = n.encode() + b'\x00'
            pad = _pad4(off)
            parts += [bytes(pad), _U32.pack(len(b)), b]
            off += pad + 4 + len(b)
        self._names = b''.join(parts)
        self._names_len = off

    def pack(self, header: bytes, p0: float, p1: float, v0: float, v1: float) -> bytes:
        rel = len(header)                           # payload offset after the header
        out = [ENCAPSULATION, header]
        pad = _pad4(rel)
        out.append(bytes(pad))
        rel += pad
        out.append(self._names)
        rel += self._names_len
        for a, b in ((p0, p1), (v0, v1)):
            pad = _pad4(rel)
            out += [bytes(pad), _U32.pack(2)]
            rel += pad + 4
            pad = _pad8(rel)
            out += [bytes(pad), _2D.pack(a, b)]
            rel += pad + 16
        pad = _pad4(rel)
        out += [bytes(pad), _U32.pack(0)]           # effort: empty
        return b''.join(out)


def _put_string(out: bytearray, s: str) -> None:
    """A CDR string at the end of ``out`` (payload offsets: ``out`` starts after the
    encapsulation): aligned to 4, uint32 length with the NUL, the bytes, the NUL."""
    b = s.encode()
    out += bytes(_pad4(len(out)))
    out += _U32.pack(len(b) + 1)
    out += b
    out += b'\x00'


def pack_diagnostic_array(sec: int, nanosec: int, statuses, frame_id: str = '') -> bytes:
    """diagnostic_msgs/DiagnosticArray as wire bytes. ``statuses``: (level, name, message,
    hardware_id, values) each, level an int 0-3 or the one byte of ``DiagnosticStatus.OK`` ...,
    values (key, value) pairs or a mapping, of any type (``str()`` of each). rclpy decodes them to the same message,
    and they are as long as its own serialization (unit-tested; the alignment padding here is
    zeros, rclpy leaves it as it finds it), for a fraction of the cost of building the message
    as objects: a node's diagnostics (~25 key-values) took 0.35-0.6 ms on the project's machine
    that way, holding the GIL (PERFORMANCE.md, "What each mechanism buys")."""
    out = bytearray(pack_header(sec, nanosec, frame_id))
    statuses = list(statuses)
    out += bytes(_pad4(len(out)))
    out += _U32.pack(len(statuses))
    for level, name, message, hardware_id, values in statuses:
        out += level if isinstance(level, (bytes, bytearray)) else bytes((int(level),))
        _put_string(out, str(name))
        _put_string(out, str(message))
        _put_string(out, str(hardware_id))
        items = list(values.items() if hasattr(values, 'items') else values)
        out += bytes(_pad4(len(out)))
        out += _U32.pack(len(items))
        for k, v in items:
            _put_string(out, str(k))
            _put_string(out, str(v))
    return ENCAPSULATION + bytes(out)


_STATUS_U = struct.Struct('<3d?')      # u, u_unsaturated, friction_compensation, saturated
_STATUS_SWITCH = struct.Struct('<iII')  # last_switch.sec, last_switch.nanosec, switch_count


def pack_controller_status(header: bytes, seq: int, mode: str, law: str, u: float, u_unsaturated: float,
                           friction_compensation: float, saturated: bool, last_switch: tuple[int, int],
                           switch_count: int, reason: str, fault: str) -> bytes:
    """rwpend_msgs/ControllerStatus as wire bytes, its alignment padding zeros: rclpy's
    serializer leaves the padding as it finds it in a reused buffer, so two lockstep runs
    published the same status with different bytes (a bag that is not "the same bag",
    rwpend_bag.sameness). ``last_switch``: (sec, nanosec)."""
    out = bytearray(header)
    out += bytes(_pad8(len(out)))
    out += struct.pack('<Q', seq)
    _put_string(out, mode)
    _put_string(out, law)
    out += bytes(_pad8(len(out)))
    out += _STATUS_U.pack(u, u_unsaturated, friction_compensation, saturated)
    out += bytes(_pad4(len(out)))
    out += _STATUS_SWITCH.pack(*last_switch, switch_count & _U32_MAX)
    _put_string(out, reason)
    _put_string(out, fault)
    return ENCAPSULATION + bytes(out)
