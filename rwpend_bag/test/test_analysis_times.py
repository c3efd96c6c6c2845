"""The analysis's time base on the rig: samples every period, stamps that jitter (no ROS)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from rwpend_bag import analysis
from rwpend_bag.reader import Bag


def test_sample_times_are_seq_times_the_mean_period():
    rng = np.random.default_rng(1)
    seq = np.arange(100, 20100)
    stamps = (seq - 100) * 1e-3 + rng.uniform(0, 1.5e-3, seq.size)   # receive times, 0-1.5 ms late
    stamps[0], stamps[-1] = 0.0, (seq[-1] - 100) * 1e-3
    t = analysis.sample_times(stamps, seq)
    assert np.allclose(np.diff(t), 1e-3)
    assert analysis.sample_times(stamps, None) is stamps
    assert analysis.sample_times(stamps[:1], seq[:1]) is not None


def test_balanced_time_on_jittered_stamps_counts_every_balanced_sample():
    # 5 s hanging, then 20 s upright, stamped by a driver whose reads come in bursts: the median
    # spacing of the stamps is 0.5 ms (it was taken as the period: 10 s balanced)
    n = 25000
    seq = np.arange(n)
    stamps = np.repeat(np.arange(0, n, 2) * 1e-3, 2)[:n] + np.tile([0.0, 5e-4], n // 2)[:n]
    theta = np.where(seq < 5000, 0.0, np.pi)
    state = {'_stamp_ns': (stamps * 1e9).astype(np.int64), 'seq': seq, 'theta': theta,
             'wheel_angle': np.zeros(n), 'wheel_rate': np.zeros(n), '_topic': '/rwpend/state',
             '_log_ns': (stamps * 1e9).astype(np.int64)}
    assert abs(np.median(np.diff(stamps)) - 5e-4) < 1e-9
    m = analysis.analyze(Bag(Path('synthetic'), [], {}, True, {}, []), {'state': state})
    assert abs(m['swing_up_time_s'] - 5.0) < 2e-3
    assert abs(m['balanced_time_s'] - 20.0) < 2e-3
