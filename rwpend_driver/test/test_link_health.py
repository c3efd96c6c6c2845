"""How the link's health is judged: sample delays on the device's clock, findings and their levels."""
from __future__ import annotations

import pytest

from rwpend_driver import link_health as H


def test_delay_meter_measures_above_the_fastest_transfer():
    m = H.DelayMeter(drift_ppm=0.0)
    offset = 5_000_000.0                         # the two clocks differ by 5 s
    delays = [m.delay_us(k * 1000, offset + k * 1000 + extra) for k, extra in
              enumerate([300, 250, 900, 250, 4250])]
    assert delays == pytest.approx([0, 0, 650, 0, 4000])


def test_delay_meter_unwraps_the_device_clock_and_resets_on_restart():
    m = H.DelayMeter(drift_ppm=0.0)
    t0 = 0xFFFFFFFF - 1500
    assert m.delay_us(t0, 100.0) == 0.0
    assert m.delay_us((t0 + 1000) & H.MASK32, 1100.0) == pytest.approx(0.0)
    assert m.delay_us((t0 + 2000) & H.MASK32, 2600.0) == pytest.approx(500.0)    # across the wrap
    assert m.delay_us(10, 9_000.0) == 0.0        # the device clock went back: a new floor


def test_delay_meter_follows_a_drifting_device_clock():
    """A device clock 100 ppm slow would look like a delay growing by 0.1 ms per second; the
    floor rises with it (200 ppm allowed), so after a minute the delay is still ~0."""
    m = H.DelayMeter(drift_ppm=200.0)
    worst = 0.0
    for k in range(60_000):
        dev = k * 1000
        worst = max(worst, m.delay_us(dev, 7.0 + dev * (1 + 100e-6)))
    assert worst < 200.0
    with pytest.raises(ValueError):
        H.DelayMeter(drift_ppm=-1)


def counters(**kw):
    base = {'samples': 0, 'samples_lost': 0, 'frames_lost': 0, 'late_samples': 0, 'rx.bad_crc': 0,
            'device_rx_bad': 0, 'tx_dropped': 0, 'watchdog_trips': 0, 'old_commands': 0,
            'stale_commands': 0}
    return {**base, **kw}


def test_a_clean_window_has_no_findings():
    assert H.assess(counters(), counters(samples=500, late_samples=2), 0.5) == []
    assert H.level_of([]) == H.OK


def test_lost_samples_warn_then_error_with_the_advice():
    f = H.assess(counters(), counters(samples=500, samples_lost=2, frames_lost=2), 0.5)
    assert [(x.kind, x.level) for x in f] == [('lost', H.WARN)]
    assert '2 samples' in f[0].what and '--rt-priority' in f[0].advice
    f = H.assess(counters(), counters(samples=500, samples_lost=20, frames_lost=20), 0.5)
    assert H.level_of(f) == H.ERROR


def test_late_samples_judged_by_share():
    assert H.assess(counters(), counters(samples=1000, late_samples=10), 1.0) == []
    f = H.assess(counters(), counters(samples=1000, late_samples=50), 1.0, max_delay_ms=12.5)
    assert [(x.kind, x.level) for x in f] == [('late', H.WARN)] and '12.5 ms' in f[0].what
    f = H.assess(counters(), counters(samples=1000, late_samples=200), 1.0)
    assert H.level_of(f) == H.ERROR


def test_device_refusals_corruption_and_tx_drops():
    f = H.assess(counters(device_rx_bad=3), counters(samples=500, device_rx_bad=5, **{'rx.bad_crc': 1}), 0.5)
    kinds = {x.kind: x for x in f}
    assert set(kinds) == {'refused', 'corrupt'}
    assert 'refused 2 frames' in kinds['refused'].what and 'cable' in kinds['refused'].advice
    f = H.assess(counters(), counters(samples=500, tx_dropped=1), 0.5)
    assert f[0].kind == 'tx' and f[0].level == H.ERROR


def test_counters_that_restart_are_not_negative():
    """A new link (configure again) starts its counters at 0: no finding from the drop."""
    assert H.assess(counters(samples=9000, samples_lost=7), counters(samples=10), 0.5) == []


def test_throttle_logs_each_kind_once_per_interval():
    t = H.Throttle(interval=10.0)
    lost = H.Finding(H.WARN, 'lost', 'x', 'y')
    late = H.Finding(H.WARN, 'late', 'x', 'y')
    assert t.due([lost], 0.0) == [lost]
    assert t.due([lost, late], 5.0) == [late]
    assert t.due([lost, late], 10.0) == [lost]
    assert t.due([lost, late], 15.0) == [late]


def test_histogram_percentiles():
    h = H.Histogram(bin_ms=0.1, top_ms=10.0)
    assert h.percentile(50) == 0.0 and h.summary()['n'] == 0
    for ms in [0.25] * 98 + [3.05, 42.0]:
        h.add(ms)
    assert h.percentile(50) == pytest.approx(0.3)
    assert h.percentile(99) == pytest.approx(3.1)
    assert h.percentile(100) == 42.0 and h.max == 42.0
    assert h.summary() == {'n': 100, 'p50_ms': 0.3, 'p99_ms': 3.1, 'max_ms': 42.0}
    with pytest.raises(ValueError):
        H.Histogram(bin_ms=0)
