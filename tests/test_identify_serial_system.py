"""``./rwpend identify --plant serial:LINK`` through the emulator (issue 24, the rig path): the
emulated rig's truth is the heavy example rig (``./rwpend emulate --rig HEAVY --hand``), the stack
reads the shipped rig.yaml, the student's hand is played by this test from the prompts, and the
whole plan runs in real time through the driver. Asserted: the identification runs to the end and
writes a complete rig file, with the parameters a free swing and the pulses determine well close
to the emulator's truth -- or, where this machine does not keep the sample rate in a run (the
recorder misses samples, the loop lags the plant), stops with that reason: an expected failure,
reported as such; every parameter's identified value, CI and truth are printed (the
figures of the issue's note). Real time on a shared machine: the parameters that depend most on
the loop keeping the rate (friction, stiction, motor lag) are printed, not asserted."""
from __future__ import annotations

import json
import re

import pytest

from emulated_hand import run_with_hand

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


@pytest.mark.timeout(900)
def test_identify_through_the_emulated_rig(tmp_path, ros_env):
    out = tmp_path / 'id'
    status, lines, hands, link = run_with_hand(tmp_path, ros_env, ['identify', '--plant', 'serial:{link}',
                                                                   '--out', str(out)], HAND, timeout=840,
                                               emulate_args=('--rig', HEAVY))
    text = ''.join(lines)
    print(text[-5000:])
    why = realtime_shortfall(status, text, out)
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
    records = json.loads((out / 'identification.json').read_text()).get('runs') or []
    assert all(r.get('plant') == f'serial:{link}' for r in records if isinstance(r, dict) and 'plant' in r)


@pytest.mark.timeout(600)
def test_check_through_the_emulated_rig_says_its_own_rig_file_matches(tmp_path, ros_env):
    """``identify --check HEAVY --plant serial:`` on the emulator whose truth is HEAVY: the short
    re-measurement (7 runs) says it still matches, parameter by parameter."""
    status, lines, _, _ = run_with_hand(tmp_path, ros_env, ['identify', '--check', HEAVY, '--plant', 'serial:{link}',
                                                            '--out', str(tmp_path / 'c')], HAND, timeout=540,
                                        emulate_args=('--rig', HEAVY))
    text = ''.join(lines)
    print(text[-3000:])
    why = realtime_shortfall(status, text, tmp_path / 'c')
    if why:
        pytest.xfail('the real-time path fell behind on this machine: ' + why)
    assert status == 0, text[-3000:]
    assert 'still matches the rig' in text
    table = [ln for ln in lines if ln.split()[:1] and ln.split()[0] in ('a', 'b_r', 'pendulum_energy_time_constant')]
    assert len(table) == 3 and all(ln.rstrip().endswith('matches') for ln in table), table
