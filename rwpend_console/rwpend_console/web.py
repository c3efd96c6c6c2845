"""The console's web server (Python's http.server; every asset from this package's ``static``).

Routes (JSON unless said otherwise; the action decides what access needs,
:mod:`rwpend_console.access`):

| method, path | action | what |
|---|---|---|
| GET ``/`` , ``/static/NAME`` | view | the page, its script and style |
| GET ``/api/info`` | view | whether acting needs the token; the plots' window |
| GET ``/api/overview`` | view | every rig of the watched domains: mode, health, e-stop |
| GET ``/api/rig?rig=ID`` | view | its nodes, lights, e-stop state, recording |
| GET ``/api/params?rig=ID&node=N`` | view | the gains panel of a node |
| GET ``/api/modes?rig=ID`` | view | the mode buttons (``law`` usable with the controller's
  ``law.file``) |
| GET ``/api/stream?rig=ID`` | view | Server-Sent Events: ``frame`` (decimated samples, every
  :data:`FRAME_PERIOD_S`), ``status`` (lights, overview, every :data:`STATUS_PERIOD_S`) |
| GET ``/api/bags``, ``/api/plot?bag=NAME`` | view | the bags folder, a bag's analysis (PNG) |
| GET ``/api/lab``, ``/lab/report?run=NAME`` | view | the lab's experiments and runs, a run's
  report (HTML) |
| POST ``/api/design`` | view | the gains a design gives (nothing set) |
| POST ``/api/param``, ``/api/mode``, ``/api/tap``, ``/api/record``, ``/api/analyze``,
  ``/api/estop/clear``, ``/api/lab/run``, ``/api/lab/stop`` | change | act on the rig, the folder or
  the lab |
| POST ``/api/estop`` | estop | raise the e-stop: always allowed |

Each connection has its own thread: an e-stop never waits behind a slow parameter call.
"""
from __future__ import annotations

import json
import math
import socket
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from urllib.parse import parse_qs, urlsplit

from .access import CHANGE, ESTOP, VIEW, AccessPolicy
from .app import ConsoleApp, RequestError

STATIC_DIR = Path(__file__).resolve().parent / 'static'
CONTENT_TYPES = {'.html': 'text/html; charset=utf-8', '.js': 'text/javascript; charset=utf-8',
                 '.css': 'text/css; charset=utf-8', '.png': 'image/png', '.svg': 'image/svg+xml'}
FRAME_PERIOD_S = 0.04
STATUS_PERIOD_S = 0.5
#: the largest request body taken (a parameter set is a few hundred bytes)
MAX_BODY = 64 * 1024

GET_ROUTES = {
    '/api/overview': lambda app, q: app.overview(),
    '/api/rig': lambda app, q: app.rig_info(q.get('rig')),
    '/api/params': lambda app, q: app.params(q.get('rig'), q.get('node')),
    '/api/modes': lambda app, q: app.modes(q.get('rig')),
    '/api/bags': lambda app, q: app.bag_list(),
    '/api/lab': lambda app, q: app.lab_state(),
}
POST_ROUTES = {
    '/api/design': (VIEW, lambda app, b: app.design(b)),
    '/api/param': (CHANGE, lambda app, b: app.set_param(b)),
    '/api/mode': (CHANGE, lambda app, b: app.mode(b)),
    '/api/tap': (CHANGE, lambda app, b: app.tap(b)),
    '/api/record': (CHANGE, lambda app, b: app.record(b)),
    '/api/analyze': (CHANGE, lambda app, b: app.analyze(b)),
    '/api/lab/run': (CHANGE, lambda app, b: app.lab_run(b)),
    '/api/lab/stop': (CHANGE, lambda app, b: app.lab_stop(b)),
    '/api/estop': (ESTOP, lambda app, b: app.estop(b, True)),
    '/api/estop/clear': (CHANGE, lambda app, b: app.estop(b, False)),
}


def finite(obj):
    """``obj`` with NaN and infinities as None (JSON has no such numbers)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite(v) for v in obj]
    return obj


def to_json(obj) -> bytes:
    return json.dumps(finite(obj), separators=(',', ':')).encode()


class ConsoleHandler(BaseHTTPRequestHandler):
    """The request handler of a console: routes, access checks and the event stream. Its
    subclass made by :func:`make_handler` binds the app, the access policy and the assets."""
    app: ConsoleApp
    policy: AccessPolicy
    statics: dict[str, Path]
    protocol_version = 'HTTP/1.1'
    server_version = 'rwpend-console'

    def log_message(self, fmt, *args):   # quiet: errors only (log_error)
        pass

    def _send(self, status: int, body: bytes, ctype: str = 'application/json') -> None:
        self.send_response(status)
        self.send_header('Content-Type', ctype)
        self.send_header('Content-Length', str(len(body)))
        self.send_header('Cache-Control', 'no-store')
        self.send_header('X-Content-Type-Options', 'nosniff')
        self.end_headers()
        self.wfile.write(body)

    def _refuse(self, status: int, reason: str) -> None:
        self._send(status, to_json({'ok': False, 'error': reason}))

    def _allowed(self, action: str) -> bool:
        v = self.policy.check(action, self.command, dict(self.headers.items()))
        if not v.ok:
            self._refuse(v.status, v.reason)
        return v.ok

    def do_GET(self) -> None:
        url = urlsplit(self.path)
        query = {k: v[-1] for k, v in parse_qs(url.query).items()}
        if not self._allowed(VIEW):
            return
        if url.path in ('/', '/index.html'):
            return self._send(200, self.statics['index.html'].read_bytes(), CONTENT_TYPES['.html'])
        if url.path.startswith('/static/') and url.path[8:] in self.statics:
            f = self.statics[url.path[8:]]
            return self._send(200, f.read_bytes(), CONTENT_TYPES[f.suffix])
        if url.path == '/api/stream':
            return self._stream(query.get('rig'))
        if url.path == '/api/info':
            return self._send(200, to_json({'token_required': self.policy.token_required,
                                            'listen': self.policy.listen, 'window_s': self.app.window_s}))
        try:
            if url.path == '/api/plot':
                return self._send(200, self.app.plot(query.get('bag')).read_bytes(), 'image/png')
            if url.path == '/lab/report':
                return self._send(200, self.app.lab_report(query.get('run')).read_bytes(), CONTENT_TYPES['.html'])
            if url.path in GET_ROUTES:
                return self._send(200, to_json(GET_ROUTES[url.path](self.app, query)))
        except RequestError as exc:
            return self._refuse(exc.status, exc.reason)
        self._refuse(404, f'no such page: {url.path}')

    def do_POST(self) -> None:
        path = urlsplit(self.path).path
        self.close_connection = True     # until the body is read: a refusal leaves it unread
        if path not in POST_ROUTES:
            return self._refuse(404, f'no such request: {path}')
        action, fn = POST_ROUTES[path]
        if not self._allowed(action):
            return
        try:
            n = int(self.headers.get('Content-Length', '0'))
        except ValueError:
            n = -1
        if not 0 <= n <= MAX_BODY:
            return self._refuse(413, f'a request body of 0..{MAX_BODY} bytes, with Content-Length')
        data = self.rfile.read(n)
        self.close_connection = False
        try:
            body = json.loads(data or b'{}')
        except ValueError as exc:
            return self._refuse(400, f'the body is not JSON: {exc}')
        try:
            self._send(200, to_json(fn(self.app, body)))
        except RequestError as exc:
            self._refuse(exc.status, exc.reason)

    def _stream(self, rig) -> None:
        try:
            w, ns, rid = self.app.rig(rig)
        except RequestError as exc:
            return self._refuse(exc.status, exc.reason)
        self.close_connection = True
        self.send_response(200)
        self.send_header('Content-Type', 'text/event-stream')
        self.send_header('Cache-Control', 'no-store')
        self.send_header('Connection', 'close')
        self.end_headers()
        feed = w.watch(ns)
        try:
            stream_events(self.wfile, self.app, feed, rid)
        except (BrokenPipeError, ConnectionError, socket.timeout, OSError):
            pass
        finally:
            w.unwatch(ns)


def make_handler(app: ConsoleApp, policy: AccessPolicy, static_dir: Path = STATIC_DIR):
    """The request handler class of one console (bound to its app and policy)."""
    statics = {f.name: f for f in static_dir.iterdir() if f.suffix in CONTENT_TYPES}
    return type('Handler', (ConsoleHandler,), {'app': app, 'policy': policy, 'statics': statics})


def event(name: str, obj) -> bytes:
    return b'event: ' + name.encode() + b'\ndata: ' + to_json(obj) + b'\n\n'


def stream_events(out, app: ConsoleApp, feed, rid: str) -> None:
    """Until the page goes away: new samples every FRAME_PERIOD_S, the lights and the
    overview every STATUS_PERIOD_S (the first of each at once)."""
    cursor, gen, last_status = None, None, 0.0
    while True:
        batch, cursor = feed.since(cursor, app.window_s, gen)
        gen = batch['gen']
        now = time.monotonic()
        batch['sent_ms'] = time.time() * 1e3
        if batch['reset'] or batch['s'] or batch['u'] or batch['a'] or batch['b']:
            out.write(event('frame', batch))
        if now - last_status >= STATUS_PERIOD_S:
            last_status = now
            try:
                status = {'rig': app.rig_info(rid), 'overview': app.overview()}
            except RequestError as exc:
                status = {'error': exc.reason}
            out.write(event('status', status))
        out.flush()
        time.sleep(FRAME_PERIOD_S)


class ConsoleServer(ThreadingHTTPServer):
    daemon_threads = True
    allow_reuse_address = True

    def handle_error(self, request, client_address) -> None:
        """A page that went away mid-request is no error worth a traceback."""
        import sys
        if not isinstance(sys.exc_info()[1], (ConnectionError, socket.timeout)):
            super().handle_error(request, client_address)

    def __init__(self, listen: str, port: int, handler) -> None:
        self.address_family = socket.AF_INET6 if ':' in listen else socket.AF_INET
        super().__init__((listen, port), handler)
