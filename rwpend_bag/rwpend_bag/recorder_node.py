"""Recorder node ``recorder``: raw (serialized) subscriptions to any topic, written to a bag.

Thin rclpy layer over :class:`rwpend_bag.writer.ThreadedBagWriter`: the subscription callbacks
only enqueue (topic, wire bytes, receive time); a writer thread does the MCAP work. Topics that
appear later are picked up (graph polled every 0.5 s). Each subscription uses the publishers'
reliability/durability and a keep-last 1000 history.

The topics our nodes publish at the sample rate (:data:`FAST_TYPES`) are taken through the
same-host fast path as well (:func:`rwpend_ros.common.local_subscription`;
``RWPEND_RECORDER_FAST_PATH=0`` turns it off): then every subscriber of those topics on this
host takes it, and their publishers write nothing to DDS per sample (PERFORMANCE.md, 15.: the
loop's CPU down by ~40 % at 1 kHz; 16.: lockstep with the recorder 0.5-0.9x -> 2.8-3.3x). The
recorder's fast receivers have no thread each: one thread drains them all every
:data:`FAST_POLL_S`, and a message's log time is the kernel's time of its arrival in the socket.
Each publisher's connection holds hundreds of messages (rwpend_ros.hostbus.SEND_BUFFER); a
message that reaches the recorder through DDS instead (a recorder starved for longer than
that, a publisher on another host), like every message of the other topics, is logged at the
time DDS received it (rclpy's message info, as rosbag2 does), so log times compare across the
two paths (PERFORMANCE.md, 16.). Each message is recorded once, in order. With
``RWPEND_RECORDER_FAST_PATH=0`` every message comes through DDS and is logged at its callback's
time (the EventsExecutor, which cannot hand over the message info in rclpy 7.1.6).

``progress`` (``rwpend record --progress TOPIC``, set by ``./rwpend up --lockstep --record``): every
:data:`rwpend_ros.common.RECORDER_PROGRESS_EVERY` ``/clock`` messages taken (handed to the bag
writer, whose queue loses nothing), that ``/clock`` is published on TOPIC; a lockstep simulator
keeps within its ``lockstep_recorder_window`` of it, so a recorder that falls behind slows the
run down instead of losing messages. The progress is held back while a fast topic's
:class:`rwpend_ros.hostbus.Merge` waits for DDS (a message its publisher wrote to DDS alone, the
copies DDS has not brought yet; for PROGRESS_DDS_WAIT_S at most): the bag is complete only up to there, and a recorder whose DDS
reader lags far behind would otherwise have to deliver those messages late, out of order
(PERFORMANCE.md, 17.).
"""
from __future__ import annotations

import sys
import threading
import time

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from rwpend_ros import hostbus
from rwpend_ros.common import QOS_PROGRESS, RECORDER_PROGRESS_EVERY, local_subscription
from rwpend_ros.hostbus import CALLBACK_LOCK

from . import msgdefs
from .writer import INFINITE_TIME, ThreadedBagWriter

DEPTH = 1000
#: period (s) of the thread that drains the fast path's connections (each holds what its
#: publisher's send buffer does, hundreds of messages: rwpend_ros.hostbus.SEND_BUFFER); 2 ms is
#: 2-4 samples per topic at 1-2 kHz
FAST_POLL_S = 0.002
#: ... an eighth of it while a drain finds more than this many messages on one topic
FAST_BACKLOG = 64
#: types our nodes publish at the sample rate with rwpend_ros.common.LocalPublisher (the
#: same-host fast path): the loop's, the simulator's truth and clock, the estimator's joint
#: states, the controller's status (every 10 samples)
FAST_TYPES = frozenset({'rwpend_msgs/msg/EncoderCounts', 'rwpend_msgs/msg/StateEstimate',
                        'rwpend_msgs/msg/MotorCommand', 'rwpend_msgs/msg/PlantState',
                        'sensor_msgs/msg/JointState', 'rosgraph_msgs/msg/Clock',
                        'rwpend_msgs/msg/ControllerStatus'})
POLL_S = 0.5
#: longest the progress is held back for one fast topic waiting for DDS (s): a DDS copy that
#: never comes (its publisher died before DDS sent it) must not stop a lockstep run, whose
#: simulator gives up on the recorder after lockstep_recorder_timeout (5 s)
PROGRESS_DDS_WAIT_S = 2.0
DRAIN_IDLE_S = 0.25    # on stop: keep recording until nothing arrived for this long ...
DRAIN_LIMIT_S = 2.0    # ... or this long at most (a second Ctrl-C ends it at once)


def _dur(d) -> dict:
    ns = getattr(d, 'nanoseconds', None)
    if ns is None or ns >= 9223372036854775807:
        return dict(INFINITE_TIME)
    return {'sec': ns // 1_000_000_000, 'nsec': ns % 1_000_000_000}


def qos_dict(q) -> dict:
    """rclpy QoSProfile -> rosbag2 v9 offered_qos_profiles entry."""
    def nm(v):
        return v.name.lower() if hasattr(v, 'name') else str(v).lower()
    return {'history': nm(q.history), 'depth': int(q.depth), 'reliability': nm(q.reliability),
            'durability': nm(q.durability), 'deadline': _dur(q.deadline),
            'lifespan': _dur(q.lifespan), 'liveliness': nm(q.liveliness),
            'liveliness_lease_duration': _dur(q.liveliness_lease_duration),
            'avoid_ros_namespace_conventions': bool(q.avoid_ros_namespace_conventions)}


class Recorder(Node):
    def __init__(self, out_dir: str, topics: list[str] | None, record_all: bool,
                 progress: str | None = None):
        super().__init__('recorder')
        #: publisher of the progress (the newest /clock taken), None without --progress
        self.progress_pub = None
        self.progress_topic = None
        if progress:
            from rosgraph_msgs.msg import Clock
            self.progress_pub = self.create_publisher(Clock, progress, QOS_PROGRESS)
            self.progress_topic = self.progress_pub.topic_name
        self._clocks = 0
        #: the /clock to report as the progress once no fast topic waits for DDS (None: none due)
        self._progress_due: bytes | None = None
        self.progress_held = 0       # drains that held the progress back (a merge waited for DDS)
        self._dds_wait_since: dict[str, float] = {}   # fast topic -> when it began to wait
        self.writer = ThreadedBagWriter(out_dir)
        self.wanted = set(topics or [])
        self.record_all = record_all
        self.subs: dict[str, object] = {}
        self.skipped: dict[str, str] = {}
        self._closed = False
        self._received = [0]
        self.fast = hostbus.recorder_enabled()
        #: log time of a DDS message = when DDS received it (rclpy's message info, as rosbag2),
        #: not when its callback ran: a fast message's is its arrival in the socket, and the two
        #: must compare across topics. Needs the SingleThreadedExecutor (rclpy 7.1.6's
        #: EventsExecutor fails on such callbacks; run_recorder picks it), so only with the fast
        #: path, which leaves the recorder few DDS messages; without it every message comes by
        #: DDS and the callback's time orders them all alike
        self.dds_info = self.fast
        self._batch: list[tuple[int, str, bytes]] = []   # fast topics: (log time, topic, data)
        self._last_ns: dict[str, int] = {}
        self._fast_stop = threading.Event()
        self._fast_thread: threading.Thread | None = None
        self.create_timer(POLL_S, self.discover)
        self.get_logger().info(f'recording to {out_dir} '
                               f'({"all topics" if record_all else ", ".join(sorted(self.wanted))})')
        self.discover()

    def discover(self) -> None:
        for name, types in self.get_topic_names_and_types():
            if name in self.subs or name in self.skipped or name == self.progress_topic:
                continue     # (its own progress: not part of the run)
            if not self.record_all and name not in self.wanted:
                continue
            type_name = types[0]
            try:
                cls = msgdefs.import_message_class(type_name)
                msgdefs.joined_definition(type_name)
            except (ImportError, LookupError, ValueError) as exc:
                self.skipped[name] = str(exc)
                self.get_logger().warn(f'not recording {name}: {exc}')
                continue
            pubs = self.get_publishers_info_by_topic(name)
            if not pubs:
                continue  # QoS unknown until a publisher exists; retry at the next poll
            offered = [p.qos_profile for p in pubs]
            reliable = all(q.reliability == ReliabilityPolicy.RELIABLE for q in offered)
            latched = all(q.durability == DurabilityPolicy.TRANSIENT_LOCAL for q in offered)
            qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=DEPTH,
                             reliability=ReliabilityPolicy.RELIABLE if reliable
                             else ReliabilityPolicy.BEST_EFFORT,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL if latched
                             else DurabilityPolicy.VOLATILE)
            self.writer.add_topic(name, type_name, [qos_dict(q) for q in offered])
            if type_name in FAST_TYPES and self.fast:
                self._last_ns[name] = 0
                self.subs[name] = local_subscription(self, cls, name, self._fast_receiver(name), qos,
                                                     intra=False, polled=True, dds_info=self.dds_info)
                if self._fast_thread is None:
                    self._fast_thread = threading.Thread(target=self._fast_loop, name='recorder-fast',
                                                         daemon=True)
                    self._fast_thread.start()
            else:
                self.subs[name] = self.create_subscription(
                    cls, name, self._receiver(name, progress=name == '/clock'), qos, raw=True)
            self.get_logger().info(f'recording {name} [{type_name}] '
                                   f'{"reliable" if reliable else "best effort"}')

    def _receiver(self, name: str, progress: bool = False):
        """Callback of a DDS-only topic: into the writer's queue, logged at DDS's reception time
        (``dds_info``: rclpy then passes the message info) or at the callback's; ``progress``:
        the recorder's progress is counted on it (/clock)."""
        put = self.writer.put
        counter = self._received
        taken = self._clock_taken if progress and self.progress_pub is not None else None

        if self.dds_info:
            def receive(data, info, _n=name, _put=put, _now=time.time_ns, _count=counter, _taken=taken):
                _put(_n, data, info.get('received_timestamp') or _now())
                _count[0] += 1
                if _taken is not None:
                    _taken(data)
            return receive

        def receive_now(data, _n=name, _put=put, _now=time.time_ns, _count=counter, _taken=taken):
            _put(_n, data, _now())
            _count[0] += 1
            if _taken is not None:
                _taken(data)
        return receive_now

    def _clock_taken(self, data: bytes) -> None:
        """A /clock message is in the writer's queue: every RECORDER_PROGRESS_EVERY of them,
        published as the progress (the same bytes: rosgraph_msgs/Clock) -- unless a fast topic
        waits for DDS (:meth:`_waiting_for_dds`): then the newest due is published once it no
        longer does (:meth:`_report_progress`, at the next drain of the fast path)."""
        self._clocks += 1
        if self._clocks % RECORDER_PROGRESS_EVERY == 0:
            self._progress_due = data
            self._report_progress()

    def _waiting_for_dds(self) -> bool:
        """Whether a fast topic has messages the bag does not have yet because DDS has not
        brought them: held for a marker (its publisher wrote a message to DDS alone), or
        syncing behind the fast path (CALLBACK_LOCK held) -- for PROGRESS_DDS_WAIT_S at most
        per episode (then a warning, and the run goes on)."""
        waiting = False
        now = time.monotonic()
        since = self._dds_wait_since
        for name, merge in getattr(self, 'hostbus_merges', {}).items():
            if not (merge.held or (not merge.fast_mode and merge.syncing)):
                since.pop(name, None)
                continue
            t0 = since.setdefault(name, now)
            if now - t0 < PROGRESS_DDS_WAIT_S:
                waiting = True
            elif t0 > 0:
                since[name] = 0.0    # reported once per episode
                self.get_logger().warn(
                    f'{name}: DDS has not brought what the fast path waits for in '
                    f'{PROGRESS_DDS_WAIT_S:g} s; reporting progress anyway (messages may be late)')
        return waiting

    def _report_progress(self) -> None:
        data = self._progress_due
        if data is None:
            return
        with CALLBACK_LOCK:
            behind = self._waiting_for_dds()
        if behind:
            self.progress_held += 1
            return
        self._progress_due = None
        self.progress_pub.publish(bytes(data))

    def _fast_receiver(self, name: str):
        """Callback of a fast topic (either path; CALLBACK_LOCK held): into the batch, with the
        arrival time in the socket or DDS's reception time (now if neither is known), kept
        increasing per topic."""
        last = self._last_ns

        def receive(data, _n=name):
            t = hostbus.delivery_stamp() or time.time_ns()
            if t <= last[_n]:
                t = last[_n] + 1
            last[_n] = t
            self._batch.append((t, _n, data))
        return receive

    def poll_fast(self) -> int:
        """Drain the fast path's sockets; the batch goes to the writer in log-time order.
        Returns the most datagrams one socket held."""
        most = 0
        with CALLBACK_LOCK:
            for receiver in list(getattr(self, 'hostbus_receivers', {}).values()):
                if receiver is not None and not receiver.closed:
                    most = max(most, receiver.drain())
            batch, self._batch = self._batch, []
        if batch:
            batch.sort(key=lambda item: item[0])
            put = self.writer.put
            progress = self.progress_pub is not None
            for t, name, data in batch:
                put(name, data, t)
                if progress and name == '/clock':
                    self._clock_taken(data)
            self._received[0] += len(batch)
        if self.progress_pub is not None:
            self._report_progress()      # one held back: DDS may have brought what it waited for
        return most

    def _fast_loop(self) -> None:
        """Every FAST_POLL_S; sooner while a drain finds a backlog (a recorder that fell
        behind)."""
        wait = FAST_POLL_S
        while not self._fast_stop.wait(wait):
            try:
                wait = FAST_POLL_S if self.poll_fast() <= FAST_BACKLOG else FAST_POLL_S / 8
            except Exception as exc:  # noqa: BLE001 - reported; DDS still delivers
                self.get_logger().error(f'fast path: {exc!r}')
                return

    def drain(self, executor, idle: float = DRAIN_IDLE_S, limit: float = DRAIN_LIMIT_S,
              abort=lambda: False) -> int:
        """Keep taking messages until none arrived for ``idle`` s (at most ``limit`` s); returns how
        many were taken. Called when asked to stop: what the stack sent last (its final samples,
        still in the DDS queues of a recorder that runs behind) goes into the bag too."""
        n0 = last = self._received[0]
        t_last = end = time.monotonic()
        end += limit
        while time.monotonic() < end and not abort():
            executor.spin_once(timeout_sec=0.02)
            n = self._received[0]
            if n != last:
                last, t_last = n, time.monotonic()
            elif time.monotonic() - t_last >= idle:
                break
        return last - n0

    def close(self) -> dict:
        if self._closed:
            return {}
        self._closed = True
        self._fast_stop.set()
        if self._fast_thread is not None:
            self._fast_thread.join(1.0)
        self.poll_fast()             # what is still in the sockets and the batch
        with CALLBACK_LOCK:          # what waits for a DDS copy that is not coming any more
            for merge in getattr(self, 'hostbus_merges', {}).values():
                merge.finish()
        self.poll_fast()
        hostbus.close_all()          # nothing comes through the fast path after this
        for sub in list(self.subs.values()):
            try:
                self.destroy_subscription(sub)
            except Exception:  # noqa: BLE001 - context may be gone already
                pass
        extra = {'skipped_topics': self.skipped}
        merges = getattr(self, 'hostbus_merges', {})
        if merges:       # how each fast topic reached the bag (PERFORMANCE.md 15.)
            extra['fast_path'] = {t: m.counters() for t, m in merges.items()}
        if self.progress_pub is not None:
            extra['progress_held'] = self.progress_held
        report = self.writer.close(extra)
        print_report(report)
        return report


def print_report(report: dict, file=sys.stdout) -> None:
    print(f"bag {report['bag']}: {report['message_count']} messages", file=file)
    for name, d in report['topics'].items():
        print(f'  {name}: {d["text"]}', file=file)
    for name, c in report.get('fast_path', {}).items():
        print(f"  {name}: same-host fast path {c['fast']}, DDS {c['dds']} "
              f"(returns to DDS {c['resyncs']}, skipped by DDS and taken from the fast path "
              f"{c['recovered']})", file=file)
    if report.get('progress_held'):
        print(f"  lockstep progress held back {report['progress_held']} time(s) while a fast topic "
              f"waited for DDS", file=file)
    for name, why in report.get('skipped_topics', {}).items():
        print(f'  {name}: NOT RECORDED ({why})', file=file)
    if report.get('writer_error'):
        print(f"  WRITER ERROR: {report['writer_error']}", file=file)
    file.flush()


def run_recorder(out_dir: str, topics: list[str] | None, record_all: bool,
                 progress: str | None = None) -> int:
    """The ``record`` process: record until SIGINT/SIGTERM, then drain (:meth:`Recorder.drain`)
    and close the bag. rclpy's own signal handlers are off, so the context stays usable while
    draining. Priority from the environment (``rwpend_ros.common.apply_scheduling``)."""
    import signal
    import threading

    import rclpy
    from rclpy.signals import SignalHandlerOptions

    from rwpend_ros.common import apply_scheduling, freeze_gc, make_executor
    from rwpend_ros.transport import apply_transport_or_exit
    apply_transport_or_exit()  # before rclpy.init
    try:
        hostbus.recorder_enabled()
    except ValueError as exc:
        print(f'rwpend record: {exc}', file=sys.stderr)
        return 2
    apply_scheduling()
    # the bag-writer thread works through its queue in batches (ThreadedBagWriter.poll_s):
    # hand the GIL over to the receiving thread within 0.5 ms (default 5 ms), so a batch does
    # not delay the receive times that become the bag's log times
    sys.setswitchinterval(0.0005)
    rclpy.init(args=[], signal_handler_options=SignalHandlerOptions.NO)
    stop = threading.Event()
    signals = [0]

    def on_signal(*_):
        signals[0] += 1
        stop.set()
    old = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    node = None
    try:
        node = Recorder(out_dir, topics, record_all, progress)
        if node.dds_info:      # the message info (DDS's reception times): see Recorder
            from rclpy.executors import SingleThreadedExecutor
            executor = SingleThreadedExecutor()
        else:
            executor = make_executor()
        executor.add_node(node)
        freeze_gc()
        while not stop.is_set() and rclpy.ok():
            executor.spin_once(timeout_sec=0.1)
        if rclpy.ok():
            node.drain(executor, abort=lambda: signals[0] > 1)
    except KeyboardInterrupt:  # pragma: no cover - handlers are ours
        pass
    finally:
        if node is not None:
            node.close()
            node.destroy_node()
        rclpy.try_shutdown()
        for sig, h in old.items():
            signal.signal(sig, h)
    return 0
