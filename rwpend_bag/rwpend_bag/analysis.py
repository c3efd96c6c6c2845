"""Analysis of a Reaction Wheel Pendulum run from a bag. Pure (numpy, matplotlib Agg; no rclpy).

Messages are decoded from the bag's embedded ros2msg definitions, column-wise (cdr.py), so bags
recorded elsewhere work too. Topics are found by type (PlantState preferred over StateEstimate
for theta). Times are header stamps, in seconds from the first state sample.
"""
from __future__ import annotations

import math
import time

import numpy as np

from . import cdr
from .reader import Bag, read_bag

U_MAX = 10.0
CATCH_WINDOW = 0.5   # |wrap(theta - pi)| below this counts as "up"
SETTLE_S = 1.0       # s of uninterrupted balance before a sample counts as "settled"
BALANCE_LAWS = ('catch', 'balance')


def _unwrapped_lines(x, y):
    """x, y with a NaN inserted where the wrapped angle x jumps by 2 pi (no line across the plot)."""
    x = np.asarray(x, float)
    y = np.asarray(y, float)[:len(x)]
    x = x[:len(y)]
    cut = np.where(np.abs(np.diff(x)) > np.pi)[0] + 1
    return np.insert(x, cut, np.nan), np.insert(y, cut, np.nan)


def wrap(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def _by_type(bag: Bag, short: str):
    """Topics of a type ('PlantState'), shortest name first."""
    names = [n for n, t in bag.topics.items() if t.type.endswith('/' + short) and t.count]
    return sorted(names, key=len)


def _decode(bag, name, fields=None):
    t = bag.topics[name]
    cols, _ = cdr.decode(t.type, t.schema, t.datas, fields)
    cols['_log_ns'] = t.log_ns()
    if 'header.stamp.sec' in cols:
        cols['_stamp_ns'] = (cols['header.stamp.sec'].astype(np.int64) * 1_000_000_000
                             + cols['header.stamp.nanosec'].astype(np.int64))
    return cols


def load_series(bag: Bag) -> dict:
    """Decode the topics the analysis needs into {'state': cols, 'command': ..., ...}."""
    out = {}
    for key, short in (('truth', 'PlantState'), ('state', 'StateEstimate'),
                       ('command', 'MotorCommand'), ('encoders', 'EncoderCounts'),
                       ('status', 'ControllerStatus')):
        names = _by_type(bag, short)
        if names:
            out[key] = _decode(bag, names[0])
            out[key]['_topic'] = names[0]
    return out


def _first_true(mask):
    idx = np.nonzero(mask)[0]
    return int(idx[0]) if idx.size else None


def _segments(mask):
    """(start, stop) index pairs of runs of True."""
    m = np.concatenate([[False], np.asarray(mask, bool), [False]])
    d = np.diff(m.astype(np.int8))
    return list(zip(np.nonzero(d == 1)[0], np.nonzero(d == -1)[0]))


def limit_cycle(t, wheel_angle, min_cycles=2):
    """Period and amplitude of the wheel oscillation: detrend (linear), upward zero crossings."""
    if len(t) < 10:
        return None
    p = np.polyfit(t - t[0], wheel_angle, 1)
    x = wheel_angle - np.polyval(p, t - t[0])
    up = np.nonzero((x[:-1] < 0) & (x[1:] >= 0))[0]
    if len(up) < min_cycles + 1:
        return None
    # linear interpolation of the crossing instants
    tc = t[up] - x[up] * (t[up + 1] - t[up]) / (x[up + 1] - x[up])
    periods = np.diff(tc)
    periods = periods[periods > 0.02]  # ignore noise re-crossings (< 20 ms)
    if periods.size < min_cycles:
        return None
    seg = x[up[0]:up[-1] + 1]
    return {'period_s': float(np.median(periods)), 'cycles': int(periods.size),
            'amplitude_rad': float((np.max(seg) - np.min(seg)) / 2),
            'amplitude_rms_rad': float(np.sqrt(np.mean(seg ** 2)) * math.sqrt(2)),
            'wheel_drift_rad_s': float(p[0])}


def sample_times(stamps: np.ndarray, seq: np.ndarray | None) -> np.ndarray:
    """The instants of the samples (s from the first): a stamp says when the sample was taken in
    -- on the rig the driver's receive time, which jitters with the serial reads (a median
    spacing of 0.72 ms for a 1 ms period: the balanced time came out 14.8 s for 20.7 s) -- while
    the plant samples every period: seq times the mean period over the run. Without a seq, or
    with no seq span, the stamps."""
    if seq is None or len(stamps) < 2:
        return stamps
    seq = np.asarray(seq).astype(np.int64)
    span = int(seq[-1] - seq[0])
    if span <= 0:
        return stamps
    return (seq - seq[0]) * ((stamps[-1] - stamps[0]) / span) + stamps[0]


def analyze(bag: Bag | str, series: dict | None = None) -> dict:
    """All metrics of a run (dict; None where a metric cannot be computed from this bag)."""
    if not isinstance(bag, Bag):
        bag = read_bag(bag)
    s = series if series is not None else load_series(bag)
    src = 'truth' if 'truth' in s else ('state' if 'state' in s else None)
    m: dict = {'bag': str(bag.path), 'theta_source': s[src]['_topic'] if src else None}
    if src is None:
        m['error'] = 'no PlantState or StateEstimate topic in the bag'
        return m
    st = s[src]
    t0 = int(st['_stamp_ns'][0])
    t = sample_times((st['_stamp_ns'] - t0) / 1e9, st.get('seq'))
    theta = st['theta']
    err = wrap(theta - np.pi)
    m['duration_s'] = float(t[-1] - t[0]) if len(t) else 0.0
    i_up = _first_true(np.abs(err) < CATCH_WINDOW)
    m['swing_up_time_s'] = float(t[i_up]) if i_up is not None else None

    laws, balanced = _law_metrics(s['status'] if 'status' in s else None, t, t0, err, i_up)
    m.update(laws)
    m.update(_balance_metrics(t, err, balanced))
    m.update(_control_metrics(s, st))
    wr = st.get('wheel_rate')
    m['wheel_rate_range_rad_s'] = [float(wr.min()), float(wr.max())] if wr is not None and len(wr) else None

    # wheel limit cycle over the longest balanced segment
    m['limit_cycle'] = None
    segs = _segments(balanced)
    if segs:
        a, b = max(segs, key=lambda ab: ab[1] - ab[0])
        if 'wheel_angle' in st:
            m['limit_cycle'] = limit_cycle(t[a:b], st['wheel_angle'][a:b])

    m['estimator_gaps'] = estimator_gaps(s.get('state'))

    # loop latency: not in a bag logged on the simulated clock (there both receive times are
    # the sample's sim time)
    m['loop_latency_ms'] = None
    m['log_time'] = ((bag.metadata or {}).get('custom_data') or {}).get('rwpend.log_time', 'receive')
    if 'command' in s and 'encoders' in s and m['log_time'] != 'sim':
        m['loop_latency_ms'] = loop_latency(s['encoders'], s['command'])
    return m


def _law_metrics(cs: dict | None, t: np.ndarray, t0: int, err: np.ndarray,
                 i_up: int | None) -> tuple[dict, np.ndarray]:
    """The metrics of the controller's laws from its status ``cs`` (None: not in the bag) --
    time to catch, mode switches, law changes seen, the laws -- and the mask of the samples
    (times ``t`` from ``t0`` ns, angles ``err`` from upright) balanced: up under a balancing
    law (step-hold of the status onto the state time base); without the status, up from the
    first time up ``i_up`` on."""
    m: dict = {}
    if cs is not None:
        ts = (cs['_stamp_ns'] - t0) / 1e9
        laws = cs['law']
        i_catch = _first_true(np.isin(laws, BALANCE_LAWS))
        m['time_to_catch_s'] = float(ts[i_catch]) if i_catch is not None else None
        changes = int(np.sum(laws[1:] != laws[:-1])) + int(np.sum(cs['mode'][1:] != cs['mode'][:-1]))
        sc = cs['switch_count'].astype(np.int64)
        m['mode_switches'] = int(sc[-1] - sc[0]) if len(sc) else 0
        m['law_changes_seen'] = changes
        m['laws'] = sorted(set(laws.tolist()))
        idx = np.searchsorted(ts, t, side='right') - 1
        law_at = np.where(idx >= 0, laws[np.clip(idx, 0, None)], '')
        balanced = np.isin(law_at, BALANCE_LAWS) & (np.abs(err) < CATCH_WINDOW)
    else:
        m['time_to_catch_s'] = None
        m['mode_switches'] = None
        balanced = np.zeros(len(t), bool)
        if i_up is not None:
            balanced[i_up:] = np.abs(err[i_up:]) < CATCH_WINDOW
    return m, balanced


def _balance_metrics(t: np.ndarray, err: np.ndarray, balanced: np.ndarray) -> dict:
    """Time balanced and the RMS angle from upright while balanced: over every balanced sample,
    and after the catch transients (samples balanced for >= SETTLE_S without interruption)."""
    m: dict = {}
    m['balanced_time_s'] = float(np.sum(balanced) * np.median(np.diff(t))) if len(t) > 1 else 0.0
    m['balance_rms_rad'] = float(np.sqrt(np.mean(err[balanced] ** 2))) if balanced.any() else None
    settled = np.zeros(len(t), bool)
    if balanced.any() and len(t) > 1:
        idx = np.arange(len(t))
        starts = np.where(balanced & ~np.r_[False, balanced[:-1]], idx, 0)
        run = idx - np.maximum.accumulate(starts)
        settled = balanced & (run * np.median(np.diff(t)) >= SETTLE_S)
    m['balance_rms_settled_rad'] = float(np.sqrt(np.mean(err[settled] ** 2))) if settled.any() else None
    return m


def _control_metrics(s: dict, st: dict) -> dict:
    """RMS of the command and the fraction of samples at |u| = U_MAX, from the ``command``
    topic, else the command the state message carries (None where neither is)."""
    m: dict = {}
    if 'command' in s:
        u = s['command']['u']
    elif 'u_commanded' in st:
        u = st['u_commanded']
    else:
        u = None
    if u is not None and len(u):
        m['control_rms'] = float(np.sqrt(np.mean(u ** 2)))
        m['saturation_fraction'] = float(np.mean(np.abs(u) >= U_MAX - 1e-9))
    else:
        m['control_rms'] = m['saturation_fraction'] = None
    return m


def loop_latency(enc: dict, cmd: dict) -> dict | None:
    """Loop latency (ms): the command's receive time minus the encoders' of the same seq;
    percentiles and counts (None when no command matches a sample of the encoders)."""
    es, el = enc['seq'].astype(np.int64), enc['_log_ns']
    cseq, cl = cmd['seq'].astype(np.int64), cmd['_log_ns']
    order = np.argsort(es, kind='stable')
    pos = np.searchsorted(es[order], cseq)
    ok = pos < len(es)
    ok[ok] &= es[order][pos[ok]] == cseq[ok]
    if not ok.any():
        return None
    lat = (cl[ok] - el[order][pos[ok]]) / 1e6
    return {'p50': float(np.percentile(lat, 50)), 'p99': float(np.percentile(lat, 99)),
            'max': float(lat.max()), 'matched': int(ok.sum()),
            'commands': int(len(cseq)), 'encoders': int(len(es))}


def estimator_gaps(state: dict | None) -> dict | None:
    """Re-synchronisations of the estimator and the samples it missed, from StateEstimate's
    ``resyncs`` / ``missed`` (None for a bag without them, e.g. recorded before they existed)."""
    if state is None or 'resyncs' not in state or not len(state['resyncs']):
        return None
    r = state['resyncs'].astype(np.int64)
    missed = state['missed'].astype(np.int64)
    changes = int(np.count_nonzero(np.diff(r)))
    return {'resyncs': changes + int(r[0]), 'missed': int(missed.sum()),
            'longest_gap': int(missed.max()), 'gaps': int(np.count_nonzero(missed))}


def format_metrics(m: dict) -> str:
    def f(v, unit='', fmt='{:.3f}'):
        return 'n/a' if v is None else fmt.format(v) + unit
    lc = m.get('limit_cycle')
    lat = m.get('loop_latency_ms')
    lines = [f"Bag:                  {m['bag']}",
             f"theta from:           {m.get('theta_source')}",
             f"duration:             {f(m.get('duration_s'), ' s')}",
             f"swing-up time:        {f(m.get('swing_up_time_s'), ' s')}",
             f"time to catch:        {f(m.get('time_to_catch_s'), ' s')}",
             f"balanced time:        {f(m.get('balanced_time_s'), ' s')}",
             f"balance RMS theta-pi: {f(m.get('balance_rms_rad'), ' rad', '{:.5f}')}",
             f"  after {SETTLE_S:g} s settled: {f(m.get('balance_rms_settled_rad'), ' rad', '{:.5f}')}",
             f"control RMS:          {f(m.get('control_rms'), ' units')}",
             f"saturation fraction:  {f(m.get('saturation_fraction'), '', '{:.4f}')}",
             'wheel rate range:     ' + ('n/a' if not m.get('wheel_rate_range_rad_s') else
                                         '{:.2f} .. {:.2f} rad/s'.format(*m['wheel_rate_range_rad_s'])),
             'limit cycle:          ' + ('n/a' if not lc else
                                         f"period {lc['period_s']:.3f} s, amplitude "
                                         f"{lc['amplitude_rad']:.4f} rad ({lc['cycles']} cycles)"),
             f"mode switches:        {m.get('mode_switches') if m.get('mode_switches') is not None else 'n/a'}",
             'estimator gaps:       ' + ('n/a' if not m.get('estimator_gaps') else
                                         '{resyncs} re-synchronisations, {missed} samples missed in {gaps} '
                                         'gaps (longest {longest_gap})'.format(**m['estimator_gaps'])),
             'loop latency:         ' + (('n/a (log times are sim time)' if m.get('log_time') == 'sim'
                                          else 'n/a') if not lat else
                                         f"p50 {lat['p50']:.3f} ms, p99 {lat['p99']:.3f} ms, "
                                         f"max {lat['max']:.3f} ms ({lat['matched']} matched)")]
    if m.get('error'):
        lines.append(f"error: {m['error']}")
    return '\n'.join(lines)


def plot(bag: Bag | str, out_file: str, series: dict | None = None) -> None:
    """Book-style figure: theta, theta', wheel rate, u, law, energy vs time; phase portrait."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    if not isinstance(bag, Bag):
        bag = read_bag(bag)
    s = series if series is not None else load_series(bag)
    src = 'truth' if 'truth' in s else 'state'
    if src not in s:
        raise ValueError('no PlantState or StateEstimate topic to plot')
    st = s[src]
    t0 = int(st['_stamp_ns'][0])
    t = (st['_stamp_ns'] - t0) / 1e9
    fig = plt.figure(figsize=(11, 12))
    gs = fig.add_gridspec(6, 2, width_ratios=[2.2, 1])
    axes = [fig.add_subplot(gs[i, 0]) for i in range(6)]
    for ax in axes[1:]:
        ax.sharex(axes[0])
    axes[0].plot(t, st['theta'], lw=0.8)
    axes[0].axhline(np.pi, color='k', ls=':', lw=0.6)
    axes[0].set_ylabel(r'$\theta$ [rad]')
    axes[1].plot(t, st['theta_dot'], lw=0.8)
    axes[1].set_ylabel(r"$\dot\theta$ [rad/s]")
    axes[2].plot(t, st['wheel_rate'], lw=0.8)
    axes[2].set_ylabel(r'$\dot\theta_r$ [rad/s]')
    if 'command' in s:
        axes[3].plot((s['command']['_stamp_ns'] - t0) / 1e9, s['command']['u'], lw=0.6)
    elif 'u_commanded' in st:
        axes[3].plot(t, st['u_commanded'], lw=0.6)
    axes[3].set_ylabel('u')
    axes[3].set_ylim(-11, 11)
    if 'status' in s:
        cs = s['status']
        laws = cs['law']
        names = sorted(set(laws.tolist()))
        axes[4].step((cs['_stamp_ns'] - t0) / 1e9, [names.index(x) for x in laws], where='post')
        axes[4].set_yticks(range(len(names)), names)
    axes[4].set_ylabel('law')
    if 'state' in s and 'energy' in s['state']:
        e_t = (s['state']['_stamp_ns'] - t0) / 1e9
        energy = s['state']['energy']
    else:
        e_t, energy = t, 1 - np.cos(st['theta'])
    axes[5].plot(e_t, energy, lw=0.8)
    axes[5].axhline(2.0, color='k', ls=':', lw=0.6)
    axes[5].set_ylabel('E')
    axes[5].set_xlabel('t [s]')
    for ax in axes:
        ax.grid(alpha=0.3)
    ph = fig.add_subplot(gs[0:3, 1])
    ph.plot(*_unwrapped_lines(wrap(st['theta'] - np.pi) + np.pi, st['theta_dot']), lw=0.5)
    ph.set_xlabel(r'$\theta$ [rad] (wrapped)')
    ph.set_ylabel(r'$\dot\theta$ [rad/s]')
    ph.set_title('phase portrait')
    ph.grid(alpha=0.3)
    en = fig.add_subplot(gs[3:6, 1])
    en.plot(*_unwrapped_lines(wrap(st['theta'] - np.pi) + np.pi,
                              1 - np.cos(st['theta']) if src == 'truth' else energy[:len(t)]), lw=0.5)
    en.set_xlabel(r'$\theta$ [rad] (wrapped)')
    en.set_ylabel('E' if src != 'truth' else r'$1-\cos\theta$')
    en.set_title('energy vs angle')
    en.grid(alpha=0.3)
    fig.suptitle(f'Reaction wheel pendulum run: {bag.path.name}')
    fig.tight_layout()
    fig.savefig(out_file, dpi=110)
    plt.close(fig)


def bench_decode(bag: Bag | str, repeat: int = 3) -> dict:
    """Decode throughput: every topic of the bag, column-wise (best of ``repeat``)."""
    t_read = time.perf_counter()
    if not isinstance(bag, Bag):
        bag = read_bag(bag)
    t_read = time.perf_counter() - t_read
    best = None
    per_topic = {}
    for _ in range(max(1, repeat)):
        t1 = time.perf_counter()
        for name, t in bag.topics.items():
            if not t.count:
                continue
            _, bulk = cdr.decode(t.type, t.schema, t.datas)
            per_topic[name] = {'count': t.count, 'bulk': bulk}
        dt = time.perf_counter() - t1
        best = dt if best is None else min(best, dt)
    n = sum(v['count'] for v in per_topic.values())
    return {'messages': n, 'decode_s': best, 'msgs_per_s': n / best if best else float('inf'),
            'read_s': t_read if t_read > 1e-4 else None,
            'read_msgs_per_s': n / t_read if t_read > 1e-4 else None, 'topics': per_topic}
