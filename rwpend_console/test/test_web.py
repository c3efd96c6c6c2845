"""The web server's routing and access checks, with a stand-in for the console's app (no ROS)."""
import http.client
import json
import threading

import pytest

from rwpend_console.access import AccessPolicy
from rwpend_console.app import RequestError
from rwpend_console.feed import Feed
from rwpend_console.web import ConsoleServer, finite, make_handler

TOKEN = 'abcdefghijklmnop_1234'


class FakeWatcher:
    def __init__(self):
        self.feed = Feed()
        self.watching = 0

    def watch(self, ns):
        self.watching += 1
        return self.feed

    def unwatch(self, ns):
        self.watching -= 1


class FakeApp:
    window_s = 20.0

    def __init__(self):
        self.calls = []
        self.w = FakeWatcher()

    def rig(self, text):
        if text != '0:/rwpend':
            raise RequestError(f'a rig is DOMAIN:/NAMESPACE, got {text!r}')
        return self.w, '/rwpend', text

    def overview(self):
        return {'rigs': []}

    def rig_info(self, rig):
        return {'id': rig, 'lights': [], 'summary': {}, 'nodes': [],
                'estop': {'state': 'clear', 'text': 'e-stop clear (sim reports)', 'pending': ''}}

    def modes(self, rig):
        self.rig(rig)
        return {'modes': [{'mode': 'law', 'usable': False, 'help': 'needs a law'}]}

    def mode(self, body):
        self.calls.append(('mode', body))
        if body.get('mode') == 'bad':
            raise RequestError('mode: one of off, auto, got bad')
        return {'ok': True, 'message': f"mode {body['mode']}", 'nan': float('nan')}

    def estop(self, body, on):
        self.calls.append(('estop', on))
        return {'ok': True, 'on': on}


@pytest.fixture
def server(request):
    listen = getattr(request, 'param', '127.0.0.1')
    app = FakeApp()
    srv = ConsoleServer(listen, 0, make_handler(app, AccessPolicy(listen, TOKEN)))
    t = threading.Thread(target=srv.serve_forever, kwargs={'poll_interval': 0.05}, daemon=True)
    t.start()
    yield app, srv.server_address[1]
    srv.shutdown()
    srv.server_close()


def req(port, method, path, body=None, headers=None):
    c = http.client.HTTPConnection('127.0.0.1', port, timeout=10)
    h = {'Host': f'127.0.0.1:{port}', **(headers or {})}
    data = None
    if body is not None:
        data = json.dumps(body).encode() if not isinstance(body, bytes) else body
        h.setdefault('Content-Type', 'application/json')
    c.request(method, path, body=data, headers=h)
    r = c.getresponse()
    out = r.status, r.getheader('Content-Type'), r.read()
    c.close()
    return out


def test_page_and_assets(server):
    _, port = server
    status, ctype, body = req(port, 'GET', '/')
    assert status == 200 and 'text/html' in ctype and b'E-STOP' in body
    assert b'<script src="/static/console.js">' in body and b'http' not in body.replace(b'http-equiv', b'')
    status, ctype, body = req(port, 'GET', '/static/console.js')
    assert status == 200 and 'javascript' in ctype and b'EventSource' in body
    assert req(port, 'GET', '/static/../web.py')[0] == 404
    assert req(port, 'GET', '/nothing')[0] == 404


def test_actions_need_json_and_answer_reasons(server):
    app, port = server
    status, _, body = req(port, 'POST', '/api/mode', {'rig': '0:/rwpend', 'mode': 'auto'})
    assert status == 200 and json.loads(body) == {'ok': True, 'message': 'mode auto', 'nan': None}
    status, _, body = req(port, 'POST', '/api/mode', {'rig': '0:/rwpend', 'mode': 'bad'})
    assert status == 400 and 'one of' in json.loads(body)['error']
    assert req(port, 'POST', '/api/mode', b'{}', {'Content-Type': 'text/plain'})[0] == 415
    assert req(port, 'POST', '/api/mode', b'{not json')[0] == 400
    assert req(port, 'POST', '/api/mode', b'x' * 70000)[0] == 413
    assert req(port, 'GET', '/api/mode')[0] == 404
    assert req(port, 'POST', '/api/unknown', {})[0] == 404
    assert len(app.calls) == 2


def test_other_host_names_are_refused_on_the_loopback(server):
    _, port = server
    status, _, body = req(port, 'GET', '/', headers={'Host': 'attacker.example'})
    assert status == 421 and b'this machine only' in body


@pytest.mark.parametrize('server', ['0.0.0.0'], indirect=True)
def test_a_shared_console_needs_the_token_except_for_the_estop(server):
    app, port = server
    status, _, body = req(port, 'POST', '/api/mode', {'rig': '0:/rwpend', 'mode': 'auto'})
    assert status == 403 and b'token' in body and app.calls == []
    status, _, _ = req(port, 'POST', '/api/mode', {'rig': '0:/rwpend', 'mode': 'auto'}, {'X-Rwpend-Token': TOKEN})
    assert status == 200
    assert req(port, 'POST', '/api/estop', {'rig': '0:/rwpend'})[0] == 200
    assert req(port, 'POST', '/api/estop/clear', {'rig': '0:/rwpend'})[0] == 403
    assert app.calls[-1] == ('estop', True)
    info = json.loads(req(port, 'GET', '/api/info')[2])
    assert info['token_required'] is True


def test_stream_sends_frames_and_status_and_lets_go(server):
    app, port = server
    app.w.feed.add_state(1_000_000_000, 2_000_000_000, 0.1, 0.2, 0.3, 0.4)
    app.w.feed.add_applied(1_000_000_000, -5e-324)
    c = http.client.HTTPConnection('127.0.0.1', port, timeout=10)
    c.request('GET', '/api/stream?rig=0:/rwpend', headers={'Host': f'127.0.0.1:{port}'})
    r = c.getresponse()
    assert r.status == 200 and r.getheader('Content-Type') == 'text/event-stream'
    events = {}
    while len(events) < 2:
        line = r.fp.readline().decode()
        if line.startswith('event: '):
            name = line[7:].strip()
            events[name] = json.loads(r.fp.readline().decode()[6:])
    assert events['frame']['s'] == [[1.0, 0.1, 0.2, 0.3, 0.4, 2000.0]] and events['status']['rig']['id'] == '0:/rwpend'
    assert events['frame']['a'] == [[1.0, 0.0]], 'the applied command, its subnormal leftover as 0'
    assert events['status']['rig']['estop']['state'] == 'clear'
    assert app.w.watching == 1
    c.close()
    assert req(port, 'GET', '/api/stream?rig=nonsense')[0] == 400


def test_finite():
    assert finite({'a': [1.0, float('inf'), {'b': float('nan')}], 'c': 'x'}) == {'a': [1.0, None, {'b': None}], 'c': 'x'}


def test_mode_buttons_route(server):
    _, port = server
    status, _, body = req(port, 'GET', '/api/modes?rig=0:/rwpend')
    assert status == 200 and json.loads(body)['modes'][0] == {'mode': 'law', 'usable': False, 'help': 'needs a law'}
    assert req(port, 'GET', '/api/modes?rig=nonsense')[0] == 400


def test_the_page_has_the_new_parts(server):
    """The e-stop state, the applied-command readout, the mode note; the script formats numbers."""
    _, port = server
    page = req(port, 'GET', '/')[2]
    for part in (b'id="estop-state"', b'id="readout-applied"', b'id="mode-note"', b'id="lights"'):
        assert part in page, part
    js = req(port, 'GET', '/static/console.js')[2]
    assert b'rwpendFormat' in js and b"'law'" in js and b'/api/modes' in js
