"""Lab experiments from the page (rwpend_console.labruns and the app's requests): a stand-in for
the lab runner, no ROS."""
import json
import signal
import sys
import time

import pytest

from rwpend_console.app import ConsoleApp, RequestError
from rwpend_console.labruns import STOP_GRACE_S, LabRuns, check_run_name, lab_domain

# writes what the lab runner writes: a line of log, results.json, report.html (or sleeps)
STANDIN = r'''
import json, pathlib, sys, time
n, out = sys.argv[2], pathlib.Path(sys.argv[4])
print('Experiment', n, 'env domain', __import__('os').environ['ROS_DOMAIN_ID'], flush=True)
if n == '3':
    time.sleep(60)
(out / 'results.json').write_text(json.dumps({'passed': n != '2', 'quantities': [{'name': 'k_u', 'pass': n != '2'}]}))
(out / 'report.html').write_text('<html>report %s</html>' % n)
'''


@pytest.fixture
def lab(tmp_path):
    script = tmp_path / 'standin.py'
    script.write_text(STANDIN)
    runs = LabRuns(tmp_path / 'lab_out', 17, [sys.executable, str(script)])
    yield runs
    runs.close()


def wait_done(lab, timeout=30):
    end = time.monotonic() + timeout
    while lab.state()['running'] and time.monotonic() < end:
        time.sleep(0.05)
    assert not lab.state()['running']


def test_the_experiments_the_simulator_runs(lab):
    exps = {e['number']: e for e in lab.experiments(wait=300)}
    assert 1 in exps and 3 in exps and exps[3]['title'] and exps[3]['section'] == '2.6'
    assert all(e['needs'] for e in exps.values())


def test_lab_domain_is_one_the_console_does_not_watch():
    assert lab_domain([0]) == 1
    assert lab_domain([5, 6]) == 7
    assert lab_domain([232]) == 0
    assert lab_domain([0], 42) == 42
    with pytest.raises(ValueError, match='watches'):
        lab_domain([0, 42], 42)


@pytest.mark.parametrize('bad', ['../etc', 'exp1_20260101_000000', 'exp01_2026', 'exp01_20260101_000000/..', 3, None])
def test_run_names_are_checked(bad):
    with pytest.raises(ValueError, match='expNN_'):
        check_run_name(bad)


def test_a_run_writes_its_report_and_the_state_says_so(lab):
    r = lab.start(1)
    assert r['ok'] and r['run'].startswith('exp01_') and r['domain'] == 17
    wait_done(lab)
    s = lab.state()
    row, = s['runs']
    assert row['name'] == r['run'] and row['experiment'] == 1 and row['exit'] == 0
    assert row['passed'] is True and row['quantities'] == [{'name': 'k_u', 'pass': True}]
    assert 'env domain 17' in row['log'], 'the run is on the lab domain'
    assert lab.report(r['run']).read_text() == '<html>report 1</html>'


def test_one_run_at_a_time_and_stop(lab):
    r = lab.start(3)
    with pytest.raises(ValueError, match='one experiment at a time'):
        lab.start(1)
    with pytest.raises(ValueError, match='not running'):
        lab.stop('exp01_20260101_000000')
    with pytest.raises(ValueError, match='no report'):
        lab.report(r['run'])
    assert lab.state()['running'] == r['run']
    assert lab.stop(r['run'])['ok']
    assert lab.state()['running'] is None
    assert lab.start(2)['ok'], 'the next one starts once it stopped'
    wait_done(lab)
    assert [x['passed'] for x in lab.state()['runs'] if x['experiment'] == 2] == [False]


def test_a_run_stops_at_sigint_even_when_the_console_ignores_it(lab):
    """A console started with SIGINT ignored (a script's background job) starts its runs with
    SIGINT at its default: stop() ends a run at once, not at the SIGTERM after STOP_GRACE_S."""
    old = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        r = lab.start(3)                # the stand-in sleeps 60 s
    finally:
        signal.signal(signal.SIGINT, old)
    time.sleep(0.5)                     # the stand-in's Python is up
    t0 = time.monotonic()
    assert lab.stop(r['run'])['exit'] == -signal.SIGINT
    assert time.monotonic() - t0 < STOP_GRACE_S / 3


def test_unknown_experiments_are_refused(lab):
    with pytest.raises(ValueError, match='no experiment 99'):
        lab.start(99)
    assert lab.state()['runs'] == []


def test_a_broken_results_file_is_said(lab):
    d = lab.folder / 'exp05_20260101_000000'
    d.mkdir(parents=True)
    (d / 'results.json').write_text('{not json')
    row, = lab.state()['runs']
    assert row['passed'] is None and 'results.json unreadable' in row['error']


def test_the_apps_requests(lab, tmp_path):
    app = ConsoleApp({}, tmp_path / 'bags', 20.0, lab)
    lab.experiments(wait=300)
    st = app.lab_state()
    assert not st['loading'] and {e['number'] for e in st['experiments']} >= {1, 3}
    for body, why in (({}, "missing 'experiment'"), ({'experiment': '3'}, 'the number of an experiment'),
                      ({'experiment': True}, 'the number of an experiment'), ({'experiment': 99}, 'no experiment 99')):
        with pytest.raises(RequestError, match=why) as e:
            app.lab_run(body)
        assert e.value.status == 400
    r = app.lab_run({'experiment': 3})
    with pytest.raises(RequestError, match='one experiment at a time') as e:
        app.lab_run({'experiment': 1})
    assert e.value.status == 409
    with pytest.raises(RequestError, match='expNN_') as e:
        app.lab_report('../../etc/passwd')
    assert e.value.status == 404
    assert app.lab_stop({'run': r['run']})['ok']
    with pytest.raises(RequestError, match='no lab'):
        ConsoleApp({}, tmp_path / 'bags', 20.0).lab_state()
    json.dumps(app.lab_state())
