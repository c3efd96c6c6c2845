"""Device logic (the firmware's reference): handshake, enable, commands, watchdog with a fake clock."""
from __future__ import annotations

import random

import pytest

from rwpend_driver import protocol as P
from support.device import DeviceCore
from rwpend_model.rig import load_rig

H = 0.001


class Host:
    """The PC side in miniature: frames out, parsed frames in."""

    def __init__(self, dev: DeviceCore) -> None:
        self.dev = dev
        self.seq = 0
        self.parser = P.StreamParser()
        self.t = 0.0
        self.samples: list[P.Sample] = []
        self.others: list[P.Frame] = []

    def send(self, msg) -> int:
        s = self.seq
        self.seq += 1
        self._rx(self.dev.receive(P.pack(msg, s), self.t))
        return s

    def raw(self, data: bytes) -> None:
        self._rx(self.dev.receive(data, self.t))

    def _rx(self, data: bytes) -> None:
        for f in self.parser.feed(data):
            (self.samples.append(f.msg) if f.type == P.SAMPLE else self.others.append(f))

    def tick(self, n: int = 1) -> P.Sample:
        for _ in range(n):
            self.t += H
            self._rx(self.dev.tick(self.t))
        return self.samples[-1]

    def last_ack(self) -> P.Ack:
        return [f.msg for f in self.others if f.type == P.ACK][-1]


@pytest.fixture
def host():
    return Host(DeviceCore(load_rig(), watchdog_ms=20))


def test_hello_reports_version_and_resolution(host):
    host.send(P.Hello(1, 0))
    r = host.others[-1].msg
    assert isinstance(r, P.HelloReply)
    assert (r.proto_major, r.counts_per_rev_pendulum, r.counts_per_rev_motor) == (1, 4000, 4000)
    assert r.sample_period_us == 1000 and r.u_max_milli == 10000 and r.watchdog_ms == 20
    s = host.send(P.Hello(2, 0))
    assert host.last_ack() == P.Ack(P.HELLO, P.R_UNSUPPORTED, s)


def test_one_sample_per_tick_with_counter(host):
    for _ in range(10):
        host.tick()
    assert [s.sample for s in host.samples] == list(range(1, 11))
    assert host.samples[-1].time_us == 10000
    assert all(s.status & P.ST_ENABLED == 0 for s in host.samples)


def test_disabled_ignores_commands(host):
    host.tick()
    host.send(P.Command(1, 5000))
    s = host.tick()
    assert s.u_applied_milli == 0 and host.dev.counters.ignored_commands == 1


def test_command_applied_and_echoed(host):
    host.send(P.Enable(1))
    assert host.last_ack().result == P.R_OK
    s = host.tick()
    host.send(P.Command(s.sample, 2500))
    s2 = host.tick()
    assert s2.status & P.ST_ENABLED and s2.status & P.ST_CMD_FRESH
    assert s2.u_applied_milli == 2500 and s2.cmd_sample == s.sample
    assert host.dev.plant.u_held == pytest.approx(2.5)
    # future sample refused; older than the held one refused
    host.send(P.Command(s2.sample + 5, 100))
    host.send(P.Command(s.sample - 1, 100))
    s3 = host.tick()
    assert s3.u_applied_milli == 2500 and host.dev.counters.refused == 2 and s3.rx_bad == 2
    # saturation is flagged
    host.send(P.Command(s3.sample, 20000))
    s4 = host.tick()
    assert s4.u_applied_milli == 10000 and s4.status & P.ST_SATURATED


def test_watchdog_trips_within_period_fake_clock(host):
    host.send(P.Enable(1))
    for _ in range(100):                         # commands every sample: no trip
        s = host.tick()
        host.send(P.Command(s.sample, 3000))
    assert host.dev.enabled and host.dev.counters.watchdog_trips == 0
    t_last = host.t
    trip_t = None
    for _ in range(100):                         # commands stop
        s = host.tick()
        if s.status & P.ST_WATCHDOG:
            trip_t = host.t
            break
        assert s.u_applied_milli == 3000
    assert trip_t is not None
    assert 0.020 < trip_t - t_last <= 0.020 + H + 1e-9    # motor zero within period + one sample
    assert host.dev.plant.u_held == 0.0 and s.u_applied_milli == 0 and not s.status & P.ST_ENABLED
    assert host.dev.last_trip.since_command == pytest.approx(trip_t - t_last)
    # latched: commands do nothing until ENABLE 1
    host.send(P.Command(s.sample, 3000))
    s = host.tick()
    assert s.u_applied_milli == 0 and s.status & P.ST_WATCHDOG
    host.send(P.Enable(1))
    s = host.tick()
    assert not s.status & P.ST_WATCHDOG and s.status & P.ST_ENABLED and s.u_applied_milli == 0


def test_watchdog_period_setting(host):
    s = host.send(P.SetWatchdog(1))
    assert host.last_ack() == P.Ack(P.SET_WATCHDOG, P.R_BAD_VALUE, s)
    host.send(P.SetWatchdog(5))
    assert host.last_ack().result == P.R_OK and host.dev.watchdog_ms == 5
    host.send(P.Enable(1))
    n = 0
    while not host.tick().status & P.ST_WATCHDOG:
        n += 1
    assert n == 5


def test_zero_only_when_disabled(host):
    host.dev.plant = type(host.dev.plant)(host.dev.rig, theta=0.5)
    assert host.dev.counts()[0] != 0
    host.send(P.Enable(1))
    host.send(P.Zero(3))
    assert host.last_ack().result == P.R_BAD_STATE
    host.send(P.Enable(0))
    host.send(P.Zero(0))
    assert host.last_ack().result == P.R_BAD_VALUE
    host.send(P.Zero(3))
    assert host.last_ack().result == P.R_OK
    assert host.dev.counts() == (0, 0) and host.tick().status & P.ST_ZEROED


def test_garbage_never_acts(host):
    """Random bytes and corrupted commands: counted, never applied."""
    host.send(P.Enable(1))
    rng = random.Random(3)
    for i in range(10000):
        s = host.tick() if i % 10 == 0 else host.samples[-1] if host.samples else host.tick()
        host.send(P.Command(s.sample, 0))             # keeps the watchdog fed, u = 0
        bad = bytearray(P.pack(P.Command(s.sample, 9000), 1000 + i))
        r = rng.random()
        if r < 0.3:
            bad[rng.randrange(2, len(bad))] ^= 1 << rng.randrange(8)
        elif r < 0.6:
            bad = bad[:rng.randrange(1, len(bad))]
        else:
            bad = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 30)))
        host.raw(bytes(bad))
        assert host.dev.u_milli == 0
    assert host.dev.enabled and host.dev.parser.stats.errors > 1000
    assert max(abs(s.u_applied_milli) for s in host.samples) == 0
