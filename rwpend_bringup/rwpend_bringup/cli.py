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
  gains     the book's gain designs, and applying them to a running controller
  record    record topics to a rosbag2 MCAP bag
  play      replay a bag
  bag info  topics, counts, rates, seq gaps of a bag
  analyze   metrics and plots of a run
  emulate   the rig's microcontroller on a pseudo-terminal (for --plant serial:PATH)
  bench     the real-time / lockstep benchmark (JSON in bench_out/)
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
MODES = ('off', 'wheel_velocity', 'wheel_angle', 'balance', 'swingup', 'auto')
NODE_MODULES = {
    'sim': 'rwpend_sim.sim_node',
    'estimator': 'rwpend_estimation.estimator_node',
    'controller': 'rwpend_control.controller_node',
    'driver': 'rwpend_driver.driver_node',
}
#: ``--composed`` values: which nodes share one process (rwpend_bringup.composed)
COMPOSITIONS = ('all', 'control')
#: ./rwpend up --lockstep --record: samples the simulator may run ahead of the recorder
LOCKSTEP_RECORDER_WINDOW = 50


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


def check_override_types(files, params: dict[str, dict], rig: dict, flag: str = '--set') -> None:
    """Each value of a ``--params`` file or a ``--set`` must have the type of the value it
    overrides (rig.yaml, stack.yaml, an earlier ``--params``): rcl keeps the earlier value,
    silently, when a later file gives another type (measured with rclpy 7.1.6: ``soon`` over 0.5
    and 2.5 over 1 are ignored). An integer where a float was is fine (the nodes take it as
    that float). ``params``: the ``--set`` values per node (``flag``: ``-p`` of ``rwpend node``),
    ``rig``: those of ``rig.*``. ValueError with the reason otherwise, before anything starts."""
    from rwpend_model.rig import read_params_file, typed_like
    for node in params:
        seen = {**read_params_file(rig_file(), node), **read_params_file(stack_file(), node)}
        sources = [(str(f), read_params_file(f, node)) for f in files]
        sources.append((flag, {**params[node], **rig}))
        for source, values in sources:
            for name, value in values.items():
                if name in seen and value is not None:
                    try:
                        typed_like(name, value, seen[name])
                    except ValueError as exc:
                        where = (f'{source} ({node})' if source != flag else f'{flag} {name}'
                                 if name in rig or flag != '--set' else f'--set {node}.{name}')
                        raise ValueError(f'{where}: {exc} (the type of {seen[name]!r} it overrides; '
                                         f'ROS would keep that value)') from None
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
                   'the simulator, wall time with a serial plant)')
    p.add_argument('--mode', choices=MODES, default=None, help='controller mode at start')
    p.add_argument('--estimator', default=None, help='estimator at start (see estimator node)')
    p.add_argument('--record', metavar='DIR', default=None, help='record every topic to this bag')
    p.add_argument('--params', action='append', default=[], metavar='FILE',
                   help='extra ROS 2 params file for the nodes (later files win)')
    p.add_argument('--set', action='append', default=[], metavar='NODE.PARAM=VALUE',
                   help="parameter override, e.g. controller.balance.design.omega0=2wp, rig.g=9.91")
    p.add_argument('--ns', type=namespace_arg, default=DEFAULT_NS, help=f'namespace of the rig (default {DEFAULT_NS})')
    p.add_argument('--theta0', type=float, default=None, help='sim: initial pendulum angle (rad, 0 = down)')
    p.add_argument('--tap', action='append', default=[], metavar='T:DV',
                   help='sim: scripted tap at simulated time T s, theta_dot += DV rad/s')
    p.add_argument('--h', type=float, default=None, help='sample period (s), all nodes (rig.sample_period)')
    p.add_argument('--no-controller', action='store_true', help='do not start the controller')
    p.add_argument('--rt-priority', type=int, default=0, metavar='N',
                   help='SCHED_FIFO priority N (1-99) for the loop processes (plant, estimator, '
                   'controller), N-10 for the recorder (N in lockstep); falls back to nice -10 where real-time '
                   'scheduling is not permitted (default 0: ordinary scheduling); see PERFORMANCE.md')
    p.add_argument('--cpu-latency', type=int, default=None, metavar='US',
                   help='while the stack runs, ask the kernel (PM QoS, /dev/cpu_dma_latency) to keep '
                   'idle CPUs in states that wake within US microseconds; 0 = idle CPUs poll, the '
                   'fastest wake-up, at the cost of spinning CPUs. Needs root (else a warning, no '
                   'request); default: no request; see PERFORMANCE.md')
    p.add_argument('--cpus', default=None, metavar='LOOP[:RECORDER]',
                   help='CPU affinity: the loop processes (plant, estimator, controller) on the CPUs '
                   'LOOP (e.g. 1 or 0,1), the recorder on RECORDER if given (e.g. --cpus 1:0); '
                   'see PERFORMANCE.md')
    p.add_argument('--pin', action='append', default=[], metavar='PROCESS=CPUS',
                   help='CPU affinity of one process of the stack (repeatable; overrides --cpus for '
                   'it): sim, driver, estimator, controller, control (--composed control), stack '
                   '(--composed) or recorder, on the CPUs CPUS (e.g. 0 or 0,1). On a 2-CPU machine '
                   '--pin sim=0 --pin estimator=0 --pin controller=1 took 12-57 us off the median '
                   'loop latency of separate processes (PERFORMANCE.md, 20.)')
    p.add_argument('--composed', nargs='?', const='all', default=None, choices=COMPOSITIONS,
                   help='nodes in one process on one executor: "all" (the default of a bare '
                   '--composed): plant (simulator), estimator and controller; "control": estimator '
                   'and controller, the plant (simulator or driver) in its own process, like '
                   'ros2_control separates hardware from controllers. The recorder stays a process '
                   'of its own; see PERFORMANCE.md')


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


def build_stack(a, prog: str) -> tuple[list[NodeSpec], list[str]]:
    """Node specs and params files from the ``up`` arguments; raises ValueError with the reason
    (also for a bad ``RWPEND_TRANSPORT``, ``RWPEND_HOST_BUS`` or ``RWPEND_RECORDER_FAST_PATH``:
    refused here, before any process starts)."""
    from rwpend_ros import hostbus
    from rwpend_ros.transport import transport_choice
    transport_choice()
    hostbus.recorder_enabled()      # checks RWPEND_HOST_BUS too
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
    check_override_types(a.params, params, rig)
    if a.h is not None:
        rig['rig.sample_period'] = float(a.h)
    if rig:
        from rwpend_model.rig import load_rig
        load_rig(overrides=rig)   # validated now, with the reason, before anything starts
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
        plant_spec = NodeSpec('sim', NODE_MODULES['sim'], {**rig, **params['sim']}, stop_rank=3)
    elif plant.startswith('serial:') and len(plant) > 7:
        if a.lockstep or a.tap or a.theta0 is not None:
            raise ValueError('--lockstep, --tap and --theta0 need the simulator (--plant sim)')
        params['driver']['port'] = plant[7:]
        plant_spec = NodeSpec('driver', NODE_MODULES['driver'], {**rig, **params['driver']}, stop_rank=3)
    else:
        raise ValueError(f"--plant must be 'sim' or 'serial:PORT', got {plant!r}")
    # lockstep: sim time; the estimator and controller take it from the samples' stamps rather
    # than /clock (rwpend_ros.common.SampleTime: one DDS message less per sample and node)
    sim_time = {'use_sim_time': True, 'time_from_samples': True} if a.lockstep else {}
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
        out = Path(a.record)
        if out.exists() and (not out.is_dir() or any(out.iterdir())):
            raise ValueError(f'{out} already exists (choose a new bag directory)')
        if not out.parent.exists():
            raise ValueError(f'{out.parent} does not exist')
        rec_args = ['record', '-o', str(out), '--all']
        if plant == 'sim' and a.lockstep:
            # the simulator keeps within 50 samples of the recorder: a recorder that falls
            # behind slows the run down rather than losing messages (rwpend_sim.sim_node)
            plant_spec.params.setdefault('lockstep_recorder_window', LOCKSTEP_RECORDER_WINDOW)
            rec_args += ['--progress', a.ns.rstrip('/') + '/recorder/progress']
        specs.append(NodeSpec('recorder', 'rwpend_bag.cli', args=rec_args, ros_args=False, stop_rank=9))
    composed = getattr(a, 'composed', None)
    if composed is True:      # a caller's boolean (the flag before it took a value)
        composed = 'all'
    if composed:
        if composed not in COMPOSITIONS:
            raise ValueError(f'--composed must be one of {", ".join(COMPOSITIONS)}, got {composed!r}')
        if composed == 'all' and plant != 'sim':
            raise ValueError('--composed all needs the simulator (--plant sim): the driver runs in '
                             'its own process (--composed control keeps it there)')
        members = ('sim', 'estimator', 'controller') if composed == 'all' else ('estimator', 'controller')
        nodes = [s for s in specs if s.name in members and s.module == NODE_MODULES[s.name]]
        name = 'stack' if composed == 'all' else 'control'
        first = specs.index(nodes[0])
        rest = [s for s in specs if s not in nodes]
        specs = [*rest[:first],
                 NodeSpec(name, 'rwpend_bringup.composed', args=[s.name for s in nodes],
                          node_params={s.name: s.params for s in nodes},
                          stop_rank=min(s.stop_rank for s in nodes)),
                 *rest[first:]]
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
    cpus = getattr(a, 'cpus', None)
    if cpus:
        loop, _, rec = cpus.partition(':')
        n = os.cpu_count() or 1
        for part in (loop, rec):
            ids = [c.strip() for c in part.split(',')] if part else []
            if part and not all(c.isdigit() and int(c) < n for c in ids):
                raise ValueError(f'--cpus: CPU numbers 0..{n - 1} separated by commas, LOOP[:RECORDER], '
                                 f'got {cpus!r}')
        if not loop:
            raise ValueError(f'--cpus: LOOP CPUs missing in {cpus!r}')
        for s in specs:
            if s.name == 'recorder':
                if rec:
                    s.env['RWPEND_CPUS'] = rec
            else:
                s.env['RWPEND_CPUS'] = loop
    for name, ids in parse_pins(getattr(a, 'pin', None) or [], [s.name for s in specs]).items():
        for s in specs:
            if s.name == name:
                s.env['RWPEND_CPUS'] = ids
    files = [str(rig_file()), str(stack_file()), *map(str, a.params)]
    return specs, files


def up_main(argv) -> int:
    p = Parser(prog='rwpend up', description='Run the stack (Ctrl-C stops it: controller first, '
               'recorder last).')
    add_stack_args(p)
    a = p.parse_args(argv)
    try:
        specs, files = build_stack(a, p.prog)
    except ValueError as exc:
        return fail(p.prog, str(exc))
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
        if a.plant == 'sim':
            # the simulator exits by itself after --duration s from its sample 0 (simulated time in
            # lockstep); the wall-clock bound only catches a stack that never starts
            bound = None if a.duration is None else 120.0 + (20.0 if a.lockstep else 1.5) * a.duration
            status = launcher.run(bound, on_started=on_started)
        else:
            status = launcher.run(a.duration, on_started=on_started)
        print(f'rwpend: stopped ({launcher.reason})', flush=True)
        return status


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
    cmd = [sys.executable, '-u', '-m', NODE_MODULES[name], '--ros-args']
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
        why = ('lockstep: deterministic, the same bag every run; on a 2-core VM the real-time '
               '1 kHz loop of separate processes answered 0-0.26 % of its samples late in 20-60 s runs '
               'with `up --rt-priority 50 --cpu-latency 0` (more when the host stalls, and without '
               'those options: PERFORMANCE.md); `--realtime` to try it')
    print(f'rwpend demo: {why}')
    print(f'rwpend demo: {a.duration:g} s simulated in {wall:.1f} s wall\n'
          f'  bag:     {bag}\n  plot:    {plot}\n  metrics: {metrics_file}', flush=True)
    return 0


# ------------------------------------------------------------------ param / mode / tap / estop
def _tool(ns):
    from .rostools import RosTool
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
    s = sub.add_parser('describe', help='descriptions and constraints')
    s.add_argument('node')
    s.add_argument('names', nargs='+')
    a = p.parse_args(argv)
    from .rostools import ToolError, format_value, parse_value
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
                for d in t.describe(a.node, a.names):
                    ro = ' (read-only)' if d.read_only else ''
                    print(f'{d.name}{ro}: {d.description}')
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


def mode_main(argv) -> int:
    p = Parser(prog='rwpend mode', description='Set the controller mode (controller/set_mode).')
    p.add_argument('mode', choices=MODES)
    p.add_argument('--ns', type=namespace_arg, default=DEFAULT_NS)
    a = p.parse_args(argv)
    from .rostools import ToolError
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
    from .rostools import ToolError
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
    a = p.parse_args(argv)
    from .rostools import ToolError
    try:
        with _tool(a.ns) as t:
            results = t.estop(not a.clear)
    except ToolError as exc:
        return fail(p.prog, str(exc), 1)
    bad = 0
    for name, ok, msg in results:
        print(f'{name}: {msg}')
        bad += not ok
    return 1 if bad else 0


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


COMMANDS = {
    'up': up_main, 'node': node_main, 'sim': sim_main, 'demo': demo_main, 'param': param_main, 'mode': mode_main,
    'tap': tap_main, 'estop': estop_main, 'gains': gains_main, 'record': record_main,
    'play': play_main, 'bag': bag_main, 'analyze': analyze_main, 'emulate': emulate_main,
    'bench': bench_main,
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
