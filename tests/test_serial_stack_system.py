"""The whole stack on the serial driver: `./rwpend emulate` (the rig's firmware on a pty, driving
the plant model in real time) + `./rwpend up --plant serial:PATH` -- the estimator and controller
unchanged -- swings up and balances as on the simulator (issue 6). Real time, so the assertions
are about the outcome, not about timing. Run as on a rig: the firmware (emulator) and the loop
at real-time priority where permitted; with ordinary scheduling on a loaded 2-core machine the
command latency went from ~0.25 to 1-1.7 ms (p50) and 3 runs in 7 lost the balance."""
from __future__ import annotations

import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

from rwpend_bag.analysis import _decode, analyze, wrap
from rwpend_bag.judge import SOURCE_RIG, judge, read_run
from rwpend_bag.reader import read_bag

ROOT = Path(__file__).resolve().parents[1]
RWPEND = str(ROOT / 'rwpend')
#: the late share (device's applied: command_seq < seq - 1) above which a lost balance is the
#: host's, not the stack's: 10x the issue's target for this path (0.2 %)
LATE_SHARE_HOST_BEHIND = 0.02


#: --duration per layout: the loop swings up (< 8 s; ~4 s measured) and balances over the last 3 s;
#: the other layout is checked to run the rig (> 5000 samples of 1 ms)
@pytest.mark.parametrize('layout, duration', [([], 11), (['--composed', 'control'], 7)],
                         ids=['loop', 'composed_control'])
def test_stack_on_the_emulated_rig_swings_up_and_balances(tmp_path, ros_env, layout, duration):
    link = tmp_path / 'rig'
    bag = tmp_path / 'serial_run'
    emu_log = open(tmp_path / 'emulator.log', 'w')
    emu = subprocess.Popen([RWPEND, 'emulate', '--link', str(link), '--rt-priority', '60'],
                           env=ros_env, stdout=emu_log, stderr=subprocess.STDOUT)
    try:
        end = time.monotonic() + 20
        while not link.exists() and time.monotonic() < end:
            time.sleep(0.1)
        assert link.exists(), 'the emulator did not create its link'
        p = subprocess.run([RWPEND, 'up', '--plant', f'serial:{link}', '--mode', 'auto',
                            '--duration', str(duration), '--record', str(bag), '--rt-priority', '50', *layout],
                           env=ros_env, capture_output=True, text=True, timeout=120)
        assert p.returncode == 0, p.stdout[-3000:] + p.stderr[-3000:]
    finally:
        emu.terminate()
        emu.wait(timeout=10)
        emu_log.close()
    b = read_bag(bag)
    assert '/rwpend/encoders' in b.topics and 'rwpend_msgs/msg/PlantState' not in {
        t.type for t in b.topics.values()}, 'the plant is the driver, not the simulator'
    u = _decode(b, '/rwpend/command')['u']
    assert np.all(np.isfinite(u)) and np.abs(u).max() <= 10.0
    # the independent reader (rosbags) on the device's own report (applied): never driven by a
    # stale command, every gap of the bag in the recording report -- whatever the host's speed
    v = judge(read_run(bag))
    assert v.source == SOURCE_RIG and v.timed_samples > 3000, (v.source, v.timed_samples, v.problems)
    assert v.unsafe_samples == 0 and not v.unaccounted, v.problems
    if layout:
        # separate processes exchange every sample over DDS: on a 2-core VM 43-58 % of the
        # samples were late (PERFORMANCE.md, "The loop"), and the device zeroes a command 3
        # samples old (its hold limit) as the simulator does -- whether it balances then depends
        # on the host's steal; the layout is checked to run the rig, the loop to balance it
        assert len(u) > 5000 and b.topics['/rwpend/applied'].count > 5000
        return
    m = analyze(bag)
    st = _decode(b, '/rwpend/state')
    t = (st['_stamp_ns'] - st['_stamp_ns'][0]) / 1e9
    err = np.abs(wrap(st['theta'] - np.pi))
    last = t > t[-1] - 3.0
    balanced = m['swing_up_time_s'] is not None and m['swing_up_time_s'] < 8.0 and err[last].max() < 0.2
    late = v.late_samples / v.timed_samples
    if not balanced and late > LATE_SHARE_HOST_BEHIND:
        # the device held a command that did not answer the previous sample in this share of the
        # samples: the PC fell behind the rate (a host figure: PERFORMANCE.md, make bench), the
        # outcome is not the stack's to answer for
        pytest.xfail(f'this PC fell behind the sample rate: {100 * late:.1f} % of the samples late '
                     f'({v.late_samples} of {v.timed_samples}), {v.zero_samples} at zero; swing-up '
                     f'{m["swing_up_time_s"]} s, max |theta - pi| over the last 3 s {err[last].max():.2f} rad')
    assert m['swing_up_time_s'] is not None and m['swing_up_time_s'] < 8.0, (m, v.timing())
    assert err[last].max() < 0.2, f'balanced over the last 3 s ({v.timing()})'
