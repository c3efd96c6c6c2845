"""Pure rosbag2 (Jazzy, metadata version 9) + MCAP bag writer. No rclpy.

A bag is a directory ``<dir>/`` holding ``metadata.yaml`` and ``<dir>_0.mcap``, written as
Jazzy's ``rosbag2_storage_mcap`` writes them (checked against its source, jazzy branch):

* header profile ``ros2`` (library: ``rwpend_bag <version>, mcap-python/<version>``; Jazzy's
  is ``libmcap 1.3.0``, rosbags' ``rosbags-<version>``);
* one ``ros2msg`` schema per type with the full joined definition; one channel per topic,
  ``cdr`` encoding, channel metadata ``offered_qos_profiles`` (YAML text of the list, as
  ``serialize_rclcpp_qos_vector`` writes it) and ``topic_type_hash`` (RIHS01, '' if unknown);
* a Metadata record named ``rosbag2`` with one key, ``serialized_metadata``: the YAML of the
  bag's metadata (the content of ``metadata.yaml`` without its ``rosbag2_bagfile_information``
  key), written when the bag is opened (nothing recorded yet, as Jazzy's SequentialWriter does
  at open) and again, complete, at close -- readers take the last one;
* messages in log-time order (:mod:`rwpend_bag.logtime`: every message's log time >= the one
  before it in the file, whatever the caller gives; what had to be raised is counted).

Differences from Jazzy, on purpose: chunks are zstd compressed with CRCs (Jazzy's default is
uncompressed without chunk CRCs) and closed after ~1 MB or ~1 s, always between two log times
(so no two chunks' time ranges overlap, also when many messages share a sim time), each
flushed to the file, so a writer killed with SIGKILL leaves every completed chunk readable
(see reader.py); the message
``sequence`` is a per-channel counter (Jazzy and rosbags write 0; the spec lets a recorder
assign it). ``metadata.yaml`` is written by :meth:`BagWriter.close`.

:class:`ThreadedBagWriter` feeds a BagWriter from a queue in its own thread (for the recorder:
the executor callback only enqueues bytes), through an order policy
(:class:`rwpend_bag.logtime.ArrivalOrder` in real time, :class:`~rwpend_bag.logtime.SimTimeOrder`
in lockstep), and tracks the ``seq`` of every message.
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
from mcap.writer import LIBRARY_IDENTIFIER, CompressionType, Writer

from . import msgdefs
from .logtime import ArrivalOrder, LogTimeGuard, SimTimeOrder, stamp_kind
from .seqtrack import SeqTracker

CHUNK_BYTES = 1024 * 1024
CHUNK_SECONDS = 1.0
INFINITE_TIME = {'sec': 9223372036, 'nsec': 854775807}
#: the initial metadata's starting time (Jazzy: std::chrono::nanoseconds::max())
NO_TIME_NS = 9223372036854775807
VERSION = '0.1.0'
LIBRARY = f'rwpend_bag {VERSION}, {LIBRARY_IDENTIFIER}'
#: name and key of the metadata record Jazzy's rosbag2_storage_mcap writes
METADATA_RECORD = 'rosbag2'
METADATA_KEY = 'serialized_metadata'


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
    """YAML text of a list of QoS profiles (the channel metadata ``offered_qos_profiles``), as
    Jazzy's ``serialize_rclcpp_qos_vector`` writes it (block style; ``[]`` for none)."""
    lst = _qos_list(qos)
    return yaml.safe_dump(lst, default_flow_style=False, sort_keys=False).strip() if lst else '[]'


def check_new_bag_path(path) -> Path:
    """``path`` as a Path, if a bag may be written there (BagError otherwise)."""
    p = Path(path)
    if p.exists() and (not p.is_dir() or any(p.iterdir())):
        raise BagError(f'{p} already exists (refusing to overwrite a bag)')
    if not p.name:
        raise BagError(f'bad bag path {path!r}')
    return p


class BagWriter:
    """Write one rosbag2 MCAP bag directory.

    ``BagWriter(path)``; ``add_topic(name, type, qos)``; ``write(topic, data, log_time_ns)``;
    ``close(custom_data=None)``. ``path`` must not exist yet (or be an empty directory).
    """

    def __init__(self, path, chunk_bytes: int = CHUNK_BYTES, chunk_seconds: float = CHUNK_SECONDS,
                 compression: str = 'zstd'):
        self.path = check_new_bag_path(path)
        self.path.mkdir(parents=True, exist_ok=True)
        self.file_name = f'{self.path.name}_0.mcap'
        self.mcap_path = self.path / self.file_name
        self._stream = open(self.mcap_path, 'wb')
        comp = {'zstd': CompressionType.ZSTD, 'lz4': CompressionType.LZ4,
                'none': CompressionType.NONE}[compression]
        # chunks are closed here, not by the mcap writer's size check (never reached): only
        # between two log times, so the chunks' time ranges do not overlap (mcap info: overlaps no)
        self._mcap = Writer(self._stream, chunk_size=1 << 62, compression=comp)
        self._mcap.start(profile='ros2', library=LIBRARY)
        self._chunk_bytes = chunk_bytes
        self._chunk_seconds = chunk_seconds
        self._pending = 0              # bytes of messages in the chunk in progress
        self._last_flush = time.monotonic()
        self._schemas: dict[str, int] = {}
        self.topics: dict[str, dict[str, Any]] = {}
        self.start_ns: int | None = None
        self.end_ns: int | None = None
        self.guard = LogTimeGuard()
        self.closed = False
        self._write_metadata_record(self.metadata())

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
        # as Jazzy: both keys on every channel (an unknown hash is '')
        meta = {'offered_qos_profiles': qos_yaml(qos_l), 'topic_type_hash': type_hash or ''}
        cid = self._mcap.register_channel(topic=name, message_encoding='cdr',
                                          schema_id=self._schemas[type_name], metadata=meta)
        self.topics[name] = {'type': type_name, 'channel': cid, 'qos': qos_l,
                             'hash': type_hash, 'count': 0, 'definition': definition}

    def stamp_kind(self, topic: str) -> str:
        """How a topic's messages are logged in lockstep (:func:`rwpend_bag.logtime.stamp_kind`)."""
        t = self.topics[topic]
        return stamp_kind(t['type'], t['definition'])

    def write(self, topic: str, data: bytes, log_time_ns: int,
              publish_time_ns: int | None = None) -> None:
        """Append one serialized (CDR, wire bytes) message. A log time older than the last one
        written is raised to it (counted: :attr:`guard`); ``publish_time_ns`` (default: the
        log time asked for) keeps the message's own time."""
        t = self.topics.get(topic)
        if t is None:
            raise BagError(f'topic {topic} was not added')
        asked = int(log_time_ns)
        before = self.guard.last_ns
        log_time_ns = self.guard.admit(topic, asked)
        if self._pending and log_time_ns != before and (
                self._pending >= self._chunk_bytes
                or time.monotonic() - self._last_flush >= self._chunk_seconds):
            self.flush()               # the chunk ends before the first message of a new log time
        seq = t['count'] & 0xFFFFFFFF
        self._mcap.add_message(channel_id=t['channel'], log_time=log_time_ns, data=data,
                               publish_time=asked if publish_time_ns is None else int(publish_time_ns),
                               sequence=seq)
        t['count'] += 1
        self._pending += len(data) + 31          # + the Message record's opcode, length, fields
        if self.start_ns is None or log_time_ns < self.start_ns:
            self.start_ns = int(log_time_ns)
        if self.end_ns is None or log_time_ns > self.end_ns:
            self.end_ns = int(log_time_ns)

    def maybe_flush(self) -> None:
        """Close the chunk in progress if it is older than chunk_seconds (the writer thread
        calls it when no message waits)."""
        if self._pending and time.monotonic() - self._last_flush >= self._chunk_seconds:
            self.flush()

    def flush(self) -> None:
        """Close the chunk in progress and flush the file."""
        self._mcap.flush()
        self._pending = 0
        self._last_flush = time.monotonic()

    @property
    def message_count(self) -> int:
        return sum(t['count'] for t in self.topics.values())

    def metadata(self, custom_data: dict[str, str] | None = None) -> dict:
        """The bag's rosbag2 metadata (version 9, keys in Jazzy's order): the content of
        ``metadata.yaml`` under ``rosbag2_bagfile_information`` and of the MCAP ``rosbag2``
        record. Before the first message, the starting times are Jazzy's "none yet" (int64 max)."""
        start = NO_TIME_NS if self.start_ns is None else self.start_ns
        duration = (self.end_ns - self.start_ns) if self.start_ns is not None else 0
        count = self.message_count
        return {
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
        }

    def _write_metadata_record(self, meta: dict) -> None:
        text = yaml.safe_dump(meta, default_flow_style=False, sort_keys=False)
        self._mcap.add_metadata(METADATA_RECORD, {METADATA_KEY: text})

    def close(self, custom_data: dict[str, str] | None = None) -> None:
        """Finish the MCAP (the final ``rosbag2`` metadata record, summary, footer) and write
        metadata.yaml (atomically)."""
        if self.closed:
            return
        self.closed = True
        meta = self.metadata(custom_data)
        self._write_metadata_record(meta)
        self._mcap.finish()
        self._stream.flush()
        os.fsync(self._stream.fileno())
        self._stream.close()
        tmp = self.path / 'metadata.yaml.tmp'
        tmp.write_text(yaml.safe_dump({'rosbag2_bagfile_information': meta}, default_flow_style=False,
                                      sort_keys=False), encoding='utf-8')
        tmp.replace(self.path / 'metadata.yaml')

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class BagSink:
    """The writing end shared by :class:`ThreadedBagWriter` and :class:`ProcessBagWriter`:
    items taken one at a time (``('msg', topic, data, time_ns)`` or ``('topic', name, type,
    qos)``) go through ``order`` (default :class:`~rwpend_bag.logtime.ArrivalOrder`: logged at
    the time given; :class:`~rwpend_bag.logtime.SimTimeOrder` in lockstep) into a
    :class:`BagWriter`, the ``seq`` of every message tracked (:class:`SeqTracker`, in the order
    the messages were put). A failing item is counted and the others are still written.
    :meth:`finish` writes the recording report (``recording_report.json`` and metadata
    custom_data) and finalises the bag."""

    def __init__(self, path, order: ArrivalOrder | SimTimeOrder | None = None, **kwargs):
        self.bag = BagWriter(path, **kwargs)
        self.order = ArrivalOrder() if order is None else order
        self.seqs = SeqTracker()
        self.error: BaseException | None = None
        self.errors = 0
        self.max_queue = 0

    def _failed(self, exc: BaseException) -> None:
        self.errors += 1
        if self.error is None:
            self.error = exc

    def _write(self, entries) -> None:
        bag = self.bag
        for e in entries:
            try:
                bag.write(e.topic, e.data, e.log_ns, e.publish_ns)
            except BaseException as exc:  # noqa: BLE001 - keep writing the others; reported
                self._failed(exc)

    def take(self, item) -> None:
        try:
            if item[0] == 'msg':
                _, topic, data, t = item
                self.seqs.add(topic, data)
                self._write(self.order.push(topic, data, t))
            elif item[0] == 'topic':
                self.bag.add_topic(item[1], item[2], item[3])
                self.seqs.register(item[1], self.bag.topics[item[1]]['type'])
                self.order.add_topic(item[1], self.bag.stamp_kind(item[1]))
        except BaseException as exc:  # noqa: BLE001 - keep writing the other topics
            self._failed(exc)

    def idle(self) -> None:
        """Nothing waits: close a chunk that is old enough (a killed writer loses at most it)."""
        if not self.bag.closed:
            self.bag.maybe_flush()

    def finish(self, extra: dict[str, Any] | None = None) -> dict[str, Any]:
        """Write what the order still holds, finalise; returns the recording report (dict)."""
        self._write(self.order.flush())
        report = self.seqs.report()
        report_doc = {'bag': str(self.bag.path), 'message_count': self.bag.message_count,
                      'topics': report, 'max_queue': self.max_queue,
                      'log_times': {**self.order.report(), 'written': self.bag.guard.report()}}
        if self.error is not None:
            report_doc['writer_error'] = repr(self.error)
            report_doc['writer_errors'] = self.errors
        if extra:
            report_doc.update(extra)
        custom = {'rwpend.recording_report': json.dumps(report_doc, sort_keys=True),
                  'rwpend.log_time': self.order.mode}
        self.bag.close(custom)
        (self.bag.path / 'recording_report.json').write_text(
            json.dumps(report_doc, indent=2, sort_keys=True) + '\n', encoding='utf-8')
        return report_doc


class ThreadedBagWriter:
    """A :class:`BagSink` driven by its own thread: ``put()`` only enqueues (safe from any
    thread). ``close()`` drains the queue and the order's buffer and returns the recording
    report."""

    #: seconds between two looks at the queue when it is empty
    poll_s = 0.002

    def __init__(self, path, order: ArrivalOrder | SimTimeOrder | None = None, **kwargs):
        self.sink = BagSink(path, order, **kwargs)
        self.bag = self.sink.bag
        self._q: queue.SimpleQueue = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._run, name='bag-writer', daemon=True)
        self._thread.start()

    @property
    def error(self) -> BaseException | None:
        return self.sink.error

    @property
    def errors(self) -> int:
        return self.sink.errors

    def add_topic(self, name: str, type_name: str, qos=None) -> None:
        self._q.put(('topic', name, type_name, qos))

    def put(self, topic: str, data: bytes, log_time_ns: int) -> None:
        self._q.put(('msg', topic, data, log_time_ns))

    def queue_size(self) -> int:
        """Messages put and not yet taken by the writer thread."""
        return self._q.qsize()

    def _run(self) -> None:
        q = self._q
        sink = self.sink
        poll = self.poll_s
        while True:
            try:
                item = q.get_nowait()
            except queue.Empty:
                sink.idle()
                # one wake-up per poll period, not one per message: at 1 kHz the recorder gets
                # ~5000 messages/s, and waking this thread for each cost the recorder CPU and
                # the loop's processes CPU time (PERFORMANCE.md)
                time.sleep(poll)
                continue
            if item[0] == 'stop':
                return
            sink.take(item)
            n = q.qsize()
            if n > sink.max_queue:
                sink.max_queue = n

    def close(self, extra: dict[str, Any] | None = None) -> dict[str, Any]:
        """Drain, finalise; returns the recording report (dict)."""
        self._q.put(('stop',))
        self._thread.join()
        return self.sink.finish(extra)
