"""System test: a sweep run is the lockstep ``up`` run of the same scenario -- the same encoder
counts and the same command on every sample (the bag of ``./rwpend up --lockstep --record``)."""
from __future__ import annotations

import os
import subprocess
from pathlib import Path

import numpy as np
import pytest

from rwpend_bag.reader import read_bag
from rwpend_ros import wire
from rwpend_ros.testenv import test_domain_id
from rwpend_sweep.build import prepare
from rwpend_sweep.run import samples_of
from rwpend_sweep.spec import study_from_dict

#: its outcome does not depend on the host keeping a sample rate: make test runs it beside another
pytestmark = pytest.mark.parallel

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.system
@pytest.mark.parametrize('mode, theta0, taps', [('auto', 0.0, ['1.5:0.5']), ('balance', 3.1, [])])
def test_sweep_run_equals_the_lockstep_up_bag(tmp_path, mode, theta0, taps):
    duration = 2.0
    bag = tmp_path / 'bag'
    env = dict(os.environ, ROS_DOMAIN_ID=str(test_domain_id()), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    args = [str(ROOT / 'rwpend'), 'up', '--lockstep', '--duration', str(duration), '--mode', mode,
            '--theta0', str(theta0), '--record', str(bag)]
    for t in taps:
        args += ['--tap', t]
    p = subprocess.run(args, env=env, capture_output=True, text=True, timeout=180)
    assert p.returncode == 0, p.stdout[-2000:] + p.stderr[-2000:]
    b = read_bag(bag, topics=['/rwpend/encoders', '/rwpend/command'])
    enc = [wire.unpack_encoders(d) for d in b.topics['/rwpend/encoders'].datas]
    cmd = dict(wire.unpack_command(d) for d in b.topics['/rwpend/command'].datas)
    study = study_from_dict({'scenario': {'mode': mode, 'duration': duration, 'initial': {'theta': theta0},
                                          'taps': [{'t': float(t.split(':')[0]), 'dv': float(t.split(':')[1])}
                                                   for t in taps]}})
    _, setups = prepare(study)
    tr = samples_of(setups[0])
    assert len(enc) == len(tr.seq) == round(duration / 1e-3)
    assert [e[1] for e in enc] == tr.seq.tolist()
    assert [e[2] for e in enc] == tr.pendulum_counts.tolist()
    assert [e[3] for e in enc] == tr.motor_counts.tolist()
    assert np.array_equal(np.array([cmd[s] for s in tr.seq.tolist()]), tr.u)
