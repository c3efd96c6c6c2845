"""Pure part of the player: the merged, filtered, remapped schedule and the precise wait."""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import yaml

from .reader import Bag

SPIN_S = 0.0015


@dataclass
class PlayTopic:
    name: str
    out_name: str
    type: str
    qos: list


@dataclass
class Schedule:
    topics: list[PlayTopic]
    topic_index: np.ndarray  # per message
    log_ns: np.ndarray       # per message, bag time
    rel_ns: np.ndarray       # per message, from the first played message
    datas: list

    def __len__(self):
        return len(self.datas)


def schedule(bag: Bag, topics=None, remap: dict | None = None, start_s: float = 0.0) -> Schedule:
    remap = remap or {}
    sel = [n for n in sorted(bag.topics) if bag.topics[n].count and (not topics or n in topics)]
    pts, idxs, times, datas = [], [], [], []
    for i, n in enumerate(sel):
        t = bag.topics[n]
        try:
            qos = yaml.safe_load(t.qos) if t.qos else []
        except yaml.YAMLError:
            qos = []
        pts.append(PlayTopic(n, remap.get(n, n), t.type, qos if isinstance(qos, list) else []))
        idxs.append(np.full(t.count, i, np.int32))
        times.append(t.log_ns())
        datas.extend(t.datas)
    if not sel:
        return Schedule([], np.zeros(0, np.int32), np.zeros(0, np.int64), np.zeros(0, np.int64), [])
    idx = np.concatenate(idxs)
    ts = np.concatenate(times)
    order = np.argsort(ts, kind='stable')
    idx, ts = idx[order], ts[order]
    datas = [datas[k] for k in order]
    if start_s > 0:
        keep = ts >= ts[0] + int(start_s * 1e9)
        first = int(np.argmax(keep)) if keep.any() else len(ts)
        idx, ts, datas = idx[first:], ts[first:], datas[first:]
    rel = ts - ts[0] if len(ts) else ts
    return Schedule(pts, idx, ts, rel, datas)


def wait_until(target: float, stop=None) -> bool:
    """Sleep until shortly before ``target`` (time.monotonic), then busy-wait; True at the
    target, False as soon as ``stop`` (a threading.Event, optional) is set."""
    while True:
        if stop is not None and stop.is_set():
            return False
        dt = target - time.monotonic()
        if dt <= 0:
            return True
        if dt > SPIN_S:
            if stop is None:
                time.sleep(dt - SPIN_S)
            elif stop.wait(dt - SPIN_S):
                return False
