"""The protocol client's binary frames, as the specification lays them out."""
import struct

import pytest

from rwpend_console.wsclient import (Client, ProtocolError, parse_message_data, parse_service_response,
                                     service_request_frame)


def test_message_data_frame():
    frame = bytes([1]) + struct.pack('<IQ', 7, 123456789) + b'payload'
    assert parse_message_data(frame) == (7, 123456789, b'payload')
    with pytest.raises(ProtocolError):
        parse_message_data(b'\x02' + frame[1:])


def test_service_frames():
    req = service_request_frame(3, 9, 'cdr', b'\x00\x01\x00\x00xy')
    assert req[:13] == bytes([2]) + struct.pack('<III', 3, 9, 3) and req[13:16] == b'cdr' and req[16:] == b'\x00\x01\x00\x00xy'
    resp = bytes([3]) + struct.pack('<III', 3, 9, 3) + b'cdr' + b'body'
    assert parse_service_response(resp) == (3, 9, 'cdr', b'body')


def test_session_bookkeeping():
    c = Client('ws://x')
    c.take('{"op": "advertise", "channels": [{"id": 1, "topic": "/a"}, {"id": 2, "topic": "/b"}]}')
    c.take('{"op": "unadvertise", "channelIds": [1]}')
    c.take('{"op": "advertiseServices", "services": [{"id": 4, "name": "/s"}]}')
    c.take('{"op": "status", "level": 2, "message": "refused"}')
    c.take(bytes([1]) + struct.pack('<IQ', 1, 5) + b'm')
    s = c.session
    assert list(s.channels) == [2] and c.channel('/b')['id'] == 2 and c.service('/s')['id'] == 4
    assert s.statuses[0]['level'] == 2 and s.messages == [(1, 5, b'm')]
