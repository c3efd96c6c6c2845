"""The tests' domain ids: each pytest-xdist worker its own slice of RWPEND_TEST_DOMAINS."""
import pytest

from rwpend_ros.testenv import test_domain_id, worker_range


def test_each_worker_takes_its_own_slice_of_the_range():
    assert worker_range(100, 230, 'gw0', '2') == (100, 164)
    assert worker_range(100, 230, 'gw1', '2') == (165, 229)
    slices = [worker_range(0, 232, f'gw{i}', '4') for i in range(4)]
    assert all(a[1] < b[0] for a, b in zip(slices, slices[1:]))


def test_without_workers_or_with_too_few_ids_the_whole_range():
    assert worker_range(100, 230, None, None) == (100, 230)
    assert worker_range(100, 230, 'master', '2') == (100, 230)
    assert worker_range(100, 101, 'gw2', '3') == (100, 101)
    assert worker_range(100, 230, 'gw5', '2') == (100, 230)


def test_domain_id_of_a_worker_is_in_its_slice():
    env = {'RWPEND_TEST_DOMAINS': '10-19', 'PYTEST_XDIST_WORKER': 'gw1', 'PYTEST_XDIST_WORKER_COUNT': '2'}
    assert {test_domain_id(env) for _ in range(200)} <= set(range(15, 20))
    with pytest.raises(ValueError, match='expected LO-HI'):
        test_domain_id({'RWPEND_TEST_DOMAINS': 'x'})
