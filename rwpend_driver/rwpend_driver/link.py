"""PC side of the serial link: open, handshake, sample stream, commands, loss and reconnection.

Pure Python, no rclpy: the transport comes from an ``opener(port, baud)`` callable returning a
non-blocking port (:mod:`rwpend_driver.port`: ``wait``, ``read``, ``write``, ``flush_input``,
``close``; :func:`rwpend_driver.port.serial_opener` for the real one). Errors of the transport
(OSError, pyserial's SerialException) mean the link is lost.

One thread (the node's link thread) calls :meth:`DriverLink.poll` in a loop; it alone reads: it
waits for bytes (``poll``, without the GIL), takes everything there, and hands each SAMPLE on at
once. :meth:`DriverLink.command` and :meth:`DriverLink.set_active` may be called from other
threads (the ROS callbacks); they write their frame at once, never waiting for the port.

States: CLOSED (waiting for the next attempt, backoff 0.1 s doubling to 2 s) -> handshake
(HELLO/HELLO_REPLY, resolution check, SET_WATCHDOG, optional ZERO, ENABLE when active) ->
CONNECTED.  CONNECTED -> CLOSED when the port fails or no valid frame arrives for
``link_timeout`` s.  After every (re)connection the device holds zero torque until a fresh
command arrives that answers a sample of the new connection.

Sample numbering: the published ``seq`` never goes back and counts time. Within a connection it
follows the device's sample counter (a gap there is a gap in seq, counted in ``samples_lost``).
Across a reconnection to the same device (same serial number, counter advanced as much as the
time allows) it goes on following that counter, so the outage is a gap of exactly the samples
the device took meanwhile; after a device restart it jumps by the time elapsed, in samples.
Either way the gap is counted in ``outage_samples``.

Commands (:meth:`DriverLink.command`), as the simulator's :meth:`rwpend_sim.sim_core.SimCore.command`:
refused when non-finite, answering a sample not published yet or of a previous connection, not
newer than the last one sent (``stale_commands``), or
answering a sample ``command_timeout_samples`` or more old (``old_commands``): a controller acting
on old states never moves the motor. So the device never has a reason to refuse one.
"""
from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, field, fields
from typing import Callable, Optional

from . import protocol as P
from .link_health import DelayMeter
from .port import serial_opener

MASK32 = 0xFFFFFFFF


class HandshakeError(Exception):
    """The device answered, but is not usable (version, resolution): retrying will not help."""


@dataclass
class LinkConfig:
    port: str = ''
    baud: int = 921600
    counts_per_rev: int = 4000
    sample_period: float = 0.0       # s, checked against the device's (0: not checked)
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
        h = self.sample_period
        if not isinstance(h, (int, float)) or not math.isfinite(h) or not (h == 0 or 1e-5 <= h <= 0.1):
            e.append(f'sample_period must be 0 (not checked) or in [1e-5, 0.1] s, got {h!r}')
        for name in ('pendulum_sign', 'motor_sign'):
            if getattr(self, name) not in (1, -1):
                e.append(f'{name} must be 1 or -1, got {getattr(self, name)!r}')
        wd = self.watchdog_period
        if not isinstance(wd, (int, float)) or not math.isfinite(wd) or \
                not P.WATCHDOG_MIN_MS <= round(wd * 1000) <= P.WATCHDOG_MAX_MS:
            e.append(f'watchdog_period must be in [{P.WATCHDOG_MIN_MS / 1000}, {P.WATCHDOG_MAX_MS / 1000}] s, '
                     f'got {wd!r}')
        if not isinstance(self.command_timeout_samples, int) or \
                not 1 <= self.command_timeout_samples <= P.HOLD_MAX_SAMPLES:
            e.append(f'command_timeout_samples must be an integer in 1..{P.HOLD_MAX_SAMPLES} (the device\'s '
                     f'hold limit), got {self.command_timeout_samples!r}')
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
    samples_lost: int = 0            # gaps in the device's sample counter while connected
    frames_lost: int = 0             # gaps in the device's frame sequence numbers
    outage_samples: int = 0          # the seq gap across reconnections (samples taken while down)
    duplicate_samples: int = 0       # a sample number again (dropped)
    device_restarts: int = 0         # the device's counter went back while connected
    reads: int = 0                   # reads that brought at least one sample
    overruns: int = 0                # ... more than one: the link thread was a period behind
    max_backlog: int = 0             # most samples in one read
    late_samples: int = 0            # taken more than one period after the device sent them
    commands_sent: int = 0
    commands_refused: int = 0        # non-finite, future, from a previous connection
    stale_commands: int = 0          # not newer than the last command sent (or zeroed)
    old_commands: int = 0            # answering a sample command_timeout_samples or more old
    commands_inactive: int = 0       # arrived while not active or the link down (ignored)
    commands_saturated: int = 0
    tx_dropped: int = 0              # frames the port could not take (its buffer full)
    timeout_samples: int = 0         # samples answered with u = 0 by the PC-side timeout
    timeouts: int = 0                # timeout episodes
    watchdog_trips: int = 0          # rising edges of the device's ST_WATCHDOG
    device_rx_bad: int = 0           # frames the device refused since the first connection
    nacks: int = 0
    last_refusal: str = ''
    parser_totals: dict = field(default_factory=dict)


class FrameWriter:
    """Frames to a non-blocking port, never cut: when the port takes only part of a frame, the
    rest goes out before anything else; a frame that finds the port full (or a rest still
    pending) is dropped whole. Not thread-safe: the link's lock guards it."""

    def __init__(self, port) -> None:
        self.port = port
        self.rest = b''

    def send(self, data: bytes) -> bool:
        """False: the frame was dropped (the port is full)."""
        if self.rest:
            self.rest = self.rest[max(self.port.write(self.rest), 0):]
            if self.rest:
                return False
        n = self.port.write(data)
        if n <= 0:
            return False
        self.rest = data[n:]
        return True


@dataclass
class Resume:
    """Where the previous connection stopped: to number the samples of the next one."""
    seq: int
    dev_sample: int
    at: float            # clock time of its last sample
    serial: int
    period: float        # the device's sample period, s


class DriverLink:
    def __init__(self, cfg: LinkConfig, opener: Callable = serial_opener,
                 clock: Callable[[], float] = time.monotonic,
                 on_sample: Optional[Callable[[int, int, int, P.Sample, float], None]] = None,
                 log: Optional[Callable[[str, str], None]] = None,
                 sleep: Callable[[float], None] = time.sleep,
                 trace=None) -> None:
        errs = cfg.errors()
        if errs:
            raise ValueError('; '.join(errs))
        self.cfg = cfg
        self.opener = opener
        self.clock = clock
        self.sleep = sleep
        self.on_sample = on_sample
        self.log = log or (lambda level, msg: None)
        self.trace = trace                # rwpend_ros.trace.Trace or None (profiling)
        self.lock = threading.Lock()      # tx, the seq mapping, the command state
        self.port = None
        self.writer: Optional[FrameWriter] = None
        self.parser = P.StreamParser(accept={P.HELLO_REPLY, P.SAMPLE, P.ACK})
        self.counters = LinkCounters()
        self.delay = DelayMeter()
        self.window_max_delay_us = 0.0
        self.tx_seq = 0
        self.connected = False
        self.want_active = False
        self.zero_pending = bool(cfg.zero_on_configure)
        self.error = 'not connected yet'
        self.fatal = False
        self.hello: Optional[P.HelloReply] = None
        self.hold_limit = 0                  # the device's hold limit set at connect (SET_HOLD; 0: none)
        self.hold_warned = False
        self.period = 0.001               # the device's sample period (HELLO_REPLY)
        self.next_attempt = 0.0
        self.backoff = cfg.backoff_initial
        self.last_rx = 0.0
        self.last_enable_tx = -math.inf
        # sample numbering: seq = ros_base + (device sample - dev_base) mod 2^32
        self.ros_base: Optional[int] = None
        self.dev_base = 0
        self.resume: Optional[Resume] = None
        self.last_seq: Optional[int] = None
        self.last_sample_at = 0.0
        self.last_dev_sample: Optional[int] = None
        self.last_frame_seq: Optional[int] = None
        self.last_sample: Optional[P.Sample] = None
        self.last_rx_bad: Optional[int] = None
        self.last_cmd_seq = -1
        self.last_cmd_dev: Optional[int] = None     # device sample of the last command sent
        self.last_cmd_arrival: Optional[int] = None
        self.timed_out = False
        self.prev_tripped = False

    # ------------------------------------------------------------ transport
    def _write(self, msg) -> int:
        """Send a message at once; returns its frame seq (-1: the port was full, dropped).
        Raises OSError when the port fails. Call with the lock held."""
        if self.port is None:
            raise OSError('port closed')
        seq = self.tx_seq
        self.tx_seq = (self.tx_seq + 1) & 0xFFFF
        if not self.writer.send(P.pack(msg, seq)):
            self.counters.tx_dropped += 1
            return -1
        return seq

    def _send(self, msg) -> int:
        with self.lock:
            return self._write(msg)

    def _close_port(self) -> None:
        with self.lock:
            if self.connected:
                self._remember_resume()
            port, self.port, self.writer = self.port, None, None
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

    def _read_frames(self, timeout: float) -> list[P.Frame]:
        """Wait up to ``timeout`` s for bytes, then parse everything there."""
        port = self.port
        if port is None or not port.wait(timeout):
            return []
        data = port.read()
        return self.parser.feed(data) if data else []

    # ------------------------------------------------------------ connection
    def _await(self, pred, timeout: float, resend=None):
        """Read frames until pred(frame) is true; samples are dropped. Returns the frame or None."""
        end = self.clock() + timeout
        last_send = self.clock()
        while self.clock() < end:
            for fr in self._read_frames(min(0.02, max(0.0, end - self.clock()))):
                if pred(fr):
                    return fr
            if resend is not None and self.clock() - last_send > 0.1:
                resend()
                last_send = self.clock()
        return None

    def _request(self, msg, what: str) -> None:
        seq = self._send(msg)
        fr = self._await(lambda f: f.type == P.ACK and f.msg.request_seq == seq, self.cfg.handshake_timeout)
        if fr is None:
            raise TimeoutError(f'no ACK to {what} within {self.cfg.handshake_timeout} s')
        if fr.msg.result != P.R_OK:
            self.counters.nacks += 1
            raise HandshakeError(f'device refused {what}: {P.RESULT_NAMES.get(fr.msg.result, fr.msg.result)}')

    def _hello(self) -> P.HelloReply:
        c = self.cfg
        hello = P.Hello(P.PROTOCOL_MAJOR, P.PROTOCOL_MINOR)

        def send_hello():
            self._send(hello)
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
        if c.sample_period and h.sample_period_us != int(round(c.sample_period * 1e6)):
            raise HandshakeError(f'the device samples every {h.sample_period_us} us, the stack runs with '
                                 f'rig.sample_period = {c.sample_period * 1e6:g} us: run both with the '
                                 f'same h (the firmware\'s; ./rwpend emulate --h, ./rwpend up --h)')
        return h

    def connect(self) -> None:
        """Open the port and handshake. Raises OSError/TimeoutError/HandshakeError on failure."""
        c = self.cfg
        self._close_port()
        port = self.opener(c.port, c.baud)
        with self.lock:
            self.port, self.writer = port, FrameWriter(port)
        port.flush_input()
        h = self._hello()
        self.hello = h
        self.period = h.sample_period_us * 1e-6 if h.sample_period_us else 0.001
        self._request(P.Enable(0), 'ENABLE 0')
        self._request(P.SetWatchdog(int(round(c.watchdog_period * 1000))), 'SET_WATCHDOG')
        self.hold_limit = 0
        if h.proto_minor >= P.HOLD_SINCE_MINOR:
            # the device zeroes a command command_timeout_samples old by itself: a PC that
            # stalls leaves no command on the motor longer than the simulator would
            self._request(P.SetHold(c.command_timeout_samples), 'SET_HOLD')
            self.hold_limit = c.command_timeout_samples
        elif not self.hold_warned:
            self.hold_warned = True
            self.log('warn', f'firmware protocol {h.proto_major}.{h.proto_minor} has no hold limit (SET_HOLD, '
                             f'1.{P.HOLD_SINCE_MINOR}): when this PC stalls, the device holds the last command '
                             f'until its watchdog ({c.watchdog_period * 1000:g} ms); update the firmware')
        if self.zero_pending:
            self._request(P.Zero(P.ZERO_PENDULUM | P.ZERO_MOTOR), 'ZERO')
            self.zero_pending = False
            self.log('info', 'encoders zeroed (zero_on_configure)')
        first = self._await(lambda f: f.type == P.SAMPLE, c.handshake_timeout)
        if first is None:
            raise TimeoutError(f'device answered the handshake but sends no SAMPLE frames '
                               f'within {c.handshake_timeout} s')
        # a watchdog that tripped while the link was down (the cable pulled while the motor was
        # on) is seen here, before the ENABLE below clears it
        tripped_offline = bool(first.msg.status & P.ST_WATCHDOG)
        with self.lock:
            self.connected = True
            self.ros_base = None
            self.last_cmd_arrival = None
            self.last_cmd_dev = None
            self.last_frame_seq = None
            self.last_rx_bad = None
            self.prev_tripped = tripped_offline
            self.last_rx = self.clock()
            self.delay.reset()
            if self.want_active:
                self._write(P.Enable(1))
                self.last_enable_tx = self.clock()
        self.counters.connects += 1
        if tripped_offline:
            self.counters.watchdog_trips += 1
            self.log('warn', 'device watchdog tripped while the link was down: motor at zero')
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
    def poll(self, timeout: float = 0.01) -> None:
        """One iteration of the link thread: waits at most ``timeout`` s for bytes (less when the
        link timeout comes first), then handles every frame that is there."""
        if not self.connected:
            if self.clock() >= self.next_attempt:
                self.try_connect()
            else:
                self.sleep(min(timeout, max(0.0, self.next_attempt - self.clock())))
            return
        try:
            left = self.last_rx + self.cfg.link_timeout - self.clock()
            frames = self._read_frames(min(timeout, max(0.0, left)))
            now = self.clock()
            samples = 0
            for fr in frames:
                self.last_rx = now
                if self.last_frame_seq is not None:     # every frame the device sent has a seq
                    self.counters.frames_lost += P.seq_gap(self.last_frame_seq, fr.seq)
                self.last_frame_seq = fr.seq
                if fr.type == P.SAMPLE:
                    samples += 1
                    self._on_sample(fr, now)
                elif fr.type == P.ACK and fr.msg.result != P.R_OK:
                    self.counters.nacks += 1
            if samples:
                self._count_read(samples)
            if now - self.last_rx > self.cfg.link_timeout:
                self.lose(f'device silent for {now - self.last_rx:.3f} s (link_timeout {self.cfg.link_timeout} s)')
        except OSError as exc:
            self.lose(f'port error: {exc}')

    def _count_read(self, samples: int) -> None:
        c = self.counters
        c.reads += 1
        if samples > 1:
            c.overruns += 1
            c.max_backlog = max(c.max_backlog, samples)

    def _sequence(self, s: P.Sample, now: float) -> Optional[int]:
        """The seq of a sample (None: a duplicate, dropped). Call with the lock held."""
        c = self.counters
        if self.ros_base is not None:
            d = (s.sample - self.dev_base) & MASK32
            seq = self.ros_base + d
            if s.sample == self.last_dev_sample:
                c.duplicate_samples += 1
                return None
            if d < 0x80000000 and seq > self.last_seq:
                c.samples_lost += seq - self.last_seq - 1
                return seq
            c.device_restarts += 1            # its counter went back: number on from here
            self.ros_base = None
            self.resume = Resume(self.last_seq, s.sample, now, self.hello.serial if self.hello else 0, 0.0)
        seq = self._first_seq(s, now)
        self.ros_base, self.dev_base = seq, s.sample
        if self.trace is not None:
            self.trace('drv.offset', seq - s.sample)   # device sample + offset = seq (for traces)
        return seq

    def _first_seq(self, s: P.Sample, now: float) -> int:
        """The seq of the first sample of a connection: the device's counter on from where it
        was when it is the same device and the counter advanced no more than the time allows,
        else the time elapsed in samples; the gap is counted in ``outage_samples``."""
        r = self.resume
        if r is None:
            return 0 if self.last_seq is None else self.last_seq + 1
        elapsed = max(0.0, now - r.at)
        d = (s.sample - r.dev_sample) & MASK32
        same = (self.hello is not None and self.hello.serial == r.serial and r.period > 0
                and 0 < d <= 2 * elapsed / r.period + 100)
        gap = d if same else max(1, round(elapsed / self.period))
        self.counters.outage_samples += gap - 1
        return r.seq + gap

    def _on_sample(self, fr: P.Frame, now: float) -> None:
        s: P.Sample = fr.msg
        c = self.counters
        with self.lock:
            seq = self._sequence(s, now)
            if seq is None:
                return
            self.last_seq = seq
            self.last_sample_at = now
            self.last_dev_sample = s.sample
            self.last_sample = s
            c.samples += 1
        if self.trace is not None:
            self.trace('drv.rx', seq, int(now * 1e9))
        if self.on_sample is not None:      # first: the bookkeeping can wait, the loop cannot
            self.on_sample(seq, self.cfg.pendulum_sign * s.pendulum_counts, self.cfg.motor_sign * s.motor_counts,
                           s, now)
        self._device_report(s, now)
        self._supervise(seq, s)

    def _device_report(self, s: P.Sample, now: float) -> None:
        """What the sample says about the link: its delay, the device's rx_bad, its watchdog."""
        c = self.counters
        delay = self.delay.delay_us(s.time_us, now * 1e6)
        if delay > self.period * 1e6:
            c.late_samples += 1
        self.window_max_delay_us = max(self.window_max_delay_us, delay)
        if self.last_rx_bad is not None:
            c.device_rx_bad += (s.rx_bad - self.last_rx_bad) & 0xFFFF
        self.last_rx_bad = s.rx_bad
        tripped = bool(s.status & P.ST_WATCHDOG)
        if tripped and not self.prev_tripped:
            c.watchdog_trips += 1
            self.log('warn', 'device watchdog tripped: motor at zero')
        self.prev_tripped = tripped

    def _supervise(self, seq: int, s: P.Sample) -> None:
        """Keep the amplifier in the wanted state; PC-side command timeout."""
        enabled = bool(s.status & P.ST_ENABLED)
        now = self.clock()
        with self.lock:
            if enabled != self.want_active and now - self.last_enable_tx > 0.05:
                self._write(P.Enable(1 if self.want_active else 0))
                self.last_enable_tx = now
            if not (self.want_active and enabled):
                return
            arrival = self.last_cmd_arrival
            if arrival is not None and seq - arrival < self.cfg.command_timeout_samples:
                self.timed_out = False
                return
            if not self.timed_out and arrival is not None:
                self.counters.timeouts += 1
            self.timed_out = True
            self.counters.timeout_samples += 1
            # PC-side timeout: an explicit zero (keeps the watchdog fed), answering the sample of
            # the last command sent, so that the device still takes any newer one (as the
            # simulator does: a late command less than the timeout old is applied)
            self._write(P.Command(self.dev_base if self.last_cmd_dev is None else self.last_cmd_dev, 0))

    def _remember_resume(self) -> None:
        """Where this connection stopped, for the numbering of the next one. Lock held."""
        if self.last_seq is not None and self.last_dev_sample is not None:
            self.resume = Resume(self.last_seq, self.last_dev_sample, self.last_sample_at,
                                 self.hello.serial if self.hello else 0, self.period)

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

    def _refuse(self, reason: str, counter: str = 'commands_refused') -> tuple[bool, str]:
        c = self.counters
        setattr(c, counter, getattr(c, counter) + 1)
        c.last_refusal = reason
        return False, reason

    def command(self, seq: int, u: float) -> tuple[bool, str]:
        """A MotorCommand answering published sample ``seq``; sent to the device at once when
        acceptable (see the module doc for the rules)."""
        if not isinstance(u, (int, float)) or not math.isfinite(u):
            return self._refuse(f'non-finite u {u!r} (seq {seq})')
        with self.lock:
            why = self._check_command(seq)
            if why is not None:
                return why
            u_dev = self.cfg.motor_sign * float(u)
            if self.hello is not None and abs(u_dev) * P.U_SCALE > self.hello.u_max_milli:
                self.counters.commands_saturated += 1
            dev_sample = (self.dev_base + (seq - self.ros_base)) & MASK32
            try:
                if self._write(P.Command(dev_sample, P.u_to_milli(u_dev))) < 0:
                    return False, 'port full: frame dropped'
            except OSError as exc:
                return False, f'port error: {exc}'
            self.last_cmd_seq = seq
            self.last_cmd_dev = dev_sample
            self.last_cmd_arrival = self.last_seq
            self.counters.commands_sent += 1
        if self.trace is not None:
            self.trace('drv.tx', seq)
        return True, ''

    def _check_command(self, seq: int) -> Optional[tuple[bool, str]]:
        """None when a command for ``seq`` is to be sent, else (False, reason). Lock held."""
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
            return self._refuse(f'stale command for seq {seq} (already sent or zeroed {self.last_cmd_seq})',
                                'stale_commands')
        age = self.last_seq - seq
        if age >= self.cfg.command_timeout_samples:
            return self._refuse(f'old command for seq {seq}: {age} samples old at sample {self.last_seq} '
                                f'(>= command_timeout_samples {self.cfg.command_timeout_samples})',
                                'old_commands')
        return None

    def applied(self, seq: int, s: P.Sample) -> tuple[int, float]:
        """What the motor was driven with over the interval ending at sample ``seq`` (the
        AppliedCommand message): the seq of the sample the held command answered -- ``seq``
        minus the device samples between that one and ``s`` -- or -1 when none was held, and
        the held command in control units (after the device's clamp, with the motor sign)."""
        held = -1 if s.cmd_sample == P.NO_SAMPLE else seq - ((s.sample - s.cmd_sample) & MASK32)
        return held, self.cfg.motor_sign * s.u_applied_milli / P.U_SCALE

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
    def counter_values(self) -> dict:
        """The integer counters (and the parser's, as ``rx.*``): what :func:`health.assess` compares."""
        c = self.counters
        d = {f.name: getattr(c, f.name) for f in fields(c) if isinstance(getattr(c, f.name), int)}
        for k, v in self.parser_stats().items():
            d[f'rx.{k}'] = v
        return d

    def summary(self) -> str:
        """One line for the log at the end: what the link did and what it could not do."""
        c = self.counters
        n = max(c.samples, 1)
        return (f'{c.samples} samples ({c.samples_lost} lost, {c.outage_samples} in {c.link_losses} '
                f'outage(s), {c.late_samples} = {100 * c.late_samples / n:.2f} % taken late, '
                f'{c.overruns} reads behind), {c.frames_lost} frames lost, '
                f'{sum(self.parser_stats().get(k, 0) for k in ("bad_crc", "truncated", "bad_length"))} corrupt; '
                f'{c.commands_sent} commands sent, {c.old_commands} old and {c.stale_commands} stale refused, '
                f'{c.tx_dropped} not written; the device refused {c.device_rx_bad} frames, its watchdog '
                f'tripped {c.watchdog_trips} time(s)')

    def take_window_max_delay_ms(self) -> float:
        """The largest sample delay since the last call, ms (and start a new window)."""
        m, self.window_max_delay_us = self.window_max_delay_us, 0.0
        return m / 1000.0

    def snapshot(self) -> dict:
        c = self.counters
        d = {'port': self.cfg.port, 'connected': self.connected, 'active': self.want_active,
             'error': self.error, 'fatal': self.fatal,
             'silent_for': f'{self.clock() - self.last_rx:.3f}' if self.connected else '',
             **self.counter_values(), 'last_refusal': c.last_refusal, 'command_timed_out': self.timed_out}
        if self.hello is not None:
            h = self.hello
            d.update({'firmware': f'{h.fw_major}.{h.fw_minor}.{h.fw_patch}',
                      'protocol': f'{h.proto_major}.{h.proto_minor}', 'device_serial': f'{h.serial:#010x}',
                      'device_counts_per_rev': h.counts_per_rev_pendulum,
                      'device_hold_limit_samples': self.hold_limit})
        s = self.last_sample
        if s is not None:
            d.update({'device.sample': s.sample, 'device.time_us': s.time_us,
                      'device.status': ','.join(P.status_names(s.status)) or 'none',
                      'device.enabled': bool(s.status & P.ST_ENABLED),
                      'device.watchdog_tripped': bool(s.status & P.ST_WATCHDOG),
                      'device.overspeed': bool(s.status & P.ST_OVERSPEED),
                      'device.u_applied': s.u_applied_milli / P.U_SCALE * self.cfg.motor_sign,
                      'device.cmd_sample': s.cmd_sample, 'device.rx_bad': s.rx_bad})
        return d
