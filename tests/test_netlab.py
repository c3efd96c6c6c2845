"""The test network's pure parts: the delay line's checksums (tests/support/delayline.py) and
the refusals of tests/support/netlab.py."""
from __future__ import annotations

import struct

import pytest

from support import delayline, netlab


def udp_frame(payload: bytes, checksum: int = 0) -> bytes:
    ip = struct.pack('!BBHHHBBH4s4s', 0x45, 0, 20 + 8 + len(payload), 1, 0, 64, 17, 0,
                     bytes([10, 77, 0, 1]), bytes([10, 77, 0, 2]))
    udp = struct.pack('!HHHH', 7411, 7413, 8 + len(payload), checksum)
    return b'\xff' * 12 + b'\x08\x00' + ip + udp + payload


def udp_checksum_ok(frame: bytes) -> bool:
    """The receiver's check: the ones'-complement sum over the pseudo-header and the datagram
    is 0xffff."""
    seg = frame[34:]
    pseudo = frame[26:34] + struct.pack('!BBH', 0, 17, len(seg))
    return delayline.ones_sum(pseudo + seg) == 0xFFFF


@pytest.mark.parametrize('payload', [b'', b'x', b'RTPS' * 37, bytes(range(256)) + b'z'])
def test_checksum_is_what_the_hardware_would_write(payload):
    frame = delayline.fill_checksum(udp_frame(payload, checksum=0x1234))
    assert udp_checksum_ok(frame) and len(frame) == len(udp_frame(payload))
    assert frame[42:] == payload


def test_frames_that_are_not_unfragmented_udp_or_tcp_stay_as_they_are():
    arp = b'\xff' * 12 + b'\x08\x06' + b'\0' * 28
    assert delayline.fill_checksum(arp) == arp
    frag = bytearray(udp_frame(b'abc', 0x1234))
    frag[20] = 0x20                          # more fragments
    assert delayline.fill_checksum(bytes(frag)) == bytes(frag)


def test_lab_refusals(monkeypatch):
    monkeypatch.setattr(netlab, 'why_not_available', lambda: 'not root')
    with pytest.raises(netlab.NetLabError, match='not root'):
        netlab.NetLab()
