"""Wire protocol: CRC vectors, round trips, stream parser resync and fuzzing (no ROS)."""
from __future__ import annotations

import random

import pytest

from rwpend_driver import protocol as P

ALL = [
    P.Hello(1, 0), P.Command(123456, -2500), P.Enable(1), P.SetWatchdog(50), P.Zero(3),
    P.HelloReply(1, 0, 1, 0, 0, 0, 4000, 4000, 1000, 10000, 50, 0x52570001),
    P.Sample(0xFFFFFFFF, 42, -2_000_000_000, 2_000_000_000, P.ST_ENABLED | P.ST_WATCHDOG, -10000, P.NO_SAMPLE, 65535),
    P.Ack(P.ENABLE, P.R_BAD_VALUE, 65535),
]


@pytest.mark.parametrize('data,crc', [
    (b'123456789', 0x29B1),        # the CRC-16/CCITT-FALSE check value
    (b'', 0xFFFF),
    (b'\x00', 0xE1F0),
    (b'A', 0xB915),
])
def test_crc_vectors(data, crc):
    assert P.crc16(data) == crc
    assert P.crc16_reference(data) == crc


def test_crc_fast_equals_reference_random():
    rng = random.Random(1)
    for _ in range(300):
        d = bytes(rng.randrange(256) for _ in range(rng.randrange(0, 80)))
        assert P.crc16(d) == P.crc16_reference(d)


# Frame test vectors, also printed in PROTOCOL.md
VECTORS = [
    (P.Hello(1, 0), 0, 'a55a010200000100023c'),
    (P.Enable(1), 1, 'a55a03010100017bae'),
    (P.Command(1000, 1500), 7, 'a55a02060700e8030000dc0564ca'),
    (P.SetHold(3), 4, 'a55a060204000300d058'),
]


@pytest.mark.parametrize('msg,seq,hexframe', VECTORS)
def test_frame_vectors(msg, seq, hexframe):
    assert P.pack(msg, seq).hex() == hexframe
    frames = P.StreamParser().feed(bytes.fromhex(hexframe))
    assert frames == [P.Frame(P.TYPE_OF[type(msg)], seq, msg)]


@pytest.mark.parametrize('msg', ALL)
def test_round_trip(msg):
    b = P.pack(msg, 0xBEEF)
    assert b[:2] == P.SYNC and len(b) == P.OVERHEAD + P.LAYOUT[P.TYPE_OF[type(msg)]][0].size
    p = P.StreamParser()
    # byte by byte: incremental
    out = []
    for i in range(len(b)):
        out += p.feed(b[i:i + 1])
    assert out == [P.Frame(P.TYPE_OF[type(msg)], 0xBEEF, msg)]
    assert p.stats.errors == 0 and p.stats.garbage_bytes == 0


def test_sizes():
    assert len(P.pack(ALL[6], 0)) == 34      # SAMPLE, device -> PC, per sample
    assert len(P.pack(ALL[1], 0)) == 14      # COMMAND, PC -> device, per sample


def test_pack_refuses_out_of_range():
    with pytest.raises(P.ProtocolError):
        P.pack(P.Command(-1, 0), 0)
    with pytest.raises(P.ProtocolError):
        P.pack(P.Command(0, 40000), 0)
    with pytest.raises(P.ProtocolError):
        P.u_to_milli(float('nan'))
    with pytest.raises(P.ProtocolError):
        P.pack((1, 2), 0)
    assert P.u_to_milli(100.0) == P.U_MILLI_LIMIT
    assert P.u_to_milli(-1.2345) == -1234 or P.u_to_milli(-1.2345) == -1235


def test_resync_after_garbage_and_errors():
    good = [P.pack(P.Command(i, i), i) for i in range(5)]
    bad_crc = bytearray(P.pack(P.Command(99, 99), 99))
    bad_crc[-1] ^= 0xFF
    truncated = P.pack(P.Command(77, 77), 77)[:9]
    wrong_len = P.frame(P.COMMAND, 5, b'\x00\x00\x00')        # valid CRC, wrong length for COMMAND
    too_long = P.SYNC + bytes([P.COMMAND, 200, 0, 0]) + b'\x00' * 10
    unknown = P.frame(0x7F, 0, b'')
    stream = (b'\x00\xa5\xff' + good[0] + bytes(bad_crc) + good[1] + truncated + good[2] + wrong_len
              + too_long + good[3] + unknown + b'\xa5' + good[4])
    p = P.StreamParser()
    frames = p.feed(stream)
    assert [f.msg.sample for f in frames] == [0, 1, 2, 3, 4]
    s = p.stats
    assert s.bad_crc == 1 and s.truncated == 1 and s.bad_length == 2 and s.unknown_type == 1
    assert s.frames == 5


def test_accept_filters_direction():
    p = P.StreamParser(accept={P.COMMAND})
    assert p.feed(P.pack(P.Enable(1), 0)) == []
    assert p.stats.unknown_type == 1


def test_flush_counts_partial_frame():
    p = P.StreamParser()
    p.feed(P.pack(P.Enable(1), 0)[:5])
    assert p.flush() == 5 and p.stats.truncated == 1


def test_fuzz_random_chunks_no_crash_no_false_frames():
    """>= 10 000 random chunks: no exception, nothing delivered that was not sent."""
    rng = random.Random(20261107)
    p = P.StreamParser(accept={P.COMMAND, P.ENABLE})
    delivered = 0
    for _ in range(12000):
        chunk = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 40)))
        if rng.random() < 0.2:
            chunk = P.SYNC + chunk      # provoke header parsing
        delivered += len(p.feed(chunk))
    # a random frame needs a matching 16-bit CRC *and* the exact length of its type
    assert delivered <= 2
    assert p.stats.bytes > 100000
    assert p.stats.errors > 1000


def test_fuzz_mutated_valid_stream():
    """Valid frames with random corruption: every delivered frame is one that was sent."""
    rng = random.Random(7)
    sent = [P.Command(i, rng.randrange(-10000, 10001)) for i in range(10000)]
    data = bytearray(b''.join(P.pack(m, i) for i, m in enumerate(sent)))
    for _ in range(3000):                       # flip, drop, insert bytes
        i = rng.randrange(len(data))
        r = rng.random()
        if r < 0.4:
            data[i] ^= 1 << rng.randrange(8)
        elif r < 0.7:
            del data[i:i + rng.randrange(1, 20)]
        else:
            data[i:i] = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 10)))
    p = P.StreamParser()
    got = []
    pos = 0
    while pos < len(data):
        n = rng.randrange(1, 64)
        got += p.feed(bytes(data[pos:pos + n]))
        pos += n
    sent_set = {(i & 0xFFFF, m) for i, m in enumerate(sent)}
    assert all((f.seq, f.msg) in sent_set for f in got)
    assert len(got) > 5000
    assert p.stats.errors > 0
