"""Network addresses given on the command line (pure: no sockets, no rclpy): ``--listen``,
``--port`` and ``up --console [LISTEN:]PORT``. Shared by ``up`` (its console process) and the
lab console and bridge (rwpend_console)."""
from __future__ import annotations

import ipaddress


def parse_listen(text: str) -> str:
    """``--listen`` value: an IPv4/IPv6 address or ``localhost``; ValueError with the reason."""
    text = (text or '').strip()
    if text == 'localhost':
        return '127.0.0.1'
    try:
        return str(ipaddress.ip_address(text.strip('[]')))
    except ValueError:
        raise ValueError(f'--listen expects an IP address (127.0.0.1, 0.0.0.0, ::, or one of this '
                         f"machine's addresses), got {text!r}") from None


def parse_port(text) -> int:
    """A TCP port, 1..65535; ValueError with the reason."""
    try:
        port = int(str(text), 10)
    except ValueError:
        raise ValueError(f'a port is an integer in 1..65535, got {text!r}') from None
    if not 1 <= port <= 65535:
        raise ValueError(f'a port is an integer in 1..65535, got {port}')
    return port


def parse_console_address(text: str) -> tuple[str, int]:
    """``up --console`` value: 'PORT', 'LISTEN:PORT' or '[IPv6]:PORT' -> (listen, port)."""
    text = str(text).strip()
    if text.startswith('['):
        host, sep, port = text[1:].partition(']:')
    elif text.count(':') == 1:
        host, sep, port = text.partition(':')
    else:
        host, sep, port = '127.0.0.1', ':', text
    if not sep:
        raise ValueError(f'--console expects [LISTEN:]PORT (e.g. 8080 or 0.0.0.0:8080), got {text!r}')
    try:
        return parse_listen(host), parse_port(port)
    except ValueError as exc:
        raise ValueError(f'--console {text}: {exc}') from None
