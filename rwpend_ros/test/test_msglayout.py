"""The layouts derived from the .msg files (rwpend_ros.msglayout) and the wire codecs built on
them, against rclpy's serializer for random values of every field: a .msg that changes so that
a codec's fields (its function's arguments) no longer match fails here, and at wire's import."""
from __future__ import annotations

import inspect
import os
import random
import struct
import subprocess
import sys

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import JointState

from rwpend_ros import msglayout, wire
from rwpend_ros.msglayout import FORMAT, align, field_offset, layout, leaves, run, runs, segments

INT = {'int8': 8, 'int16': 16, 'int32': 32, 'int64': 64}
UINT = {'uint8': 8, 'octet': 8, 'uint16': 16, 'uint32': 32, 'uint64': 64}
ALPHABET = 'abcxyz_/: 0123456789éü→'

PACKERS = {
    wire.ENCODERS: wire.pack_encoders,
    wire.COMMAND: wire.pack_command,
    wire.STATE: wire.StatePacker.pack,
    wire.PLANT: wire.pack_plant_state,
    wire.APPLIED: wire.pack_applied,
    wire.STATUS: wire.pack_controller_status,
}
#: fields a codec is given otherwise than as an argument of its pack function
GIVEN_APART = {wire.STATE: ['estimator']}


def message_class(type_name: str):
    pkg, _, name = type_name.split('/')
    return getattr(__import__(f'{pkg}.msg', fromlist=[name]), name)


def random_text(rng: random.Random) -> str:
    return ''.join(rng.choice(ALPHABET) for _ in range(rng.randrange(0, 17)))


def random_value(t: str, rng: random.Random):
    if t in INT:
        return rng.randrange(-2 ** (INT[t] - 1), 2 ** (INT[t] - 1))
    if t in UINT:
        v = rng.choice([0, 2 ** UINT[t] - 1, rng.randrange(2 ** UINT[t])])
        return bytes([v]) if t == 'octet' else v
    if t == 'double':
        return rng.choice([0.0, -0.0, rng.uniform(-1e3, 1e3), rng.uniform(-1e300, 1e300), 5e-324])
    if t == 'float':
        return struct.unpack('<f', struct.pack('<f', rng.uniform(-1e3, 1e3)))[0]
    if t == 'boolean':
        return rng.random() < 0.5
    if t == 'string':
        return random_text(rng)
    raise AssertionError(f'no random value of {t}')


def random_message(cls, rng: random.Random):
    """A message with a random value in every field (nested messages too), as rclpy knows them."""
    m = cls()
    for name, t in m.get_fields_and_field_types().items():
        if '/' in t:
            setattr(m, name, random_message(type(getattr(m, name)), rng))
        else:
            setattr(m, name, random_value(t, rng))
    if hasattr(m, 'header'):
        m.header.stamp.sec = rng.randrange(0, 2 ** 31)         # the loop's stamps are not negative
    return m


def header_of(m) -> bytes:
    return wire.pack_header(m.header.stamp.sec, m.header.stamp.nanosec, m.header.frame_id)


def stamp_ns(m) -> int:
    return m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec


def arguments(fn) -> list[str]:
    return [p for p in inspect.signature(fn).parameters if p not in ('self', 'header')]


def pack(type_name: str, m) -> bytes:
    """``m`` packed by wire's codec of its type, each argument the field of its name."""
    values = [getattr(m, a) for a in arguments(PACKERS[type_name])]
    values = [(v.sec, v.nanosec) if hasattr(v, 'nanosec') else v for v in values]   # a Time
    if type_name == wire.STATE:
        return wire.StatePacker(m.estimator).pack(header_of(m), *values)
    return PACKERS[type_name](header_of(m), *values)


# ------------------------------------------------------------------ msglayout
def test_align_ints_and_arrays():
    assert [align(o, 8) for o in range(10)] == [0, 8, 8, 8, 8, 8, 8, 8, 8, 16]
    assert [align(o, 4) for o in range(6)] == [0, 4, 4, 4, 4, 8]
    assert [align(o, 1) for o in range(3)] == [0, 1, 2]
    assert align(13, 16) == 16                        # 8 at most
    assert list(align(np.arange(10), 8)) == [align(o, 8) for o in range(10)]


def test_layout_pads_before_each_value():
    assert layout(('bool', 'float64')).format == '<?7xd'
    assert layout(('bool', 'float64'), at=3).format == '<?4xd'
    assert layout(('uint32', 'float64'), at=5).format == '<3xI4xd'
    assert layout(('int32', 'uint32'), order='>').format == '>iI'


def test_runs_and_segments_of_the_loop_messages():
    assert run(wire.HEADER, ('stamp.sec', 'stamp.nanosec', 'frame_id')).format == '<iII'
    assert [s.format for s in runs(wire.ENCODERS, ('seq', 'pendulum_counts', 'motor_counts'))] == \
        ['<Qii'] + [f'<{8 - k}xQii' for k in range(1, 8)]
    assert segments(wire.STATUS)[1:] == (('seq', 'mode'), ('law',), (
        'u', 'u_unsaturated', 'friction_compensation', 'saturated', 'last_switch.sec', 'last_switch.nanosec',
        'switch_count', 'switch_code', 'reason'), ('fault_code', 'fault'))
    with pytest.raises(ValueError, match='variable length'):
        run(wire.STATUS, ('seq', 'mode', 'law'))
    with pytest.raises(ValueError, match='not seq, theta'):
        run(wire.PLANT, ('seq', 'theta'))


def test_leaves_are_the_fields_rclpy_knows():
    """rosbags' parse of each .msg file and rosidl's generated class list the same fields."""
    for type_name in wire.TYPES:
        def flat(cls, prefix=''):
            out = []
            for name, t in cls.get_fields_and_field_types().items():
                if '/' in t and not t.startswith('sequence<'):
                    out += flat(type(getattr(cls(), name)), f'{prefix}{name}.')
                else:
                    out.append(prefix + name)
            return out
        assert [p for p, _ in leaves(type_name)] == flat(message_class(type_name)), type_name


@pytest.mark.parametrize('type_name', wire.LOOP_TYPES)
def test_field_offset_against_rclpy(type_name):
    """Every field up to the first string after the header, at the offset derived from the .msg,
    holds its value in rclpy's bytes, for frame_ids of every length modulo 8."""
    rng = random.Random(type_name)
    cls = message_class(type_name)
    for _ in range(24):
        m = random_message(cls, rng)
        data = serialize_message(m)
        for path, f in leaves(type_name):
            if f.type not in FORMAT or f.array:
                if path == 'header.frame_id':
                    continue
                break
            v = m
            for part in path.split('.'):
                v = getattr(v, part)
            got, = struct.unpack_from('<' + FORMAT[f.type], data, field_offset(type_name, path, m.header.frame_id))
            assert got == v, (type_name, path)


def test_field_offset_refuses_a_field_after_another_string():
    assert field_offset(wire.STATUS, 'seq', 'rwpend') == 4 + 24
    with pytest.raises(ValueError, match='after mode'):
        field_offset(wire.STATUS, 'u')


# ------------------------------------------------------------------ the codecs, field by field
@pytest.mark.parametrize('type_name', PACKERS)
def test_a_codec_takes_every_field_of_its_message(type_name):
    """The pack function's arguments are the message's fields after the header, in order: a field
    added to (or removed from) the .msg and not to the codec fails here."""
    fields = [f for f in message_class(type_name).get_fields_and_field_types() if f != 'header']
    assert arguments(PACKERS[type_name]) + GIVEN_APART.get(type_name, []) == fields


@pytest.mark.parametrize('type_name', PACKERS)
def test_pack_decodes_to_the_message_rclpy_builds(type_name):
    rng = random.Random(type_name)
    cls = message_class(type_name)
    for _ in range(48):
        m = random_message(cls, rng)
        if type_name == wire.STATE:
            m.missed = min(m.missed, 2 ** 32 - 1)
        data = pack(type_name, m)
        assert len(data) == len(serialize_message(m))
        assert deserialize_message(data, cls) == m


@pytest.mark.parametrize('type_name', wire.LOOP_TYPES)
def test_unpack_reads_what_rclpy_writes(type_name):
    rng = random.Random(type_name)
    cls = message_class(type_name)
    for _ in range(48):
        m = random_message(cls, rng)
        data = serialize_message(m)
        assert wire.message_seq_stamp(data) == (m.seq, stamp_ns(m))
        assert wire.message_stamp_ns(data) == stamp_ns(m) == wire.unpack_clock_ns(data)
        assert wire.header_bytes(data) == header_of(m)
        if type_name == wire.ENCODERS:
            assert wire.unpack_encoders(data) == (header_of(m), m.seq, m.pendulum_counts, m.motor_counts)
        elif type_name == wire.COMMAND:
            assert wire.unpack_command(data) == (m.seq, m.u)
            assert wire.unpack_command_sender(data) == (m.seq, m.u, m.controller_id, m.release)
        elif type_name == wire.STATE:
            assert wire.unpack_state(data) == (header_of(m), m.seq, m.theta, m.theta_dot, m.wheel_angle,
                                               m.wheel_rate, m.friction, m.energy, m.resyncs, m.missed)


def test_clock_both_ways():
    from rosgraph_msgs.msg import Clock
    rng = random.Random(1)
    for _ in range(20):
        c = random_message(Clock, rng)
        c.clock.sec = abs(c.clock.sec)
        assert wire.pack_clock(c.clock.sec, c.clock.nanosec) == serialize_message(c)
        assert wire.unpack_clock_ns(serialize_message(c)) == c.clock.sec * 1_000_000_000 + c.clock.nanosec
    be = b'\x00\x00\x00\x00' + struct.pack('>iI', 7, 8)
    assert wire.unpack_clock_ns(be) == 7_000_000_008
    for short in (b'', b'\x00', b'\x00\x01\x00\x00\x01'):
        with pytest.raises(struct.error):
            wire.unpack_clock_ns(short)


def test_joint_states_for_random_names_and_frames():
    """Decoded, the same message (rclpy's bytes may be 4 longer: its serializer pads the empty
    effort to 8 after its count, for no element; the decoders read past neither)."""
    rng = random.Random(2)
    for _ in range(48):
        names = (random_text(rng), random_text(rng))
        m = JointState()
        m.header.frame_id, m.header.stamp.sec, m.header.stamp.nanosec = random_text(rng), 3, 4
        m.name = list(names)
        m.position, m.velocity = [rng.uniform(-9, 9) for _ in range(2)], [rng.uniform(-9, 9) for _ in range(2)]
        data = wire.JointStatePacker(names).pack(header_of(m), *m.position, *m.velocity)
        assert len(serialize_message(m)) - len(data) in (0, 4)
        assert deserialize_message(data, JointState) == m


# ------------------------------------------------------------------ a .msg that changes
def changed_prefix(tmp_path, type_name: str, text: str) -> dict:
    pkg, _, name = type_name.split('/')
    d = tmp_path / 'share' / pkg / 'msg'
    d.mkdir(parents=True)
    (d / f'{name}.msg').write_text(text)
    env = dict(os.environ)
    env['AMENT_PREFIX_PATH'] = os.pathsep.join([str(tmp_path), env.get('AMENT_PREFIX_PATH', ''), sys.prefix])
    return env


def import_wire(env: dict, code: str = '') -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, '-c', 'from rwpend_ros import wire\n' + code], env=env,
                          capture_output=True, text=True, timeout=60)


@pytest.mark.parametrize('type_name, edit', [
    (wire.ENCODERS, lambda t: t + 'uint32 flags\n'),                              # a field more
    (wire.PLANT, lambda t: t.replace('bool stuck', 'bool stuck\nfloat64 extra')),   # a field between two
    (wire.STATE, lambda t: t.replace('uint32 missed', '')),                        # a field less
])
def test_wire_refuses_to_import_against_a_changed_msg(tmp_path, type_name, edit):
    """The codecs' fields are checked against the installed .msg files at import: one that no
    longer matches stops the import, naming the type (no node starts with a wrong layout)."""
    r = import_wire(changed_prefix(tmp_path, type_name, edit(msglayout.msg_text(type_name))))
    assert r.returncode != 0 and 'ValueError' in r.stderr and type_name in r.stderr, r.stderr


def test_the_layout_follows_a_field_of_another_type(tmp_path):
    """The same fields, one of another type: the structs follow the .msg (nothing retyped)."""
    text = msglayout.msg_text(wire.COMMAND).replace('float64 u', 'float32 u')
    r = import_wire(changed_prefix(tmp_path, wire.COMMAND, text), 'print(wire._CMD[0].format)')
    assert r.returncode == 0 and r.stdout.strip() == '<Qf4xQ?', r.stderr
