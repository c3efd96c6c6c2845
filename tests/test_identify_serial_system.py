"""``./rwpend identify --plant serial:LINK`` through the emulator (issue 24, the rig path): the
emulated rig's truth is the heavy example rig (``./rwpend emulate --rig HEAVY --hand``), the stack
reads the shipped rig.yaml, the student's hand is played by this test from the prompts, and the
whole plan runs in real time through the driver. Asserted: the identification runs to the end and
writes a complete rig file, with the parameters a free swing and the pulses determine well close
to the emulator's truth -- or, where this machine does not keep the sample rate in a run (the
recorder misses samples, the loop lags the plant), stops with that reason: an expected failure,
reported as such; every parameter's identified value, CI and truth are printed (the
figures of the issue's note). Real time on a shared machine: the parameters that depend most on
the loop keeping the rate (friction, stiction, motor lag) are printed, not asserted.

``identify --check`` on this path is judged on the same run's bags (``--check HEAVY --from``: the
refit of what went through the emulated rig says the emulator's own rig file matches), not by a
second real-time session of 7 runs; the check's own runs through the stack are
tests/test_identify_system.py::test_check_through_the_stack_says_the_identified_rig_matches
(lockstep)."""
from __future__ import annotations

import json
import os
import re
import subprocess

import pytest

from emulated_hand import RWPEND, run_with_hand

from rwpend_ident.rigfile import example_rig_file
from rwpend_model.rig import load_rig_file

HEAVY = str(example_rig_file())
HAND = {'Let the pendulum hang still': 'steady 0.5', 'Lift the pendulum to about': 'lift 20 1.5',
        'Let go of the pendulum now': ''}
#: the reasons identify gives when this machine does not keep the sample rate in a run, or does not
#: start the stack of a run in time (at a load of 8-10 on 2 cores the nodes were still importing
#: numpy and rclpy after the 30 s: 'encoders has 1 of 3 subscribers')
REALTIME_SHORTFALL = re.compile(r'\d+ encoder samples missing in the recording|the step never started[^\n]*'
                                r'|did not reach the motor whole[^\n]*'
                                r'|the stack was not ready within \d+ s[^\n]*')
#: the driver's summary of a run: commands sent, and refused as too old
OLD_COMMANDS = re.compile(r'(\d+) commands sent, (\d+) old')
#: relative tolerance of the parameters asserted on the real-time path
TOLERANCE = {'a': 0.01, 'omega_p_stuck': 0.01, 'b_r': 0.05, 'b_p': 0.05, 'pendulum_energy_time_constant': 0.05}


def realtime_shortfall(status: int, text: str, out) -> str | None:
    """Why a refused identification (exit 2) was this machine's, not the stack's: the recorder
    missed samples, a step never started, a run's stack was not up in time, or the driver refused
    more than 10 % of a run's commands as too old (the loop did not keep the rate); None otherwise."""
    old_share = max((int(o) / max(int(n) + int(o), 1) for f in (out / 'runs').glob('*.log')
                     for n, o in OLD_COMMANDS.findall(f.read_text())), default=0.0)
    print(f'largest share of commands the driver refused as old in a run: {old_share:.3f}')
    if status != 2:
        return None
    why = REALTIME_SHORTFALL.search(text)
    if why:
        return why.group(0)
    return f'{100 * old_share:.0f} % of a run\'s commands came too late' if old_share > 0.1 else None


@pytest.fixture(scope='module')
def through_the_rig(tmp_path_factory):
    """One identification through the emulated rig for both tests: (exit status, output lines,
    hand actions, link, its output directory, why this machine fell behind or None)."""
    from rwpend_ros.testenv import test_domain_id
    tmp = tmp_path_factory.mktemp('identify_serial')
    env = {**os.environ, 'ROS_DOMAIN_ID': str(test_domain_id()), 'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST',
           'PYTHONUNBUFFERED': '1'}
    env['RMW_IMPLEMENTATION'] = env.get('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp')
    out = tmp / 'id'
    status, lines, hands, link = run_with_hand(tmp, env, ['identify', '--plant', 'serial:{link}', '--out', str(out)],
                                               HAND, timeout=840, emulate_args=('--rig', HEAVY))
    text = ''.join(lines)
    print(text[-5000:])
    return status, text, hands, link, out, realtime_shortfall(status, text, out), env


@pytest.mark.timeout(900)       # the shared identification is set up in this test
def test_identify_through_the_emulated_rig(through_the_rig):
    status, text, hands, link, out, why, _ = through_the_rig
    if why:
        # this machine did not keep the sample rate for a run (the recorder or the loop fell
        # behind): the identification stops with that reason rather than fitting bad data
        pytest.xfail('the real-time path fell behind on this machine: ' + why)
    assert status == 0, text[-4000:]
    assert hands and all(a is not None for a in hands)
    truth = load_rig_file(HEAVY)
    rig = load_rig_file(out / 'rig.yaml')
    doc = json.loads((out / 'identification.json').read_text())
    rows = {q['name']: q for q in doc['quantities']}
    table = {}
    for name, q in rows.items():
        true = getattr(truth, name, None)
        table[name] = {'identified': q['value'], 'ci95': q.get('ci95'),
                       'true': true if isinstance(true, (int, float)) else None}
    print('measured:', json.dumps(table))
    print('validation:', json.dumps(doc.get('validation')))
    for name, tol in TOLERANCE.items():
        assert abs(getattr(rig, name) - getattr(truth, name)) <= tol * abs(getattr(truth, name)), \
            f'{name}: identified {getattr(rig, name)} vs the emulator\'s {getattr(truth, name)}'
    records = doc.get('runs') or []
    assert all(r.get('plant') == f'serial:{link}' for r in records if isinstance(r, dict) and 'plant' in r)


def check_of_the_recorded_runs(env, out, tmp_path) -> tuple[int, str]:
    """``./rwpend identify --check HEAVY --from OUT``: the check of the emulator's own rig file on
    the bags recorded through it (no new runs); (exit status, output)."""
    p = subprocess.run([RWPEND, 'identify', '--check', HEAVY, '--from', str(out), '--out', str(tmp_path / 'c')],
                       env=env, capture_output=True, text=True, timeout=300)
    return p.returncode, p.stdout + p.stderr


def assert_check_says_it_matches(status: int, text: str) -> None:
    """The check's verdict: its own rig file matches, parameter by parameter."""
    print(text[-3000:])
    assert status == 0, text[-3000:]
    assert 'still matches the rig' in text
    table = [ln for ln in text.splitlines()
             if ln.split()[:1] and ln.split()[0] in ('a', 'b_r', 'pendulum_energy_time_constant')]
    assert len(table) == 3 and all(ln.rstrip().endswith('matches') for ln in table), table


@pytest.mark.timeout(900)       # the shared identification, when this test runs alone
def test_check_of_the_runs_through_the_emulated_rig_says_its_own_rig_file_matches(through_the_rig, tmp_path):
    """``identify --check HEAVY`` on the bags recorded through the emulator whose truth is HEAVY:
    it still matches, parameter by parameter."""
    status, text, _, _, out, why, env = through_the_rig
    if why:
        pytest.xfail('the real-time path fell behind on this machine: ' + why)
    assert status == 0, text[-4000:]
    assert_check_says_it_matches(*check_of_the_recorded_runs(env, out, tmp_path))
