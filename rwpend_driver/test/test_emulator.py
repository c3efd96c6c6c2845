"""The emulator on a real pty (no ROS): it knows when a host has the port open, counts what a host
did not take apart from what nobody listened to, and times the commands it gets."""
from __future__ import annotations

import json
import os
import threading
import time

import pytest

from rwpend_driver import protocol as P
from rwpend_driver.emulator import Emulator, parse_args


def start(tmp_path, *extra):
    emu = Emulator(parse_args(['--link', str(tmp_path / 'rig'), '--json', *extra]))
    th = threading.Thread(target=emu.run, daemon=True)
    th.start()
    end = time.monotonic() + 10
    while not (tmp_path / 'rig').exists() and time.monotonic() < end:
        time.sleep(0.01)
    return emu, th


def stop(emu, th):
    emu.stop = True
    th.join(timeout=5)
    assert not th.is_alive()


def wait_for(pred, timeout=10.0):
    end = time.monotonic() + timeout
    while not pred() and time.monotonic() < end:
        time.sleep(0.01)
    assert pred()


def serve(fd, emu):
    """A host in miniature: enable, then answer the newest sample until 20 commands were timed."""
    parser = P.StreamParser()
    while True:
        try:
            if not os.read(fd, 65536):
                break
        except BlockingIOError:
            break
    os.write(fd, P.pack(P.Enable(1), 0))
    seq, newest = 1, None
    end = time.monotonic() + 10
    while emu.latency.n < 20 and time.monotonic() < end:
        try:
            frames = parser.feed(os.read(fd, 65536))
        except BlockingIOError:
            time.sleep(0.0005)
            continue
        samples = [f.msg.sample for f in frames if f.type == P.SAMPLE]
        if samples and samples[-1] != newest:
            newest = samples[-1]
            os.write(fd, P.pack(P.Command(newest, 100), seq))
            seq += 1


def test_unheard_then_dropped_then_served(tmp_path, capsys):
    emu, th = start(tmp_path)
    try:
        wait_for(lambda: emu.counters.unheard_tx > 34 * 20)
        assert emu.counters.dropped_tx == 0 and not emu.host     # nobody has the port open
        fd = os.open(str(tmp_path / 'rig'), os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        try:
            wait_for(lambda: emu.host)
            wait_for(lambda: emu.counters.dropped_tx > 0)        # a host that does not read
            serve(fd, emu)
            assert emu.core.counters.commands > 10 and emu.core.rx_bad == 0
        finally:
            os.close(fd)
        wait_for(lambda: not emu.host)
    finally:
        stop(emu, th)
    events = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    hosts = [e['present'] for e in events if e['event'] == 'host']
    assert hosts == [True, False]
    status = [e for e in events if e['event'] == 'status'][-1]
    for key in ('dropped_tx', 'unheard_tx', 'overruns', 'stalls', 'max_late_ms', 'rx_bad', 'refused',
                'watchdog_trips', 'late_commands', 'cmd_latency'):
        assert key in status
    assert status['cmd_latency']['n'] == emu.latency.n


def test_unplug_replug_by_request(tmp_path):
    emu, th = start(tmp_path)
    try:
        emu.want_unplug = True
        wait_for(lambda: emu.pty is None)
        assert not os.path.lexists(tmp_path / 'rig')
        emu.want_replug = True
        wait_for(lambda: emu.pty is not None and (tmp_path / 'rig').exists())
    finally:
        stop(emu, th)


def test_the_emulator_runs_the_firmware_core(tmp_path, capsys):
    """``./rwpend emulate`` runs the firmware's C core: its version is in the ready, status and exit
    lines, and it samples the plant the hand moved."""
    from rwpend_driver.firmware import firmware_version
    emu = Emulator(parse_args(['--json', '--duration', '0.05', '--status-period', '0.02']))
    emu.hands.put('lift 20 1')
    emu.run()
    assert emu.core.counts() == emu.plant.counts() and emu.core.counts()[0] > 200
    events = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert {e['fw'] for e in events if e['event'] in ('ready', 'status', 'exit')} == {firmware_version()}


def test_the_device_logic_is_not_a_choice():
    """The firmware's core is the only device logic the emulator has: no ``--core``."""
    with pytest.raises(SystemExit):
        parse_args(['--core', 'python'])
