"""Who may do what on the console (pure: no sockets, no rclpy).

Safe by default:

* The console listens on 127.0.0.1. Only users of this machine reach it; a request must name
  this machine in its ``Host`` header (``127.0.0.1``, ``localhost``, ``[::1]``): a web page of
  another site that makes the browser resolve its own name to 127.0.0.1 (DNS rebinding) is
  refused.
* Listening on any other address (``--listen 0.0.0.0``), every state-changing request (mode,
  tap, gains, recording, analysis, clearing the e-stop) needs the token the console prints at
  its start: the header ``X-Rwpend-Token`` (the page takes it from ``?token=`` in its address).
* Every state-changing request is a POST of JSON (``Content-Type: application/json``) whose
  ``Origin``, when the browser sends one, is the console itself: another site's page cannot
  make a visitor's browser send one (a cross-site JSON POST needs a CORS pre-flight, which the
  console never grants).
* Raising the e-stop is always allowed: no token, any origin, any address.
"""
from __future__ import annotations

import hmac
import ipaddress
import re
import secrets
from dataclasses import dataclass
from typing import Mapping
from urllib.parse import urlsplit

from rwpend_bringup.addresses import parse_listen

#: what a request does
VIEW = 'view'          # read: the page, the stream, parameters, bags, a design preview
ESTOP = 'estop'        # raise the e-stop: always allowed
CHANGE = 'change'      # anything that changes the rig or the disk

TOKEN_HEADER = 'X-Rwpend-Token'
_TOKEN_RE = re.compile(r'[A-Za-z0-9_-]{16,128}')
_LOCAL_NAMES = {'localhost', '127.0.0.1', '::1'}


def new_token() -> str:
    """A random token (22 URL-safe characters, 128 bits)."""
    return secrets.token_urlsafe(16)


def check_token_text(token: str) -> str:
    """A token given by the user (``--token``): 16-128 characters of A-Z a-z 0-9 _ -."""
    if not isinstance(token, str) or not _TOKEN_RE.fullmatch(token):
        raise ValueError('a token is 16-128 characters of A-Z, a-z, 0-9, _ and -')
    return token


def is_loopback(address: str) -> bool:
    try:
        return ipaddress.ip_address(address.strip('[]')).is_loopback
    except ValueError:
        return address == 'localhost'


def host_name(host_header: str) -> str:
    """The host part of a ``Host`` header (``[::1]:8080`` -> ``::1``, ``a:80`` -> ``a``)."""
    h = (host_header or '').strip().lower()
    if h.startswith('['):
        return h[1:h.find(']')] if ']' in h else h[1:]
    return h.rsplit(':', 1)[0] if h.count(':') == 1 else h


@dataclass(frozen=True)
class Verdict:
    ok: bool
    status: int = 200      # the HTTP status of a refusal
    reason: str = ''


class AccessPolicy:
    """The rules above for one console: ``listen`` is the address it listens on, ``token`` the
    token printed at its start."""

    def __init__(self, listen: str, token: str) -> None:
        self.listen = parse_listen(listen)
        self.token = check_token_text(token)
        self.token_required = not is_loopback(self.listen)

    def check(self, action: str, method: str, headers: Mapping[str, str]) -> Verdict:
        """May a request (``headers``: name -> value, any case) do ``action``?"""
        h = {k.lower(): v for k, v in headers.items()}
        if action == ESTOP:
            return Verdict(True)
        if not self.token_required and host_name(h.get('host', '')) not in _LOCAL_NAMES:
            return Verdict(False, 421, 'this console serves this machine only (it listens on '
                           f'{self.listen}); open it as http://127.0.0.1:PORT/')
        if action == VIEW and method == 'GET':
            return Verdict(True)
        if method != 'POST':
            return Verdict(False, 405, 'requests that act are POST requests')
        if h.get('content-type', '').split(';')[0].strip().lower() != 'application/json':
            return Verdict(False, 415, 'requests that act send JSON (Content-Type: application/json)')
        origin = h.get('origin')
        if origin and origin != 'null' and urlsplit(origin).netloc.lower() != h.get('host', '').lower():
            return Verdict(False, 403, f'request from another site ({origin}) refused')
        if action == VIEW or not self.token_required:
            return Verdict(True)
        if hmac.compare_digest(h.get(TOKEN_HEADER.lower(), '').encode(), self.token.encode()):
            return Verdict(True)
        return Verdict(False, 403, f'this console listens on {self.listen}: changing the rig needs the '
                       'token printed when the console started (open the page with ?token=TOKEN); '
                       'the e-stop works without it')
