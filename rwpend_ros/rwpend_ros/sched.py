"""Process priority and CPU affinity. Pure (no rclpy): used by the nodes (through
rwpend_ros.runner) and by the rig emulator, which is not a ROS node."""
from __future__ import annotations

import os
import sys
from typing import Mapping

#: real time: the loop's (and a node's) SCHED_FIFO priority where permitted, as ros2_control's
#: controller manager takes by default (./rwpend up, ./rwpend node)
DEFAULT_RT_PRIORITY = 50
#: a recorder (a process of its own, or the loop's bag writer) this many SCHED_FIFO priorities
#: below the loop it records: above every ordinary process, below the loop, which cannot wait
RECORDER_BELOW = 10


def apply_scheduling(environ: Mapping[str, str] | None = None) -> dict:
    """Process priority and CPU affinity from the environment (set by the launcher per node).

    * ``RWPEND_RT_PRIORITY=N`` (1-99): SCHED_FIFO priority N; a FIFO thread runs as soon as it is
      runnable, ahead of every ordinary process on the host. Falls back to ``nice -10`` where
      real-time scheduling is not permitted.
    * ``RWPEND_NICE=N``: nice value (negative needs privileges; refused silently otherwise).
    * ``RWPEND_CPUS=0,1``: CPU affinity.

    Call it before ``rclpy.init``: threads inherit the policy of the thread that creates them,
    so the DDS threads created later get it too. Never fails: what is not permitted is left
    as it is, and reported in the returned dict (``{'rt': .., 'nice': .., 'cpus': ..}``).
    """
    env = os.environ if environ is None else environ
    done: dict = {}
    prio = env.get('RWPEND_RT_PRIORITY', '').strip()
    if prio and prio != '0':
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(int(prio)))
            done['rt'] = int(prio)
        except (OSError, ValueError, AttributeError) as exc:
            done['rt'] = f'not permitted ({exc})'
            env = {**env, 'RWPEND_NICE': env.get('RWPEND_NICE') or '-10'}
            print(f'rwpend: real-time priority {prio} not permitted ({exc}); trying nice -10',
                  file=sys.stderr, flush=True)
    nice = env.get('RWPEND_NICE', '').strip()
    if nice:
        try:
            done['nice'] = os.nice(int(nice) - os.nice(0))
        except (OSError, ValueError) as exc:
            done['nice'] = f'not permitted ({exc})'
    cpus = env.get('RWPEND_CPUS', '').strip()
    if cpus:
        try:
            ids = {int(c) for c in cpus.split(',') if c.strip()}
            os.sched_setaffinity(0, ids)
            done['cpus'] = sorted(os.sched_getaffinity(0))
            # threads started before this call (numpy's BLAS workers, at import) too: the
            # threads started later inherit it
            for tid in os.listdir('/proc/self/task') if os.path.isdir('/proc/self/task') else ():
                try:
                    os.sched_setaffinity(int(tid), ids)
                except OSError:
                    pass
        except (OSError, ValueError, AttributeError) as exc:
            done['cpus'] = f'not permitted ({exc})'
    return done


def realtime_permitted(priority: int = 50) -> tuple[bool, str]:
    """Whether this process may use SCHED_FIFO at ``priority`` (what ``--rt-priority`` needs), and
    why not: tried on a short-lived thread of its own, so nothing else changes."""
    result: list = []

    def probe():
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
            result.append('')
        except (OSError, AttributeError, ValueError) as exc:
            result.append(str(exc) or type(exc).__name__)
    import threading
    t = threading.Thread(target=probe, name='rt-probe')
    t.start()
    t.join()
    return (result == ['']), (result[0] if result else 'no result')


#: A node's ``thread_priority`` parameter (as ros2_control's controller manager has one): the
#: SCHED_FIFO priority its process takes at start, so that ``./rwpend node X -p
#: thread_priority:=50`` started alone, the ROS way, runs as it does under ``./rwpend up``.
THREAD_PRIORITY_DESCRIPTION = ('SCHED_FIFO priority (1-99) of this node\'s process, taken at start where '
                               'permitted (as ros2_control\'s thread_priority); 0: as the process was '
                               'started (./rwpend up gives its processes --rt-priority)')


def thread_priority_spec():
    """The ``thread_priority`` parameter of a node (read-only, 0..99, default 0)."""
    from rwpend_ros.paramspec import ParamSpec
    return ParamSpec('thread_priority', 0, THREAD_PRIORITY_DESCRIPTION, low=0, high=99, read_only=True)


def set_process_priority(priority: int) -> str:
    """Every thread of this process (and those it starts later) at SCHED_FIFO ``priority``
    (1-99); returns what was done, for the log -- never an error (not permitted: said)."""
    if not 1 <= int(priority) <= 99:
        raise ValueError(f'a SCHED_FIFO priority is 1..99, got {priority!r}')
    try:
        param = os.sched_param(int(priority))
        tids = [int(t) for t in os.listdir('/proc/self/task')] if os.path.isdir('/proc/self/task') else [0]
        for tid in tids:
            try:
                os.sched_setscheduler(tid, os.SCHED_FIFO, param)
            except ProcessLookupError:
                pass                      # a thread that ended meanwhile
        return f'SCHED_FIFO {int(priority)}'
    except (OSError, AttributeError) as exc:
        return f'SCHED_FIFO {int(priority)} not permitted ({exc}): ordinary scheduling'


def raise_thread_priority(step: int = 1) -> str:
    """The calling thread (on Linux a policy is per thread) ``step`` real-time priorities above
    its process's SCHED_FIFO priority, so it runs ahead of the process's other threads and of the
    other loop processes at the same priority (e.g. the serial driver's link thread, which must
    take each sample as it comes). Nothing when the thread is not SCHED_FIFO or it is not
    permitted. Returns what it did, for diagnostics."""
    try:
        if os.sched_getscheduler(0) != os.SCHED_FIFO:
            return 'not real-time'
        prio = min(os.sched_getparam(0).sched_priority + step, os.sched_get_priority_max(os.SCHED_FIFO))
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(prio))
        return f'SCHED_FIFO {prio}'
    except (OSError, AttributeError) as exc:
        return f'not changed ({exc})'


#: The kernel's PM QoS interface for the CPU wake-up latency (Documentation/power/pm_qos_interface.rst).
CPU_DMA_LATENCY = '/dev/cpu_dma_latency'


class CpuLatencyRequest:
    """Hold a PM QoS request for the CPUs' wake-up latency while the stack runs.

    An idle CPU waits in an idle state (``halt``, C-states) and takes time to wake up when a
    message arrives; on this project's 2-vCPU VM a wake-up costs ~30-60 µs at the median, and a
    loop sample wakes four threads in turn (PERFORMANCE.md, "What each mechanism buys"). Writing
    ``us`` to ``/dev/cpu_dma_latency`` and keeping the file open tells the cpuidle governor to use
    only idle states that wake up within ``us`` microseconds; 0 keeps an idle CPU polling (the
    setting ``cyclictest`` and real-time Linux guides use). The request ends when the file is
    closed (:meth:`close`, or the process exits), so nothing outlives the stack.

    The cost: an idle CPU keeps spinning (power, heat; on a VM, host CPU). Needs the right to
    open the device (root, or a udev rule); where that is missing, or the kernel has no cpuidle,
    the request is not made and :attr:`status` says why -- never an error.
    """

    def __init__(self, us: int, path: str = CPU_DMA_LATENCY) -> None:
        if not (isinstance(us, int) and 0 <= us <= 2_000_000_000):
            raise ValueError(f'CPU wake-up latency must be an integer >= 0 (µs), got {us!r}')
        self.us = us
        self.fd: int | None = None
        try:
            fd = os.open(path, os.O_WRONLY)
        except OSError as exc:
            self.status = f'not made ({path}: {exc.strerror or exc})'
            return
        try:
            os.write(fd, int(us).to_bytes(4, sys.byteorder, signed=True))
        except OSError as exc:
            os.close(fd)
            self.status = f'not made (writing {path}: {exc.strerror or exc})'
            return
        self.fd = fd
        self.status = f'{us} µs' + (' (idle CPUs poll)' if us == 0 else '')

    @property
    def active(self) -> bool:
        return self.fd is not None

    def close(self) -> None:
        if self.fd is not None:
            os.close(self.fd)
            self.fd = None

    def __enter__(self) -> 'CpuLatencyRequest':
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class _NoCpuLatencyRequest:
    """What :func:`request_cpu_latency` gives when no request was asked for."""
    us = None
    fd = None
    active = False
    status = 'none'

    def close(self) -> None:
        pass

    def __enter__(self) -> '_NoCpuLatencyRequest':
        return self

    def __exit__(self, *exc) -> None:
        pass


def request_cpu_latency(us: int | None):
    """:class:`CpuLatencyRequest` for ``us``, or one that does nothing when ``us`` is None (the
    ``--cpu-latency`` option not given)."""
    return _NoCpuLatencyRequest() if us is None else CpuLatencyRequest(us)
