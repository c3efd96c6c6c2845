"""System test of the lab overview: one console watching two domains lists both rigs with their
mode and health, and acts on the one it is asked to (its HTTP API, as the page uses it)."""
from __future__ import annotations

import http.client
import json
import os
import subprocess
import time
from pathlib import Path

import pytest

from rwpend_ros.testenv import free_port, stop_processes, test_domain_id

ROOT = Path(__file__).resolve().parents[1]
RWPEND = str(ROOT / 'rwpend')


def api(port, path, body=None):
    c = http.client.HTTPConnection('127.0.0.1', port, timeout=60)
    headers = {'Content-Type': 'application/json'} if body is not None else {}
    c.request('POST' if body is not None else 'GET', path, json.dumps(body) if body is not None else None, headers)
    r = c.getresponse()
    out = r.status, json.loads(r.read() or b'{}')
    c.close()
    return out


def wait_for(fn, timeout, what):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        try:
            v = fn()
        except (OSError, ValueError):
            v = None
        if v:
            return v
        time.sleep(0.5)
    raise AssertionError(f'timed out after {timeout} s waiting for {what}')


@pytest.mark.timeout(900)
def test_one_console_lists_and_drives_the_rigs_of_two_domains(tmp_path):
    a, b = test_domain_id(), test_domain_id()
    while b == a:
        b = test_domain_id()
    base = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', PYTHONUNBUFFERED='1')
    log = open(tmp_path / 'lab.log', 'w')
    port = free_port()
    procs = [subprocess.Popen([RWPEND, 'up', '--ns', ns, '--mode', mode, '--duration', '600'],
                              env=dict(base, ROS_DOMAIN_ID=str(d)), stdout=log, stderr=subprocess.STDOUT,
                              start_new_session=True)
             for d, ns, mode in ((a, '/rigA', 'wheel_velocity'), (b, '/rigB', 'off'))]
    procs.append(subprocess.Popen([RWPEND, 'console', '--domain', str(a), '--domain', str(b), '--port', str(port),
                                   '--no-bridge'], env=dict(base, ROS_DOMAIN_ID=str(a)), stdout=log,
                                  stderr=subprocess.STDOUT, start_new_session=True))
    try:
        def both():
            rows = {r['id']: r for r in api(port, '/api/overview')[1]['rigs']}
            ra, rb = rows.get(f'{a}:/rigA'), rows.get(f'{b}:/rigB')
            # the overview fills in as each node's status arrives: the mode (the controller's
            # status) can come before the plant (the simulator's /diagnostics)
            return rows if (ra and rb and ra['mode'] == 'wheel_velocity' and rb['mode'] == 'off'
                            and rb['plant']) else None
        rows = wait_for(both, 300, 'both rigs with their modes and plants in the overview')
        assert rows[f'{b}:/rigB']['plant'] == 'sim' and rows[f'{b}:/rigB']['level'] in ('ok', 'warn', 'error')
        status, r = api(port, '/api/mode', {'rig': f'{b}:/rigB', 'mode': 'wheel_velocity'})
        assert status == 200 and r['ok'], r
        wait_for(lambda: {x['id']: x for x in api(port, '/api/overview')[1]['rigs']}[f'{b}:/rigB']['mode']
                 == 'wheel_velocity', 120, 'rig B in its new mode')
        status, r = api(port, '/api/mode', {'rig': f'{b}:/rigA', 'mode': 'off'})
        assert status == 503 and 'not available' in r['error'], 'rig A is not on domain B'
        status, r = api(port, '/api/mode', {'rig': '233:/rigA', 'mode': 'off'})
        assert status == 400 and 'does not watch domain 233' in r['error']
        lights = api(port, f'/api/rig?rig={a}:/rigA')[1]['lights']
        assert {'late', 'timeouts', 'faults', 'estop', 'node:sim', 'node:controller'} <= {x['key'] for x in lights}
    finally:
        stop_processes(procs)
        log.close()


@pytest.mark.timeout(900)
def test_an_experiment_started_from_the_console_writes_its_report(tmp_path):
    """Experiment 3 (three torque pulses) through the console's HTTP API as the page starts it:
    on the console's lab domain (not the watched one), listed while it runs, then its quantities
    and its report.html served by the console."""
    a, lab_domain = test_domain_id(), test_domain_id()
    while lab_domain == a:
        lab_domain = test_domain_id()
    base = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', PYTHONUNBUFFERED='1', ROS_DOMAIN_ID=str(a))
    port = free_port()
    log = open(tmp_path / 'console.log', 'w')
    console = subprocess.Popen([RWPEND, 'console', '--port', str(port), '--no-bridge', '--lab', str(tmp_path / 'lab'),
                                '--lab-domain', str(lab_domain)], env=base, stdout=log, stderr=subprocess.STDOUT,
                               start_new_session=True)
    try:
        wait_for(lambda: not api(port, '/api/lab')[1]['loading'], 300, 'the list of experiments')
        status, r = api(port, '/api/lab/run', {'experiment': 99})
        assert status == 400 and 'no experiment 99' in r['error']
        status, r = api(port, '/api/lab/run', {'experiment': 3})
        assert status == 200 and r['ok'] and r['domain'] == lab_domain, r
        run = r['run']
        status, r = api(port, '/api/lab/run', {'experiment': 1})
        assert status == 409 and 'one experiment at a time' in r['error']
        assert api(port, '/api/lab')[1]['running'] == run
        row = wait_for(lambda: next((x for x in api(port, '/api/lab')[1]['runs']
                                     if x['name'] == run and not x['running']), None), 600, 'the experiment to end')
        # the console's part: the run ended by itself (the lab's exit 1: a quantity fails -- the
        # lab's own tests judge the physics), and the page gets its quantities and its report
        res = json.loads((tmp_path / 'lab' / run / 'results.json').read_text())
        assert row['exit'] in (0, 1) and row['exit'] == (0 if res['passed'] else 1), row['log']
        assert row['passed'] == res['passed'] and len(row['quantities']) == len(res['quantities']) == 12
        assert 'report.html' in row['log'], 'the page shows the end of what the lab printed'
        c = http.client.HTTPConnection('127.0.0.1', port, timeout=60)
        c.request('GET', f'/lab/report?run={run}')
        resp = c.getresponse()
        html = resp.read().decode()
        assert resp.status == 200 and 'data:image/png;base64,' in html and 'Experiment 3' in html
        c.close()
    finally:
        stop_processes([console])
        log.close()
