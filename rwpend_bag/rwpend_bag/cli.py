"""Command-line entry points: ``record``, ``bag info``, ``play``, ``analyze``.

Each ``*_main(argv)`` returns an exit status (2 for usage errors and unreadable input).
``python -m rwpend_bag.cli {record,info,play,analyze} ...`` runs them directly.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # exit 2 with a clear message (argparse's default, explicit)
        self.print_usage(sys.stderr)
        print(f'{self.prog}: error: {message}', file=sys.stderr)
        raise SystemExit(2)


def _run(fn, argv):
    try:
        return fn(argv)
    except SystemExit as exc:
        return exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 2)


def _usage_error(prog, msg) -> int:
    print(f'{prog}: error: {msg}', file=sys.stderr, flush=True)
    return 2


def _abs_topic(name: str, namespace: str) -> str:
    if name.startswith('/'):
        return name
    ns = namespace.rstrip('/')
    return f'{ns}/{name}' if ns else f'/{name}'


# ------------------------------------------------------------------ record
def recorder_priority(given: int | None, env_value: str | None, sim_time: bool,
                      permitted) -> tuple[int | None, str]:
    """The SCHED_FIFO priority ``rwpend record`` takes (None: leave ``RWPEND_RT_PRIORITY`` as
    the environment has it, or ordinary scheduling), and why.

    ``given``: ``--rt-priority``; ``env_value``: ``RWPEND_RT_PRIORITY`` (``./rwpend up`` sets it
    for its recorder); ``permitted``: ``priority -> (ok, reason)``
    (:func:`rwpend_ros.sched.realtime_permitted`). Nodes started the ROS way (``./rwpend node``)
    take SCHED_FIFO 50 in real time; a recorder beside them at ordinary priority gets only the
    CPU they leave (PERFORMANCE.md, "What each mechanism buys"). So, as the recorder of
    ``./rwpend up`` does, it runs ``RECORDER_BELOW`` priorities below them: ahead of every
    ordinary process, behind the loop, which cannot wait. With ``--sim-time`` (lockstep) the
    nodes run at ordinary priority and wait for the recorder."""
    from rwpend_ros.sched import DEFAULT_RT_PRIORITY, RECORDER_BELOW
    if given is not None:
        return given, (f'SCHED_FIFO {given} (--rt-priority)' if given else
                       'ordinary scheduling (--rt-priority 0)')
    if env_value is not None and env_value.strip():
        return None, f'priority from RWPEND_RT_PRIORITY={env_value.strip()} (0: ordinary scheduling)'
    if sim_time:
        return None, 'ordinary scheduling (--sim-time: lockstep nodes wait for the recorder)'
    prio = max(1, DEFAULT_RT_PRIORITY - RECORDER_BELOW)
    ok, reason = permitted(prio)
    if not ok:
        return None, (f'ordinary scheduling: real-time priority not permitted here ({reason}); beside '
                      'nodes at real-time priority a busy machine may then keep samples from the bag')
    return prio, (f"SCHED_FIFO {prio} ({RECORDER_BELOW} below the nodes' default {DEFAULT_RT_PRIORITY}, "
                  'where permitted; --rt-priority 0 to turn it off)')


def record_main(argv=None) -> int:
    return _run(_record, sys.argv[1:] if argv is None else argv)


def _record(argv) -> int:
    p = _Parser(prog='rwpend record',
                description='Record topics to a rosbag2 MCAP bag (Ctrl-C / SIGTERM to stop).')
    p.add_argument('-o', '--output', help='bag directory to create (default: rwpend_<date>)')
    p.add_argument('-a', '--all', action='store_true', help='record every topic (also later ones)')
    p.add_argument('--namespace', default='/', help='namespace for relative topic names')
    p.add_argument('--progress', metavar='TOPIC',
                   help='publish on TOPIC (rosgraph_msgs/Clock) every 10th /clock recorded: a lockstep '
                        'simulator with lockstep_recorder_window waits for it (./rwpend up --lockstep '
                        '--record sets it)')
    p.add_argument('--sim-time', action='store_true',
                   help='log times on the simulated clock (header stamps, /clock), written in a '
                        'deterministic order: two lockstep runs give the same bag (./rwpend up '
                        '--lockstep --record sets it; rwpend_bag.logtime)')
    p.add_argument('--rt-priority', type=int, default=None, metavar='N',
                   help='SCHED_FIFO priority of the recorder (1-99; 0: ordinary scheduling; default: '
                        'RWPEND_RT_PRIORITY, which ./rwpend up sets, else 40 where permitted -- 10 below '
                        "the nodes' default 50, ahead of every ordinary process -- and ordinary with "
                        '--sim-time)')
    p.add_argument('topics', nargs='*', help='topics to record')
    a = p.parse_args(argv)
    if a.rt_priority is not None and not 0 <= a.rt_priority <= 99:
        return _usage_error(p.prog, f'--rt-priority must be in 0..99, got {a.rt_priority}')
    if a.all and a.topics:
        return _usage_error(p.prog, 'give either --all or topics, not both')
    if not a.all and not a.topics:
        return _usage_error(p.prog, 'nothing to record: give topics or --all')
    out = Path(a.output or time.strftime('rwpend_%Y_%m_%d-%H_%M_%S'))
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        return _usage_error(p.prog, f'{out} already exists (choose a new bag directory)')
    if not out.parent.exists():
        return _usage_error(p.prog, f'{out.parent} does not exist')
    topics = [_abs_topic(t, a.namespace) for t in a.topics]
    progress = None
    if a.progress is not None:
        from rclpy.exceptions import InvalidTopicNameException
        from rclpy.validate_full_topic_name import validate_full_topic_name
        progress = _abs_topic(a.progress, a.namespace)
        try:
            validate_full_topic_name(progress)
        except InvalidTopicNameException as exc:
            return _usage_error(p.prog, f'--progress: invalid topic name {a.progress!r} ({exc})')
    from rwpend_ros.sched import realtime_permitted
    prio, why = recorder_priority(a.rt_priority, os.environ.get('RWPEND_RT_PRIORITY'), a.sim_time,
                                  realtime_permitted)
    if prio is not None:
        os.environ['RWPEND_RT_PRIORITY'] = str(prio)   # taken by the recorder at its start
    print(f'rwpend record: {why}', file=sys.stderr, flush=True)
    from .recorder_node import run_recorder
    return run_recorder(str(out), topics, a.all, progress, a.sim_time)


# ------------------------------------------------------------------ info
def info_main(argv=None) -> int:
    return _run(_info, sys.argv[1:] if argv is None else argv)


def _info(argv) -> int:
    p = _Parser(prog='rwpend bag info', description='Topics, counts, rates, duration, seq gaps.')
    p.add_argument('bag')
    p.add_argument('--json', action='store_true')
    a = p.parse_args(argv)
    from .info import bag_info, format_info
    from .reader import BagReadError
    try:
        info = bag_info(a.bag)
    except BagReadError as exc:
        return _usage_error(p.prog, str(exc))
    print(json.dumps(info, indent=2) if a.json else format_info(info))
    return 0


# ------------------------------------------------------------------ play
def play_main(argv=None) -> int:
    return _run(_play, sys.argv[1:] if argv is None else argv)


def _play(argv) -> int:
    p = _Parser(prog='rwpend play', description='Publish a bag with its original timing.')
    p.add_argument('bag')
    p.add_argument('--rate', type=float, default=1.0)
    p.add_argument('--loop', action='store_true')
    p.add_argument('--topics', nargs='+', default=None)
    p.add_argument('--remap', action='append', default=[], metavar='FROM:=TO')
    p.add_argument('--start', type=float, default=0.0, metavar='S', help='skip the first S seconds')
    p.add_argument('--clock', action='store_true', help='publish /clock from the bag time')
    p.add_argument('--wait', type=float, default=2.0,
                   help='wait up to this long for a subscriber before playing (s)')
    a = p.parse_args(argv)
    if not (a.rate > 0) or a.rate > 1000:
        return _usage_error(p.prog, '--rate must be in (0, 1000]')
    if a.start < 0:
        return _usage_error(p.prog, '--start must be >= 0')
    remap = {}
    for r in a.remap:
        src, sep, dst = r.partition(':=')
        if not sep or not src or not dst:
            return _usage_error(p.prog, f'bad --remap {r!r} (expected from:=to)')
        remap[_abs_topic(src, '/')] = _abs_topic(dst, '/')
    from .player_core import schedule
    from .reader import BagReadError, read_bag
    try:
        bag = read_bag(a.bag)
    except BagReadError as exc:
        return _usage_error(p.prog, str(exc))
    for w in bag.warnings:
        print(f'play: warning: {w}', file=sys.stderr)
    topics = [_abs_topic(t, '/') for t in a.topics] if a.topics else None
    if topics:
        unknown = [t for t in topics if t not in bag.topics]
        if unknown:
            return _usage_error(p.prog, f'not in the bag: {", ".join(unknown)}')
    sched = schedule(bag, topics, remap, a.start)
    if not len(sched):
        return _usage_error(p.prog, 'nothing to play (empty selection)')
    from .player_node import run
    return run(sched, a.rate, a.loop, a.clock, a.wait)


# ------------------------------------------------------------------ analyze
def analyze_main(argv=None) -> int:
    return _run(_analyze, sys.argv[1:] if argv is None else argv)


def _analyze(argv) -> int:
    p = _Parser(prog='rwpend analyze', description='Metrics and plots of a run.')
    p.add_argument('bag')
    p.add_argument('--plot', metavar='FILE', help='write the figure (.png or .svg)')
    p.add_argument('--json', action='store_true', help='print the metrics as JSON')
    p.add_argument('--bench', action='store_true', help='also measure decode throughput')
    a = p.parse_args(argv)
    if a.plot and os.path.splitext(a.plot)[1].lower() not in ('.png', '.svg', '.pdf'):
        return _usage_error(p.prog, '--plot must end in .png, .svg or .pdf')
    if a.plot and not Path(a.plot).resolve().parent.exists():
        return _usage_error(p.prog, f'{Path(a.plot).parent} does not exist')
    from . import analysis
    from .reader import BagReadError, read_bag
    try:
        bag = read_bag(a.bag)
    except BagReadError as exc:
        return _usage_error(p.prog, str(exc))
    for w in bag.warnings:
        print(f'analyze: warning: {w}', file=sys.stderr)
    series = analysis.load_series(bag)
    m = analysis.analyze(bag, series)
    if a.bench:
        m['decode_bench'] = analysis.bench_decode(bag)
    print(json.dumps(m, indent=2) if a.json else analysis.format_metrics(m))
    if a.plot:
        if m.get('error'):
            print(f'analyze: no plot: {m["error"]}', file=sys.stderr)
            return 1
        analysis.plot(bag, a.plot, series)
        if not a.json:
            print(f'plot: {a.plot}')
    return 1 if m.get('error') else 0


COMMANDS = {'record': record_main, 'info': info_main, 'play': play_main, 'analyze': analyze_main}


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:2] == ['bag', 'info']:
        argv = ['info'] + argv[2:]
    if not argv or argv[0] not in COMMANDS:
        print('usage: python -m rwpend_bag.cli {record,info,play,analyze} ...', file=sys.stderr)
        return 2
    return COMMANDS[argv[0]](argv[1:])


if __name__ == '__main__':
    sys.exit(main())
