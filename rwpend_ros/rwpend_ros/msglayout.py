"""Message layouts from the ``.msg`` files: the one source of every hand-free codec.

* The ``.msg`` files are looked up under ``<prefix>/share/<pkg>/msg/`` for every prefix of
  ``$AMENT_PREFIX_PATH`` (then ``sys.prefix``): where rosidl installs them, the files rclpy's
  own serializer is generated from (:func:`msg_text`).
* rosbags parses them (:func:`fields`, :func:`parse`; :func:`constants` for the enumerated
  values); :func:`leaves` flattens a type's nested messages into dotted paths
  (``header.stamp.sec``).
* :func:`layout` applies CDR's alignment (:func:`align`) to a run of primitive fields and gives
  its ``struct.Struct``; :func:`run` / :func:`runs` name the run by its fields, :func:`segments`
  cuts a type at its strings and sequences (whose length is known only from the bytes),
  :func:`field_offset` places one field for a given ``header.frame_id``.

The layout is XCDR1 (what rmw_fastrtps puts on the wire): a 4-byte encapsulation header, then the
fields, each primitive aligned to its size (8 at most) counted from the end of the encapsulation
header; a string is a uint32 length (NUL included), the bytes and the NUL; a sequence a uint32
count and its elements; a fixed array its elements. :mod:`rwpend_ros.wire` builds its struct
layouts from these at import, :mod:`rwpend_bag.cdr` and :mod:`rwpend_bag.msgdefs` parse with
:func:`parse`. Pure Python (rosbags, struct), no rclpy.
"""
from __future__ import annotations

import functools
import os
import struct
import sys
from dataclasses import dataclass
from pathlib import Path

from rosbags.interfaces import Nodetype
from rosbags.typesys import TypesysError, get_types_from_msg

#: bytes before the payload: the CDR encapsulation header (representation id and options)
ENCAPSULATION_SIZE = 4

#: struct codes of the primitive types (``byte`` is one ``bytes`` as rclpy gives it, ``char`` an int)
FORMAT = {'bool': '?', 'byte': 'c', 'char': 'B', 'int8': 'b', 'uint8': 'B', 'int16': 'h',
          'uint16': 'H', 'int32': 'i', 'uint32': 'I', 'int64': 'q', 'uint64': 'Q',
          'float32': 'f', 'float64': 'd'}
STRINGS = ('string', 'wstring')
#: the type of a string's length (NUL included) and of a sequence's count
LENGTH = 'uint32'


class DefinitionNotFound(LookupError):
    """No .msg file for a type name."""


@dataclass(frozen=True)
class Field:
    name: str
    type: str          # primitive name, 'string', 'wstring', or full 'pkg/msg/Name'
    array: str | None  # None scalar, 'fixed', 'seq'
    size: int = 0      # fixed array length


def split_type(type_name: str) -> tuple[str, str]:
    """'pkg/msg/Name' or 'pkg/Name' -> ('pkg', 'Name')."""
    parts = type_name.strip().split('/')
    if len(parts) == 3 and parts[1] == 'msg':
        return parts[0], parts[2]
    if len(parts) == 2:
        return parts[0], parts[1]
    raise ValueError(f'not a message type name: {type_name!r} (expected pkg/msg/Name)')


def full_type(type_name: str) -> str:
    pkg, name = split_type(type_name)
    return f'{pkg}/msg/{name}'


def type_key(type_name: str) -> str:
    """The name :func:`parse` gives a type: 'pkg/Name' -> 'pkg/msg/Name'; 'pkg/msg/Name' and
    'pkg/action/Name' as they are."""
    return type_name if type_name.count('/') == 2 else full_type(type_name)


def share_dirs() -> list[Path]:
    prefixes = [p for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]
    prefixes += [sys.prefix]
    out, seen = [], set()
    for p in prefixes:
        d = Path(p) / 'share'
        if d not in seen:
            seen.add(d)
            out.append(d)
    return out


@functools.lru_cache(maxsize=None)
def msg_text(type_name: str) -> str:
    """Text of the .msg file of a type."""
    pkg, name = split_type(type_name)
    for share in share_dirs():
        f = share / pkg / 'msg' / f'{name}.msg'
        if f.is_file():
            return f.read_text(encoding='utf-8')
    raise DefinitionNotFound(f'no {pkg}/msg/{name}.msg under any of '
                             f'{", ".join(str(s) for s in share_dirs())}')


def _type(node, detail) -> str:
    if node == Nodetype.BASE:
        return detail[0]
    if detail.rsplit('/', 1)[-1] == 'wstring':   # rosbags' .msg parser reads wstring as a name
        return 'wstring'
    return detail


def _field(name: str, desc) -> Field:
    node, detail = desc
    if node in (Nodetype.BASE, Nodetype.NAME):
        return Field(name, _type(node, detail), None)
    (sub_node, sub), n = detail
    if node == Nodetype.ARRAY:
        return Field(name, _type(sub_node, sub), 'fixed', n)
    return Field(name, _type(sub_node, sub), 'seq')


def parse(text: str, type_name: str) -> dict[str, list[Field]]:
    """A .msg text (or rosbag2's joined ``ros2msg`` text: the type, then ``MSG: pkg/Name``
    blocks) parsed by rosbags -> {full type name: fields}, constants left out; ValueError when
    rosbags cannot parse it."""
    try:
        types = get_types_from_msg(text, type_key(type_name))
    except TypesysError as exc:
        raise ValueError(f'cannot parse the definition of {type_name}: {exc}') from exc
    return {name: [_field(n, d) for n, d in defs] for name, (_consts, defs) in types.items()}


@functools.lru_cache(maxsize=None)
def constants(type_name: str) -> dict[str, int | float | str]:
    """The constants of a type (``uint8 FAULT_NONE=0`` -> ``{'FAULT_NONE': 0}``), from its
    installed .msg file: what code that cannot import the generated message (pure code) names
    the message's enumerated values by."""
    name = full_type(type_name)
    try:
        types = get_types_from_msg(msg_text(name), name)
    except TypesysError as exc:
        raise ValueError(f'cannot parse the definition of {name}: {exc}') from exc
    return {n: v for n, _t, v in types[name][0]}


@functools.lru_cache(maxsize=None)
def fields(type_name: str) -> tuple[Field, ...]:
    """The fields of a type, from its installed .msg file."""
    name = full_type(type_name)
    return tuple(parse(msg_text(name), name)[name])


def dependencies(fs) -> list[str]:
    """The message types ('pkg/msg/Name') that fields use, in order, each once."""
    out: list[str] = []
    for f in fs:
        if f.type not in FORMAT and f.type not in STRINGS and f.type not in out:
            out.append(f.type)
    return out


@functools.lru_cache(maxsize=None)
def leaves(type_name: str) -> tuple[tuple[str, Field], ...]:
    """The fields of a type with its nested (scalar) messages flattened: (dotted path, field)
    pairs in wire order, each a primitive, a string, a fixed array or a sequence."""
    out = []
    for f in fields(type_name):
        if f.array is None and f.type not in FORMAT and f.type not in STRINGS:
            out += [(f'{f.name}.{p}', g) for p, g in leaves(f.type)]
        else:
            out.append((f.name, f))
    return tuple(out)


def align(offset, size):
    """``offset`` (payload bytes: counted after the encapsulation header) rounded up to where
    a primitive of ``size`` bytes starts: a multiple of its size, 8 at most (XCDR1). Works on
    ints and numpy integer arrays alike."""
    a = min(size, 8)
    return offset + (-offset) % a


def layout(types, at: int = 0, order: str = '<') -> struct.Struct:
    """The primitives ``types`` (names of :data:`FORMAT`) one after the other from payload
    offset ``at``, each aligned by :func:`align`: a struct whose pad bytes ('x', packed as zeros)
    come before each value that needs them, the first included."""
    codes, off = [], at
    for t in types:
        size = struct.calcsize(order + FORMAT[t])
        start = align(off, size)
        codes.append(f'{start - off}x{FORMAT[t]}' if start > off else FORMAT[t])
        off = start + size
    return struct.Struct(order + ''.join(codes))


def _wire_types(type_name: str, path: str, f: Field) -> list[str]:
    """The primitives a leaf puts on the wire before any variable-length part."""
    if f.array is None and f.type in FORMAT:
        return [f.type]
    if f.array == 'fixed' and f.type in FORMAT:
        return [f.type] * f.size
    if f.array == 'seq' or (f.array is None and f.type == 'string'):
        return [LENGTH]                         # the count / the length, then the variable part
    raise ValueError(f'{type_name}.{path} ({f.type}{"[]" if f.array else ""}) has no fixed layout here')


def variable(f: Field) -> bool:
    """Whether a leaf's length is known only from the bytes (a string, a sequence, an array
    of strings or of messages)."""
    return f.array == 'seq' or f.type in STRINGS or (f.array == 'fixed' and f.type not in FORMAT)


def run(type_name: str, names, at: int = 0, order: str = '<') -> struct.Struct:
    """The leaves ``names`` of a type, consecutive in it, as one struct from payload offset
    ``at`` (:func:`layout`); a string or a sequence gives its uint32 length / count and ends
    the run. ValueError when the .msg does not have these fields in this order."""
    names = tuple(names)
    paths = [p for p, _ in leaves(type_name)]
    if not names or names[0] not in paths:
        raise ValueError(f'{type_name} has no field {names[:1]} (its fields: {", ".join(paths)})')
    i = paths.index(names[0])
    got = leaves(type_name)[i:i + len(names)]
    if tuple(p for p, _ in got) != names:
        raise ValueError(f'{type_name}: the fields from {names[0]} are {", ".join(paths[i:])}, '
                         f'not {", ".join(names)}')
    types = []
    for k, (p, f) in enumerate(got):
        if variable(f) and k != len(got) - 1:
            raise ValueError(f'{type_name}.{p} has a variable length: it ends a run')
        types += _wire_types(type_name, p, f)
    return layout(types, at, order)


def runs(type_name: str, names, order: str = '<') -> tuple[struct.Struct, ...]:
    """:func:`run` for each start offset modulo 8: ``runs(...)[offset & 7]`` packs and unpacks
    the fields at payload ``offset`` with the padding before them."""
    return tuple(run(type_name, names, at, order) for at in range(8))


@functools.lru_cache(maxsize=None)
def segments(type_name: str) -> tuple[tuple[str, ...], ...]:
    """A type's leaves cut after each string or sequence: the runs whose layout is fixed once
    the offset where they start is known."""
    out, cur = [], []
    for p, f in leaves(type_name):
        cur.append(p)
        if variable(f):
            out.append(tuple(cur))
            cur = []
    if cur:
        out.append(tuple(cur))
    return tuple(out)


def field_offset(type_name: str, path: str, frame_id: str = '') -> int:
    """Where leaf ``path`` of a message starts in its wire bytes (the encapsulation header
    included), its ``header.frame_id`` being ``frame_id``: the only string or sequence that
    may come before it. ValueError for a field behind another variable-length one."""
    off = 0
    for p, f in leaves(type_name):
        types = _wire_types(type_name, p, f)
        if not types:
            continue
        if p == path:
            return ENCAPSULATION_SIZE + align(off, struct.calcsize('<' + FORMAT[types[0]]))
        off += layout(types, off).size
        if variable(f):
            if p != 'header.frame_id':
                raise ValueError(f'{type_name}.{path} comes after {p}, of variable length')
            off += len(frame_id.encode()) + 1
    raise ValueError(f'{type_name} has no field {path}')
