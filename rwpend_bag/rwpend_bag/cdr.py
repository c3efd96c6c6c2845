"""Column-wise (numpy, vectorised) decoding of CDR messages from ros2msg schema text. No rclpy.

:func:`parse_schema` turns the joined ``ros2msg`` text embedded in a bag into struct definitions
(rosbags parses it: :func:`rwpend_ros.msglayout.parse`).
:func:`decode_columns` decodes *all* messages of one topic at once: it walks the fields once,
keeping a numpy array of the current offset of every message, so variable-length strings
(header.frame_id, ...) only shift offsets; every primitive field becomes one fancy-index gather,
aligned by CDR's rule (:func:`rwpend_ros.msglayout.align`).
Types with sequences of strings/structs raise :class:`NotBulkDecodable` (callers fall back to
``mcap_ros2``'s per-message decoder, :func:`decode_columns_fallback`).
"""
from __future__ import annotations

import functools
import struct

import numpy as np

from rwpend_ros.msglayout import Field, align, parse, type_key  # noqa: F401 - Field: the fields' type
from rwpend_ros.wire import message_seq_stamp

PRIM = {  # name: (numpy dtype, size)
    'bool': ('?', 1), 'byte': ('u1', 1), 'char': ('u1', 1), 'uint8': ('u1', 1), 'int8': ('i1', 1),
    'int16': ('<i2', 2), 'uint16': ('<u2', 2), 'int32': ('<i4', 4), 'uint32': ('<u4', 4),
    'int64': ('<i8', 8), 'uint64': ('<u8', 8), 'float32': ('<f4', 4), 'float64': ('<f8', 8),
}
STRINGS = {'string', 'wstring'}


class NotBulkDecodable(Exception):
    """The type (or this data) cannot be decoded column-wise."""


@functools.lru_cache(maxsize=256)
def _parsed(type_name: str, text: str) -> dict[str, tuple[Field, ...]]:
    return {name: tuple(fs) for name, fs in parse(text, type_name).items()}


def parse_schema(type_name: str, text: str) -> dict[str, list[Field]]:
    """Joined ros2msg text -> {full type name: fields}; the main type is ``type_name``.
    ValueError when it cannot be parsed."""
    return {name: list(fs) for name, fs in _parsed(type_key(type_name), text).items()}


class _Walker:
    def __init__(self, types, buf, starts, ends, want):
        self.types, self.buf, self.ends = types, buf, ends
        self.base = starts + 4
        self.off = self.base.copy()
        self.cols: dict[str, np.ndarray] = {}
        self.want = want

    def _check(self, nbytes):
        if np.any(self.off + nbytes > self.ends):
            raise NotBulkDecodable('message shorter than its layout')

    def _gather(self, dt, size, count=1):
        self.off = self.base + align(self.off - self.base, size)
        total = size * count
        self._check(total)
        idx = self.off[:, None] + np.arange(total)
        vals = self.buf[idx].view(dt)
        self.off = self.off + total
        return vals if count > 1 else vals.ravel()

    def _string(self):
        n = self._gather('<u4', 4).astype(np.int64)
        self._check(n)
        starts = self.off
        self.off = self.off + n
        return starts, n

    def _want(self, path):
        return self.want is None or any(path == w or path.startswith(w + '.') or w.startswith(path + '.')
                                        for w in self.want)

    def struct(self, type_name, prefix):
        fields = self.types.get(type_name)
        if fields is None:
            raise NotBulkDecodable(f'no definition of {type_name} in the schema')
        for f in fields:
            path = f'{prefix}{f.name}'
            if f.array is None:
                if f.type in PRIM:
                    dt, size = PRIM[f.type]
                    v = self._gather(dt, size)
                    if self._want(path):
                        self.cols[path] = v
                elif f.type in STRINGS:
                    if f.type == 'wstring':
                        raise NotBulkDecodable('wstring')
                    s, n = self._string()
                    if self._want(path):
                        self.cols[path] = self._strings(s, n)
                else:
                    self.struct(f.type, path + '.')
            elif f.type in PRIM:
                dt, size = PRIM[f.type]
                if f.array == 'fixed':
                    count = f.size
                else:
                    counts = self._gather('<u4', 4)
                    if counts.size and not np.all(counts == counts[0]):
                        raise NotBulkDecodable(f'sequence {path} of varying length')
                    count = int(counts[0]) if counts.size else 0
                if count == 0:
                    if self._want(path):
                        self.cols[path] = np.zeros((len(self.off), 0), dt)
                    continue
                v = self._gather(dt, size, count).reshape(len(self.off), count)
                if self._want(path):
                    self.cols[path] = v
            else:
                raise NotBulkDecodable(f'array of {f.type} ({path})')

    def _strings(self, starts, n):
        """Strings (NUL dropped) as a numpy unicode array; vectorised per distinct length."""
        out = np.empty(len(starts), dtype=object)
        for length in np.unique(n):
            sel = np.nonzero(n == length)[0]
            L = int(length) - 1  # without the NUL
            if L <= 0:
                out[sel] = ''
                continue
            raw = self.buf[starts[sel, None] + np.arange(L)]
            out[sel] = np.char.decode(raw.view(f'S{L}').ravel(), 'utf-8', 'replace')
        return out.astype(str) if len(out) else np.zeros(0, dtype=str)


def decode_columns(type_name: str, schema_text: str, datas: list[bytes],
                   fields: list[str] | None = None) -> dict[str, np.ndarray]:
    """Decode every message of one type column-wise. ``fields``: dotted paths to keep (None: all).

    Returns {'header.stamp.sec': array, 'seq': array, ...}. Raises NotBulkDecodable.
    """
    types = parse_schema(type_name, schema_text)
    main = type_key(type_name)
    if not datas:
        return {}
    lengths = np.fromiter((len(d) for d in datas), dtype=np.int64, count=len(datas))
    buf = np.frombuffer(b''.join(datas), dtype=np.uint8)
    ends = np.cumsum(lengths)
    starts = ends - lengths
    if np.any(lengths < 4):
        raise NotBulkDecodable('message shorter than the CDR header')
    if np.any(buf[starts + 1] != 1) or np.any(buf[starts] != 0):
        raise NotBulkDecodable('not little-endian plain CDR')
    w = _Walker(types, buf, starts, ends, fields)
    w.struct(main, '')
    return w.cols


def decode_columns_fallback(type_name: str, schema_text: str, datas: list[bytes],
                            fields: list[str] | None = None) -> dict[str, np.ndarray]:
    """Per-message decoding with mcap_ros2's dynamic decoder; scalar leaves become columns."""
    from mcap_ros2._dynamic import read_message  # noqa: F401 - availability check
    from mcap_ros2.decoder import DecoderFactory
    from mcap.records import Schema
    dec = DecoderFactory().decoder_for('cdr', Schema(id=1, name=type_name, encoding='ros2msg',
                                                     data=schema_text.encode()))
    rows = [dec(d) for d in datas]
    cols: dict[str, list] = {}

    def walk(obj, prefix):
        for k in getattr(obj, '__slots__', None) or list(vars(obj)):
            v = getattr(obj, k)
            path = prefix + k
            if hasattr(v, '__slots__') or hasattr(v, '__dict__') and not isinstance(v, (str, bytes)):
                walk(v, path + '.')
            else:
                cols.setdefault(path, []).append(v)

    for r in rows:
        walk(r, '')
    out = {}
    for k, v in cols.items():
        if fields is not None and not any(k == f or k.startswith(f + '.') for f in fields):
            continue
        if len(v) != len(rows):
            continue
        try:
            out[k] = np.asarray(v)
        except Exception:  # noqa: BLE001 - ragged
            out[k] = np.asarray(v, dtype=object)
    return out


def decode(type_name: str, schema_text: str, datas: list[bytes],
           fields: list[str] | None = None) -> tuple[dict[str, np.ndarray], bool]:
    """Bulk decode, falling back to mcap_ros2. Returns (columns, bulk_used)."""
    try:
        return decode_columns(type_name, schema_text, datas, fields), True
    except NotBulkDecodable:
        return decode_columns_fallback(type_name, schema_text, datas, fields), False


def header_seq_layout(type_name: str, schema_text: str) -> bool:
    """True when the type starts with ``std_msgs/Header header`` followed by ``uint64 seq``."""
    try:
        types = parse_schema(type_name, schema_text)
    except ValueError:
        return False
    f = types.get(type_key(type_name), [])
    return (len(f) >= 2 and f[0].type == 'std_msgs/msg/Header' and f[0].array is None
            and f[1].name == 'seq' and f[1].type == 'uint64' and f[1].array is None)


def seq_of(data: bytes) -> int | None:
    """The uint64 after the Header of one CDR message (None if too short): the layout of the
    loop's messages (:func:`rwpend_ros.wire.message_seq_stamp`)."""
    try:
        return message_seq_stamp(data)[0]
    except struct.error:
        return None


def starts_with_header(type_name: str, schema_text: str) -> bool:
    """True when the type's first field is a ``std_msgs/Header`` (not an array)."""
    try:
        types = parse_schema(type_name, schema_text)
    except ValueError:
        return False
    f = types.get(type_key(type_name), [])
    return bool(f) and f[0].type == 'std_msgs/msg/Header' and f[0].array is None
