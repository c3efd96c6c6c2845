"""Domain ids and ports for tests (pure): every test that starts ROS takes a random ROS_DOMAIN_ID
from ``RWPEND_TEST_DOMAINS`` (``LO-HI``, default ``100-230``), so test runs side by side on one
host can be kept apart by giving each its own range (the workers of one ``pytest -n N`` run each
take their own slice of it: :func:`worker_range`); a server under test gets a free port; the
processes a test started are stopped as Ctrl-C stops them."""
from __future__ import annotations

import os
import random
import signal
import socket
import subprocess


def test_domain_id(env=None) -> int:
    """A random domain id of ``RWPEND_TEST_DOMAINS`` (ValueError when malformed), of this
    pytest-xdist worker's slice of it (:func:`worker_range`) when the tests run on several."""
    source = os.environ if env is None else env
    text = source.get('RWPEND_TEST_DOMAINS', '100-230')
    try:
        lo, hi = (int(v) for v in text.split('-'))
    except ValueError:
        raise ValueError(f'RWPEND_TEST_DOMAINS={text!r}: expected LO-HI, e.g. 100-230') from None
    if not 0 <= lo <= hi <= 232:
        raise ValueError(f'RWPEND_TEST_DOMAINS={text!r}: ids must be in 0..232, LO <= HI')
    lo, hi = worker_range(lo, hi, source.get('PYTEST_XDIST_WORKER', os.environ.get('PYTEST_XDIST_WORKER')),
                          source.get('PYTEST_XDIST_WORKER_COUNT', os.environ.get('PYTEST_XDIST_WORKER_COUNT')))
    return random.SystemRandom().randint(lo, hi)


def worker_range(lo: int, hi: int, worker: str | None, count: str | None) -> tuple[int, int]:
    """Worker ``gwI`` of ``count`` pytest-xdist workers: the I-th of ``count`` equal slices of
    [lo, hi] (two tests that run at once never share a domain); the whole range without
    workers, or when the range has fewer ids than workers."""
    try:
        i, n = int(str(worker).removeprefix('gw')), int(count)
    except (TypeError, ValueError):
        return lo, hi
    size = (hi - lo + 1) // n if n > 0 else 0
    if size < 1 or not 0 <= i < n:
        return lo, hi
    return lo + i * size, lo + (i + 1) * size - 1


test_domain_id.__test__ = False     # not a pytest test


def free_port() -> int:
    """A TCP port on 127.0.0.1 that is free now (the OS's choice)."""
    with socket.socket() as s:
        s.bind(('127.0.0.1', 0))
        return s.getsockname()[1]


def stop_processes(procs, timeout: float = 60.0) -> None:
    """Stop processes as Ctrl-C does: SIGINT to each still running, the last started first (all
    before any is waited for, so they shut down side by side), then each waited for; one still
    running ``timeout`` s later is killed."""
    for p in reversed(procs):
        if p.poll() is None:
            p.send_signal(signal.SIGINT)
    for p in procs:
        try:
            p.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()
