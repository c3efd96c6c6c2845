"""CDR layout from ros2msg schema text, and column-wise (numpy, vectorised) decoding. No rclpy.

:func:`parse_schema` turns the joined ``ros2msg`` text embedded in a bag into struct definitions.
:func:`decode_columns` decodes *all* messages of one topic at once: it walks the fields once,
keeping a numpy array of the current offset of every message, so variable-length strings
(header.frame_id, ...) only shift offsets; every primitive field becomes one fancy-index gather.
Types with sequences of strings/structs raise :class:`NotBulkDecodable` (callers fall back to
``mcap_ros2``'s per-message decoder, :func:`decode_columns_fallback`).
"""
from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

SEPARATOR_RE = re.compile(r'^={80,}\s*$', re.M)

PRIM = {  # name: (numpy dtype, size)
    'bool': ('?', 1), 'byte': ('u1', 1), 'char': ('u1', 1), 'uint8': ('u1', 1), 'int8': ('i1', 1),
    'int16': ('<i2', 2), 'uint16': ('<u2', 2), 'int32': ('<i4', 4), 'uint32': ('<u4', 4),
    'int64': ('<i8', 8), 'uint64': ('<u8', 8), 'float32': ('<f4', 4), 'float64': ('<f8', 8),
}
STRINGS = {'string', 'wstring'}


class NotBulkDecodable(Exception):
    """The type (or this data) cannot be decoded column-wise."""


@dataclass(frozen=True)
class Field:
    name: str
    type: str          # primitive name, 'string', or full 'pkg/msg/Name'
    array: str | None  # None scalar, 'fixed', 'seq'
    size: int = 0      # fixed array length


_LINE = re.compile(r'^([A-Za-z][\w/]*)(?:<=\d+)?(\[(<=)?(\d*)\])?\s+([A-Za-z]\w*)(\s*=.*)?')


def _resolve(t: str, pkg: str) -> str:
    if t in PRIM or t in STRINGS:
        return t
    if t == 'Header':
        return 'std_msgs/msg/Header'
    parts = t.split('/')
    if len(parts) == 2:
        return f'{parts[0]}/msg/{parts[1]}'
    if len(parts) == 3:
        return t
    return f'{pkg}/msg/{t}'


def parse_msg(text: str, pkg: str) -> list[Field]:
    fields = []
    for line in text.splitlines():
        line = line.split('#', 1)[0].strip()
        if not line:
            continue
        m = _LINE.match(line)
        if not m:
            raise ValueError(f'cannot parse message definition line: {line!r}')
        if m.group(6):  # constant NAME=value
            continue
        base, brackets, bounded, n, name = m.groups()[:5]
        arr = None
        size = 0
        if brackets:
            if n and not bounded:
                arr, size = 'fixed', int(n)
            else:
                arr = 'seq'
        fields.append(Field(name, _resolve(base, pkg), arr, size))
    return fields


def parse_schema(type_name: str, text: str) -> dict[str, list[Field]]:
    """Joined ros2msg text -> {full type name: fields}; the main type is ``type_name``."""
    parts = SEPARATOR_RE.split(text)
    types: dict[str, list[Field]] = {}
    main_pkg = type_name.split('/')[0]
    types[_resolve(type_name, main_pkg)] = parse_msg(parts[0], main_pkg)
    for part in parts[1:]:
        part = part.lstrip('\n')
        first, _, body = part.partition('\n')
        if not first.startswith('MSG:'):
            raise ValueError(f'bad dependency block in schema of {type_name}: {first!r}')
        dep = _resolve(first[4:].strip(), main_pkg)
        types[dep] = parse_msg(body, dep.split('/')[0])
    return types


def _align(off, base, a):
    return base + ((off - base + (a - 1)) // a) * a


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
        self.off = _align(self.off, self.base, min(size, 8))
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
    main = _resolve(type_name, type_name.split('/')[0])
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
    f = types.get(_resolve(type_name, type_name.split('/')[0]), [])
    return (len(f) >= 2 and f[0].type == 'std_msgs/msg/Header' and f[0].array is None
            and f[1].name == 'seq' and f[1].type == 'uint64' and f[1].array is None)


def seq_of(data: bytes) -> int | None:
    """The uint64 after the Header of one CDR message (None if too short)."""
    # 4 encapsulation + 8 stamp, then frame_id string: uint32 length + bytes (incl. NUL)
    if len(data) < 20:
        return None
    n = int.from_bytes(data[12:16], 'little')
    off = 16 + n - 4                 # relative to the CDR body (after the 4-byte encapsulation)
    off = (off + 7) & ~7
    p = 4 + off
    if p + 8 > len(data):
        return None
    return int.from_bytes(data[p:p + 8], 'little')


def starts_with_header(type_name: str, schema_text: str) -> bool:
    """True when the type's first field is a ``std_msgs/Header`` (not an array)."""
    try:
        types = parse_schema(type_name, schema_text)
    except ValueError:
        return False
    f = types.get(_resolve(type_name, type_name.split('/')[0]), [])
    return bool(f) and f[0].type == 'std_msgs/msg/Header' and f[0].array is None
