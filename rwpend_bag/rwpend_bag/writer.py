"""Pure rosbag2 (Jazzy, metadata version 9) + MCAP bag writer. No rclpy.

A bag is a directory ``<dir>/`` holding ``metadata.yaml`` and ``<dir>_0.mcap`` (profile ``ros2``,
``ros2msg`` schemas with the full joined definitions, ``cdr`` messages). Chunks are zstd
compressed and closed every ~1 MB or ~1 s, and each closed chunk is flushed to the file, so a
writer killed with SIGKILL leaves every completed chunk readable (see reader.py for recovery).
``metadata.yaml`` is written by :meth:`BagWriter.close`.

:class:`ThreadedBagWriter` feeds a BagWriter from a queue in its own thread (for the recorder:
the executor callback only enqueues bytes) and tracks the ``seq`` of every message.
"""
from __future__ import annotations

import json
import os
import queue
import threading
import time
from pathlib import Path
from typing import Any

import yaml
from mcap.writer import CompressionType, Writer

from . import msgdefs
from .seqtrack import SeqTracker

CHUNK_BYTES = 1024 * 1024
CHUNK_SECONDS = 1.0
INFINITE_TIME = {'sec': 9223372036, 'nsec': 854775807}


class BagError(Exception):
    """Bad bag path or use of the writer/reader."""


def default_qos(reliability: str = 'reliable', durability: str = 'volatile', depth: int = 0,
                history: str = 'unknown') -> dict[str, Any]:
    """One offered QoS profile as rosbag2 Jazzy writes it in metadata version 9."""
    return {'history': history, 'depth': depth, 'reliability': reliability,
            'durability': durability, 'deadline': dict(INFINITE_TIME),
            'lifespan': dict(INFINITE_TIME), 'liveliness': 'automatic',
            'liveliness_lease_duration': dict(INFINITE_TIME),
            'avoid_ros_namespace_conventions': False}


def _qos_list(qos) -> list[dict]:
    if qos is None:
        return []
    if isinstance(qos, str):
        loaded = yaml.safe_load(qos) if qos.strip() else []
        return list(loaded or [])
    if isinstance(qos, dict):
        return [qos]
    return list(qos)


def qos_yaml(qos) -> str:
    """YAML text of a list of QoS profiles (the channel metadata ``offered_qos_profiles``)."""
    lst = _qos_list(qos)
    return yaml.safe_dump(lst, default_flow_style=False, sort_keys=False).strip() if lst else ''


class BagWriter:
    """Write one rosbag2 MCAP bag directory.

    ``BagWriter(path)``; ``add_topic(name, type, qos)``; ``write(topic, data, log_time_ns)``;
    ``close(custom_data=None)``. ``path`` must not exist yet (or be an empty directory).
    """

    def __init__(self, path, chunk_bytes: int = CHUNK_BYTES, chunk_seconds: float = CHUNK_SECONDS,
                 compression: str = 'zstd'):
        self.path = Path(path)
        if self.path.exists() and (not self.path.is_dir() or any(self.path.iterdir())):
            raise BagError(f'{self.path} already exists (refusing to overwrite a bag)')
        if not self.path.name:
            raise BagError(f'bad bag path {path!r}')
        self.path.mkdir(parents=True, exist_ok=True)
        self.file_name = f'{self.path.name}_0.mcap'
        self.mcap_path = self.path / self.file_name
        self._stream = open(self.mcap_path, 'wb')
        comp = {'zstd': CompressionType.ZSTD, 'lz4': CompressionType.LZ4,
                'none': CompressionType.NONE}[compression]
        self._mcap = Writer(self._stream, chunk_size=chunk_bytes, compression=comp)
        self._mcap.start(profile='ros2', library='rwpend_bag')
        self._chunk_seconds = chunk_seconds
        self._last_flush = time.monotonic()
        self._schemas: dict[str, int] = {}
        self.topics: dict[str, dict[str, Any]] = {}
        self.start_ns: int | None = None
        self.end_ns: int | None = None
        self.closed = False

    def add_topic(self, name: str, type_name: str, qos=None, definition: str | None = None,
                  type_hash: str | None = None) -> None:
        """Register a topic. ``qos``: list of profile dicts, one dict, YAML text or None.
        ``definition``: joined ros2msg text (default: built from the installed .msg files)."""
        if name in self.topics:
            if self.topics[name]['type'] != msgdefs.full_type(type_name):
                raise BagError(f'topic {name} already added with type {self.topics[name]["type"]}')
            return
        type_name = msgdefs.full_type(type_name)
        if definition is None:
            definition = msgdefs.joined_definition(type_name)
        if type_hash is None:
            type_hash = msgdefs.type_hash(type_name, definition)
        if type_name not in self._schemas:
            self._schemas[type_name] = self._mcap.register_schema(
                name=type_name, encoding='ros2msg', data=definition.encode('utf-8'))
        qos_l = _qos_list(qos)
        meta = {'offered_qos_profiles': qos_yaml(qos_l)}
        if type_hash:
            meta['topic_type_hash'] = type_hash
        cid = self._mcap.register_channel(topic=name, message_encoding='cdr',
                                          schema_id=self._schemas[type_name], metadata=meta)
        self.topics[name] = {'type': type_name, 'channel': cid, 'qos': qos_l,
                             'hash': type_hash, 'count': 0}

    def write(self, topic: str, data: bytes, log_time_ns: int,
              publish_time_ns: int | None = None) -> None:
        """Append one serialized (CDR, wire bytes) message."""
        t = self.topics.get(topic)
        if t is None:
            raise BagError(f'topic {topic} was not added')
        seq = t['count'] & 0xFFFFFFFF
        self._mcap.add_message(channel_id=t['channel'], log_time=int(log_time_ns), data=data,
                               publish_time=int(log_time_ns if publish_time_ns is None
                                                else publish_time_ns), sequence=seq)
        t['count'] += 1
        if self.start_ns is None or log_time_ns < self.start_ns:
            self.start_ns = int(log_time_ns)
        if self.end_ns is None or log_time_ns > self.end_ns:
            self.end_ns = int(log_time_ns)
        self.maybe_flush()

    def maybe_flush(self) -> None:
        """Close the chunk in progress if it is older than chunk_seconds."""
        now = time.monotonic()
        if now - self._last_flush >= self._chunk_seconds:
            self.flush()

    def flush(self) -> None:
        self._mcap.flush()
        self._last_flush = time.monotonic()

    @property
    def message_count(self) -> int:
        return sum(t['count'] for t in self.topics.values())

    def metadata(self, custom_data: dict[str, str] | None = None) -> dict:
        start = self.start_ns or 0
        duration = (self.end_ns - self.start_ns) if self.start_ns is not None else 0
        count = self.message_count
        return {'rosbag2_bagfile_information': {
            'version': 9,
            'storage_identifier': 'mcap',
            'duration': {'nanoseconds': duration},
            'starting_time': {'nanoseconds_since_epoch': start},
            'message_count': count,
            'topics_with_message_count': [
                {'topic_metadata': {'name': name, 'type': t['type'],
                                    'serialization_format': 'cdr',
                                    'offered_qos_profiles': t['qos'],
                                    'type_description_hash': t['hash']},
                 'message_count': t['count']}
                for name, t in self.topics.items()],
            'compression_format': '',
            'compression_mode': '',
            'relative_file_paths': [self.file_name],
            'files': [{'path': self.file_name,
                       'starting_time': {'nanoseconds_since_epoch': start},
                       'duration': {'nanoseconds': duration},
                       'message_count': count}],
            'custom_data': {str(k): str(v) for k, v in custom_data.items()} if custom_data else None,
            'ros_distro': 'jazzy',
        }}

    def close(self, custom_data: dict[str, str] | None = None) -> None:
        """Finish the MCAP (summary, footer) and write metadata.yaml (atomically)."""
        if self.closed:
            return
        self.closed = True
        if custom_data:
            self._mcap.add_metadata('rwpend', {str(k): str(v) for k, v in custom_data.items()})
        self._mcap.finish()
        self._stream.flush()
        os.fsync(self._stream.fileno())
        self._stream.close()
        tmp = self.path / 'metadata.yaml.tmp'
        tmp.write_text(yaml.safe_dump(self.metadata(custom_data), default_flow_style=False,
                                      sort_keys=False), encoding='utf-8')
        tmp.replace(self.path / 'metadata.yaml')

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class ThreadedBagWriter:
    """A BagWriter driven by its own thread: ``put()`` only enqueues (safe from any thread).

    Also tracks ``seq`` per topic (:class:`SeqTracker`). ``close()`` drains the queue, writes the
    recording report (``recording_report.json`` and metadata custom_data) and finalises the bag.
    """

    #: seconds between two looks at the queue when it is empty
    poll_s = 0.002

    def __init__(self, path, **kwargs):
        self.bag = BagWriter(path, **kwargs)
        self.seqs = SeqTracker()
        self._q: queue.SimpleQueue = queue.SimpleQueue()
        self.error: BaseException | None = None
        self.max_queue = 0
        self._thread = threading.Thread(target=self._run, name='bag-writer', daemon=True)
        self._thread.start()

    def add_topic(self, name: str, type_name: str, qos=None) -> None:
        self._q.put(('topic', name, type_name, qos))

    def put(self, topic: str, data: bytes, log_time_ns: int) -> None:
        self._q.put(('msg', topic, data, log_time_ns))

    def _run(self) -> None:
        q = self._q
        bag = self.bag
        poll = self.poll_s
        while True:
            try:
                item = q.get_nowait()
            except queue.Empty:
                if not bag.closed:
                    bag.maybe_flush()
                # one wake-up per poll period, not one per message: at 1 kHz the recorder gets
                # ~5000 messages/s, and waking this thread for each cost the recorder CPU and
                # the loop's processes CPU time (PERFORMANCE.md)
                time.sleep(poll)
                continue
            kind = item[0]
            try:
                if kind == 'msg':
                    _, topic, data, t = item
                    bag.write(topic, data, t)
                    self.seqs.add(topic, data)
                elif kind == 'topic':
                    bag.add_topic(item[1], item[2], item[3])
                    self.seqs.register(item[1], bag.topics[item[1]]['type'])
                elif kind == 'stop':
                    return
            except BaseException as exc:  # noqa: BLE001 - keep writing the other topics
                if self.error is None:
                    self.error = exc
            n = q.qsize()
            if n > self.max_queue:
                self.max_queue = n

    def close(self, extra: dict[str, Any] | None = None) -> dict[str, Any]:
        """Drain, finalise; returns the recording report (dict)."""
        self._q.put(('stop',))
        self._thread.join()
        report = self.seqs.report()
        report_doc = {'bag': str(self.bag.path), 'message_count': self.bag.message_count,
                      'topics': report, 'max_queue': self.max_queue}
        if self.error is not None:
            report_doc['writer_error'] = repr(self.error)
        if extra:
            report_doc.update(extra)
        self.bag.close({'rwpend.recording_report': json.dumps(report_doc, sort_keys=True)})
        (self.bag.path / 'recording_report.json').write_text(
            json.dumps(report_doc, indent=2, sort_keys=True) + '\n', encoding='utf-8')
        return report_doc
