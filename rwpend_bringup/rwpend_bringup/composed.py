"""Composed mode (``./rwpend up --composed``): several of the stack's nodes in ONE process, on one
executor.

    python -m rwpend_bringup.composed [NODE ...] --ros-args -r __ns:=/rwpend --params-file ...

``NODE`` is one of :data:`NODES` (default: sim estimator controller). The nodes are the same
classes the separate processes run; they talk over the same topics (so a recorder in another
process sees everything), but the messages between them stay inside one DDS participant and one
executor: no process hop, no context switch between sender and receiver.

The ``--ros-args`` apply to every node of the process: the namespace remap, and the params
files, whose ``/**/<node>`` sections select per node (the launcher writes the overrides of each
node into its own section). No ``__node`` remap is given: it would rename every node.

Nodes are created in reverse stop order (the plant last, so its sample loop starts when the
loop exists) and closed in stop order (controller, estimator, plant), like the launcher stops
separate processes. The simulator ends the process at ``duration`` by shutting the context down.
"""
from __future__ import annotations

import importlib
import sys

#: node name -> (module, class); in stop order (first stopped first)
NODES = {
    'controller': ('rwpend_control.controller_node', 'ControllerNode'),
    'estimator': ('rwpend_estimation.estimator_node', 'EstimatorNode'),
    'sim': ('rwpend_sim.sim_node', 'SimNode'),
}
DEFAULT = ('sim', 'estimator', 'controller')


def _split(argv: list[str]) -> tuple[list[str], list[str]]:
    if '--ros-args' in argv:
        i = argv.index('--ros-args')
        return argv[:i], argv[i:]
    return argv, []


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    names, ros = _split(argv)
    if any(n in ('-h', '--help') for n in names):
        print(__doc__.strip())
        return 0
    names = names or list(DEFAULT)
    unknown = [n for n in names if n not in NODES]
    if unknown or len(set(names)) != len(names):
        print(f'rwpend composed: error: nodes must be distinct names of {", ".join(NODES)}, got '
              f'{" ".join(names)}', file=sys.stderr, flush=True)
        return 2
    ordered = [n for n in NODES if n in names]          # stop order
    import rclpy
    from rclpy.executors import ExternalShutdownException

    from rwpend_ros.common import ConfigError, apply_scheduling, freeze_gc, make_executor, spin_executor
    apply_scheduling()   # before rclpy.init: the DDS threads inherit it
    rclpy.init(args=[sys.argv[0], *ros])
    nodes = []
    status = 0
    try:
        for name in reversed(ordered):                    # the plant last
            module, cls = NODES[name]
            nodes.append(getattr(importlib.import_module(module), cls)())
        executor = make_executor()
        for node in nodes:
            executor.add_node(node)
        freeze_gc()
        spin_executor(executor)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except ConfigError as exc:
        print(f'error: {exc}', file=sys.stderr, flush=True)
        status = 2
    finally:
        for node in reversed(nodes):                      # stop order: controller first
            close = getattr(node, 'close', None)
            if callable(close):
                try:
                    close()
                except Exception as exc:  # noqa: BLE001 - report, keep shutting down
                    print(f'error while closing {node.get_name()}: {exc}', file=sys.stderr, flush=True)
        for node in reversed(nodes):
            try:
                node.destroy_node()
            except Exception:  # noqa: BLE001 - context may be gone
                pass
        rclpy.try_shutdown()
    return status


if __name__ == '__main__':
    raise SystemExit(main())
