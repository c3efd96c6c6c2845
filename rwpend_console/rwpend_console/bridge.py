"""``./rwpend bridge``: the rig over the Foxglove WebSocket protocol (``foxglove-sdk``), so
Foxglove or Lichtblick opens ``ws://HOST:8765`` and sees it.

    ./rwpend bridge [--port 8765] [--listen 127.0.0.1] [--ns NS] [--max-rate 100]

* **Topics**: every topic of the domain (or of ``--ns`` and ``/diagnostics``, ``/clock``) is a
  channel: its CDR bytes as they came over DDS (no re-encoding), ``cdr`` encoding, with the
  full ``ros2msg`` definition as schema (:mod:`rwpend_console.schemas`). A topic is subscribed
  (best effort, polled: :mod:`rwpend_console.taps`) only while a client subscribes to it, and
  forwarded at ``--max-rate`` messages per second at most (:class:`~.decimate.RateLimiter`).
* **Parameters** (capability ``parameters``): every node's parameters, named
  ``/ns/node.param``; get and set through the nodes' standard services; a refusal comes back as
  an error status with the node's reason, and the parameter's value as the node holds it.
* **Services** (capability ``services``, ``cdr``): the rig's services (set_mode, disturb, estop,
  reset, ...; not the parameter and type-description services), called through DDS.

Listening on another address than the loopback (``--listen 0.0.0.0``) the bridge is read-only
-- the protocol has no token -- except the e-stop (``.../estop`` with ``data: true``).
"""
from __future__ import annotations

import argparse
import importlib
import signal
import sys
import threading
import time

from rwpend_bringup.addresses import parse_listen, parse_port

from .access import is_loopback
from .console import Parser, argtype
from .decimate import RateLimiter

REFRESH_S = 2.0
#: service types the bridge does not offer (they have their own capability, or are internal)
HIDDEN_SERVICE_PREFIXES = ('rcl_interfaces/srv/', 'type_description_interfaces/srv/')
GLOBAL_TOPICS = ('/diagnostics', '/clock')
#: forwarded messages of a topic may come in bursts of this many (several publishers)
BURST = 10
#: nodes of our tools, not of the rig (their parameters are not offered)
OWN_NODES = ('rwpend_bridge', 'rwpend_console', 'rwpend_cli')


def parser() -> argparse.ArgumentParser:
    p = Parser(prog='rwpend bridge', description='The rig over the Foxglove WebSocket '
                                'protocol: topics (CDR, ros2msg schemas), parameters, services.')
    p.add_argument('--port', type=argtype(parse_port), default=8765, help='WebSocket port (default 8765)')
    p.add_argument('--listen', type=argtype(parse_listen), default='127.0.0.1',
                   help='address to listen on (default 127.0.0.1); any other makes the bridge read-only '
                   '(the e-stop excepted)')
    p.add_argument('--ns', default=None, help='only this namespace (and /diagnostics, /clock); default: all')
    p.add_argument('--max-rate', type=float, default=100.0,
                   help='messages per second per topic at most (default 100; the loop runs at 1 kHz)')
    return p


def srv_class(type_name: str):
    pkg, _, name = type_name.split('/')
    return getattr(importlib.import_module(f'{pkg}.srv'), name)


class Bridge:
    """The ROS side of the bridge, and the server listener foxglove-sdk calls back."""

    def __init__(self, worker, taps, fctx, scope: str | None, max_rate: float, read_only: bool) -> None:
        self.worker, self.taps, self.fctx = worker, taps, fctx
        self.scope = None if scope in (None, '', '/') else '/' + scope.strip('/')
        self.max_rate, self.read_only = max_rate, read_only
        self.server = None
        self.lock = threading.Lock()
        self.channels: dict[str, tuple] = {}        # topic -> (foxglove Channel, type name)
        self.clients: dict[str, int] = {}           # topic -> subscribed clients
        self.tapped: dict[str, object] = {}         # topic -> Tap
        self.services: dict[str, str] = {}          # name -> type
        self.unknown: set[str] = set()              # types without a definition here (said once)

    # ------------------------------------------------------------ the graph
    def in_scope(self, name: str) -> bool:
        return self.scope is None or name.startswith(self.scope + '/') or name in GLOBAL_TOPICS

    def refresh(self) -> None:
        topics = {n: t[0] for n, t in self.worker.node.get_topic_names_and_types() if self.in_scope(n) and t}
        services = {n: t[0] for n, t in self.worker.node.get_service_names_and_types()
                    if self.in_scope(n) and t and not t[0].startswith(HIDDEN_SERVICE_PREFIXES)}
        self._refresh_channels(topics)
        self._refresh_services(services)

    def _refresh_channels(self, topics: dict[str, str]) -> None:
        import foxglove
        from rwpend_bag.msgdefs import DefinitionNotFound
        from .schemas import MESSAGE_ENCODING, SCHEMA_ENCODING, message_schema
        for topic, type_name in sorted(topics.items()):
            if topic in self.channels and self.channels[topic][1] == type_name:
                continue
            try:
                s = message_schema(type_name)
            except (DefinitionNotFound, ValueError) as exc:
                if type_name not in self.unknown:
                    self.unknown.add(type_name)
                    print(f'rwpend bridge: {topic} not offered: {exc}', file=sys.stderr, flush=True)
                continue
            schema = foxglove.Schema(name=s.name, encoding=SCHEMA_ENCODING, data=s.text.encode())
            ch = foxglove.Channel(topic, schema=schema, message_encoding=MESSAGE_ENCODING, context=self.fctx)
            with self.lock:
                old = self.channels.pop(topic, None)
                self.channels[topic] = (ch, type_name)
            if old is not None:
                old[0].close()
        for topic in [t for t in self.channels if t not in topics]:
            with self.lock:
                ch, _ = self.channels.pop(topic)
            ch.close()

    def _refresh_services(self, services: dict[str, str]) -> None:
        from foxglove.websocket import Service
        new = {n: t for n, t in services.items() if self.services.get(n) != t}
        gone = [n for n in self.services if n not in services or n in new]
        if gone:
            self.server.remove_services(gone)
            for n in gone:
                self.services.pop(n, None)
        offered = []
        for name, type_name in sorted(new.items()):
            try:
                offered.append(Service(name, schema=self._service_schema(type_name),
                                       handler=self._service_handler(name, type_name)))
            except (LookupError, ValueError, ImportError, AttributeError) as exc:
                if type_name not in self.unknown:
                    self.unknown.add(type_name)
                    print(f'rwpend bridge: service {name} not offered: {exc}', file=sys.stderr, flush=True)
                continue
            self.services[name] = type_name
        if offered:
            self.server.add_services(offered)

    @staticmethod
    def _service_schema(type_name: str):
        import foxglove
        from foxglove.websocket import MessageSchema, ServiceSchema
        from .schemas import MESSAGE_ENCODING, SCHEMA_ENCODING, service_schemas
        s = service_schemas(type_name)

        def part(m):
            return MessageSchema(encoding=MESSAGE_ENCODING, schema=foxglove.Schema(
                name=m.name, encoding=SCHEMA_ENCODING, data=m.text.encode()))
        return ServiceSchema(type_name, request=part(s.request), response=part(s.response))

    # ------------------------------------------------------------ topics
    def on_subscribe(self, client, channel) -> None:
        topic = channel.topic
        with self.lock:
            self.clients[topic] = self.clients.get(topic, 0) + 1
            first = self.clients[topic] == 1 and topic in self.channels
            entry = self.channels.get(topic)
        if first:
            self._tap(topic, entry)

    def _tap(self, topic: str, entry) -> None:
        from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
        from rwpend_bag.msgdefs import import_message_class
        from .taps import Tap
        channel, type_name = entry
        limiter = RateLimiter(self.max_rate, burst=BURST)
        qos = QoSProfile(reliability=ReliabilityPolicy.BEST_EFFORT, history=HistoryPolicy.KEEP_LAST, depth=BURST)

        def forward(taken: list) -> None:
            for data, info in taken:
                now = info.get('received_timestamp') or time.time_ns()
                if limiter.admit(now):
                    channel.log(bytes(data), log_time=now)
        tap = Tap(import_message_class(type_name), topic, qos, forward, raw=True, limit=BURST)
        with self.lock:
            self.tapped[topic] = tap
        self.taps.add(tap)

    def on_unsubscribe(self, client, channel) -> None:
        topic = channel.topic
        with self.lock:
            self.clients[topic] = max(0, self.clients.get(topic, 0) - 1)
            tap = self.tapped.pop(topic, None) if self.clients[topic] == 0 else None
        if tap is not None:
            self.taps.remove(tap)

    # ------------------------------------------------------------ parameters
    def _nodes(self) -> list[str]:
        out = []
        for name, ns in self.worker.node.get_node_names_and_namespaces():
            fqn = f'{ns.rstrip("/")}/{name}'
            if not name.startswith(OWN_NODES) and self.in_scope(fqn):
                out.append(fqn)
        return sorted(set(out))

    def on_get_parameters(self, client, param_names: list[str], request_id=None) -> list:
        from .foxglove_params import split_name
        wanted: dict[str, list[str] | None] = {}
        if not param_names:
            wanted = {n: None for n in self._nodes()}
        for full in param_names:
            try:
                node, param = split_name(full)
            except ValueError as exc:
                self._status(str(exc), error=True)
                continue
            wanted.setdefault(node, []).append(param)
        out = []
        for node, names in wanted.items():
            out += self._read(node, names)
        return out

    def _read(self, node: str, names: list[str] | None) -> list:
        from . import paramsvc
        from .rosside import CallError
        try:
            names = paramsvc.list_names(self.worker.call, node) if names is None else names
            values = paramsvc.get_typed(self.worker.call, node, names) if names else {}
        except CallError as exc:
            self._status(f'{node}: {exc}', error=True)
            return []
        return [self._parameter(node, n, t, v) for n, (t, v) in values.items()]

    @staticmethod
    def _parameter(node: str, name: str, type_name: str, value):
        from foxglove.websocket import Parameter, ParameterType
        from .foxglove_params import join_name, to_wire
        v, hint = to_wire(type_name, value)
        kind = {'float64': ParameterType.Float64, 'float64_array': ParameterType.Float64Array,
                'byte_array': ParameterType.ByteArray}.get(hint)
        return Parameter(join_name(node, name), value=v, **({'type': kind} if kind is not None else {}))

    def on_set_parameters(self, client, parameters: list, request_id=None) -> list:
        from .foxglove_params import split_name
        by_node: dict[str, dict] = {}
        for p in parameters:
            try:
                node, param = split_name(p.name)
            except ValueError as exc:
                self._status(str(exc), error=True)
                continue
            by_node.setdefault(node, {})[param] = p.get_value()
        out = []
        for node, values in by_node.items():
            if self.read_only:
                self._status(f'{node}: not set: this bridge listens beyond this machine and is read-only '
                             '(set parameters with the console and its token)', error=True)
            else:
                self._set(node, values)
            out += self._read(node, list(values))
        return out

    def _set(self, node: str, values: dict) -> None:
        from . import paramsvc
        from .foxglove_params import from_wire
        from .rosside import CallError
        try:
            fields = {f.name: f for f in paramsvc.read_fields(self.worker.call, node, list(values))}
            typed = {}
            for name, raw in values.items():
                f = fields.get(name)
                if f is None:
                    self._status(f'{node}.{name}: no such parameter', error=True)
                    continue
                try:
                    typed[name] = from_wire(node, name, f.type, f.read_only, raw)
                except ValueError as exc:
                    self._status(f'{node}.{name}: refused: {exc}', error=True)
            results = paramsvc.set_values(self.worker.call, node, typed) if typed else []
        except CallError as exc:
            self._status(f'{node}: {exc}', error=True)
            return
        for name, ok, reason in results:
            if not ok:
                self._status(f'{node}.{name}: refused by the node: {reason}', error=True)

    def _status(self, message: str, error: bool = False) -> None:
        from foxglove.websocket import StatusLevel
        print(f'rwpend bridge: {message}', file=sys.stderr, flush=True)
        if self.server is not None:
            self.server.publish_status(message, StatusLevel.Error if error else StatusLevel.Info)

    # ------------------------------------------------------------ services
    def _service_handler(self, name: str, type_name: str):
        cls = srv_class(type_name)

        def handle(request) -> bytes:
            from rclpy.serialization import deserialize_message, serialize_message
            req = deserialize_message(bytes(request.payload), cls.Request)
            if self.read_only and not (name.endswith('/estop') and getattr(req, 'data', False) is True):
                raise RuntimeError('this bridge listens beyond this machine and is read-only: only '
                                   'raising the e-stop is allowed')
            return serialize_message(self.worker.call(cls, name, req, timeout=5.0))
        return handle


def main(argv=None) -> int:
    a = parser().parse_args(sys.argv[1:] if argv is None else argv)
    if not 1 <= a.max_rate <= 10_000:
        print(f'rwpend bridge: error: --max-rate in 1..10000 messages/s, got {a.max_rate}', file=sys.stderr)
        return 2
    from rwpend_ros.transport import apply_transport_or_exit
    apply_transport_or_exit()
    import foxglove
    from foxglove.websocket import Capability
    from .rosside import RosWorker
    from .taps import Taps
    worker = RosWorker('rwpend_bridge')
    taps = Taps(worker.context, 'rwpend_bridge_taps', 0.5 / a.max_rate)
    bridge = Bridge(worker, taps, foxglove.Context(), a.ns, a.max_rate, read_only=not is_loopback(a.listen))
    try:
        bridge.server = foxglove.start_server(
            name='rwpend', host=a.listen, port=a.port, context=bridge.fctx, server_listener=bridge,
            capabilities=[Capability.Parameters, Capability.Services], supported_encodings=['cdr'])
    except Exception as exc:  # noqa: BLE001 - the SDK's error (port in use, ...), said plainly
        print(f'rwpend bridge: error: cannot listen on {a.listen}:{a.port}: {exc}', file=sys.stderr)
        worker.close()
        return 1
    worker.start()
    taps.start()
    ro = ' (read-only: it listens beyond this machine; the e-stop excepted)' if bridge.read_only else ''
    print(f'rwpend bridge: Foxglove WebSocket on ws://{a.listen}:{bridge.server.port}{ro}, domain '
          f'{worker.domain}', flush=True)
    return serve(bridge, worker, taps)


def serve(bridge: Bridge, worker, taps) -> int:
    stop = threading.Event()
    for s in (signal.SIGINT, signal.SIGTERM):
        signal.signal(s, lambda *_: stop.set())
    while not stop.is_set():
        try:
            worker.in_spin(bridge.refresh, timeout=10.0)
        except Exception as exc:  # noqa: BLE001 - a graph that changes while read: next time
            print(f'rwpend bridge: refresh: {exc}', file=sys.stderr, flush=True)
        stop.wait(REFRESH_S)
    bridge.server.stop()
    taps.close()
    worker.close()
    return 0


if __name__ == '__main__':
    sys.exit(main())
