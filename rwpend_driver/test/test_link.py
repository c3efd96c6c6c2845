"""PC-side link state machine against the device logic over a fake serial port (fake clock, no ROS)."""
from __future__ import annotations

import pytest

from rwpend_driver import protocol as P
from rwpend_driver.device import DeviceCore
from rwpend_driver.link import DriverLink, LinkConfig
from rwpend_model.rig import load_rig

H = 0.001


class Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


class FakeWire:
    """A device on a cable: each read advances the fake clock by h and returns one sample frame."""

    def __init__(self, clock: Clock, dev: DeviceCore) -> None:
        self.clock = clock
        self.dev = dev
        self.plugged = True
        self.silent = False
        self.corrupt = None          # callable(bytes) -> bytes
        self.rx_pending = bytearray()
        self.opens = 0


class FakePort:
    def __init__(self, wire: FakeWire) -> None:
        self.wire = wire
        self.closed = False

    def _check(self):
        if not self.wire.plugged or self.closed:
            raise OSError(5, 'Input/output error')

    def write(self, data):
        self._check()
        self.wire.rx_pending += self.wire.dev.receive(bytes(data), self.wire.clock.t)

    def read(self, n):
        self._check()
        w = self.wire
        w.clock.t += H
        out = bytes(w.rx_pending) + w.dev.tick(w.clock.t)
        w.rx_pending.clear()
        if w.silent:
            out = b''
        if w.corrupt is not None:
            out = w.corrupt(out)
        return out

    def reset_input_buffer(self):
        self.wire.rx_pending.clear()

    def close(self):
        self.closed = True


def make(**cfg):
    clock = Clock()
    wire = FakeWire(clock, DeviceCore(load_rig(), now=0.0))
    published = []

    def opener(port, baud):
        if not wire.plugged:
            raise FileNotFoundError(2, 'No such file or directory', port)
        wire.opens += 1
        return FakePort(wire)

    link = DriverLink(LinkConfig(port='/dev/fake', **cfg), opener=opener, clock=clock,
                      on_sample=lambda seq, pc, mc, s: published.append((seq, pc, mc, s)),
                      sleep=lambda dt: None)
    return link, wire, clock, published


def run(link, n):
    for _ in range(n):
        link.poll()


def test_config_validation():
    for bad in (dict(port=''), dict(baud=0), dict(pendulum_sign=2), dict(motor_sign=0),
                dict(watchdog_period=0.0), dict(watchdog_period=5.0), dict(command_timeout_samples=0),
                dict(counts_per_rev=-1), dict(link_timeout=float('nan'))):
        with pytest.raises(ValueError):
            DriverLink(LinkConfig(**{'port': '/dev/x', **bad}))


def test_handshake_and_continuous_seq():
    link, wire, clock, pub = make(watchdog_period=0.03)
    assert link.try_connect(), link.error
    assert wire.dev.watchdog_ms == 30 and link.hello.counts_per_rev_pendulum == 4000
    run(link, 200)
    seqs = [p[0] for p in pub]
    assert len(seqs) >= 190 and seqs == list(range(seqs[0], seqs[0] + len(seqs)))
    assert not wire.dev.enabled                   # not active: amplifier stays off


def test_resolution_mismatch_is_fatal():
    link, wire, clock, pub = make(counts_per_rev=2048)
    assert not link.try_connect()
    assert link.fatal and 'resolution' in link.error


def test_active_commands_reach_device_and_signs():
    link, wire, clock, pub = make(motor_sign=-1, pendulum_sign=-1)
    link.set_active(True)
    assert link.try_connect()
    run(link, 5)
    assert wire.dev.enabled
    for _ in range(50):
        seq = pub[-1][0]
        ok, why = link.command(seq, 2.0)
        assert ok, why
        link.poll()
    assert wire.dev.plant.u_held == pytest.approx(-2.0)       # motor_sign = -1
    assert link.last_sample.u_applied_milli == -2000
    assert link.snapshot()['device.u_applied'] == pytest.approx(2.0)
    pc, mc = wire.dev.counts()
    assert pub[-1][2] == -link.last_sample.motor_counts and link.last_sample.motor_counts != 0
    # refused: future, stale, non-finite
    last = pub[-1][0]
    assert not link.command(last + 1, 1.0)[0]
    assert not link.command(last - 5, 1.0)[0]
    assert not link.command(last, float('nan'))[0]
    assert link.counters.commands_refused == 3
    assert wire.dev.plant.u_held == pytest.approx(-2.0)


def test_pc_side_command_timeout_sends_zero():
    link, wire, clock, pub = make(command_timeout_samples=3)
    link.set_active(True)
    assert link.try_connect()
    run(link, 3)
    link.command(pub[-1][0], 4.0)
    link.poll()
    assert wire.dev.u_milli == 4000
    run(link, 5)
    assert wire.dev.u_milli == 0 and wire.dev.enabled             # zero sent, watchdog fed
    assert link.counters.timeouts == 1 and link.timed_out
    run(link, 200)
    assert wire.dev.counters.watchdog_trips == 0


def test_unplug_watchdog_and_replug_with_zero_torque():
    link, wire, clock, pub = make(watchdog_period=0.02)
    link.set_active(True)
    assert link.try_connect()
    run(link, 3)
    for _ in range(20):
        link.command(pub[-1][0], 3.0)
        link.poll()
    assert wire.dev.u_milli == 3000
    wire.plugged = False
    link.poll()                                   # port error -> link lost
    assert not link.connected and link.counters.link_losses == 1
    n_pub = len(pub)
    for _ in range(25):                           # the device runs on, unattended
        clock.t += H
        wire.dev.tick(clock.t)
        link.poll()
    assert wire.dev.tripped and wire.dev.plant.u_held == 0.0
    assert len(pub) == n_pub                      # nothing published while down
    wire.plugged = True
    for _ in range(3000):
        link.poll()
        clock.t += 0.001
        if link.connected:
            break
    assert link.connected and link.counters.connects == 2
    run(link, 20)
    assert wire.dev.enabled and not wire.dev.tripped and wire.dev.u_milli == 0
    seqs = [p[0] for p in pub]
    assert seqs == sorted(set(seqs))              # monotone across the reconnection
    # a command answering a sample from before the reconnection is refused
    assert not link.command(pub[n_pub - 1][0], 3.0)[0]
    assert link.command(pub[-1][0], 1.0)[0]
    link.poll()
    assert wire.dev.u_milli == 1000


def test_silent_device_detected_and_reconnect_backoff():
    link, wire, clock, pub = make(link_timeout=0.05)
    assert link.try_connect()
    run(link, 10)
    wire.silent = True
    n = len(pub)
    run(link, 100)
    assert not link.connected and 'silent' in link.error and len(pub) == n
    # handshake keeps failing while silent: backoff grows to the maximum
    for _ in range(20000):
        link.poll()
        clock.t += 0.001
    assert link.counters.failed_attempts >= 3 and link.backoff == link.cfg.backoff_max
    wire.silent = False
    for _ in range(4000):
        link.poll()
        clock.t += 0.001
        if link.connected:
            break
    assert link.connected


def test_corrupt_stream_counted_never_published_wrong():
    import random
    rng = random.Random(5)

    def corrupt(b):
        b = bytearray(b)
        if b and rng.random() < 0.3:
            b[rng.randrange(len(b))] ^= 0x10
        if rng.random() < 0.1:
            b = b[:rng.randrange(len(b) + 1)]
        return bytes(b)
    link, wire, clock, pub = make()
    assert link.try_connect()
    wire.corrupt = corrupt
    run(link, 3000)
    st = link.parser_stats()
    assert st['bad_crc'] + st['truncated'] + st['bad_length'] > 100
    assert link.counters.samples_lost > 100
    seqs = [p[0] for p in pub]
    assert seqs == sorted(set(seqs))
    # every published sample matches the device counter mapping (no invented samples)
    assert all(p[3].sample - pub[0][3].sample == p[0] - pub[0][0] for p in pub)
