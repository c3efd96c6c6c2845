"""ROS glue shared by every rwpend node: QoS profiles, rig parameters, executor, process life.

Nodes stay thin: algorithms live in the pure packages (rwpend_model, rwpend_estimation,
rwpend_control, ...); this module only deals with rclpy.
"""
from __future__ import annotations

import os
import sys
import threading
from typing import Any, Callable, Iterable, Mapping

import rclpy
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from rwpend_model.rig import Rig, default_rig_file, read_params_file
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
#: Latched state (e-stop): a late joiner gets the last value.
QOS_LATCHED = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST,
                         depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)


class LocalPublisher:
    """A publisher whose messages reach the subscribers of :func:`local_subscription` in this
    process directly (the in-process bus, :mod:`rwpend_ros.intra`), then DDS as usual. Takes
    wire bytes (the per-sample path) or message objects; everything else is the rclpy
    publisher's (``get_subscription_count`` ...)."""

    def __init__(self, node, msg_type, topic: str, qos) -> None:
        self.pub = node.create_publisher(msg_type, topic, qos)
        self.topic = self.pub.topic_name

    def publish(self, msg) -> None:
        if not isinstance(msg, (bytes, bytearray)):
            if not BUS.local(self.topic):
                self.pub.publish(msg)
                return
            from rclpy.serialization import serialize_message
            msg = serialize_message(msg)
        BUS.publish(self.topic, bytes(msg), self.pub.publish)

    def __getattr__(self, name):
        if name == 'pub':           # not built (the publisher's creation failed)
            raise AttributeError(name)
        return getattr(self.pub, name)


def local_subscription(node, msg_type, topic: str, callback: Callable[[bytes], None], qos,
                       before_dds: bool = True):
    """A raw subscription (``callback`` takes wire bytes) that also takes the messages of a
    :class:`LocalPublisher` of another node of this process directly, without the DDS hop
    (:mod:`rwpend_ros.intra`; the DDS copy of those is dropped); ``before_dds`` see
    :meth:`rwpend_ros.intra.LocalBus.subscribe`. Returns the rclpy subscription."""
    holder = []
    sub = node.create_subscription(msg_type, topic, lambda data: holder[0].from_dds(data), qos, raw=True)
    holder.append(BUS.subscribe(sub.topic_name, callback, before_dds))
    return sub


class ConfigError(ValueError):
    """A node's configuration (parameters) is invalid: the node reports it and exits with status 2."""


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
    ``RWPEND_TRANSPORT``).
    """
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


def diagnostic_status(name: str, hardware_id: str, level: int, message: str,
                      values: Mapping[str, Any] | Iterable[tuple[str, Any]] = ()) -> DiagnosticStatus:
    """A DiagnosticStatus (level: DiagnosticStatus.OK/WARN/ERROR/STALE) with string key-values."""
    items = values.items() if isinstance(values, Mapping) else values
    return DiagnosticStatus(level=bytes([level]) if isinstance(level, int) else level, name=name,
                            hardware_id=hardware_id, message=message,
                            values=[KeyValue(key=str(k), value=str(v)) for k, v in items])


def stamp_to_ns(stamp) -> int:
    """builtin_interfaces/Time -> integer nanoseconds."""
    return stamp.sec * 1_000_000_000 + stamp.nanosec
