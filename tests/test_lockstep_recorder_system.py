"""System test: a lockstep run of separate processes keeps pace with its recorder (the simulator's
``lockstep_recorder_window``, the recorder's ``--progress``), so a recorder that stalls slows the
run down instead of losing messages; one that stops reporting for ``lockstep_recorder_timeout``
is given up on, loudly, and the run finishes."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from mcap_rules import assert_log_time_order
from rwpend_bag import sameness
from test_safety_system import diagnostics
from test_stack_system import RWPEND, series

from rwpend_bringup.verdict import EXIT_SHORT_BAG

#: its outcome does not depend on the host keeping a sample rate: make test runs it beside another
pytestmark = pytest.mark.parallel


def recorder_pid(bag: Path, timeout: float = 60.0) -> int:
    """The pid of the recorder process writing ``bag`` (started by ./rwpend up)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        p = subprocess.run(['pgrep', '-f', f'rwpend_bag.cli record -o {bag} '], capture_output=True, text=True)
        pids = [int(x) for x in p.stdout.split()]
        if pids:
            return pids[0]
        time.sleep(0.1)
    raise AssertionError(f'no recorder process for {bag}')


def run_with_a_stalled_recorder(bag: Path, env: dict, duration: float, stall_s: float, extra=()):
    """./rwpend up --lockstep --record BAG; once the run has started (sample 0 is out when the
    simulator logs the controller's first switch, the swing-up), the recorder is stopped
    (SIGSTOP) for ``stall_s`` s. Returns (exit code, output)."""
    # the recorder in a process of its own (separate layout): in the loop's process it takes the
    # bytes directly and cannot be stalled alone
    proc = subprocess.Popen([RWPEND, 'up', '--lockstep', '--duration', str(duration), '--mode', 'auto',
                             '--composed', 'none', '--record', str(bag), *extra], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    lines: list[str] = []
    started = threading.Event()

    def read():
        for line in proc.stdout:
            lines.append(line)
            if 'auto/swingup' in line:
                started.set()
    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    try:
        pid = recorder_pid(bag)
        assert started.wait(90), ''.join(lines[-40:])
        os.kill(pid, signal.SIGSTOP)
        try:
            time.sleep(stall_s)
        finally:
            os.kill(pid, signal.SIGCONT)
        code = proc.wait(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    reader.join(5)
    return code, ''.join(lines)


def sim_values(bag):
    last = {}
    for _, name, level, message, values in diagnostics(bag):
        if name.endswith('sim: plant'):
            last = dict(values, level=level, message=message)
    return last


def test_a_stalled_recorder_slows_a_lockstep_run_and_nothing_is_lost(tmp_path, ros_env):
    bag = tmp_path / 'stalled'
    code, out = run_with_a_stalled_recorder(bag, ros_env, duration=5, stall_s=1.5)
    assert code == 0, out[-3000:]
    for topic in ('/rwpend/encoders', '/rwpend/state', '/rwpend/command', '/rwpend/sim/true_state'):
        seq = series(bag, topic)['seq'].astype(np.int64)
        assert np.array_equal(seq, np.arange(5000)), f'{topic}: {len(seq)} recorded, not every sample in order'
    v = sim_values(bag)
    assert v['recorder_window'] == '50' and v['recorder_given_up'] == 'False', v
    assert int(v['recorder_holds']) >= 1 and float(v['recorder_hold_s']) >= 1.0, v
    assert '/rwpend/recorder/progress' not in out, 'the recorder does not record its own progress'
    # a stall changes when the messages came, not the bag's log times or order
    assert_log_time_order(bag)
    lt = json.loads((bag / 'recording_report.json').read_text())['log_times']
    assert sameness.order_faults(lt) == {} and lt['written']['raised'] == 0, lt


def test_a_recorder_that_stops_reporting_is_given_up_on_loudly(tmp_path, ros_env):
    bag = tmp_path / 'given_up'
    # the run goes on after the recorder comes back (a publisher that has ended cannot repair
    # what a stopped reader missed, and the last diagnostics are what is checked)
    code, out = run_with_a_stalled_recorder(bag, ros_env, duration=10, stall_s=2.0,
                                            extra=['--set', 'sim.lockstep_recorder_timeout=1.0'])
    # what the stopped recorder missed is said by up: a warning per topic, and exit status 4
    # (EXIT_SHORT_BAG) when the bag holds less than 90 % of the run's samples
    # (with 4 MB socket buffers a 2 s stall often loses nothing: the messages wait in its socket)
    assert code in (0, EXIT_SHORT_BAG), out[-3000:]
    if code == EXIT_SHORT_BAG:
        assert 'much shorter than the run' in out, out[-3000:]
    assert 'the recorder reported no progress for 1 s' in out, out[-3000:]
    v = sim_values(bag)
    assert v['recorder_given_up'] == 'True' and v['recorder_window'] == '0', v
    assert v['level'] == 1 and 'without the recorder' in v['message'], v     # WARN
    assert len(series(bag, '/rwpend/encoders')['seq']) > 0
    # the bag is still in log-time order; whatever came late or was lost is in the report
    assert_log_time_order(bag)
    report = json.loads((bag / 'recording_report.json').read_text())
    lt = report['log_times']
    assert lt['deterministic_order'] == (lt['late'] == 0 and lt['forced'] == 0), lt
    if not lt['deterministic_order']:
        assert 'NOT deterministic' in out, out[-3000:]
