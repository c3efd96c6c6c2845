"""Read a rosbag2 MCAP bag (ours, rosbag2's or rosbags') into per-topic arrays. No rclpy.

Always scans the data section (chunk by chunk), so a bag whose writer was killed (no summary,
no footer, no metadata.yaml, truncated last chunk) is read up to its last complete record;
``Bag.complete`` tells whether the file was finished and ``Bag.warnings`` what was recovered.
"""
from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml
from mcap.exceptions import McapError
from mcap.records import Channel, Chunk, Footer, Schema
from mcap.stream_reader import StreamReader

MAGIC = b'\x89MCAP0\r\n'
_U16 = struct.Struct('<H')
_U32 = struct.Struct('<I')
_HDR = struct.Struct('<BQ')
_MSG = struct.Struct('<HIQQ')


class BagReadError(Exception):
    """The path is not a readable bag."""


@dataclass
class Topic:
    name: str
    type: str
    schema: str
    encoding: str = 'cdr'
    qos: str = ''
    datas: list = field(default_factory=list)
    log_times: list = field(default_factory=list)
    publish_times: list = field(default_factory=list)

    @property
    def count(self) -> int:
        return len(self.datas)

    def log_ns(self) -> np.ndarray:
        return np.asarray(self.log_times, dtype=np.int64)


@dataclass
class Bag:
    path: Path
    files: list[Path]
    topics: dict[str, Topic]
    complete: bool
    metadata: dict | None
    warnings: list[str]

    @property
    def message_count(self) -> int:
        return sum(t.count for t in self.topics.values())

    def time_range(self) -> tuple[int, int] | None:
        ts = [t.log_ns() for t in self.topics.values() if t.count]
        if not ts:
            return None
        return int(min(a.min() for a in ts)), int(max(a.max() for a in ts))


def find_files(path) -> tuple[Path, list[Path], dict | None]:
    p = Path(path)
    if not p.exists():
        raise BagReadError(f'{p}: no such bag (directory or .mcap file)')
    if p.is_file():
        return p.parent, [p], None
    meta = None
    files: list[Path] = []
    mfile = p / 'metadata.yaml'
    if mfile.is_file():
        try:
            meta = yaml.safe_load(mfile.read_text(encoding='utf-8'))['rosbag2_bagfile_information']
            files = [p / f for f in meta.get('relative_file_paths', [])]
            files = [f for f in files if f.is_file()]
        except Exception:  # noqa: BLE001 - damaged metadata: scan the directory
            meta = None
    if not files:
        files = sorted(p.glob('*.mcap'))
    if not files:
        raise BagReadError(f'{p}: no .mcap file in the bag directory')
    return p, files, meta


def _str(buf, o):
    n = _U32.unpack_from(buf, o)[0]
    o += 4
    return bytes(buf[o:o + n]).decode('utf-8'), o + n


def _decompress(chunk: Chunk) -> bytes:
    if chunk.compression == 'zstd':
        import zstandard
        return zstandard.ZstdDecompressor().decompress(chunk.data,
                                                       max_output_size=chunk.uncompressed_size)
    if chunk.compression == 'lz4':
        import lz4.frame
        return lz4.frame.decompress(chunk.data)
    if chunk.compression == '':
        return chunk.data
    raise BagReadError(f'unsupported chunk compression {chunk.compression!r}')


class _Scan:
    def __init__(self, topics_filter=None):
        self.schemas: dict[int, tuple[str, str]] = {}
        self.channels: dict[int, Topic | None] = {}
        self.topics: dict[str, Topic] = {}
        self.filter = set(topics_filter) if topics_filter else None

    def schema(self, sid, name, data):
        self.schemas[sid] = (name, data.decode('utf-8', 'replace') if isinstance(data, (bytes, bytearray, memoryview)) else data)

    def channel(self, cid, sid, topic, enc, metadata):
        if cid in self.channels:
            return
        if self.filter is not None and topic not in self.filter:
            self.channels[cid] = None
            return
        sname, stext = self.schemas.get(sid, ('', ''))
        t = self.topics.get(topic)
        if t is None:
            t = self.topics[topic] = Topic(topic, sname, stext, enc,
                                           metadata.get('offered_qos_profiles', ''))
        self.channels[cid] = t

    def chunk_records(self, buf: bytes):
        mv = memoryview(buf)
        o, n = 0, len(buf)
        channels = self.channels
        while o + 9 <= n:
            op, length = _HDR.unpack_from(buf, o)
            o += 9
            end = o + length
            if op == 0x05:  # Message
                cid, _seq, lt, pt = _MSG.unpack_from(buf, o)
                t = channels.get(cid)
                if t is not None:
                    t.datas.append(bytes(mv[o + 22:end]))
                    t.log_times.append(lt)
                    t.publish_times.append(pt)
            elif op == 0x03:  # Schema
                sid = _U16.unpack_from(buf, o)[0]
                name, p = _str(buf, o + 2)
                _enc, p = _str(buf, p)
                dl = _U32.unpack_from(buf, p)[0]
                self.schema(sid, name, bytes(mv[p + 4:p + 4 + dl]))
            elif op == 0x04:  # Channel
                cid, sid = struct.unpack_from('<HH', buf, o)
                topic, p = _str(buf, o + 4)
                enc, p = _str(buf, p)
                ml = _U32.unpack_from(buf, p)[0]
                p += 4
                mend = p + ml
                meta = {}
                while p < mend:
                    k, p = _str(buf, p)
                    v, p = _str(buf, p)
                    meta[k] = v
                self.channel(cid, sid, topic, enc, meta)
            o = end


def read_bag(path, topics=None) -> Bag:
    """Read every message of a bag (directory or .mcap). ``topics``: only these topics."""
    root, files, meta = find_files(path)
    scan = _Scan(topics)
    warnings: list[str] = []
    complete = True
    for f in files:
        with open(f, 'rb') as fh:
            if fh.read(8) != MAGIC:
                raise BagReadError(f'{f}: not an MCAP file')
            fh.seek(0)
            reader = StreamReader(fh, emit_chunks=True, record_size_limit=1 << 31)
            footer = False
            try:
                for rec in reader.records:
                    if isinstance(rec, Chunk):
                        try:
                            data = _decompress(rec)
                        except Exception as exc:  # noqa: BLE001
                            warnings.append(f'{f.name}: damaged chunk skipped ({exc})')
                            continue
                        if rec.uncompressed_crc and zlib.crc32(data) != rec.uncompressed_crc:
                            warnings.append(f'{f.name}: chunk with bad CRC skipped')
                            continue
                        scan.chunk_records(data)
                    elif isinstance(rec, Schema):
                        scan.schema(rec.id, rec.name, rec.data)
                    elif isinstance(rec, Channel):
                        scan.channel(rec.id, rec.schema_id, rec.topic, rec.message_encoding,
                                     rec.metadata)
                    elif isinstance(rec, Footer):
                        footer = True
                    elif type(rec).__name__ == 'Message':
                        t = scan.channels.get(rec.channel_id)
                        if t is not None:
                            t.datas.append(bytes(rec.data))
                            t.log_times.append(rec.log_time)
                            t.publish_times.append(rec.publish_time)
            except (McapError, EOFError, struct.error, ValueError, MemoryError) as exc:
                warnings.append(f'{f.name}: truncated/unfinished file, recovered every complete '
                                f'chunk ({type(exc).__name__})')
            except Exception as exc:  # noqa: BLE001 - e.g. mcap's EndOfFile
                warnings.append(f'{f.name}: truncated/unfinished file, recovered every complete '
                                f'chunk ({type(exc).__name__})')
            if not footer:
                complete = False
    if meta is None and Path(path).is_dir():
        warnings.append('no metadata.yaml (recorder did not finish): recovered by scanning')
        complete = False
    # topics known only from metadata.yaml (no message recorded)
    if meta:
        for tw in meta.get('topics_with_message_count') or []:
            tm = tw.get('topic_metadata', {})
            name = tm.get('name')
            if name and name not in scan.topics and (topics is None or name in topics):
                scan.topics[name] = Topic(name, tm.get('type', ''), '', 'cdr')
    return Bag(root, files, scan.topics, complete, meta, warnings)
