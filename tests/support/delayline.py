"""A userspace Ethernet delay line between two interfaces: every frame that arrives on one goes
out of the other ``delay`` ms later, in order. For test networks on a kernel without the
``netem`` qdisc (the project's machines: ``tc qdisc add ... netem`` fails with "Specified qdisc
kind is unknown"), where no kernel mechanism delays packets by a fixed time.

    python tests/support/delayline.py IF_A IF_B --delay-ms 5 [--report FILE]

Run it as root in the namespace that holds both interfaces (``tests/support/netlab.py`` does). It
reads frames with AF_PACKET sockets and writes them to the other interface; it prints ``ready``
once both sockets are bound. A line ``delay MS`` on its standard input changes the delay (frames
already held keep theirs: the order of the frames never changes); the end of its input,
SIGINT or SIGTERM end it, and it writes what it did (frames, bytes, how late each frame left) as
JSON to ``--report``.

What it is and is not: the delay is measured from when the line *read* the frame, and a frame
leaves when the line gets the CPU after its due time, so on a loaded machine frames leave later
than asked: the report gives that lateness (p50/p99/max). It adds its own processing (tens of
microseconds per frame) even at 0 ms. A frame whose checksum the sending kernel left to the
"hardware" (checksum offload, ``TP_STATUS_CSUMNOTREADY``) gets its TCP/UDP checksum computed
here, as the hardware would have done.
"""
from __future__ import annotations

import argparse
import errno
import json
import os
import select
import signal
import socket
import struct
import sys
import time
from collections import deque

ETH_P_ALL = 0x0003
SOL_PACKET = 263
PACKET_AUXDATA = 8
PACKET_IGNORE_OUTGOING = 23
TP_STATUS_CSUMNOTREADY = 0x8
SO_TIMESTAMPNS = getattr(socket, 'SO_TIMESTAMPNS', 35)
SCM_TIMESTAMPNS = SO_TIMESTAMPNS
_AUX = struct.Struct('=IIIHHHH')      # struct tpacket_auxdata
#: checksum field offset in the transport header, per IP protocol
_CSUM_AT = {6: 16, 17: 6}


def ones_sum(data: bytes) -> int:
    """The 16-bit ones'-complement sum of ``data`` (RFC 1071), as a big-endian word value."""
    if len(data) % 2:
        data += b'\0'
    total = sum(memoryview(data).cast('H'))       # native order: the sum is order-independent
    while total >> 16:
        total = (total & 0xFFFF) + (total >> 16)
    return int.from_bytes(total.to_bytes(2, sys.byteorder), 'big')


def fill_checksum(frame: bytes) -> bytes:
    """``frame`` (Ethernet, IPv4) with its TCP or UDP checksum computed; unchanged when it is
    not an unfragmented IPv4 TCP/UDP frame."""
    if len(frame) < 34 or frame[12:14] != b'\x08\x00':
        return frame
    ihl = (frame[14] & 0x0F) * 4
    proto = frame[23]
    frag = struct.unpack_from('!H', frame, 20)[0] & 0x3FFF
    at = _CSUM_AT.get(proto)
    if at is None or frag or len(frame) < 14 + ihl + at + 2:
        return frame
    total_len = struct.unpack_from('!H', frame, 16)[0]
    seg = bytearray(frame[14 + ihl:14 + total_len])
    seg[at:at + 2] = b'\0\0'
    pseudo = frame[26:34] + struct.pack('!BBH', 0, proto, len(seg))
    csum = 0xFFFF - ones_sum(pseudo + bytes(seg))
    if proto == 17 and csum == 0:
        csum = 0xFFFF                                  # 0 means "no checksum" for UDP
    seg[at:at + 2] = struct.pack('!H', csum)
    return frame[:14 + ihl] + bytes(seg) + frame[14 + total_len:]


def open_port(ifname: str) -> socket.socket:
    s = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(ETH_P_ALL))
    s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
    s.setsockopt(SOL_PACKET, PACKET_AUXDATA, 1)
    s.setsockopt(SOL_PACKET, PACKET_IGNORE_OUTGOING, 1)   # not the frames we send (Linux >= 4.20)
    s.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)    # when the kernel received each frame
    s.bind((ifname, 0))
    s.setblocking(False)
    return s


def read_frame(s: socket.socket) -> tuple[bytes, float | None] | None:
    """One frame from ``s``, its checksum filled in where the sender left it, and when the
    kernel received it (``time.time()`` seconds; None if it did not say); None when none."""
    try:
        data, anc, _, _ = s.recvmsg(65536, socket.CMSG_SPACE(_AUX.size) + socket.CMSG_SPACE(16))
    except BlockingIOError:
        return None
    except OSError as exc:              # the interface went down (a cut link): nothing to read
        if exc.errno in (errno.ENETDOWN, errno.ENXIO):
            return None
        raise
    stamp = None
    for level, kind, value in anc:
        if level == SOL_PACKET and kind == PACKET_AUXDATA and len(value) >= 4:
            if struct.unpack_from('=I', value)[0] & TP_STATUS_CSUMNOTREADY:
                data = fill_checksum(data)
        elif level == socket.SOL_SOCKET and kind == SCM_TIMESTAMPNS and len(value) >= 16:
            sec, nsec = struct.unpack_from('=qq', value)
            stamp = sec + nsec * 1e-9
    return data, stamp


class Direction:
    """Frames held on their way from one interface to the other, and what happened to them.
    Times are ``time.time()`` seconds (the clock of the kernel's receive stamps)."""

    def __init__(self, out: socket.socket) -> None:
        self.out = out
        self.held: deque[tuple[float, bytes]] = deque()   # (due, frame)
        self.frames = 0
        self.bytes = 0
        self.send_errors = 0
        self.read_late: list[float] = []     # s from the kernel's receive stamp to our read
        self.left_late: list[float] = []     # s from the due time to the send

    def hold(self, frame: bytes, received: float, now: float, delay: float) -> None:
        """Hold ``frame``, received by the kernel at ``received``, until ``received + delay``
        (or after the frame before it: the order is kept)."""
        due = max(received + delay, self.held[-1][0] if self.held else 0.0)
        self.held.append((due, frame))
        if len(self.read_late) < 2_000_000:
            self.read_late.append(now - received)

    def send_due(self, now: float) -> None:
        while self.held and self.held[0][0] <= now:
            due, frame = self.held.popleft()
            try:
                self.out.send(frame)
            except OSError:          # the other side is down (a cut link): the frame is lost
                self.send_errors += 1
                continue
            self.frames += 1
            self.bytes += len(frame)
            if len(self.left_late) < 2_000_000:
                self.left_late.append(now - due)

    def report(self) -> dict:
        return {'frames': self.frames, 'bytes': self.bytes, 'send_errors': self.send_errors,
                'read_late_us': quantiles_us(self.read_late), 'left_late_us': quantiles_us(self.left_late)}


def quantiles_us(values: list[float]) -> dict:
    v = sorted(values)

    def q(p: float) -> float | None:
        return round(v[min(len(v) - 1, int(p * len(v)))] * 1e6, 1) if v else None
    return {'p50': q(0.5), 'p99': q(0.99), 'max': q(1.0), 'n': len(v)}


def realtime_priority(priority: int) -> str:
    """SCHED_FIFO at ``priority`` where permitted: the line stands for a wire, which does not
    wait for a CPU; returns what was done."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        return f'SCHED_FIFO {priority}'
    except (AttributeError, PermissionError, OSError) as exc:
        return f'ordinary scheduling ({exc})'


def run(if_a: str, if_b: str, delay_ms: float, report_path: str | None, priority: int) -> int:
    a, b = open_port(if_a), open_port(if_b)
    ways = {a: Direction(b), b: Direction(a)}
    names = {a: f'{if_a}->{if_b}', b: f'{if_b}->{if_a}'}
    delay = delay_ms / 1e3
    sched = realtime_priority(priority) if priority else 'ordinary scheduling'
    changes: list[tuple[float, float]] = [(time.time(), delay_ms)]
    stop: list[int] = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda signum, frame: stop.append(signum))
    print(f'ready {if_a} <-> {if_b}, delay {delay_ms:g} ms, {sched}', flush=True)
    stdin = sys.stdin
    while not stop:
        due = [w.held[0][0] for w in ways.values() if w.held]
        timeout = max(0.0, min(due) - time.time()) if due else 1.0
        try:
            ready, _, _ = select.select([a, b, stdin], [], [], timeout)
        except InterruptedError:
            continue
        now = time.time()
        for s in ready:
            if s is stdin:
                line = stdin.readline()
                if not line:
                    stop.append(0)
                elif line.split()[:1] == ['delay']:
                    delay_ms = float(line.split()[1])
                    delay = delay_ms / 1e3
                    changes.append((now, delay_ms))
                continue
            for _ in range(64):                    # drain what is there, a bounded batch
                got = read_frame(s)
                if got is None:
                    break
                frame, received = got
                ways[s].hold(frame, now if received is None else received, now, delay)
        for w in ways.values():
            w.send_due(time.time())
    if report_path:
        t0 = changes[0][0]
        doc = {'scheduling': sched,
               'delay_changes': [{'at_s': round(t - t0, 3), 'delay_ms': d} for t, d in changes],
               **{names[s]: w.report() for s, w in ways.items()}}
        with open(report_path, 'w', encoding='utf-8') as f:
            json.dump(doc, f, indent=2)
    return 0


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="delayline.py", description=__doc__.split('\n\n')[0])
    p.add_argument('if_a')
    p.add_argument('if_b')
    p.add_argument('--delay-ms', type=float, default=0.0)
    p.add_argument('--report', default=None, help='write what was done as JSON here at the end')
    p.add_argument('--rt-priority', type=int, default=70, metavar='N',
                   help='SCHED_FIFO priority where permitted (default 70, above the stack; 0: none)')
    a = p.parse_args(argv)
    if not 0 <= a.delay_ms <= 1000:
        p.error(f'--delay-ms must be in 0..1000, got {a.delay_ms}')
    if not 0 <= a.rt_priority <= 99:
        p.error(f'--rt-priority must be in 0..99, got {a.rt_priority}')
    return run(a.if_a, a.if_b, a.delay_ms, a.report, a.rt_priority)


if __name__ == '__main__':
    raise SystemExit(main())
