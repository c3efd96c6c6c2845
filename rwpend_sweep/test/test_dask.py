"""A study on a local 2-worker Dask cluster gives the rows of the local run (make test installs
the cluster extra: make setup-cluster)."""
import csv

import pytest

from rwpend_sweep.execute import study_fingerprint
from rwpend_sweep.spec import study_from_dict
from rwpend_sweep.study import run_study

distributed = pytest.importorskip('distributed')
pytestmark = pytest.mark.loop    # each run is the stack's loop in lockstep (in the workers)

DOC = {'scenario': {'mode': 'auto', 'duration': 0.5, 'success': {'last': 0.2}},
       'axes': {'initial.theta_dot': [-1.0, 0.0, 1.0], 'plant.m_r': {'uniform': [0.08, 0.09]},
                'sensor.noise_counts': [0.0, 1.0]},
       'samples': 2, 'seed': 11}


def _rows(path):
    with open(path) as fh:
        return [{k: v for k, v in r.items() if k != 'cpu_s'} for r in csv.DictReader(fh)]


def test_dask_local_cluster_equals_local_run(tmp_path):
    s = study_from_dict(DOC)
    fp = study_fingerprint(DOC, {})
    run_study(s, tmp_path / 'local', fp, workers=1)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:
        run_study(s, tmp_path / 'dask', fp, scheduler=cluster.scheduler_address)
    local, dask = _rows(tmp_path / 'local' / 'results.csv'), _rows(tmp_path / 'dask' / 'results.csv')
    assert len(local) == s.runs == 12
    assert dask == local
