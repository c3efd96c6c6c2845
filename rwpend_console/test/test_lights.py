"""Diagnostics as status lights, per rig."""
from rwpend_console.lights import STALE_AFTER_S, StatusBoard, split_status_name


def test_status_names():
    assert split_status_name('/rwpend/sim: plant') == ('/rwpend', 'sim')
    assert split_status_name('/rig2/controller') == ('/rig2', 'controller')
    assert split_status_name('/a/b/driver: serial link') == ('/a/b', 'driver')
    assert split_status_name('controller') == ('/', 'controller')


def board(now=100.0, estop='False', late='0.050', plant_level=0, plant_msg='running', ctrl=(0, 'auto/balance')):
    b = StatusBoard()
    b.update('/rwpend/sim: plant', plant_level, plant_msg,
             {'estop': estop, 'loop_late_percent': late, 'loop_late_commands': '5', 'timeouts': '0',
              'loop_dead': 'False'}, now)
    b.update('/rwpend/controller', ctrl[0], ctrl[1], {'mode': 'auto', 'law': 'balance'}, now)
    b.update('/rwpend/estimator', 0, 'observer: ok', {'estimator': 'observer'}, now)
    b.update('/rig2/controller', 2, 'stale state', {'mode': 'off', 'law': 'off'}, now)
    b.update('/rwpend/console: e-stop', 1, 'e-stop raised from the console', {}, now)
    return b


def lights(b, now=100.0):
    return {x.key: x for x in b.lights('/rwpend', now)}


def test_lights_of_a_healthy_rig():
    ls = lights(board())
    assert [ls[k].level for k in ('late', 'timeouts', 'faults', 'estop')] == ['ok', 'ok', 'ok', 'ok']
    assert set(ls) >= {'node:sim', 'node:controller', 'node:estimator'}
    assert 'node:console' not in ls, "the console's own e-stop record is not a node"
    assert ls['node:controller'].facts == {'mode': 'auto', 'law': 'balance'}


def test_late_timeouts_faults_estop():
    assert lights(board(late='0.5'))['late'].level == 'warn'
    assert lights(board(late='2.0'))['late'].level == 'error'
    ls = lights(board(plant_level=1, plant_msg='command timeout: no command for 3 samples, u = 0'))
    assert ls['timeouts'].level == 'warn' and 'command timeout' in ls['timeouts'].message
    assert lights(board(ctrl=(2, 'stale state: u = 0')))['faults'].level == 'error'
    e = lights(board(estop='True', plant_level=2, plant_msg='e-stop latched'))['estop']
    assert e.level == 'error' and 'E-STOP' in e.message


def test_stale_nodes():
    ls = lights(board(), now=100.0 + STALE_AFTER_S + 1)
    assert ls['node:sim'].level == 'stale' and ls['late'].level == 'stale'
    assert StatusBoard().lights('/rwpend', 0.0)[0].level == 'stale'


def test_overview_rows():
    b = board(estop='True')
    assert b.rigs() == ['/rig2', '/rwpend']
    row = b.summary('/rwpend', 100.0)
    assert row['mode'] == 'auto' and row['law'] == 'balance' and row['estop'] and row['plant'] == 'sim'
    assert row['level'] == 'error', 'the worst light: the e-stop'
    assert board().summary('/rwpend', 100.0)['level'] == 'ok'
    assert board(late='0.5').summary('/rwpend', 100.0)['level'] == 'warn'
    assert b.summary('/rig2', 100.0)['level'] == 'error'
    assert StatusBoard().summary('/none', 0.0)['level'] == 'stale'


def test_the_estop_light_and_state_follow_the_plant():
    """Raised from this console, cleared elsewhere (./rwpend estop --clear): the light and the
    board's e-stop say clear (the console used to keep its own raise)."""
    b = board(now=100.0)
    b.estop_requested('/rwpend', True, 100.5)
    assert lights(b, 100.6)['estop'].level == 'warn', 'sent, not reported yet'
    b.update('/rwpend/sim: plant', 2, 'e-stop latched: motor at zero', {'estop': 'True'}, 100.7)
    st = b.estop('/rwpend', 100.8)
    assert (st.state, st.by) == ('raised', 'console') and lights(b, 100.8)['estop'].level == 'error'
    assert b.summary('/rwpend', 100.8)['estop'] is True
    b.update('/rwpend/sim: plant', 0, 'running', {'estop': 'False'}, 105.0)
    st = b.estop('/rwpend', 105.1)
    assert (st.state, st.by) == ('clear', 'elsewhere') and 'cleared elsewhere' in st.text
    e = lights(b, 105.1)['estop']
    assert e.level == 'ok' and e.message == st.text
    assert b.summary('/rwpend', 105.1)['estop'] is False
    assert b.estop('/rig2', 105.1).state == 'unknown', 'a rig without a plant report'
    assert b.estop('/rwpend', 105.0 + STALE_AFTER_S + 1).state == 'unknown', 'the rig lost'
