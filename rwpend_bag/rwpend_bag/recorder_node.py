"""Recorder node ``recorder``: raw (serialized) subscriptions to any topic, written to a bag.

Thin rclpy layer over :class:`rwpend_bag.writer.ThreadedBagWriter`: the subscription callbacks
only enqueue (topic, wire bytes, the time the callback took it); a writer thread does the MCAP
work. Topics that appear later are picked up (graph polled every 0.5 s). Each subscription
uses the publishers' reliability/durability and a keep-last 1000 history.

Log times (:mod:`rwpend_bag.logtime`), in log-time order in the file whatever happens:

* real time (default): the time the callback took the message (the system clock; a clock
  stepped back is counted in the report, never written backwards);
* ``sim_time`` (``rwpend record --sim-time``, set by ``./rwpend up --lockstep --record``): on
  the simulated clock -- the header stamp, /clock's value, else the newest /clock -- in a
  deterministic order (:class:`rwpend_bag.logtime.SimTimeOrder`).

``progress`` (``rwpend record --progress TOPIC``, set by ``./rwpend up --lockstep --record``): every
:data:`rwpend_ros.qos.RECORDER_PROGRESS_EVERY` ``/clock`` messages taken (handed to the bag
writer, whose queue loses nothing), that ``/clock`` is published on TOPIC; a lockstep simulator
keeps within its ``lockstep_recorder_window`` of it, so a recorder that falls behind slows the
run down instead of losing messages.
"""
from __future__ import annotations

import sys
import time

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from rwpend_ros.qos import QOS_PROGRESS, RECORDER_PROGRESS_EVERY

from . import msgdefs
from .logtime import SimTimeOrder, describe
from .writer import INFINITE_TIME, ThreadedBagWriter

DEPTH = 1000
POLL_S = 0.5
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
                 progress: str | None = None, sim_time: bool = False, direct: dict | None = None,
                 writer_process=False):
        """``direct``: {topic: (type name, offered QoS list)} of topics whose messages are put
        into :attr:`writer` by their publishers in this process (rwpend_loop.host), not
        subscribed. ``writer_process``: the bag is written by a child process
        (:class:`rwpend_bag.procwriter.ProcessBagWriter`), not by a thread of this one -- the
        child started ahead when it is a :class:`~rwpend_bag.procwriter.WriterProcess`."""
        super().__init__('recorder')
        #: publisher of the progress (the newest /clock taken), None without --progress
        self.progress_pub = None
        self.progress_topic = None
        if progress:
            from rosgraph_msgs.msg import Clock
            self.progress_pub = self.create_publisher(Clock, progress, QOS_PROGRESS)
            self.progress_topic = self.progress_pub.topic_name
        self._clocks = 0
        order = SimTimeOrder() if sim_time else None
        if writer_process:
            from .procwriter import ProcessBagWriter, WriterProcess
            ahead = writer_process if isinstance(writer_process, WriterProcess) else None
            self.writer = ProcessBagWriter(out_dir, order=order, process=ahead)
        else:
            self.writer = ThreadedBagWriter(out_dir, order=order)
        self.wanted = set(topics or [])
        self.record_all = record_all
        self.subs: dict[str, object] = {}
        self.skipped: dict[str, str] = {}
        self._closed = False
        self._received = 0
        self.direct_received = 0
        self.direct = dict(direct or {})
        for name, (type_name, qos) in self.direct.items():
            self.writer.add_topic(name, type_name, qos)
        self.create_timer(POLL_S, self.discover)
        self.get_logger().info(f'recording to {out_dir} '
                               f'({"all topics" if record_all else ", ".join(sorted(self.wanted))}; '
                               f'log times: {"sim time" if sim_time else "receive time"})')
        self.discover()

    def discover(self) -> None:
        for name, types in self.get_topic_names_and_types():
            if name in self.subs or name in self.skipped or name == self.progress_topic or name in self.direct:
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
            self.subs[name] = self.create_subscription(
                cls, name, self._receiver(name, progress=name == '/clock'), qos, raw=True)
            self.get_logger().info(f'recording {name} [{type_name}] '
                                   f'{"reliable" if reliable else "best effort"}')

    def _receiver(self, name: str, progress: bool = False):
        """Callback of a topic: into the writer's queue with the callback's time (the writer
        keeps the log times in order); ``progress``: the recorder's progress is counted on it
        (/clock)."""
        taken = self._clock_taken if progress and self.progress_pub is not None else None

        def receive(data, _n=name, _put=self.writer.put, _now=time.time_ns, _taken=taken):
            _put(_n, data, _now())
            self._received += 1
            if _taken is not None:
                _taken(data)
        return receive

    def _clock_taken(self, data: bytes) -> None:
        """A /clock message is in the writer's queue: every RECORDER_PROGRESS_EVERY of them,
        published as the progress (the same bytes: rosgraph_msgs/Clock)."""
        self._clocks += 1
        if self._clocks % RECORDER_PROGRESS_EVERY == 0:
            self.progress_pub.publish(bytes(data))

    def drain(self, executor, idle: float = DRAIN_IDLE_S, limit: float = DRAIN_LIMIT_S,
              abort=lambda: False) -> int:
        """Keep taking messages until none arrived for ``idle`` s (at most ``limit`` s); returns how
        many were taken. Called when asked to stop: what the stack sent last (its final samples,
        still in the DDS queues of a recorder that runs behind) goes into the bag too."""
        n0 = last = self._received
        t_last = end = time.monotonic()
        end += limit
        while time.monotonic() < end and not abort():
            executor.spin_once(timeout_sec=0.02)
            n = self._received
            if n != last:
                last, t_last = n, time.monotonic()
            elif time.monotonic() - t_last >= idle:
                break
        return last - n0

    def close(self) -> dict:
        if self._closed:
            return {}
        self._closed = True
        for sub in list(self.subs.values()):
            try:
                self.destroy_subscription(sub)
            except Exception:  # noqa: BLE001 - context may be gone already
                pass
        report = self.writer.close({'skipped_topics': self.skipped})
        print_report(report)
        return report


def print_report(report: dict, file=sys.stdout) -> None:
    count = report.get('message_count')
    print(f"bag {report['bag']}: {'an unknown number of' if count is None else count} messages", file=file)
    for name, d in report['topics'].items():
        print(f'  {name}: {d["text"]}', file=file)
    for name, why in report.get('skipped_topics', {}).items():
        print(f'  {name}: NOT RECORDED ({why})', file=file)
    for line in describe(report.get('log_times', {})):
        print(f'  {line}', file=file)
    if report.get('writer_error'):
        print(f"  WRITER ERROR ({report.get('writer_errors', 1)}): {report['writer_error']}", file=file)
    file.flush()


def run_recorder(out_dir: str, topics: list[str] | None, record_all: bool,
                 progress: str | None = None, sim_time: bool = False) -> int:
    """The ``record`` process: record until SIGINT/SIGTERM, then drain (:meth:`Recorder.drain`)
    and close the bag. rclpy's own signal handlers are off, so the context stays usable while
    draining. Priority from the environment (``rwpend_ros.sched.apply_scheduling``)."""
    import signal
    import threading

    import rclpy
    from rclpy.signals import SignalHandlerOptions

    from rwpend_ros.runner import freeze_gc, make_executor
    from rwpend_ros.sched import apply_scheduling
    from rwpend_ros.transport import apply_transport_or_exit
    apply_transport_or_exit()  # before rclpy.init
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
        node = Recorder(out_dir, topics, record_all, progress, sim_time)
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
