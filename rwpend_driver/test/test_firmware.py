"""The reference firmware's core (firmware/core, C99) on this PC, through ctypes: the same code the
STM32 board runs (rwpend_driver.firmware).

* its frame codec against the driver's (rwpend_driver.protocol) on the same bytes;
* its device logic against the Python statement of the contract (tests/support/device.py) on the same
  random traffic, frame for frame;
* watchdog, e-stop (ENABLE 0 held until ENABLE 1), the "too old" rule, counter wrap, bad frames
  (truncated, bad CRC, unknown type, oversized: counted, never acted on, never a crash);
* the build: the host library (rwpend_driver.firmware.build_host_library, always), the board's image
  (where Debian's arm-none-eabi-gcc is installed: ``make firmware``), and the board's image booted
  in QEMU's netduinoplus2 (an STM32F405) with the driver's handshake and a few hundred
  SAMPLE/COMMAND exchanges over its USART (where qemu-system-arm is installed).
"""
from __future__ import annotations

import ctypes
import math
import os
import random
import re
import shutil
import subprocess
import time

import pytest

from rwpend_driver import firmware as E
from rwpend_driver import protocol as P
from support.device import DeviceCore
from rwpend_model.plant import Plant
from rwpend_model.rig import load_rig

TO_DEVICE, TO_HOST = 0, 1
REQUESTS = {P.HELLO, P.COMMAND, P.ENABLE, P.SET_WATCHDOG, P.ZERO, P.SET_HOLD}


@pytest.fixture(scope='module')
def lib():
    E.build_host_library()            # always runs where cc is
    return E.load_library()


@pytest.fixture
def rig():
    return load_rig()


class Dev:
    """The firmware's core with a test clock (integer microseconds) and the PC side's parser."""

    def __init__(self, rig, watchdog_ms=20, events=None):
        self.core = E.FirmwareCore(rig, watchdog_ms=watchdog_ms,
                                   on_event=(lambda n, d: events.append((n, d))) if events is not None else None)
        self.t_us = 0
        self.seq = 0
        self.parser = P.StreamParser()
        self.samples: list[P.Sample] = []
        self.others: list[P.Frame] = []

    def _rx(self, data: bytes) -> None:
        for f in self.parser.feed(data):
            (self.samples.append(f.msg) if f.type == P.SAMPLE else self.others.append(f))

    def send(self, msg, dt_us: int = 7) -> int:
        s, self.seq = self.seq, self.seq + 1
        self.raw(P.pack(msg, s), dt_us)
        return s

    def raw(self, data: bytes, dt_us: int = 7) -> None:
        self.t_us += dt_us
        self._rx(self.core.receive(data, self.t_us * 1e-6))

    def tick(self, n: int = 1, counts=(0, 0)) -> P.Sample:
        for _ in range(n):
            self.t_us = (self.t_us // 1000 + 1) * 1000
            self.core.tick_begin(self.t_us * 1e-6)
            self._rx(self.core.tick_end(self.t_us * 1e-6, *counts))
        return self.samples[-1]

    def last_ack(self) -> P.Ack:
        return [f.msg for f in self.others if f.type == P.ACK][-1]


# ------------------------------------------------------------------------------------- the codec
@pytest.mark.parametrize('data,crc', [(b'123456789', 0x29B1), (b'', 0xFFFF), (b'\x00', 0xE1F0), (b'A', 0xB915)])
def test_crc_check_values_of_protocol_md(lib, data, crc):
    assert lib.rw_crc16(data, len(data)) == crc


def test_crc_equals_the_drivers_on_random_data(lib):
    rng = random.Random(1)
    for _ in range(2000):
        d = bytes(rng.randrange(256) for _ in range(rng.randrange(0, 80)))
        assert lib.rw_crc16(d, len(d)) == P.crc16(d) == P.crc16_reference(d)


def test_message_table_is_the_drivers(lib):
    """One header states the types and sizes (firmware/core/rw_protocol.h): the same as the PC
    side's, each in its direction only."""
    for t, (st, _) in P.LAYOUT.items():
        own, other = (TO_DEVICE, TO_HOST) if t in REQUESTS else (TO_HOST, TO_DEVICE)
        assert lib.rw_payload_size(t, own) == st.size, P.NAMES[t]
        assert lib.rw_payload_size(t, other) == -1
    for t in set(range(256)) - set(P.LAYOUT):
        assert lib.rw_payload_size(t, TO_DEVICE) == -1 and lib.rw_payload_size(t, TO_HOST) == -1


def test_frame_encoding_equals_the_drivers(lib):
    rng = random.Random(2)
    out = ctypes.create_string_buffer(128)
    for _ in range(500):
        t, seq = rng.randrange(256), rng.randrange(65536)
        payload = bytes(rng.randrange(256) for _ in range(rng.randrange(0, P.MAX_PAYLOAD + 1)))
        n = lib.rw_frame_encode(out, len(out), t, seq, payload, len(payload))
        assert out.raw[:n] == P.frame(t, seq, payload)
    assert lib.rw_frame_encode(out, 10, 1, 0, b'\0' * 8, 8) == 0          # does not fit: nothing
    assert lib.rw_frame_encode(out, 128, 1, 0, b'\0' * 65, 65) == 0      # len > 64


def test_protocol_md_vectors_made_and_taken_by_the_core(rig):
    """PROTOCOL.md's test vectors: its requests taken by the core, its HELLO_REPLY, SAMPLE and ACK
    made by it byte for byte."""
    c = E.FirmwareCore(rig, watchdog_ms=50)
    assert c.receive(bytes.fromhex('a55a010200000100023c'), 0.0).hex() == (      # HELLO 1.0, seq 0
        'a55a81180000010101010000a00f0000a00f0000e80310273200010057527f' 'a6')
    c = E.FirmwareCore(rig, watchdog_ms=50)
    c.receive(P.pack(P.Enable(1), 0), 0.0)                                        # ACK, seq 0
    c.tick_begin(0.001)
    assert c.tick_end(0.001, 0, 0).hex() == (                                     # SAMPLE k 1, seq 1
        'a55a821a010001000000e803000000000000000000000100' '0000ffffffff00005056')
    assert c.receive(bytes.fromhex('a55a03010100017bae'), 0.002).hex() == (      # ENABLE 1, seq 1
        'a55a8304020003000100a1e6')                                                # ACK, seq 2
    assert c.receive(bytes.fromhex('a55a02060700e8030000dc0564ca'), 0.002) == b''  # COMMAND 1000 (future)
    assert c.rx_bad == 1
    assert c.receive(bytes.fromhex('a55a0402020032' '00adc2'), 0.002)[2] == P.ACK  # SET_WATCHDOG 50
    assert c.receive(bytes.fromhex('a55a0501030003dc2d'), 0.002)[6:8] == bytes([P.ZERO, P.R_BAD_STATE])
    assert c.receive(bytes.fromhex('a55a060204000300d058'), 0.002)[6:8] == bytes([P.SET_HOLD, P.R_OK])  # SET_HOLD 3


def test_the_cores_version_is_the_hello_replys(rig):
    d = Dev(rig)
    d.send(P.Hello(1, 0))
    r = d.others[-1].msg
    assert f'{r.fw_major}.{r.fw_minor}.{r.fw_patch}' == E.firmware_version() == d.core.version
    s = d.send(P.Hello(2, 0))
    assert d.last_ack() == P.Ack(P.HELLO, P.R_UNSUPPORTED, s) and d.core.rx_bad == 1


# ------------------------------------------------------------------- the contract, frame by frame
def _random_traffic(rng: random.Random, k: int, frame_seq: int) -> bytes:
    """What a host (and a bad cable) might send: mostly well-formed requests with random fields."""
    r = rng.random()
    if r < 0.45:
        msg = P.Command((k - rng.choice([0, 0, 0, 1, 2, 5, -1, -3, 40])) & 0xFFFFFFFF,
                        rng.choice([0, 500, -700, 2500, 9999, -10001, 20000, -32767, rng.randrange(-32767, 32768)]))
    elif r < 0.56:
        msg = P.Enable(rng.choice([0, 1, 1, 1, 2, 255]))
    elif r < 0.6:
        msg = P.SetHold(rng.choice([0, 1, 3, 3, 1000, 1001, 65535]))
    elif r < 0.68:
        msg = P.SetWatchdog(rng.choice([1, 2, 5, 20, 50, 1000, 1001, 65535]))
    elif r < 0.75:
        msg = P.Zero(rng.choice([0, 1, 2, 3, 4, 7]))
    elif r < 0.8:
        msg = P.Hello(rng.choice([1, 1, 2]), rng.randrange(3))
    elif r < 0.85:                       # a device->PC type sent to the device, an unknown type
        return P.frame(rng.choice([P.SAMPLE, P.ACK, 0x42, 0x00]), frame_seq,
                       bytes(rng.randrange(256) for _ in range(4)))
    elif r < 0.88:                       # a known type with the wrong length
        return P.frame(P.ENABLE, frame_seq, b'\x01\x00')
    else:                                # a damaged frame or plain noise
        b = bytearray(P.pack(P.Command(k, rng.randrange(-9000, 9000)), frame_seq))
        how = rng.random()
        if how < 0.35:
            b[rng.randrange(2, len(b))] ^= 1 << rng.randrange(8)
        elif how < 0.7:
            b = b[:rng.randrange(1, len(b))]
        else:
            b = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 40)))
        return bytes(b)
    return P.pack(msg, frame_seq)


@pytest.mark.parametrize('seed', [11, 12, 13])
def test_the_c_core_does_what_the_python_statement_does(rig, seed):
    """Same random traffic and sample instants into the firmware's core and into
    support.device.DeviceCore (each driving its own copy of the plant): every frame out is
    the same, and so is every command the motor got. (OVERSPEED aside: Python takes it from the
    true speed, the firmware from the counter's change over a period; the wheel stays far below.)"""
    rng = random.Random(seed)
    py = DeviceCore(rig, Plant(rig), watchdog_ms=20, now=0.0)
    c = E.FirmwareCore(rig, watchdog_ms=20)
    c_plant = Plant(rig)
    py_out, c_out = P.StreamParser(), P.StreamParser()
    t_us, frame_seq, n_frames = 0, 0, 0
    for step in range(6000):
        if rng.random() < 0.55:                     # bytes within the period: never on a tick
            t_us += rng.randrange(1, 300)
            data = _random_traffic(rng, py.k, frame_seq)
            frame_seq = (frame_seq + 1) & 0xFFFF
            a = py_out.feed(py.receive(data, t_us * 1e-6))
            b = c_out.feed(c.receive(data, t_us * 1e-6))
        else:                                       # the sample instant
            t_us = (t_us // 1000 + 1) * 1000
            a = py_out.feed(py.tick(t_us * 1e-6))
            u = c.tick_begin(t_us * 1e-6)
            c_plant.step(u / P.U_SCALE)
            b = c_out.feed(c.tick_end(t_us * 1e-6, *c_plant.counts()))
            assert c_plant.u_held == py.plant.u_held, step
        mask = lambda fs: [f._replace(msg=f.msg._replace(status=f.msg.status & ~P.ST_OVERSPEED))  # noqa: E731
                           if f.type == P.SAMPLE else f for f in fs]
        assert mask(b) == mask(a), f'step {step}'
        n_frames += len(a)
        assert c.rx_bad == py.rx_bad
    stats = py.parser.stats.as_dict()
    assert c.rx_stats() == stats
    assert (c.counters.commands, c.counters.refused, c.counters.ignored_commands, c.counters.watchdog_trips) == (
        py.counters.commands, py.counters.refused, py.counters.ignored_commands, py.counters.watchdog_trips)
    # the run went through the interesting states
    assert py.counters.commands > 300 and py.counters.watchdog_trips > 3 and py.counters.refused > 50
    assert stats['bad_crc'] and stats['truncated'] and stats['unknown_type'] and stats['bad_length']
    assert n_frames > 3000


def test_receiver_rules_equal_the_drivers_on_noise(rig):
    """Byte soup with frames in it, fed in random chunks: the core's receiver counts exactly what
    the driver's StreamParser (accepting PC -> device types) counts."""
    rng = random.Random(5)
    c = E.FirmwareCore(rig)
    ref = P.StreamParser(accept=REQUESTS)
    stream = bytearray()
    for i in range(4000):
        r = rng.random()
        if r < 0.5:
            stream += _random_traffic(rng, 0, i)
        elif r < 0.7:
            stream += bytes([0xA5, 0x5A]) + bytes(rng.randrange(256) for _ in range(rng.randrange(0, 8)))
        else:
            stream += bytes(rng.randrange(256) for _ in range(rng.randrange(1, 20)))
    pos = 0
    while pos < len(stream):
        n = rng.randrange(1, 200)
        chunk = bytes(stream[pos:pos + n])
        pos += n
        c.receive(chunk, 0.0)
        ref.feed(chunk)
    assert c.rx_stats() == ref.stats.as_dict()
    c.link_lost()
    ref.flush()
    assert c.rx_stats() == ref.stats.as_dict()


# ------------------------------------------------------------------------------- device behaviour
def test_commands_held_clamped_and_echoed(rig):
    d = Dev(rig)
    d.send(P.Enable(1))
    s = d.tick()
    d.send(P.Command(s.sample, 2500))
    drive = d.core.drive()
    assert (drive.amplifier_on, drive.reverse, drive.magnitude_milli) == (1, 0, 2500)     # at once
    s2 = d.tick()
    assert s2.status & P.ST_CMD_FRESH and s2.u_applied_milli == 2500 and s2.cmd_sample == s.sample
    assert not d.tick().status & P.ST_CMD_FRESH                                         # held, not fresh
    d.send(P.Command(d.samples[-1].sample, -20000))                                     # |u| clamp
    s4 = d.tick()
    assert s4.u_applied_milli == -10000 and s4.status & P.ST_SATURATED
    drive = d.core.drive()
    assert (drive.amplifier_on, drive.reverse, drive.magnitude_milli) == (1, 1, 10000)   # the motor sign


def test_too_old_and_future_commands_are_refused_and_counted(rig):
    d = Dev(rig)
    d.send(P.Command(0, 500))                          # disabled: ignored, not a refusal
    assert d.core.counters.ignored_commands == 1 and d.core.rx_bad == 0
    d.send(P.Enable(1))
    s = d.tick(5)
    d.send(P.Command(s.sample - 2, 1000))              # 2 samples old but newer than none: held
    d.send(P.Command(s.sample + 1, 2000))              # answers a sample not sent yet
    d.send(P.Command(s.sample - 3, 3000))              # older than the command held
    d.send(P.Command(s.sample - 2, 1500))              # the same sample again: taken
    s2 = d.tick()
    assert s2.u_applied_milli == 1500 and s2.cmd_sample == s.sample - 2
    assert d.core.counters.refused == 2 and s2.rx_bad == 2 and d.core.counters.commands == 2


def test_watchdog_zeroes_the_motor_within_its_period_and_latches(rig):
    events = []
    d = Dev(rig, watchdog_ms=20, events=events)
    d.send(P.Enable(1))
    for _ in range(50):
        s = d.tick()
        d.send(P.Command(s.sample, 3000))
    t_last = d.t_us
    while not d.tick().status & P.ST_WATCHDOG:
        assert d.samples[-1].u_applied_milli == 3000
    s = d.samples[-1]
    assert 20_000 < d.t_us - t_last <= 20_000 + 1000          # period + at most one sample
    assert s.u_applied_milli == 0 and not s.status & P.ST_ENABLED and s.cmd_sample == P.NO_SAMPLE
    assert d.core.drive().amplifier_on == 0
    name, data = [e for e in events if e[0] == 'watchdog_trip'][-1]
    assert data['since_command'] == pytest.approx((d.t_us - t_last) * 1e-6) and data['u_before'] == 3.0
    assert data['period'] == 0.020 and data['sample'] == s.sample - 1
    d.send(P.Command(s.sample, 3000))                         # latched: nothing moves
    assert d.tick().u_applied_milli == 0 and d.samples[-1].status & P.ST_WATCHDOG
    d.send(P.Enable(1))                                       # until ENABLE 1, with u = 0
    s = d.tick()
    assert not s.status & P.ST_WATCHDOG and s.status & P.ST_ENABLED and s.u_applied_milli == 0


def test_set_watchdog_range(rig):
    d = Dev(rig)
    for bad in (0, 1, 1001, 65535):
        s = d.send(P.SetWatchdog(bad))
        assert d.last_ack() == P.Ack(P.SET_WATCHDOG, P.R_BAD_VALUE, s)
    assert d.core.watchdog_ms == 20 and d.core.rx_bad == 4
    d.send(P.SetWatchdog(5))
    assert d.last_ack().result == P.R_OK and d.core.watchdog_ms == 5
    d.send(P.Enable(1))
    n = 0
    while not d.tick().status & P.ST_WATCHDOG:
        n += 1
    assert n == 5


def test_hold_limit_zeroes_a_command_too_old_until_a_newer_one(rig):
    """SET_HOLD n (protocol 1.1): a non-zero command drives the motor over the n periods after
    the sample it answers, then zero -- the SAMPLE says no command held -- until a newer
    COMMAND; a zero command is left alone; 0 turns it off; above 1000 refused."""
    events = []
    d = Dev(rig, watchdog_ms=50, events=events)
    for bad in (1001, 65535):
        s = d.send(P.SetHold(bad))
        assert d.last_ack() == P.Ack(P.SET_HOLD, P.R_BAD_VALUE, s)
    d.send(P.SetHold(3))
    assert d.last_ack().result == P.R_OK and ('hold_limit', {'max_age': 3}) in events
    assert d.core.snapshot().hold_samples == 3
    d.send(P.Enable(1))
    s = d.tick()
    d.send(P.Command(s.sample, 4000))
    held = [d.tick() for _ in range(5)]
    assert [x.u_applied_milli for x in held] == [4000, 4000, 4000, 0, 0]
    assert [x.cmd_sample for x in held] == [s.sample] * 3 + [P.NO_SAMPLE] * 2
    assert d.core.drive().magnitude_milli == 0 and d.core.snapshot().hold_expired == 1
    name, data = [e for e in events if e[0] == 'hold_expired'][-1]
    assert data['age'] == 4 and data['u_before'] == 4.0
    assert held[-1].status & P.ST_ENABLED and not held[-1].status & P.ST_WATCHDOG   # not a trip
    d.send(P.Command(held[-1].sample, -2000))                # a newer command drives it again
    assert d.tick().u_applied_milli == -2000
    d.send(P.Command(d.samples[-1].sample, 0))               # zero: nothing to expire
    d.tick(6)
    assert d.core.snapshot().hold_expired == 1 and d.samples[-1].cmd_sample != P.NO_SAMPLE
    d.send(P.SetHold(0))                                     # off: held until the watchdog
    d.send(P.Command(d.samples[-1].sample, 1000))
    assert [x.u_applied_milli for x in (d.tick(), d.tick(10))] == [1000, 1000]


def test_estop_enable_0_holds_the_motor_at_zero_until_enable_1(rig):
    """The host's e-stop (the driver's latched e-stop sends ENABLE 0): the motor at zero at once,
    every command ignored while it lasts, and after ENABLE 1 zero until a new command."""
    events = []
    d = Dev(rig, events=events)
    d.send(P.Enable(1))
    s = d.tick()
    d.send(P.Command(s.sample, 4000))
    assert d.tick().u_applied_milli == 4000
    d.send(P.Enable(0))
    assert d.core.drive().amplifier_on == 0 and d.core.drive().magnitude_milli == 0      # at once
    for _ in range(30):                                       # a controller that keeps commanding
        s = d.tick()
        d.send(P.Command(s.sample, 4000))
        assert s.u_applied_milli == 0 and not s.status & P.ST_ENABLED
    assert d.core.counters.ignored_commands == 30 and d.core.counters.watchdog_trips == 0
    d.send(P.Enable(1))
    s = d.tick()
    assert s.status & P.ST_ENABLED and s.u_applied_milli == 0 and s.cmd_sample == P.NO_SAMPLE
    d.send(P.Command(s.sample, 4000))
    assert d.tick().u_applied_milli == 4000
    assert [n for n, _ in events] == ['enable', 'disable', 'enable']


def test_zero_only_when_disabled_and_from_the_last_sample(rig):
    events = []
    d = Dev(rig, events=events)
    d.tick(counts=(1234, -77))
    d.send(P.Enable(1))
    s = d.send(P.Zero(3))
    assert d.last_ack() == P.Ack(P.ZERO, P.R_BAD_STATE, s)
    d.send(P.Enable(0))
    for bad in (0, 4, 7):
        d.send(P.Zero(bad))
        assert d.last_ack().result == P.R_BAD_VALUE
    d.send(P.Zero(P.ZERO_PENDULUM))
    assert d.last_ack().result == P.R_OK and d.core.counts() == (0, -77)
    s = d.tick(counts=(1240, -70))
    assert (s.pendulum_counts, s.motor_counts) == (6, -70) and s.status & P.ST_ZEROED
    assert ('zero', {'mask': 1}) in events


def test_overspeed_from_the_motor_counter(rig):
    limit = math.floor(rig.omega_max * rig.counts_per_rev * rig.sample_period / (2 * math.pi))
    d = Dev(rig)
    m = 0
    for step in (limit, limit + 1, -limit - 1, 3):
        m += step
        s = d.tick(counts=(0, m))
        assert bool(s.status & P.ST_OVERSPEED) == (abs(step) > limit), step


# ------------------------------------------------------------------------------------- wrapping
def test_sample_counter_wraps_and_commands_follow(lib, rig):
    d = Dev(rig)
    lib.rw_core_set_sample(d.core._mem, 0xFFFFFFFE)
    d.send(P.Enable(1))
    assert d.tick().sample == 0xFFFFFFFF
    d.send(P.Command(0xFFFFFFFF, 100))
    assert d.tick().sample == 0 and d.samples[-1].cmd_sample == 0xFFFFFFFF
    d.send(P.Command(0, 200))                   # newer across the wrap
    d.send(P.Command(0xFFFFFFFF, 300))          # older across the wrap: refused
    d.send(P.Command(1, 400))                   # ahead of the last sample (0): refused
    s = d.tick()
    assert (s.sample, s.u_applied_milli, s.cmd_sample, s.rx_bad) == (1, 200, 0, 2)


def test_frame_seq_rx_bad_time_and_counts_wrap(rig):
    d = Dev(rig, watchdog_ms=50)
    # seq: u16, +1 per frame sent
    for _ in range(65537):
        d.core.tick_begin(0.0)
        d.core.tick_end(0.0, 0, 0)
    d.tick()
    assert d.parser.feed(b'') == [] and d.samples[-1].sample == 65538
    assert P.StreamParser().feed(d.core.tick_end(0.0, 0, 0))[0].seq == 65538 & 0xFFFF
    # rx_bad: u16 on the wire, the counters go on
    oversized = bytes([0xA5, 0x5A, 0x01, 65, 0, 0])      # len 65 > 64: bad length, one byte dropped
    d.raw(oversized * 65537)
    s = d.tick()
    assert s.rx_bad == 65537 & 0xFFFF and d.core.rx_stats()['bad_length'] == 65537
    # the device clock wraps at 2^32 us (71.6 min) and the watchdog does not care
    d.t_us = 2 ** 32 - 30_000
    d.send(P.Enable(1))
    s = d.tick()
    d.send(P.Command(s.sample, 1000))
    for _ in range(40):
        s = d.tick()
        d.send(P.Command(s.sample, 1000))
        assert s.status & P.ST_ENABLED
    assert s.time_us < 20_000                            # wrapped
    # encoder counts wrap as i32 (the hardware counter's), and so do ZERO's differences
    s = d.tick(counts=(2 ** 31 + 5, -(2 ** 31) - 5))
    assert (s.pendulum_counts, s.motor_counts) == (-(2 ** 31) + 5, 2 ** 31 - 5)


def test_16_bit_counter_extension(lib):
    ext = lib.rw_counter_extend16
    assert ext(0, 5) == 5 and ext(5, 0xFFFE) == -2 and ext(-2, 3) == 3
    v, raw = 0, 0
    rng = random.Random(4)
    for _ in range(20000):                              # moves of up to +-30000 counts per read
        step = rng.randrange(-30000, 30001)
        raw = (raw + step) & 0xFFFF
        v2 = ext(v, raw)
        assert v2 == E._i32(v + step)
        v = v2
    assert ext(0x7FFFFFFF, 0x0001) == -(2 ** 31) + 1     # the 32-bit count wraps too


# ---------------------------------------------------------------------------------- bad frames
@pytest.mark.parametrize('name,data,counter', [
    ('truncated', P.pack(P.Command(0, 9000), 1)[:9] + P.pack(P.Hello(1, 0), 2), 'truncated'),
    ('bad CRC', P.pack(P.Command(0, 9000), 1)[:-1] + b'\x00', 'bad_crc'),
    ('unknown type', P.frame(0x42, 1, b'\x01\x02'), 'unknown_type'),
    ('wrong direction', P.pack(P.Ack(P.ENABLE, 0, 1), 1), 'unknown_type'),
    ('oversized', bytes([0xA5, 0x5A, P.COMMAND, 200, 1, 0]) + bytes(200), 'bad_length'),
    ('wrong length', P.frame(P.COMMAND, 1, bytes(7)), 'bad_length'),
])
def test_bad_frames_counted_never_acted_on(rig, name, data, counter):
    d = Dev(rig)
    d.send(P.Enable(1))
    s = d.tick()
    d.send(P.Command(s.sample, 100))
    before = d.core.rx_bad
    d.raw(data)
    assert d.core.rx_stats()[counter] >= 1, name
    s = d.tick()
    assert s.u_applied_milli == 100 and s.rx_bad > before and d.core.enabled
    assert d.core.counters.commands == 1


def test_random_bytes_never_crash_never_move_the_motor(rig):
    d = Dev(rig, watchdog_ms=1000)
    d.send(P.Enable(1))
    rng = random.Random(9)
    for i in range(300):
        d.raw(bytes(rng.randrange(256) for _ in range(rng.randrange(1, 4000))))
        if i % 10 == 0:
            d.tick()
            d.send(P.Command(d.samples[-1].sample, 0))
    st = d.core.rx_stats()
    assert st['bytes'] > 500_000 and st['garbage_bytes'] > 400_000
    assert max(abs(s.u_applied_milli) for s in d.samples) == 0
    assert d.core.counters.commands == 30       # only the real ones (random COMMANDs need a valid CRC)


def test_replies_that_do_not_fit_are_dropped_and_counted(lib, rig):
    c = E.FirmwareCore(rig)
    out = ctypes.create_string_buffer(20)
    hello = P.pack(P.Hello(1, 0), 0)
    assert lib.rw_core_receive(c._mem, hello, len(hello), 0, out, 20) == 0      # 32 bytes needed
    s = c.snapshot()
    assert s.tx_overflow == 1 and s.tx_seq == 1          # the seq moved: the host sees the gap


def test_a_rig_the_firmware_cannot_describe_is_refused(rig):
    import dataclasses
    with pytest.raises(E.FirmwareError, match='sample_period_us'):
        E.FirmwareCore(dataclasses.replace(rig, sample_period=0.07))
    with pytest.raises(E.FirmwareError, match='u_max_milli'):
        E.FirmwareCore(dataclasses.replace(rig, u_max=70.0))


# ------------------------------------------------------------------------------------- builds
def test_host_build_when_missing_or_stale_and_a_clear_error_without_cc(tmp_path, monkeypatch):
    fw = tmp_path / 'firmware'
    shutil.copytree(E.FIRMWARE_DIR, fw, ignore=shutil.ignore_patterns('build'))
    monkeypatch.setattr(E, 'FIRMWARE_DIR', fw)
    monkeypatch.setattr(E, 'HOST_LIBRARY', fw / 'build' / 'host' / 'librwpend_fw.so')
    t0 = time.monotonic()
    lib_path = E.build_host_library()
    took = time.monotonic() - t0
    assert lib_path.exists() and took < 30
    mtime = lib_path.stat().st_mtime_ns
    assert E.build_host_library() == lib_path and lib_path.stat().st_mtime_ns == mtime   # current: no build
    later = time.time() + 2
    os.utime(fw / 'core' / 'rw_core.c', (later, later))
    E.build_host_library()
    assert lib_path.stat().st_mtime_ns != mtime                                          # stale: rebuilt
    assert E.load_library(lib_path).rw_fw_version().decode() == E.firmware_version()
    lib_path.unlink()
    monkeypatch.setenv('CC', 'no-such-cc')
    with pytest.raises(E.FirmwareError, match='no C compiler'):
        E.build_host_library()
    (fw / 'core' / 'rw_core.c').write_text('this is not C\n')
    monkeypatch.setenv('CC', 'cc')
    with pytest.raises(E.FirmwareError, match='failed'):
        E.build_host_library()


def test_core_under_address_and_undefined_behaviour_sanitizers():
    """firmware/bench/rw_fuzz.c: random requests, damaged frames, byte soup, sample instants, reply
    buffers without room -- built with -fsanitize=address,undefined, nothing found."""
    fw = E.FIRMWARE_DIR
    r = subprocess.run(['make', '-s', '-C', str(fw), 'build/host/rw_fuzz'], capture_output=True, text=True,
                       timeout=300)
    if r.returncode != 0 and 'sanitize' in r.stderr and ('cannot find' in r.stderr or 'not found' in r.stderr):
        pytest.skip(f'this cc has no sanitizer runtime: {r.stderr.strip()[-200:]}')
    assert r.returncode == 0, r.stdout + r.stderr
    r = subprocess.run([str(fw / 'build' / 'host' / 'rw_fuzz'), '300000'], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0 and 'no sanitizer finding' in r.stdout, r.stdout + r.stderr


CROSS = shutil.which('arm-none-eabi-gcc')
QEMU = shutil.which('qemu-system-arm')
BOARD_ELF = E.FIRMWARE_DIR / 'build' / 'stm32f4' / 'rwpend_fw.elf'


@pytest.fixture(scope='module')
def board_image():
    if CROSS is None:
        pytest.skip('arm-none-eabi-gcc is not installed (make firmware installs Debian\'s gcc-arm-none-eabi)')
    r = subprocess.run(['make', '-C', str(E.FIRMWARE_DIR), 'board'], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    assert 'warning' not in (r.stdout + r.stderr).lower()
    m = re.search(r'^\s*(\d+)\s+(\d+)\s+(\d+)\s+\d+\s+\w+\s+\S*rwpend_fw\.elf', r.stdout, re.M)
    assert m, r.stdout
    return tuple(int(x) for x in m.groups())


def test_board_image_builds_without_warnings_and_fits(board_image):
    text, data, bss = board_image
    print(f'board image: text {text} B, data {data} B, bss {bss} B')
    assert text + data < 64 * 1024 and data + bss < 16 * 1024


def _boot_qemu():
    q = subprocess.Popen([QEMU, '-M', 'netduinoplus2', '-display', 'none', '-monitor', 'none',
                          '-serial', 'null', '-serial', 'pty', '-kernel', str(BOARD_ELF)],
                         stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    end = time.monotonic() + 20
    while time.monotonic() < end:
        line = q.stdout.readline()
        m = re.search(r'(/dev/pts/\d+) \(label serial1\)', line)
        if m:
            return q, m.group(1)
        if not line and q.poll() is not None:
            break
    q.kill()
    raise AssertionError('qemu did not say where USART2 is')


@pytest.mark.timeout(120)
def test_board_image_in_qemu_speaks_to_the_driver(board_image):
    """The board's image (not the host build) in QEMU's netduinoplus2 (STM32F405; its timers in
    encoder mode and the RCC are not emulated, the USARTs and the Cortex-M4 are): the driver's own
    handshake over USART2, a few hundred COMMANDs each answering a SAMPLE and echoed by the next
    ones, then the device's watchdog trips when the commands stop."""
    if QEMU is None:
        pytest.skip('qemu-system-arm is not installed (apt-get install qemu-system-arm)')
    from rwpend_driver.link import DriverLink, LinkConfig
    q, pts = _boot_qemu()
    sent: dict[int, float] = {}
    echoed: list[tuple[int, float, float]] = []
    link = None
    try:
        def on_sample(seq, pc, mc, s, now):
            held, u = link.applied(seq, s)
            if held in sent:
                echoed.append((held, sent[held], u))
            v = round(1.0 + (seq % 7) * 0.5, 3)
            if link.command(seq, v)[0]:
                sent[seq] = v

        # QEMU's UART answers several samples late: a hold limit (and the link's freshness rule)
        # of 1000 samples (its most) keeps those commands on the motor; SET_HOLD goes through the image
        link = DriverLink(LinkConfig(port=pts, counts_per_rev=4000, sample_period=0.001, handshake_timeout=2.0,
                                     link_timeout=0.5, command_timeout_samples=1000), on_sample=on_sample)
        link.set_active(True)
        end = time.monotonic() + 60
        while len(echoed) < 400 and time.monotonic() < end:
            link.poll(0.01)
        snap = link.snapshot()
        assert link.connected and snap['firmware'] == E.firmware_version(), snap
        assert snap['protocol'] == '1.1' and snap["device_hold_limit_samples"] == 1000, snap
        assert len(echoed) >= 400, (len(echoed), snap)
        assert all(abs(u - v) < 1e-9 for _, v, u in echoed)           # the device holds what was sent
        assert snap['device.rx_bad'] == 0 and snap['rx.bad_crc'] == 0 and snap['commands_sent'] >= 400
        print(f'qemu: {len(echoed)} commands echoed, {snap["commands_sent"]} sent, {snap["samples"]} samples, '
              f'{snap["samples_lost"]} lost, device rx_bad {snap["device.rx_bad"]}')
        link.close()
        link = None
        # raw: enabled, then silence -> the device's watchdog zeroes the motor
        import serial
        port = serial.Serial(pts, 921600, timeout=0)
        try:
            parser = P.StreamParser()
            port.write(P.pack(P.Enable(1), 0))
            end = time.monotonic() + 10
            tripped = None
            while tripped is None and time.monotonic() < end:
                for f in parser.feed(port.read(4096)):
                    if f.type == P.SAMPLE and f.msg.status & P.ST_WATCHDOG:
                        tripped = f.msg
                time.sleep(0.005)
            assert tripped is not None and not tripped.status & P.ST_ENABLED and tripped.u_applied_milli == 0
        finally:
            port.close()
    finally:
        if link is not None:
            link.close()
        q.kill()
        q.wait(timeout=10)
