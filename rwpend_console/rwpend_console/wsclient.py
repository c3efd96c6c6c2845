"""A small client of the Foxglove WebSocket protocol, written from the protocol's specification
(foxglove/ws-protocol, docs/spec.md: ``foxglove.websocket.v1``) with the ``websockets``
package -- independent of foxglove-sdk, whose server it talks to in the tests, and handy for
scripts. Messages are decoded from the advertised ``ros2msg`` schema with ``rosbags``
(:func:`decode`), also independent of rclpy.

The subprotocol: foxglove-sdk's server (0.30) accepts only ``foxglove.sdk.v1`` (the same
protocol under a new name; Lichtblick added that name in December 2025, its older versions ask
for ``foxglove.websocket.v1`` only and are refused). The client offers both.

The binary frames (little-endian) it reads and writes:

* server -> client ``0x01`` message data: subscription id u32, log time u64, payload;
* server -> client ``0x03`` service call response: service id u32, call id u32, encoding
  length u32, encoding, payload;
* client -> server ``0x02`` service call request: service id u32, call id u32, encoding length
  u32, encoding, payload.
"""
from __future__ import annotations

import asyncio
import itertools
import json
import struct
from dataclasses import dataclass, field

SUBPROTOCOLS = ('foxglove.sdk.v1', 'foxglove.websocket.v1')
OP_MESSAGE_DATA, OP_TIME, OP_SERVICE_RESPONSE = 0x01, 0x02, 0x03
OP_SERVICE_REQUEST = 0x02


class ProtocolError(RuntimeError):
    pass


def parse_message_data(frame: bytes) -> tuple[int, int, bytes]:
    """(subscription id, log time ns, payload) of a message-data frame."""
    if len(frame) < 13 or frame[0] != OP_MESSAGE_DATA:
        raise ProtocolError(f'not a message-data frame ({len(frame)} bytes, opcode {frame[:1].hex()})')
    sub, t = struct.unpack_from('<IQ', frame, 1)
    return sub, t, frame[13:]


def service_request_frame(service_id: int, call_id: int, encoding: str, payload: bytes) -> bytes:
    enc = encoding.encode()
    return struct.pack('<BIII', OP_SERVICE_REQUEST, service_id, call_id, len(enc)) + enc + payload


def parse_service_response(frame: bytes) -> tuple[int, int, str, bytes]:
    """(service id, call id, encoding, payload) of a service-call-response frame."""
    if len(frame) < 13 or frame[0] != OP_SERVICE_RESPONSE:
        raise ProtocolError('not a service-call-response frame')
    service_id, call_id, n = struct.unpack_from('<III', frame, 1)
    return service_id, call_id, frame[13:13 + n].decode(), frame[13 + n:]


def _typestore(schema_name: str, schema_text: str):
    """(rosbags typestore with the schema's types, the name of the top type in it). rosbags
    names message types ``pkg/msg/Name``: a service part (``pkg/srv/Name_Request``) is
    registered as ``pkg/msg/Name_Request``."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore
    parts = schema_name.split('/')
    name = f'{parts[0]}/msg/{parts[-1]}' if len(parts) == 3 else schema_name
    store = get_typestore(Stores.EMPTY)
    store.register(get_types_from_msg(schema_text, name))
    return store, name


def decode(schema_name: str, schema_text: str, payload: bytes):
    """A CDR payload decoded with its ``ros2msg`` schema (rosbags' typestore, empty otherwise)."""
    store, name = _typestore(schema_name, schema_text)
    return store.deserialize_cdr(payload, name)


def encode(schema_name: str, schema_text: str, message) -> bytes:
    store, name = _typestore(schema_name, schema_text)
    return bytes(store.serialize_cdr(message, name))


def message_class(schema_name: str, schema_text: str):
    store, name = _typestore(schema_name, schema_text)
    return store.types[name]


@dataclass
class Session:
    """What the server said so far."""

    server_info: dict = field(default_factory=dict)
    channels: dict = field(default_factory=dict)       # id -> advertised channel
    services: dict = field(default_factory=dict)       # id -> advertised service
    statuses: list = field(default_factory=list)
    parameter_values: list = field(default_factory=list)
    messages: list = field(default_factory=list)       # (subscription id, log time, payload)
    responses: list = field(default_factory=list)      # (service id, call id, encoding, payload)
    failures: list = field(default_factory=list)       # serviceCallFailure messages


class Client:
    """``async with Client(url) as c:`` -- :meth:`pump` reads the server's messages into
    ``c.session``; the other methods send requests."""

    def __init__(self, url: str) -> None:
        self.url = url
        self.session = Session()
        self._ids = itertools.count(1)

    async def __aenter__(self) -> 'Client':
        import websockets
        self.ws = await websockets.connect(self.url, subprotocols=list(SUBPROTOCOLS), max_size=None)
        if self.ws.subprotocol not in SUBPROTOCOLS:
            raise ProtocolError(f'the server chose subprotocol {self.ws.subprotocol!r}')
        return self

    async def __aexit__(self, *exc) -> None:
        await self.ws.close()

    def take(self, frame) -> None:
        s = self.session
        if isinstance(frame, bytes):
            if frame[:1] == bytes([OP_MESSAGE_DATA]):
                s.messages.append(parse_message_data(frame))
            elif frame[:1] == bytes([OP_SERVICE_RESPONSE]):
                s.responses.append(parse_service_response(frame))
            return
        msg = json.loads(frame)
        op = msg.get('op')
        if op == 'serverInfo':
            s.server_info = msg
        elif op == 'advertise':
            s.channels.update({c['id']: c for c in msg['channels']})
        elif op == 'unadvertise':
            for i in msg['channelIds']:
                s.channels.pop(i, None)
        elif op == 'advertiseServices':
            s.services.update({x['id']: x for x in msg['services']})
        elif op == 'unadvertiseServices':
            for i in msg['serviceIds']:
                s.services.pop(i, None)
        elif op == 'status':
            s.statuses.append(msg)
        elif op == 'parameterValues':
            s.parameter_values.append(msg)
        elif op == 'serviceCallFailure':
            s.failures.append(msg)

    async def pump(self, seconds: float, until=None) -> bool:
        """Read for up to ``seconds`` or until ``until(session)``; True if ``until`` held."""
        loop = asyncio.get_running_loop()
        end = loop.time() + seconds
        while True:
            if until is not None and until(self.session):
                return True
            left = end - loop.time()
            if left <= 0:
                return False
            try:
                self.take(await asyncio.wait_for(self.ws.recv(), left))
            except asyncio.TimeoutError:
                return until is not None and until(self.session)

    async def send(self, op: str, **fields) -> None:
        await self.ws.send(json.dumps({'op': op, **fields}))

    def channel(self, topic: str) -> dict | None:
        return next((c for c in self.session.channels.values() if c['topic'] == topic), None)

    def service(self, name: str) -> dict | None:
        return next((s for s in self.session.services.values() if s['name'] == name), None)

    async def subscribe(self, channel_id: int) -> int:
        sub = next(self._ids)
        await self.send('subscribe', subscriptions=[{'id': sub, 'channelId': channel_id}])
        return sub

    async def get_parameters(self, names: list[str], request_id: str) -> None:
        await self.send('getParameters', parameterNames=names, id=request_id)

    async def set_parameters(self, params: list[dict], request_id: str) -> None:
        await self.send('setParameters', parameters=params, id=request_id)

    async def call_service(self, service_id: int, encoding: str, payload: bytes) -> int:
        call = next(self._ids)
        await self.ws.send(service_request_frame(service_id, call, encoding, payload))
        return call
