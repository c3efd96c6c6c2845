"""The control path's messages as CDR wire bytes, for raw subscriptions and raw publishing.

Taking a message as a Python object costs rclpy a constructor call per nested message (e.g.
EncoderCounts -> Header -> Time) and a ``getattr`` by name per field; publishing one costs the
reverse. With ``create_subscription(..., raw=True)`` and ``publisher.publish(bytes)`` the
per-sample path does a ``struct.unpack_from`` / ``pack`` instead: measured on the project's
2-core machine, one in-process StateEstimate delivery (publish + take + callback) costs
23 us of CPU as objects and 8 us as bytes (PERFORMANCE.md).

Layout: XCDR1, little endian (what rmw_fastrtps puts on the wire). Every struct here is derived
at import from the installed ``.msg`` files (:mod:`rwpend_ros.msglayout`: rosbags parses them,
one function applies CDR's alignment), one struct per start offset modulo 8 where the fields
follow a string (a header's frame_id, ...): ``_ENC_TAIL[len(header) & 7]`` carries the padding
before ``seq``. Each codec names the fields it handles in the order of its function's arguments,
and the import checks them against the ``.msg`` (ValueError: the ``.msg`` changed, the codec here
must too). The header of an incoming sample is kept as its wire bytes and copied into the
messages that carry it on (state, joint_states), so frame_id is never decoded.

Pure Python (struct, rosbags at import), no rclpy: tested against rclpy's serializer in the unit
tests.
"""
from __future__ import annotations

import struct

from rwpend_ros.msglayout import ENCAPSULATION_SIZE, LENGTH, layout, leaves, run, runs, segments
from rwpend_ros.msglayout import field_offset  # noqa: F401 - where a field starts, for a given frame_id

ENCAPSULATION = b'\x00\x01\x00\x00'   # CDR little endian, no options
_E = ENCAPSULATION_SIZE
assert len(ENCAPSULATION) == _E

HEADER = 'std_msgs/msg/Header'
CLOCK = 'rosgraph_msgs/msg/Clock'
ENCODERS = 'rwpend_msgs/msg/EncoderCounts'
COMMAND = 'rwpend_msgs/msg/MotorCommand'
STATE = 'rwpend_msgs/msg/StateEstimate'
PLANT = 'rwpend_msgs/msg/PlantState'
APPLIED = 'rwpend_msgs/msg/AppliedCommand'
STATUS = 'rwpend_msgs/msg/ControllerStatus'
JOINTS = 'sensor_msgs/msg/JointState'
DIAGNOSTICS = 'diagnostic_msgs/msg/DiagnosticArray'
DIAGNOSTIC_STATUS = 'diagnostic_msgs/msg/DiagnosticStatus'
KEY_VALUE = 'diagnostic_msgs/msg/KeyValue'
#: the loop's messages: a Header, then the uint64 seq of the sample (:func:`message_seq_stamp`)
LOOP_TYPES = (ENCODERS, COMMAND, STATE, PLANT, APPLIED, STATUS)
#: every type this module codes
TYPES = LOOP_TYPES + (HEADER, CLOCK, JOINTS, DIAGNOSTICS, DIAGNOSTIC_STATUS, KEY_VALUE)


def _codec(type_name: str, *segs: tuple[str, ...]) -> None:
    """Check that the fields of ``type_name``, cut after each string and sequence
    (:func:`rwpend_ros.msglayout.segments`), are ``segs``: those the codec here reads or writes,
    in this order."""
    got = segments(type_name)
    if got != segs:
        raise ValueError(f'{type_name}: its .msg has the fields {got}; rwpend_ros.wire codes {segs}: '
                         'change the codec with the .msg')


def _sequence_of(type_name: str, path: str, element: str) -> None:
    """Check that field ``path`` of ``type_name`` is a sequence of ``element``."""
    f = dict(leaves(type_name))[path]
    if (f.array, f.type) != ('seq', element):
        raise ValueError(f'{type_name}.{path}: a {f.type} {f.array or "scalar"}; rwpend_ros.wire '
                         f'codes a sequence of {element}')


_HEAD_NAMES = ('stamp.sec', 'stamp.nanosec', 'frame_id')
_codec(HEADER, _HEAD_NAMES)
_HEAD = run(HEADER, _HEAD_NAMES)       # stamp.sec, stamp.nanosec, frame_id length (then its bytes)
_HEAD_SIZE = _HEAD.size
_HDR = tuple(f'header.{n}' for n in _HEAD_NAMES)


def _after_header(type_name: str, *names: str) -> tuple[struct.Struct, ...]:
    """The structs (by start offset modulo 8) of ``names``: every field of ``type_name`` after
    its leading std_msgs/Header ``header`` (checked)."""
    _codec(type_name, _HDR, names)
    return runs(type_name, names)


_ENC_TAIL = _after_header(ENCODERS, 'seq', 'pendulum_counts', 'motor_counts')
_CMD = _after_header(COMMAND, 'seq', 'u', 'controller_id', 'release')
_CMD_TAIL = runs(COMMAND, ('seq', 'u'))        # the layout before controller_id, release
_STATE_NAMES = ('seq', 'theta', 'theta_dot', 'wheel_angle', 'wheel_rate', 'friction', 'energy', 'resyncs',
                'missed')
_STATE_TAIL = _after_header(STATE, *_STATE_NAMES, 'estimator')   # ... the estimator's length
_STATE_FIELDS = runs(STATE, _STATE_NAMES)
_PLANT_TAIL = _after_header(PLANT, 'seq', 'command_seq', 'theta', 'theta_dot', 'wheel_angle', 'wheel_rate',
                            'u_commanded', 'u_applied', 'friction', 'disturbance', 'stuck', 'command_timeout')
_APPLIED_TAIL = _after_header(APPLIED, 'seq', 'command_seq', 'u')
_SEQ = runs(ENCODERS, ('seq',))
for _t in LOOP_TYPES:
    if segments(_t)[1][0] != 'seq' or [s.format for s in runs(_t, ('seq',))] != [s.format for s in _SEQ]:
        raise ValueError(f'{_t}: not a std_msgs/Header then the uint64 seq, as every loop message')
_codec(CLOCK, ('clock.sec', 'clock.nanosec'))
_CLOCK = run(CLOCK, ('clock.sec', 'clock.nanosec'))
#: the builtin_interfaces/Time that starts a Clock's or a Header's payload, by the byte order
#: (the encapsulation's low bit: CDR_BE 0x0000, CDR_LE 0x0001, the PL_ variants alike)
_TIME_AT_START = (run(CLOCK, ('clock.sec', 'clock.nanosec'), order='>'), _CLOCK)
if run(HEADER, _HEAD_NAMES[:2]).format != _CLOCK.format:
    raise ValueError(f'{HEADER} does not start with the builtin_interfaces/Time of {CLOCK}')
_U32_MAX = 0xFFFF_FFFF


def header_end(data: bytes) -> int:
    """Offset (in ``data``, encapsulation included) just after the std_msgs/Header."""
    return _E + _HEAD_SIZE + _HEAD.unpack_from(data, _E)[2]


def message_stamp_ns(data: bytes) -> int:
    """header.stamp in ns of a message (encapsulation included) that starts with a Header."""
    sec, nanosec, _ = _HEAD.unpack_from(data, _E)
    return sec * 1_000_000_000 + nanosec


def header_bytes(data: bytes) -> bytes:
    """The wire bytes of the std_msgs/Header at the start of a message (no encapsulation)."""
    return bytes(data[_E:header_end(data)])


def pack_header(sec: int, nanosec: int, frame_id: str) -> bytes:
    """A std_msgs/Header as wire bytes (no encapsulation)."""
    f = frame_id.encode() + b'\x00'
    return _HEAD.pack(sec, nanosec, len(f)) + f


def header_stamp(header: bytes) -> tuple[int, int]:
    sec, nanosec, _ = _HEAD.unpack_from(header, 0)
    return sec, nanosec


def header_frame_id(header: bytes) -> str:
    n = _HEAD.unpack_from(header, 0)[2]
    return header[_HEAD_SIZE:_HEAD_SIZE + n - 1].decode(errors='replace')


def message_seq_stamp(data: bytes) -> tuple[int, int]:
    """(seq, header.stamp in ns) of a loop message (:data:`LOOP_TYPES`: a Header, then the uint64
    seq); struct.error when too short."""
    sec, nanosec, n = _HEAD.unpack_from(data, _E)
    end = _HEAD_SIZE + n                         # payload offset after the header
    return _SEQ[end & 7].unpack_from(data, _E + end)[0], sec * 1_000_000_000 + nanosec


def unpack_encoders(data: bytes) -> tuple[bytes, int, int, int]:
    """rwpend_msgs/EncoderCounts -> (header bytes, seq, pendulum_counts, motor_counts)."""
    end = _HEAD_SIZE + _HEAD.unpack_from(data, _E)[2]
    seq, pc, mc = _ENC_TAIL[end & 7].unpack_from(data, _E + end)
    return bytes(data[_E:_E + end]), seq, pc, mc


def unpack_command(data: bytes) -> tuple[int, float]:
    """rwpend_msgs/MotorCommand -> (seq, u) (the header is not needed by its readers)."""
    end = _HEAD_SIZE + _HEAD.unpack_from(data, _E)[2]
    return _CMD_TAIL[end & 7].unpack_from(data, _E + end)


def unpack_command_sender(data: bytes) -> tuple[int, float, int, bool]:
    """rwpend_msgs/MotorCommand -> (seq, u, controller_id, release). A command of the layout
    before ``controller_id`` (a bag recorded earlier, played back) ends after ``u``: it comes
    from an anonymous sender (id 0, no release)."""
    end = _HEAD_SIZE + _HEAD.unpack_from(data, _E)[2]
    full = _CMD[end & 7]
    if len(data) >= _E + end + full.size:
        return full.unpack_from(data, _E + end)
    seq, u = _CMD_TAIL[end & 7].unpack_from(data, _E + end)
    return seq, u, 0, False


def command_sender(data: bytes) -> int:
    """The ``controller_id`` of a MotorCommand's wire bytes (0 for the earlier layout)."""
    return unpack_command_sender(data)[2]


def unpack_state(data: bytes) -> tuple:
    """rwpend_msgs/StateEstimate -> (header bytes, seq, theta, theta_dot, wheel_angle,
    wheel_rate, friction, energy, resyncs, missed); the estimator's name is not decoded."""
    end = _HEAD_SIZE + _HEAD.unpack_from(data, _E)[2]
    return (bytes(data[_E:_E + end]),) + _STATE_FIELDS[end & 7].unpack_from(data, _E + end)


def pack_plant_state(header: bytes, seq: int, command_seq: int, theta: float, theta_dot: float,
                     wheel_angle: float, wheel_rate: float, u_commanded: float, u_applied: float,
                     friction: float, disturbance: float, stuck: bool, command_timeout: bool) -> bytes:
    """rwpend_msgs/PlantState (the simulator's sim/true_state)."""
    return (ENCAPSULATION + header
            + _PLANT_TAIL[len(header) & 7].pack(seq, command_seq, theta, theta_dot, wheel_angle, wheel_rate,
                                                u_commanded, u_applied, friction, disturbance, stuck,
                                                command_timeout))


def pack_clock(sec: int, nanosec: int) -> bytes:
    """rosgraph_msgs/Clock."""
    return ENCAPSULATION + _CLOCK.pack(sec, nanosec)


def unpack_clock_ns(data: bytes) -> int:
    """rosgraph_msgs/Clock (wire bytes, either byte order) -> its time in ns; the same for the
    stamp of a message that starts with a Header. struct.error when too short, ValueError for a
    negative time."""
    try:
        time = _TIME_AT_START[data[1] & 1]
    except IndexError:
        raise struct.error('shorter than the encapsulation header') from None
    sec, nanosec = time.unpack_from(data, _E)
    if sec < 0:
        raise ValueError(f'negative clock: {sec} s')
    return sec * 1_000_000_000 + nanosec


def pack_encoders(header: bytes, seq: int, pendulum_counts: int, motor_counts: int) -> bytes:
    return ENCAPSULATION + header + _ENC_TAIL[len(header) & 7].pack(seq, pendulum_counts, motor_counts)


def pack_applied(header: bytes, seq: int, command_seq: int, u: float) -> bytes:
    """rwpend_msgs/AppliedCommand as CDR bytes."""
    return ENCAPSULATION + header + _APPLIED_TAIL[len(header) & 7].pack(seq, command_seq, u)


def pack_command(header: bytes, seq: int, u: float, controller_id: int = 0, release: bool = False) -> bytes:
    return ENCAPSULATION + header + _CMD[len(header) & 7].pack(seq, u, controller_id, release)


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
        return b''.join((ENCAPSULATION, header,
                         _STATE_TAIL[len(header) & 7].pack(seq, theta, theta_dot, wheel_angle, wheel_rate,
                                                           friction, energy, resyncs & _U32_MAX,
                                                           min(missed, _U32_MAX), len(self._name)),
                         self._name))


_codec(JOINTS, _HDR, ('name',), ('position',), ('velocity',), ('effort',))
_sequence_of(JOINTS, 'name', 'string')
_JOINT_NAMES = runs(JOINTS, ('name',))                    # the count of the names
_STRING = tuple(layout((LENGTH,), at) for at in range(8))  # the length of a string in a sequence
for _f in ('position', 'velocity', 'effort'):
    _sequence_of(JOINTS, _f, 'float64')
#: after the names: position (count, 2 values), velocity (count, 2 values), effort (count 0)
_JOINT_VALUES = tuple(layout((LENGTH, 'float64', 'float64') * 2 + (LENGTH,), at) for at in range(8))


class JointStatePacker:
    """sensor_msgs/JointState with fixed joint names, 2 positions, 2 velocities, no effort; what
    follows the header is laid out once for each header length modulo 8."""

    def __init__(self, names: tuple[str, ...] = ('pendulum', 'wheel')) -> None:
        if len(names) != 2:
            raise ValueError('two joints')
        self.names = tuple(names)
        encoded = [n.encode() + b'\x00' for n in names]
        self._after_header = []
        for at in range(8):                         # the payload offset after the header, mod 8
            out = bytearray(_JOINT_NAMES[at].pack(len(encoded)))
            for b in encoded:
                out += _STRING[(at + len(out)) & 7].pack(len(b)) + b
            self._after_header.append((bytes(out), _JOINT_VALUES[(at + len(out)) & 7]))

    def pack(self, header: bytes, p0: float, p1: float, v0: float, v1: float) -> bytes:
        names, values = self._after_header[len(header) & 7]
        return b''.join((ENCAPSULATION, header, names, values.pack(2, p0, p1, 2, v0, v1, 0)))


def _put(out: bytearray, structs: tuple[struct.Struct, ...], *values) -> None:
    """``values`` packed at the end of ``out`` (payload bytes: ``out`` starts after the
    encapsulation) by the struct for that offset, padding zeros before them."""
    out += structs[len(out) & 7].pack(*values)


def _string(s) -> bytes:
    """A CDR string's bytes (after its length): ``str(s)`` in UTF-8 and the NUL."""
    return str(s).encode() + b'\x00'


_codec(DIAGNOSTICS, _HDR, ('status',))
_sequence_of(DIAGNOSTICS, 'status', DIAGNOSTIC_STATUS)
_codec(DIAGNOSTIC_STATUS, ('level', 'name'), ('message',), ('hardware_id',), ('values',))
_sequence_of(DIAGNOSTIC_STATUS, 'values', KEY_VALUE)
_codec(KEY_VALUE, ('key',), ('value',))
_DIAG_COUNT = runs(DIAGNOSTICS, ('status',))
_DIAG_LEVEL_NAME = runs(DIAGNOSTIC_STATUS, ('level', 'name'))
_DIAG_MESSAGE = runs(DIAGNOSTIC_STATUS, ('message',))
_DIAG_HARDWARE_ID = runs(DIAGNOSTIC_STATUS, ('hardware_id',))
_DIAG_VALUES = runs(DIAGNOSTIC_STATUS, ('values',))
_KV_KEY = runs(KEY_VALUE, ('key',))
_KV_VALUE = runs(KEY_VALUE, ('value',))


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
    _put(out, _DIAG_COUNT, len(statuses))
    for level, name, message, hardware_id, values in statuses:
        level = bytes(level) if isinstance(level, (bytes, bytearray)) else bytes((int(level),))
        b = _string(name)
        _put(out, _DIAG_LEVEL_NAME, level, len(b))
        out += b
        b = _string(message)
        _put(out, _DIAG_MESSAGE, len(b))
        out += b
        b = _string(hardware_id)
        _put(out, _DIAG_HARDWARE_ID, len(b))
        out += b
        items = list(values.items() if hasattr(values, 'items') else values)
        _put(out, _DIAG_VALUES, len(items))
        for k, v in items:                      # (inline: ~25 of them per node)
            b = str(k).encode() + b'\x00'
            out += _KV_KEY[len(out) & 7].pack(len(b))
            out += b
            b = str(v).encode() + b'\x00'
            out += _KV_VALUE[len(out) & 7].pack(len(b))
            out += b
    return ENCAPSULATION + bytes(out)


_codec(STATUS, _HDR, ('seq', 'mode'), ('law',), ('u', 'u_unsaturated', 'friction_compensation', 'saturated',
                                                 'last_switch.sec', 'last_switch.nanosec', 'switch_count',
                                                 'switch_code', 'reason'), ('fault_code', 'fault'))
_STATUS_SEQ_MODE, _STATUS_LAW, _STATUS_U_SWITCH, _STATUS_FAULT = (runs(STATUS, s) for s in segments(STATUS)[1:])


def pack_controller_status(header: bytes, seq: int, mode: str, law: str, u: float, u_unsaturated: float,
                           friction_compensation: float, saturated: bool, last_switch: tuple[int, int],
                           switch_count: int, switch_code: int, reason: str, fault_code: int,
                           fault: str) -> bytes:
    """rwpend_msgs/ControllerStatus as wire bytes, its alignment padding zeros: rclpy's
    serializer leaves the padding as it finds it in a reused buffer, so two lockstep runs
    published the same status with different bytes (a bag that is not "the same bag",
    rwpend_bag.sameness). ``last_switch``: (sec, nanosec); ``switch_code``, ``fault_code``: the
    message's SWITCH_* and FAULT_* constants."""
    out = bytearray(header)
    m, la, r, f = _string(mode), _string(law), _string(reason), _string(fault)
    _put(out, _STATUS_SEQ_MODE, seq, len(m))
    out += m
    _put(out, _STATUS_LAW, len(la))
    out += la
    _put(out, _STATUS_U_SWITCH, u, u_unsaturated, friction_compensation, saturated, *last_switch,
         switch_count & _U32_MAX, switch_code, len(r))
    out += r
    _put(out, _STATUS_FAULT, fault_code, len(f))
    out += f
    return ENCAPSULATION + bytes(out)
