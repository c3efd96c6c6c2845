"""The stack library: a typed description of a stack (:class:`Stack`) and :func:`plan`, which
turns it into the processes to start (:class:`Plan`: node specs and params files for
:class:`rwpend_bringup.launch.Launcher`), validating it first.

``./rwpend up`` parses its command line into a :class:`Stack` (``rwpend_bringup.cli``); the lab,
identification and the bench describe their stacks with it directly. Nothing here
starts a process or imports rclpy.

The layouts (``layout``): ``loop`` -- the plant (simulator or driver), estimator, controller and
the recorder are nodes of one loop process (``rwpend_loop.host``); ``control`` -- the estimator
and the controller in one loop process fed by the plant's ``encoders`` topic, the plant in a
process of its own (the default of a stack split across hosts, ``only``); ``none`` -- every node
a process of its own (docs/architecture.md).
"""
from __future__ import annotations

import dataclasses
import hashlib
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

from rwpend_ros.sched import DEFAULT_RT_PRIORITY, RECORDER_BELOW

from .launch import DEFAULT_NS, NodeSpec

#: the nodes of a stack and the module of each one's process
NODE_MODULES = {
    'sim': 'rwpend_loop.host',     # the loop's process with the simulator alone (NODE_ARGS)
    'estimator': 'rwpend_estimation.estimator_node',
    'controller': 'rwpend_control.controller_node',
    'driver': 'rwpend_driver.driver_node',
}
#: the arguments of a node's process before --ros-args
NODE_ARGS = {'sim': ['sim']}
#: the controller's modes (its ``mode`` parameter)
MODES = ('off', 'wheel_velocity', 'wheel_angle', 'balance', 'swingup', 'auto', 'law')
#: the layouts with a loop process (rwpend_loop.host); ``none`` is the third layout
COMPOSITIONS = ('loop', 'control')
LAYOUTS = (*COMPOSITIONS, 'none')
#: lockstep with a recorder: samples the simulator may run ahead of the recorder
LOCKSTEP_RECORDER_WINDOW = 50
#: the layout per plant when none is given (PERFORMANCE.md, "Layouts")
DEFAULT_LAYOUT = {'sim': 'loop', 'serial': 'loop'}
LAYOUT_TEXT = {'loop': 'the loop in one real-time thread of one process (plant, estimator, controller '
                       'and the recorder as its nodes)',
               'none': 'separate processes (plant, estimator, controller)',
               'control': 'estimator + controller in one loop process, the plant in its own'}
#: the nodes (and ``rig``, the rig data every node reads) a per-node override may name
OVERRIDE_TARGETS = ('sim', 'estimator', 'controller', 'driver', 'rig')


def rig_file() -> Path:
    """The shipped rig YAML (rwpend_model/config/rig.yaml)."""
    from rwpend_model.rig import default_rig_file
    return default_rig_file()


def stack_file() -> Path:
    """The stack's defaults for every node (a ROS 2 params file)."""
    return Path(__file__).resolve().parent / 'config' / 'stack.yaml'


@dataclass
class Stack:
    """What to run. A field has the meaning of the ``./rwpend up`` option of its name
    (``./rwpend up --help``), None the option not given; the others:

    ``params_files``: ``--params``. ``overrides`` (``--set NODE.PARAM=VALUE``): per node ('sim',
    'estimator', 'controller', 'driver') and 'rig' (rig data for every node), parameter name ->
    value. ``taps`` (``--tap``): (simulated time s, Δθ̇ rad/s) pairs. ``controller``: not
    ``--no-controller``. ``pins`` (``--pin``): process name -> CPU ids. ``layout``
    (``--composed``): 'loop', 'control' or 'none'. ``rt_priority`` and ``layout`` None: chosen by
    :func:`resolve` for the machine and the plant. ``only`` (``--only``): the processes of this
    host, None for all."""
    plant: str = 'sim'
    lockstep: bool = False
    duration: float | None = None
    mode: str | None = None
    estimator: str | None = None
    record: str | None = None
    params_files: tuple[str, ...] = ()
    overrides: dict[str, dict[str, object]] = field(default_factory=dict)
    ns: str = DEFAULT_NS
    rig: str | None = None
    plant_rig: str | None = None
    theta0: float | None = None
    taps: tuple[tuple[float, float], ...] = ()
    h: float | None = None
    controller: bool = True
    rt_priority: int | None = None
    cpu_latency: int | None = None
    pins: dict[str, tuple[int, ...]] = field(default_factory=dict)
    console: str | None = None
    layout: str | None = None
    only: tuple[str, ...] | None = None

    @property
    def plant_kind(self) -> str:
        """'sim' or 'serial'."""
        return 'sim' if self.plant == 'sim' else 'serial'

    @property
    def loop_process(self) -> str:
        """The name of the process the plant runs in ('loop', or the plant's node name)."""
        if self.layout == 'loop':
            return 'loop'
        return 'sim' if self.plant == 'sim' else 'driver'


@dataclass
class Plan:
    """The processes of a stack (``specs``, for the launcher), the params files every node
    reads (``files``, in order), and the lines that say what :func:`resolve` chose and why."""
    stack: Stack
    specs: list[NodeSpec]
    files: list[str]
    notes: list[str]


def parse_assignment(text: str) -> tuple[str, str, object]:
    """'controller.balance.kpp=-280' -> ('controller', 'balance.kpp', -280.0 as YAML reads it);
    ValueError with the reason for anything else."""
    import yaml
    if '=' not in text:
        raise ValueError(f'expected NODE.PARAM=VALUE, got {text!r}')
    lhs, rhs = text.split('=', 1)
    if '.' not in lhs:
        raise ValueError(f'expected NODE.PARAM=VALUE, got {text!r}')
    node, name = lhs.split('.', 1)
    if node not in OVERRIDE_TARGETS or not name:
        raise ValueError(f'unknown node {node!r} in {text!r} ({", ".join(OVERRIDE_TARGETS)})')
    try:
        value = yaml.safe_load(rhs)
    except yaml.YAMLError as exc:
        raise ValueError(f'cannot read the value of {text!r}: {exc}') from exc
    if value is None or isinstance(value, dict):
        raise ValueError(f'no usable value in {text!r}')
    return node, name, value


def overrides_from(assignments) -> dict[str, dict[str, object]]:
    """``NODE.PARAM=VALUE`` texts (:func:`parse_assignment`) -> :attr:`Stack.overrides`."""
    out: dict[str, dict[str, object]] = {}
    for text in assignments:
        node, name, value = parse_assignment(text)
        out.setdefault(node, {})[name] = value
    return out


def check_override_types(files, params: dict[str, dict], rig: dict, flag: str = '--set',
                         rig_path=None) -> None:
    """Each value of a params file or an override must have the type of the value it overrides
    (rig.yaml, stack.yaml, an earlier params file): rcl keeps the earlier value, silently, when a
    later file gives another type (measured with rclpy 7.1.6: ``soon`` over 0.5 and 2.5 over 1 are
    ignored). An integer where a float was is fine (the nodes take it as that float).
    ``params``: the overrides per node (``flag``: how the user gave them, ``--set`` or ``-p``),
    ``rig``: those of ``rig.*``; where such a value overrides a string and YAML read it as a
    boolean (``mode=off``: false), it is replaced in ``params`` by the string the nodes take for
    it, 'off' / 'on' (rwpend_ros.paramspec). ValueError with the reason otherwise."""
    from rwpend_model.rig import read_params_file, typed_like
    for node in params:
        seen = {**read_params_file(rig_path or rig_file(), node), **read_params_file(stack_file(), node)}
        sources = [(str(f), read_params_file(f, node)) for f in files]
        sources.append((flag, {**params[node], **rig}))
        for source, values in sources:
            for name, value in values.items():
                if name in seen and value is not None:
                    if source == flag and isinstance(seen[name], str) and isinstance(value, bool):
                        value = 'on' if value else 'off'
                        params[node][name] = value
                    try:
                        typed_like(name, value, seen[name])
                    except ValueError as exc:
                        where = (f'{source} ({node})' if source != flag else f'{flag} {name}'
                                 if name in rig or flag != '--set' else f'--set {node}.{name}')
                        hint = (" (YAML reads on/off/yes/no as true/false: quote the string, 'off')"
                                if isinstance(value, bool) and isinstance(seen[name], str) else '')
                        raise ValueError(f'{where}: {exc} (the type of {seen[name]!r} it overrides; '
                                         f'ROS would keep that value){hint}') from None
                seen[name] = value


def namespace(ns: str) -> str:
    """A rig's namespace, normalised ('rig2' -> '/rig2'); ValueError with the reason."""
    ns = '/' + str(ns).strip('/')
    if ns != '/' and not re.fullmatch(r'(/[A-Za-z][A-Za-z0-9_]*)+', ns):
        raise ValueError(f'invalid namespace {ns!r} (letters, digits, _; e.g. /rig2)')
    return ns


def usable_cpus() -> set[int]:
    """The CPUs this process may run on (its affinity: a container or a cgroup may allow fewer
    than the machine has)."""
    try:
        return set(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return set(range(os.cpu_count() or 1))


def parse_pins(pins: list[str]) -> dict[str, tuple[int, ...]]:
    """``PROCESS=CPUS`` texts (``--pin``) -> {process: CPU ids}; ValueError with the reason for a
    bad item or a process given twice (:func:`check_pins` checks them against a stack)."""
    out: dict[str, tuple[int, ...]] = {}
    for item in pins:
        name, sep, cpus = item.partition('=')
        name, ids = name.strip(), [c.strip() for c in cpus.split(',')]
        if not sep or not name or not cpus.strip():
            raise ValueError(f'--pin: PROCESS=CPUS (e.g. sim=0 or controller=0,1), got {item!r}')
        if not all(c.isdigit() for c in ids):
            raise ValueError(f'--pin: CPU numbers separated by commas, got {item!r}')
        if name in out:
            raise ValueError(f'--pin: {name} given twice')
        out[name] = tuple(int(c) for c in ids)
    return out


def check_pins(pins: dict[str, tuple[int, ...]], processes: list[str]) -> None:
    """ValueError with the reason for a pinned process this stack does not run, or a CPU this
    process may not use (:func:`usable_cpus`)."""
    usable = usable_cpus()
    for name, ids in pins.items():
        if name not in processes:
            raise ValueError(f'--pin: no process {name!r} in this stack (its processes: '
                             f'{", ".join(processes)})')
        if not ids or not set(ids) <= usable:
            raise ValueError(f'--pin: {name}={",".join(map(str, ids))}: this process may use CPUs '
                             f'{",".join(map(str, sorted(usable)))} only')


def resolve(stack: Stack) -> tuple[Stack, list[str]]:
    """The stack with the defaults that depend on the machine and the plant chosen: the
    real-time priority (DEFAULT_RT_PRIORITY in real time where permitted, 0 in lockstep) and the
    layout (DEFAULT_LAYOUT of the plant; ``control`` for a stack split across hosts); and the
    lines that say what was chosen and why."""
    notes = []
    layout = stack.layout or DEFAULT_LAYOUT[stack.plant_kind]
    if layout not in LAYOUTS:
        raise ValueError(f'--composed must be one of {", ".join(LAYOUTS)}, got {layout!r}')
    if stack.layout is None and stack.only and layout == 'loop':
        # a stack split across hosts (--only sim / control / recorder): the plant in a process
        # of its own, the estimator and the controller in another
        layout = 'control'
    notes.append(f'layout: {LAYOUT_TEXT[layout]}' + ('' if stack.layout else
                 f' (the default for --plant {stack.plant_kind}; --composed loop|control|none to change)'))
    prio = stack.rt_priority
    if prio is None:
        if stack.lockstep:
            prio, why = 0, 'lockstep runs at ordinary priority'
        else:
            from rwpend_ros.sched import realtime_permitted
            ok, reason = realtime_permitted(DEFAULT_RT_PRIORITY)
            prio = DEFAULT_RT_PRIORITY if ok else 0
            why = ('where permitted (the default; --rt-priority 0 to turn it off)' if ok else
                   f'not permitted here ({reason}): ordinary scheduling; a busy machine may then miss '
                   'samples (run as root or set an rtprio limit)')
        notes.append(f'real-time priority: {prio or "none"} ({why})')
    return dataclasses.replace(stack, layout=layout, rt_priority=prio), notes


def lockstep_controller_id(ns: str) -> int:
    """The controller id of a lockstep stack in namespace ``ns``: fixed, non-zero, < 2^63."""
    return int.from_bytes(hashlib.blake2b(ns.encode(), digest_size=8).digest(), 'big') >> 1 | 1


def plan(stack: Stack) -> Plan:
    """The processes of ``stack`` (after :func:`resolve`); ValueError with the reason for
    anything that cannot run (also for a bad ``RWPEND_TRANSPORT``), before any process starts."""
    stack, notes = resolve(stack)
    from rwpend_ros.transport import transport_choice
    transport_choice()
    params, rig, model, model_file, truth = _node_params(stack)
    if stack.plant == 'sim':
        plant_spec = _sim_spec(stack, params, rig, truth, model)
    elif stack.plant.startswith('serial:') and len(stack.plant) > 7:
        if stack.lockstep or stack.taps or stack.theta0 is not None or truth:
            raise ValueError('--lockstep, --tap, --theta0 and --plant-rig need the simulator (--plant sim); '
                             "the rig's truth is the rig (the emulator's: ./rwpend emulate --rig FILE)")
        params['driver']['port'] = stack.plant[7:]
        if stack.duration:   # counted by the driver from its first command (the loop closed)
            params['driver']['duration'] = float(stack.duration)
        plant_spec = NodeSpec('driver', NODE_MODULES['driver'], {**rig, **params['driver']}, stop_rank=3)
    else:
        raise ValueError(f"--plant must be 'sim' or 'serial:PORT', got {stack.plant!r}")
    specs = [plant_spec, *_loop_node_specs(stack, params, rig, plant_spec)]
    if stack.record:
        specs.append(_recorder_spec(stack, plant_spec))
    if stack.layout == 'loop':
        specs = loop_layout(specs, stack)
    else:
        if stack.record and stack.controller:
            # the controller in another process than the plant: the plant's first sample waits
            # for the recorder of command too (it subscribes once it has seen the controller's
            # publisher), or the bag may begin its commands seconds after its samples; a
            # separate estimator subscribes to command as well
            plant_spec.params['start.command_subscribers'] = 2 if stack.layout == 'none' else 1
        if stack.layout == 'control':
            specs = control_layout(specs)
    _apply_scheduling(stack, specs)
    if stack.console is not None:   # not a loop process: its own priority, no pinning
        specs.append(console_spec(stack, plant_spec))
    files = [str(model_file), str(stack_file()), *map(str, stack.params_files)]
    return Plan(stack, select_part(specs, stack.only), files, notes)


def _node_params(stack: Stack):
    """(params per node, rig.* overrides, the rig model every node reads, its file, the plant's
    own truth) of ``stack``, validated."""
    from rwpend_model.rig import load_rig, read_params_file
    params: dict[str, dict] = {'sim': {}, 'estimator': {}, 'controller': {}, 'driver': {}}
    rig: dict = {}
    for f in stack.params_files:
        if not Path(f).is_file():
            raise ValueError(f'params file {f} does not exist')
        read_params_file(f)   # validates the format
    for node, values in stack.overrides.items():
        if node not in OVERRIDE_TARGETS:
            raise ValueError(f'unknown node {node!r} in the overrides ({", ".join(OVERRIDE_TARGETS)})')
        if node == 'rig':
            rig.update({'rig.' + k: v for k, v in values.items()})
        else:
            params[node].update(values)
    model_file, truth = rig_files(stack)
    check_override_types(stack.params_files, params, rig, rig_path=model_file)
    if stack.h is not None:
        rig['rig.sample_period'] = float(stack.h)
    model = load_rig(model_file, overrides=rig)   # validated now, with the reason, before anything starts
    if stack.duration is not None and not (math.isfinite(stack.duration) and stack.duration > 0):
        raise ValueError(f'--duration must be > 0, got {stack.duration}')
    if stack.mode:
        if stack.mode not in MODES:
            raise ValueError(f'--mode must be one of {", ".join(MODES)}, got {stack.mode!r}')
        params['controller']['mode'] = stack.mode
    if stack.estimator:
        params['estimator']['estimator'] = stack.estimator
    if stack.lockstep:
        # the id in every command (rwpend_ros.claim) fixed, so that a lockstep bag is the same
        # every run, on one host or several; in real time each controller draws its own
        params['controller'].setdefault('controller_id', lockstep_controller_id(stack.ns))
    return params, rig, model, model_file, truth


def _sim_spec(stack: Stack, params, rig, truth, model) -> NodeSpec:
    """The simulator's process: the plant's truth (--plant-rig), then what every node gets, then
    the simulator's own overrides; the model the others read goes along for the simulator's
    report of the difference."""
    sim = params['sim']
    if stack.lockstep:
        sim['lockstep'] = True
    if stack.duration:   # counted by the simulator from sample 0 (which waits for the loop)
        sim['duration'] = float(stack.duration)
    if stack.theta0 is not None:
        sim['initial.theta'] = float(stack.theta0)
    if stack.taps:
        sim['taps.times'] = [float(t) for t, _ in stack.taps]
        sim['taps.sizes'] = [float(dv) for _, dv in stack.taps]
    model_params = {'model_' + k: v for k, v in model.as_params().items()}
    return NodeSpec('sim', NODE_MODULES['sim'], {**truth, **rig, **sim, **model_params},
                    args=list(NODE_ARGS['sim']), stop_rank=3)


def _loop_node_specs(stack: Stack, params, rig, plant_spec: NodeSpec) -> list[NodeSpec]:
    """The estimator's and the controller's processes."""
    # lockstep: sim time; the estimator and controller take it from the samples' stamps rather
    # than /clock (rwpend_ros.simtime.SampleTime: one DDS message less per sample and node)
    sim_time = {'use_sim_time': True, 'time_from_samples': True} if stack.lockstep else {}
    specs = [NodeSpec('estimator', NODE_MODULES['estimator'], {**rig, **sim_time, **params['estimator']},
                      stop_rank=2)]
    if stack.controller:
        specs.append(NodeSpec('controller', NODE_MODULES['controller'],
                              {**rig, **sim_time, **params['controller']}, stop_rank=1))
    if stack.plant == 'sim' and stack.lockstep:
        # sample 0 waits until the controller (and the recorder) listen to state: otherwise
        # state 0 may be published before the controller matched it, and the run would start
        # with u = 0 for a few samples -- not deterministic
        plant_spec.params['start.state_subscribers'] = int(stack.controller) + int(bool(stack.record))
    return specs


def _recorder_spec(stack: Stack, plant_spec: NodeSpec) -> NodeSpec:
    """The recorder of every topic, and what the plant waits for before its first sample."""
    if stack.plant == 'sim':   # the simulator holds sample 0 until the recorder listens
        plant_spec.params.update({'start.encoders_subscribers': 2, 'start.true_state_subscribers': 1})
    else:                      # the driver publishes no sample until the recorder listens
        n = plant_spec.params.get('start.encoders_subscribers', 1)
        plant_spec.params['start.encoders_subscribers'] = max(2, n if isinstance(n, int) else 2)
    out = Path(stack.record)
    # (with only and the recorder on another host, the path is that host's)
    if stack.only is None or 'recorder' in stack.only:
        if out.exists() and (not out.is_dir() or any(out.iterdir())):
            raise ValueError(f'{out} already exists (choose a new bag directory)')
        if not out.parent.exists():
            raise ValueError(f'{out.parent} does not exist')
    args = ['record', '-o', str(out), '--all']
    if stack.plant == 'sim' and stack.lockstep:
        # the simulator keeps within 50 samples of the recorder: a recorder that falls behind
        # slows the run down rather than losing messages (rwpend_loop.host)
        plant_spec.params.setdefault('lockstep_recorder_window', LOCKSTEP_RECORDER_WINDOW)
        args += ['--progress', stack.ns.rstrip('/') + '/recorder/progress']
    if stack.lockstep:
        # log times on the simulated clock, in a deterministic order (rwpend_bag.logtime)
        args.append('--sim-time')
    return NodeSpec('recorder', 'rwpend_bag.cli', args=args, ros_args=False, stop_rank=9)


def _apply_scheduling(stack: Stack, specs: list[NodeSpec]) -> None:
    """Real-time priority and CPU affinity of the processes, validated."""
    prio = stack.rt_priority or 0
    if not 0 <= prio <= 99:
        raise ValueError(f'--rt-priority must be in 0..99, got {prio}')
    for s in specs:
        # real time: the recorder below the loop (it can wait, the loop cannot); lockstep:
        # the loop keeps both CPUs busy and waits for the recorder (its window), so the
        # recorder runs at the loop's priority; none for the loop, none for the recorder (said:
        # rwpend record alone takes a priority of its own)
        if s.name == 'recorder':
            below = prio and not stack.lockstep
            s.env['RWPEND_RT_PRIORITY'] = str(max(1, prio - RECORDER_BELOW) if below else prio)
        elif prio:
            s.env['RWPEND_RT_PRIORITY'] = str(prio)
    if stack.cpu_latency is not None and stack.cpu_latency < 0:
        raise ValueError(f'--cpu-latency must be >= 0 (µs), got {stack.cpu_latency}')
    check_pins(stack.pins, [s.name for s in specs])
    for name, ids in stack.pins.items():
        for s in specs:
            if s.name == name:
                s.env['RWPEND_CPUS'] = ','.join(map(str, ids))


def loop_layout(specs: list[NodeSpec], stack: Stack) -> list[NodeSpec]:
    """The plant (simulator or driver), estimator and controller of ``specs`` as nodes of one
    loop process (rwpend_loop.host, rwpend_loop.rig): the sample path in one thread. The
    recorder is a node of that process too: the bag is written from the bytes the nodes publish
    (no DDS hop), by a child process of its own below the loop (rwpend_bag.procwriter)."""
    members = [s for s in specs if s.name in ('sim', 'driver', 'estimator', 'controller')
               and s.module == NODE_MODULES[s.name]]
    plant = members[0]
    args = [s.name for s in members]
    rest = [s for s in specs if s not in members]
    rec = next((s for s in rest if s.name == 'recorder'), None)
    if rec is not None:
        rest.remove(rec)
        if 'start.state_subscribers' in plant.params:     # the recorder no longer subscribes to state
            plant.params['start.state_subscribers'] -= 1
        args += ['--record', str(stack.record)] + (['--sim-time'] if stack.lockstep else [])
        # (the driver counts the listeners of its process itself: DriverNode.listeners_here)
        for key in ('start.encoders_subscribers', 'start.true_state_subscribers', 'lockstep_recorder_window'):
            if plant.name == 'sim':
                plant.params.pop(key, None)
    host = NodeSpec('loop', 'rwpend_loop.host', args=args, node_params={s.name: s.params for s in members},
                    stop_rank=min(s.stop_rank for s in members))
    return [host, *rest]


def control_layout(specs: list[NodeSpec]) -> list[NodeSpec]:
    """The estimator and controller of ``specs`` as the nodes of one loop process without the
    plant (rwpend_loop.control: one loop step per ``encoders`` message); the plant and the
    recorder stay processes of their own."""
    members = [s for s in specs if s.name in ('estimator', 'controller') and s.module == NODE_MODULES[s.name]]
    if not members:
        return specs
    first = specs.index(members[0])
    rest = [s for s in specs if s not in members]
    if len(members) == 1:            # no controller: the estimator alone, a node process of its own
        host = NodeSpec('control', members[0].module, node_params={members[0].name: members[0].params},
                        stop_rank=members[0].stop_rank)
    else:
        for plant in specs:         # the controller takes the state inside its process: not a subscriber
            if plant.name == 'sim' and plant.params.get('start.state_subscribers', 0) > 0:
                plant.params['start.state_subscribers'] -= 1
        host = NodeSpec('control', 'rwpend_loop.host', args=[s.name for s in members],
                        node_params={s.name: s.params for s in members},
                        stop_rank=min(s.stop_rank for s in members))
    return [*rest[:first], host, *rest[first:]]


def select_part(specs: list[NodeSpec], only) -> list[NodeSpec]:
    """The processes named in ``only``, all when None. ValueError for a name the stack has not
    (its processes listed) or an empty list. Each process keeps the parameters it has in the
    whole stack (the simulator waits for the subscribers of the other hosts, lockstep nodes take
    sim time), so every host gives the same description."""
    if only is None:
        return specs
    names = list(only)
    known = [s.name for s in specs]
    bad = [n for n in names if n not in known]
    if not names or bad:
        raise ValueError(f'--only: {", ".join(bad) or "no process"}: this stack runs {", ".join(known)} '
                         '(--composed changes the processes)')
    return [s for s in specs if s.name in names]


def rig_files(stack: Stack) -> tuple[Path, dict]:
    """(the rig file every node reads, ``rig.*`` of the plant's own truth or {}) from ``rig``
    and ``plant_rig``: complete rig files (rwpend_model.rig.load_rig_file), ValueError
    otherwise."""
    from rwpend_model.rig import load_rig_file
    rigs = {}
    for flag, f in (('--rig', stack.rig or rig_file()), ('--plant-rig', stack.plant_rig)):
        if f is None:
            continue
        if not Path(f).is_file():
            raise ValueError(f'{flag}: no such file {f}')
        try:
            rigs[flag] = load_rig_file(f)
        except ValueError as exc:
            raise ValueError(f'{flag}: {exc}') from None
    truth = rigs['--plant-rig'].as_params() if '--plant-rig' in rigs else {}
    return Path(stack.rig or rig_file()), truth


def console_spec(stack: Stack, plant_spec: NodeSpec) -> NodeSpec:
    """The lab console as a process of the stack, not of the loop: no pinning, in real time
    SCHED_FIFO 40 below the loop's priority (under the recorder, above ordinary programs: its
    e-stop must not wait for the CPU), ordinary priority in lockstep. In lockstep the
    simulator's sample 0 waits for one more subscriber of ``state``: the console takes state
    while a page watches the rig, so the run starts when the page is open. ValueError for a bad
    address."""
    from .addresses import parse_console_address
    listen, port = parse_console_address(stack.console)
    if stack.plant == 'sim' and stack.lockstep:
        plant_spec.params['start.state_subscribers'] = plant_spec.params.get('start.state_subscribers', 0) + 1
    prio = stack.rt_priority or 0
    return NodeSpec('console', 'rwpend_console.console', args=['--ns', stack.ns, '--listen', listen, '--port', str(port)],
                    ros_args=False, required=stack.lockstep, stop_rank=8,
                    env={'RWPEND_RT_PRIORITY': str(max(1, prio - 40)) if prio and not stack.lockstep else '0'})
