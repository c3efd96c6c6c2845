"""``./rwpend`` -- the project's command line (run from the repository root; no sourcing needed).

Commands (``./rwpend COMMAND --help`` for each):

  up        run the stack: plant (simulator or serial driver), estimator, controller [, recorder]
  node      run one node (like ``ros2 run``): sim, estimator, controller, driver; -p NAME:=VALUE
  sim       the simulator alone (= ``node sim``), e.g. ``./rwpend sim -p lockstep:=true``
  demo      swing-up, catch, balance and a tap on the simulator; bag + plot + metrics
  param     get / set / list / dump / describe parameters of a running node (standard services)
  mode      set the controller's mode (off, wheel_velocity, wheel_angle, balance, swingup, auto)
  tap       tap the simulated pendulum (theta_dot jumps by DV rad/s)
  estop     raise the latched e-stop (``--clear`` to clear it)
  graph     the nodes this host sees, and who publishes what each subscribes to
  gains     the book's gain designs, and applying them to a running controller
  record    record topics to a rosbag2 MCAP bag
  play      replay a bag
  bag info  topics, counts, rates, seq gaps of a bag
  analyze   metrics and plots of a run
  emulate   the rig's microcontroller on a pseudo-terminal (for --plant serial:PATH)
  bench     the real-time / lockstep benchmark (JSON in bench_out/)
  soak      real-time runs under load with injected faults, judged from the bags (make soak)
  lab       the book's 20 experiments: lab list | lab run N | lab report DIR...
  identify  identify a rig (its rig YAML, a report), or --check RIG.yaml whether it still matches
  console   the lab console: the rig in a web browser (plots, gains, e-stop) + the Foxglove bridge
  bridge    the Foxglove WebSocket bridge alone (ws://127.0.0.1:8765)
  sweep     robustness studies: many lockstep runs over a grid or Monte-Carlo axes (results, plots)
  exec      run any command inside the project's ROS environment (handled by ./rwpend)
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path

from .launch import DEFAULT_NS, Launcher, NodeSpec

ROOT = Path(os.environ.get('RWPEND_ROOT', Path(__file__).resolve().parents[2]))
MODES = ('off', 'wheel_velocity', 'wheel_angle', 'balance', 'swingup', 'auto', 'law')
NODE_MODULES = {
    'sim': 'rwpend_loop.host',     # the loop's process with the simulator alone (NODE_ARGS)
    'estimator': 'rwpend_estimation.estimator_node',
    'controller': 'rwpend_control.controller_node',
    'driver': 'rwpend_driver.driver_node',
}
#: the arguments of a node's process before --ros-args
NODE_ARGS = {'sim': ['sim']}
#: ``--composed`` values: which nodes share the loop's process (rwpend_loop.host); ``loop``: the
#: plant, estimator, controller and recorder; ``control``: the estimator and the controller,
#: fed by the plant's ``encoders`` topic (rwpend_loop.control), the plant in a process of its own
COMPOSITIONS = ('loop', 'control')
#: ./rwpend up --lockstep --record: samples the simulator may run ahead of the recorder
LOCKSTEP_RECORDER_WINDOW = 50
#: ./rwpend up in real time: the loop's SCHED_FIFO priority where permitted (--rt-priority)
DEFAULT_RT_PRIORITY = 50
#: ./rwpend up without --composed: the layout per plant (PERFORMANCE.md, "Layouts")
DEFAULT_LAYOUT = {'sim': 'loop', 'serial': 'loop'}
LAYOUT_TEXT = {'loop': 'the loop in one real-time thread of one process (plant, estimator, controller '
                       'and the recorder as its nodes)',
               'none': 'separate processes (plant, estimator, controller)',
               'control': 'estimator + controller in one loop process, the plant in its own'}


class Parser(argparse.ArgumentParser):
    def error(self, message):
        self.print_usage(sys.stderr)
        print(f'{self.prog}: error: {message}', file=sys.stderr)
        raise SystemExit(2)


def fail(prog: str, msg: str, status: int = 2) -> int:
    print(f'{prog}: error: {msg}', file=sys.stderr, flush=True)
    return status


def rig_file() -> Path:
    from rwpend_model.rig import default_rig_file
    return default_rig_file()


def stack_file() -> Path:
    return Path(__file__).resolve().parent / 'config' / 'stack.yaml'


def apply_network_defaults(env=None) -> None:
    """Network hygiene: ROS_DOMAIN_ID and ROS_AUTOMATIC_DISCOVERY_RANGE from the
    ``/**/rwpend_network`` section of stack.yaml, unless already set in the environment
    (discovery stays on this host by default).  Every node and tool started by ./rwpend inherits
    them."""
    import yaml
    env = os.environ if env is None else env
    try:
        net = yaml.safe_load(stack_file().read_text())['/**/rwpend_network']['ros__parameters']
    except (OSError, KeyError, TypeError, yaml.YAMLError):
        net = {}
    domain = net.get('domain_id', 0)
    if isinstance(domain, int) and not isinstance(domain, bool) and 0 <= domain <= 232:
        env.setdefault('ROS_DOMAIN_ID', str(domain))
    env.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', str(net.get('discovery_range', 'LOCALHOST')))


def parse_assignment(text: str) -> tuple[str, str, object]:
    """'controller.balance.kpp=-280' -> ('controller', 'balance.kpp', -280.0 as YAML reads it)."""
    import yaml
    if '=' not in text:
        raise ValueError(f'expected NODE.PARAM=VALUE, got {text!r}')
    lhs, rhs = text.split('=', 1)
    if '.' not in lhs:
        raise ValueError(f'expected NODE.PARAM=VALUE, got {text!r}')
    node, name = lhs.split('.', 1)
    if node not in ('sim', 'estimator', 'controller', 'driver', 'rig') or not name:
        raise ValueError(f'unknown node {node!r} in {text!r} (sim, estimator, controller, driver, rig)')
    try:
        value = yaml.safe_load(rhs)
    except yaml.YAMLError as exc:
        raise ValueError(f'cannot read the value of {text!r}: {exc}') from exc
    if value is None or isinstance(value, dict):
        raise ValueError(f'no usable value in {text!r}')
    return node, name, value


def check_override_types(files, params: dict[str, dict], rig: dict, flag: str = '--set',
                         rig_path=None) -> None:
    """Each value of a ``--params`` file or a ``--set`` must have the type of the value it
    overrides (rig.yaml, stack.yaml, an earlier ``--params``): rcl keeps the earlier value,
    silently, when a later file gives another type (measured with rclpy 7.1.6: ``soon`` over 0.5
    and 2.5 over 1 are ignored). An integer where a float was is fine (the nodes take it as
    that float). ``params``: the ``--set`` values per node (``flag``: ``-p`` of ``rwpend node``),
    ``rig``: those of ``rig.*``; where such a value overrides a string and YAML read it as a
    boolean (``mode=off``: false), it is replaced by the string the nodes take for it, 'off' /
    'on' (rwpend_ros.paramspec). ValueError with the reason otherwise, before anything starts."""
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


def namespace_arg(ns: str) -> str:
    ns = '/' + ns.strip('/')
    import re
    if ns != '/' and not re.fullmatch(r'(/[A-Za-z][A-Za-z0-9_]*)+', ns):
        raise argparse.ArgumentTypeError(f'invalid namespace {ns!r} (letters, digits, _; e.g. /rig2)')
    return ns


# ------------------------------------------------------------------ up
def add_stack_args(p: argparse.ArgumentParser) -> None:
    p.add_argument('--plant', default='sim', help="'sim' (default) or 'serial:PORT' (the real rig, "
                   'or the emulator\'s path)')
    p.add_argument('--lockstep', action='store_true',
                   help='simulator in lockstep with the loop (sim time on /clock, deterministic)')
    p.add_argument('--duration', type=float, default=None,
                   help='stop after S seconds of the run (simulated time from the first sample with '
                   'the simulator, wall time from the first command sent to the device with a '
                   'serial plant: start-up on a busy machine does not shorten the run)')
    p.add_argument('--mode', choices=MODES, default=None, help='controller mode at start')
    p.add_argument('--estimator', default=None, help='estimator at start (see estimator node)')
    p.add_argument('--record', metavar='DIR', default=None, help='record every topic to this bag')
    p.add_argument('--params', action='append', default=[], metavar='FILE',
                   help='extra ROS 2 params file for the nodes (later files win)')
    p.add_argument('--set', action='append', default=[], metavar='NODE.PARAM=VALUE',
                   help="parameter override, e.g. controller.balance.design.omega0=2wp, rig.g=9.91")
    p.add_argument('--ns', type=namespace_arg, default=DEFAULT_NS, help=f'namespace of the rig (default {DEFAULT_NS})')
    p.add_argument('--rig', metavar='FILE', default=None,
                   help='the rig YAML every node reads (estimator, controller and its gain designs, plant): '
                   'a complete rig file such as DIR/rig.yaml of ./rwpend identify (default: the shipped '
                   'rwpend_model/config/rig.yaml)')
    p.add_argument('--plant-rig', metavar='FILE', default=None,
                   help='sim: the simulated plant\'s physical truth from this rig file of its own, while the '
                   'estimator and the controller keep reading --rig; the simulator reports the difference '
                   '(like --set sim.rig.KEY=VALUE for every key)')
    p.add_argument('--theta0', type=float, default=None, help='sim: initial pendulum angle (rad, 0 = down)')
    p.add_argument('--tap', action='append', default=[], metavar='T:DV',
                   help='sim: scripted tap at simulated time T s, theta_dot += DV rad/s')
    p.add_argument('--h', type=float, default=None, help='sample period (s), all nodes (rig.sample_period)')
    p.add_argument('--no-controller', action='store_true', help='do not start the controller')
    p.add_argument('--rt-priority', type=int, default=None, metavar='N',
                   help='SCHED_FIFO priority N (1-99) for the loop processes (plant, estimator, '
                   'controller), N-10 for the recorder or, in the loop layout, its bag writer (N in '
                   'lockstep); falls back to nice -10 where '
                   f'real-time scheduling is not permitted; 0: ordinary scheduling. Default: '
                   f'{DEFAULT_RT_PRIORITY} in real time where permitted, 0 in lockstep (a lockstep run keeps '
                   'the CPUs busy: at real-time priority it would starve the machine)')
    p.add_argument('--cpu-latency', type=int, default=None, metavar='US',
                   help='while the stack runs, ask the kernel (PM QoS, /dev/cpu_dma_latency) to keep '
                   'idle CPUs in states that wake within US microseconds; 0 = idle CPUs poll, the '
                   'fastest wake-up, at the cost of spinning CPUs. Needs root (else a warning, no '
                   'request); default: no request; see PERFORMANCE.md')
    p.add_argument('--pin', action='append', default=[], metavar='PROCESS=CPUS',
                   help='CPU affinity of one process of the stack (repeatable): loop, sim, driver, '
                   'estimator, controller, control (--composed control) or recorder, on the CPUs '
                   'CPUS (e.g. 0 or 0,1). On a 2-CPU machine '
                   '--pin sim=0 --pin estimator=0 --pin controller=1 took 12-57 us off the median '
                   'loop latency of separate processes (PERFORMANCE.md, "What each mechanism buys")')
    p.add_argument('--console', nargs='?', const='8080', default=None, metavar='[LISTEN:]PORT',
                   help='also run the lab console (./rwpend console: the rig in a browser, and the '
                   'Foxglove bridge on 8765), on 127.0.0.1:8080 unless given; in lockstep sample 0 waits '
                   'until its page is open, so the page shows the run from its start')
    p.add_argument('--composed', nargs='?', const='loop', default=None, choices=COMPOSITIONS + ('none',),
                   help='the nodes of the loop\'s process: "loop" (the default, also of a bare '
                   '--composed): plant (simulator or driver), estimator, controller and the recorder '
                   'around one loop thread; "control": estimator and controller, fed by the plant\'s '
                   'encoders topic, the plant in a process of its own (the default of --only: a stack '
                   'split across hosts); "none": each node a process of its own. See '
                   'docs/architecture.md')
    p.add_argument('--only', default=None, metavar='PROCESS[,PROCESS...]',
                   help='run only these processes of the stack, on this host (the others run on other '
                   'hosts of the network with the same up arguments): sim or driver, control '
                   '(estimator and controller; estimator, controller with --composed none), '
                   'recorder; e.g. the rig PC --only sim, a laptop --only control, a console --only '
                   'recorder. See docs/network.md.')


def usable_cpus() -> set[int]:
    """The CPUs this process may run on (its affinity: a container or a cgroup may allow fewer
    than the machine has)."""
    try:
        return set(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return set(range(os.cpu_count() or 1))


def parse_pins(pins: list[str], processes: list[str]) -> dict[str, str]:
    """``--pin PROCESS=CPUS`` items -> {process: 'cpu,cpu'}; ValueError with the reason for a
    process this stack does not run, a CPU it may not use (:func:`usable_cpus`), or a bad item."""
    usable = usable_cpus()
    out: dict[str, str] = {}
    for item in pins:
        name, sep, cpus = item.partition('=')
        name, ids = name.strip(), [c.strip() for c in cpus.split(',')]
        if not sep or not name or not cpus.strip():
            raise ValueError(f'--pin: PROCESS=CPUS (e.g. sim=0 or controller=0,1), got {item!r}')
        if name not in processes:
            raise ValueError(f'--pin: no process {name!r} in this stack (its processes: '
                             f'{", ".join(processes)})')
        if not all(c.isdigit() for c in ids):
            raise ValueError(f'--pin: CPU numbers separated by commas, got {item!r}')
        if not {int(c) for c in ids} <= usable:
            raise ValueError(f'--pin: {item!r}: this process may use CPUs '
                             f'{",".join(map(str, sorted(usable)))} only')
        if name in out:
            raise ValueError(f'--pin: {name} given twice')
        out[name] = ','.join(str(int(c)) for c in ids)
    return out


def choose_defaults(a) -> list[str]:
    """Resolve the defaults of ``up`` that depend on the machine and the plant, in ``a``: the
    real-time priority (``--rt-priority``: DEFAULT_RT_PRIORITY in real time where permitted, 0 in
    lockstep) and the layout (``--composed``: DEFAULT_LAYOUT of the plant; ``none`` = separate
    processes). Returns the lines that say what was chosen and why (printed by ``up``)."""
    notes = []
    plant = 'sim' if a.plant == 'sim' else 'serial'
    if getattr(a, 'composed', None) is True:      # a caller's boolean (the flag before it took a value)
        a.composed = 'loop'
    given = getattr(a, 'composed', None)
    layout = given or DEFAULT_LAYOUT[plant]
    if given is None and getattr(a, 'only', None) and layout == 'loop':
        # a stack split across hosts (--only sim / control / recorder): the plant in a process
        # of its own, the estimator and the controller in another
        layout = 'control'
    a.composed = None if layout == 'none' else layout
    notes.append(f'layout: {LAYOUT_TEXT[layout]}' + ('' if given else f' (the default for --plant {plant}; '
                                                      '--composed loop|control|none to change)'))
    prio = getattr(a, 'rt_priority', None)
    if prio is None:
        if a.lockstep:
            prio, why = 0, 'lockstep runs at ordinary priority'
        else:
            from rwpend_ros.sched import realtime_permitted
            ok, reason = realtime_permitted(DEFAULT_RT_PRIORITY)
            prio = DEFAULT_RT_PRIORITY if ok else 0
            why = ('where permitted (the default; --rt-priority 0 to turn it off)' if ok else
                   f'not permitted here ({reason}): ordinary scheduling; a busy machine may then miss '
                   'samples (run as root or set an rtprio limit)')
        notes.append(f'real-time priority: {prio or "none"} ({why})')
    a.rt_priority = prio
    return notes


def lockstep_controller_id(ns: str) -> int:
    """The controller id of ``up --lockstep`` in namespace ``ns``: fixed, non-zero, < 2^63."""
    import hashlib
    return int.from_bytes(hashlib.blake2b(ns.encode(), digest_size=8).digest(), 'big') >> 1 | 1


def build_stack(a, prog: str) -> tuple[list[NodeSpec], list[str]]:
    """Node specs and params files from the ``up`` arguments; raises ValueError with the reason
    (also for a bad ``RWPEND_TRANSPORT``: refused here, before any process starts). Call
    :func:`choose_defaults` first."""
    from rwpend_ros.transport import transport_choice
    transport_choice()
    params: dict[str, dict] = {'sim': {}, 'estimator': {}, 'controller': {}, 'driver': {}}
    rig: dict = {}
    for f in a.params:
        from rwpend_model.rig import read_params_file
        if not Path(f).is_file():
            raise ValueError(f'params file {f} does not exist')
        read_params_file(f)   # validates the format
    for s in a.set:
        node, name, value = parse_assignment(s)
        if node == 'rig':
            rig['rig.' + name] = value
        else:
            params[node][name] = value
    model_file, truth = rig_files(a)
    check_override_types(a.params, params, rig, rig_path=model_file)
    if a.h is not None:
        rig['rig.sample_period'] = float(a.h)
    from rwpend_model.rig import load_rig
    model = load_rig(model_file, overrides=rig)   # validated now, with the reason, before anything starts
    if a.duration is not None and not (math.isfinite(a.duration) and a.duration > 0):
        raise ValueError(f'--duration must be > 0, got {a.duration}')
    if a.mode:
        params['controller']['mode'] = a.mode
    if a.estimator:
        params['estimator']['estimator'] = a.estimator
    plant = a.plant
    if plant == 'sim':
        if a.lockstep:
            params['sim']['lockstep'] = True
        if a.duration:   # counted by the simulator from sample 0 (which waits for the loop)
            params['sim']['duration'] = float(a.duration)
        if a.theta0 is not None:
            params['sim']['initial.theta'] = float(a.theta0)
        if a.tap:
            times, sizes = [], []
            for t in a.tap:
                try:
                    ts, dvs = t.split(':')
                    times.append(float(ts))
                    sizes.append(float(dvs))
                except ValueError:
                    raise ValueError(f'--tap expects T:DV (e.g. 9:0.5), got {t!r}') from None
            params['sim']['taps.times'] = times
            params['sim']['taps.sizes'] = sizes
        # the plant's truth (--plant-rig), then what every node gets, then --set sim.*; the model
        # the others read goes along for the simulator's report of the difference
        model_params = {'model_' + k: v for k, v in model.as_params().items()}
        plant_spec = NodeSpec('sim', NODE_MODULES['sim'], {**truth, **rig, **params['sim'], **model_params},
                              args=list(NODE_ARGS['sim']), stop_rank=3)
    elif plant.startswith('serial:') and len(plant) > 7:
        if a.lockstep or a.tap or a.theta0 is not None or truth:
            raise ValueError('--lockstep, --tap, --theta0 and --plant-rig need the simulator (--plant sim); '
                             "the rig's truth is the rig (the emulator's: ./rwpend emulate --rig FILE)")
        params['driver']['port'] = plant[7:]
        if a.duration:   # counted by the driver from its first command (the loop closed)
            params['driver']['duration'] = float(a.duration)
        plant_spec = NodeSpec('driver', NODE_MODULES['driver'], {**rig, **params['driver']}, stop_rank=3)
    else:
        raise ValueError(f"--plant must be 'sim' or 'serial:PORT', got {plant!r}")
    # lockstep: sim time; the estimator and controller take it from the samples' stamps rather
    # than /clock (rwpend_ros.simtime.SampleTime: one DDS message less per sample and node)
    sim_time = {'use_sim_time': True, 'time_from_samples': True} if a.lockstep else {}
    if a.lockstep:
        # the id in every command (rwpend_ros.claim) fixed, so that a lockstep bag is the same
        # every run, on one host or several; in real time each controller draws its own
        params['controller'].setdefault('controller_id', lockstep_controller_id(a.ns))
    specs = [plant_spec,
             NodeSpec('estimator', NODE_MODULES['estimator'], {**rig, **sim_time, **params['estimator']},
                      stop_rank=2)]
    if not a.no_controller:
        specs.append(NodeSpec('controller', NODE_MODULES['controller'],
                              {**rig, **sim_time, **params['controller']}, stop_rank=1))
    if plant == 'sim' and a.lockstep:
        # sample 0 waits until the controller (and the recorder) listen to state: otherwise
        # state 0 may be published before the controller matched it, and the run would start
        # with u = 0 for a few samples -- not deterministic
        plant_spec.params['start.state_subscribers'] = int(not a.no_controller) + int(bool(a.record))
    if a.record:
        if plant == 'sim':   # the simulator holds sample 0 until the recorder listens
            plant_spec.params.update({'start.encoders_subscribers': 2, 'start.true_state_subscribers': 1})
        else:                # the driver publishes no sample until the recorder listens
            n = plant_spec.params.get('start.encoders_subscribers', 1)
            plant_spec.params['start.encoders_subscribers'] = max(2, n if isinstance(n, int) else 2)
        out = Path(a.record)
        # (with --only and the recorder on another host, the path is that host's)
        here = getattr(a, 'only', None) is None or 'recorder' in a.only.split(',')
        if here and out.exists() and (not out.is_dir() or any(out.iterdir())):
            raise ValueError(f'{out} already exists (choose a new bag directory)')
        if here and not out.parent.exists():
            raise ValueError(f'{out.parent} does not exist')
        rec_args = ['record', '-o', str(out), '--all']
        if plant == 'sim' and a.lockstep:
            # the simulator keeps within 50 samples of the recorder: a recorder that falls
            # behind slows the run down rather than losing messages (rwpend_loop.host)
            plant_spec.params.setdefault('lockstep_recorder_window', LOCKSTEP_RECORDER_WINDOW)
            rec_args += ['--progress', a.ns.rstrip('/') + '/recorder/progress']
        if a.lockstep:
            # log times on the simulated clock, in a deterministic order (rwpend_bag.logtime)
            rec_args.append('--sim-time')
        specs.append(NodeSpec('recorder', 'rwpend_bag.cli', args=rec_args, ros_args=False, stop_rank=9))
    composed = getattr(a, 'composed', None)
    if composed is True:      # a caller's boolean (the flag before it took a value)
        composed = 'loop'
    if composed not in (None, 'none', *COMPOSITIONS):
        raise ValueError(f'--composed must be one of {", ".join(COMPOSITIONS)} or none, got {composed!r}')
    if composed == 'loop':
        specs = loop_layout(specs, a)
    elif composed == 'control':
        specs = control_layout(specs)
    prio = getattr(a, 'rt_priority', 0) or 0
    if not 0 <= prio <= 99:
        raise ValueError(f'--rt-priority must be in 0..99, got {prio}')
    if prio:
        for s in specs:
            # real time: the recorder below the loop (it can wait, the loop cannot); lockstep:
            # the loop keeps both CPUs busy and waits for the recorder (its window), so the
            # recorder runs at the loop's priority
            below = s.name == 'recorder' and not a.lockstep
            s.env['RWPEND_RT_PRIORITY'] = str(max(1, prio - 10) if below else prio)
    lat = getattr(a, 'cpu_latency', None)
    if lat is not None and lat < 0:
        raise ValueError(f'--cpu-latency must be >= 0 (µs), got {lat}')
    for name, ids in parse_pins(getattr(a, 'pin', None) or [], [s.name for s in specs]).items():
        for s in specs:
            if s.name == name:
                s.env['RWPEND_CPUS'] = ids
    if getattr(a, 'console', None) is not None:   # not a loop process: its own priority, no pinning
        specs.append(console_spec(a, plant_spec))
    files = [str(model_file), str(stack_file()), *map(str, a.params)]
    return select_part(specs, getattr(a, 'only', None)), files


def loop_layout(specs: list[NodeSpec], a) -> list[NodeSpec]:
    """The plant (simulator or driver), estimator and controller of ``specs`` as nodes of one
    loop process (rwpend_loop.host, rwpend_loop.rig): the sample path in one thread. The
    recorder is a node of that process too: the bag is written from the bytes the nodes publish
    (no DDS hop), by a child process of its own below the loop (rwpend_bag.procwriter)."""
    members = [s for s in specs if s.name in ('sim', 'driver', 'estimator', 'controller')
               and s.module == NODE_MODULES[s.name]]
    sim = members[0]
    args = [s.name for s in members]
    rest = [s for s in specs if s not in members]
    rec = next((s for s in rest if s.name == 'recorder'), None)
    if rec is not None:
        rest.remove(rec)
        if 'start.state_subscribers' in sim.params:     # the recorder no longer subscribes to state
            sim.params['start.state_subscribers'] -= 1
        args += ['--record', str(a.record)] + (['--sim-time'] if a.lockstep else [])
        # (the driver counts the listeners of its process itself: DriverNode.listeners_here)
        for key in ('start.encoders_subscribers', 'start.true_state_subscribers', 'lockstep_recorder_window'):
            if sim.name == 'sim':
                sim.params.pop(key, None)
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
    if len(members) == 1:            # --no-controller: the estimator alone, a node process of its own
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


def select_part(specs: list[NodeSpec], only: str | None) -> list[NodeSpec]:
    """The processes of ``--only`` (comma-separated names of ``specs``), all when None.
    ValueError for a name the stack has not (its processes listed) or an empty list. Each
    process keeps the parameters it has in the whole stack (the simulator waits for the
    subscribers of the other hosts, lockstep nodes take sim time), so every host gives the
    same ``up`` arguments."""
    if only is None:
        return specs
    names = [n.strip() for n in only.split(',') if n.strip()]
    known = [s.name for s in specs]
    bad = [n for n in names if n not in known]
    if not names or bad:
        raise ValueError(f'--only: {", ".join(bad) or "no process"}: this stack runs {", ".join(known)} '
                         '(--composed changes the processes)')
    return [s for s in specs if s.name in names]


def rig_files(a) -> tuple[Path, dict]:
    """(the rig file every node reads, ``rig.*`` of the plant's own truth or {}) from ``--rig`` and
    ``--plant-rig``: complete rig files (rwpend_model.rig.load_rig_file), ValueError otherwise."""
    from rwpend_model.rig import load_rig_file
    rigs = {}
    for flag, f in (('--rig', getattr(a, 'rig', None) or rig_file()), ('--plant-rig', getattr(a, 'plant_rig', None))):
        if f is None:
            continue
        if not Path(f).is_file():
            raise ValueError(f'{flag}: no such file {f}')
        try:
            rigs[flag] = load_rig_file(f)
        except ValueError as exc:
            raise ValueError(f'{flag}: {exc}') from None
    truth = rigs['--plant-rig'].as_params() if '--plant-rig' in rigs else {}
    return Path(getattr(a, 'rig', None) or rig_file()), truth


def console_spec(a, plant_spec: NodeSpec) -> NodeSpec:
    """``up --console``: the lab console as a process of the stack, not of the loop: no pinning,
    in real time SCHED_FIFO 40 below the loop's priority (under the recorder, above ordinary
    programs: its e-stop must not wait for the CPU), ordinary priority in lockstep. In lockstep
    the simulator's sample 0 waits for one more subscriber of ``state``: the console takes state
    while a page watches the rig, so the run starts when the page is open. ValueError for a bad
    address."""
    from rwpend_console.console import parse_console_address
    listen, port = parse_console_address(a.console)
    if a.plant == 'sim' and a.lockstep:
        plant_spec.params['start.state_subscribers'] = plant_spec.params.get('start.state_subscribers', 0) + 1
    prio = getattr(a, 'rt_priority', 0) or 0
    return NodeSpec('console', 'rwpend_console.console', args=['--ns', a.ns, '--listen', listen, '--port', str(port)],
                    ros_args=False, required=a.lockstep, stop_rank=8,
                    env={'RWPEND_RT_PRIORITY': str(max(1, prio - 40)) if prio and not a.lockstep else '0'})


def up_main(argv) -> int:
    p = Parser(prog='rwpend up', description='Run the stack (Ctrl-C stops it: controller first, '
               'recorder last).')
    add_stack_args(p)
    a = p.parse_args(argv)
    try:
        notes = choose_defaults(a)
        specs, files = build_stack(a, p.prog)
    except ValueError as exc:
        return fail(p.prog, str(exc))
    for n in notes:
        print(f'rwpend: {n}', flush=True)
    if a.console is not None and a.lockstep:
        print('rwpend: lockstep with --console: the run starts when the console page is open (its '
              'address follows)', flush=True)
    return run_stack(a, specs, files)


def run_stack(a, specs, files, on_started=None) -> int:
    launcher = Launcher(specs, namespace=a.ns, params_files=files)
    names = ', '.join(s.name for s in specs)
    from rwpend_ros.transport import discovery_range, transport_choice
    print(f'rwpend: starting {names} in {a.ns} (ROS_DOMAIN_ID={os.environ.get("ROS_DOMAIN_ID", "0")}, '
          f'discovery {discovery_range()}, transport {transport_choice()})',
          flush=True)
    from rwpend_ros.sched import request_cpu_latency
    with request_cpu_latency(getattr(a, 'cpu_latency', None)) as req:   # held until the stack has stopped
        if req.us is not None:
            print(f'rwpend: CPU wake-up latency request: {req.status}', flush=True,
                  file=sys.stdout if req.active else sys.stderr)
        t0 = time.monotonic()
        # the plant exits by itself after --duration s from its sample 0 (simulated time in
        # lockstep) or, the driver, from its first command; the wall-clock bound only catches a
        # stack that never starts
        bound = None if a.duration is None else 120.0 + (20.0 if a.lockstep else 1.5) * a.duration
        status = launcher.run(bound, on_started=on_started)
        print(f'rwpend: stopped ({launcher.reason})', flush=True)
        return judge_run(a, specs, launcher.exit_codes, status, time.monotonic() - t0,
                         interrupted=launcher.reason == 'signal')


#: s to wait for the loop's bag writer to finish a bag its process did not close
WRITER_FINISH_S = 30.0


def judge_run(a, specs, exit_codes: dict, status: int, wall_s: float, interrupted: bool = False) -> int:
    """The exit status of ``up``: non-zero, with the reason, when the loop was dead at the end
    (a node's exit status :data:`rwpend_ros.health.EXIT_LOOP_DEAD`) or the bag is much shorter
    than the run (:func:`rwpend_bringup.verdict.recording_problems`). A run stopped by a signal
    (Ctrl-C, ``interrupted``) before its ``--duration`` is expected to hold what the wall time
    allows in real time, and is not judged by length in lockstep (its simulated length is the
    plant's, unknown here)."""
    from .verdict import EXIT_LOOP_DEAD, EXIT_SHORT_BAG, dead_nodes, expected_samples, recording_problems
    dead = dead_nodes(exit_codes)
    if dead:
        print(f'rwpend: FAILED: the loop was dead at the end of the run (reported by {", ".join(dead)}: '
              'no fresh command for seconds; see its log above)', file=sys.stderr, flush=True)
        status = EXIT_LOOP_DEAD
    names = {s.name for s in specs}
    if not a.record or not names & {'recorder', 'loop'}:
        return status
    report_file = Path(a.record) / 'recording_report.json'
    if 'loop' in names and not report_file.exists():
        # the loop's bag writer is a process of its own: when the loop's process ended without
        # closing the bag, the writer finishes it on its own (rwpend_bag.procwriter)
        end = time.monotonic() + WRITER_FINISH_S
        while not report_file.exists() and time.monotonic() < end:
            time.sleep(0.1)
    try:
        report = json.loads(report_file.read_text())
    except (OSError, ValueError) as exc:
        print(f'rwpend: FAILED: no recording report in {a.record} ({exc}): the bag may be incomplete',
              file=sys.stderr, flush=True)
        return status or EXIT_SHORT_BAG
    h = next((float(s.params['rig.sample_period']) for s in specs if 'rig.sample_period' in s.params),
             None) or _rig_sample_period()
    expected = expected_samples(h, a.duration, a.lockstep, wall_s, interrupted)
    if not a.duration and not names & {'sim', 'driver', 'loop'}:
        # a host without the plant (up --only recorder): its own wall time says nothing of the
        # plant's samples
        expected = None
    problems, warnings = recording_problems(report, expected)
    for w in warnings:
        print(f'rwpend: warning: the bag is missing messages: {w} (recording_report.json)', flush=True)
    for p in problems:
        print(f'rwpend: FAILED: {p} ({report_file})', file=sys.stderr, flush=True)
    if problems and not status:
        status = EXIT_SHORT_BAG
    return status


def _rig_sample_period() -> float:
    from rwpend_model.rig import load_rig
    return load_rig().sample_period


NODE_USAGE = """usage: rwpend node {NODES} [-p NAME:=VALUE ...] [--params FILE ...] [--ns NS] [--ros-args ...]
       rwpend sim [-p NAME:=VALUE ...] [...]          (= rwpend node sim)

Runs one node (like `ros2 run`) with the rig YAML and the stack defaults loaded, in namespace
{NS} unless --ns (or --ros-args -r __ns:=...) is given. -p NAME:=VALUE overrides a
parameter (rig data too: -p rig.g:=9.91); --params adds a ROS 2 params file (later wins).
Examples:
  ./rwpend sim -p lockstep:=true -p initial.theta:=3.1416     # the simulator alone
  ./rwpend node estimator --ns /offline -p estimator:=observer3"""


def node_main(argv, name: str | None = None) -> int:
    """One node process. -p overrides are written to a last params file: rclpy ranks a file's
    `/**/node` section above a command-line -p, so a plain -p would lose to stack.yaml."""
    import tempfile

    import yaml
    prog = 'rwpend sim' if name == 'sim' else 'rwpend node'
    usage = NODE_USAGE.format(NODES='{' + ','.join(NODE_MODULES) + '}', NS=DEFAULT_NS)
    argv = list(argv)
    if name is None:
        if not argv or argv[0] in ('-h', '--help'):
            print(usage)
            return 0 if argv else 2
        if argv[0] not in NODE_MODULES:
            return fail(prog, f'unknown node {argv[0]!r} (one of {", ".join(NODE_MODULES)})')
        name, argv = argv[0], argv[1:]
    ros = argv[argv.index('--ros-args') + 1:] if '--ros-args' in argv else []
    ours = argv[:argv.index('--ros-args')] if '--ros-args' in argv else argv
    if any(x in ('-h', '--help') for x in ours):
        print(usage)
        return 0
    overrides: dict = {}
    files: list[str] = []
    ns = None
    rest_ros: list[str] = []
    i = 0
    items = [('ours', x) for x in ours] + [('ros', x) for x in ros]
    while i < len(items):
        kind, x = items[i]
        nxt = items[i + 1][1] if i + 1 < len(items) else None
        if x in ('-p', '--param'):
            if nxt is None or ':=' not in nxt:
                return fail(prog, f'{x} expects NAME:=VALUE, got {nxt!r}')
            key, val = nxt.split(':=', 1)
            if not key:
                return fail(prog, f'{x} expects NAME:=VALUE, got {nxt!r}')
            try:
                overrides[key] = yaml.safe_load(val) if val != '' else ''
            except yaml.YAMLError:
                overrides[key] = val
            i += 2
        elif kind == 'ours' and x == '--params':
            if nxt is None or not Path(nxt).is_file():
                return fail(prog, f'--params: no such file {nxt!r}')
            files.append(str(Path(nxt).resolve()))
            i += 2
        elif kind == 'ours' and x == '--ns':
            if nxt is None:
                return fail(prog, '--ns expects a namespace')
            try:
                ns = namespace_arg(nxt)
            except (argparse.ArgumentTypeError, ValueError) as exc:
                return fail(prog, str(exc))
            i += 2
        elif kind == 'ours':
            return fail(prog, f'unknown argument {x!r} (ROS arguments go after --ros-args)')
        else:
            rest_ros.append(x)
            i += 1
    for f in files:
        from rwpend_model.rig import read_params_file
        try:
            read_params_file(f)
        except ValueError as exc:
            return fail(prog, f'{f}: {exc}')
    try:
        check_override_types(files, {name: overrides}, {}, flag='-p')
    except ValueError as exc:
        return fail(prog, str(exc))
    if ns is None and not any(x.startswith('__ns:=') for x in rest_ros):
        ns = DEFAULT_NS
    cmd = [sys.executable, '-u', '-m', NODE_MODULES[name], *NODE_ARGS.get(name, ()), '--ros-args']
    if ns is not None:
        cmd += ['-r', f'__ns:={ns}']
    cmd += ['--params-file', str(rig_file()), '--params-file', str(stack_file())]
    for f in files:
        cmd += ['--params-file', f]
    if overrides:
        fd, path = tempfile.mkstemp(prefix=f'rwpend_{name}_', suffix='.yaml')
        with os.fdopen(fd, 'w') as fh:
            yaml.safe_dump({f'/**/{name}': {'ros__parameters': overrides}}, fh)
        cmd += ['--params-file', path]
    cmd += rest_ros
    sys.stdout.flush()
    os.execv(sys.executable, cmd)
    return 0  # pragma: no cover


def sim_main(argv) -> int:
    return node_main(argv, name='sim')


# ------------------------------------------------------------------ demo
def demo_main(argv) -> int:
    p = Parser(prog='rwpend demo', description='Swing-up, catch, balance and a tap on the simulator '
               '(lockstep, deterministic); writes a bag, a plot and metrics to OUT.')
    p.add_argument('-o', '--out', default=str(ROOT / 'demo_out'), help='output directory (default demo_out)')
    p.add_argument('--duration', type=float, default=16.0, help='simulated seconds (default 16)')
    p.add_argument('--tap', default='11:0.6', metavar='T:DV', help='tap (default 11:0.6)')
    p.add_argument('--realtime', action='store_true', help='run in real time instead of lockstep')
    a = p.parse_args(argv)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    bag = out / time.strftime('demo_%Y%m%d_%H%M%S')
    up_args = ['--mode', 'auto', '--duration', str(a.duration), '--tap', a.tap, '--record', str(bag)]
    if not a.realtime:
        up_args.append('--lockstep')
    sp = Parser(prog='rwpend demo')
    add_stack_args(sp)
    ua = sp.parse_args(up_args)
    try:
        for n in choose_defaults(ua):
            print(f'rwpend: {n}', flush=True)
        specs, files = build_stack(ua, p.prog)
    except ValueError as exc:
        return fail(p.prog, str(exc))
    t0 = time.monotonic()
    status = run_stack(ua, specs, files)
    wall = time.monotonic() - t0
    if status != 0:
        return fail(p.prog, 'the stack did not run cleanly (see above)', 1)
    from rwpend_bag.cli import analyze_main
    plot = out / 'demo.png'
    metrics_file = out / 'metrics.json'
    print(f'rwpend demo: analysing {bag}', flush=True)
    import contextlib
    import io
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        st = analyze_main([str(bag), '--plot', str(plot), '--json'])
    if st != 0:
        print(buf.getvalue())
        return fail(p.prog, f'analysis of {bag} failed', 1)
    metrics = json.loads(buf.getvalue())
    metrics_file.write_text(json.dumps(metrics, indent=2) + '\n')
    from rwpend_bag.analysis import format_metrics
    print(format_metrics(metrics))
    if a.realtime:
        why = 'real time (--realtime), like the rig'
    else:
        why = ('lockstep: deterministic, the same bag every run; `--realtime` runs it on the wall '
               'clock like the rig (how many samples a machine like ours answers late, per layout: '
               'PERFORMANCE.md)')
    print(f'rwpend demo: {why}')
    print(f'rwpend demo: {a.duration:g} s simulated in {wall:.1f} s wall\n'
          f'  bag:     {bag}\n  plot:    {plot}\n  metrics: {metrics_file}', flush=True)
    return 0


# ------------------------------------------------------------------ param / mode / tap / estop
def _tool(ns):
    from rwpend_ros.tools import RosTool
    return RosTool(ns)


def param_main(argv) -> int:
    p = Parser(prog='rwpend param', description='Parameters of a running node through the standard '
               'ROS 2 parameter services (what `ros2 param` does). NODE is relative to --ns '
               '(controller -> /rwpend/controller) or absolute.')
    p.add_argument('--ns', type=namespace_arg, default=DEFAULT_NS)
    sub = p.add_subparsers(dest='cmd', required=True)
    s = sub.add_parser('list', help='parameter names')
    s.add_argument('node')
    s = sub.add_parser('get', help='values')
    s.add_argument('node')
    s.add_argument('names', nargs='+')
    s = sub.add_parser('set', help='set NAME VALUE [NAME VALUE ...] (validated by the node; several '
                       'pairs are set atomically: all or nothing)')
    s.add_argument('node')
    s.add_argument('pairs', nargs='+', metavar='NAME VALUE')
    s = sub.add_parser('dump', help='all parameters as a ROS 2 params file')
    s.add_argument('node')
    s = sub.add_parser('load', help='set the parameters of a ROS 2 params file (e.g. a dump), one by '
                       'one as `ros2 param load` does; read-only ones with the value they have are left out')
    s.add_argument('node')
    s.add_argument('file')
    s = sub.add_parser('describe', help='type, description, range and constraints')
    s.add_argument('node')
    s.add_argument('names', nargs='*', help='parameters (default: all)')
    a = p.parse_args(argv)
    from rwpend_ros.tools import ToolError, format_descriptor, format_value, parse_value
    if a.cmd == 'set' and len(a.pairs) % 2:
        return fail(p.prog, 'set expects NAME VALUE pairs')
    try:
        with _tool(a.ns) as t:
            if a.cmd == 'list':
                print('\n'.join(t.list_params(a.node)))
            elif a.cmd == 'get':
                for n, v in t.get_params(a.node, a.names).items():
                    print(f'{n}: {format_value(v)}')
            elif a.cmd == 'dump':
                print(t.dump(a.node), end='')
            elif a.cmd == 'describe':
                names = a.names or t.list_params(a.node)
                for n, d in zip(names, t.describe(a.node, names)):
                    d.name = d.name or n
                    print(format_descriptor(d))
            elif a.cmd == 'load':
                return _param_load(t, a.node, a.file, p.prog)
            else:
                values = {a.pairs[i]: parse_value(a.pairs[i + 1]) for i in range(0, len(a.pairs), 2)}
                if len(values) > 1:   # a set of gains is validated as a whole: all or nothing
                    ok, reason = t.set_params_atomically(a.node, values)
                    if not ok:
                        print(f'refused (nothing changed): {reason or "no reason given"}', file=sys.stderr)
                        return 1
                    print('set: ' + ', '.join(values))
                    return 0
                results = t.set_params(a.node, values)
                bad = 0
                for name, ok, reason in results:
                    if ok:
                        print(f'{name}: set')
                    else:
                        bad += 1
                        print(f'{name}: refused: {reason or "no reason given"}', file=sys.stderr)
                return 1 if bad else 0
    except ToolError as exc:
        return fail(p.prog, str(exc), 1)
    return 0


def _param_load(tool, node: str, path: str, prog: str) -> int:
    """``rwpend param load``: the file's values for the node (its section and ``/**``), set one by
    one; exit status 1 when one is refused."""
    from rwpend_model.rig import read_params_file
    try:
        values = read_params_file(path, tool.fqn(node))
    except ValueError as exc:
        return fail(prog, str(exc))
    if not values:
        return fail(prog, f'{path} has no parameters for {tool.fqn(node)}')
    results, unchanged = tool.load(node, values)
    bad = [(n, why) for n, ok, why in results if not ok]
    for n, why in bad:
        print(f'{n}: refused: {why or "no reason given"}', file=sys.stderr)
    print(f'loaded {len(results) - len(bad)} of {len(results)} parameters'
          + (f' ({unchanged} read-only ones unchanged, left out)' if unchanged else ''))
    return 1 if bad else 0


def mode_main(argv) -> int:
    p = Parser(prog='rwpend mode', description='Set the controller mode (controller/set_mode).')
    p.add_argument('mode', choices=MODES)
    p.add_argument('--ns', type=namespace_arg, default=DEFAULT_NS)
    a = p.parse_args(argv)
    from rwpend_ros.tools import ToolError
    try:
        with _tool(a.ns) as t:
            ok, msg = t.set_mode(a.mode)
    except ToolError as exc:
        return fail(p.prog, str(exc), 1)
    print(msg) if ok else print(f'refused: {msg}', file=sys.stderr)
    return 0 if ok else 1


def tap_main(argv) -> int:
    p = Parser(prog='rwpend tap', description='Tap the simulated pendulum (sim/disturb): theta_dot += DV; '
               'or, with --torque, apply a torque of DV units for --seconds.')
    p.add_argument('dv', type=float, help='rad/s (or control units with --torque)')
    p.add_argument('--torque', action='store_true')
    p.add_argument('--seconds', type=float, default=0.5)
    p.add_argument('--ns', type=namespace_arg, default=DEFAULT_NS)
    a = p.parse_args(argv)
    from rwpend_ros.tools import ToolError
    try:
        with _tool(a.ns) as t:
            ok, msg = t.disturb(1 if a.torque else 0, a.dv, a.seconds if a.torque else 0.0)
    except ToolError as exc:
        return fail(p.prog, str(exc), 1)
    print(msg) if ok else print(f'refused: {msg}', file=sys.stderr)
    return 0 if ok else 1


def estop_main(argv) -> int:
    p = Parser(prog='rwpend estop', description='Raise the latched e-stop on the plant/driver (motor '
               'held at zero whatever the controller sends), or clear it.')
    p.add_argument('--clear', action='store_true')
    p.add_argument('--ns', type=namespace_arg, default=DEFAULT_NS)
    p.add_argument('--timeout', type=float, default=5.0, metavar='S',
                   help='seconds to find the e-stop services and for each to answer (default 5; '
                   'discovery on a busy lab network can take longer)')
    a = p.parse_args(argv)
    from rwpend_ros.tools import RosTool, ToolError
    if not a.timeout > 0:
        return fail(p.prog, f'--timeout must be > 0, got {a.timeout}')
    try:
        with RosTool(a.ns, timeout=a.timeout) as t:
            results = t.estop(not a.clear)
    except ToolError as exc:
        return fail(p.prog, str(exc), 1)
    bad = 0
    for name, ok, msg in results:
        print(f'{name}: {msg}')
        bad += not ok
    return 1 if bad else 0


def graph_main(argv) -> int:
    p = Parser(prog='rwpend graph', description='What this host sees of its ROS domain '
               '(ROS_DOMAIN_ID, discovery range): every node, the topics it subscribes to and who '
               'publishes them. Says where a node takes a topic from another namespace (another rig), '
               '/diagnostics, /parameter_events, /rosout and /clock aside.')
    p.add_argument('--settle', type=float, default=3.0, help='seconds of discovery first (default 3)')
    p.add_argument('--json', action='store_true', help='the graph as JSON')
    a = p.parse_args(argv)
    from rwpend_ros.tools import RosTool, foreign_publishers
    with RosTool('/') as t:
        g = t.graph(a.settle)
    if a.json:
        print(json.dumps(g, indent=2, sort_keys=True))
        return 0
    for node, info in sorted(g.items()):
        print(node)
        for topic, pubs in sorted(info['subscriptions'].items()):
            print(f'  <- {topic}: {", ".join(pubs) or "no publisher"}')
    foreign = foreign_publishers(g)
    print(f'{len(g)} nodes; ' + (f'{len(foreign)} subscription(s) reached from another namespace:\n  '
                                  + '\n  '.join(foreign) if foreign else 'every node hears its own namespace only'))
    return 0


# ------------------------------------------------------------------ delegated commands
def gains_main(argv) -> int:
    from rwpend_control.gains_cli import main
    return main(argv)


def bag_main(argv) -> int:
    from rwpend_bag import cli
    if not argv or argv[0] != 'info':
        print('usage: rwpend bag info BAG', file=sys.stderr)
        return 2
    return cli.info_main(argv[1:])


def record_main(argv) -> int:
    from rwpend_bag.cli import record_main as m
    return m(argv)


def play_main(argv) -> int:
    from rwpend_bag.cli import play_main as m
    return m(argv)


def analyze_main(argv) -> int:
    from rwpend_bag.cli import analyze_main as m
    return m(argv)


def emulate_main(argv) -> int:
    from rwpend_driver.emulator import main
    return main(argv)


def bench_main(argv) -> int:
    try:
        from .bench import main
    except ImportError:
        return fail('rwpend bench', 'the benchmark is not available in this version', 1)
    return main(argv)


def soak_main(argv) -> int:
    from .soak import main
    return main(argv)


def lab_main(argv) -> int:
    from rwpend_lab.cli import main
    return main(argv)


def identify_main(argv) -> int:
    from rwpend_ident.cli import main
    return main(argv)


def console_main(argv) -> int:
    from rwpend_console.console import main
    return main(argv)


def bridge_main(argv) -> int:
    from rwpend_console.bridge import main
    return main(argv)


def sweep_main(argv) -> int:
    from rwpend_sweep.cli import main
    return main(argv)


COMMANDS = {
    'up': up_main, 'node': node_main, 'sim': sim_main, 'demo': demo_main, 'param': param_main, 'mode': mode_main,
    'tap': tap_main, 'estop': estop_main, 'graph': graph_main, 'gains': gains_main, 'record': record_main,
    'play': play_main, 'bag': bag_main, 'analyze': analyze_main, 'emulate': emulate_main,
    'bench': bench_main, 'soak': soak_main, 'lab': lab_main, 'identify': identify_main,
    'console': console_main, 'bridge': bridge_main, 'sweep': sweep_main,
}


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if not argv or argv[0] in ('-h', '--help', 'help'):
        print(__doc__.strip().replace('``', '`'))
        return 0 if argv else 2
    cmd = argv[0]
    apply_network_defaults()
    from rwpend_ros.transport import apply_transport_or_exit
    apply_transport_or_exit()   # every node and tool started from here inherits it
    if cmd not in COMMANDS:
        print(f'rwpend: unknown command {cmd!r}; `./rwpend --help` lists them', file=sys.stderr)
        return 2
    try:
        return COMMANDS[cmd](argv[1:])
    except SystemExit as exc:
        return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 2)
    except KeyboardInterrupt:
        return 130


if __name__ == '__main__':
    sys.exit(main())
