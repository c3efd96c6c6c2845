"""System test of the Foxglove bridge with an independent client of the protocol
(rwpend_console.wsclient: written from the specification with ``websockets``; messages decoded
from the advertised ros2msg schemas with ``rosbags``, not rclpy):

* channels listed with their schemas; the rig's state received as CDR and decoded with its schema;
* a parameter set and read back (and by the param tool), a refused parameter reported with the
  controller's reason, its value unchanged;
* a service (controller/set_mode) called; a bridge listening beyond the loopback is read-only
  but for the e-stop.
"""
from __future__ import annotations

import asyncio
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest

from rwpend_console.wsclient import Client, decode, encode, message_class
from rwpend_ros.testenv import free_port, stop_processes

ROOT = Path(__file__).resolve().parents[1]
RWPEND = str(ROOT / 'rwpend')


@pytest.fixture(scope='module')
def rig(tmp_path_factory):
    """A real-time stack in auto mode and two bridges: on the loopback and on 0.0.0.0."""
    import os
    from rwpend_ros.testenv import test_domain_id
    env = dict(os.environ, ROS_DOMAIN_ID=str(test_domain_id()), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               PYTHONUNBUFFERED='1')
    logdir = tmp_path_factory.mktemp('bridge')
    log = open(logdir / 'stack.log', 'w')
    ports = free_port(), free_port()
    procs = [subprocess.Popen([RWPEND, 'up', '--mode', 'auto', '--duration', '200'], env=env, stdout=log,
                              stderr=subprocess.STDOUT, start_new_session=True)]
    procs += [subprocess.Popen([RWPEND, 'bridge', '--port', str(p), '--listen', listen], env=env, stdout=log,
                               stderr=subprocess.STDOUT, start_new_session=True)
              for p, listen in zip(ports, ('127.0.0.1', '0.0.0.0'))]
    yield env, ports, logdir / 'stack.log'
    stop_processes(procs)
    log.close()


def param_get(env, name):
    p = subprocess.run([RWPEND, 'param', 'get', 'controller', name], env=env, capture_output=True, text=True,
                       timeout=60)
    assert p.returncode == 0, p.stderr
    return p.stdout.split(':', 1)[1].strip()


async def connect(port, needs, timeout=120):
    """A client whose session has what ``needs`` asks (retrying while the bridge starts)."""
    end = time.monotonic() + timeout
    while True:
        try:
            c = await Client(f'ws://127.0.0.1:{port}').__aenter__()
        except OSError:
            if time.monotonic() > end:
                raise
            await asyncio.sleep(1.0)
            continue
        if await c.pump(max(1.0, end - time.monotonic()), needs):
            return c
        await c.__aexit__()
        raise AssertionError(f'the bridge did not advertise what was needed: {c.session.channels}')


def has_rig(s):
    topics = {c['topic'] for c in s.channels.values()}
    names = {v['name'] for v in s.services.values()}
    return {'/rwpend/state', '/rwpend/controller/status'} <= topics and '/rwpend/controller/set_mode' in names


@pytest.mark.timeout(600)
def test_topics_parameters_and_services(rig):
    env, (port, _), _ = rig
    asyncio.run(topics_parameters_and_services(env, port))


async def topics_parameters_and_services(env, port):
    c = await connect(port, has_rig)
    try:
        assert {'parameters', 'services'} <= set(c.session.server_info['capabilities'])
        ch = c.channel('/rwpend/state')
        assert (ch['encoding'], ch['schemaName'], ch['schemaEncoding']) == ('cdr', 'rwpend_msgs/msg/StateEstimate', 'ros2msg')
        assert 'MSG: std_msgs/Header' in ch['schema']
        sub = await c.subscribe(ch['id'])
        assert await c.pump(60, lambda s: sum(m[0] == sub for m in s.messages) >= 20), 'state messages'
        states = [decode(ch['schemaName'], ch['schema'], m[2]) for m in c.session.messages if m[0] == sub]
        seq = np.array([m.seq for m in states])
        assert np.all(np.diff(seq) > 0) and all(np.isfinite(m.theta) for m in states) and states[0].estimator
        await parameters(c, env)
        await set_mode(c, env, 'wheel_velocity')
    finally:
        await c.__aexit__()


async def parameters(c, env):
    name = '/rwpend/controller.balance.kpp'
    await c.set_parameters([{'name': name, 'value': -300.0, 'type': 'float64'}], 'set-1')
    assert await c.pump(30, lambda s: any(p.get('id') == 'set-1' for p in s.parameter_values))
    got = next(p for p in c.session.parameter_values if p.get('id') == 'set-1')['parameters']
    assert got == [{'name': name, 'type': 'float64', 'value': -300.0}]
    await c.get_parameters([name, '/rwpend/controller.mode'], 'get-1')
    assert await c.pump(30, lambda s: any(p.get('id') == 'get-1' for p in s.parameter_values))
    got = {p['name']: p['value'] for p in next(p for p in c.session.parameter_values if p.get('id') == 'get-1')['parameters']}
    assert got[name] == -300.0 and got['/rwpend/controller.mode'] == 'auto'
    assert float(param_get(env, 'balance.kpp')) == -300.0, 'the param tool reads what the bridge set'
    await c.set_parameters([{'name': name, 'value': 50.0, 'type': 'float64'}], 'set-2')
    assert await c.pump(30, lambda s: any(p.get('id') == 'set-2' for p in s.parameter_values))
    refusal = [s for s in c.session.statuses if s['level'] == 2 and 'balance.kpp' in s['message']]
    assert refusal and 'unstable' in refusal[-1]['message'], c.session.statuses
    got = next(p for p in c.session.parameter_values if p.get('id') == 'set-2')['parameters']
    assert got[0]['value'] == -300.0, 'the refused value did not take'


async def call(c, name, fields):
    sv = c.service(name)
    req, resp = sv['request'], sv['response']
    payload = encode(req['schemaName'], req['schema'], message_class(req['schemaName'], req['schema'])(**fields))
    call_id = await c.call_service(sv['id'], req['encoding'], payload)
    assert await c.pump(30, lambda s: any(r[1] == call_id for r in s.responses)
                        or any(f['callId'] == call_id for f in s.failures))
    for r in c.session.responses:
        if r[1] == call_id:
            return decode(resp['schemaName'], resp['schema'], r[3]), None
    return None, next(f for f in c.session.failures if f['callId'] == call_id)['message']


async def set_mode(c, env, mode):
    answer, failure = await call(c, '/rwpend/controller/set_mode', {'mode': mode})
    assert failure is None and answer.success and answer.previous_mode == 'auto', (answer, failure)
    assert param_get(env, 'mode') == mode


@pytest.mark.timeout(600)
def test_a_bridge_beyond_the_loopback_is_read_only_but_for_the_estop(rig):
    env, (_, port), _ = rig
    asyncio.run(read_only(env, port))


async def read_only(env, port):
    def ready(s):
        return has_rig(s) and any(v['name'].endswith('/estop') for v in s.services.values())
    c = await connect(port, ready)
    try:
        before = param_get(env, 'status_every')
        await c.set_parameters([{'name': '/rwpend/controller.status_every', 'value': 20}], 'ro-1')
        assert await c.pump(30, lambda s: any(p.get('id') == 'ro-1' for p in s.parameter_values))
        assert any('read-only' in s['message'] for s in c.session.statuses)
        assert param_get(env, 'status_every') == before
        mode = param_get(env, 'mode')
        answer, failure = await call(c, '/rwpend/controller/set_mode', {'mode': 'off'})
        assert answer is None and 'read-only' in failure
        assert param_get(env, 'mode') == mode
        estop = next(v['name'] for v in c.session.services.values() if v['name'].endswith('/estop'))
        answer, failure = await call(c, estop, {'data': True})
        assert failure is None and answer.success, failure
        answer, failure = await call(c, estop, {'data': False})
        assert answer is None and 'read-only' in failure, 'clearing the e-stop needs the loopback'
    finally:
        await c.__aexit__()
