"""Device-side logic of the rig's microcontroller stated in Python: the tests' oracle of the firmware.

:class:`DeviceCore` is pure (no I/O, no clock of its own): the caller feeds the received bytes
with :meth:`DeviceCore.receive` and calls :meth:`DeviceCore.tick` once per sample period with
the current time; both return the bytes to transmit (or :meth:`DeviceCore.tick_begin` and
:meth:`DeviceCore.tick_end` around the plant's step, as the firmware's C core is called).  The C
core (``firmware/core``) is what ``./rwpend emulate`` and the board run; this statement of it
is the one its host tests compare with frame for frame (``rwpend_driver/test/test_firmware.py``)
and the PC side's tests' fake device (``test_link.py``, ``test_device.py``).

Per tick (sample k -> k+1):
1. watchdog: enabled and more than ``watchdog_period`` since the last valid COMMAND (or since
   ENABLE) -> amplifier disabled, command zero, ST_WATCHDOG latched (until ENABLE 1);
   hold limit (SET_HOLD, protocol 1.1): a non-zero held command answering a sample more than
   ``max_age`` samples before k+1 -> command zero until the next valid COMMAND;
2. the held command (0 when disabled) drives the plant over one sample period (ZOH);
3. the encoders are read and one SAMPLE frame is sent.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional

from rwpend_model.plant import Plant
from rwpend_model.rig import Rig

from rwpend_driver import protocol as P

FW_VERSION = (1, 1, 0)


@dataclass
class DeviceCounters:
    commands: int = 0            # valid COMMANDs applied
    ignored_commands: int = 0    # valid COMMANDs while disabled
    refused: int = 0             # well-formed frames refused (future sample, bad value, state)
    watchdog_trips: int = 0
    hold_expired: int = 0        # non-zero commands zeroed by the hold limit
    samples: int = 0
    tx_bytes: int = 0


@dataclass
class WatchdogEvent:
    t: float                 # time of the tick that tripped
    since_command: float     # time since the last valid command (or enable)
    sample: int
    u_before: float


class DeviceCore:
    """State machine of the device: enable, watchdog, command hold, zeroing, framing."""

    def __init__(self, rig: Rig, plant: Optional[Plant] = None, *, serial: int = 0x52570001,
                 watchdog_ms: int = P.DEFAULT_WATCHDOG_MS, now: float = 0.0,
                 on_event: Optional[Callable[[str, dict], None]] = None) -> None:
        self.rig = rig
        self.plant = plant if plant is not None else Plant(rig)
        self.serial = serial
        self.h = rig.sample_period
        self.u_max_milli = int(round(rig.u_max * P.U_SCALE))
        self.parser = P.StreamParser(accept={P.HELLO, P.COMMAND, P.ENABLE, P.SET_WATCHDOG, P.ZERO, P.SET_HOLD})
        self.tx_seq = 0
        self.k = 0                      # sample counter (u32 on the wire)
        self.t0 = now
        self.enabled = False
        self.tripped = False
        self.watchdog_ms = watchdog_ms
        self.hold_samples = 0           # SET_HOLD max_age (0: no limit)
        self.expired = False            # the held command was zeroed by the hold limit
        self.last_command_time = now
        self.u_milli = 0                # held command (milli-units, clamped)
        self.cmd_sample = P.NO_SAMPLE   # sample answered by the held command
        self.fresh = False
        self.saturated = False
        self.zeroed = False
        self.zero_p = 0                 # encoder offsets (counts) set by ZERO
        self.zero_m = 0
        self.u_applied_milli = 0        # command held over the last integrated period
        self.counters = DeviceCounters()
        self.on_event = on_event
        self.last_trip: Optional[WatchdogEvent] = None
        self._applied_sample = P.NO_SAMPLE    # the command sample held over the period being stepped
        self.version = 'python ' + '.'.join(map(str, FW_VERSION))

    # -------------------------------------------------------------- helpers
    def _event(self, name: str, **data) -> None:
        if self.on_event is not None:
            self.on_event(name, data)

    def _send(self, msg) -> bytes:
        b = P.pack(msg, self.tx_seq)
        self.tx_seq = (self.tx_seq + 1) & 0xFFFF
        self.counters.tx_bytes += len(b)
        return b

    def _ack(self, fr: P.Frame, result: int) -> bytes:
        if result != P.R_OK:
            self.counters.refused += 1
        return self._send(P.Ack(fr.type, result, fr.seq))

    @property
    def rx_bad(self) -> int:
        return (self.parser.stats.errors + self.counters.refused) & 0xFFFF

    def counts(self) -> tuple[int, int]:
        pc, mc = self.plant.counts()
        return pc - self.zero_p, mc - self.zero_m

    def status(self) -> int:
        s = 0
        if self.enabled:
            s |= P.ST_ENABLED
        if self.tripped:
            s |= P.ST_WATCHDOG
        st = self.plant.state
        if abs(st.wheel_rate - st.theta_dot) > self.rig.omega_max:
            s |= P.ST_OVERSPEED
        if self.fresh:
            s |= P.ST_CMD_FRESH
        if self.saturated:
            s |= P.ST_SATURATED
        if self.zeroed:
            s |= P.ST_ZEROED
        return s

    def hello_reply(self) -> P.HelloReply:
        return P.HelloReply(P.PROTOCOL_MAJOR, P.PROTOCOL_MINOR, *FW_VERSION, 0,
                            self.rig.counts_per_rev, self.rig.counts_per_rev,
                            int(round(self.h * 1e6)), self.u_max_milli, self.watchdog_ms, self.serial)

    # -------------------------------------------------------------- input
    def receive(self, data: bytes, now: float) -> bytes:
        """Bytes received from the PC; returns the replies (HELLO_REPLY, ACK) to send."""
        out = bytearray()
        for fr in self.parser.iter_feed(data):
            out += self._handle(fr, now)
        return bytes(out)

    def _handle(self, fr: P.Frame, now: float) -> bytes:
        m = fr.msg
        if fr.type == P.COMMAND:
            self._command(m, now)
            return b''
        if fr.type == P.HELLO:
            if m.proto_major != P.PROTOCOL_MAJOR:
                return self._ack(fr, P.R_UNSUPPORTED)
            return self._send(self.hello_reply())
        if fr.type == P.ENABLE:
            if m.on not in (0, 1):
                return self._ack(fr, P.R_BAD_VALUE)
            self.set_enabled(bool(m.on), now)
            return self._ack(fr, P.R_OK)
        if fr.type == P.SET_WATCHDOG:
            if not P.WATCHDOG_MIN_MS <= m.period_ms <= P.WATCHDOG_MAX_MS:
                return self._ack(fr, P.R_BAD_VALUE)
            self.watchdog_ms = m.period_ms
            self._event('watchdog_period', period_ms=m.period_ms)
            return self._ack(fr, P.R_OK)
        if fr.type == P.SET_HOLD:
            if m.max_age > P.HOLD_MAX_SAMPLES:
                return self._ack(fr, P.R_BAD_VALUE)
            self.hold_samples = m.max_age
            self._event('hold_limit', max_age=m.max_age)
            return self._ack(fr, P.R_OK)
        if fr.type == P.ZERO:
            if m.mask == 0 or m.mask & ~(P.ZERO_PENDULUM | P.ZERO_MOTOR):
                return self._ack(fr, P.R_BAD_VALUE)
            if self.enabled:
                return self._ack(fr, P.R_BAD_STATE)
            pc, mc = self.plant.counts()
            if m.mask & P.ZERO_PENDULUM:
                self.zero_p = pc
            if m.mask & P.ZERO_MOTOR:
                self.zero_m = mc
            self.zeroed = True
            self._event('zero', mask=m.mask)
            return self._ack(fr, P.R_OK)
        return self._ack(fr, P.R_UNSUPPORTED)  # pragma: no cover - parser filters types

    def _command(self, m: P.Command, now: float) -> None:
        ahead = (m.sample - self.k) & 0xFFFFFFFF
        if ahead != 0 and ahead < 0x80000000:       # answers a sample not sent yet
            self.counters.refused += 1
            return
        if not self.enabled:
            self.counters.ignored_commands += 1
            return
        if self.cmd_sample != P.NO_SAMPLE and ((m.sample - self.cmd_sample) & 0xFFFFFFFF) >= 0x80000000:
            self.counters.refused += 1              # older than the command held
            return
        u = m.u_milli
        self.saturated = abs(u) > self.u_max_milli
        self.u_milli = max(-self.u_max_milli, min(self.u_max_milli, u))
        self.cmd_sample = m.sample
        self.expired = False
        self.last_command_time = now
        self.fresh = True
        self.counters.commands += 1

    def set_enabled(self, on: bool, now: float) -> None:
        self.u_milli = 0
        self.expired = False
        self.cmd_sample = P.NO_SAMPLE
        self.saturated = False
        self.last_command_time = now
        if on:
            self.tripped = False
        if on != self.enabled:
            self.enabled = on
            self._event('enable' if on else 'disable', sample=self.k)

    # -------------------------------------------------------------- sample clock
    def check_watchdog(self, now: float) -> bool:
        """Trip when enabled and no valid command for more than the watchdog period."""
        if self.enabled and now - self.last_command_time > self.watchdog_ms * 1e-3:
            ev = WatchdogEvent(t=now, since_command=now - self.last_command_time, sample=self.k,
                               u_before=self.u_milli / P.U_SCALE)
            self.enabled = False
            self.tripped = True
            self.u_milli = 0
            self.cmd_sample = P.NO_SAMPLE
            self.counters.watchdog_trips += 1
            self.last_trip = ev
            self._event('watchdog_trip', t=now, since_command=ev.since_command, sample=ev.sample,
                        u_before=ev.u_before, period=self.watchdog_ms * 1e-3)
            return True
        return False

    def check_hold(self) -> bool:
        """The hold limit: a non-zero command answering a sample more than ``hold_samples`` before
        the one this period ends at (k+1) is zeroed until the next valid command."""
        age = (self.k + 1 - self.cmd_sample) & 0xFFFFFFFF
        if (self.enabled and self.hold_samples and self.u_milli != 0 and self.cmd_sample != P.NO_SAMPLE
                and age > self.hold_samples):
            before = self.u_milli
            self.u_milli = 0
            self.saturated = False
            self.expired = True
            self.counters.hold_expired += 1
            self._event('hold_expired', sample=self.k, age=age, u_before=before / P.U_SCALE)
            return True
        return False

    def held_command(self) -> float:
        return self.u_milli / P.U_SCALE if self.enabled else 0.0

    def tick(self, now: float) -> bytes:
        """One sample period: watchdog, integrate [t_k, t_k+1) with the held command, send SAMPLE k+1."""
        u_milli = self.tick_begin(now)
        self.plant.step(u_milli / P.U_SCALE)
        return self.tick_end(now)

    def tick_begin(self, now: float) -> int:
        """The sample instant, as the firmware's core (rw_core_tick_begin): the watchdog, then the
        command the motor gets over [t_k, t_k+1) (milli-units; 0 while disabled)."""
        self.check_watchdog(now)
        self.check_hold()
        self.u_applied_milli = self.u_milli if self.enabled else 0
        self._applied_sample = self.cmd_sample if self.enabled and not self.expired else P.NO_SAMPLE
        return self.u_applied_milli

    def tick_end(self, now: float, pendulum_counts: int | None = None, motor_counts: int | None = None) -> bytes:
        """The plant stepped over the period: SAMPLE k+1 (rw_core_tick_end).  The counts are this
        core's plant's (the emulator steps the same plant; the arguments are the HAL's)."""
        self.k = (self.k + 1) & 0xFFFFFFFF
        self.counters.samples += 1
        return self.sample_frame(now, self._applied_sample)

    def rx_stats(self) -> dict:
        """What the receiver counted (the PC side's ParserStats names)."""
        return self.parser.stats.as_dict()

    def sample_frame(self, now: float, applied_sample: Optional[int] = None) -> bytes:
        pc, mc = self.counts()
        status = self.status()
        self.fresh = False
        time_us = int(round((now - self.t0) * 1e6)) & 0xFFFFFFFF
        cs = self.cmd_sample if applied_sample is None else applied_sample
        return self._send(P.Sample(self.k, time_us, _i32(pc), _i32(mc), status,
                                   self.u_applied_milli, cs, self.rx_bad))


def _i32(v: int) -> int:
    """Wrap to a signed 32-bit counter, as a hardware quadrature counter does."""
    return ((v + 0x80000000) & 0xFFFFFFFF) - 0x80000000
