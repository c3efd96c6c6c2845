"""Wire protocol between the PC and the rig's microcontroller (see ../PROTOCOL.md).

Frame (all integers little-endian)::

    0xA5 0x5A | type u8 | len u8 | seq u16 | payload (len bytes) | crc u16

crc = CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, xorout 0) over
type, len, seq and payload (not the sync bytes).  ``seq`` counts the frames sent by each
side (wraps at 2**16).

Pure Python (struct and binascii only): no rclpy, no pyserial.
"""
from __future__ import annotations

import binascii
import struct
from dataclasses import dataclass, field
from typing import Iterator, NamedTuple, Union

SYNC = b'\xA5\x5A'
HEADER = struct.Struct('<BBH')          # type, len, seq (after the sync bytes)
HEADER_SIZE = 2 + HEADER.size           # 6
CRC_SIZE = 2
OVERHEAD = HEADER_SIZE + CRC_SIZE       # 8
MAX_PAYLOAD = 64                        # longer len fields are refused as bad length

PROTOCOL_MAJOR = 1
PROTOCOL_MINOR = 1

# ----------------------------------------------------------------- message types
# PC -> device
HELLO = 0x01
COMMAND = 0x02
ENABLE = 0x03
SET_WATCHDOG = 0x04
ZERO = 0x05
SET_HOLD = 0x06            # protocol 1.1
# device -> PC
HELLO_REPLY = 0x81
SAMPLE = 0x82
ACK = 0x83

# status flags of SAMPLE.status
ST_ENABLED = 0x0001        # amplifier enabled (torque follows the commands)
ST_WATCHDOG = 0x0002       # watchdog tripped (latched until ENABLE 1)
ST_OVERSPEED = 0x0004      # |wheel speed relative to the pendulum| > back-EMF limit
ST_CMD_FRESH = 0x0008      # a valid command arrived since the previous sample
ST_SATURATED = 0x0010      # the held command was clamped to +-u_max
ST_ZEROED = 0x0020         # the encoders were zeroed by a ZERO request since power-up
STATUS_NAMES = {ST_ENABLED: 'enabled', ST_WATCHDOG: 'watchdog_tripped', ST_OVERSPEED: 'overspeed',
                ST_CMD_FRESH: 'cmd_fresh', ST_SATURATED: 'saturated', ST_ZEROED: 'zeroed'}

# ACK results
R_OK = 0
R_BAD_VALUE = 1
R_BAD_STATE = 2
R_UNSUPPORTED = 3
RESULT_NAMES = {R_OK: 'ok', R_BAD_VALUE: 'bad value', R_BAD_STATE: 'bad state',
                R_UNSUPPORTED: 'unsupported'}

#: No command held (SAMPLE.cmd_sample).
NO_SAMPLE = 0xFFFFFFFF
#: Command scale: u is sent in milli-units (i16), |u| <= 10 -> |u_milli| <= 10000.
U_SCALE = 1000
U_MILLI_LIMIT = 32767
WATCHDOG_MIN_MS = 2
#: the watchdog period at power-up (PROTOCOL.md, "Device behaviour"; firmware RW_WATCHDOG_POWER_UP_MS)
DEFAULT_WATCHDOG_MS = 50
WATCHDOG_MAX_MS = 1000
#: SET_HOLD max_age range (samples; 0 = no limit, the power-up value)
HOLD_MAX_SAMPLES = 1000
#: the first minor version with SET_HOLD
HOLD_SINCE_MINOR = 1
ZERO_PENDULUM = 0x01
ZERO_MOTOR = 0x02


class Hello(NamedTuple):
    proto_major: int
    proto_minor: int


class Command(NamedTuple):
    sample: int        # device sample counter this command answers
    u_milli: int       # command in 1/1000 control units


class Enable(NamedTuple):
    on: int


class SetWatchdog(NamedTuple):
    period_ms: int


class Zero(NamedTuple):
    mask: int


class SetHold(NamedTuple):
    max_age: int       # samples a held command may drive the motor after the one it answers (0: no limit)


class HelloReply(NamedTuple):
    proto_major: int
    proto_minor: int
    fw_major: int
    fw_minor: int
    fw_patch: int
    reserved: int
    counts_per_rev_pendulum: int
    counts_per_rev_motor: int
    sample_period_us: int
    u_max_milli: int
    watchdog_ms: int
    serial: int


class Sample(NamedTuple):
    sample: int            # device sample counter k (u32, wraps)
    time_us: int           # device clock at the sample (u32 microseconds, wraps)
    pendulum_counts: int   # i32
    motor_counts: int      # i32
    status: int            # ST_* flags
    u_applied_milli: int   # command held over the previous sample period (milli-units)
    cmd_sample: int        # sample answered by that command, NO_SAMPLE if none
    rx_bad: int            # frames the device refused since power-up (u16, wraps)


class Ack(NamedTuple):
    request_type: int
    result: int
    request_seq: int


Message = Union[Hello, Command, Enable, SetWatchdog, Zero, SetHold, HelloReply, Sample, Ack]

#: type -> (struct, NamedTuple)
LAYOUT: dict[int, tuple[struct.Struct, type]] = {
    HELLO: (struct.Struct('<BB'), Hello),
    COMMAND: (struct.Struct('<Ih'), Command),
    ENABLE: (struct.Struct('<B'), Enable),
    SET_WATCHDOG: (struct.Struct('<H'), SetWatchdog),
    ZERO: (struct.Struct('<B'), Zero),
    SET_HOLD: (struct.Struct('<H'), SetHold),
    HELLO_REPLY: (struct.Struct('<BBBBBBIIHHHI'), HelloReply),
    SAMPLE: (struct.Struct('<IIiiHhIH'), Sample),
    ACK: (struct.Struct('<BBH'), Ack),
}
TYPE_OF = {cls: t for t, (_, cls) in LAYOUT.items()}
NAMES = {HELLO: 'HELLO', COMMAND: 'COMMAND', ENABLE: 'ENABLE', SET_WATCHDOG: 'SET_WATCHDOG',
         ZERO: 'ZERO', SET_HOLD: 'SET_HOLD', HELLO_REPLY: 'HELLO_REPLY', SAMPLE: 'SAMPLE', ACK: 'ACK'}


class ProtocolError(ValueError):
    """A message cannot be encoded (field out of range)."""


def crc16(data: bytes, init: int = 0xFFFF) -> int:
    """CRC-16/CCITT-FALSE (``crc16(b'123456789') == 0x29B1``)."""
    return binascii.crc_hqx(data, init)


def crc16_reference(data: bytes) -> int:
    """Bit-by-bit CRC-16/CCITT-FALSE, the form a firmware author may port."""
    crc = 0xFFFF
    for b in data:
        crc ^= b << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) & 0xFFFF if crc & 0x8000 else (crc << 1) & 0xFFFF
    return crc


def frame(msg_type: int, seq: int, payload: bytes) -> bytes:
    """Wrap a payload into a frame."""
    if not 0 <= msg_type <= 0xFF:
        raise ProtocolError(f'message type {msg_type} out of range')
    if len(payload) > MAX_PAYLOAD:
        raise ProtocolError(f'payload of {len(payload)} bytes > {MAX_PAYLOAD}')
    body = HEADER.pack(msg_type, len(payload), seq & 0xFFFF) + payload
    return SYNC + body + struct.pack('<H', crc16(body))


def pack(msg: Message, seq: int) -> bytes:
    """Encode a message (one of the NamedTuples above) into a frame with sequence number seq."""
    t = TYPE_OF.get(type(msg))
    if t is None:
        raise ProtocolError(f'not a protocol message: {msg!r}')
    st, _ = LAYOUT[t]
    try:
        payload = st.pack(*msg)
    except struct.error as exc:
        raise ProtocolError(f'{NAMES[t]} field out of range: {msg!r} ({exc})') from exc
    return frame(t, seq, payload)


def u_to_milli(u: float) -> int:
    """Control units -> the COMMAND's i16 milli-units (rounded, clamped to the i16 range)."""
    if u != u or u in (float('inf'), float('-inf')):
        raise ProtocolError(f'non-finite command {u!r}')
    m = int(round(u * U_SCALE))
    return max(-U_MILLI_LIMIT, min(U_MILLI_LIMIT, m))


class Frame(NamedTuple):
    type: int
    seq: int
    msg: Message


@dataclass
class ParserStats:
    frames: int = 0          # valid frames delivered
    bad_crc: int = 0         # complete frames whose CRC did not match
    bad_length: int = 0      # len field > MAX_PAYLOAD or not the length of its type
    truncated: int = 0       # frames cut short (a new frame started inside, or flushed partial)
    unknown_type: int = 0    # valid CRC, unknown type
    garbage_bytes: int = 0   # bytes skipped while looking for a sync
    bytes: int = 0           # bytes fed

    @property
    def errors(self) -> int:
        return self.bad_crc + self.bad_length + self.truncated + self.unknown_type

    def as_dict(self) -> dict:
        return {'frames': self.frames, 'bad_crc': self.bad_crc, 'bad_length': self.bad_length,
                'truncated': self.truncated, 'unknown_type': self.unknown_type,
                'garbage_bytes': self.garbage_bytes, 'bytes': self.bytes}


class StreamParser:
    """Incremental frame parser: feed arbitrary byte chunks, get valid frames.

    Resynchronises on garbage: on any error it drops the first sync byte and searches for
    the next ``A5 5A``.  Errors are counted in :attr:`stats`, never returned as frames.
    ``accept`` restricts the delivered types (e.g. the device accepts only PC -> device).
    """

    def __init__(self, accept: set[int] | None = None, max_buffer: int = 4096) -> None:
        self.buf = bytearray()
        self.stats = ParserStats()
        self.accept = set(LAYOUT) if accept is None else set(accept)
        self.max_buffer = max_buffer

    def _drop(self, n: int) -> None:
        del self.buf[:n]

    def feed(self, data: bytes) -> list[Frame]:
        return list(self.iter_feed(data))

    def iter_feed(self, data: bytes) -> Iterator[Frame]:
        buf = self.buf
        st = self.stats
        st.bytes += len(data)
        buf += data
        while True:
            i = buf.find(SYNC)
            if i < 0:
                # keep a trailing first sync byte, it may be completed by the next chunk
                keep = 1 if buf and buf[-1] == SYNC[0] else 0
                st.garbage_bytes += len(buf) - keep
                del buf[:len(buf) - keep]
                return
            if i:
                st.garbage_bytes += i
                del buf[:i]
            if len(buf) < HEADER_SIZE:
                return
            t, n, seq = HEADER.unpack_from(buf, 2)
            if n > MAX_PAYLOAD:
                st.bad_length += 1
                self._drop(1)
                continue
            total = HEADER_SIZE + n + CRC_SIZE
            if len(buf) < total:
                return
            body = bytes(buf[2:HEADER_SIZE + n])
            (crc,) = struct.unpack_from('<H', buf, HEADER_SIZE + n)
            if crc16(body) != crc:
                if buf.find(SYNC, 2, total) >= 0:
                    st.truncated += 1      # another frame began inside this one
                else:
                    st.bad_crc += 1
                self._drop(1)
                continue
            layout = LAYOUT.get(t)
            if layout is None or t not in self.accept:
                st.unknown_type += 1
                self._drop(total)
                continue
            s, cls = layout
            if n != s.size:
                st.bad_length += 1
                self._drop(total)
                continue
            msg = cls(*s.unpack_from(body, HEADER.size))
            self._drop(total)
            st.frames += 1
            yield Frame(t, seq, msg)

    def flush(self) -> int:
        """Discard a partial frame (link lost or idle); counts it as truncated. Returns bytes dropped."""
        n = len(self.buf)
        if n:
            if self.buf.startswith(SYNC):
                self.stats.truncated += 1
            else:
                self.stats.garbage_bytes += n
            self.buf.clear()
        return n


def status_names(status: int) -> list[str]:
    return [name for bit, name in STATUS_NAMES.items() if status & bit]


def seq_gap(prev: int, cur: int, modulo: int = 1 << 16) -> int:
    """Frames lost between two consecutive sequence numbers (modular)."""
    return (cur - prev - 1) % modulo
