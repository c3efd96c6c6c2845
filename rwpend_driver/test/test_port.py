"""The non-blocking port on a real pseudo-terminal (no ROS, no pyserial needed except to open)."""
from __future__ import annotations

import os
import time
import tty

import pytest

from rwpend_driver.port import FdPort, absent_port_hint, serial_opener, serial_ports_present


@pytest.fixture
def pty_pair():
    master, slave = os.openpty()
    tty.setraw(slave)
    os.set_blocking(master, False)
    yield master, slave
    for fd in (master, slave):
        try:
            os.close(fd)
        except OSError:
            pass


def test_wait_read_write(pty_pair):
    master, slave = pty_pair
    port = FdPort(slave)
    t = time.monotonic()
    assert not port.wait(0.02) and time.monotonic() - t >= 0.015
    assert port.read() == b''
    os.write(master, b'\xa5\x5a' * 100)
    assert port.wait(1.0)
    got = b''
    while len(got) < 200 and port.wait(0.2):
        got += port.read()
    assert got == b'\xa5\x5a' * 100
    assert port.write(b'abc') == 3
    assert os.read(master, 10) == b'abc'


def test_write_never_blocks_when_the_device_does_not_read(pty_pair):
    master, slave = pty_pair
    port = FdPort(slave)
    total, t = 0, time.monotonic()
    for _ in range(10_000):
        n = port.write(b'x' * 14)
        total += n
        if n == 0:
            break
    assert n == 0 and total > 0 and time.monotonic() - t < 1.0


def test_hang_up_is_an_error(pty_pair):
    master, slave = pty_pair
    port = FdPort(slave)
    os.write(master, b'last')
    os.close(master)
    assert port.wait(1.0)
    with pytest.raises(OSError):
        for _ in range(3):              # what was still there, then the hang-up
            port.read()
            port.wait(0.1)


def test_flush_input_drops_what_came_before(pty_pair):
    master, slave = pty_pair
    port = FdPort(slave)
    os.write(master, b'old' * 1000)
    time.sleep(0.05)
    port.flush_input()
    assert port.read() == b''
    os.write(master, b'new')
    assert port.wait(1.0) and port.read() == b'new'
    port.close()
    port.close()                        # twice: harmless


def test_serial_opener_on_a_pty(pty_pair):
    pytest.importorskip('serial')
    master, slave = pty_pair
    port = serial_opener(os.ttyname(slave), 921600)
    try:
        os.write(master, b'hello')
        assert port.wait(1.0) and port.read() == b'hello'
        assert port.write(b'\x01\x02') == 2 and os.read(master, 10) == b'\x01\x02'
    finally:
        port.close()


def test_absent_port_hint_names_the_ports_there_are(tmp_path):
    missing = str(tmp_path / 'ttyACM9')
    assert absent_port_hint(missing, ['/dev/ttyUSB0', '/dev/ttyACM0']) == \
        f'{missing} does not exist; serial ports present: /dev/ttyACM0, /dev/ttyUSB0'
    assert 'no serial port is present' in absent_port_hint(missing, [])
    assert absent_port_hint(str(tmp_path), []) == '', 'a path that exists: the open error says it'
    assert absent_port_hint('socket://rig.lab:7000', []) == '', "a URL is pyserial's to judge"
    assert all(isinstance(p, str) for p in serial_ports_present())
