"""One controller per rig (rwpend_ros.claim) and the order gates per sender (rwpend_ros.order)."""
from __future__ import annotations

import pytest

from rwpend_ros.claim import CommandClaim, format_id
from rwpend_ros.order import SourceGates

A, B = 0xA, 0xB
YES, NO = (lambda: True), (lambda: False)


def test_the_first_controller_claims_and_others_are_refused():
    c = CommandClaim(timeout_samples=3)
    assert c.admit(A, 10, YES) and c.event == 'claimed' and c.holder == A
    assert not c.admit(B, 10, YES) and c.event == 'refused'
    assert not c.admit(B, 11, YES) and c.event is None, 'an intruder is said once'
    assert c.admit(A, 11, YES) and c.event is None
    assert (c.refused, c.intruder, c.claims) == (2, B, 1)
    assert c.intruding(12, within=1000) and not c.intruding(2000, within=1000)


def test_an_intruders_command_is_never_offered_to_the_plant():
    c = CommandClaim(3)
    c.admit(A, 0, YES)
    offered = []
    assert not c.admit(B, 1, lambda: offered.append(1) or True) and not offered


def test_handed_over_after_the_holder_is_silent_for_the_timeout():
    c = CommandClaim(timeout_samples=3)
    c.admit(A, 10, YES)
    assert not c.admit(B, 12, YES), 'two samples of silence: still held'
    assert c.admit(B, 13, YES) and c.holder == B and c.lapses == 1 and c.event == 'claimed'
    assert not c.admit(A, 14, YES) and c.event == 'refused', 'the first one is now the intruder'


def test_a_holder_that_keeps_sending_keeps_the_rig():
    """Its commands too late to be taken (the plant holds the motor at zero): still its rig."""
    c = CommandClaim(timeout_samples=3)
    assert c.admit(A, 10, YES)
    for k in range(11, 40):
        assert not c.admit(A, k, NO)
        assert not c.admit(B, k, YES)
    assert c.holder == A and c.lapses == 0 and c.refused == 29


def test_commands_the_plant_does_not_take_claim_nothing():
    """Two controllers whose commands both come too late do not pass the rig back and forth."""
    c = CommandClaim(timeout_samples=3)
    for k in range(10):
        assert not c.admit(A if k % 2 else B, k, NO)
    assert c.holder is None and c.claims == 0 and c.refused == 0


def test_release_hands_over_at_once():
    c = CommandClaim(timeout_samples=3)
    c.admit(A, 10, YES)
    assert not c.admit(A, 11, YES, release=True) and c.event == 'released' and c.holder is None
    assert c.admit(B, 11, YES) and c.holder == B and c.releases == 1 and c.lapses == 0
    assert not c.admit(A, 12, YES, release=True), "an intruder's release changes nothing"
    assert c.holder == B and c.event is None


def test_claim_values_and_ids():
    c = CommandClaim(3)
    assert c.values()['claimed_by'] == 'none'
    c.admit(2**63 - 1, 0, YES)
    assert c.values()['claimed_by'] == '0x7fffffffffffffff' and format_id(None) == 'none'
    with pytest.raises(ValueError):
        CommandClaim(0)
    with pytest.raises(ValueError):
        CommandClaim(True)


def test_source_gates_take_each_senders_stream_once_and_in_order():
    g = SourceGates()
    # two controllers answer the same samples with the same seq and stamp
    assert g.admit(A, 1, 100) and g.admit(B, 1, 100)
    assert not g.admit(A, 1, 100), 'the same message again: a duplicate'
    assert g.admit(A, 2, 200) and g.admit(B, 3, 300) and not g.admit(B, 2, 200)
    c = g.counters()
    assert (c['taken'], c['duplicates'], c['stale']) == (4, 1, 1)
    assert 'senders 2' in g.summary()


def test_source_gates_are_bounded_and_keep_the_counts():
    g = SourceGates(max_sources=2)
    for source in range(5):
        g.admit(source, 1, 1)
    assert len(g.gates) == 2 and g.evicted == 3 and g.counters()['taken'] == 5
    assert '+3 forgotten' in g.summary()
    with pytest.raises(ValueError):
        SourceGates(0)

