"""ROS glue shared by every rwpend node: QoS profiles, rig parameters, executor, process life.

Nodes stay thin: algorithms live in the pure packages (rwpend_model, rwpend_estimation,
rwpend_control, ...); this module only deals with rclpy.
"""
from __future__ import annotations

import functools
import os
import struct
import sys
import threading
from typing import Any, Callable, Iterable, Mapping

import rclpy
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.clock import Clock, ClockType
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.time import Time

from rwpend_model.rig import Rig, default_rig_file, read_params_file, typed_like
from rwpend_ros import hostbus, wire
from rwpend_ros.hostbus import CALLBACK_LOCK
from rwpend_ros.intra import BUS
from rwpend_ros.sched import apply_scheduling  # noqa: F401 - re-exported (pure module)
from rwpend_ros.transport import apply_transport_or_exit

#: Control path (encoders, command, state, joint_states): reliable, keep-last 1000 on both
#: sides. Reliable delivery lost no samples across processes in our measurements
#: (ENVIRONMENT.md) and lets a reliable recorder match every publisher; the depth of 1000 (1 s at
#: 1 kHz) is what survives a stalled reader: with depth 10, a recorder stalled 40-60 ms by a
#: loaded CPU lost 150 of 10000 samples and an estimator fed by the player 60 (measured). A
#: reader that falls behind works through the backlog in order; the plant ignores commands
#: answering an older sample than the newest it holds.
QOS_CONTROL = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST,
                         depth=1000, durability=DurabilityPolicy.VOLATILE)
#: Publishers of the control path: reliable, keep-last 100. The depth that protects a stalled
#: reader is its own (subscriptions keep 1000: a sample, once delivered, waits in
#: the reader's history); the writer's history only serves repairs. With 1000 here, every
#: publisher of a 1 kHz topic stalled for 1.5-2.5 ms about once a second (once per history's
#: worth of samples), which made ~1 % of the commands late; with 100 the stalls are gone
#: (PERFORMANCE.md).
QOS_CONTROL_PUB = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST,
                             depth=100, durability=DurabilityPolicy.VOLATILE)
#: The controller's input (state): reliable, keep-last 5. A controller that fell behind acts on
#: the newest state and drops the older ones, instead of working through a backlog of stale
#: states (in real time an old state is worse than none; the plant's timeout covers the gap).
#: The estimator keeps QOS_CONTROL: every sample feeds its observers.
QOS_CONTROL_LATEST = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST,
                                depth=5, durability=DurabilityPolicy.VOLATILE)
#: Status and diagnostics.
QOS_STATUS = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST,
                        depth=100, durability=DurabilityPolicy.VOLATILE)
#: The recorder's progress in lockstep (``--progress``: the newest /clock it took, every
#: RECORDER_PROGRESS_EVERY of them) and the simulator's subscription to it.
QOS_PROGRESS = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST,
                          depth=10, durability=DurabilityPolicy.VOLATILE)
RECORDER_PROGRESS_EVERY = 10
#: bounds of the simulator's lockstep_recorder_window (samples): above twice the recorder's
#: reporting step (else the run could wait for a report that only comes later), below the
#: publishers' depth (QOS_CONTROL_PUB, 100) less that step (a reader that lags more loses samples)
RECORDER_WINDOW_MIN = 2 * RECORDER_PROGRESS_EVERY
RECORDER_WINDOW_MAX = 80
#: Latched state (e-stop): a late joiner gets the last value.
QOS_LATCHED = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST,
                         depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)


def locked(callback, owner=None):
    """``callback`` run holding :data:`rwpend_ros.hostbus.CALLBACK_LOCK` (also a decorator);
    with ``owner`` (its node), as a callback of that node for the in-process bus
    (:meth:`rwpend_ros.intra.LocalBus.call`: a message the bus has for the node meanwhile waits
    until it returns)."""
    if callback is None:
        return None

    def run(*args, **kwargs):
        with CALLBACK_LOCK:
            if owner is None:
                return callback(*args, **kwargs)
            return BUS.call(owner, callback, *args, **kwargs)
    run.__wrapped__ = callback
    return run


class LockedCallbacks:
    """Mixin for an rclpy Node class: its callbacks (subscriptions, timers, services, parameter
    callbacks, and those rclpy makes itself through these methods: parameter services,
    ``/clock``) all run holding the process's :data:`rwpend_ros.hostbus.CALLBACK_LOCK`, which
    the same-host fast path's receiving threads hold too: a node's callbacks run one at a time
    whichever thread runs them. (A LifecycleNode makes its state services without these
    methods: decorate its transition callbacks with :func:`locked`.)"""

    def create_subscription(self, msg_type, topic, callback, *args, **kwargs):
        return super().create_subscription(msg_type, topic, locked(callback, self), *args, **kwargs)

    def create_timer(self, timer_period_sec, callback, *args, **kwargs):
        return super().create_timer(timer_period_sec, locked(callback, self), *args, **kwargs)

    def create_service(self, srv_type, srv_name, callback, *args, **kwargs):
        return super().create_service(srv_type, srv_name, locked(callback, self), *args, **kwargs)

    def add_on_set_parameters_callback(self, callback):
        return super().add_on_set_parameters_callback(locked(callback, self))

    def add_pre_set_parameters_callback(self, callback):
        return super().add_pre_set_parameters_callback(locked(callback, self))

    def add_post_set_parameters_callback(self, callback):
        return super().add_post_set_parameters_callback(locked(callback, self))


class SlackTimer:
    """A periodic timer of a loop node whose work must not delay a sample (diagnostics: 0.35-0.6
    ms of CPU holding the callback lock and the GIL on the project's machine, measured:
    PERFORMANCE.md, 19.). While the loop runs (:meth:`sample_done` was called since the last
    tick) the tick only marks the work due, and the next per-sample callback hands it to
    :meth:`rwpend_ros.intra.LocalBus.after`: it runs right after that callback (in a composed
    process, after the sample's chain), in the slack of the period. When no sample came since
    the last tick the work runs at the tick, as a plain timer's would; so it never waits
    longer than one period more than the timer alone. Events that must be reported at once
    (an e-stop, a stale state) do not go through it."""

    def __init__(self, node, period: float, fn: Callable[[], None]) -> None:
        self.fn = fn
        self.samples = 0         # per-sample callbacks that reported (sample_done)
        self._seen = 0           # ... as of the last tick
        self.due = False
        self.in_slack = 0        # runs in the loop's slack
        self.at_tick = 0         # runs at the tick (no loop running)
        node.create_timer(period, self._tick)

    def _tick(self) -> None:
        if self.samples != self._seen:
            self._seen = self.samples
            self.due = True
        else:
            self.due = False
            self.at_tick += 1
            self.fn()

    def sample_done(self) -> None:
        """Called at the end of the node's per-sample callback (holding the callback lock)."""
        self.samples += 1
        if self.due:
            self.due = False
            self.in_slack += 1
            BUS.after(self.fn)


class RwNode(LockedCallbacks, Node):
    """rclpy Node with :class:`LockedCallbacks` (the simulator, estimator and controller)."""


TIME_FROM_SAMPLES_DOC = (
    'lockstep: with use_sim_time, the node\'s ROS time is the stamp of the newest sample it '
    'took (the simulator stamps sample k with its sim time k h, the /clock it publishes next) '
    'instead of /clock, which it then does not subscribe to: one message less per sample '
    '(./rwpend up --lockstep sets it)')


class SampleTime:
    """A node's ROS time from the stamps of the samples it takes (``time_from_samples``).

    In lockstep the simulator publishes sample k stamped with its sim time t_k, then ``/clock``
    = t_k. A node of the loop can take t_k from the sample itself: rclpy's ``/clock``
    subscription (a DDS message, a Python message object and a callback per sample, in every
    node, all competing with the loop for the CPU) is then left out. Measured in lockstep,
    separate processes: 2.5-2.9x -> 3.9-4.4x real time, CPU 0.66-0.77 -> 0.34-0.38 s per
    simulated s (PERFORMANCE.md, 15.). The time only moves forward; timers on the ROS clock
    fire as with ``/clock`` (the same rclpy override). What ``/clock`` gives and this does
    not: time moving while no sample comes (a controller's stale-state watchdog cannot see
    the estimator stop -- in lockstep the simulator's ``lockstep_timeout`` zeroes the motor
    and counts it instead)."""

    def __init__(self, node) -> None:
        ts = getattr(node, '_time_source', None)
        if ts is None or not hasattr(ts, '_associated_clocks') or not hasattr(ts, '_clock_sub'):
            raise ConfigError('time_from_samples: this rclpy has no TimeSource internals to feed '
                              '(use /clock: time_from_samples false)')
        self._ts = ts
        self._node = node
        self.last_ns = -1
        self._drop_clock_subscription()

    def _drop_clock_subscription(self) -> None:
        sub, self._ts._clock_sub = self._ts._clock_sub, None
        if sub is not None:
            self._node.destroy_subscription(sub)

    def __call__(self, data: bytes) -> None:
        """Advance the node's ROS time to the stamp of ``data`` (wire bytes of a message that
        starts with a Header); an older or malformed stamp changes nothing."""
        try:
            ns = wire.message_stamp_ns(data)
        except struct.error:
            return
        if ns <= self.last_ns:
            return
        self.last_ns = ns
        if self._ts._clock_sub is not None:      # use_sim_time was set again at run time
            self._drop_clock_subscription()
        t = Time(nanoseconds=ns, clock_type=ClockType.ROS_TIME)
        self._ts._last_time_set = t
        for clock in self._ts._associated_clocks:
            clock.set_ros_time_override(t)


def sample_time(node) -> SampleTime | None:
    """Declare ``time_from_samples`` (read-only, default false) on ``node``; a
    :class:`SampleTime` when it is true, None otherwise. ConfigError when it is true without
    ``use_sim_time``."""
    node.declare_parameter('time_from_samples', False, ParameterDescriptor(
        read_only=True, dynamic_typing=True, description=TIME_FROM_SAMPLES_DOC))
    value = node.get_parameter('time_from_samples').value
    if not isinstance(value, bool):
        raise ConfigError(f'time_from_samples must be a bool, got {value!r}')
    if not value:
        return None
    if node.get_parameter('use_sim_time').value is not True:
        raise ConfigError('time_from_samples needs use_sim_time:=true (it replaces /clock as the '
                          'source of sim time)')
    return SampleTime(node)


#: how often (s, steady clock) a publisher with the same-host fast path looks at its number of
#: subscribers; the graph is read when it changed, when a receiver was dropped, and every
#: HOST_RETRY_PERIOD s (a receiver absent at the last reading may have come since) -- at every
#: look for HOST_SETTLE_PERIOD s after the number changed while the fast path reaches fewer
#: subscribers than DDS matched (the graph and the matching come apart at start-up: a
#: subscriber missing from one reading would otherwise get every message through DDS, and its
#: publisher write them all, for HOST_RETRY_PERIOD s; PERFORMANCE.md, 17.)
HOST_REFRESH_PERIOD = 0.25
HOST_RETRY_PERIOD = 2.0
HOST_SETTLE_PERIOD = 2.0


def qos_matches(pub, sub) -> bool:
    """Whether DDS matches a subscription of QoS ``sub`` with a publisher of QoS ``pub`` as to
    reliability and durability (the policies our topics set; rclpy's ``qos_check_compatible``
    is not usable with the profiles of the graph: their deadline and lease read 'Infinite'
    where the publisher's read 'default', and it calls them incompatible)."""
    if pub.reliability == ReliabilityPolicy.BEST_EFFORT and sub.reliability == ReliabilityPolicy.RELIABLE:
        return False
    return not (pub.durability == DurabilityPolicy.VOLATILE and sub.durability == DurabilityPolicy.TRANSIENT_LOCAL)


class LocalPublisher:
    """A publisher of the loop's wire bytes: a message first goes to the subscribers of
    :func:`local_subscription` in other processes of this host (:mod:`rwpend_ros.hostbus`,
    ``host=True``), then to those in this process (:mod:`rwpend_ros.intra`), then to DDS as
    usual. Takes wire bytes (the per-sample path) or message objects; everything else is the
    rclpy publisher's (``get_subscription_count`` ...). ``publish`` may be called from another
    thread than the executor's (the simulator's sample loop)."""

    def __init__(self, node, msg_type, topic: str, qos, host: bool = True, intra: bool = True) -> None:
        self.pub = node.create_publisher(msg_type, topic, qos)
        self.topic = self.pub.topic_name
        #: to subscribers of this process through the in-process bus (False: through DDS)
        self.intra = intra
        self.sender: hostbus.Sender | None = None
        self.dds_writes = 0     # messages written to DDS (the others went by the fast path only)
        if host and hostbus.enabled():
            self.sender = hostbus.Sender()
            if not hasattr(node, 'hostbus_publishers'):
                node.hostbus_publishers = {}
            node.hostbus_publishers[self.topic] = self
            self._node = node
            self._domain = node.context.get_domain_id()
            self._count = -1
            self._ticks = 0
            self._seen = -1          # the number of subscribers at the last look ...
            self._steady = 0         # ... and for how many looks it has not changed
            node.create_timer(HOST_REFRESH_PERIOD, self._refresh, clock=Clock(clock_type=ClockType.STEADY_TIME))

    def _refresh(self) -> None:
        """Targets of the fast path from the graph (the subscribers' node names; a subscription
        whose QoS does not match the publisher's gets nothing from DDS, nor from here)."""
        count = self.pub.get_subscription_count()
        self._ticks += 1
        if count != self._seen:
            self._seen, self._steady = count, 0
        else:
            self._steady += 1
        # a subscriber not reached directly: the graph is read again while the number settles,
        # and then every HOST_RETRY_PERIOD s (one absent at the last reading may have come
        # since) -- only then: a reading holds the lock and the GIL for 0.02-0.56 ms
        # (PERFORMANCE.md, 19.)
        missing = len(self.sender.targets) + len(self.local_subscribers()) < count
        settling = missing and self._steady * HOST_REFRESH_PERIOD < HOST_SETTLE_PERIOD
        if (count == self._count and not self.sender.dropped and not settling
                and (not missing or self._ticks * HOST_REFRESH_PERIOD < HOST_RETRY_PERIOD)):
            return
        try:
            infos = self._node.get_subscriptions_info_by_topic(self.topic)
            qos = self.pub.qos_profile
            infos = [i for i in infos if qos_matches(qos, i.qos_profile)]
        except Exception:  # noqa: BLE001 - node or context going away: keep the targets
            return
        # the graph may not show every subscriber DDS has matched yet: then look again at the
        # next tick (not HOST_RETRY_PERIOD later), or the one missing gets DDS alone meanwhile
        self._count = count if len(infos) >= count else -1
        self._ticks = 0
        self.sender.set_targets(
            hostbus.address(self._domain, self.topic, hostbus.node_fqn(info.node_namespace, info.node_name))
            for info in infos)

    def publish(self, msg) -> None:
        """Fast path first (:meth:`rwpend_ros.hostbus.Sender.send`), then this process's
        subscribers and DDS. The DDS write is left out (*fast only*) when every subscription
        DDS matched is one the message reaches directly: a fast-path target it just reached or
        a subscriber of this process the bus delivers it to now (as many matched as those), and
        the targets unchanged since the last DDS write (so a new subscriber gets one message
        through DDS first, the marker its merge syncs on). Any other reader on the topic (one
        of this process the bus does not serve from this thread, a recorder reading DDS, a
        node on another host) keeps every message on DDS."""
        sender = self.sender
        if not isinstance(msg, (bytes, bytearray)):
            if not (sender is not None and sender.targets) and not self.local_subscribers():
                self.pub.publish(msg)
                return
            from rclpy.serialization import serialize_message
            msg = serialize_message(msg)
        data = hostbus.pad4(bytes(msg))    # the bytes DDS delivers across processes
        if sender is not None and sender.targets:
            local = self.local_subscribers()
            fast_only = (not sender.fresh
                         and self.pub.get_subscription_count() == len(sender.targets) + len(local))
            # first: the other process starts while this one goes on
            if sender.send(data, fast_only, sender.marker) and fast_only:
                if local:
                    BUS.publish(self.topic, data, _no_dds_write)
                return
        if self.intra:
            BUS.publish(self.topic, data, self.pub.publish)
        else:
            self.pub.publish(data)
        self.dds_writes += 1
        if sender is not None:      # the marker of what follows: the last DDS write, whatever
            sender.marker = data    # the targets were
            sender.fresh = False

    def local_subscribers(self) -> list:
        """The subscribers of this process a publish from this thread reaches through the
        in-process bus (none with ``intra=False``)."""
        return BUS.local(self.topic) if self.intra else []

    def __getattr__(self, name):
        if name == 'pub':           # not built (the publisher's creation failed)
            raise AttributeError(name)
        return getattr(self.pub, name)


def _no_dds_write(data: bytes) -> None:
    """LocalPublisher.publish, fast only: the bus delivers, DDS is left out."""


def local_subscription(node, msg_type, topic: str, callback: Callable[[bytes], None], qos,
                       before_dds: bool = True, intra: bool = True, host: bool = True,
                       polled: bool = False, dds_info: bool = False):
    """A raw subscription (``callback`` takes wire bytes, holding
    :data:`rwpend_ros.hostbus.CALLBACK_LOCK`) that also takes the messages of a
    :class:`LocalPublisher` directly: from another node of this process (``intra``,
    :mod:`rwpend_ros.intra`; ``before_dds`` see :meth:`rwpend_ros.intra.LocalBus.subscribe`) and
    from another process of this host (``host``, :mod:`rwpend_ros.hostbus`, received by a
    thread of its own). Each message is delivered once, in the publisher's order (the DDS copies
    of those are dropped). ``polled``: the fast path's receiver has no thread of its own
    (:class:`rwpend_ros.hostbus.Receiver`, the recorder). ``dds_info``: a message from DDS is
    delivered with the time DDS received it as :func:`rwpend_ros.hostbus.delivery_stamp` (the
    rclpy message info: not with rclpy 7.1.6's EventsExecutor, which fails on such callbacks --
    the recorder runs a SingleThreadedExecutor then). Returns the rclpy subscription; the
    fast path's :class:`rwpend_ros.hostbus.Merge` is in ``node.hostbus_merges[topic]``, its
    receiver in ``node.hostbus_receivers[topic]``."""
    topic_name = node.resolve_topic_name(topic)
    local = BUS.subscribe(topic_name, callback, before_dds, owner=node) if intra else None
    deliver = local.run if local is not None else functools.partial(BUS.call, node, callback)
    merge = receiver = None
    if host and hostbus.enabled():
        # bound before the subscription shows in the graph: a publisher that sees it can send
        # a polled subscriber (the recorder) waits as long as it takes for a message that went
        # to it through DDS alone (its socket was full: DDS lags then), rather than reorder
        merge = (hostbus.Merge(deliver, hold=hostbus.KEEP, keep=hostbus.KEEP_POLLED) if polled
                 else hostbus.Merge(deliver, hold=hostbus.HOLD))
        addr = hostbus.address(node.context.get_domain_id(), topic_name, node.get_fully_qualified_name())
        depth = qos.depth if qos.history == HistoryPolicy.KEEP_LAST else 1 << 30
        try:
            receiver = hostbus.Receiver(addr, merge, depth, on_error=_host_callback_failed,
                                        on_start=BUS.extra_threads.add, polled=polled)
        except OSError as exc:
            node.get_logger().warn(f'{topic_name}: no same-host fast path ({exc}); DDS only')
            merge = None
    if local is not None and merge is not None:
        local.sink = merge.from_dds         # in-process copies dropped first, then the merge
    take = local.from_dds if local is not None else merge.from_dds if merge is not None else deliver

    def from_dds(data):
        with CALLBACK_LOCK:
            take(data)

    def from_dds_info(data, info):
        with CALLBACK_LOCK:
            before = hostbus.set_stamp(info.get('received_timestamp') or 0)
            try:
                take(data)
            finally:
                hostbus.set_stamp(before)
    try:
        sub = Node.create_subscription(node, msg_type, topic, from_dds_info if dds_info else from_dds,
                                       qos, raw=True)
    except BaseException:
        if receiver is not None:
            receiver.close()
        if local is not None:
            BUS.unsubscribe(topic_name, local)
        raise
    if merge is not None:
        if not hasattr(node, 'hostbus_merges'):
            node.hostbus_merges = {}
            node.hostbus_receivers = {}
        node.hostbus_merges[topic_name] = merge
        node.hostbus_receivers[topic_name] = receiver
    return sub


def fast_path_values(node) -> dict[str, str]:
    """Diagnostics key-values of ``node``'s same-host fast path: one per subscription
    (messages delivered fast / through DDS, DDS copies dropped, returns to DDS: resyncs, fast
    ones DDS skipped: recovered) and one
    per publisher (datagrams sent, sends that failed -- a receiver's socket full --, messages
    also written to DDS)."""
    values = {f'fast_path {topic}': (f"fast {c['fast']}, dds {c['dds']}, duplicates {c['duplicates']}, "
                                     f"skipped {c['skipped']}, resyncs {c['resyncs']}, recovered {c['recovered']}")
              for topic, c in ((t, m.counters()) for t, m in getattr(node, 'hostbus_merges', {}).items())}
    for topic, pub in getattr(node, 'hostbus_publishers', {}).items():
        sender = pub.sender
        values[f'fast_path_out {topic}'] = (f'sent {sender.sent}, failed {sender.failed}, '
                                            f'dds writes {pub.dds_writes}')
    return values


#: an exception raised by a callback on a fast-path receiving thread (re-raised by spin_executor)
_HOST_ERRORS: list[BaseException] = []


def _host_callback_failed(exc: BaseException) -> None:
    _HOST_ERRORS.append(exc)


class ConfigError(ValueError):
    """A node's configuration (parameters) is invalid: the node reports it and exits with status 2."""


def declare_read_only(node, params: dict) -> dict:
    """Declare ``params`` ({name: (default, description)}) read-only on ``node`` and return their
    values, each of its default's type (:func:`rwpend_model.rig.typed_like`): a value of another type is refused
    with a ConfigError naming it, rather than rclpy's InvalidParameterTypeException from the
    node's constructor."""
    values = {}
    for name, (default, descr) in params.items():
        node.declare_parameter(name, default, ParameterDescriptor(description=descr, read_only=True,
                                                                  dynamic_typing=True))
        try:
            values[name] = typed_like(name, node.get_parameter(name).value, default)
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
    return values


def declare_rig(node) -> Rig:
    """Declare every ``rig.*`` parameter (read-only, defaults from the rig YAML) and return the Rig.

    Values come from the params file / overrides given to the node; the shipped rig YAML only
    provides the defaults. Raises ConfigError with the reasons when the values are invalid.
    """
    defaults = read_params_file(default_rig_file())
    names = []
    for name, value in defaults.items():
        if not name.startswith('rig.'):
            continue
        node.declare_parameter(name, value, ParameterDescriptor(
            read_only=True, dynamic_typing=True,
            description='rig parameter (rwpend_model/config/rig.yaml)'))
        names.append(name)
    values = {name: node.get_parameter(name).value for name in names}
    try:
        return Rig.from_params(values)
    except ValueError as exc:
        raise ConfigError(str(exc)) from exc


def make_executor():
    """The executor for a node process.

    rclpy's EventsExecutor by default (lockstep loop measured 3x faster than with the
    SingleThreadedExecutor; ENVIRONMENT.md: 1.5x lower ring latency), ``RWPEND_EXECUTOR=single``
    for the SingleThreadedExecutor. Known limits of the EventsExecutor in rclpy 7.1.6, which our
    nodes avoid: its ``spin()`` fires no timer and ignores shutdown (0 callbacks of a 10 ms timer
    in 1 s at 100 % CPU) -- drive it with :func:`spin_executor` (``spin_once``); and a one-shot
    timer destroyed inside its own callback made ``spin_once`` raise "Unable to convert call
    argument '0'" -- nodes keep their timers for their whole life.
    """
    if os.environ.get('RWPEND_EXECUTOR', 'events') != 'single':
        try:
            from rclpy.experimental import EventsExecutor
            return EventsExecutor()
        except ImportError:  # pragma: no cover - older rclpy
            pass
    return SingleThreadedExecutor()


def spin_executor(executor, until: Callable[[], bool] | None = None) -> None:
    """Spin ``executor`` until rclpy shuts down (SIGINT/SIGTERM) or ``until()`` is true."""
    while rclpy.ok() and not (until is not None and until()):
        if _HOST_ERRORS:     # a callback failed on a fast-path thread: as if on the executor's
            raise _HOST_ERRORS.pop(0)
        try:
            executor.spin_once(timeout_sec=0.1)
        except ExternalShutdownException:
            break   # SIGINT/SIGTERM shut the context down while waiting: the normal end
        except RuntimeError:
            # rclpy 7.1.6's executors raise "Unable to convert call argument '0'" when the
            # context is shut down (SIGINT) during spin_once: a normal end, not an error. The
            # shutdown may still be completing when the error arrives (seen once in ~400 stops:
            # rclpy.ok() still true), so give it a moment before calling it an error.
            if _shutdown_completes(0.5):
                break
            raise


def _shutdown_completes(within: float) -> bool:
    """True once rclpy's context is shut down, waiting up to ``within`` s for it."""
    import time
    deadline = time.monotonic() + within
    while rclpy.ok():
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.01)
    return True


def freeze_gc() -> None:
    """Collect once, then move every object alive now (modules, nodes, ...) out of the cyclic
    garbage collector's reach (``gc.freeze``): a full collection of a node process otherwise
    walks ~40 000 objects and stalls it for milliseconds (measured 2.7 ms for generation 1 and
    32 ms for generation 2 in an estimator + controller process), which shows up as late samples.
    Later garbage is still collected. ``RWPEND_GC_FREEZE=0`` turns it off (for comparisons)."""
    if os.environ.get('RWPEND_GC_FREEZE', '1') != '0':
        import gc
        gc.collect()
        gc.freeze()


def run_node(factory: Callable[[], Any], args: list[str] | None = None) -> int:
    """Run one node in this process until SIGINT/SIGTERM; returns the exit status
    (:func:`run_nodes` with one factory)."""
    return run_nodes([factory], args)


def run_nodes(factories: Iterable[Callable[[], Any]], args: list[str] | None = None) -> int:
    """Run nodes in this process on one executor until SIGINT/SIGTERM; returns the exit status.

    The factories build the nodes in the given order (after rclpy.init); the nodes are closed
    and destroyed in the reverse order. A ConfigError while building is printed and gives
    status 2. A node may define ``close()``, called before destruction (e.g. to zero the motor
    or finalise a file). Priority / affinity: :func:`apply_scheduling`; DDS transport:
    :func:`rwpend_ros.transport.apply_transport` (UDP by default; exit status 2 for a bad
    ``RWPEND_TRANSPORT``, and for an ``RWPEND_HOST_BUS`` other than 0 or 1, before anything is
    changed).
    """
    try:
        hostbus.enabled()       # a bad RWPEND_HOST_BUS: refused before anything is changed
    except ValueError as exc:
        print(f'error: {exc}', file=sys.stderr, flush=True)
        return 2
    apply_transport_or_exit()   # before rclpy.init: Fast DDS reads it when the participant is made
    apply_scheduling()   # before rclpy.init: the DDS threads inherit it
    rclpy.init(args=args)
    nodes = []
    status = 0
    try:
        for factory in factories:
            nodes.append(factory())
        executor = make_executor()
        for node in nodes:
            executor.add_node(node)
        freeze_gc()
        BUS.thread = threading.get_ident()   # in-process delivery on this (the executor's) thread
        spin_executor(executor)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except ConfigError as exc:
        print(f'error: {exc}', file=sys.stderr, flush=True)
        status = 2
    finally:
        hostbus.close_all()
        BUS.reset()
        for node in reversed(nodes):
            close = getattr(node, 'close', None)
            if callable(close):
                try:
                    close()
                except Exception as exc:  # noqa: BLE001 - report, keep shutting down
                    print(f'error while closing {node.get_name()}: {exc}', file=sys.stderr, flush=True)
        for node in nodes:
            trace = getattr(node, 'trace', None)    # rwpend_ros.trace (RWPEND_TRACE set)
            if trace is not None:
                try:
                    trace.dump()
                except OSError as exc:
                    print(f'trace of {node.get_name()} not written: {exc}', file=sys.stderr, flush=True)
        for node in reversed(nodes):
            try:
                node.destroy_node()
            except Exception:  # noqa: BLE001 - the context may be gone
                pass
        rclpy.try_shutdown()
    return status


def publish_diagnostic(pub, stamp_ns: int, name: str, hardware_id: str, level, message: str,
                       values: Mapping[str, Any] | Iterable[tuple[str, Any]] = ()) -> None:
    """One DiagnosticStatus (``level``: ``DiagnosticStatus.OK`` / ``WARN`` / ``ERROR`` / ``STALE``
    or 0-3; ``values``: key-values, each turned into text with ``str()``) in a DiagnosticArray
    stamped ``stamp_ns``, published as wire bytes (:func:`rwpend_ros.wire.pack_diagnostic_array`),
    without building the message as rclpy objects (PERFORMANCE.md, 19.)."""
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    pub.publish(wire.pack_diagnostic_array(sec, nanosec, [(level, name, message, hardware_id, values)]))


def stamp_to_ns(stamp) -> int:
    """builtin_interfaces/Time -> integer nanoseconds."""
    return stamp.sec * 1_000_000_000 + stamp.nanosec
