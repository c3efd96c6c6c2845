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
import os
import sys
import time
from pathlib import Path

from .launch import DEFAULT_NS, Launcher
from .stack import (COMPOSITIONS, DEFAULT_RT_PRIORITY, MODES, NODE_ARGS, NODE_MODULES, Stack,
                    check_override_types, namespace, overrides_from, parse_pins, plan, rig_file, stack_file)

ROOT = Path(os.environ.get('RWPEND_ROOT', Path(__file__).resolve().parents[2]))


class Parser(argparse.ArgumentParser):
    def error(self, message):
        self.print_usage(sys.stderr)
        print(f'{self.prog}: error: {message}', file=sys.stderr)
        raise SystemExit(2)


def fail(prog: str, msg: str, status: int = 2) -> int:
    print(f'{prog}: error: {msg}', file=sys.stderr, flush=True)
    return status


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


def namespace_arg(ns: str) -> str:
    """``--ns``: :func:`rwpend_bringup.stack.namespace` for argparse."""
    try:
        return namespace(ns)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


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


def stack_from_args(a: argparse.Namespace) -> Stack:
    """The :class:`rwpend_bringup.stack.Stack` of the ``up`` arguments (:func:`add_stack_args`);
    ValueError with the reason for an option the parser could not check alone."""
    taps = []
    for t in a.tap:
        try:
            ts, dvs = t.split(':')
            taps.append((float(ts), float(dvs)))
        except ValueError:
            raise ValueError(f'--tap expects T:DV (e.g. 9:0.5), got {t!r}') from None
    only = None
    if a.only is not None:
        only = tuple(n.strip() for n in a.only.split(',') if n.strip())
    return Stack(plant=a.plant, lockstep=a.lockstep, duration=a.duration, mode=a.mode, estimator=a.estimator,
                 record=a.record, params_files=tuple(a.params), overrides=overrides_from(a.set), ns=a.ns,
                 rig=a.rig, plant_rig=a.plant_rig, theta0=a.theta0, taps=tuple(taps), h=a.h,
                 controller=not a.no_controller, rt_priority=a.rt_priority, cpu_latency=a.cpu_latency,
                 pins=parse_pins(a.pin), console=a.console, layout=a.composed, only=only)


def up_main(argv) -> int:
    p = Parser(prog='rwpend up', description='Run the stack (Ctrl-C stops it: controller first, '
               'recorder last).')
    add_stack_args(p)
    a = p.parse_args(argv)
    try:
        run = plan(stack_from_args(a))
    except ValueError as exc:
        return fail(p.prog, str(exc))
    for n in run.notes:
        print(f'rwpend: {n}', flush=True)
    if a.console is not None and a.lockstep:
        print('rwpend: lockstep with --console: the run starts when the console page is open (its '
              'address follows)', flush=True)
    return run_stack(run.stack, run.specs, run.files)


def run_stack(stack: Stack, specs, files, on_started=None) -> int:
    """Start ``specs`` (a :class:`rwpend_bringup.stack.Plan`'s) and wait until the stack stops;
    the exit status of ``up`` (:func:`judge_run`)."""
    a = stack
    launcher = Launcher(specs, namespace=a.ns, params_files=files)
    names = ', '.join(s.name for s in specs)
    from rwpend_ros.transport import discovery_range, transport_choice
    print(f'rwpend: starting {names} in {a.ns} (ROS_DOMAIN_ID={os.environ.get("ROS_DOMAIN_ID", "0")}, '
          f'discovery {discovery_range()}, transport {transport_choice()})',
          flush=True)
    from rwpend_ros.sched import request_cpu_latency
    with request_cpu_latency(a.cpu_latency) as req:   # held until the stack has stopped
        if req.us is not None:
            print(f'rwpend: CPU wake-up latency request: {req.status}', flush=True,
                  file=sys.stdout if req.active else sys.stderr)
        t0 = time.monotonic()
        # the plant exits by itself after --duration s from its sample 0 (simulated time in
        # lockstep) or, the driver, from its first command; the wall-clock bound only catches a
        # stack that never starts
        bound = None if a.duration is None else 120.0 + (20.0 if a.lockstep else 1.5) * a.duration
        status = launcher.run(bound, on_started=on_started)
        why = launcher.reason
        if why == 'duration':   # the plant ends a run of --duration itself: this is the bound
            why = (f'{bound:.0f} s without the end of the {a.duration:g} s run: the plant never started '
                   'it or never ended it (its log above says why)')
        print(f'rwpend: stopped ({why})', flush=True)
        return judge_run(a, specs, launcher.exit_codes, status, time.monotonic() - t0,
                         interrupted=launcher.reason == 'signal')


#: s to wait for the loop's bag writer to finish a bag its process did not close
WRITER_FINISH_S = 30.0


def judge_run(a: Stack, specs, exit_codes: dict, status: int, wall_s: float, interrupted: bool = False) -> int:
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
    if 'loop' in names and not Path(a.record).exists():
        # the loop's process ended before its recorder opened the bag (a refused parameter:
        # its reason is above): there is no bag to wait for
        print(f'rwpend: no bag: the loop ended before it opened {a.record}', file=sys.stderr, flush=True)
        return status or EXIT_SHORT_BAG
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
Real time as under `./rwpend up`: the node's `thread_priority` parameter (as ros2_control's)
is 50 unless given, where SCHED_FIFO is permitted (0 in lockstep: lockstep:=true or
use_sim_time:=true); -p thread_priority:=0 turns it off.
Examples:
  ./rwpend sim -p lockstep:=true -p initial.theta:=3.1416     # the simulator alone
  ./rwpend node estimator --ns /offline -p estimator:=observer3"""


def ros_params_files(ros: list[str]) -> list[str]:
    """The ``--params-file F`` of ROS arguments."""
    return [ros[i + 1] for i, x in enumerate(ros[:-1]) if x == '--params-file']


def ros_param_overrides(ros: list[str]) -> dict:
    """The ``-p NAME:=VALUE`` of ROS arguments (YAML values, as rcl reads them)."""
    import yaml
    out: dict = {}
    for i, x in enumerate(ros[:-1]):
        if x in ('-p', '--param') and ':=' in ros[i + 1]:
            key, val = ros[i + 1].split(':=', 1)
            try:
                out[key] = yaml.safe_load(val)
            except yaml.YAMLError:
                out[key] = val
    return out


def node_thread_priority(name: str, given: dict, permitted) -> tuple[int | None, str]:
    """The ``thread_priority`` ``./rwpend node NAME`` sets when the user set none, and why.

    ``given``: the parameters the user gave (-p and --params files, flattened); ``permitted``:
    a callable ``priority -> (ok, reason)`` (rwpend_ros.sched.realtime_permitted). None: leave
    the parameter as given (or at its default 0). As ``./rwpend up`` gives its processes
    DEFAULT_RT_PRIORITY in real time and none in lockstep: a node started alone, the ROS way,
    then runs as it does under ``up`` (across two test hosts, estimator and controller nodes at
    ordinary priority left 20 % of the samples late at load ~2.4, at priority 50 0.11 %)."""
    if 'thread_priority' in given:
        return None, f'thread_priority {given["thread_priority"]} (given)'
    if given.get('lockstep') is True or given.get('use_sim_time') is True:
        # a lockstep run goes as fast as its nodes answer: at real-time priority they would
        # take both CPUs from everything else (a recorder lost a quarter of the samples)
        return None, 'ordinary scheduling (lockstep, as ./rwpend up --lockstep)'
    ok, reason = permitted(DEFAULT_RT_PRIORITY)
    if not ok:
        return None, (f'ordinary scheduling: real-time priority not permitted here ({reason}); a busy '
                      'machine may then miss samples')
    return DEFAULT_RT_PRIORITY, (f'thread_priority {DEFAULT_RT_PRIORITY} (real time where permitted, as '
                                 './rwpend up; -p thread_priority:=0 to turn it off)')


def parse_node_args(ours: list[str], ros: list[str]) -> tuple[dict, list[str], str | None, list[str]]:
    """``rwpend node`` arguments before ``--ros-args`` (``ours``) and after (``ros``) ->
    (-p overrides, --params files, --ns or None, the other ROS arguments); ValueError with the
    reason."""
    import yaml
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
                raise ValueError(f'{x} expects NAME:=VALUE, got {nxt!r}')
            key, val = nxt.split(':=', 1)
            if not key:
                raise ValueError(f'{x} expects NAME:=VALUE, got {nxt!r}')
            try:
                overrides[key] = yaml.safe_load(val) if val != '' else ''
            except yaml.YAMLError:
                overrides[key] = val
            i += 2
        elif kind == 'ours' and x == '--params':
            if nxt is None or not Path(nxt).is_file():
                raise ValueError(f'--params: no such file {nxt!r}')
            files.append(str(Path(nxt).resolve()))
            i += 2
        elif kind == 'ours' and x == '--ns':
            if nxt is None:
                raise ValueError('--ns expects a namespace')
            try:
                ns = namespace_arg(nxt)
            except (argparse.ArgumentTypeError, ValueError) as exc:
                raise ValueError(str(exc)) from None
            i += 2
        elif kind == 'ours':
            raise ValueError(f'unknown argument {x!r} (ROS arguments go after --ros-args)')
        else:
            rest_ros.append(x)
            i += 1
    return overrides, files, ns, rest_ros


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
    try:
        overrides, files, ns, rest_ros = parse_node_args(ours, ros)
    except ValueError as exc:
        return fail(prog, str(exc))
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
    from rwpend_model.rig import read_params_file
    from rwpend_ros.sched import realtime_permitted
    given: dict = {}
    for f in files + ros_params_files(rest_ros):
        try:
            given.update(read_params_file(f, name))
        except (ValueError, OSError):
            pass                                # rcl says what is wrong with it
    given.update(ros_param_overrides(rest_ros))
    given.update(overrides)
    prio, why = node_thread_priority(name, given, realtime_permitted)
    if prio is not None:
        overrides = {**overrides, 'thread_priority': prio}
    print(f'{prog}: {why}', file=sys.stderr, flush=True)
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
    try:
        tap_t, tap_dv = (float(x) for x in a.tap.split(':'))
    except ValueError:
        return fail(p.prog, f'--tap expects T:DV (e.g. 11:0.6), got {a.tap!r}')
    try:
        run = plan(Stack(mode='auto', duration=a.duration, taps=((tap_t, tap_dv),), record=str(bag),
                         lockstep=not a.realtime))
    except ValueError as exc:
        return fail(p.prog, str(exc))
    for n in run.notes:
        print(f'rwpend: {n}', flush=True)
    t0 = time.monotonic()
    status = run_stack(run.stack, run.specs, run.files)
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
#: The commands implemented in other packages, by name: 'module:function' (like ros2cli's entry
#: points), the module imported when its command runs. rwpend_bringup imports none of the
#: packages above it (tests/test_layering.py); each function takes the command's arguments and
#: returns the exit status.
DELEGATED = {
    'gains': 'rwpend_control.gains_cli:main',
    'record': 'rwpend_bag.cli:record_main',
    'play': 'rwpend_bag.cli:play_main',
    'analyze': 'rwpend_bag.cli:analyze_main',
    'emulate': 'rwpend_driver.emulator:main',
    'bench': 'rwpend_bench.bench:main',
    'soak': 'rwpend_bench.soak:main',
    'lab': 'rwpend_lab.cli:main',
    'identify': 'rwpend_ident.cli:main',
    'console': 'rwpend_console.console:main',
    'bridge': 'rwpend_console.bridge:main',
    'sweep': 'rwpend_sweep.cli:main',
}


class NotInstalled(RuntimeError):
    """The module of a delegated command is not installed (its package is missing)."""


def resolve(target: str):
    """The function of a 'module:function' target, its module imported now; NotInstalled when
    the module (or its package) is missing -- not when something the module imports is."""
    import importlib
    module, _, name = target.partition(':')
    try:
        mod = importlib.import_module(module)
    except ModuleNotFoundError as exc:
        parts = module.split('.')
        if exc.name not in {'.'.join(parts[:i]) for i in range(1, len(parts) + 1)}:
            raise
        raise NotInstalled(f'{module} is not installed (make setup)') from None
    return getattr(mod, name)


def bag_main(argv) -> int:
    """``bag info BAG``: the one ``bag`` subcommand."""
    if not argv or argv[0] != 'info':
        print('usage: rwpend bag info BAG', file=sys.stderr)
        return 2
    return resolve('rwpend_bag.cli:info_main')(argv[1:])


COMMANDS = {
    'up': up_main, 'node': node_main, 'sim': sim_main, 'demo': demo_main, 'param': param_main, 'mode': mode_main,
    'tap': tap_main, 'estop': estop_main, 'graph': graph_main, 'bag': bag_main,
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
    if cmd not in COMMANDS and cmd not in DELEGATED:
        print(f'rwpend: unknown command {cmd!r}; `./rwpend --help` lists them', file=sys.stderr)
        return 2
    try:
        run = COMMANDS[cmd] if cmd in COMMANDS else resolve(DELEGATED[cmd])
        return run(argv[1:])
    except NotInstalled as exc:
        return fail(f'rwpend {cmd}', str(exc), 1)
    except SystemExit as exc:
        return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 2)
    except KeyboardInterrupt:
        return 130


if __name__ == '__main__':
    sys.exit(main())
