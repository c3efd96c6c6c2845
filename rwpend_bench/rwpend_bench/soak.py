"""``./rwpend soak``: real-time runs that look for death, not for a median (``make soak``).

Each run is the stack as a user starts it (``./rwpend up --mode auto --record BAG --duration D``,
in one layout), on a host loaded on purpose (a busy loop pinned to each CPU), with faults
injected on a schedule:

* ``stop``: SIGSTOP, then SIGCONT after the given time, of the process that holds the estimator
  (the loop layout, the default: the loop's process, simulator included; separate: the
  estimator; ``--composed control``: the loop process of estimator + controller) -- a stalled or
  preempted node, a laptop that sleeps;
* ``stall-recorder``: the same for the process that writes the bag -- a slow disk;
* ``drop``: a share of the UDP datagrams dropped (nftables, inside the run's own network
  namespace; skipped with the reason where that is not possible).

Afterwards the bag is judged by :mod:`rwpend_bag.judge` (read with the rosbags library, not
rwpend's reader): alive at the end, the motor never driven by a stale command, no stream
latched, every gap in the recording report; and ``up`` itself must not have reported the loop
dead. The counts are printed: stalls injected, gaps seen, re-synchronisations, falls,
recoveries, time to recover.

Needs root for the network namespace and nftables (``drop``): without them, the runs take place
in the host's network and the ``drop`` faults are skipped, said so in the output.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(os.environ.get('RWPEND_ROOT', Path(__file__).resolve().parents[2]))
LAYOUTS = {'loop': ['--composed', 'loop'], 'separate': ['--composed', 'none'], 'control': ['--composed', 'control']}
#: the process holding the estimator, by layout (a substring of its command line)
ESTIMATOR_PROCESS = {'loop': 'rwpend_loop.host sim estimator controller',
                     'separate': 'rwpend_estimation.estimator_node',
                     'control': 'rwpend_loop.host estimator controller'}

#: the process writing the bag, by layout: the loop's process hands the bytes to a child of its
#: own (rwpend_bag.procwriter, found by its process name); the others run ./rwpend record
RECORDER_PROCESS = {'loop': 'rwpend-bag', 'separate': 'rwpend_bag.cli record',
                    'control': 'rwpend_bag.cli record'}


@dataclass(frozen=True)
class Fault:
    at: float          # s after the stack's start
    kind: str          # stop | stall-recorder | drop
    seconds: float     # how long
    share: float = 0.0  # drop: share of datagrams dropped

    def describe(self) -> str:
        what = {'stop': 'SIGSTOP the estimator', 'stall-recorder': 'SIGSTOP the recorder',
                'drop': f'drop {100 * self.share:g} % of UDP datagrams'}[self.kind]
        return f'{what} for {self.seconds:g} s at {self.at:g} s'


#: the short version (make test): one fault that makes the pendulum fall, then recovery
SHORT = (40.0, (Fault(15.0, 'stop', 0.5),))
#: make soak: several minutes per layout, every kind of fault, the last one 40 s before the end
FULL = (240.0, (Fault(20.0, 'stop', 0.05), Fault(35.0, 'stop', 0.5), Fault(60.0, 'stop', 3.0),
                Fault(95.0, 'stall-recorder', 2.0), Fault(120.0, 'drop', 10.0, 0.01),
                Fault(145.0, 'stop', 0.05), Fault(146.0, 'stop', 0.05), Fault(147.0, 'stop', 0.05),
                Fault(170.0, 'stop', 0.5), Fault(200.0, 'stall-recorder', 0.5)))


def children(pid: int) -> list[int]:
    """Every descendant of ``pid`` (from /proc)."""
    by_parent: dict[int, list[int]] = {}
    for entry in Path('/proc').iterdir():
        if not entry.name.isdigit():
            continue
        try:
            ppid = int((entry / 'stat').read_text().rsplit(')', 1)[1].split()[1])
        except (OSError, IndexError, ValueError):
            continue
        by_parent.setdefault(ppid, []).append(int(entry.name))
    out, todo = [], [pid]
    while todo:
        for c in by_parent.get(todo.pop(), []):
            out.append(c)
            todo.append(c)
    return out


def cmdline(pid: int) -> str:
    try:
        return Path(f'/proc/{pid}/cmdline').read_bytes().replace(b'\0', b' ').decode(errors='replace')
    except OSError:
        return ''


def comm(pid: int) -> str:
    try:
        return Path(f'/proc/{pid}/comm').read_text().strip()
    except OSError:
        return ''


def find_process(root_pid: int, needle: str, timeout: float = 30.0) -> int | None:
    """A descendant of ``root_pid`` whose command line contains ``needle``, or whose process
    name is ``needle``."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        for pid in children(root_pid):
            if needle in cmdline(pid) or comm(pid) == needle:
                return pid
        time.sleep(0.2)
    return None


def busy_loops(cpus) -> list[subprocess.Popen]:
    """One busy loop pinned to each CPU, at ordinary priority."""
    code = 'import os, sys\nos.sched_setaffinity(0, {int(sys.argv[1])})\nwhile True:\n    pass\n'
    return [subprocess.Popen([sys.executable, '-c', code, str(c)]) for c in cpus]


def drop_rule(share: float) -> str:
    """The nftables ruleset (one line) that drops ``share`` of the UDP datagrams coming in."""
    return (f'table inet rwsoak {{ chain input {{ type filter hook input priority 0; '
            f'meta l4proto udp numgen random mod 10000 < {int(share * 10000)} drop; }}; }}')


class Netns:
    """A network namespace of the run (only its loopback), for isolation and for ``drop``."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.ok = False
        self.nft = shutil.which('nft') is not None
        self.why = ''
        if os.geteuid() != 0 or shutil.which('ip') is None:
            self.why = 'not root or no ip(8): running in the host network'
            return
        r = subprocess.run(['ip', 'netns', 'add', name], capture_output=True, text=True)
        if r.returncode:
            self.why = f'ip netns add failed: {r.stderr.strip()}'
            return
        subprocess.run(['ip', 'netns', 'exec', name, 'ip', 'link', 'set', 'lo', 'up'], check=True)
        self.ok = True
        if not self.nft:
            self.why = 'no nft(8) (Debian package nftables): drop faults skipped'

    def prefix(self) -> list[str]:
        return ['ip', 'netns', 'exec', self.name] if self.ok else []

    def drop(self, share: float) -> None:
        subprocess.run(self.prefix() + ['nft', '-f', '-'], input=drop_rule(share), text=True, check=True)

    def undrop(self) -> None:
        subprocess.run(self.prefix() + ['nft', 'delete', 'table', 'inet', 'rwsoak'], check=False)

    def close(self) -> None:
        if self.ok:
            subprocess.run(['ip', 'netns', 'del', self.name], check=False)


def inject(fault: Fault, up_pid: int, layout: str, net: Netns, log) -> bool:
    """Carry out one fault; False when it could not be (said in ``log``)."""
    if fault.kind == 'drop':
        if not (net.ok and net.nft):
            log(f'skipped: {fault.describe()} ({net.why})')
            return False
        net.drop(fault.share)
        time.sleep(fault.seconds)
        net.undrop()
        return True
    needle = ESTIMATOR_PROCESS[layout] if fault.kind == 'stop' else RECORDER_PROCESS[layout]
    pid = find_process(up_pid, needle, timeout=1.0)
    if pid is None:
        running = '; '.join(cmdline(c)[:80] for c in children(up_pid)) or 'none'
        log(f'skipped: {fault.describe()} (no process "{needle}"; running: {running})')
        return False
    os.kill(pid, signal.SIGSTOP)
    time.sleep(fault.seconds)
    os.kill(pid, signal.SIGCONT)
    return True


def run_layout(layout: str, duration: float, faults, out_dir: Path, load: bool = True,
               domain: int | None = None, extra: list[str] | None = None, log=print) -> dict:
    """One soak run; returns {'layout', 'up_status', 'faults', 'verdict', 'ok', ...}. Its bag,
    ``out_dir/soak_<layout>``, must not exist yet (ValueError): a run judges only what it recorded."""
    from rwpend_bag.judge import Verdict, judge, read_run
    bag = out_dir / f'soak_{layout}'
    if bag.exists():
        raise ValueError(f'{bag} already exists (a bag of an earlier soak; choose another --out)')
    out_dir.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ)
    env['ROS_DOMAIN_ID'] = str(domain if domain is not None else 100 + os.getpid() % 100)
    env.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    net = Netns(f'rwsoak{os.getpid()}_{layout}')
    if net.why:
        log(f'[{layout}] {net.why}')
    cmd = [*net.prefix(), str(ROOT / 'rwpend'), 'up', '--mode', 'auto', '--record', str(bag),
           '--duration', f'{duration:g}', *LAYOUTS[layout], *(extra or [])]
    hogs = busy_loops(sorted(os.sched_getaffinity(0))) if load else []
    done, failed, t0 = [], [], time.monotonic()
    up_log = open(out_dir / f'up_{layout}.log', 'w')
    try:
        up = subprocess.Popen(cmd, env=env, stdout=up_log, stderr=subprocess.STDOUT)

        def schedule():
            for f in sorted(faults, key=lambda f: f.at):
                delay = t0 + 5.0 + f.at - time.monotonic()   # ~5 s of start-up before sample 0
                if delay > 0 and up.poll() is None:
                    time.sleep(delay)
                if up.poll() is not None:
                    return
                try:
                    injected = inject(f, up.pid, layout, net, lambda m: log(f'[{layout}] {m}'))
                except (OSError, subprocess.SubprocessError) as exc:   # said, and the run judged without it
                    log(f'[{layout}] could not inject {f.describe()}: {exc}')
                    failed.append(f'could not inject: {f.describe()} ({exc})')
                    continue
                if injected:
                    done.append(f)
                    log(f'[{layout}] {time.monotonic() - t0:6.1f} s: {f.describe()}')
        th = threading.Thread(target=schedule, daemon=True)
        th.start()
        status = up.wait(timeout=duration * 3 + 180)
        th.join(timeout=5)
    finally:
        for h in hogs:
            h.kill()
        up_log.close()
        net.close()
    if bag.is_dir():
        verdict = judge(read_run(bag))
    else:            # up failed before it recorded anything (its log says why)
        verdict = Verdict(problems=[f'no bag: {bag} was not written'])
    # a stop or a stall can always be injected: one that was not leaves the run untested
    missed = [f for f in faults if f.kind != 'drop' and f not in done]
    verdict.problems += [f'not injected: {f.describe()}' for f in missed] + failed
    ok = status == 0 and not verdict.problems
    result = {'layout': layout, 'duration_s': duration, 'up_status': status, 'ok': ok,
              'faults_injected': [f.describe() for f in done],
              'stalls_injected': sum(f.kind in ('stop', 'stall-recorder') for f in done),
              'load': f'busy loop on CPUs {sorted(os.sched_getaffinity(0))}' if load else 'none',
              'network': f'netns {net.name}' if net.ok else 'host', 'verdict': verdict.as_dict()}
    (out_dir / f'soak_{layout}.json').write_text(json.dumps(result, indent=1))
    return result


def summary(results: list[dict]) -> str:
    rows = ['layout    ok   up  stalls  gaps seen  resyncs  falls  recoveries  recover max s  unsafe  latched',
            '--------  ---  --  ------  ---------  -------  -----  ----------  -------------  ------  -------']
    for r in results:
        v = r['verdict']
        gaps = sum(g['seen'] for g in v['gaps'].values())
        rec = max(v['recover_s']) if v['recover_s'] else '-'
        rows.append(f"{r['layout']:<8}  {'yes' if r['ok'] else 'NO':<3}  {r['up_status']:<2}  "
                    f"{r['stalls_injected']:>6}  {gaps:>9}  {str(v['resyncs']):>7}  {v['falls']:>5}  "
                    f"{v['recoveries']:>10}  {rec!s:>13}  {v['unsafe_samples']:>6}  "
                    f"{','.join(v['latched']) or '-':>7}")
    for r in results:
        for p in r['verdict']['problems']:
            rows.append(f"  {r['layout']}: {p}")
        if r['up_status']:
            rows.append(f"  {r['layout']}: ./rwpend up exited with {r['up_status']} (see up_{r['layout']}.log)")
    return '\n'.join(rows)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog='rwpend soak', description=__doc__.split('\n\n')[0])
    p.add_argument('--short', action='store_true', help=f'the short version ({SHORT[0]:g} s, one fault)')
    p.add_argument('--layouts', default=','.join(LAYOUTS), help='comma-separated: loop, separate, control')
    p.add_argument('--duration', type=float, default=None, help='s per run (default: the scenario\'s)')
    p.add_argument('--no-load', action='store_true', help='no busy loops')
    p.add_argument('-o', '--out', default=None,
                   help='output directory, new or without soak bags (default soak_out/<date>_<time>)')
    a = p.parse_args(argv)
    layouts = [s.strip() for s in a.layouts.split(',') if s.strip()]
    bad = [s for s in layouts if s not in LAYOUTS]
    if bad or not layouts:
        p.error(f'--layouts: one or more of {", ".join(LAYOUTS)}, got {a.layouts!r}')
    duration, faults = SHORT if a.short else FULL
    if a.duration is not None:
        if not a.duration > 0:
            p.error('--duration must be > 0')
        duration = a.duration
    faults = [f for f in faults if f.at + f.seconds < duration - 30.0] or list(faults[:1])
    out = Path(a.out) if a.out else ROOT / 'soak_out' / time.strftime('%Y%m%d_%H%M%S')
    if out.exists() and not out.is_dir():
        p.error(f'--out {out}: exists and is not a directory')
    there = [str(out / f'soak_{layout}') for layout in layouts if (out / f'soak_{layout}').exists()]
    if there:        # judged, they would pass for this run's; never overwritten
        p.error(f'--out {out}: already holds the bag(s) of an earlier soak: {", ".join(there)}')
    t0 = time.monotonic()
    results = []
    for layout in layouts:
        print(f'soak: {layout}, {duration:g} s, faults: ' + '; '.join(f.describe() for f in faults), flush=True)
        results.append(run_layout(layout, duration, faults, out, load=not a.no_load))
    print(summary(results))
    print(f'soak: {time.monotonic() - t0:.0f} s; results in {out}', flush=True)
    return 0 if all(r['ok'] for r in results) else 1


if __name__ == '__main__':
    raise SystemExit(main())
