"""``bag info``: topics, types, counts, rates, duration, seq gaps. Pure (no rclpy)."""
from __future__ import annotations

import numpy as np

from . import cdr
from .reader import Bag, read_bag


def seq_gaps(seqs: np.ndarray, max_list: int = 20) -> dict:
    s = np.asarray(seqs, dtype=np.int64)
    if s.size == 0:
        return {'first': None, 'last': None, 'missing': 0, 'gaps': [], 'gap_count': 0,
                'duplicates': 0, 'backwards': 0}
    d = np.diff(s)
    if d.size:
        vals, cnt = np.unique(d[d > 0], return_counts=True)
        stride = int(vals[np.argmax(cnt)]) if vals.size else 1
    else:
        stride = 1
    if stride > 1:  # a decimated echo (e.g. controller status at 100 Hz of a 1 kHz seq)
        return {'first': int(s[0]), 'last': int(s[-1]), 'stride': stride, 'missing': 0,
                'gaps': [], 'gap_count': 0, 'duplicates': int(np.sum(d == 0)),
                'backwards': int(np.sum(d < 0)), 'irregular': int(np.sum(d > stride))}
    jumps = np.nonzero(d > 1)[0]
    gaps = [[int(s[i] + 1), int(s[i + 1] - 1)] for i in jumps]
    return {'first': int(s[0]), 'last': int(s[-1]), 'missing': int(np.sum(d[d > 1] - 1)),
            'gaps': gaps[:max_list], 'gap_count': len(gaps),
            'duplicates': int(np.sum(d == 0)), 'backwards': int(np.sum(d < 0))}


def topic_seqs(topic) -> np.ndarray | None:
    """seq column of a topic (None when its type has no Header+seq)."""
    if not topic.count or not cdr.header_seq_layout(topic.type, topic.schema):
        return None
    try:
        cols, _ = cdr.decode(topic.type, topic.schema, topic.datas, fields=['seq'])
        return cols['seq'].astype(np.int64)
    except Exception:  # noqa: BLE001
        return np.array([cdr.seq_of(d) for d in topic.datas], dtype=np.int64)


def bag_info(bag: Bag | str) -> dict:
    if not isinstance(bag, Bag):
        bag = read_bag(bag)
    rng = bag.time_range()
    out = {'path': str(bag.path), 'files': [str(f) for f in bag.files], 'complete': bag.complete,
           'warnings': list(bag.warnings), 'message_count': bag.message_count,
           'start_ns': rng[0] if rng else None, 'end_ns': rng[1] if rng else None,
           'duration_s': (rng[1] - rng[0]) / 1e9 if rng else 0.0, 'topics': {},
           'log_time': ((bag.metadata or {}).get('custom_data') or {}).get('rwpend.log_time', 'receive')}
    for name in sorted(bag.topics):
        t = bag.topics[name]
        lt = t.log_ns()
        dur = (lt.max() - lt.min()) / 1e9 if t.count > 1 else 0.0
        d = {'type': t.type, 'count': t.count,
             'rate_hz': (t.count - 1) / dur if dur > 0 else 0.0, 'duration_s': dur}
        seqs = topic_seqs(t)
        d['seq'] = seq_gaps(seqs) if seqs is not None else None
        out['topics'][name] = d
    return out


def format_info(info: dict) -> str:
    lines = [f"Bag:        {info['path']}",
             f"Files:      {', '.join(info['files'])}",
             f"Complete:   {'yes' if info['complete'] else 'NO (recovered by scanning)'}",
             f"Duration:   {info['duration_s']:.3f} s",
             'Log times:  ' + ('sim time (lockstep: header stamps, /clock)' if info.get('log_time') == 'sim'
                               else 'receive time'),
             f"Messages:   {info['message_count']}"]
    for w in info['warnings']:
        lines.append(f'Warning:    {w}')
    lines.append('Topics:')
    width = max([len(n) for n in info['topics']] + [10])
    for name, d in info['topics'].items():
        s = d['seq']
        if s is None:
            seqtxt = 'no seq'
        elif s['first'] is None:
            seqtxt = 'empty'
        elif s.get('stride', 1) > 1:
            seqtxt = (f"seq {s['first']}..{s['last']} stride {s['stride']} "
                      f"({s['irregular']} longer steps)")
        elif s['missing'] == 0 and not s['duplicates'] and not s['backwards']:
            seqtxt = f"seq {s['first']}..{s['last']} no gaps"
        else:
            g = ', '.join(f'{a}' if a == b else f'{a}..{b}' for a, b in s['gaps'][:5])
            seqtxt = (f"seq {s['first']}..{s['last']} MISSING {s['missing']} in "
                      f"{s['gap_count']} gap(s) [{g}{' ...' if s['gap_count'] > 5 else ''}]")
            if s['duplicates'] or s['backwards']:
                seqtxt += f", {s['duplicates']} duplicate(s), {s['backwards']} backwards"
        lines.append(f"  {name:<{width}}  {d['type']:<34} {d['count']:>8} msgs "
                     f"{d['rate_hz']:>9.1f} Hz  {seqtxt}")
    return '\n'.join(lines)
