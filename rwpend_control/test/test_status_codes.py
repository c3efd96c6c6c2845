"""The codes of controller/status (pure): switch_code and fault_code are the .msg's constants and
the supervisor sets one wherever it sets a reason or a fault."""
from __future__ import annotations

import math

import pytest

from rwpend_control import status_codes as sc
from rwpend_control.supervisor import Controller
from rwpend_model.rig import load_rig
from rwpend_ros.msglayout import constants

rig = load_rig()
H = rig.sample_period


def test_the_codes_are_the_constants_of_the_msg_and_distinct():
    c = constants('rwpend_msgs/msg/ControllerStatus')
    names = [n for n in dir(sc) if n.startswith(('SWITCH_', 'FAULT_'))]
    assert {n: getattr(sc, n) for n in names} == c
    for kind in ('SWITCH_', 'FAULT_'):
        values = [v for n, v in c.items() if n.startswith(kind)]
        assert len(set(values)) == len(values) and all(0 <= v < 256 for v in values)
    assert sc.code_name(sc.FAULT_STALE_STATE) == 'FAULT_STALE_STATE'
    assert sc.code_name(sc.SWITCH_CATCH, 'SWITCH') == 'SWITCH_CATCH'


def test_the_generated_message_has_the_same_constants():
    msg = pytest.importorskip('rwpend_msgs.msg')
    for name, value in constants('rwpend_msgs/msg/ControllerStatus').items():
        assert getattr(msg.ControllerStatus, name) == value, name
    m = msg.ControllerStatus()
    assert (m.switch_code, m.fault_code) == (sc.SWITCH_START, sc.FAULT_NONE)


def feed(c, k, theta, theta_dot=0.0, wheel_rate=0.0):
    """State sample k (stamp k h) to ``c``: (u, status)."""
    return c.update(k * H, k, theta, theta_dot, 0.0, wheel_rate, 0.0)


def test_switch_codes_go_with_their_reasons():
    c = Controller(rig)
    assert (c.switch_code, c.reason) == (sc.SWITCH_START, 'start')
    feed(c, 0, 0.0)                             # hanging: auto starts with the swing-up
    assert c.set_mode('auto')[0] and (c.law, c.switch_code) == ('swingup', sc.SWITCH_SET_MODE)
    _, st = feed(c, 1, math.pi - 0.1)
    assert st.law == 'catch' and st.switch_code == sc.SWITCH_CATCH and st.event.code == sc.SWITCH_CATCH
    _, st = feed(c, 2, math.pi - 1.0)
    assert st.law == 'swingup' and st.switch_code == sc.SWITCH_FALL and st.reason.startswith('fall')
    c.set_mode('off')
    _, st = feed(c, 3, math.pi)
    assert st.switch_code == sc.SWITCH_SET_MODE and st.event.code == sc.SWITCH_SET_MODE
    assert c.set_mode('balance')[0]
    _, st = feed(c, 4, math.pi - 1.0)
    assert (st.mode, st.switch_code) == ('off', sc.SWITCH_FELL) and st.switch_code in sc.SAFETY_SWITCHES
    assert c.estop(True) and c.switch_code == sc.SWITCH_ESTOP_RAISED
    assert c.estop(False) and c.switch_code == sc.SWITCH_ESTOP_CLEARED
    assert c.set_mode('wheel_velocity')[0]
    _, st = feed(c, 5, 0.0, wheel_rate=10 * rig.omega_max / 11)
    assert (st.law, st.switch_code) == ('brake', sc.SWITCH_OVERSPEED)
    _, st = feed(c, 6, 0.0, wheel_rate=0.0)
    assert (st.law, st.switch_code) == ('off', sc.SWITCH_WHEEL_BRAKED)


def test_fault_codes_go_with_their_faults():
    c = Controller(rig, mode='wheel_velocity')
    _, st = feed(c, 0, 0.0)
    assert (st.fault, st.fault_code) == ('', sc.FAULT_NONE)
    _, st = feed(c, 1, float('nan'))
    assert st.fault.startswith('bad state') and st.fault_code == sc.FAULT_BAD_STATE
    _, st = feed(c, 0, 0.0)                     # seq 0 again: out of order, not answered
    assert not st.answer and st.fault_code == sc.FAULT_OUT_OF_ORDER
    st = c.check_stale(1.0)
    assert st.fault.startswith('stale state') and st.fault_code == sc.FAULT_STALE_STATE
    assert sc.FAULT_STALE_STATE in sc.LOOP_FAULTS and sc.FAULT_BAD_STATE in sc.LOOP_FAULTS
    st = c.internal_error(1.0, 9, ZeroDivisionError('x'))
    assert st.fault == 'internal error: ZeroDivisionError: x' and st.fault_code == sc.FAULT_INTERNAL
    assert st.switch_code == c.switch_code and st.u == 0.0
