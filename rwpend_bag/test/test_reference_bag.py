"""The committed reference bag (bags/reference/swingup_tap, made by tools/make_reference_bag.sh):
a lockstep simulator run in auto mode -- swing-up, catch, balance -- with a tap of 0.4 rad/s at
7 s. Our reader, analysis and plot, and the `rosbags` and `mcap` readers all read it."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rwpend_bag.analysis import _decode, analyze, plot, wrap
from rwpend_bag.reader import read_bag

BAG = Path(__file__).resolve().parents[2] / 'bags' / 'reference' / 'swingup_tap'
SEQ_TOPICS = ('/rwpend/encoders', '/rwpend/command', '/rwpend/state', '/rwpend/sim/true_state')


def test_reference_bag_is_complete():
    bag = read_bag(BAG)
    for name in SEQ_TOPICS:
        seq = _decode(bag, name, ['seq'])['seq'].astype(np.int64)
        assert len(seq) == 10000 and np.all(np.diff(seq) == 1), name


def test_reference_run_swings_up_balances_and_survives_the_tap(tmp_path):
    m = analyze(BAG)
    assert 2.0 < m['swing_up_time_s'] < 5.0
    assert m['time_to_catch_s'] == pytest.approx(m['swing_up_time_s'], abs=0.1)
    assert m['balance_rms_settled_rad'] < 0.01
    assert m['loop_latency_ms']['matched'] == 10000
    assert m['estimator_gaps'] is None          # recorded before StateEstimate had resyncs/missed
    truth = _decode(read_bag(BAG), '/rwpend/sim/true_state')
    t = (truth['_stamp_ns'] - truth['_stamp_ns'][0]) / 1e9
    err = np.abs(wrap(truth['theta'] - np.pi))
    tap = np.searchsorted(t, 7.0)
    assert truth['theta_dot'][tap + 1] - truth['theta_dot'][tap - 1] == pytest.approx(0.4, abs=0.05)
    assert err[(t > 5.0) & (t < 7.0)].max() < 0.05          # balanced before the tap
    assert err[t > 9.0].max() < 0.05                          # and again after it
    plot(BAG, str(tmp_path / 'ref.png'))
    assert (tmp_path / 'ref.png').stat().st_size > 10_000


def test_reference_bag_opens_with_rosbags_and_mcap():
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore
    with AnyReader([BAG], default_typestore=get_typestore(Stores.EMPTY)) as r:
        conns = [c for c in r.connections if c.topic == '/rwpend/encoders']
        seqs = [r.deserialize(raw, c.msgtype).seq for c, _, raw in r.messages(connections=conns)]
    assert seqs == list(range(10000))
    from mcap_ros2.reader import read_ros2_messages
    mcap = next(BAG.glob('*.mcap'))
    n = sum(1 for m in read_ros2_messages(str(mcap), topics=['/rwpend/command']))
    assert n == 10000
