"""``./rwpend bench`` -- the real-time / lockstep benchmark of the whole stack (issue 8).

What it runs (every run is the full stack started by :class:`rwpend_bringup.launch.Launcher`
from :func:`rwpend_bringup.stack.plan`, i.e. exactly what ``./rwpend up`` runs, with
``--rt-priority 50 --cpu-latency 0`` unless told otherwise; PERFORMANCE.md, "What each mechanism
buys"):

1. **real time**, for each sample period h (default 1 ms and 0.5 ms) and each layout (``loop``:
   the default of ``up``, the loop in one thread of one process; separate processes;
   ``control``: estimator and controller in one loop process, ``up --composed control``): simulator on
   the wall clock, estimator, controller in ``auto`` (swing-up, catch, balance), recorder. The
   measured window opens ``SETTLE_S`` s after the start (the loop is running by then) and lasts
   ``--duration`` s (default 60). From the bag, over the samples whose instant lies in the window:

   * sensor-to-command latency -- from the instant of sample k (the encoders' header stamp: the
     simulator's ideal k*h grid, on the system clock) to the recorder receiving command seq k
     (the seq echo); p50/p99/p99.9/max. An upper bound of what the plant sees: the recorder is
     one more DDS reader, with its own scheduling delay;
   * late samples -- ``late_fraction``: command k received (by the recorder) after the instant
     of sample k+1, or never; ``plant_late_fraction``: what the plant actually held over
     [t_k, t_k+1) (``sim/true_state.u_commanded`` of sample k+1) was not command k -- exact, and
     independent of the recorder's timing (see :func:`plant_late`);
   * latency **at the plant** and its breakdown -- from the nodes' traces (rwpend_ros.trace,
     ``RWPEND_TRACE`` set for every run; ``RWPEND_TRACE=0`` in the environment turns it off):
     sample instant to the simulator's command callback receiving command k (the true
     sensor-to-actuator delay, no extra reader in the path), the fraction of commands received
     after the next sample instant, and p50/p99 of each stage (:func:`trace_metrics`);
   * sample-period jitter -- from the recorder's receive times of ``encoders`` (an upper bound
     of the simulator's publishing jitter);
   * dropped messages per topic -- seq gaps seen by the recorder (``recording_report.json``);
   * CPU per process -- ``/proc/PID/stat`` utime+stime over the window, in cores (1.0 = one core
     busy); and the CPU of every *other* process on the host in the same window
     (``other_cpu_cores``: the figures of a shared machine depend on it), plus the load average
     and the host's steal time (``host_steal_pct``, /proc/stat: on a VM, the share of CPU time the
     hypervisor gave to other guests; our test VM also has slow spells that do not show as steal
     -- the CPU per process, the same work, then rises by up to 50 %).

2. **lockstep** throughput (simulated s per wall s) of the full pipeline, with and without the
   recorder, from the simulator's own "N s simulated in M s wall" report, and the CPU seconds of
   all processes per simulated second.
3. **bag decode** throughput of rwpend_bag's reader (read + column-wise CDR decode of the
   biggest real-time bag): messages/s.
4. **scale** (issue 22): how many simulated rigs at 1 kHz the machine carries -- 1, 2, 3 ... rigs
   in real time at once (``--scale-layout``, default loop: one process per rig; no recorder;
   each rig its own namespace /scaleN and domain id, as a lab separates them), ``--scale-duration``
   s measured at each step, until the late fraction at the plants (from the traces: command k
   received after the instant of sample k+1, or never, over every rig's samples) passes 0.1 %
   (``SCALE_LATE_LIMIT``) or ``--scale-max`` rigs run. ``rigs_carried``: the most rigs with every
   step up to it within the limit. Not a pass/fail test: a figure of this machine at its load.

Results: printed, and written to ``OUTDIR/bench.json`` (plus each run's log; bags with
``--keep-bags``). PERFORMANCE.md has the figures of this machine.
"""
from __future__ import annotations

import argparse
import io
import json
import os
import platform
import re
import shutil
import signal
import sys
import threading
import time
from dataclasses import dataclass, replace
from pathlib import Path

from rwpend_ros.transport import transport_choice

from rwpend_bringup.launch import Launcher

DEFAULT_PERIODS = (0.001, 0.0005)
#: bench layouts -> ./rwpend up arguments
#: the benchmark's layouts: their names -> rwpend_bringup.stack.Stack.layout
LAYOUTS = {'loop': 'loop', 'separate': 'none', 'control': 'control'}
#: ``--pin`` of the real-time runs by default (when CPUs 0 and 1 are usable): separate processes
#: only, the simulator and the estimator on CPU 0, the controller on CPU 1, the recorder free.
#: Measured (PERFORMANCE.md, "What each mechanism buys"): lower median latency in 10 of 10
#: interleaved pairs, lower p99 in 9 of 10; no gain for the control layout; lockstep not pinned
#: (not measured)
DEFAULT_PINS = {'separate': ('sim=0', 'estimator=0', 'controller=1')}
SETTLE_S = 4.0            # wall seconds after start before the measured window opens
#: a lockstep run is stopped after this many wall seconds per simulated second (plus
#: SETTLE_S + 30): the slowest ever measured ran at ~1x; once, a run froze with Fast DDS's async
#: writer thread spinning at 100 % in two processes (rmw_fastrtps#666 describes such a loop),
#: and the bench must not wait ten minutes for it (PERFORMANCE.md, "What is measured")
LOCKSTEP_WALL_PER_SIM_S = 10.0


# ------------------------------------------------------------------ helpers
class _Tee(io.TextIOBase):
    """File-like for Launcher(out=...): keeps the lines and writes them to a log file."""

    def __init__(self, path: Path, echo=None):
        self.f = open(path, 'w', encoding='utf-8')
        self.lines: list[str] = []
        self.times: list[float] = []      # monotonic time each line was seen
        self.echo = echo
        self._lock = threading.Lock()

    def write(self, s: str) -> int:
        with self._lock:
            self.f.write(s)
            now = time.monotonic()
            for x in s.splitlines():
                if x:
                    self.lines.append(x)
                    self.times.append(now)
            if self.echo is not None:
                self.echo.write(s)
        return len(s)

    def flush(self) -> None:
        with self._lock:
            self.f.flush()

    def close(self) -> None:
        self.f.close()


def _clk_tck() -> int:
    try:
        return os.sysconf('SC_CLK_TCK')
    except (ValueError, OSError):  # pragma: no cover
        return 100


def proc_cpu_s(pid: int) -> float | None:
    """utime + stime of a process (all its threads), seconds; None if it is gone."""
    try:
        with open(f'/proc/{pid}/stat', 'rb') as f:
            data = f.read().decode()
    except OSError:
        return None
    rest = data[data.rindex(')') + 2:].split()   # fields after "pid (comm) "
    return (int(rest[11]) + int(rest[12])) / _clk_tck()   # fields 14, 15 of stat(5)


def descendants(pid: int) -> list[int]:
    """The processes started by ``pid`` and by them (/proc/PID/task/TID/children)."""
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        try:
            tasks = os.listdir(f'/proc/{p}/task')
        except OSError:
            continue
        for t in tasks:
            try:
                with open(f'/proc/{p}/task/{t}/children') as f:
                    kids = [int(k) for k in f.read().split()]
            except (OSError, ValueError):
                continue
            out += kids
            todo += kids
    return out


def process_name(pid: int) -> str:
    try:
        with open(f'/proc/{pid}/comm') as f:
            return f.read().strip()
    except OSError:
        return str(pid)


def cpu_snapshot(launcher: Launcher) -> dict[str, float | None]:
    """CPU seconds of each process of the stack, and of the processes they started (named
    ``PROCESS/NAME``, e.g. ``loop/rwpend-bag``, the loop's bag writer)."""
    out = {}
    for name, p in launcher.procs.items():
        out[name] = proc_cpu_s(p.pid)
        for d in descendants(p.pid):
            out[f'{name}/{process_name(d)}'] = proc_cpu_s(d)
    return out


def all_cpu_snapshot() -> dict[int, float]:
    """utime + stime of every process on the host (to measure the load of everyone else)."""
    out = {}
    for d in os.listdir('/proc'):
        if d.isdigit():
            v = proc_cpu_s(int(d))
            if v is not None:
                out[int(d)] = v
    return out


def cpu_times() -> list[int] | None:
    """The host's CPU time counters (``/proc/stat``, all CPUs: user nice system idle iowait irq
    softirq steal ...), in clock ticks; None where unreadable."""
    try:
        with open('/proc/stat') as f:
            return [int(x) for x in f.readline().split()[1:]]
    except (OSError, ValueError):
        return None


def steal_percent(before: list[int] | None, after: list[int] | None) -> float | None:
    """Share (%) of the CPU time of the window that the hypervisor gave to other guests
    ("steal", the 8th counter of /proc/stat): a VM whose vCPUs wait for the host runs everything
    late, whatever the stack does. None without the counters or on a bare machine that has none."""
    if not before or not after or len(before) < 8 or len(after) < 8:
        return None
    d = [b - a for a, b in zip(before, after)]
    total = sum(d[:8])     # guest time is counted in user already
    return round(100.0 * d[7] / total, 2) if total > 0 else None


def other_cpu_cores(before: dict[int, float], after: dict[int, float], ours: set[int],
                    window: float) -> float | None:
    """CPU (cores) used during the window by processes other than the benchmark's (a lower bound:
    processes that ended inside the window are not seen)."""
    if window <= 0:
        return None
    total = sum(v - before.get(pid, 0.0) for pid, v in after.items() if pid not in ours)
    return round(max(total, 0.0) / window, 3)


def percentiles(values, qs=(50, 99, 99.9)) -> dict:
    import numpy as np
    v = np.asarray(values, dtype=float)
    if v.size == 0:
        return {f'p{q:g}': None for q in qs} | {'max': None, 'n': 0}
    out = {f'p{q:g}': float(np.percentile(v, q)) for q in qs}
    out['max'] = float(v.max())
    out['n'] = int(v.size)
    return out


def machine_info() -> dict:
    model = ''
    try:
        for line in Path('/proc/cpuinfo').read_text().splitlines():
            if line.startswith('model name'):
                model = line.split(':', 1)[1].strip()
                break
    except OSError:
        pass
    try:
        affinity = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover
        affinity = None
    return {'cpus': os.cpu_count(), 'cpus_usable': affinity, 'cpu_model': model,
            'kernel': platform.release(), 'python': platform.python_version(),
            'rmw': os.environ.get('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp'),
            'transport': transport_choice(),
            'loadavg_start': _loadavg()}


def _loadavg() -> list[float] | None:
    try:
        return [float(x) for x in Path('/proc/loadavg').read_text().split()[:3]]
    except OSError:
        return None


# ------------------------------------------------------------------ running the stack
def realtime_pins(pin: list[str] | None, layouts) -> dict[str, tuple[str, ...]]:
    """The ``--pin`` items of each layout's real-time runs: the defaults (:data:`DEFAULT_PINS`,
    when CPUs 0 and 1 are usable) when ``pin`` is None, nothing for ``['none']``; else those items whose
    process the layout runs. ValueError for a process no layout of the run has, or a bad item."""
    from rwpend_bringup import stack
    if pin is None:
        return dict(DEFAULT_PINS) if {0, 1} <= stack.usable_cpus() else {}
    if [v.strip().lower() for v in pin] == ['none']:
        return {}
    # each layout's processes as ./rwpend up builds them, and the recorder of every real-time run
    processes = {x: {s.name for s in _plan(stack.Stack(layout=LAYOUTS[x], rt_priority=0)).specs} | {'recorder'}
                 for x in layouts}
    parsed = stack.parse_pins(pin)      # the reason for a bad item
    stack.check_pins(parsed, sorted(set().union(*processes.values())))
    out = {}
    for x in layouts:
        mine = tuple(f'{k}={",".join(map(str, v))}' for k, v in parsed.items() if k in processes[x])
        if mine:
            out[x] = mine
    return out


def _plan(stack):
    """The processes of ``stack`` (:func:`rwpend_bringup.stack.plan`, what ``./rwpend up`` runs)."""
    from rwpend_bringup.stack import plan
    return plan(stack)


def _base(base):
    """The stack every run starts from (the benchmark's ``--set``, priority...): ``base`` or up's."""
    from rwpend_bringup.stack import Stack
    return Stack() if base is None else base


def _launcher(run, out: Path, tag: str, env: dict, echo, spec_hook):
    """(launcher, log, environment, trace directory) of a run's plan ``run`` (its specs first
    given to ``spec_hook``), its log ``out/TAG.log`` and its trace ``out/TAG.trace``."""
    if spec_hook is not None:
        spec_hook(run.specs)
    log = _Tee(out / f'{tag}.log', echo)
    env, trace_dir = _with_trace(env, out / f'{tag}.trace')
    return Launcher(run.specs, namespace=run.stack.ns, params_files=run.files, env=env, out=log), log, env, trace_dir


def _cpu_latency_request(a):
    """The ``--cpu-latency`` PM QoS request of a run (what ``rwpend up`` holds for its stack),
    held by the benchmark while the run's launcher runs; a no-op without the option."""
    from rwpend_ros.sched import request_cpu_latency
    req = request_cpu_latency(a.cpu_latency)
    if req.us is not None and not req.active:
        print(f'rwpend bench: CPU wake-up latency request {req.status}', file=sys.stderr, flush=True)
    return req


def run_realtime(out: Path, h: float, duration: float, layout: str, env: dict,
                 ns: str, echo=None, base=None, spec_hook=None, tag: str | None = None) -> dict:
    """A real-time run of ``base`` (a :class:`rwpend_bringup.stack.Stack`; up's by default) in
    ``layout``, mode auto, recorded; judged from its bag."""
    tag = tag or f'rt_{layout}_h{h * 1e6:g}us'
    bag = out / tag
    if bag.exists():
        shutil.rmtree(bag)
    run = _plan(replace(_base(base), mode='auto', h=h, record=str(bag), ns=ns, layout=LAYOUTS[layout]))
    a = run.stack
    launcher, log, env, trace_dir = _launcher(run, out, tag, env, echo, spec_hook)
    load0 = _loadavg()
    cpu_req = _cpu_latency_request(a)
    try:
        launcher.start()
        # the loop starts once every node is up and connected (the simulator holds sample 0 until
        # the estimator and the recorder listen): the measured window opens SETTLE_S s later
        reason = launcher.wait(SETTLE_S)
        a0 = all_cpu_snapshot()
        s0 = cpu_times()
        t0, w0, c0 = time.monotonic(), time.time_ns(), cpu_snapshot(launcher)
        if reason == 'duration':
            reason = launcher.wait(duration)
        t1, w1, c1 = time.monotonic(), time.time_ns(), cpu_snapshot(launcher)
        s1 = cpu_times()
        a1 = all_cpu_snapshot()
        ours = {os.getpid(), *(p.pid for p in launcher.procs.values()),
                *(d for p in launcher.procs.values() for d in descendants(p.pid))}
    finally:
        codes = launcher.stop()
        cpu_req.close()
        log.close()
    window = t1 - t0
    cpu = {n: (None if c0[n] is None or c1.get(n) is None else round((c1[n] - c0[n]) / window, 4))
           for n in c0}
    res = {'layout': layout, 'h_s': h, 'rate_hz': round(1.0 / h), 'wall_s': round(window + SETTLE_S, 3),
           'stop_reason': reason, 'exit_codes': codes, 'bag': str(bag), 'log': str(out / f'{tag}.log'),
           'loadavg_before': load0, 'loadavg_after': _loadavg(),
           'other_cpu_cores': other_cpu_cores(a0, a1, ours, window),
           'other_cpu_source': 'CPU of every other process on the host during the window (lower bound)',
           'host_steal_pct': steal_percent(s0, s1), 'cpu_latency_request': cpu_req.status}
    res['cpu_cores'] = cpu
    res['cpu_cores_total'] = round(sum(v for v in cpu.values() if v is not None), 4)
    res['cpu_window_s'] = round(window, 3)
    res.update(bag_metrics(bag, ns, h, (w0, w1)))
    res['judged'] = judged(bag)
    if trace_dir is not None:
        res.update(trace_metrics(trace_dir, res.get('window_seq')))
    return res


def judged(bag: Path) -> dict:
    """The verdict of the whole run by the independent reader (:mod:`rwpend_bag.judge`, rosbags):
    per sample, late = the command the plant held did not answer the previous sample
    (``command_seq < seq - 1``, from ``sim/true_state`` or, on the rig, the device's ``applied``),
    at zero = the command timeout held the motor at 0; falls after the first catch."""
    from rwpend_bag.judge import judge, read_run
    try:
        v = judge(read_run(bag))
    except Exception as exc:  # noqa: BLE001 - a bag that cannot be read: said in the result
        return {'error': f'{type(exc).__name__}: {exc}'}
    n = max(v.timed_samples, 1)
    return {'samples': v.samples, 'timed_samples': v.timed_samples, 'late_samples': v.late_samples,
            'late_fraction': v.late_samples / n, 'zero_samples': v.zero_samples,
            'zero_fraction': v.zero_samples / n, 'falls': v.falls, 'alive_at_end': v.alive_at_end,
            'problems': list(v.problems), 'source': v.source}


def run_rig(out: Path, h: float, duration: float, env: dict, ns: str, echo=None, base=None,
            rt_priority: int = 0) -> dict:
    """A real-time run of the rig path: the device's firmware core on a pseudo-terminal (``./rwpend
    emulate``, a process of its own, 10 real-time priorities above the loop where the loop has
    one) and ``up --plant serial:LINK`` in its default layout (the driver as the loop's plant);
    the emulator's own counters (its late instants, the commands' latency) go into the result."""
    import subprocess
    tag = f'rig_h{h * 1e6:g}us'
    link = out / f'{tag}.link'
    emu_log = out / f'{tag}.emulator.log'
    cmd = [sys.executable, '-m', 'rwpend_driver.emulator', '--link', str(link), '--h', repr(h),
           '--rt-priority', str(min(99, rt_priority + 10) if rt_priority else 0)]
    with open(emu_log, 'w', encoding='utf-8') as f:
        emu = subprocess.Popen(cmd, stdout=f, stderr=subprocess.STDOUT, env=env)
    try:
        deadline = time.monotonic() + 30.0
        while not link.exists() and emu.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        if not link.exists():
            return {'layout': 'rig', 'h_s': h, 'rate_hz': round(1.0 / h),
                    'error': f'the emulator did not start (its log: {emu_log})'}
        res = run_realtime(out, h, duration, 'loop', env, ns, echo,
                           base=replace(_base(base), plant=f'serial:{link}'), tag=tag)
    finally:
        emu.send_signal(signal.SIGINT)
        try:
            emu.wait(timeout=10)
        except subprocess.TimeoutExpired:
            emu.kill()
            emu.wait()
    res['layout'] = 'rig'
    status = [ln for ln in emu_log.read_text(encoding='utf-8').splitlines() if ' status ' in ln]
    res['emulator_status'] = status[-1].split(' status ', 1)[1] if status else None
    return res


def _with_trace(env: dict, directory: Path) -> tuple[dict, Path | None]:
    """env with RWPEND_TRACE (rwpend_ros.trace) set to a fresh ``directory``, unless the caller's
    env says RWPEND_TRACE=0."""
    if env.get('RWPEND_TRACE', '').strip() == '0':
        return env, None
    if directory.exists():
        shutil.rmtree(directory)
    directory.mkdir(parents=True)
    return {**env, 'RWPEND_TRACE': str(directory)}, directory


def trace_metrics(directory: Path, window_seq=None) -> dict:
    """Latency as the plant sees it, and where it goes, from the nodes' traces
    (rwpend_ros.trace: CLOCK_MONOTONIC marks taken inside each node's callbacks).

    ``plant_latency_us``: sample instant k (real time: t0 + k h; lockstep: when the simulator
    starts sample k) to the simulator's callback receiving command k -- exact, no extra DDS
    reader in the path. ``plant_rx_late_fraction``: command k received after the instant of
    sample k+1, or never. ``stages_us``: p50/p99 of each stage of the path (sim.tick -> sim.pub
    -> est.rx -> est.pub -> ctl.rx -> ctl.pub -> sim.rx). ``step_us`` (lockstep): sample k to
    sample k+1."""
    import numpy as np

    from rwpend_ros.trace import load, stages
    marks = load(directory)
    tick, rx = marks.get('sim.tick', {}), marks.get('sim.rx', {})
    ks = sorted(k for k in tick if k + 1 in tick)
    if window_seq:
        ks = [k for k in ks if window_seq[0] <= k <= window_seq[1]]
    if not ks:
        return {'trace_error': f'no traced sample in {directory}'}
    lat = np.array([rx[k] - tick[k] for k in ks if k in rx]) / 1e3
    late = sum(1 for k in ks if k not in rx or rx[k] > tick[k + 1])
    step = np.array([tick[k + 1] - tick[k] for k in ks]) / 1e3
    st = stages(marks, seqs=ks)
    return {'plant_latency_us': percentiles(lat),
            'plant_rx_late_fraction': late / len(ks), 'plant_rx_late_samples': late,
            'plant_traced_samples': len(ks),
            'step_us': percentiles(step, (50, 99)),
            'stages_us': {name: percentiles(v, (50, 99)) for name, v in st.items()},
            'trace_source': ('CLOCK_MONOTONIC marks inside the nodes (rwpend_ros.trace); latency = '
                             'sample instant to the simulator receiving the command')}


def bag_metrics(bag: Path, ns: str, h: float, window_ns: tuple[int, int] | None = None) -> dict:
    """Jitter, latency, late samples and drops of a real-time run, from its bag.

    The samples analysed are those whose sample instant (the encoders' header stamp: the ideal
    grid t0 + k*h of the simulator, on the system clock like the recorder's receive times) lies
    in ``window_ns`` (the CPU window), up to the last sample that has a successor.
    """
    import numpy as np

    from rwpend_bag.analysis import _decode
    from rwpend_bag.reader import read_bag
    b = read_bag(bag)
    nsp = ns.rstrip('/')
    t_enc, t_cmd = f'{nsp}/encoders', f'{nsp}/command'
    m: dict = _dropped(bag, (t_enc, f'{nsp}/sim/true_state', f'{nsp}/state', t_cmd))
    if t_enc not in b.topics or t_cmd not in b.topics or not b.topics[t_cmd].count:
        m['error'] = 'no encoders/command in the bag'
        m['samples'] = 0
        m['jitter_us'] = m['period_us'] = m['latency_us'] = None
        m['late_fraction'] = None
        return m
    enc = _decode(b, t_enc, ['header.stamp.sec', 'header.stamp.nanosec', 'seq'])
    cmd = _decode(b, t_cmd, ['seq', 'u'])
    es, el, est = enc['seq'].astype(np.int64), enc['_log_ns'].astype(np.int64), enc['_stamp_ns']
    cs, cl = cmd['seq'].astype(np.int64), cmd['_log_ns'].astype(np.int64)
    n = int(max(es.max(), cs.max())) + 2
    # per seq: sample instant, receive times at the recorder (first arrival); -1 = none
    ts = np.full(n, -1, np.int64)
    te = np.full(n, -1, np.int64)
    tc = np.full(n, -1, np.int64)
    ts[es[::-1]] = est[::-1]
    te[es[::-1]] = el[::-1]
    tc[cs[::-1]] = cl[::-1]
    have = (ts >= 0) & (np.roll(ts, -1) >= 0)          # sample k and k+1 were recorded
    have[-1] = False
    if window_ns is not None:
        have &= (ts >= window_ns[0]) & (ts <= window_ns[1])
    # the controller starts answering once it has discovered the loop: start at its first command
    have &= np.arange(n) >= cs.min()
    ks = np.nonzero(have)[0]
    m['samples'] = int(ks.size)
    if not ks.size:
        m['error'] = 'no sample in the measured window'
        m['jitter_us'] = m['period_us'] = m['latency_us'] = None
        m['late_fraction'] = None
        return m
    m['window_seq'] = [int(ks[0]), int(ks[-1])]
    answered = tc[ks] >= 0
    lat = (tc[ks] - ts[ks])[answered] / 1e3
    # late: command k not received (by the recorder) before the instant of sample k+1
    late = ~answered | (tc[ks] > ts[ks + 1])
    m['latency_us'] = percentiles(lat)
    m['latency_source'] = ('sample instant of encoders seq k (header stamp, the ideal k*h grid on the '
                           'system clock) to the recorder receiving command seq k (seq echo): an upper '
                           'bound of what the plant sees (the recorder is one more DDS reader)')
    m['late_samples'] = int(late.sum())
    m['unanswered_samples'] = int((~answered).sum())
    m['late_fraction'] = float(late.mean())
    m['late_definition'] = 'command k received after the instant of sample k+1, or never'
    m.update(plant_late(b, nsp, h, cs, cmd, ks))
    m.update(_receive_times(h, ks, ts, te, tc, answered))
    return m


def _dropped(bag: Path, topics) -> dict:
    """The messages of ``topics`` the recorder saw missing (its recording report)."""
    report = {}
    rf = Path(bag) / 'recording_report.json'
    if rf.is_file():
        report = json.loads(rf.read_text()).get('topics', {})
    return {'dropped': {name: None if report.get(name) is None else report[name].get('missing') for name in topics},
            'dropped_source': 'seq gaps seen by the recorder over the whole run (recording_report.json)'}


def _receive_times(h: float, ks, ts, te, tc, answered) -> dict:
    """Loop time, publish delay, period and jitter from the recorder's receive times of the
    samples ``ks`` (per seq: ``ts`` sample instant, ``te`` encoders and ``tc`` command received)."""
    import numpy as np
    m: dict = {}
    both = answered & (te[ks] >= 0)
    m['loop_us'] = percentiles((tc[ks] - te[ks])[both] / 1e3)
    m['loop_source'] = 'recorder receive time of command seq k minus that of encoders seq k'
    pub = te[ks][te[ks] >= 0] - ts[ks][te[ks] >= 0]
    m['encoders_delay_us'] = percentiles(pub / 1e3)
    m['encoders_delay_source'] = ('sample instant to the recorder receiving encoders seq k (the '
                                  "simulator's wake-up and publish delay plus one DDS hop)")
    tk = te[ks]
    tk = tk[tk >= 0]
    period = np.diff(tk) / 1e3
    m['period_us'] = percentiles(period, (50, 99))
    m['period_us']['min'] = float(period.min()) if period.size else None
    m['jitter_us'] = percentiles(np.abs(period - h * 1e6), (50, 99, 99.9))
    m['jitter_source'] = ('recorder receive times of encoders (header stamps are the ideal k*h '
                          'grid by construction); |period - h|')
    return m


def plant_late(b, nsp: str, h: float, cs, cmd, ks) -> dict:
    """Late commands as the plant saw them, independent of the recorder's timing.

    ``sim/true_state`` of sample k+1 carries ``u_commanded``, the command the simulator held over
    [t_k, t_{k+1}): the PWM-quantized u of command k if it had arrived when the simulator
    integrated that interval, else an older one (or 0 after the command timeout). Over the
    samples whose command differs (after quantization) from the previous one -- elsewhere the
    two cannot be told apart -- late = the plant held something else than command k.
    """
    import numpy as np

    from rwpend_bag.analysis import _decode
    from rwpend_model.plant import Plant
    from rwpend_model.rig import load_rig
    t_true = f'{nsp}/sim/true_state'
    if t_true not in b.topics or not b.topics[t_true].count:
        return {'plant_late_fraction': None}
    tr = _decode(b, t_true, ['seq', 'u_commanded'])
    n = int(max(tr['seq'].max(), cs.max())) + 2
    held = np.full(n, np.nan)
    held[tr['seq'].astype(np.int64)] = tr['u_commanded']
    q = np.vectorize(Plant(load_rig(overrides={'rig.sample_period': h})).quantize_command, otypes=[float])
    uq = np.full(n, np.nan)
    uq[cs] = q(cmd['u'])
    k = ks[(ks >= 1) & (ks + 1 < n)]
    k = k[~np.isnan(uq[k]) & ~np.isnan(uq[k - 1]) & ~np.isnan(held[k + 1])]
    told = k[uq[k] != uq[k - 1]]
    late = held[told + 1] != uq[told]
    return {'plant_late_fraction': float(late.mean()) if told.size else None,
            'plant_late_samples': int(late.sum()), 'plant_judged_samples': int(told.size),
            'plant_late_source': ('sim/true_state u_commanded of sample k+1 vs the quantized u of '
                                  'command k, over the samples where command k differs from command '
                                  'k-1')}


def run_lockstep(out: Path, h: float, sim_s: float, layout: str, record: bool, env: dict,
                 ns: str, echo=None, base=None, spec_hook=None, tag: str | None = None) -> dict:
    """A lockstep run of ``base`` (a :class:`rwpend_bringup.stack.Stack`; up's by default) in
    ``layout``, mode auto, ``sim_s`` simulated seconds, with or without the recorder."""
    tag = tag or f'ls_{layout}_h{h * 1e6:g}us_{"rec" if record else "norec"}'
    bag = out / tag
    if record and bag.exists():
        shutil.rmtree(bag)
    run = _plan(replace(_base(base), lockstep=True, mode='auto', duration=sim_s, h=h, ns=ns,
                        record=str(bag) if record else None, layout=LAYOUTS[layout]))
    a = run.stack
    launcher, log, env, trace_dir = _launcher(run, out, tag, env, echo, spec_hook)
    t0 = time.monotonic()
    load0 = _loadavg()
    polls: list[tuple[float, dict]] = []    # (time, CPU s per node), every 50 ms
    cpu_req = _cpu_latency_request(a)
    s0 = cpu_times()
    try:
        launcher.start()
        reason = 'duration'
        limit = SETTLE_S + 30.0 + LOCKSTEP_WALL_PER_SIM_S * sim_s
        while reason == 'duration' and time.monotonic() - t0 < limit:
            snap = cpu_snapshot(launcher)
            if polls:   # a process that has ended keeps its last figure
                snap = {n: (polls[-1][1].get(n) if v is None else v) for n, v in snap.items()}
            polls.append((time.monotonic(), snap))
            reason = launcher.wait(0.05)
        if reason == 'duration':
            reason = f'wall limit ({limit:g} s)'
    finally:
        s1 = cpu_times()
        codes = launcher.stop()
        cpu_req.close()
        log.close()
    total = time.monotonic() - t0
    simulated = wall = t_end = None
    for line, t in zip(log.lines, log.times):
        mt = re.search(r'duration reached: ([0-9.]+) s simulated in ([0-9.]+) s wall', line)
        if mt:
            simulated, wall, t_end = float(mt.group(1)), float(mt.group(2)), t
    res = {'layout': layout, 'h_s': h, 'recorder': record, 'simulated_s': simulated,
           'wall_s': wall, 'sim_per_wall': None if not wall else round(simulated / wall, 3),
           'total_wall_s': round(total, 2), 'stop_reason': reason, 'exit_codes': codes,
           'log': str(out / f'{tag}.log'), 'bag': str(bag) if record else None,
           'loadavg_before': load0, 'loadavg_after': _loadavg(),
           'host_steal_pct': steal_percent(s0, s1), 'cpu_latency_request': cpu_req.status}
    # CPU of each process over the run (sample 0 to the end), from the 50 ms polls
    if wall and t_end is not None and polls:
        def at(t):
            return min(polls, key=lambda p: abs(p[0] - t))
        (ta, ca), (tb, cb) = at(t_end - wall), at(t_end)
        cpu = {n: (None if ca.get(n) is None or cb.get(n) is None else round(cb[n] - ca[n], 3))
               for n in cb}
        res['cpu_s'] = cpu
        res['cpu_window_s'] = round(tb - ta, 3)
        known = [v for v in cpu.values() if v is not None]
        res['cpu_s_per_simulated_s'] = round(sum(known) / simulated, 3) if known and simulated else None
    if trace_dir is not None:
        tm = trace_metrics(trace_dir)
        res['step_us'] = tm.get('step_us')
        res['stages_us'] = tm.get('stages_us')
    if record:
        res['dropped'] = lockstep_dropped(bag, ns)
    return res


def lockstep_dropped(bag: Path, ns: str) -> dict:
    """Seq gaps the recorder saw on the loop's topics (recording_report.json; None: no report
    or topic): a lockstep run keeps pace with its recorder, so any gap is a fault."""
    rf = Path(bag) / 'recording_report.json'
    report = json.loads(rf.read_text()).get('topics', {}) if rf.is_file() else {}
    nsp = ns.rstrip('/')
    return {name: (report[name].get('missing') if name in report else None)
            for name in (f'{nsp}/encoders', f'{nsp}/sim/true_state', f'{nsp}/state', f'{nsp}/command')}


def run_decode(bag: Path) -> dict:
    from rwpend_bag.analysis import bench_decode
    r = bench_decode(str(bag), repeat=3)
    r.pop('topics', None)
    r['bag'] = str(bag)
    for k in ('decode_s', 'read_s', 'msgs_per_s', 'read_msgs_per_s'):
        if r.get(k) is not None:
            r[k] = round(r[k], 4 if k.endswith('_s') else 0)
    n, read_s, dec_s = r['messages'], r.get('read_s'), r.get('decode_s')
    r['read_and_decode_msgs_per_s'] = (round(n / (read_s + dec_s)) if read_s and dec_s else None)
    return r


# ------------------------------------------------------------------ scale: rigs per machine
#: the late fraction (commands received by the plant after the next sample instant, or never)
#: above which a machine no longer carries its rigs
SCALE_LATE_LIMIT = 0.001


def scale_carried(steps: list[dict], limit: float = SCALE_LATE_LIMIT) -> int:
    """The most rigs the machine carried: the largest n such that every step with up to n rigs
    had a late fraction of at most ``limit`` (the steps in any order; a step without a figure
    counts as failed). 0 when even one rig was late."""
    carried = 0
    for s in sorted(steps, key=lambda s: s['rigs']):
        f = s.get('late_fraction')
        if f is None or f > limit:
            break
        carried = s['rigs']
    return carried


def scale_step_figures(rigs: list[dict]) -> dict:
    """The late fraction of one step of the scale run over all its rigs (late samples / traced
    samples, each rig's from :func:`trace_metrics`), the worst rig's and the median latency of
    the worst rig; None when a rig has no traced sample."""
    if not rigs or any(not r.get('plant_traced_samples') for r in rigs):
        return {'late_fraction': None, 'worst_rig_late_fraction': None}
    late = sum(r['plant_rx_late_samples'] for r in rigs)
    n = sum(r['plant_traced_samples'] for r in rigs)
    worst = max(rigs, key=lambda r: r['plant_rx_late_fraction'])
    return {'late_fraction': late / n, 'late_samples': late, 'samples': n,
            'worst_rig_late_fraction': worst['plant_rx_late_fraction'],
            'worst_rig_latency_us': worst.get('plant_latency_us')}


def window_seqs(directory: Path, t0_ns: int, t1_ns: int) -> tuple[int, int] | None:
    """The first and last seq of a run's trace whose sample instant (``sim.tick``, monotonic)
    lies in [t0_ns, t1_ns)."""
    from rwpend_ros.trace import load
    ks = [k for k, t in load(directory).get('sim.tick', {}).items() if t0_ns <= t < t1_ns]
    return (min(ks), max(ks)) if ks else None


def run_scale(out: Path, h: float, duration: float, max_rigs: int, env: dict, layout: str,
              echo=None, base=None, say=None, limit: float = SCALE_LATE_LIMIT) -> dict:
    """1, 2, 3 ... simulated rigs in real time at once on this machine, each the stack of
    ``./rwpend up --mode auto`` (``layout``, no recorder) in a namespace and domain id of its own
    (/scaleN, the environment's domain id + N - 1: one rig per domain, as a lab separates them),
    until the late fraction at the plants (from the nodes' traces: command k received after the
    instant of sample k+1, or never) passes ``limit`` or ``max_rigs`` is reached. Each step's
    window opens when every rig has been running for SETTLE_S s and lasts ``duration`` s."""
    say = say or (lambda s: None)
    domain0 = int(env.get('ROS_DOMAIN_ID', '60'))
    steps = []
    for n in range(1, max_rigs + 1):
        say(f'rwpend bench: scale, {n} rig(s) at {1 / h:g} Hz, {duration:g} s ...')
        tag = f'scale_{n}'
        log = _Tee(out / f'{tag}.log', echo)
        launchers, traces = [], []
        load0 = _loadavg()
        cpu_req = None
        try:
            for i in range(1, n + 1):
                ns = f'/scale{i}'
                run = _plan(replace(_base(base), mode='auto', h=h, ns=ns, layout=LAYOUTS[layout], pins={}))
                a, specs, files = run.stack, run.specs, run.files
                if cpu_req is None:
                    cpu_req = _cpu_latency_request(a)
                renv, tdir = _with_trace({**env, 'ROS_DOMAIN_ID': str(domain0 + i - 1)},
                                         out / f'{tag}_{i}.trace')
                la = Launcher(specs, namespace=a.ns, params_files=files, env=renv, out=log)
                launchers.append(la)
                traces.append(tdir)
                la.start()
            # the processes of n rigs start on two CPUs: discovery and imports take longer
            settle = SETTLE_S + 1.0 * n
            reasons = [la.wait(settle / n) for la in launchers]
            a0, s0 = all_cpu_snapshot(), cpu_times()
            t0, m0 = time.monotonic(), time.monotonic_ns()
            end = t0 + duration
            for la in launchers:
                r = la.wait(max(0.0, end - time.monotonic()))
                reasons.append(r)
            t1, m1 = time.monotonic(), time.monotonic_ns()
            a1, s1 = all_cpu_snapshot(), cpu_times()
            ours = {os.getpid(), *(p.pid for la in launchers for p in la.procs.values())}
            bad = [r for r in reasons if r not in ('duration',)]
        finally:
            codes = [la.stop() for la in launchers]
            if cpu_req is not None:
                cpu_req.close()
            log.close()
        rigs = []
        for i, tdir in enumerate(traces, 1):
            if tdir is None:
                rigs.append({'rig': i, 'trace_error': 'RWPEND_TRACE=0: no late fraction'})
                continue
            w = window_seqs(tdir, m0, m1)
            m = trace_metrics(tdir, w) if w else {'trace_error': f'no sample in the window ({tdir})'}
            rigs.append({'rig': i, 'window_seq': w, **{k: m.get(k) for k in (
                'plant_rx_late_fraction', 'plant_rx_late_samples', 'plant_traced_samples',
                'plant_latency_us', 'trace_error') if k in m}})
            shutil.rmtree(tdir, ignore_errors=True)
        step = {'rigs': n, 'h_s': h, 'layout': layout, 'window_s': round(t1 - t0, 3),
                'stop_reasons': bad, 'exit_codes': codes, 'loadavg_before': load0,
                'loadavg_after': _loadavg(), 'other_cpu_cores': other_cpu_cores(a0, a1, ours, t1 - t0),
                'host_steal_pct': steal_percent(s0, s1), 'log': str(out / f'{tag}.log'),
                **scale_step_figures(rigs), 'per_rig': rigs}
        steps.append(step)
        f = step['late_fraction']
        say(f'rwpend bench: scale, {n} rig(s): late {"n/a" if f is None else f"{100 * f:.3f} %"}')
        if f is None or f > limit:
            break
    return {'h_s': h, 'layout': layout, 'late_limit': limit, 'max_rigs': max_rigs,
            'rigs_carried': scale_carried(steps, limit),
            'reached_max': bool(steps) and len(steps) == max_rigs and scale_carried(steps, limit) == max_rigs,
            'steps': steps}


# ------------------------------------------------------------------ report
def _fmt(v, nd=0):
    return 'n/a' if v is None else f'{v:.{nd}f}'


def summary_text(res: dict) -> str:
    """The benchmark's results (bench.json) as the text ``./rwpend bench`` prints."""
    m = res['machine']
    st = res['settings']
    lines = ['rwpend bench -- ' + time.strftime('%Y-%m-%d %H:%M', time.localtime(res['started'])),
             f"machine: {m['cpus']} CPU ({m['cpu_model']}), Python {m['python']}, {m['rmw']}, "
             f"transport {m.get('transport', 'udp')}; "
             f"load average {m.get('loadavg_start')} -> {m.get('loadavg_end')}",
             f"settings: rt priority {st.get('rt_priority')}, CPU wake-up latency request "
             f"{'none' if st.get('cpu_latency_us') is None else str(st['cpu_latency_us']) + ' us'}, "
             f"{st['duration_s']:g} s real time, "
             f"{st['lockstep_duration_s']:g} s lockstep"
             + ''.join(f"; {x} pinned {' '.join(v)}" for x, v in (st.get('pin_realtime') or {}).items())]
    if res['realtime']:
        lines += _realtime_text(res['realtime'])
    if res['lockstep']:
        lines += _lockstep_text(res['lockstep'])
    sc = res.get('scale')
    if sc:
        lines.append(f"scale (simulated rigs at {1 / sc['h_s']:g} Hz on this machine, {sc['layout']} layout, "
                     f"no recorder; late = command k received by the plant after sample k+1, limit "
                     f"{100 * sc['late_limit']:g} %): {sc['rigs_carried']} rig(s) carried"
                     + (f" (the most tried: {sc['max_rigs']})" if sc.get('reached_max') else ''))
        for s in sc['steps']:
            f, w = s.get('late_fraction'), s.get('worst_rig_late_fraction')
            lat = s.get('worst_rig_latency_us') or {}
            lines.append(f"  {s['rigs']:>2} rig(s): late {_fmt(None if f is None else 100 * f, 3)} % "
                         f"(worst rig {_fmt(None if w is None else 100 * w, 3)} %, its latency p50 "
                         f"{_fmt(lat.get('p50'))} p99 {_fmt(lat.get('p99'))} us), {s.get('samples', 0)} samples; "
                         f"load {s.get('loadavg_before')}, other processes {_fmt(s.get('other_cpu_cores'), 2)} "
                         f"cores, steal {_fmt(s.get('host_steal_pct'), 1)} %"
                         + (f"; stopped: {s['stop_reasons']}" if s.get('stop_reasons') else ''))
    if res.get('sweep'):
        from rwpend_sweep.bench import bench_text
        lines.append(bench_text(res['sweep']))
    d = res.get('decode')
    if d:
        lines.append(f"bag decode: {d['messages']} messages, read {_fmt(d.get('read_s'), 3)} s, decode "
                     f"{_fmt(d.get('decode_s'), 3)} s = {_fmt(d.get('msgs_per_s'))} msg/s decode, "
                     f"{_fmt(d.get('read_and_decode_msgs_per_s'))} msg/s read+decode")
    return '\n'.join(lines)




def _realtime_text(runs: list[dict]) -> list[str]:
    """The real-time runs' table, each run's judgement and CPU per process below its row."""
    lines = []
    lines.append('real time (recorder running). latency = sample instant -> command at the recorder '
                 '(us); late = command k after sample k+1')
    lines.append(f"  {'layout':<9} {'rate':>6} {'samples':>8} {'lat p50':>8} {'p99':>7} {'p99.9':>7} "
                 f"{'max':>7} {'late%':>7} {'plant%':>7} {'jit p99':>8} {'dropped':>8} {'CPU':>5} {'other':>6} "
                 f"{'steal%':>6}")
    for r in runs:
        lat = r.get('latency_us') or {}
        jit = r.get('jitter_us') or {}
        drops = [v for v in (r.get('dropped') or {}).values() if v is not None]
        late, plate = r.get('late_fraction'), r.get('plant_late_fraction')
        lines.append(
            f"  {r['layout']:<9} {r['rate_hz']:>4}Hz {r.get('samples', 0):>8} {_fmt(lat.get('p50')):>8} "
            f"{_fmt(lat.get('p99')):>7} {_fmt(lat.get('p99.9')):>7} {_fmt(lat.get('max')):>7} "
            f"{_fmt(None if late is None else 100 * late, 3):>7} "
            f"{_fmt(None if plate is None else 100 * plate, 3):>7} {_fmt(jit.get('p99')):>8} "
            f"{sum(drops) if drops else 'n/a':>8} {_fmt(r.get('cpu_cores_total'), 2):>5} "
            f"{_fmt(r.get('other_cpu_cores'), 2):>6} {_fmt(r.get('host_steal_pct'), 1):>6}")
        pl = r.get('plant_latency_us')
        if pl:
            pr = r.get('plant_rx_late_fraction')
            lines.append(f"            at the plant (trace): latency p50 {_fmt(pl.get('p50'))}, p99 "
                         f"{_fmt(pl.get('p99'))}, p99.9 {_fmt(pl.get('p99.9'))}, max {_fmt(pl.get('max'))} us; "
                         f"late {_fmt(None if pr is None else 100 * pr, 3)} %")
            lines.append('            stages p50/p99 (us): ' + _stages_text(r.get('stages_us')))
        j = r.get('judged') or {}
        if 'late_fraction' in j:
            lines.append(f"            judged from the bag, per sample ({j['source']}): late "
                         f"{100 * j['late_fraction']:.3f} %, at zero {100 * j['zero_fraction']:.3f} % of "
                         f"{j['timed_samples']}; falls {j['falls']}, alive at the end {j['alive_at_end']}")
        elif j:
            lines.append(f"            judged from the bag: {j.get('error')}")
        if r.get('error'):
            lines.append(f"            error: {r['error']}")
        lines.append('            CPU per process (cores): ' + ', '.join(
            f'{k} {_fmt(v, 2)}' for k, v in r.get('cpu_cores', {}).items())
            + f"; load {r.get('loadavg_before')}")
    return lines


def _lockstep_text(runs: list[dict]) -> list[str]:
    """The lockstep runs: speed, CPU, and where the time goes."""
    lines = []
    lines.append('lockstep (simulated s per wall s; CPU s per simulated s, all processes):')
    for r in runs:
        drops = [v for v in (r.get('dropped') or {}).values() if v is not None]
        rec = ('no ' if not r['recorder'] else
               f"yes (dropped {sum(drops) if drops else 'n/a'})")
        lines.append(f"  {r['layout']:<9} h={r['h_s'] * 1e3:g} ms  recorder {rec:<3}  "
                     f"{_fmt(r['simulated_s'], 1)} s in "
                     f"{_fmt(r['wall_s'], 2)} s = {_fmt(r['sim_per_wall'], 2)}x real time, CPU "
                     f"{_fmt(r.get('cpu_s_per_simulated_s'), 2)} s/s; load {r.get('loadavg_before')}; "
                     f"host steal {_fmt(r.get('host_steal_pct'), 1)} %")
        if r.get('stages_us'):
            lines.append(f"            step p50 {_fmt((r.get('step_us') or {}).get('p50'))} us; stages p50/p99 (us): "
                         + _stages_text(r['stages_us']))
    return lines


def _stages_text(st) -> str:
    if not st:
        return 'n/a'
    return ', '.join(f"{k.replace(' -> ', '>')} {_fmt(v.get('p50'))}/{_fmt(v.get('p99'))}"
                     for k, v in st.items() if k != 'total')


# ------------------------------------------------------------------ main
def _parser() -> argparse.ArgumentParser:
    from rwpend_bringup.cli import Parser
    p = Parser(prog='rwpend bench', description='Real-time (1 kHz and 2 kHz), lockstep and bag '
               'decode benchmark of the full stack; prints a summary and writes OUTDIR/bench.json. '
               'Timing figures depend on the load of the machine: the JSON records the load average '
               'and the CPU used by every other process during each run.')
    p.add_argument('--duration', type=float, default=None,
                   help='wall seconds of each real-time run (default 60; 8 with --quick)')
    p.add_argument('--quick', action='store_true', help='short runs (8 s real time, 4 s lockstep)')
    p.add_argument('-o', '--out', default=None, help='output directory (default bench_out/)')
    p.add_argument('--h', type=float, action='append', default=None, metavar='S',
                   help='sample period(s) to run (repeatable; default 0.001 and 0.0005)')
    p.add_argument('--layout', action='append', default=None, choices=(*LAYOUTS, 'both', 'all'),
                   help='loop: the loop in one thread of one process (the default of up, '
                   'rwpend_loop.host); separate: every node its own process; control: estimator and '
                   'controller in one loop process fed by the encoders topic, the plant in its own (up '
                   '--composed control); repeatable; both = loop and separate, all = the three (default)')
    p.add_argument('--lockstep-duration', type=float, default=None,
                   help='simulated seconds of each lockstep run (default 12; 4 with --quick)')
    p.add_argument('--no-realtime', action='store_true', help='skip the real-time runs')
    p.add_argument('--no-rig', action='store_true', help='skip the real-time runs of the rig through '
                   'the emulator (./rwpend emulate, up --plant serial:)')
    p.add_argument('--no-lockstep', action='store_true', help='skip the lockstep runs')
    p.add_argument('--no-decode', action='store_true', help='skip the bag decode benchmark')
    p.add_argument('--no-scale', action='store_true', help='skip the scale run (rigs per machine)')
    p.add_argument('--no-sweep', action='store_true', help='skip the robustness-study speed (runs/s per core)')
    p.add_argument('--scale-max', type=int, default=8, metavar='N',
                   help='the scale run adds simulated rigs one by one up to N (default 8) or until '
                   'the late fraction at the plants passes 0.1 %%')
    p.add_argument('--scale-duration', type=float, default=None, metavar='S',
                   help='wall seconds measured at each step of the scale run (default 20; 8 with --quick)')
    p.add_argument('--scale-layout', default='loop', choices=tuple(LAYOUTS),
                   help='the layout of each rig of the scale run (default loop: one process '
                   'per rig, the cheapest)')
    p.add_argument('--domain-id', type=int, default=None,
                   help='ROS_DOMAIN_ID of the runs (default: the environment\'s, else 60)')
    p.add_argument('--ns', default='/bench', help='namespace of the benchmarked rig (default /bench)')
    p.add_argument('--keep-bags', action='store_true', help='keep the bags (default: delete them '
                   'after the metrics are taken); a later bench refuses an --out holding them')
    p.add_argument('-v', '--verbose', action='store_true', help="show the nodes' output")
    p.add_argument('--rt-priority', type=int, default=50, metavar='N',
                   help='./rwpend up --rt-priority of the runs (default 50; 0 = ordinary scheduling)')
    p.add_argument('--set', action='append', default=[], metavar='NODE.PARAM=VALUE',
                   help='./rwpend up --set of the runs (repeatable), e.g. controller.status_every=1')
    p.add_argument('--pin', action='append', default=None, metavar='PROCESS=CPUS|none',
                   help='./rwpend up --pin of the real-time runs (repeatable; each run takes those '
                   'of its processes). Default: separate processes --pin sim=0 --pin estimator=0 '
                   '--pin controller=1 when CPUs 0 and 1 are usable, the other layouts none; '
                   'none = no pinning')
    p.add_argument('--cpu-latency', default='0', metavar='US|none',
                   help='./rwpend up --cpu-latency of the runs (PM QoS CPU wake-up latency; '
                   'default 0: idle CPUs poll while a run lasts; none = no request)')
    p.add_argument('--json', action='store_true', help='print the JSON instead of the summary')
    p.add_argument('--performance', metavar='DOC.md', default=None,
                   help="write the results' tables into DOC.md between its two marker lines "
                   '(rwpend_bench.table; e.g. PERFORMANCE.md)')
    p.add_argument('--tables-from', metavar='BENCH.json', default=None,
                   help='run nothing: print the tables of a saved bench.json (and write them with '
                   '--performance)')
    return p


def write_tables(res: dict, doc: str | None) -> str:
    """The Markdown tables of ``res``, written into ``doc``'s marked region when given;
    ValueError (nothing written) when the document cannot take them."""
    from .table import markdown_tables, replace_region
    tables = markdown_tables(res)
    if doc:
        path = Path(doc)
        try:
            text = path.read_text(encoding='utf-8')
        except OSError as exc:
            raise ValueError(f'{doc}: {exc.strerror or exc}') from exc
        path.write_text(replace_region(text, tables), encoding='utf-8')
    return tables


def _tables_from(a) -> int:
    """``--tables-from BENCH.json``: the tables of a saved result (written with --performance)."""
    try:
        res = json.loads(Path(a.tables_from).read_text(encoding='utf-8'))
        print(write_tables(res, a.performance))
    except (OSError, ValueError, KeyError, TypeError) as exc:
        print(f'rwpend bench: error: {a.tables_from}: {type(exc).__name__}: {exc}', file=sys.stderr)
        return 2
    if a.performance:
        print(f'written: the tables of {a.performance}')
    return 0


@dataclass
class Settings:
    """What a benchmark runs, from its command line (:func:`settings`)."""
    duration: float             # s of each real-time run
    ls_dur: float               # simulated s of each lockstep run
    periods: tuple              # sample periods (s)
    layouts: list               # names of LAYOUTS
    base: object                # the rwpend_bringup.stack.Stack every run starts from
    pins: dict                  # layout -> its real-time runs' --pin items
    cpu_latency: int | None


def settings(a) -> Settings:
    """The :class:`Settings` of the parsed arguments ``a``; ValueError with the reason."""
    from rwpend_bringup.stack import Stack, overrides_from
    duration = a.duration if a.duration is not None else (8.0 if a.quick else 60.0)
    ls_dur = a.lockstep_duration if a.lockstep_duration is not None else (4.0 if a.quick else 12.0)
    if not (duration > 0 and ls_dur > 0):
        raise ValueError('durations must be > 0')
    periods = tuple(a.h) if a.h else DEFAULT_PERIODS
    if any(not (1e-5 <= h <= 0.1) for h in periods):
        raise ValueError('--h must be in [1e-5, 0.1] s')
    layouts = []
    for name in a.layout or ['all']:
        for x in {'both': ['loop', 'separate'], 'all': list(LAYOUTS)}.get(name, [name]):
            if x not in layouts:
                layouts.append(x)
    if not 0 <= a.rt_priority <= 99:
        raise ValueError('--rt-priority must be in 0..99')
    cpu_latency = None if str(a.cpu_latency).lower() == 'none' else a.cpu_latency
    if cpu_latency is not None:
        if not str(cpu_latency).strip().isdigit():
            raise ValueError(f'--cpu-latency expects microseconds (an integer >= 0) or none, got {cpu_latency!r}')
        cpu_latency = int(cpu_latency)
    base = Stack(rt_priority=a.rt_priority, overrides=overrides_from(a.set), cpu_latency=cpu_latency)
    _plan(base)      # refuse a bad --set before any run
    return Settings(duration, ls_dur, periods, layouts, base, realtime_pins(a.pin, layouts), cpu_latency)


def _environment(a) -> dict:
    """The runs' environment: their domain id (60 unless given), discovery on this host."""
    env = dict(os.environ)
    if a.domain_id is not None:
        env['ROS_DOMAIN_ID'] = str(a.domain_id)
    env.setdefault('ROS_DOMAIN_ID', '60')
    env.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    env['PYTHONUNBUFFERED'] = '1'
    return env


def _run_all(a, st: Settings, out: Path, env: dict, res: dict, say) -> None:
    """Every part of the benchmark the arguments ask for, its results into ``res``."""
    from rwpend_bringup.stack import parse_pins
    echo = sys.stderr if a.verbose else None
    if not a.no_realtime:
        for layout in st.layouts:
            for h in st.periods:
                say(f'rwpend bench: real time, {layout}, h = {h * 1e3:g} ms, {st.duration:g} s ...')
                res['realtime'].append(run_realtime(out, h, st.duration, layout, env, a.ns, echo,
                                                    base=replace(st.base, pins=parse_pins(st.pins.get(layout, ())))))
        if not a.no_rig:
            for h in st.periods:
                say(f'rwpend bench: real time, the rig through the emulator, h = {h * 1e3:g} ms, '
                    f'{st.duration:g} s ...')
                res['realtime'].append(run_rig(out, h, st.duration, env, a.ns, echo, base=st.base,
                                               rt_priority=a.rt_priority))
    if not a.no_lockstep:
        for layout in st.layouts:
            for record in (False, True):
                say(f'rwpend bench: lockstep, {layout}, {st.ls_dur:g} s simulated, '
                    f'recorder {"on" if record else "off"} ...')
                res['lockstep'].append(run_lockstep(out, st.periods[0], st.ls_dur, layout, record, env,
                                                    a.ns, echo, base=st.base))
    if not a.no_scale and a.scale_max >= 1:
        sdur = a.scale_duration if a.scale_duration is not None else (8.0 if a.quick else 20.0)
        res['settings'].update({'scale_duration_s': sdur, 'scale_max': a.scale_max,
                                'scale_layout': a.scale_layout})
        # no pinning: n rigs share the CPUs as the scheduler places them
        res['scale'] = run_scale(out, st.periods[0], sdur, a.scale_max, env, a.scale_layout, echo,
                                 base=st.base, say=say)
    if not a.no_sweep:
        say('rwpend bench: robustness-study speed (./rwpend sweep, pure core) ...')
        from rwpend_sweep.bench import bench as sweep_bench
        res['sweep'] = sweep_bench()
    if not a.no_decode:
        bags = [Path(r['bag']) for r in res['realtime'] + res['lockstep']
                if r.get('bag') and Path(r['bag']).is_dir()]
        if bags:
            biggest = max(bags, key=lambda b: sum(f.stat().st_size for f in b.iterdir()))
            say(f'rwpend bench: decoding {biggest} ...')
            res['decode'] = run_decode(biggest)


def main(argv=None) -> int:
    p = _parser()
    argv = sys.argv[1:] if argv is None else list(argv)
    a = p.parse_args(argv)
    if a.tables_from:
        return _tables_from(a)
    from rwpend_bringup.cli import ROOT
    if a.performance:
        try:      # refuse a document without the markers before the runs, not after
            from .table import replace_region
            replace_region(Path(a.performance).read_text(encoding='utf-8'), '')
        except (OSError, ValueError) as exc:
            print(f'rwpend bench: error: --performance {a.performance}: {exc}', file=sys.stderr)
            return 2
    try:
        st = settings(a)
    except ValueError as exc:
        print(f'rwpend bench: error: {exc}', file=sys.stderr)
        return 2
    out = Path(a.out) if a.out else ROOT / 'bench_out'
    if out.exists() and not out.is_dir():
        print(f'rwpend bench: error: --out {out}: exists and is not a directory', file=sys.stderr)
        return 2
    kept = sorted(str(d) for d in out.glob('*/metadata.yaml')) if out.is_dir() else []
    if kept:        # a bench deletes its own bags; these were kept (--keep-bags) or left by a kill
        print(f'rwpend bench: error: {out} holds the bags of an earlier bench, which this one would '
              f'overwrite: {", ".join(str(Path(k).parent) for k in kept)} (move them, or --out DIR)',
              file=sys.stderr)
        return 2
    out.mkdir(parents=True, exist_ok=True)
    env = _environment(a)
    res = {'started': time.time(), 'machine': machine_info(),
           'settings': {'duration_s': st.duration, 'lockstep_duration_s': st.ls_dur, 'periods_s': list(st.periods),
                        'layouts': list(st.layouts), 'domain_id': int(env['ROS_DOMAIN_ID']),
                        'namespace': a.ns, 'quick': a.quick, 'rt_priority': a.rt_priority,
                        'set': list(a.set), 'pin_realtime': {k: list(v) for k, v in st.pins.items()},
                        'cpu_latency_us': st.cpu_latency, 'command': 'rwpend bench ' + ' '.join(argv)},
           'realtime': [], 'lockstep': [], 'decode': None, 'scale': None, 'sweep': None}
    try:
        _run_all(a, st, out, env, res, say=lambda s: print(s, file=sys.stderr, flush=True))
    except KeyboardInterrupt:
        res['interrupted'] = True
    finally:
        res['machine']['loadavg_end'] = _loadavg()
        res['finished'] = time.time()
        if not a.keep_bags:
            for r in res['realtime'] + res['lockstep']:
                if r.get('bag') and Path(r['bag']).is_dir():
                    shutil.rmtree(r['bag'], ignore_errors=True)
            for d in out.glob('*.trace'):
                shutil.rmtree(d, ignore_errors=True)
        (out / 'bench.json').write_text(json.dumps(res, indent=2) + '\n', encoding='utf-8')
    if a.json:
        print(json.dumps(res, indent=2))
    else:
        print(summary_text(res))
        print(f'written: {out / "bench.json"}')
    if a.performance and not res.get('interrupted'):
        write_tables(res, a.performance)
        print(f'written: the tables of {a.performance}')
    return 130 if res.get('interrupted') else 0
