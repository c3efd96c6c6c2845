"""The serial port of the link, read and written without ever blocking the caller.

pyserial opens and configures the port (raw 8N1, baud rate, an exclusive lock); after that the
link uses the port's file descriptor directly: ``poll`` to wait for bytes (releasing the GIL
while it waits), ``os.read`` for everything that is there, ``os.write`` that takes what the
port can take now. pyserial's own ``read``/``write`` are not used on the hot path: its read
waits for a byte count or a timeout rather than a frame, and its ``write`` with a
``write_timeout`` polls for writability after every write and can block the writer (the
command callback) for the whole timeout while holding the link's lock (seen: "Write timeout",
then the link lost).

A transport for :class:`rwpend_driver.link.DriverLink` has this interface (tests use fakes):

* ``wait(timeout) -> bool``: bytes (or an error) are there to read, after at most ``timeout`` s;
* ``read() -> bytes``: what is there now (``b''``: nothing); OSError when the port is gone;
* ``write(data) -> int``: bytes the port took now (0 when its buffer is full); OSError when gone;
* ``flush_input()``: drop what arrived before now; ``close()``.

Pure Python (os, select, termios; pyserial only to open), no rclpy.
"""
from __future__ import annotations

import errno
import os
import select
import termios

#: largest read; a pty delivers at most 4095 bytes per read
READ_SIZE = 16384
_GONE = select.POLLHUP | select.POLLERR | select.POLLNVAL


class FdPort:
    """A non-blocking transport on a file descriptor the caller opened (a tty, a pty slave)."""

    def __init__(self, fd: int, owner=None) -> None:
        self.fd = fd
        self.owner = owner             # what closes the fd (a pyserial Serial), or None: os.close
        os.set_blocking(fd, False)
        self.poller = select.poll()
        self.poller.register(fd, select.POLLIN)
        self.hangup = False

    def wait(self, timeout: float) -> bool:
        """True when a read will return bytes or fail, after at most ``timeout`` s."""
        try:
            events = self.poller.poll(max(0.0, timeout) * 1000.0)
        except InterruptedError:
            return False
        if not events:
            return False
        if events[0][1] & _GONE:
            self.hangup = True
        return True

    def read(self) -> bytes:
        """Everything that is there now; OSError when the device is gone (hang-up, EIO)."""
        out = b''
        while True:
            try:
                data = os.read(self.fd, READ_SIZE)
            except BlockingIOError:
                break
            if not data:               # end of file: the other side is gone
                raise OSError(errno.EIO, 'device disconnected (end of file)')
            out += data
            if len(data) < READ_SIZE:
                break
        if not out and self.hangup:
            raise OSError(errno.EIO, 'device disconnected (hang-up)')
        return out

    def write(self, data: bytes) -> int:
        """Bytes written now (maybe fewer than given, 0 when the port's buffer is full)."""
        try:
            return os.write(self.fd, data)
        except BlockingIOError:
            return 0

    def flush_input(self) -> None:
        try:
            termios.tcflush(self.fd, termios.TCIFLUSH)
        except termios.error:
            pass                       # not a tty: nothing buffered by a line discipline
        try:
            for _ in range(64):        # bounded: a device streams on while this reads
                if not os.read(self.fd, READ_SIZE):
                    break
        except OSError:                # BlockingIOError: empty; EIO: the next read reports it
            pass

    def close(self) -> None:
        fd, self.fd = self.fd, -1
        if fd < 0:
            return
        try:
            self.poller.unregister(fd)
        except (KeyError, ValueError):
            pass
        if self.owner is not None:
            self.owner.close()
        else:
            os.close(fd)


def serial_opener(port: str, baud: int) -> FdPort:
    """Open the rig's port with pyserial (raw 8N1 at ``baud``, exclusive), used through its fd."""
    import serial  # pyserial; imported here so the pure tests need no serial port
    s = serial.Serial(port, baud, timeout=0, write_timeout=0, exclusive=True)
    return FdPort(s.fileno(), owner=s)


def absent_port_hint(port: str, present: list[str]) -> str:
    """What to tell the user when ``port`` could not be opened: '' unless ``port`` is a path
    that does not exist (a URL such as ``socket://`` or ``rfc2217://`` is pyserial's to judge);
    else the serial ports ``present`` (:func:`serial_ports_present`), or that there is none."""
    if not port.startswith('/') or os.path.exists(port):
        return ''
    if present:
        return f'{port} does not exist; serial ports present: {", ".join(sorted(present))}'
    return (f'{port} does not exist and no serial port is present: is the rig plugged in and powered '
            '(or, without a rig, ./rwpend emulate --link PATH and --plant serial:PATH)?')


def serial_ports_present() -> list[str]:
    """The serial devices this host has now (pyserial's listing: USB and on-board ports); []
    when the listing fails (it only adds to an error message)."""
    try:
        from serial.tools import list_ports
        return [p.device for p in list_ports.comports()]
    except Exception:  # noqa: BLE001 - a hint, never a second failure
        return []
