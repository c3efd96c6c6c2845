"""The verdict of a run, from its bag alone, read with an independent reader.

Used by the soak tests (``./rwpend soak``, ``make soak``), which look for death, not for a
median: was the loop alive at the end, was the motor ever driven by a command computed from a
state too old to act on, did a node latch, is every gap of the bag in its recording report?

The bag is read with the ``rosbags`` library (:func:`read_run`), not with rwpend's own reader, so
a fault in our reader cannot hide a fault in our recorder. :func:`judge` is pure numpy on the
decoded columns, unit-tested on synthetic data.

What is judged, and from which topic (θ from hanging, upright = π; x = wrap(θ − π)):

* **balanced / falls / recoveries** (``sim/true_state``): "up" is |x| < ``up`` rad; a balance
  episode is up for at least ``settle_s`` s; a *fall* is the end of an episode after which |x|
  exceeds ``fallen`` rad; its *recovery* is the start of the next episode, and the time to
  recover runs from the fall (|x| passing ``fallen``) to that start.
* **alive at the end**: balanced over the last ``end_s`` s of the run.
* **motor zero when nothing fresh** (``sim/true_state.command_seq``): over every sample k whose
  held command is not zero, the command held answers a sample less than ``timeout_samples`` old
  (k − 1 − command_seq < timeout_samples): the motor is never driven by a stale state, so it is at
  zero within that many samples whenever the controller had no fresh state.
* **no latch**: the estimator's ``state`` and the controller's ``command`` streams go on to the end
  of the run (their last stamp within ``tail_s`` of the plant's last sample).
* **gaps accounted for**: the seq gaps seen in the bag, per loop topic, equal those the
  recorder's ``recording_report.json`` lists.
* **timing, per sample** (``sim/true_state.command_seq``; figures, not a verdict): from the first
  sample a command answered, a sample is *late* when the command the plant held over the
  interval before it did not answer the previous sample (0 <= command_seq < seq - 1), and *at
  zero* when the command timeout held the motor at 0 (command_seq = -1).

On the rig (the driver: no ``sim/true_state``) the plant's side is the device's own report,
``applied`` (the command it held over each interval and the sample that command answered), and
the angle is the estimator's (``state.theta``, by seq; the last estimate before a sample with
none): :func:`plant_view` builds the same columns from them, and the verdict says so
(:attr:`Verdict.source`).

``python -m rwpend_bag.judge BAG...`` prints the verdict of each bag, timing included.
"""
from __future__ import annotations

import contextlib
import json
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

LOOP_TYPES = {'PlantState': 'truth', 'StateEstimate': 'state', 'MotorCommand': 'command',
              'EncoderCounts': 'encoders', 'AppliedCommand': 'applied'}
FIELDS = {'truth': ('seq', 'theta', 'u_commanded', 'command_seq', 'command_timeout'),
          'state': ('seq', 'theta', 'resyncs', 'missed'),
          'command': ('seq', 'u'),
          'encoders': ('seq',),
          'applied': ('seq', 'command_seq', 'u')}
SOURCE_SIM = 'sim/true_state (the simulated plant)'
SOURCE_RIG = 'applied (the device) and state.theta (the estimator)'


def read_run(bag_dir: str | Path) -> dict:
    """The loop topics of a bag as numpy columns (``stamp`` in s; fields a bag lacks are absent),
    the topics' names (``topics``), the last value of every /diagnostics key per status name
    (``diagnostics``) and the recording report (``report``, {} if none) -- read with rosbags."""
    bag_dir = Path(bag_dir)
    out: dict = {'topics': {}, 'diagnostics': {}}
    with _rosbags_reader(bag_dir) as reader:
        conns = {}
        for c in reader.connections:
            short = c.msgtype.rsplit('/', 1)[-1]
            key = LOOP_TYPES.get(short)
            if key and (key not in out['topics'] or len(c.topic) < len(out['topics'][key])):
                out['topics'][key] = c.topic
                conns[key] = c
        cols = {k: {f: [] for f in ('stamp', *FIELDS[k])} for k in conns}
        by_conn = {id(c): k for k, c in conns.items()}
        wanted = list(conns.values()) + [c for c in reader.connections if c.topic == '/diagnostics']
        for conn, _, raw in reader.messages(connections=wanted):
            msg = reader.deserialize(raw, conn.msgtype)
            key = by_conn.get(id(conn))
            if key is None:                       # /diagnostics
                for st in msg.status:
                    d = out['diagnostics'].setdefault(st.name, {})
                    d.update({kv.key: kv.value for kv in st.values})
                    d['_level'] = int.from_bytes(st.level, 'little') if isinstance(st.level, bytes) else int(st.level)
                    d['_message'] = st.message
                continue
            c = cols[key]
            c['stamp'].append(msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9)
            for f in FIELDS[key]:
                if hasattr(msg, f):
                    c[f].append(getattr(msg, f))
        for key, c in cols.items():
            out[key] = {f: np.asarray(v) for f, v in c.items() if len(v) == len(c['stamp'])}
    report = bag_dir / 'recording_report.json'
    out['report'] = json.loads(report.read_text()) if report.exists() else {}
    return out


@contextlib.contextmanager
def _rosbags_reader(bag_dir: Path):
    """rosbags' AnyReader open on the rosbag2 directory ``bag_dir``. AnyReader takes a path whose
    name ends in ``.bag`` for a ROS 1 bag; a rosbag2 directory of that name (``up --record
    run.bag``) is opened through a link without the suffix."""
    from rosbags.highlevel import AnyReader
    if bag_dir.suffix != '.bag' or not bag_dir.is_dir():
        with AnyReader([bag_dir]) as reader:
            yield reader
        return
    with tempfile.TemporaryDirectory(prefix='rwpend-judge-') as tmp:
        link = Path(tmp) / bag_dir.stem
        link.symlink_to(bag_dir.resolve(), target_is_directory=True)
        with AnyReader([link]) as reader:
            yield reader


def wrap(a):
    return (np.asarray(a, float) + np.pi) % (2 * np.pi) - np.pi


def seq_gaps(seq) -> list[tuple[int, int]]:
    """The missing seq ranges (first, last) of a stream: a seq more than one above the highest
    seen before it opens a gap (duplicates and older seqs open none)."""
    s = np.asarray(seq, np.int64)
    if len(s) < 2:
        return []
    top = np.maximum.accumulate(s)[:-1]
    idx = np.nonzero(s[1:] > top + 1)[0]
    return [(int(top[i] + 1), int(s[i + 1] - 1)) for i in idx]


@dataclass
class Verdict:
    duration_s: float = 0.0
    alive_at_end: bool = False
    balanced_s: float = 0.0           # time balanced (in episodes of at least settle_s)
    catches: int = 0                  # balance episodes
    falls: int = 0
    recoveries: int = 0
    recover_s: list = field(default_factory=list)
    unsafe_samples: int = 0           # motor driven by a command too old (or none)
    first_unsafe_s: float | None = None
    latched: list = field(default_factory=list)     # streams that stopped before the end
    gaps: dict = field(default_factory=dict)        # topic -> seen / reported
    unaccounted: list = field(default_factory=list)  # topics whose gaps the report does not list
    resyncs: int | None = None
    source: str = ''                  # what the plant's side was read from
    samples: int = 0                  # plant samples in the bag (sim/true_state, or applied)
    timed_samples: int = 0            # of them from the first one a command answered on
    late_samples: int = 0             # the command held did not answer the previous sample
    zero_samples: int = 0             # the command timeout held the motor at 0
    problems: list = field(default_factory=list)

    def timing(self) -> str:
        """One line: samples, late and at-zero shares (of the timed samples)."""
        n = max(self.timed_samples, 1)
        return (f'{self.samples} samples; late {self.late_samples} = {100 * self.late_samples / n:.3f} %, '
                f'at zero {self.zero_samples} = {100 * self.zero_samples / n:.3f} % '
                f'(of {self.timed_samples} from the first command)')

    def as_dict(self) -> dict:
        return dict(self.__dict__)


def _episodes(t, up, settle_s):
    """(start, end) times of the runs of ``up`` lasting at least settle_s."""
    out = []
    edges = np.diff(np.concatenate([[0], up.astype(np.int8), [0]]))
    starts, ends = np.nonzero(edges == 1)[0], np.nonzero(edges == -1)[0] - 1
    for a, b in zip(starts, ends):
        if t[b] - t[a] >= settle_s:
            out.append((a, b))
    return out


def plant_view(run: dict) -> dict | None:
    """The plant's columns of a rig run (module doc): ``applied`` of every sample with the
    estimator's angle of the same seq (or the last one before it; NaN before the first), as
    ``sim/true_state`` gives them on the simulator. None without ``applied`` or ``state.theta``."""
    applied, state = run.get('applied'), run.get('state')
    if applied is None or state is None or 'theta' not in state or 'command_seq' not in applied:
        return None
    seq = applied['seq'].astype(np.int64)
    order = np.argsort(state['seq'], kind='stable')
    s_seq, s_theta = state['seq'].astype(np.int64)[order], np.asarray(state['theta'], float)[order]
    i = np.searchsorted(s_seq, seq, side='right') - 1
    theta = np.where(i >= 0, s_theta[np.maximum(i, 0)], np.nan) if len(s_seq) else np.full(len(seq), np.nan)
    return {'stamp': applied['stamp'], 'seq': seq, 'theta': theta,
            'u_commanded': np.asarray(applied['u'], float), 'command_seq': applied['command_seq'].astype(np.int64)}


def judge(run: dict, *, timeout_samples: int = 3, up: float = 0.3, fallen: float = 0.8,
          settle_s: float = 1.0, end_s: float = 5.0, tail_s: float = 0.5) -> Verdict:
    """The verdict of one run (see the module doc); ``run`` as :func:`read_run` returns it."""
    v = Verdict()
    truth = run.get('truth')
    v.source = SOURCE_SIM
    if truth is None:
        truth = plant_view(run)
        v.source = SOURCE_RIG
    if truth is None or len(truth['stamp']) < 2:
        v.source = ''
        v.problems.append('neither sim/true_state nor applied with state in the bag: nothing to judge')
        return v
    t = truth['stamp'] - truth['stamp'][0]
    v.duration_s = float(t[-1])
    x = np.abs(wrap(truth['theta'] - np.pi))
    x[np.isnan(x)] = np.pi                    # no estimate yet: not balanced
    eps = _episodes(t, x < up, settle_s)
    v.catches = len(eps)
    v.balanced_s = float(sum(t[b] - t[a] for a, b in eps))
    for i, (a, b) in enumerate(eps):
        after = np.nonzero(x[b + 1:] > fallen)[0]
        if len(after) == 0:
            continue
        v.falls += 1
        fall_t = t[b + 1 + after[0]]
        nxt = [e for e in eps[i + 1:] if t[e[0]] > fall_t]
        if nxt:
            v.recoveries += 1
            v.recover_s.append(round(float(t[nxt[0][0]] - fall_t), 3))
    end = t > t[-1] - end_s
    v.alive_at_end = bool(np.all(x[end] < up))
    if not v.alive_at_end:
        v.problems.append(f'not balanced over the last {end_s:g} s (max |theta - pi| {x[end].max():.2f} rad)')
    v.samples = len(t)
    if 'command_seq' in truth:
        cs = truth['command_seq'].astype(np.int64)
        seq = truth['seq'].astype(np.int64)
        answered = np.nonzero(cs >= 0)[0]
        if len(answered):
            timed = slice(int(answered[0]), None)
            v.timed_samples = len(cs[timed])
            v.late_samples = int(np.sum((cs[timed] >= 0) & (cs[timed] < seq[timed] - 1)))
            v.zero_samples = int(np.sum(cs[timed] < 0))
        age = truth['seq'].astype(np.int64) - 1 - truth['command_seq'].astype(np.int64)
        driven = truth['u_commanded'] != 0.0
        bad = driven & ((truth['command_seq'] < 0) | (age >= timeout_samples))
        v.unsafe_samples = int(bad.sum())
        if v.unsafe_samples:
            v.first_unsafe_s = float(t[np.argmax(bad)])
            v.problems.append(f'{v.unsafe_samples} samples driven by a command {timeout_samples}+ samples '
                              f'old (first at {v.first_unsafe_s:.3f} s)')
    else:
        v.problems.append(f'{v.source} has no command_seq: the motor-zero rule cannot be judged')
    t_end = truth['stamp'][-1]
    for key in ('state', 'command'):
        s = run.get(key)
        if s is None or not len(s['stamp']) or s['stamp'][-1] < t_end - tail_s:
            last = float(s['stamp'][-1] - truth['stamp'][0]) if s is not None and len(s['stamp']) else None
            v.latched.append(key)
            v.problems.append(f'{key} stopped before the end of the run (last at {last} s of {v.duration_s:.1f})')
    state = run.get('state')
    if state is not None and 'resyncs' in state and len(state['resyncs']):
        v.resyncs = int(state['resyncs'][-1])
    report_topics = run.get('report', {}).get('topics', {})
    for key in ('truth', 'applied', 'state', 'command', 'encoders'):
        name = run['topics'].get(key)
        cols = run.get(key)
        if name is None or cols is None:
            continue
        seen = seq_gaps(cols['seq'])
        listed = report_topics.get(name, {})
        missing = sum(b - a + 1 for a, b in seen)
        v.gaps[name] = {'seen': len(seen), 'missing': missing,
                        'reported': listed.get('gap_count'), 'reported_missing': listed.get('missing')}
        if listed and (listed.get('gap_count') != len(seen) or listed.get('missing') != missing):
            v.unaccounted.append(name)
            v.problems.append(f'{name}: {len(seen)} gaps ({missing} missing) in the bag, the report says '
                              f'{listed.get("gap_count")} ({listed.get("missing")})')
    return v


def main(argv=None) -> int:
    """``python -m rwpend_bag.judge BAG...``: the verdict of each bag, with its timing; exit 1 when
    a bag has problems, 2 when one cannot be read."""
    import argparse
    import sys
    p = argparse.ArgumentParser(prog='python -m rwpend_bag.judge',
                                description='The verdict of a run from its bag (read with rosbags): alive at the '
                                'end, falls, stale commands, latched streams, gaps, and the late share per sample.')
    p.add_argument('bags', nargs='+', help='bag directories (rosbag2 layout)')
    a = p.parse_args(argv)
    status = 0
    for bag in a.bags:
        try:
            v = judge(read_run(bag))
        except Exception as exc:  # noqa: BLE001 - a bag that cannot be read: said, the others go on
            print(f'{bag}: cannot be read: {type(exc).__name__}: {exc}', file=sys.stderr)
            status = 2
            continue
        rig = f' [from {v.source}]' if v.source == SOURCE_RIG else ''
        print(f'{bag}: {v.timing()}; falls {v.falls}, recoveries {v.recoveries}, '
              f'alive at the end {v.alive_at_end}{rig}')
        for problem in v.problems:
            print(f'  problem: {problem}')
        if v.problems and status == 0:
            status = 1
    return status


if __name__ == '__main__':
    raise SystemExit(main())
