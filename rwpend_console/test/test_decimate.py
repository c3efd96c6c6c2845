"""Decimation by sample time and rate limiting by the receiver's clock."""
import pytest

from rwpend_console.decimate import Decimator, RateLimiter


def test_one_sample_per_period_of_sample_time_on_a_grid():
    d = Decimator(50.0)                       # 20 ms
    kept = [k for k in range(1000) if d.admit(k * 1_000_000)]   # 1 kHz for 1 s
    assert kept == list(range(0, 1000, 20))
    assert (d.seen, d.kept) == (1000, 50)


def test_jitter_and_gaps_keep_the_first_sample_at_or_after_each_grid_point():
    d = Decimator(10.0)                       # 100 ms
    stamps = [0, 50, 99, 101, 150, 350, 351, 400]
    kept = [s for s in stamps if d.admit(s * 1_000_000)]
    assert kept == [0, 101, 350, 400]


def test_stamps_going_back_a_second_start_again():
    d = Decimator(10.0)
    assert d.admit(5_000_000_000)
    assert not d.admit(5_050_000_000)
    assert d.admit(1_000_000)                # a new run (simulator restarted at t = 0)
    assert not d.admit(2_000_000)


@pytest.mark.parametrize('rate', [0, -1, float('nan'), '50', 1e7])
def test_bad_rates_are_refused(rate):
    with pytest.raises(ValueError):
        Decimator(rate)


def test_rate_limiter_by_arrival_time():
    r = RateLimiter(100.0)                    # 10 ms, bursts of 1
    arrivals = [0, 1, 9, 10, 12, 25, 26, 40]
    passed = [t for t in arrivals if r.admit(t * 1_000_000)]
    assert passed == [0, 10, 25, 40]
    assert (r.passed, r.dropped) == (4, 4)


def test_a_fast_topic_comes_down_to_the_rate_bursts_of_slow_publishers_pass():
    r = RateLimiter(100.0, burst=10)
    passed = sum(r.admit(k * 1_000_000) for k in range(10_000))      # 1 kHz for 10 s
    assert 1000 <= passed <= 1010
    d = RateLimiter(100.0, burst=10)
    # four nodes publishing /diagnostics once a second, within a millisecond of each other
    times = [s * 1_000_000_000 + i * 200_000 for s in range(10) for i in range(4)]
    assert all(d.admit(t) for t in times)


def test_rate_limiter_zero_passes_everything():
    r = RateLimiter(0)
    assert all(r.admit(t) for t in range(100))
    for bad in ((-5,), (10, 0), (10, 1.5)):
        with pytest.raises(ValueError):
            RateLimiter(*bad)
