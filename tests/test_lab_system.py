"""The lab end to end through the stack (lockstep on the simulator), and a faulty law in the
controller node.  Bounded in time; the figures of one measured run are in the comments."""
from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest

from rwpend_bag.reader import read_bag
from rwpend_lab.data import load_run

#: its outcome does not depend on the host keeping a sample rate: make test runs it beside another
pytestmark = pytest.mark.parallel

ROOT = Path(__file__).resolve().parents[1]
RWPEND = str(ROOT / 'rwpend')


def run(args, env, timeout=400):
    return subprocess.run([RWPEND, *args], env=env, capture_output=True, text=True, timeout=timeout)


@pytest.mark.timeout(450)
def test_lab_run_experiment_3_end_to_end(ros_env, tmp_path):
    """Experiment 3 (three torque pulses): bags of every run, results.json with every quantity
    passing, a self-contained report.html; then `lab report` gathers it."""
    out = tmp_path / 'exp03'
    p = run(['lab', 'run', '3', '--out', str(out)], ros_env)
    assert p.returncode == 0, p.stdout[-3000:] + p.stderr[-3000:]
    assert 'run 3/3' in p.stdout
    res = json.loads((out / 'results.json').read_text())
    assert res['experiment'] == 3 and res['passed'] and len(res['quantities']) == 12
    for r in res['runs']:
        assert read_bag(r['bag']).topics['/rwpend/encoders'].count == 600
    html = (out / 'report.html').read_text()
    assert 'data:image/png;base64,' in html
    p = run(['lab', 'report', str(out), '-o', str(tmp_path / 'course')], ros_env)
    assert p.returncode == 0 and (tmp_path / 'course' / 'index.html').is_file()


@pytest.mark.timeout(300)
def test_a_faulty_law_never_crashes_the_controller(ros_env, tmp_path):
    """A law that raises after 0.3 s: the controller answers u = 0 from then on, reports the fault
    on controller/status and switches off; the node runs to the end of the run."""
    law = tmp_path / 'faulty.py'
    law.write_text('def control(state, params):\n    if state.t > 0.3:\n        return 1 / 0\n    return 2.0\n')
    bag = tmp_path / 'bag'
    p = run(['up', '--lockstep', '--duration', '1', '--record', str(bag), '--set', f'controller.law.file={law}',
             '--set', 'controller.mode=law', '--set', 'sim.bracket=true'], ros_env, timeout=280)
    assert p.returncode == 0, p.stdout[-3000:] + p.stderr[-3000:]
    assert 'law fault' in p.stdout and 'ZeroDivisionError' in p.stdout
    d = load_run(bag, 0.001)
    k = int(np.nonzero(d.u == 0.0)[0][0])
    assert 0.29 <= d.t[k] <= 0.32 and np.all(d.u[k:] == 0.0) and np.all(d.u[1:k] == 2.0)
    assert any('law fault' in f for _, _, f in d.faults)      # (t, fault_code, fault)
    assert d.switches[-1][1] == 'off'
    assert len(d.u) == 1000     # the controller answered every sample to the end
