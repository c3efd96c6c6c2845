"""The bag side's readers of the derived layout (no rclpy): cdr's schema parse (rosbags), its
column decoder, and the byte peekers (cdr.seq_of, logtime.leading_time_ns) on messages of every
loop type that rosbags' serializer writes with random values and frame_ids of every length."""
from __future__ import annotations

import random

import numpy as np
import pytest
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from rwpend_bag import cdr, msgdefs
from rwpend_bag.logtime import leading_time_ns
from rwpend_ros import wire

INTS = {'int8': 8, 'int16': 16, 'int32': 32, 'int64': 64}


@pytest.fixture(scope='module')
def store():
    s = get_typestore(Stores.EMPTY)
    for t in wire.LOOP_TYPES:
        s.register(get_types_from_msg(msgdefs.joined_definition(t), t))
    return s


def random_message(store, type_name: str, rng: random.Random):
    """A message of rosbags' class with a random value in every field (the parse of its .msg)."""
    values = {}
    for f in cdr.parse_schema(type_name, msgdefs.joined_definition(type_name))[msgdefs.full_type(type_name)]:
        if f.type in INTS:
            v = rng.randrange(-2 ** (INTS[f.type] - 1), 2 ** (INTS[f.type] - 1))
        elif f.type.startswith('uint'):
            v = rng.randrange(2 ** int(f.type[4:]))
        elif f.type == 'float64':
            v = rng.uniform(-1e6, 1e6)
        elif f.type == 'bool':
            v = rng.random() < 0.5
        elif f.type == 'string':
            v = ''.join(rng.choice('ab_/é') for _ in range(rng.randrange(0, 17)))
        else:
            v = random_message(store, f.type, rng)
        values[f.name] = v
    if type_name == 'builtin_interfaces/msg/Time':
        values['sec'] = abs(values['sec'])
    return store.types[type_name](**values)


@pytest.mark.parametrize('type_name', wire.LOOP_TYPES)
def test_peekers_read_seq_and_stamp(store, type_name):
    rng = random.Random(type_name)
    msgs = [random_message(store, type_name, rng) for _ in range(64)]
    datas = [bytes(store.serialize_cdr(m, type_name)) for m in msgs]
    assert {len(m.header.frame_id.encode()) % 8 for m in msgs} == set(range(8))
    assert [cdr.seq_of(d) for d in datas] == [m.seq for m in msgs]
    stamps = [m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec for m in msgs]
    assert [leading_time_ns(d) for d in datas] == stamps
    cols = cdr.decode_columns(type_name, msgdefs.joined_definition(type_name), datas)
    assert list(cols['seq']) == [m.seq for m in msgs]
    assert list(cols['header.frame_id']) == [m.header.frame_id for m in msgs]
    assert cdr.header_seq_layout(type_name, msgdefs.joined_definition(type_name))


def test_peekers_on_short_bytes():
    assert cdr.seq_of(b'') is None and cdr.seq_of(b'\x00\x01\x00\x00' + bytes(12)) is None
    assert leading_time_ns(b'\x00\x01') is None


def test_parse_schema_with_rosbags():
    """Constants are not fields; arrays, bounded types, defaults and the names of other
    packages' types as rosbag2 writes them; a definition rosbags cannot parse is a ValueError."""
    text = ('uint8 OK=0\nstring NAME="x#y"\nint32 a 5\nfloat64[3] b\nint16[<=4] c\nstring<=8 d\n'
            'Header h\nOther o\n' + '=' * 80 + '\nMSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\n'
            'string frame_id\n' + '=' * 80 + '\nMSG: p/Other\nbool[] flags\n')
    types = cdr.parse_schema('p/msg/T', text)
    assert [(f.name, f.type, f.array, f.size) for f in types['p/msg/T']] == [
        ('a', 'int32', None, 0), ('b', 'float64', 'fixed', 3), ('c', 'int16', 'seq', 0), ('d', 'string', None, 0),
        ('h', 'std_msgs/msg/Header', None, 0), ('o', 'p/msg/Other', None, 0)]
    assert [f.type for f in types['std_msgs/msg/Header']] == ['builtin_interfaces/msg/Time', 'string']
    assert types['p/msg/Other'] == [cdr.Field('flags', 'bool', 'seq')]
    with pytest.raises(ValueError):
        cdr.parse_schema('p/msg/T', 'int32 1a\n')
    assert not cdr.header_seq_layout('p/msg/T', 'int32 1a\n')


def test_align_is_the_decoders_rule():
    """The column decoder aligns with msglayout.align: offsets relative to each message's body."""
    base = np.array([0, 100, 203])
    off = base + np.array([1, 8, 13])
    assert list(base + cdr.align(off - base, 8)) == [8, 108, 219]
