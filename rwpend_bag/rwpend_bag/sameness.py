"""What "the same bag" means for two lockstep runs, and the comparison. Pure (no rclpy).

A lockstep run (``./rwpend up --lockstep --record``) is deterministic in what the loop
computes; its bag is recorded with log times on the simulated clock in a deterministic order
(:class:`rwpend_bag.logtime.SimTimeOrder`). Two lockstep bags of the same command line are
**the same bag** when, for the *loop topics* -- ``/clock`` and, under the rig's namespace,
``encoders``, ``sim/true_state``, ``state``, ``joint_states``, ``command`` and
``controller/status`` (:data:`LOOP_TOPICS`) -- all of this is equal:

1. the channels: each loop topic present in both or in neither, with the same type, the same
   embedded ``ros2msg`` schema text and the same ``topic_type_hash``;
2. the messages: per loop topic the same number, and message by message the same CDR bytes;
3. the times: message by message the same ``log_time`` and ``publish_time`` (both sim time)
   and the same MCAP ``sequence`` (the per-channel counter);
4. the order: the loop topics' messages, taken in file order, form the same sequence
   (topic by topic interleaving included).

Not part of it (not deterministic by nature, so not compared): ``/diagnostics`` (values such
as ``wall_time``, ``recorder_holds``, ``recorder_hold_s``; how many are published per simulated
second, the simulator's diagnostics timer being on the wall clock), ``/rosout`` (wall-time
stamps, texts with wall durations), ``/parameter_events`` and any other topic; the log times of
those topics (the newest ``/clock`` when they arrived) and so where they fall between the loop
messages; the file's bytes as a whole (chunks close by size or after ~1 s of wall time,
compression), the recording report (queue sizes) and ``metadata.yaml``'s times and counts,
which include the non-loop topics. The comparison reads the files with the ``mcap``
library's stream reader in file order, not with rwpend's reader or writer.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

#: loop topics, relative to the rig's namespace (``/clock`` is global)
LOOP_TOPICS = ('encoders', 'sim/true_state', 'state', 'joint_states', 'command', 'controller/status')
MAX_LISTED = 10


def loop_topics(namespace: str = '/rwpend') -> tuple[str, ...]:
    ns = namespace.rstrip('/')
    return ('/clock',) + tuple(f'{ns}/{t}' for t in LOOP_TOPICS)


@dataclass(frozen=True)
class FileMessage:
    topic: str
    log_time: int
    publish_time: int
    sequence: int
    data: bytes


@dataclass
class FileContents:
    """The messages of one MCAP file in file order, and its channels."""
    messages: list[FileMessage] = field(default_factory=list)
    channels: dict[str, tuple[str, str, str]] = field(default_factory=dict)  # topic: (type, schema, hash)


def mcap_file(bag) -> Path:
    """The single .mcap file of a bag directory (or the file itself)."""
    p = Path(bag)
    if p.is_file():
        return p
    files = sorted(p.glob('*.mcap'))
    if len(files) != 1:
        raise ValueError(f'{p}: expected one .mcap file, found {len(files)}')
    return files[0]


def read_file_order(path, topics=None) -> FileContents:
    """Messages (of ``topics``, default all) of one MCAP file in file order."""
    from mcap.records import Channel, Message, Schema
    from mcap.stream_reader import StreamReader
    want = None if topics is None else set(topics)
    schemas: dict[int, Schema] = {}
    channels: dict[int, str] = {}
    out = FileContents()
    with open(path, 'rb') as f:
        for rec in StreamReader(f, record_size_limit=1 << 31).records:
            if isinstance(rec, Schema):
                schemas[rec.id] = rec
            elif isinstance(rec, Channel):
                if want is not None and rec.topic not in want:
                    continue
                channels[rec.id] = rec.topic
                s = schemas.get(rec.schema_id)
                out.channels.setdefault(rec.topic, (
                    s.name if s else '', bytes(s.data).decode('utf-8', 'replace') if s else '',
                    rec.metadata.get('topic_type_hash', '')))
            elif isinstance(rec, Message):
                topic = channels.get(rec.channel_id)
                if topic is not None:
                    out.messages.append(FileMessage(topic, rec.log_time, rec.publish_time,
                                                    rec.sequence, bytes(rec.data)))
    return out


def order_faults(log_times: dict, namespace: str = '/rwpend') -> dict[str, dict]:
    """Loop topics that came late or were released early in one bag (``recording_report.json``'s
    ``log_times``, :class:`rwpend_bag.logtime.SimTimeOrder`): {} when the recorder wrote them in
    the deterministic order. Late non-loop topics do not matter for the same bag."""
    if 'hold_clocks' not in log_times:
        return {'*': {'log_time': log_times.get('log_time', 'not sim time')}}
    topics = log_times.get('topics', {})
    out = {}
    for t in loop_topics(namespace):
        c = topics.get(t, {})
        bad = {k: c[k] for k in ('late', 'forced') if c.get(k)}
        if bad:
            out[t] = bad
    return out


def compare(a, b, namespace: str = '/rwpend') -> list[str]:
    """Differences between two lockstep bags by the definition above; [] = the same bag."""
    topics = loop_topics(namespace)
    fa, fb = read_file_order(mcap_file(a), topics), read_file_order(mcap_file(b), topics)
    diffs: list[str] = []
    for t in topics:
        ca, cb = fa.channels.get(t), fb.channels.get(t)
        if ca != cb:
            what = ('present in one bag only' if ca is None or cb is None else
                    'type differs' if ca[0] != cb[0] else
                    'schema differs' if ca[1] != cb[1] else 'topic_type_hash differs')
            diffs.append(f'{t}: channel {what}')
    for t in topics:
        na = sum(1 for m in fa.messages if m.topic == t)
        nb = sum(1 for m in fb.messages if m.topic == t)
        if na != nb:
            diffs.append(f'{t}: {na} vs {nb} messages')
    listed = 0
    for i, (ma, mb) in enumerate(zip(fa.messages, fb.messages)):
        if ma == mb:
            continue
        if ma.topic != mb.topic:
            why = f'order: {ma.topic} vs {mb.topic}'
        else:
            why = ', '.join(k for k in ('data', 'log_time', 'publish_time', 'sequence')
                            if getattr(ma, k) != getattr(mb, k))
            why = f'{ma.topic} #{ma.sequence}: {why} differ (log_time {ma.log_time} vs {mb.log_time})'
        diffs.append(f'loop message {i}: {why}')
        listed += 1
        if listed >= MAX_LISTED:
            diffs.append('... (more differences not listed)')
            break
    if len(fa.messages) != len(fb.messages) and listed < MAX_LISTED:
        diffs.append(f'{len(fa.messages)} vs {len(fb.messages)} loop messages in all')
    return diffs
