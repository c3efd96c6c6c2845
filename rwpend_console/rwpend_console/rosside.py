"""The console's ROS side: one node per watched domain (:class:`DomainWatcher`).

Topics (per rig, relative to its namespace):

| topic | type | QoS | when |
|---|---|---|---|
| ``/diagnostics`` | DiagnosticArray | reliable, depth 100 | always (the lights, the overview) |
| ``state`` | StateEstimate (raw) | best effort, depth 1 | while a page watches the rig |
| ``controller/status`` | ControllerStatus | reliable, depth 10 | while a page watches the rig |
| ``sim/true_state`` | PlantState (raw) | best effort, depth 1 | while a page watches the rig,
  from its first state sample (the simulator: ``u_applied``) |
| ``applied`` | AppliedCommand (raw) | best effort, depth 1 | as ``sim/true_state`` (the
  driver: ``u``) |
| ``estop`` (out) | std_msgs/Bool | latched | made when the rig is found |
| ``/diagnostics`` (out) | DiagnosticArray | reliable | one status per e-stop from the page |

Services it calls: the parameter services of every node, ``controller/set_mode``,
``sim/disturb``, every ``estop`` (SetBool) of the rig.

The e-stop state it shows is the plant's (its ``estop`` value on ``/diagnostics``), with the
requests of this console beside it (:mod:`rwpend_console.estop`, kept on the board).

It never slows the loop: it subscribes to the loop's 1 kHz topics only while a page
watches, best effort (the writer never waits for it or repeats a sample for it), depth 1, and
takes it by polling (:mod:`rwpend_console.taps`, every :data:`POLL_S`): the newest sample
then, never a wake-up per sample. Decimation (:class:`rwpend_console.decimate.Decimator`)
keeps ``rate_hz`` samples per second of sample time. All entities of the executor's node are
made and destroyed on its thread (:meth:`RosWorker.in_spin`); other threads (the web server's)
only publish and call services.
"""
from __future__ import annotations

import concurrent.futures
import os
import queue
import threading
import time

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from std_msgs.msg import Bool

from rwpend_msgs.msg import AppliedCommand, ControllerStatus, PlantState, StateEstimate
from rwpend_ros import wire
from rwpend_ros.diagnostics import publish_diagnostic
from rwpend_ros.qos import QOS_LATCHED, QOS_STATUS

from .decimate import Decimator
from .feed import Feed
from .lights import StatusBoard
from .taps import run_posted
from .rigs import rig_namespaces
from .taps import Tap, Taps

#: seconds between polls of the watched rigs' state and status (200 Hz: in lockstep up to 4x
#: real time the 50 Hz decimation still finds a sample in every 20 ms of sample time)
POLL_S = 0.005
#: seconds between looks at the graph for new rigs
DISCOVERY_PERIOD_S = 1.0
QOS_OBSERVER = QoSProfile(reliability=ReliabilityPolicy.BEST_EFFORT, history=HistoryPolicy.KEEP_LAST, depth=1)
QOS_STATUS_IN = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST, depth=10)


class CallError(RuntimeError):
    """A service call that could not be made or was not answered (the message says why)."""


class RigWatch:
    """What the console holds for one watched rig: its feed, decimators and subscriptions
    (``taps``, ``watchers`` and ``applied_on`` under ``lock``: the executor's thread and the
    Taps thread change them)."""

    def __init__(self, ns: str, rate_hz: float) -> None:
        self.ns = ns
        self.lock = threading.Lock()
        self.applied_on = False
        self.feed = Feed()
        self.state_dec = Decimator(rate_hz)
        self.status_dec = Decimator(rate_hz)
        self.applied_decs = {'sim/true_state': Decimator(rate_hz), 'applied': Decimator(rate_hz)}
        self.watchers = 0
        self.taps: list[Tap] = []


class RosWorker:
    """A context of its own on ``domain`` (None: the environment's ROS_DOMAIN_ID), a node and a
    paced executor thread; entities are made and destroyed on that thread only
    (:meth:`in_spin`, :meth:`post`), services are called from any thread (:meth:`call`)."""

    def __init__(self, name: str, domain: int | None = None) -> None:
        self._clients: dict[tuple, object] = {}
        self._todo: queue.Queue = queue.Queue()
        self._stop = threading.Event()
        self._closing = threading.Lock()    # no wake-up of a guard condition being destroyed
        self.context = rclpy.Context()
        rclpy.init(context=self.context, args=[], **({} if domain is None else {'domain_id': domain}))
        self.domain = self.context.get_domain_id()
        self.node = Node(name, namespace='/', context=self.context, start_parameter_services=False)
        # work posted from other threads wakes the executor (no polling of the queue)
        self._wake = self.node.create_guard_condition(self._run_todo)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self._spin, name=f'ros-{name}-{self.domain}', daemon=True)

    def start(self) -> None:
        self.thread.start()

    def _spin(self) -> None:
        while not self._stop.is_set() and self.context.ok():
            self._run_todo()
            try:
                self.executor.spin_once(timeout_sec=0.5)
            except Exception:  # noqa: BLE001 - the context shut down under us: the end
                if self.context.ok() and not self._stop.is_set():
                    raise
                break

    def _run_todo(self) -> None:
        run_posted(self._todo)

    def post(self, fn) -> concurrent.futures.Future:
        """Run ``fn()`` on the executor's thread, soon; the future has its result."""
        fut: concurrent.futures.Future = concurrent.futures.Future()
        with self._closing:
            if self._stop.is_set():
                fut.set_exception(CallError('the console is shutting down'))
                return fut
            self._todo.put((fn, fut))
            self._wake.trigger()
        return fut

    def in_spin(self, fn, timeout: float = 5.0):
        """Run ``fn()`` on the executor's thread and wait for its result."""
        if threading.current_thread() is self.thread:
            return fn()
        return self.post(fn).result(timeout=timeout)

    @property
    def closing(self) -> bool:
        return self._stop.is_set()

    def close(self) -> None:
        with self._closing:
            self._stop.set()
            self._wake.trigger()    # the executor thread ends now, not after its timeout
        if self.thread.is_alive():
            self.thread.join(timeout=2.0)
        try:
            self.executor.shutdown(timeout_sec=1.0)
            self.node.destroy_node()
        finally:
            rclpy.try_shutdown(context=self.context)

    def call(self, srv_type, name: str, request, timeout: float = 5.0):
        """Call service ``name``; CallError with the reason when it is not there or silent."""
        key = (srv_type, name)
        client = self._clients.get(key)
        if client is None:
            client = self.in_spin(lambda: self._clients.setdefault(key, self.node.create_client(srv_type, name)))
        end = time.monotonic() + timeout
        while not client.service_is_ready():
            if time.monotonic() >= end:
                raise CallError(f'service {name} is not available (is the rig running, on domain '
                                f'{self.domain}?)')
            time.sleep(0.02)
        done = threading.Event()
        future = client.call_async(request)
        future.add_done_callback(lambda _f: done.set())
        if not done.wait(max(0.0, end - time.monotonic())):
            future.cancel()
            raise CallError(f'service {name} did not answer within {timeout:g} s')
        if future.exception() is not None:
            raise CallError(f'service {name} failed: {future.exception()}')
        return future.result()


class DomainWatcher(RosWorker):
    """The console on one ROS domain: the rigs found there, their lights, the watched ones."""

    def __init__(self, domain: int | None = None, rate_hz: float = 50.0) -> None:
        super().__init__(f'rwpend_console_{os.getpid()}', domain)
        self.rate_hz = rate_hz
        self.board = StatusBoard()
        self.board_lock = threading.Lock()
        self.rigs: list[str] = []
        self.watches: dict[str, RigWatch] = {}
        self.estop_pubs: dict[str, object] = {}
        self.diag_pub = self.node.create_publisher(DiagnosticArray, '/diagnostics', QOS_STATUS)
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diagnostics, QOS_STATUS)
        self.node.create_timer(DISCOVERY_PERIOD_S, self._discover)
        self.taps = Taps(self.context, f'rwpend_console_{os.getpid()}_taps', POLL_S)

    def start(self) -> None:
        super().start()
        self.taps.start()

    def close(self) -> None:
        self.taps.close()
        super().close()

    # ------------------------------------------------------------ callbacks
    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        now = time.monotonic()
        with self.board_lock:
            for st in msg.status:
                level = st.level[0] if isinstance(st.level, (bytes, bytearray)) else int(st.level)
                self.board.update(st.name, level, st.message, {kv.key: kv.value for kv in st.values}, now)

    def _discover(self) -> None:
        names = [n for n, _ in self.node.get_topic_names_and_types()]
        found = rig_namespaces(names)
        with self.board_lock:
            found = sorted(set(found) | set(self.board.rigs()) - {'/'})
        for ns in found:
            if ns not in self.estop_pubs:
                self.estop_pubs[ns] = self.node.create_publisher(Bool, f'{ns.rstrip("/")}/estop', QOS_LATCHED)
        self.rigs = found

    def _on_states(self, w: RigWatch, taken: list) -> None:
        data = taken[-1][0]
        try:
            _, stamp = wire.message_seq_stamp(data)
        except Exception:  # noqa: BLE001 - malformed bytes: not shown
            return
        if not w.applied_on:
            self._start_applied(w)
        if w.state_dec.admit(stamp):
            m = deserialize_message(data, StateEstimate)
            w.feed.add_state(stamp, time.time_ns(), m.theta, m.theta_dot, m.wheel_rate, m.energy)

    def _on_applied(self, w: RigWatch, topic: str, msg_type, field: str, taken: list) -> None:
        """The command the motor got: ``field`` of the newest ``msg_type`` taken (raw bytes)."""
        data = taken[-1][0]
        try:
            _, stamp = wire.message_seq_stamp(data)
        except Exception:  # noqa: BLE001 - malformed bytes: not shown
            return
        if w.applied_decs[topic].admit(stamp):
            w.feed.add_applied(stamp, getattr(deserialize_message(data, msg_type), field))

    def _on_statuses(self, w: RigWatch, taken: list) -> None:
        for m, _ in taken:
            stamp = m.header.stamp.sec * 1_000_000_000 + m.header.stamp.nanosec
            w.feed.add_status(stamp, w.status_dec.admit(stamp), m.u, m.saturated, m.mode, m.law)

    # ------------------------------------------------------------ watching a rig
    def watch(self, ns: str) -> Feed:
        """A page watches rig ``ns``: subscribe to its state and status (the first page)."""
        return self.in_spin(lambda: self._watch(ns))

    def _watch(self, ns: str) -> Feed:
        w = self.watches.setdefault(ns, RigWatch(ns, self.rate_hz))
        added = []
        with w.lock:
            w.watchers += 1
            if w.watchers == 1:
                base = ns.rstrip('/')
                w.taps = [Tap(StateEstimate, f'{base}/state', QOS_OBSERVER, lambda t, w=w: self._on_states(w, t)),
                          Tap(ControllerStatus, f'{base}/controller/status', QOS_STATUS_IN,
                              lambda t, w=w: self._on_statuses(w, t), raw=False, limit=QOS_STATUS_IN.depth)]
                added = [self.taps.add(tap) for tap in w.taps]
        for fut in added:
            fut.result(timeout=5.0)
        return w.feed

    def _start_applied(self, w: RigWatch) -> None:
        """(The Taps thread, at the first state sample of a watch.) Take the command the motor
        got -- ``sim/true_state`` (simulator), ``applied`` (driver) -- from now on: only once the
        rig's samples flow, never before its run starts (a lockstep simulator with a recorder
        holds sample 0 until one subscriber of sim/true_state, the recorder, listens:
        ``start.true_state_subscribers``; the console must not count as that recorder)."""
        with w.lock:       # posted under the lock: a last page going away removes them after
            if w.watchers == 0 or w.applied_on:
                return
            w.applied_on = True
            base = w.ns.rstrip('/')
            new = [Tap(PlantState, f'{base}/sim/true_state', QOS_OBSERVER,
                       lambda t, w=w: self._on_applied(w, 'sim/true_state', PlantState, 'u_applied', t)),
                   Tap(AppliedCommand, f'{base}/applied', QOS_OBSERVER,
                       lambda t, w=w: self._on_applied(w, 'applied', AppliedCommand, 'u', t))]
            w.taps += new
            for tap in new:
                self.taps.add(tap)     # made on this thread at its next poll

    def unwatch(self, ns: str) -> None:
        """A page stopped watching: the last one takes the subscriptions away (the feed stays).
        Nothing to do once the console is shutting down: the subscriptions go with it."""
        try:
            self.in_spin(lambda: self._unwatch(ns))
        except CallError:
            if not self.closing:
                raise

    def _unwatch(self, ns: str) -> None:
        w = self.watches.get(ns)
        if w is None or w.watchers == 0:
            return
        with w.lock:
            w.watchers -= 1
            if w.watchers == 0:
                for tap in w.taps:
                    self.taps.remove(tap)
                w.taps = []
                w.applied_on = False

    # ------------------------------------------------------------ the graph
    def service_names(self, ns: str, suffix: str, type_name: str) -> list[str]:
        base = ns.rstrip('/') + '/'
        return sorted(n for n, types in self.node.get_service_names_and_types()
                      if n.startswith(base) and n.endswith(suffix) and type_name in types)

    def node_names(self, ns: str) -> list[str]:
        """Nodes of rig ``ns`` (relative names: 'controller', 'estimator', 'sim', ...)."""
        out = []
        for name, node_ns in self.node.get_node_names_and_namespaces():
            if node_ns.rstrip('/') == ns.rstrip('/') and not name.startswith('rwpend_console'):
                out.append(name)
        return sorted(set(out))

    def rig_topics(self, ns: str) -> list[str]:
        base = ns.rstrip('/') + '/'
        names = [n for n, _ in self.node.get_topic_names_and_types()]
        return sorted(n for n in names if n.startswith(base) or n in ('/diagnostics', '/clock'))

    # ------------------------------------------------------------ e-stop
    def publish_estop(self, ns: str, on: bool, clicked_ns: int | None) -> None:
        """The e-stop on the rig's latched ``estop`` topic, at once (no service round trip), and
        a status on /diagnostics stamped with the time of the click (a bag shows both); the
        request is noted beside the plant's reports (:meth:`estop_state`), after it went out
        (nothing delays it) with the time it was sent: a report of the change is always newer."""
        sent = time.monotonic()
        pub = self.estop_pubs.get(ns)
        if pub is None:
            pub = self.in_spin(lambda: self.estop_pubs.setdefault(
                ns, self.node.create_publisher(Bool, f'{ns.rstrip("/")}/estop', QOS_LATCHED)))
        pub.publish(Bool(data=bool(on)))
        with self.board_lock:
            self.board.estop_requested(ns, bool(on), sent)
        now = time.time_ns()
        stamp = clicked_ns if clicked_ns is not None and abs(clicked_ns - now) < 10_000_000_000 else now
        publish_diagnostic(self.diag_pub, stamp, f'{ns.rstrip("/")}/console: e-stop', 'rwpend_console',
                           1 if on else 0, 'e-stop raised from the console' if on else 'e-stop cleared '
                           'from the console', {'on': on, 'clicked_ns': clicked_ns or 0, 'sent_ns': now})

    # ------------------------------------------------------------ the board
    def lights(self, ns: str) -> list[dict]:
        with self.board_lock:
            return [x.as_dict() for x in self.board.lights(ns, time.monotonic())]

    def estop_state(self, ns: str) -> dict:
        """The rig's e-stop as its plant last reported it (:class:`rwpend_console.estop.EstopState`)."""
        with self.board_lock:
            return self.board.estop(ns, time.monotonic()).as_dict()

    def summary(self, ns: str) -> dict:
        with self.board_lock:
            return self.board.summary(ns, time.monotonic())
