"""Process priority and CPU affinity. Pure (no rclpy): used by the nodes (through
rwpend_ros.common) and by the rig emulator, which is not a ROS node."""
from __future__ import annotations

import os
import sys
from typing import Mapping


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
            os.sched_setaffinity(0, {int(c) for c in cpus.split(',') if c.strip()})
            done['cpus'] = sorted(os.sched_getaffinity(0))
        except (OSError, ValueError, AttributeError) as exc:
            done['cpus'] = f'not permitted ({exc})'
    return done
