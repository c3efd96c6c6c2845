"""``./rwpend console``: the lab console, a web page served from this package.

    ./rwpend console [--ns /rwpend] [--port 8080] [--listen 127.0.0.1] [--domain ID ...]
                     [--rate 50] [--window 20] [--bags DIR] [--bridge-port 8765 | --no-bridge]

Its own process. Its work is bounded by design (it polls the rig's state at 200 Hz, decimated,
only while a page watches: rwpend_console.rosside), so it never makes the loop wait. Its
priority: SCHED_FIFO :data:`CONSOLE_RT_PRIORITY` where permitted (``--rt-priority``; ``up
--console`` gives it the loop's priority less 40 in real time, ordinary priority in lockstep):
below the loop (50) and the recorder (40), above every ordinary program -- on a busy machine an
e-stop from the page must not wait for the CPU behind them (at nice 10 the console took over a
minute to start on our loaded 2-core VM).
"""
from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import threading
from pathlib import Path

from rwpend_bringup.addresses import parse_listen, parse_port

from .access import AccessPolicy, check_token_text, new_token

DEFAULT_PORT = 8080
DEFAULT_BRIDGE_PORT = 8765
DEFAULT_NS = '/rwpend'
DEFAULT_BAGS = Path(os.environ.get('RWPEND_ROOT', Path.cwd())) / 'bags'
DEFAULT_LAB = Path(os.environ.get('RWPEND_ROOT', Path.cwd())) / 'lab_out'
#: the console's SCHED_FIFO priority where permitted (the loop runs at 50, the recorder at 40)
CONSOLE_RT_PRIORITY = 10


class Parser(argparse.ArgumentParser):
    def error(self, message):
        self.print_usage(sys.stderr)
        print(f'{self.prog}: error: {message}', file=sys.stderr)
        raise SystemExit(2)


def argtype(fn):
    """An argparse type from a parser that raises ValueError with the reason (said as it is)."""
    def parse(text):
        try:
            return fn(text)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None
    return parse


def _within(cast, lo, hi, what: str):
    """A parser of ``cast(text)`` in [lo, hi]; ValueError naming ``what`` and the range."""
    def parse(text):
        v = cast(text)
        if not lo <= v <= hi:
            raise ValueError(f'{what} in {lo}..{hi}, got {text}')
        return v
    return parse


_rate = _within(float, 1, 500, 'a rate (Hz)')
_window = _within(float, 5, 120, 'a window (s)')
_domain = _within(int, 0, 232, 'a ROS domain id')


def _ns(text) -> str:
    from .rigs import _NS_RE
    ns = '/' + text.strip('/')
    if not _NS_RE.fullmatch(ns):
        raise ValueError(f'invalid namespace {text!r} (letters, digits, _; e.g. /rig2)')
    return ns


def parser() -> Parser:
    p = Parser(prog='rwpend console', description='The lab console: the rig in a web browser (live '
               'plots, mode, tap, record, gains, e-stop, diagnostics, bags, every rig of the lab) and '
               'the Foxglove bridge.')
    p.add_argument('--ns', type=argtype(_ns), default=DEFAULT_NS, help=f'the rig opened first (default {DEFAULT_NS})')
    p.add_argument('--port', type=argtype(parse_port), default=DEFAULT_PORT, help=f'HTTP port (default {DEFAULT_PORT})')
    p.add_argument('--listen', type=argtype(parse_listen), default='127.0.0.1',
                   help='address to listen on (default 127.0.0.1: this machine only); any other (e.g. '
                   '0.0.0.0) needs the token printed at start for every request that acts (the e-stop '
                   'excepted)')
    p.add_argument('--token', type=argtype(check_token_text), default=None,
                   help='the token (default: a new random one each start)')
    p.add_argument('--domain', type=argtype(_domain), action='append', default=None, metavar='ID',
                   help='ROS domain to watch (repeatable; default: ROS_DOMAIN_ID)')
    p.add_argument('--rate', type=argtype(_rate), default=50.0,
                   help='samples per second of sample time sent to the page per signal (default 50)')
    p.add_argument('--window', type=argtype(_window), default=20.0, help='seconds shown (default 20)')
    p.add_argument('--bags', type=Path, default=DEFAULT_BAGS, help=f'the bags folder (default {DEFAULT_BAGS})')
    p.add_argument('--bridge-port', type=argtype(parse_port), default=DEFAULT_BRIDGE_PORT,
                   help=f'port of the Foxglove bridge (default {DEFAULT_BRIDGE_PORT})')
    p.add_argument('--no-bridge', action='store_true', help='do not start the Foxglove bridge')
    p.add_argument('--lab', type=Path, default=DEFAULT_LAB,
                   help=f'folder of the lab experiments started from the page (default {DEFAULT_LAB})')
    p.add_argument('--lab-domain', type=argtype(_domain), default=None, metavar='ID',
                   help='ROS domain of those experiments, one the console does not watch (default: the '
                   'first after the watched ones)')
    p.add_argument('--rt-priority', type=argtype(_priority), default=None, metavar='N',
                   help=f'SCHED_FIFO priority (0: ordinary; default {CONSOLE_RT_PRIORITY} where permitted, '
                   'or RWPEND_RT_PRIORITY as ./rwpend up sets it): keep it below the loop\'s (50)')
    return p


def _priority(text) -> int:
    v = int(text)
    if not 0 <= v <= 99:
        raise ValueError(f'a priority in 0..99, got {text}')
    return v


def apply_priority(given: int | None) -> str:
    """The console's scheduling (see the module's docstring); returns what was done, in words."""
    from rwpend_ros.sched import apply_scheduling, realtime_permitted
    env = os.environ.get('RWPEND_RT_PRIORITY', '').strip()
    prio = given if given is not None else int(env) if env.isdigit() else None
    if prio is None:
        prio = CONSOLE_RT_PRIORITY if realtime_permitted(CONSOLE_RT_PRIORITY)[0] else 0
    if not prio:
        return 'ordinary priority'
    done = apply_scheduling({'RWPEND_RT_PRIORITY': str(prio)})
    return f'real-time priority {prio}' if done.get('rt') == prio else f'ordinary priority ({done.get("rt")})'


def _die_with_parent() -> None:  # pragma: no cover - runs in the child
    import ctypes
    try:
        ctypes.CDLL('libc.so.6').prctl(1, signal.SIGTERM)   # PR_SET_PDEATHSIG
    except OSError:
        pass


def start_bridge(a) -> subprocess.Popen:
    cmd = [sys.executable, '-u', '-m', 'rwpend_console.bridge', '--port', str(a.bridge_port),
           '--listen', a.listen]
    env = dict(os.environ, ROS_DOMAIN_ID=str(a.domain[0]))
    return subprocess.Popen(cmd, env=env, stdin=subprocess.DEVNULL, preexec_fn=_die_with_parent)


def browse_host(listen: str) -> str:
    """The host to open for a console listening on ``listen`` (any address: this machine's)."""
    if listen in ('0.0.0.0', '::'):
        return '127.0.0.1'
    return f'[{listen}]' if ':' in listen else listen


def url(listen: str, port: int, rig: str, token: str | None) -> str:
    """The page's address: ``http://HOST:PORT/?rig=...[&token=...]``."""
    from urllib.parse import urlencode
    query = {'rig': rig, **({'token': token} if token else {})}
    return f'http://{browse_host(listen)}:{port}/?{urlencode(query, safe="/:")}'


def main(argv=None) -> int:
    a = parser().parse_args(sys.argv[1:] if argv is None else argv)
    if a.domain is None:
        try:
            a.domain = [_domain(os.environ.get('ROS_DOMAIN_ID', '0') or '0')]
        except ValueError as exc:
            return _fail(f'ROS_DOMAIN_ID: {exc}')
    from .labruns import lab_domain
    try:
        a.lab_domain = lab_domain(a.domain, a.lab_domain)
    except ValueError as exc:
        return _fail(str(exc))
    policy = AccessPolicy(a.listen, a.token or new_token())
    a.priority = apply_priority(a.rt_priority)   # before rclpy: the DDS threads inherit it
    from rwpend_ros.transport import apply_transport_or_exit
    apply_transport_or_exit()   # UDP, as every node of the stack (before the first context)
    from .app import ConsoleApp
    from .labruns import LabRuns
    from .rosside import DomainWatcher
    from .web import ConsoleServer, make_handler
    watchers = {d: DomainWatcher(d, a.rate) for d in dict.fromkeys(a.domain)}
    app = ConsoleApp(watchers, a.bags, a.window, LabRuns(a.lab, a.lab_domain))
    try:
        server = ConsoleServer(a.listen, a.port, make_handler(app, policy))
    except OSError as exc:
        _close(app, watchers)
        return _fail(f'cannot listen on {a.listen}:{a.port} ({exc.strerror or exc}); choose another '
                     '--port', 1)
    for w in watchers.values():
        w.start()
    bridge = None if a.no_bridge else start_bridge(a)
    _announce(a, policy, bridge)
    return _serve(server, app, watchers, bridge)


def _announce(a, policy: AccessPolicy, bridge) -> None:
    token = policy.token if policy.token_required else None
    print(f'rwpend console: {url(a.listen, a.port, f"{a.domain[0]}:{a.ns}", token)}', flush=True)
    print(f'rwpend console: watching domain(s) {", ".join(map(str, a.domain))}; bags in {a.bags}; '
          f'{a.priority}', flush=True)
    print(f'rwpend console: lab experiments in {a.lab} on domain {a.lab_domain}', flush=True)
    if policy.token_required:
        print(f'rwpend console: listening on {a.listen}: requests that act need the token {policy.token} '
              '(the e-stop does not)', flush=True)
    if bridge is not None:
        print(f'rwpend console: Foxglove bridge on ws://{browse_host(a.listen)}:{a.bridge_port}', flush=True)


def _serve(server, app, watchers, bridge) -> int:
    stop = threading.Event()

    def on_signal(signum, frame):  # noqa: ARG001
        stop.set()
        threading.Thread(target=server.shutdown, daemon=True).start()
    for s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(s, on_signal)
    try:
        server.serve_forever(poll_interval=0.2)
    finally:
        server.server_close()
        if bridge is not None and bridge.poll() is None:
            bridge.send_signal(signal.SIGINT)
        _close(app, watchers)
        if bridge is not None:
            try:
                bridge.wait(timeout=5.0)
            except subprocess.TimeoutExpired:
                bridge.kill()
    return 0


def _close(app, watchers) -> None:
    app.close()
    for w in watchers.values():
        w.close()


def _fail(msg: str, status: int = 2) -> int:
    print(f'rwpend console: error: {msg}', file=sys.stderr, flush=True)
    return status


if __name__ == '__main__':
    sys.exit(main())
