"""PC side of the serial link: open, handshake, sample stream, commands, loss and reconnection.

Pure Python, no rclpy: the transport comes from an ``opener(port, baud)`` callable returning an
object with ``read(n) -> bytes`` (returns b'' after a short timeout), ``write(data)``,
``reset_input_buffer()`` and ``close()`` (pyserial's Serial fits; :func:`serial_opener`).
Errors of the transport (OSError, pyserial's SerialException) mean the link is lost.

One thread (the node's link thread) calls :meth:`DriverLink.poll` in a loop; it alone reads.
:meth:`DriverLink.command` and :meth:`DriverLink.set_active` may be called from other
threads (the ROS callbacks); they only write frames.

States: CLOSED (waiting for the next attempt, backoff 0.1 s doubling to 2 s) -> handshake
(HELLO/HELLO_REPLY, resolution check, SET_WATCHDOG, optional ZERO, ENABLE when active) ->
CONNECTED.  CONNECTED -> CLOSED when the port fails or no valid frame arrives for
``link_timeout`` s.  After every (re)connection the device holds zero torque until a fresh
command arrives that answers a sample of the new connection.
"""
from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, field
from typing import Callable, Optional

from . import protocol as P

MASK32 = 0xFFFFFFFF


class HandshakeError(Exception):
    """The device answered, but is not usable (version, resolution): retrying will not help."""


@dataclass
class LinkConfig:
    port: str = ''
    baud: int = 921600
    counts_per_rev: int = 4000
    pendulum_sign: int = 1
    motor_sign: int = 1
    zero_on_configure: bool = False
    watchdog_period: float = 0.05
    command_timeout_samples: int = 3
    link_timeout: float = 0.1
    handshake_timeout: float = 0.5
    backoff_initial: float = 0.1
    backoff_max: float = 2.0

    def errors(self) -> list[str]:
        e = []
        if not isinstance(self.port, str) or not self.port:
            e.append('port must be a non-empty device path')
        if not isinstance(self.baud, int) or not 1200 <= self.baud <= 12_000_000:
            e.append(f'baud must be an integer in 1200..12000000, got {self.baud!r}')
        if not isinstance(self.counts_per_rev, int) or not 1 <= self.counts_per_rev <= MASK32:
            e.append(f'counts_per_rev must be a positive integer, got {self.counts_per_rev!r}')
        for name in ('pendulum_sign', 'motor_sign'):
            if getattr(self, name) not in (1, -1):
                e.append(f'{name} must be 1 or -1, got {getattr(self, name)!r}')
        wd = self.watchdog_period
        if not isinstance(wd, (int, float)) or not math.isfinite(wd) or \
                not P.WATCHDOG_MIN_MS <= round(wd * 1000) <= P.WATCHDOG_MAX_MS:
            e.append(f'watchdog_period must be in [{P.WATCHDOG_MIN_MS / 1000}, {P.WATCHDOG_MAX_MS / 1000}] s, '
                     f'got {wd!r}')
        if not isinstance(self.command_timeout_samples, int) or self.command_timeout_samples < 1:
            e.append(f'command_timeout_samples must be an integer >= 1, got {self.command_timeout_samples!r}')
        for name in ('link_timeout', 'handshake_timeout', 'backoff_initial', 'backoff_max'):
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                e.append(f'{name} must be > 0, got {v!r}')
        return e


@dataclass
class LinkCounters:
    connects: int = 0
    link_losses: int = 0
    failed_attempts: int = 0
    samples: int = 0
    samples_lost: int = 0            # gaps in the device's sample counter
    frames_lost: int = 0             # gaps in the device's frame sequence numbers
    commands_sent: int = 0
    commands_refused: int = 0        # non-finite, stale, future, from a previous connection
    commands_inactive: int = 0       # arrived while not active (ignored)
    commands_saturated: int = 0
    timeout_samples: int = 0         # samples answered with u = 0 by the PC-side timeout
    timeouts: int = 0                # timeout episodes
    watchdog_trips: int = 0          # rising edges of the device's ST_WATCHDOG
    nacks: int = 0
    last_refusal: str = ''
    parser_totals: dict = field(default_factory=dict)


def serial_opener(port: str, baud: int):
    """Open a pyserial port for the link (raw 8N1, short read timeout)."""
    import serial  # pyserial; imported here so the pure tests need no serial port
    s = serial.Serial(port, baud, timeout=0.005, write_timeout=0.1, exclusive=True)
    return s


class DriverLink:
    def __init__(self, cfg: LinkConfig, opener: Callable = serial_opener,
                 clock: Callable[[], float] = time.monotonic,
                 on_sample: Optional[Callable[[int, int, int, P.Sample], None]] = None,
                 log: Optional[Callable[[str, str], None]] = None,
                 sleep: Callable[[float], None] = time.sleep) -> None:
        errs = cfg.errors()
        if errs:
            raise ValueError('; '.join(errs))
        self.cfg = cfg
        self.opener = opener
        self.clock = clock
        self.sleep = sleep
        self.on_sample = on_sample
        self.log = log or (lambda level, msg: None)
        self.lock = threading.RLock()
        self.port = None
        self.parser = P.StreamParser(accept={P.HELLO_REPLY, P.SAMPLE, P.ACK})
        self.counters = LinkCounters()
        self.tx_seq = 0
        self.connected = False
        self.want_active = False
        self.zero_pending = bool(cfg.zero_on_configure)
        self.error = 'not connected yet'
        self.fatal = False
        self.hello: Optional[P.HelloReply] = None
        self.next_attempt = 0.0
        self.backoff = cfg.backoff_initial
        self.last_rx = 0.0
        self.last_enable_tx = -math.inf
        # sample numbering: ros seq = ros_base + (device sample - dev_base) mod 2^32
        self.next_seq = 0                 # the seq the next published sample gets (at least)
        self.ros_base: Optional[int] = None
        self.dev_base = 0
        self.last_seq: Optional[int] = None
        self.last_dev_sample: Optional[int] = None
        self.last_frame_seq: Optional[int] = None
        self.last_sample: Optional[P.Sample] = None
        self.last_cmd_seq = -1
        self.last_cmd_arrival: Optional[int] = None
        self.timed_out = False
        self.prev_tripped = False

    # ------------------------------------------------------------ transport
    def _write(self, msg) -> int:
        """Send a message; returns its frame seq. Raises OSError when the port fails."""
        with self.lock:
            if self.port is None:
                raise OSError('port closed')
            seq = self.tx_seq
            self.tx_seq = (self.tx_seq + 1) & 0xFFFF
            self.port.write(P.pack(msg, seq))
            return seq

    def _close_port(self) -> None:
        with self.lock:
            port, self.port = self.port, None
            self.connected = False
            self.ros_base = None
        if port is not None:
            try:
                port.close()
            except Exception:  # noqa: BLE001 - closing a vanished port
                pass
        self._accumulate_parser()

    def _accumulate_parser(self) -> None:
        self.parser.flush()
        tot = self.counters.parser_totals
        for k, v in self.parser.stats.as_dict().items():
            tot[k] = tot.get(k, 0) + v
        self.parser = P.StreamParser(accept={P.HELLO_REPLY, P.SAMPLE, P.ACK})

    def parser_stats(self) -> dict:
        tot = dict(self.counters.parser_totals)
        for k, v in self.parser.stats.as_dict().items():
            tot[k] = tot.get(k, 0) + v
        return tot

    def _read_frames(self):
        port = self.port
        if port is None:
            return []
        # all that is waiting, or block (read timeout) for the first byte
        data = port.read(getattr(port, 'in_waiting', 0) or 1)
        if data:
            return self.parser.feed(data)
        return []

    # ------------------------------------------------------------ connection
    def _await(self, pred, timeout: float, resend=None):
        """Read frames until pred(frame) is true; samples are dropped. Returns the frame or None."""
        end = self.clock() + timeout
        last_send = self.clock()
        while self.clock() < end:
            for fr in self._read_frames():
                if pred(fr):
                    return fr
            if resend is not None and self.clock() - last_send > 0.1:
                resend()
                last_send = self.clock()
        return None

    def _request(self, msg, what: str) -> None:
        seq = self._write(msg)
        fr = self._await(lambda f: f.type == P.ACK and f.msg.request_seq == seq, self.cfg.handshake_timeout)
        if fr is None:
            raise TimeoutError(f'no ACK to {what} within {self.cfg.handshake_timeout} s')
        if fr.msg.result != P.R_OK:
            self.counters.nacks += 1
            raise HandshakeError(f'device refused {what}: {P.RESULT_NAMES.get(fr.msg.result, fr.msg.result)}')

    def connect(self) -> None:
        """Open the port and handshake. Raises OSError/TimeoutError/HandshakeError on failure."""
        c = self.cfg
        self._close_port()
        port = self.opener(c.port, c.baud)
        with self.lock:
            self.port = port
        try:
            port.reset_input_buffer()
        except Exception:  # noqa: BLE001 - not every transport has it
            pass
        hello = P.Hello(P.PROTOCOL_MAJOR, P.PROTOCOL_MINOR)

        def send_hello():
            self._write(hello)
        send_hello()

        def is_reply(f):
            if f.type == P.ACK and f.msg.request_type == P.HELLO and f.msg.result == P.R_UNSUPPORTED:
                raise HandshakeError(f'device does not speak protocol {P.PROTOCOL_MAJOR}.x')
            return f.type == P.HELLO_REPLY
        fr = self._await(is_reply, c.handshake_timeout, resend=send_hello)
        if fr is None:
            raise TimeoutError(f'no HELLO_REPLY from {c.port} within {c.handshake_timeout} s')
        h = fr.msg
        if h.proto_major != P.PROTOCOL_MAJOR:
            raise HandshakeError(f'device protocol {h.proto_major}.{h.proto_minor}, driver speaks '
                                 f'{P.PROTOCOL_MAJOR}.{P.PROTOCOL_MINOR}')
        if h.counts_per_rev_pendulum != c.counts_per_rev or h.counts_per_rev_motor != c.counts_per_rev:
            raise HandshakeError(f'encoder resolution mismatch: device reports {h.counts_per_rev_pendulum} '
                                 f'(pendulum) / {h.counts_per_rev_motor} (motor) counts/rev, parameter '
                                 f'counts_per_rev = {c.counts_per_rev}')
        self.hello = h
        self._request(P.Enable(0), 'ENABLE 0')
        self._request(P.SetWatchdog(int(round(c.watchdog_period * 1000))), 'SET_WATCHDOG')
        if self.zero_pending:
            self._request(P.Zero(P.ZERO_PENDULUM | P.ZERO_MOTOR), 'ZERO')
            self.zero_pending = False
            self.log('info', 'encoders zeroed (zero_on_configure)')
        if self._await(lambda f: f.type == P.SAMPLE, c.handshake_timeout) is None:
            raise TimeoutError(f'device answered the handshake but sends no SAMPLE frames '
                               f'within {c.handshake_timeout} s')
        with self.lock:
            self.connected = True
            self.ros_base = None
            self.last_cmd_arrival = None
            self.last_frame_seq = None
            self.prev_tripped = False
            self.last_rx = self.clock()
            if self.want_active:
                self._write(P.Enable(1))
                self.last_enable_tx = self.clock()
        self.counters.connects += 1
        self.backoff = c.backoff_initial
        self.error = ''
        self.fatal = False
        self.log('info', f'connected to {c.port}: firmware {h.fw_major}.{h.fw_minor}.{h.fw_patch}, protocol '
                         f'{h.proto_major}.{h.proto_minor}, {h.counts_per_rev_pendulum} counts/rev, '
                         f'h = {h.sample_period_us} us, serial {h.serial:#010x}')

    def try_connect(self) -> bool:
        try:
            self.connect()
            return True
        except HandshakeError as exc:
            self.error, self.fatal = str(exc), True
        except (OSError, TimeoutError, ValueError) as exc:
            self.error, self.fatal = f'{type(exc).__name__}: {exc}', False
        self.counters.failed_attempts += 1
        self._close_port()
        self.next_attempt = self.clock() + self.backoff
        self.backoff = min(self.backoff * 2, self.cfg.backoff_max)
        return False

    def lose(self, reason: str) -> None:
        if self.connected:
            self.counters.link_losses += 1
            self.log('error', f'link lost: {reason}; reconnecting')
        self.error = reason
        self.fatal = False
        self._close_port()
        self.backoff = self.cfg.backoff_initial
        self.next_attempt = self.clock() + self.backoff

    # ------------------------------------------------------------ loop
    def poll(self) -> None:
        """One iteration of the link thread (blocks at most ~ the port's read timeout)."""
        if not self.connected:
            if self.clock() >= self.next_attempt:
                self.try_connect()
            else:
                self.sleep(min(0.01, max(0.0, self.next_attempt - self.clock())))
            return
        try:
            frames = self._read_frames()
            now = self.clock()
            for fr in frames:
                self.last_rx = now
                if fr.type == P.SAMPLE:
                    self._on_sample(fr)
                elif fr.type == P.ACK and fr.msg.result != P.R_OK:
                    self.counters.nacks += 1
            if now - self.last_rx > self.cfg.link_timeout:
                self.lose(f'device silent for {now - self.last_rx:.3f} s (link_timeout {self.cfg.link_timeout} s)')
        except OSError as exc:
            self.lose(f'port error: {exc}')

    def _on_sample(self, fr: P.Frame) -> None:
        s: P.Sample = fr.msg
        c = self.counters
        if self.last_frame_seq is not None:
            c.frames_lost += P.seq_gap(self.last_frame_seq, fr.seq)
        self.last_frame_seq = fr.seq
        with self.lock:
            if self.ros_base is not None:
                d = (s.sample - self.dev_base) & MASK32
                seq = self.ros_base + d
                if d >= 0x80000000 or seq <= self.last_seq:   # device counter went back: rebase
                    self.ros_base = None
            if self.ros_base is None:
                self.ros_base = self.next_seq
                self.dev_base = s.sample
                seq = self.next_seq
            elif seq > self.last_seq + 1:
                c.samples_lost += seq - self.last_seq - 1
            self.last_seq = seq
            self.next_seq = seq + 1
            self.last_dev_sample = s.sample
            self.last_sample = s
            c.samples += 1
        tripped = bool(s.status & P.ST_WATCHDOG)
        if tripped and not self.prev_tripped:
            c.watchdog_trips += 1
            self.log('warn', 'device watchdog tripped: motor at zero')
        self.prev_tripped = tripped
        if self.on_sample is not None:
            self.on_sample(seq, self.cfg.pendulum_sign * s.pendulum_counts, self.cfg.motor_sign * s.motor_counts, s)
        self._supervise(seq, s)

    def _supervise(self, seq: int, s: P.Sample) -> None:
        """Keep the amplifier in the wanted state; PC-side command timeout."""
        enabled = bool(s.status & P.ST_ENABLED)
        now = self.clock()
        if enabled != self.want_active and now - self.last_enable_tx > 0.05:
            self._write(P.Enable(1 if self.want_active else 0))
            self.last_enable_tx = now
        if not (self.want_active and enabled):
            return
        with self.lock:
            arrival = self.last_cmd_arrival
            fresh = arrival is not None and seq - arrival < self.cfg.command_timeout_samples
            if fresh:
                self.timed_out = False
                return
            if not self.timed_out and arrival is not None:
                self.counters.timeouts += 1
            self.timed_out = True
            self.counters.timeout_samples += 1
            self._write(P.Command(s.sample, 0))     # PC-side timeout: explicit zero, keeps the watchdog fed

    # ------------------------------------------------------------ from ROS
    def set_active(self, on: bool) -> None:
        """Wanted amplifier state (lifecycle active). Sends ENABLE now when connected."""
        with self.lock:
            self.want_active = bool(on)
            self.last_cmd_arrival = None
            if self.connected:
                try:
                    if not on:
                        self._write(P.Command(self.last_dev_sample or 0, 0))
                    self._write(P.Enable(1 if on else 0))
                    self.last_enable_tx = self.clock()
                except OSError:
                    pass        # the link thread notices and reconnects

    def _refuse(self, reason: str) -> tuple[bool, str]:
        self.counters.commands_refused += 1
        self.counters.last_refusal = reason
        return False, reason

    def command(self, seq: int, u: float) -> tuple[bool, str]:
        """A MotorCommand answering published sample ``seq``; sent to the device when acceptable."""
        if not isinstance(u, (int, float)) or not math.isfinite(u):
            return self._refuse(f'non-finite u {u!r} (seq {seq})')
        with self.lock:
            if not self.want_active:
                self.counters.commands_inactive += 1
                return False, 'not active'
            if not self.connected or self.ros_base is None:
                self.counters.commands_inactive += 1
                return False, 'link down'
            if seq > self.last_seq:
                return self._refuse(f'command answers seq {seq}, newest sample is {self.last_seq}')
            if seq < self.ros_base:
                return self._refuse(f'command answers seq {seq}, from before the reconnection (seq {self.ros_base})')
            if seq <= self.last_cmd_seq:
                return self._refuse(f'stale command for seq {seq} (already sent {self.last_cmd_seq})')
            u_dev = self.cfg.motor_sign * float(u)
            if self.hello is not None and abs(u_dev) * P.U_SCALE > self.hello.u_max_milli:
                self.counters.commands_saturated += 1
            dev_sample = (self.dev_base + (seq - self.ros_base)) & MASK32
            try:
                self._write(P.Command(dev_sample, P.u_to_milli(u_dev)))
            except OSError as exc:
                return False, f'port error: {exc}'
            self.last_cmd_seq = seq
            self.last_cmd_arrival = self.last_seq
            self.counters.commands_sent += 1
            return True, ''

    def close(self) -> None:
        with self.lock:
            self.want_active = False
            if self.port is not None and self.connected:
                try:
                    self._write(P.Command(self.last_dev_sample or 0, 0))
                    self._write(P.Enable(0))
                except OSError:
                    pass
        self._close_port()

    # ------------------------------------------------------------ report
    def snapshot(self) -> dict:
        c = self.counters
        s = self.last_sample
        d = {
            'port': self.cfg.port, 'connected': self.connected, 'active': self.want_active,
            'error': self.error, 'fatal': self.fatal,
            'silent_for': f'{self.clock() - self.last_rx:.3f}' if self.connected else '',
            'connects': c.connects, 'link_losses': c.link_losses, 'failed_attempts': c.failed_attempts,
            'samples': c.samples, 'samples_lost': c.samples_lost, 'frames_lost': c.frames_lost,
            'commands_sent': c.commands_sent, 'commands_refused': c.commands_refused,
            'commands_inactive': c.commands_inactive, 'commands_saturated': c.commands_saturated,
            'last_refusal': c.last_refusal, 'timeout_samples': c.timeout_samples, 'timeouts': c.timeouts,
            'command_timed_out': self.timed_out, 'watchdog_trips': c.watchdog_trips, 'nacks': c.nacks,
        }
        for k, v in self.parser_stats().items():
            d[f'rx.{k}'] = v
        if self.hello is not None:
            h = self.hello
            d.update({'firmware': f'{h.fw_major}.{h.fw_minor}.{h.fw_patch}',
                      'protocol': f'{h.proto_major}.{h.proto_minor}', 'device_serial': f'{h.serial:#010x}',
                      'device_counts_per_rev': h.counts_per_rev_pendulum})
        if s is not None:
            d.update({'device.sample': s.sample, 'device.time_us': s.time_us,
                      'device.status': ','.join(P.status_names(s.status)) or 'none',
                      'device.enabled': bool(s.status & P.ST_ENABLED),
                      'device.watchdog_tripped': bool(s.status & P.ST_WATCHDOG),
                      'device.overspeed': bool(s.status & P.ST_OVERSPEED),
                      'device.u_applied': s.u_applied_milli / P.U_SCALE * self.cfg.motor_sign,
                      'device.cmd_sample': s.cmd_sample, 'device.rx_bad': s.rx_bad})
        return d
