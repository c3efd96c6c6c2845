"""The project's launcher: start the stack's nodes as separate processes, watch them, stop them.

There is no ``ros2 launch`` in the PyPI ROS 2 wheels, so this is a small launcher of our own.
Each node runs as ``python -m <module> --ros-args -r __ns:=NS --params-file RIG.yaml
--params-file STACK.yaml [--params-file USER.yaml] -p name:=value ...`` -- exactly the command
line ``ros2 run`` would produce, so the same YAML files work on a full ROS install.

Pure Python (subprocess), no rclpy import: the launcher is not a node.

* Output of every node is prefixed with ``[name]``.
* Children die with the launcher (PR_SET_PDEATHSIG), so a killed launcher leaves no motor node.
* Stop order matters for safety and for the record: controller first (the plant's command
  timeout then zeros the motor), estimator, plant/driver (zeros the motor on close), and the
  recorder last, so it records everything up to the end; each gets SIGINT, then SIGTERM, then
  SIGKILL after a grace period.
"""
from __future__ import annotations

import ctypes
import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

#: Default namespace of a rig's nodes and topics; give every rig its own on a shared network.
DEFAULT_NS = '/rwpend'


@dataclass
class NodeSpec:
    """One node process."""

    name: str                                  # node name (also the log prefix)
    module: str                                # python -m module
    params: dict = field(default_factory=dict)  # -p name:=value overrides
    args: list = field(default_factory=list)   # extra arguments before --ros-args
    ros_args: bool = True                      # pass --ros-args (False for plain programs)
    stop_rank: int = 1                         # lower stops first
    required: bool = True                      # the stack stops when this one exits
    #: a process of the loop's nodes (rwpend_loop.host): {node name: overrides}; each node gets
    #: its own ``/**/<node>`` section in the overrides file and no ``__node`` remap is given
    #: (it would rename every node of the process)
    node_params: dict | None = None
    #: environment of this process on top of the launcher's (a value None removes the variable)
    env: dict = field(default_factory=dict)


def format_param_value(value) -> str:
    """A value in the syntax of ``-p name:=value`` (YAML, as rcl parses it)."""
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, (list, tuple)):
        return '[' + ', '.join(format_param_value(v) for v in value) + ']'
    if isinstance(value, str):
        # quote strings that YAML would read as another type
        import yaml
        loaded = yaml.safe_load(value) if value else None
        if not isinstance(loaded, str) or value != loaded:
            return "'" + value.replace("'", "''") + "'"
        return value
    return str(value)


def overrides_yaml(spec: NodeSpec) -> str:
    """The node's overrides as a ROS 2 params file section ``/**/<name>`` (nested keys).

    Overrides go in a params file given last, not ``-p name:=value``: rclpy ranks a file's
    ``/**/<name>`` section above ``-p`` (which counts as ``/**``), so ``-p`` would lose
    against stack.yaml (measured: ``-p mode:=auto`` left the controller ``off``).
    """
    return params_file_text(spec.node_params if spec.node_params is not None else {spec.name: spec.params})


def params_file_text(sections: dict[str, dict]) -> str:
    """A ROS 2 params file: per node name, its parameters (dotted names) as a ``/**/<name>``
    section of nested keys (tuples written as lists)."""
    import yaml
    doc = {}
    for node, params in sections.items():
        nested: dict = {}
        for name, value in params.items():
            d = nested
            parts = name.split('.')
            for part in parts[:-1]:
                d = d.setdefault(part, {})
            d[parts[-1]] = list(value) if isinstance(value, tuple) else value
        doc[f'/**/{node}'] = {'ros__parameters': nested}
    return yaml.safe_dump(doc, sort_keys=False)


def node_command(spec: NodeSpec, namespace: str, params_files: Sequence[str | Path],
                 python: str = sys.executable, overrides_file: str | Path | None = None) -> list[str]:
    """The command line of one node process (``overrides_file``: see :func:`overrides_yaml`)."""
    cmd = [python, '-u', '-m', spec.module, *map(str, spec.args)]
    if not spec.ros_args:
        return cmd
    cmd += ['--ros-args', '-r', f'__ns:={namespace}']
    if spec.node_params is None:
        cmd += ['-r', f'__node:={spec.name}']
    for f in params_files:
        cmd += ['--params-file', str(f)]
    if overrides_file is not None:
        cmd += ['--params-file', str(overrides_file)]
    elif spec.node_params is not None:
        raise ValueError(f'{spec.name}: a multi-node process needs an overrides file')
    elif spec.params:
        for name, value in spec.params.items():
            cmd += ['-p', f'{name}:={format_param_value(value)}']
    return cmd


def _die_with_parent() -> None:  # pragma: no cover - runs in the child
    try:
        libc = ctypes.CDLL('libc.so.6', use_errno=True)
        libc.prctl(1, signal.SIGTERM)   # PR_SET_PDEATHSIG
    except OSError:
        pass
    os.setpgrp()   # own process group: a terminal Ctrl-C reaches the launcher only


#: a node's exit status when it refused its configuration (rwpend_ros.params.ConfigError)
EXIT_CONFIG = 2


def run_status(codes: dict[str, int]) -> tuple[int, str]:
    """The launcher's exit status from its nodes' ``codes`` and what to say: 0 when every node
    ended well (or by our Ctrl-C); :data:`EXIT_CONFIG` when each node that failed refused its
    configuration (its reason is in its log); 1 for any other failure."""
    failed = {n: c for n, c in codes.items() if c not in (0, -signal.SIGINT, 130)}
    if not failed:
        return 0, ''
    listed = ', '.join(f'{n} (exit {c})' for n, c in failed.items())
    if all(c == EXIT_CONFIG for c in failed.values()):
        return EXIT_CONFIG, f'node(s) refused their configuration: {listed} (the reason above)'
    return 1, f'node(s) ended with an error: {listed}'


class Launcher:
    """Runs a set of node processes; ``run()`` returns when stopped, with an exit status."""

    def __init__(self, specs: Sequence[NodeSpec], namespace: str = DEFAULT_NS,
                 params_files: Sequence[str | Path] = (), env: dict | None = None,
                 out=None, grace: float = 5.0) -> None:
        self.specs = list(specs)
        self.namespace = namespace
        self.params_files = list(params_files)
        self.env = dict(os.environ if env is None else env)
        self.env.setdefault('PYTHONUNBUFFERED', '1')
        self.out = out or sys.stdout
        self.grace = grace
        self.procs: dict[str, subprocess.Popen] = {}
        self.exit_codes: dict[str, int] = {}
        self._threads: list[threading.Thread] = []
        self._write_lock = threading.Lock()
        self.stopping = threading.Event()

    def _pump(self, name: str, stream) -> None:
        width = max(len(s.name) for s in self.specs)
        for raw in iter(stream.readline, b''):
            line = raw.decode(errors='replace').rstrip('\n')
            with self._write_lock:
                print(f'[{name:<{width}}] {line}', file=self.out, flush=True)
        stream.close()

    def start(self) -> None:
        import tempfile
        self.tmpdir = tempfile.TemporaryDirectory(prefix='rwpend_launch_')
        for spec in self.specs:
            overrides = None
            if spec.ros_args and (spec.params or spec.node_params is not None):
                overrides = Path(self.tmpdir.name) / f'{spec.name}.yaml'
                overrides.write_text(overrides_yaml(spec))
            cmd = node_command(spec, self.namespace, self.params_files, overrides_file=overrides)
            env = self.env
            if spec.env:
                env = {**env, **{k: str(v) for k, v in spec.env.items() if v is not None}}
                for k in [k for k, v in spec.env.items() if v is None]:
                    env.pop(k, None)
            p = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                 stdin=subprocess.DEVNULL, preexec_fn=_die_with_parent)
            self.procs[spec.name] = p
            t = threading.Thread(target=self._pump, args=(spec.name, p.stdout), daemon=True)
            t.start()
            self._threads.append(t)

    def poll(self) -> str | None:
        """Name of a required node that has exited, if any."""
        for spec in self.specs:
            p = self.procs.get(spec.name)
            if p is not None and p.poll() is not None:
                self.exit_codes.setdefault(spec.name, p.returncode)
                if spec.required:
                    return spec.name
        return None

    def wait(self, duration: float | None = None, until: Callable[[], bool] | None = None) -> str:
        """Block until a required node exits, ``duration`` s pass, ``until()`` or SIGINT/SIGTERM.

        Returns the reason ('exited:<name>', 'duration', 'until', 'signal').
        """
        end = None if duration is None else time.monotonic() + duration
        while True:
            if self.stopping.is_set():
                return 'signal'
            name = self.poll()
            if name is not None:
                return f'exited:{name}'
            if end is not None and time.monotonic() >= end:
                return 'duration'
            if until is not None and until():
                return 'until'
            self.stopping.wait(0.05)

    def stop(self) -> dict[str, int]:
        """Stop every process in stop order; returns {name: exit code}."""
        for rank in sorted({s.stop_rank for s in self.specs}):
            group = [s.name for s in self.specs if s.stop_rank == rank and s.name in self.procs]
            for name in group:
                p = self.procs[name]
                if p.poll() is None:
                    p.send_signal(signal.SIGINT)
            for name in group:
                p = self.procs[name]
                try:
                    p.wait(timeout=self.grace)
                except subprocess.TimeoutExpired:
                    p.terminate()
                    try:
                        p.wait(timeout=2.0)
                    except subprocess.TimeoutExpired:
                        p.kill()
                        p.wait()
                self.exit_codes.setdefault(name, p.returncode)
        for t in self._threads:
            t.join(timeout=1.0)
        tmp = getattr(self, 'tmpdir', None)
        if tmp is not None:
            tmp.cleanup()
        return dict(self.exit_codes)

    def run(self, duration: float | None = None, until: Callable[[], bool] | None = None,
            on_started: Callable[['Launcher'], None] | None = None) -> int:
        """Start, wait, stop. Status 0 unless a node failed (non-zero exit not caused by us)."""
        old = {}

        def handler(signum, frame):  # noqa: ARG001
            self.stopping.set()
        if threading.current_thread() is threading.main_thread():
            for s in (signal.SIGINT, signal.SIGTERM):
                old[s] = signal.signal(s, handler)
        try:
            self.start()
            if on_started is not None:
                on_started(self)
            reason = self.wait(duration, until)
        finally:
            codes = self.stop()
            for s, h in old.items():
                signal.signal(s, h)
        self.reason = reason
        status, said = run_status(codes)
        if said:
            print(f'rwpend: {said}', file=sys.stderr)
        return status
