"""PC-side link state machine against the device logic over a fake serial port (fake clock, no ROS)."""
from __future__ import annotations

import random

import pytest

from rwpend_driver import protocol as P
from support.device import DeviceCore
from rwpend_driver.link import DriverLink, FrameWriter, LinkConfig
from rwpend_model.rig import load_rig

H = 0.001


class Clock:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


class FakeWire:
    """A device on a cable, in fake time: the device ticks every h; what it sends waits in
    ``to_pc`` until the PC reads it (``lag`` s after it was sent: the PC side's delay)."""

    def __init__(self, clock: Clock, dev: DeviceCore) -> None:
        self.clock = clock
        self.dev = dev
        self.next_tick = H
        self.plugged = True
        self.silent = False
        self.corrupt = None          # callable(bytes) -> bytes, on what the device sends
        self.to_pc: list[tuple[float, bytes]] = []
        self.lag = 0.0
        self.opens = 0
        self.write_room = None       # bytes the port takes per write (None: all)

    def run_until(self, t: float) -> None:
        while self.next_tick <= t + 1e-12:
            self.clock.t = max(self.clock.t, self.next_tick)
            self.send(self.dev.tick(self.next_tick), self.next_tick)
            self.next_tick += H
        self.clock.t = max(self.clock.t, t)

    def send(self, data: bytes, t: float) -> None:
        if data and not self.silent:
            self.to_pc.append((t, self.corrupt(data) if self.corrupt else data))

    def ready(self) -> bool:
        return any(t + self.lag <= self.clock.t + 1e-12 for t, _ in self.to_pc)


class FakePort:
    def __init__(self, wire: FakeWire) -> None:
        self.wire = wire
        self.closed = False

    def _check(self):
        if not self.wire.plugged or self.closed:
            raise OSError(5, 'Input/output error')

    def wait(self, timeout):
        self._check()
        w = self.wire
        end = w.clock.t + max(timeout, 1e-6)      # poll(2) waits at least a clock tick
        while not w.ready() and w.next_tick <= end:
            w.run_until(w.next_tick)
        if not w.ready():
            w.run_until(end)
        return w.ready()

    def read(self):
        self._check()
        w = self.wire
        out = b''.join(d for t, d in w.to_pc if t + w.lag <= w.clock.t + 1e-12)
        w.to_pc = [(t, d) for t, d in w.to_pc if t + w.lag > w.clock.t + 1e-12]
        return out

    def write(self, data):
        self._check()
        w = self.wire
        n = len(data) if w.write_room is None else min(w.write_room, len(data))
        w.send(w.dev.receive(bytes(data[:n]), w.clock.t), w.clock.t)
        return n

    def flush_input(self):
        self.wire.to_pc.clear()

    def close(self):
        self.closed = True


def make(dev=None, **cfg):
    clock = Clock()
    wire = FakeWire(clock, dev or DeviceCore(load_rig(), now=0.0))
    published = []

    def opener(port, baud):
        if not wire.plugged:
            raise FileNotFoundError(2, 'No such file or directory', port)
        wire.opens += 1
        return FakePort(wire)

    link = DriverLink(LinkConfig(port='/dev/fake', **cfg), opener=opener, clock=clock,
                      on_sample=lambda seq, pc, mc, s, rx: published.append((seq, pc, mc, s)),
                      sleep=lambda dt: wire.run_until(clock.t + dt))
    return link, wire, clock, published


def run(link, n):
    """Until n more samples were published (or 10 n polls)."""
    start = link.counters.samples
    for _ in range(10 * n):
        if link.counters.samples - start >= n:
            return
        link.poll()


def serve(link, pub, n, u=1.0, every=1):
    """n polls, answering the newest sample with u after each."""
    for i in range(n):
        link.poll()
        if pub and i % every == 0:
            link.command(pub[-1][0], u)


def test_config_validation():
    for bad in (dict(port=''), dict(baud=0), dict(pendulum_sign=2), dict(motor_sign=0),
                dict(watchdog_period=0.0), dict(watchdog_period=5.0), dict(command_timeout_samples=0),
                dict(command_timeout_samples=1001),
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
    c = link.counters
    assert c.samples_lost == c.frames_lost == c.late_samples == c.overruns == 0


def test_the_device_zeroes_a_command_as_old_as_the_timeout_itself():
    """SET_HOLD command_timeout_samples at connect (protocol 1.1): when the PC stops answering,
    the device holds the last command for that many samples, then zero -- not until its watchdog."""
    link, wire, clock, pub = make(command_timeout_samples=3, watchdog_period=0.05)
    link.set_active(True)
    assert link.try_connect(), link.error
    assert wire.dev.hold_samples == 3 and link.snapshot()['device_hold_limit_samples'] == 3
    run(link, 5)
    serve(link, pub, 20, u=2.0)
    assert wire.dev.u_applied_milli == 2000
    k = wire.dev.k
    wire.run_until(clock.t + 0.0025)              # the PC stalls (not even its own timeout runs)
    assert wire.dev.k - k in (2, 3) and wire.dev.u_applied_milli == 2000
    wire.run_until(clock.t + 0.004)
    assert wire.dev.u_applied_milli == 0 and wire.dev.counters.hold_expired == 1
    assert wire.dev.enabled and not wire.dev.tripped   # not a watchdog trip: nothing latched


def test_a_device_of_protocol_1_0_is_served_and_the_missing_hold_limit_said():
    class Device10(DeviceCore):
        def hello_reply(self):
            return super().hello_reply()._replace(proto_minor=0)
    logs = []
    link, wire, clock, pub = make(Device10(load_rig(), now=0.0))
    link.log = lambda level, msg: logs.append((level, msg))
    assert link.try_connect(), link.error
    assert wire.dev.hold_samples == 0 and link.hold_limit == 0
    assert [m for lv, m in logs if lv == 'warn' and 'no hold limit' in m]


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
        ok, why = link.command(pub[-1][0], 2.0)
        assert ok, why
        run(link, 1)
    assert wire.dev.plant.u_held == pytest.approx(-2.0)       # motor_sign = -1
    assert link.last_sample.u_applied_milli == -2000
    assert link.snapshot()['device.u_applied'] == pytest.approx(2.0)
    assert pub[-1][2] == -link.last_sample.motor_counts and link.last_sample.motor_counts != 0
    # refused: future, stale, non-finite
    last = pub[-1][0]
    assert link.command(last, 2.0)[0]
    assert not link.command(last + 1, 1.0)[0]
    assert not link.command(last, 1.0)[0]
    assert not link.command(last, float('nan'))[0]
    c = link.counters
    assert (c.commands_refused, c.stale_commands) == (2, 1)
    run(link, 2)
    assert wire.dev.plant.u_held == pytest.approx(-2.0)
    assert wire.dev.rx_bad == 0 and c.device_rx_bad == 0     # the device refused nothing


def test_old_commands_never_reach_the_device():
    """The simulator's rule: a command answering a sample command_timeout_samples or more old is
    refused and counted; the motor stays at the PC-side timeout's zero."""
    link, wire, clock, pub = make(command_timeout_samples=3)
    link.set_active(True)
    assert link.try_connect()
    run(link, 3)
    assert link.command(pub[-1][0], 4.0)[0]
    run(link, 1)
    assert wire.dev.u_milli == 4000
    run(link, 6)
    newest = pub[-1][0]
    for age in (5, 4, 3):
        ok, why = link.command(newest - age, 5.0)
        assert not ok and 'old command' in why
    assert link.counters.old_commands == 3
    run(link, 2)
    assert wire.dev.u_milli == 0 and wire.dev.counters.commands >= 1
    assert wire.dev.rx_bad == 0


def test_late_command_after_the_timeout_zero_is_applied():
    """After the PC-side timeout sent u = 0, a late command less than the timeout old still
    reaches the motor (the simulator applies it too), and the device takes it: the zero answers
    the last command's sample, not a newer one (the device refused 8 628 late commands in issue
    21's run)."""
    link, wire, clock, pub = make(command_timeout_samples=3)
    link.set_active(True)
    assert link.try_connect()
    run(link, 3)
    link.command(pub[-1][0], 4.0)
    run(link, 4)                                 # timeout: zero sent
    assert link.timed_out and wire.dev.u_milli == 0
    ok, why = link.command(pub[-1][0] - 2, 3.0)  # 2 samples old
    assert ok, why
    run(link, 1)
    assert wire.dev.u_milli == 3000 and not link.timed_out
    assert link.command(pub[-1][0] - 1, 2.0)[0]
    run(link, 1)
    assert wire.dev.u_milli == 2000
    assert wire.dev.rx_bad == 0 and link.counters.device_rx_bad == 0


def test_pc_side_command_timeout_sends_zero():
    link, wire, clock, pub = make(command_timeout_samples=3)
    link.set_active(True)
    assert link.try_connect()
    run(link, 3)
    link.command(pub[-1][0], 4.0)
    run(link, 1)
    assert wire.dev.u_milli == 4000
    run(link, 5)
    assert wire.dev.u_milli == 0 and wire.dev.enabled             # zero sent, watchdog fed
    assert link.counters.timeouts == 1 and link.timed_out
    run(link, 200)
    assert wire.dev.counters.watchdog_trips == 0


def reconnect(link, clock, limit=5.0):
    end = clock.t + limit
    while clock.t < end and not link.connected:
        link.poll()
    assert link.connected, link.error


def test_unplug_watchdog_and_replug_with_zero_torque():
    link, wire, clock, pub = make(watchdog_period=0.02)
    link.set_active(True)
    assert link.try_connect()
    run(link, 3)
    serve(link, pub, 20, u=3.0)
    assert wire.dev.u_milli == 3000
    wire.plugged = False
    link.poll()                                   # port error -> link lost
    assert not link.connected and link.counters.link_losses == 1
    n_pub, last_dev = len(pub), pub[-1][3].sample
    wire.run_until(clock.t + 0.3)                 # the device runs on, unattended
    assert wire.dev.tripped and wire.dev.plant.u_held == 0.0
    assert len(pub) == n_pub                      # nothing published while down
    wire.plugged = True
    reconnect(link, clock)
    assert link.counters.connects == 2
    # the trip happened while the link was down: seen in the first sample after the handshake
    assert link.counters.watchdog_trips == wire.dev.counters.watchdog_trips == 1
    run(link, 20)
    assert wire.dev.enabled and not wire.dev.tripped and wire.dev.u_milli == 0
    assert link.counters.watchdog_trips == 1                       # one trip, counted once
    seqs = [p[0] for p in pub]
    assert seqs == sorted(set(seqs))              # monotone across the reconnection
    # the same device: the seq gap is exactly the samples it took meanwhile
    first = pub[n_pub]
    assert first[0] - pub[n_pub - 1][0] == first[3].sample - last_dev
    assert link.counters.outage_samples == first[0] - pub[n_pub - 1][0] - 1 > 250
    assert link.counters.samples_lost == 0
    # a command answering a sample from before the reconnection is refused
    assert not link.command(pub[n_pub - 1][0], 3.0)[0]
    assert link.command(pub[-1][0], 1.0)[0]
    run(link, 1)
    assert wire.dev.u_milli == 1000


def test_device_restart_numbered_by_time():
    """Another device (or one that restarted) after a reconnection: seq jumps by the time elapsed."""
    link, wire, clock, pub = make()
    assert link.try_connect()
    run(link, 10)
    wire.plugged = False
    link.poll()
    wire.run_until(clock.t + 0.5)
    wire.dev = DeviceCore(load_rig(), serial=0x1234, now=clock.t)     # counter from 0 again
    wire.plugged = True
    n = len(pub)
    reconnect(link, clock)
    run(link, 5)
    gap = pub[n][0] - pub[n - 1][0]
    assert 0.45 / H < gap < 0.8 / H, gap
    assert [p[0] for p in pub] == sorted(set(p[0] for p in pub))


def test_silent_device_detected_and_reconnect_backoff():
    link, wire, clock, pub = make(link_timeout=0.05)
    assert link.try_connect()
    run(link, 10)
    wire.silent = True
    n = len(pub)
    for _ in range(100):
        link.poll()
        if not link.connected:
            break
    assert not link.connected and 'silent' in link.error and len(pub) == n
    # handshake keeps failing while silent: backoff grows to the maximum
    end = clock.t + 20.0
    while clock.t < end:
        link.poll()
    assert link.counters.failed_attempts >= 3 and link.backoff == link.cfg.backoff_max
    wire.silent = False
    reconnect(link, clock)


def test_backlog_and_late_samples_counted():
    """The PC reading late: samples arrive several at a time, more than a period after the
    device sent them: counted (backlog reads, late samples), each still published once."""
    link, wire, clock, pub = make()
    assert link.try_connect()
    run(link, 50)
    assert link.counters.late_samples == 0
    link.take_window_max_delay_ms()
    for _ in range(50):
        wire.run_until(clock.t + 0.004)         # the PC busy elsewhere for 4 ms
        link.poll()
    c = link.counters
    assert c.overruns >= 49 and c.max_backlog == 4
    assert 90 <= c.late_samples <= 160          # those that waited more than a period
    assert link.take_window_max_delay_ms() == pytest.approx(3.0, abs=0.5)
    assert link.take_window_max_delay_ms() == 0.0       # a new window
    seqs = [p[0] for p in pub]
    assert seqs == list(range(seqs[0], seqs[0] + len(seqs)))
    assert c.samples_lost == 0


def test_frames_lost_on_the_way_counted():
    link, wire, clock, pub = make()
    assert link.try_connect()
    run(link, 10)
    dropped = [0]

    def drop_some(b):
        dropped[0] += 1
        return b'' if dropped[0] % 10 == 0 else b
    wire.corrupt = drop_some
    run(link, 500)
    c = link.counters
    assert c.samples_lost >= 40 and c.frames_lost == c.samples_lost
    v = link.counter_values()
    assert v['samples_lost'] == c.samples_lost and 'rx.bad_crc' in v


def test_frame_writer_never_cuts_a_frame():
    class Port:
        def __init__(self):
            self.room = 5
            self.out = b''

        def write(self, data):
            n = min(self.room, len(data))
            self.out += data[:n]
            return n
    port = Port()
    w = FrameWriter(port)
    frames = [P.pack(P.Command(i, i), i) for i in range(20)]
    sent = [f for f in frames if w.send(f)]
    port.room = 1000
    w.send(b'')
    assert port.out == b''.join(sent)                   # every frame whole, in order
    assert 0 < len(sent) < len(frames)
    p = P.StreamParser()
    assert [f.msg.sample for f in p.feed(port.out)] == [P.StreamParser().feed(f)[0].msg.sample for f in sent]
    assert p.stats.errors == 0


def test_port_full_drops_whole_frames_device_sees_none_corrupt():
    link, wire, clock, pub = make()
    link.set_active(True)
    assert link.try_connect()
    run(link, 5)
    wire.write_room = 6                 # the port takes 6 bytes per write
    serve(link, pub, 200, u=1.0)
    assert link.counters.tx_dropped > 0
    assert wire.dev.parser.stats.errors == 0 and wire.dev.rx_bad == 0


def test_device_rx_bad_counted_across_wrap():
    link, wire, clock, pub = make()
    assert link.try_connect()
    run(link, 5)
    wire.dev.counters.refused = 0xFFFE - wire.dev.parser.stats.errors   # rx_bad about to wrap
    run(link, 2)
    before = link.counters.device_rx_bad
    for _ in range(5):
        wire.dev.receive(P.pack(P.Command(wire.dev.k + 100, 0), 1), clock.t)   # refused: future
        run(link, 1)
    assert link.counters.device_rx_bad - before == 5


def test_corrupt_stream_counted_never_published_wrong():
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
    run(link, 2000)
    st = link.parser_stats()
    assert st['bad_crc'] + st['truncated'] + st['bad_length'] > 100
    assert link.counters.samples_lost > 100
    seqs = [p[0] for p in pub]
    assert seqs == sorted(set(seqs))
    # every published sample matches the device counter mapping (no invented samples)
    assert all(p[3].sample - pub[0][3].sample == p[0] - pub[0][0] for p in pub)


def test_replies_between_samples_are_not_lost_frames():
    """ACKs share the device's frame counter with the samples: no gap counted for them."""
    link, wire, clock, pub = make()
    assert link.try_connect()
    run(link, 5)
    for on in (True, False, True):
        link.set_active(on)
        run(link, 5)
    assert link.counters.frames_lost == 0 and link.counters.samples_lost == 0


def test_sample_period_mismatch_is_fatal():
    link, wire, clock, pub = make(sample_period=0.002)
    assert not link.try_connect()
    assert link.fatal and 'samples every 1000 us' in link.error
    link, wire, clock, pub = make(sample_period=0.001)
    assert link.try_connect(), link.error
    with pytest.raises(ValueError):
        DriverLink(LinkConfig(port='/dev/x', sample_period=5.0))


def test_summary_line_counts_what_happened():
    link, wire, clock, pub = make()
    assert link.try_connect()
    run(link, 20)
    text = link.summary()
    assert text.startswith('20 samples (0 lost') and 'the device refused 0 frames' in text


def test_applied_command_names_the_sample_it_answered():
    """AppliedCommand: the held command's sample in ROS seq (device samples back from this one,
    across the u32 wrap), -1 when none was held; u in control units with the motor sign."""
    link = DriverLink(LinkConfig(port='/dev/x', motor_sign=-1))
    s = P.Sample(sample=1000, time_us=0, pendulum_counts=0, motor_counts=0, status=0,
                 u_applied_milli=2500, cmd_sample=999, rx_bad=0)
    assert link.applied(5000, s) == (4999, -2.5)
    wrapped = s._replace(sample=1, cmd_sample=0xFFFFFFFE)          # three device samples back
    assert link.applied(5000, wrapped) == (4997, -2.5)
    none = s._replace(u_applied_milli=0, cmd_sample=P.NO_SAMPLE)
    assert link.applied(5000, none) == (-1, 0.0)
