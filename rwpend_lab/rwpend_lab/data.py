"""The signals of one run, aligned by sample, from a bag (or made by :mod:`rwpend_lab.twin`). No rclpy.

Every array is indexed by sample k (t = k h from the first encoder sample): the encoder counts
of sample k, the estimate of sample k, the command answering sample k (sent for
[t_k, t_k+1)), the command the plant held over [t_k, t_k+1) (``u_held``), and -- on the
simulator -- the true state at t_k.  Samples a topic lacks are NaN.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

#: The fields kept of each topic: {key: (message type, {field: name in RunData})}
TOPICS = {
    'encoders': ('EncoderCounts', {'pendulum_counts': 'pc', 'motor_counts': 'mc'}),
    'state': ('StateEstimate', {'theta': 'theta', 'theta_dot': 'theta_dot', 'wheel_angle': 'wheel_angle',
                                'wheel_rate': 'wheel_rate', 'friction': 'friction'}),
    'command': ('MotorCommand', {'u': 'u'}),
    'truth': ('PlantState', {'theta': 'true_theta', 'theta_dot': 'true_theta_dot',
                             'wheel_angle': 'true_wheel_angle', 'wheel_rate': 'true_wheel_rate',
                             'u_commanded': 'true_u_commanded', 'u_applied': 'torque', 'friction': 'true_friction',
                             'disturbance': 'disturbance'}),
}


@dataclass
class RunData:
    """Sampled signals of one run (rad, rad/s, control units; counts as floats, NaN if missing)."""

    h: float
    t: np.ndarray
    pc: np.ndarray
    mc: np.ndarray
    u: np.ndarray
    theta: np.ndarray
    theta_dot: np.ndarray
    wheel_angle: np.ndarray
    wheel_rate: np.ndarray
    friction: np.ndarray
    truth: dict = field(default_factory=dict)        # true_theta, ..., torque, disturbance (sim)
    switches: list = field(default_factory=list)     # (t, mode, law, reason) from controller/status
    # (t, fault_code, fault) from controller/status: the code one of ControllerStatus's FAULT_*
    # (rwpend_control.status_codes; None in a bag recorded before the codes), the text for people
    faults: list = field(default_factory=list)
    seq0: int = 0                                    # the plant's seq of sample 0
    #: the command the plant held over [t_k, t_k+1) -- what the motor got: the driver's
    #: ``applied`` on the rig, sim/true_state on the simulator; None when the bag has neither
    u_held: np.ndarray | None = None

    @property
    def n(self) -> int:
        return len(self.t)

    def window(self, t0: float, t1: float) -> slice:
        """Samples with t0 <= t < t1."""
        return slice(int(np.searchsorted(self.t, t0 - 1e-9)), int(np.searchsorted(self.t, t1 - 1e-9)))


def _short(type_name: str) -> str:
    return type_name.rsplit('/', 1)[-1]


def load_run(bag_path, h: float) -> RunData:
    """RunData of a bag recorded by the lab (any namespace); ValueError if it has no encoders."""
    from rwpend_bag import cdr
    from rwpend_bag.reader import read_bag
    bag = read_bag(Path(bag_path))
    cols: dict[str, dict] = {}
    for key, (short, _) in TOPICS.items():
        names = sorted((n for n, t in bag.topics.items() if _short(t.type) == short and t.count), key=len)
        if names:
            t = bag.topics[names[0]]
            cols[key], _ = cdr.decode(t.type, t.schema, t.datas, None)
    if 'encoders' not in cols:
        raise ValueError(f'{bag_path}: no encoder samples in the bag')
    seq0 = int(cols['encoders']['seq'][0])
    n = int(cols['encoders']['seq'][-1]) - seq0 + 1
    out: dict[str, np.ndarray] = {}
    for key, (_, names) in TOPICS.items():
        c = cols.get(key)
        for fname, name in names.items():
            arr = np.full(n, np.nan)
            if c is not None:
                idx = c['seq'].astype(np.int64) - seq0
                ok = (idx >= 0) & (idx < n)
                arr[idx[ok]] = c[fname][ok].astype(float)
            out[name] = arr
    truth = {k: out.pop(k) for k in list(out) if k.startswith('true_') or k in ('torque', 'disturbance')}
    if 'truth' not in cols:
        truth = {}
    u_held = _held(bag, seq0, n, cols.get('truth'))
    switches, faults = _status(bag, seq0, h)
    return RunData(h=h, t=np.arange(n) * h, truth=truth, switches=switches, faults=faults, seq0=seq0,
                   u_held=u_held, **out)


def _held(bag, seq0: int, n: int, truth) -> np.ndarray | None:
    """u held over [t_k, t_k+1), from the message of sample k+1 that reports it (the driver's
    AppliedCommand, else the simulator's PlantState u_commanded); None without either."""
    from rwpend_bag import cdr
    names = sorted((nm for nm, t in bag.topics.items() if _short(t.type) == 'AppliedCommand' and t.count), key=len)
    if names:
        t = bag.topics[names[0]]
        c, _ = cdr.decode(t.type, t.schema, t.datas, None)
        seq, u = c['seq'], c['u']
    elif truth is not None:
        seq, u = truth['seq'], truth['u_commanded']
    else:
        return None
    out = np.full(n, np.nan)
    idx = np.asarray(seq).astype(np.int64) - 1 - seq0
    ok = (idx >= 0) & (idx < n)
    out[idx[ok]] = np.asarray(u)[ok].astype(float)
    return out


ARRAYS = ('pc', 'mc', 'u', 'theta', 'theta_dot', 'wheel_angle', 'wheel_rate', 'friction')


def first_command(d: RunData, seq: int, within_s: float = 0.5) -> int:
    """The seq of the first sample at or after ``seq`` whose command is not zero (within
    ``within_s``), else ``seq``: where a law switched on at ``seq`` really started."""
    k = seq - d.seq0
    n = int(round(within_s / d.h))
    if not 0 <= k < d.n:
        return seq
    u = np.nan_to_num(d.u[k:k + n])
    hit = np.nonzero(u != 0.0)[0]
    return seq + int(hit[0]) if hit.size else seq


def trim(d: RunData, origin_seq: int, duration: float) -> RunData:
    """The samples of ``d`` from the plant's seq ``origin_seq`` on, ``duration`` s of them, as a
    run of their own (t = 0 at the origin): a rig run cut to what the simulator run holds. The
    motor counts are counted from the origin, as in a simulator run (the rotor's zero relative to
    the pendulum is wherever an earlier run left it). ValueError when the bag does not cover the
    origin."""
    k0 = origin_seq - d.seq0
    n = int(round(duration / d.h))
    if not 0 <= k0 < d.n:
        raise ValueError(f'the bag holds seq {d.seq0}..{d.seq0 + d.n - 1}, not the origin {origin_seq}')
    sl = slice(k0, min(k0 + n, d.n))
    t0 = k0 * d.h
    return RunData(h=d.h, t=d.t[sl] - t0, truth={k: v[sl] for k, v in d.truth.items()},
                   switches=[(t - t0, *rest) for t, *rest in d.switches],
                   faults=[(t - t0, *rest) for t, *rest in d.faults], seq0=origin_seq,
                   u_held=None if d.u_held is None else d.u_held[sl],
                   **{name: getattr(d, name)[sl] for name in ARRAYS if name != 'mc'},
                   mc=d.mc[sl] - (d.mc[k0] if np.isfinite(d.mc[k0]) else 0.0))


def _status(bag, seq0: int, h: float) -> tuple[list, list]:
    """Mode/law changes and faults reported on controller/status (:attr:`RunData.switches`,
    :attr:`RunData.faults`)."""
    from rwpend_bag import cdr
    names = [n for n, t in bag.topics.items() if _short(t.type) == 'ControllerStatus' and t.count]
    if not names:
        return [], []
    t = bag.topics[sorted(names, key=len)[0]]
    c, _ = cdr.decode(t.type, t.schema, t.datas, None)
    switches, faults = [], []
    last = None
    codes = c.get('fault_code')         # a bag recorded before ControllerStatus had codes: none
    for i in range(len(c['seq'])):
        ts = (int(c['seq'][i]) - seq0) * h
        key = (str(c['mode'][i]), str(c['law'][i]))
        if key != last:
            switches.append((ts, key[0], key[1], str(c['reason'][i])))
            last = key
        if str(c['fault'][i]):
            faults.append((ts, None if codes is None else int(codes[i]), str(c['fault'][i])))
    return switches, faults
