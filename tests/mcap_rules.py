"""The MCAP ordering rule, checked on a file as ``mcap doctor --strict-message-order`` checks it:
in file order, every Message's log_time is >= the greatest log_time before it in the file (equal
is allowed), across channels and chunks; and each Chunk's message_start_time /
message_end_time are the least / greatest log_time of the messages it holds.

Read with the ``mcap`` library's stream reader (records in file order, chunks opened one by
one), independently of rwpend's own reader and writer."""
from __future__ import annotations

from pathlib import Path

from mcap.records import Chunk, Message
from mcap.stream_reader import StreamReader, breakup_chunk

MAX_LISTED = 10


def ordering_violations(mcap_path) -> tuple[int, list[str]]:
    """(messages read, violations listed) of one MCAP file."""
    out: list[str] = []
    latest = None
    n = 0

    def check(msg: Message) -> None:
        nonlocal latest, n
        n += 1
        if latest is not None and msg.log_time < latest and len(out) < MAX_LISTED:
            out.append(f'message {n} (channel {msg.channel_id}): log_time {msg.log_time} < the '
                       f'latest before it, {latest}')
        latest = msg.log_time if latest is None else max(latest, msg.log_time)

    with open(mcap_path, 'rb') as f:
        for rec in StreamReader(f, emit_chunks=True, record_size_limit=1 << 31).records:
            if isinstance(rec, Message):
                check(rec)
            elif isinstance(rec, Chunk):
                times = []
                for inner in breakup_chunk(rec, validate_crc=True):
                    if isinstance(inner, Message):
                        check(inner)
                        times.append(inner.log_time)
                if times and (rec.message_start_time, rec.message_end_time) != (min(times), max(times)):
                    out.append(f'chunk times {rec.message_start_time}..{rec.message_end_time} are not '
                               f'those of its messages {min(times)}..{max(times)}')
    return n, out


def assert_log_time_order(bag) -> int:
    """Every .mcap file of a bag directory follows the rule; returns the messages checked."""
    files = sorted(Path(bag).glob('*.mcap'))
    assert files, f'no .mcap file in {bag}'
    total = 0
    for f in files:
        n, bad = ordering_violations(f)
        assert not bad, f'{f.name}: not in log-time order:\n' + '\n'.join(bad)
        total += n
    return total
