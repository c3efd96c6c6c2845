"""Composed mode (``./rwpend up --composed``): several of the stack's nodes in ONE process, on one
executor.

    python -m rwpend_bringup.composed [NODE ...] --ros-args -r __ns:=/rwpend --params-file ...

``NODE`` is one of :data:`NODES` (default: sim estimator controller). The nodes are the same
classes the separate processes run; they talk over the same topics (so a recorder in another
process sees everything), and the loop's messages between them go through the process's
in-process bus (rwpend_ros.intra, ``RWPEND_INTRA_PROCESS=0`` turns it off): no DDS hop, no
context switch between sender and receiver.

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
    from rwpend_ros.runner import run_nodes

    def factory(name):
        module, cls = NODES[name]
        return lambda bus: getattr(importlib.import_module(module), cls)(bus=bus)

    # built plant last, closed in stop order (controller first)
    return run_nodes([factory(n) for n in reversed(ordered)], [sys.argv[0], *ros])


if __name__ == '__main__':
    raise SystemExit(main())
