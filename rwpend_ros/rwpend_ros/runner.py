"""A node process: the executor, the spin loop, the process's life from ``rclpy.init`` to the
exit status (:func:`run_node`); the loop's process of several nodes is rwpend_loop.host."""
from __future__ import annotations

import os
import signal
import sys
import threading
from typing import Any, Callable

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.signals import SignalHandlerOptions

from rwpend_ros.params import ConfigError, refuse_undeclared
from rwpend_ros.sched import apply_scheduling, set_process_priority
from rwpend_ros.transport import apply_transport_or_exit

def make_executor():
    """The executor for a node process: rclpy's EventsExecutor (lockstep loop measured 3x faster
    than with the SingleThreadedExecutor; ENVIRONMENT.md: 1.5x lower ring latency). Known limits
    of the EventsExecutor in rclpy 7.1.6, which our nodes avoid: its ``spin()`` fires no timer
    and ignores shutdown (0 callbacks of a 10 ms timer in 1 s at 100 % CPU) -- drive it with
    :func:`spin_executor` (``spin_once``); and a one-shot timer destroyed inside its own
    callback made ``spin_once`` raise "Unable to convert call argument '0'" -- nodes keep their
    timers for their whole life.
    """
    try:
        from rclpy.experimental import EventsExecutor
        return EventsExecutor()
    except ImportError:  # pragma: no cover - older rclpy
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


def apply_thread_priority(nodes) -> str | None:
    """The highest ``thread_priority`` parameter of ``nodes`` (rwpend_ros.sched), taken by the
    whole process; said on stderr. None when no node asks for one (0)."""
    prio = max((int(n.get_parameter('thread_priority').value) for n in nodes
                if n.has_parameter('thread_priority')), default=0)
    if not prio:
        return None
    done = set_process_priority(prio)
    print(f'rwpend: thread_priority {prio}: {done}', file=sys.stderr, flush=True)
    return done


def close_nodes(nodes) -> None:
    """``close()`` every node that has one, the last built first; an error is printed, the
    others are still closed."""
    for node in reversed(nodes):
        close = getattr(node, 'close', None)
        if callable(close):
            try:
                close()
            except Exception as exc:  # noqa: BLE001 - report, keep shutting down
                print(f'error while closing {node.get_name()}: {exc}', file=sys.stderr, flush=True)


def run_node(factory: Callable[[], Any], args: list[str] | None = None) -> int:
    """Run one node in this process until SIGINT/SIGTERM; returns the exit status.

    ``factory`` builds the node (after rclpy.init). A ConfigError while building is printed and
    gives status 2. The node may define ``close()``, called before destruction (e.g. to zero the
    motor or finalise a file), and ``exit_status()``, asked after it is closed: a non-zero value
    becomes the process's exit status (the loop was dead at the end,
    :data:`rwpend_ros.health.EXIT_LOOP_DEAD`). A node whose ``finished`` becomes True (the
    plant's ``duration`` reached) ends the process as a signal does: the spin stops, the node is
    closed, then the context is shut down. Priority / affinity: :func:`apply_scheduling`; DDS
    transport: :func:`rwpend_ros.transport.apply_transport` (UDP by default; exit status 2 for
    a bad ``RWPEND_TRANSPORT``, before anything is changed).
    """
    apply_transport_or_exit()   # before rclpy.init: Fast DDS reads it when the participant is made
    apply_scheduling()   # before rclpy.init: the DDS threads inherit it
    # SIGINT/SIGTERM end the spin, not the context (rclpy's own handlers would shut it down at
    # once): a node's close() may still publish -- the controller's release of the rig
    # (rwpend_ros.claim) was never sent when rclpy's handler had shut the context down first
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    stop = threading.Event()
    old_handlers = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGINT, signal.SIGTERM)}
    nodes = []
    status = 0
    try:
        nodes.append(factory())
        refuse_undeclared(nodes)        # a misspelt parameter is an error, not ignored
        apply_thread_priority(nodes)
        executor = make_executor()
        for node in nodes:
            executor.add_node(node)
        freeze_gc()
        spin_executor(executor, until=lambda: stop.is_set() or any(
            getattr(node, 'finished', False) is True for node in nodes))
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except ConfigError as exc:
        print(f'error: {exc}', file=sys.stderr, flush=True)
        status = 2
    finally:
        close_nodes(nodes)
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
        for sig, h in old_handlers.items():
            signal.signal(sig, h)
    if status == 0:
        for node in nodes:
            ask = getattr(node, 'exit_status', None)
            if callable(ask) and ask():
                status = ask()
    return status
