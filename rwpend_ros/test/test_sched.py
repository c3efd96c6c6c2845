"""Process scheduling helpers (pure): the PM QoS CPU wake-up latency request."""
from __future__ import annotations

import os
import sys

import pytest

from rwpend_ros.sched import CpuLatencyRequest


def test_request_writes_the_value_and_holds_the_file_until_closed(tmp_path):
    dev = tmp_path / 'cpu_dma_latency'
    dev.write_bytes(b'')
    with CpuLatencyRequest(0, path=str(dev)) as req:
        assert req.active and req.status.startswith('0 µs')
        # what the kernel reads: one native s32
        assert int.from_bytes(dev.read_bytes(), sys.byteorder, signed=True) == 0
    assert not req.active
    req.close()                      # closing twice is harmless


def test_value_in_microseconds(tmp_path):
    dev = tmp_path / 'cpu_dma_latency'
    dev.write_bytes(b'')
    req = CpuLatencyRequest(20, path=str(dev))
    try:
        assert int.from_bytes(dev.read_bytes(), sys.byteorder, signed=True) == 20
        assert req.status == '20 µs'
    finally:
        req.close()


def test_not_permitted_or_missing_is_a_status_not_an_error(tmp_path):
    req = CpuLatencyRequest(0, path=str(tmp_path / 'missing'))
    assert not req.active and req.status.startswith('not made') and 'missing' in req.status
    req.close()


@pytest.mark.parametrize('bad', [-1, 1.5, '0', None, 2**31])
def test_bad_value_refused(bad, tmp_path):
    with pytest.raises(ValueError, match='wake-up latency'):
        CpuLatencyRequest(bad, path=str(tmp_path / 'x'))


def test_no_option_no_request():
    from rwpend_ros.sched import request_cpu_latency
    with request_cpu_latency(None) as req:
        assert req.us is None and not req.active and req.status == 'none'


def test_cpu_affinity_reaches_the_threads_started_before(tmp_path):
    """RWPEND_CPUS pins every thread of the process: those started before apply_scheduling
    (numpy's BLAS workers start at import) and those after (DDS's). In a child process: the
    test's own affinity is left alone."""
    import subprocess
    import textwrap
    code = textwrap.dedent('''
        import os, threading, time
        from rwpend_ros.sched import apply_scheduling
        ev = threading.Event()
        before = threading.Thread(target=ev.wait, daemon=True)
        before.start()
        done = apply_scheduling({'RWPEND_CPUS': '0'})
        after = threading.Thread(target=ev.wait, daemon=True)
        after.start()
        time.sleep(0.05)
        sets = {tid: sorted(os.sched_getaffinity(int(tid))) for tid in os.listdir('/proc/self/task')}
        print(done['cpus'], len(sets), all(v == [0] for v in sets.values()))
        ev.set()
    ''')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    cpus, n, pinned = out.stdout.rsplit(' ', 2)
    assert cpus == '[0]' and int(n) >= 3 and pinned.strip() == 'True', out.stdout


def test_raise_thread_priority_only_for_real_time_threads():
    """An ordinary thread stays ordinary; a SCHED_FIFO one (where permitted) goes one above its
    process, in that thread only."""
    import threading

    from rwpend_ros.sched import raise_thread_priority
    out = {}
    t = threading.Thread(target=lambda: out.setdefault('plain', raise_thread_priority()))
    t.start()
    t.join()
    assert out['plain'] == 'not real-time'

    def fifo():
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(10))
        except OSError:
            out['fifo'] = 'skip'
            return
        out['fifo'] = raise_thread_priority()
        out['after'] = os.sched_getparam(0).sched_priority
    t = threading.Thread(target=fifo)
    t.start()
    t.join()
    if out['fifo'] == 'skip':
        pytest.skip('SCHED_FIFO not permitted here')
    assert out['fifo'] == 'SCHED_FIFO 11' and out['after'] == 11
    assert os.sched_getscheduler(0) != os.SCHED_FIFO        # the test's own thread unchanged


def test_thread_priority_parameter_and_the_process_taking_it():
    """A node's thread_priority (read-only, 0..99, 0 = as started) and set_process_priority: every
    thread of the process, those started before included (in a child process, where permitted)."""
    import subprocess
    import textwrap

    from rwpend_ros.paramspec import check
    from rwpend_ros.sched import set_process_priority, thread_priority_spec
    spec = thread_priority_spec()
    assert spec.name == 'thread_priority' and spec.default == 0 and spec.read_only
    assert check(spec, 100) and not check(spec, 50) and not check(spec, 0)
    with pytest.raises(ValueError, match='1..99'):
        set_process_priority(0)
    code = textwrap.dedent('''
        import os, threading, time
        from rwpend_ros.sched import set_process_priority
        ev = threading.Event()
        before = threading.Thread(target=ev.wait, daemon=True)
        before.start()
        done = set_process_priority(7)
        after = threading.Thread(target=ev.wait, daemon=True)
        after.start()
        time.sleep(0.05)
        prios = {os.sched_getparam(int(tid)).sched_priority for tid in os.listdir('/proc/self/task')}
        print(done, '|', sorted(prios))
        ev.set()
    ''')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    done, prios = out.stdout.strip().split(' | ')
    if 'not permitted' in done:
        pytest.skip(done)
    assert done == 'SCHED_FIFO 7' and prios == '[7]', out.stdout
