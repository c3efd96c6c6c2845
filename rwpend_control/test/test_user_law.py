"""Laws of one's own (mode ``law``, the lab's --law FILE.py): loading, calling, faults."""
from __future__ import annotations

import math

import pytest

from rwpend_control.supervisor import Controller
from rwpend_control.user_law import LawError, LawState, load_law
from rwpend_model.rig import load_rig

RIG = load_rig()
S = LawState(0.0, math.pi, 0.0, 0.0, 0.0, 0.0)


def write(tmp_path, text, name='law.py'):
    f = tmp_path / name
    f.write_text(text)
    return str(f)


def test_function_and_class_laws_get_the_rig_and_the_params(tmp_path):
    f = write(tmp_path, 'def control(state, params):\n    return params["k"] * params["b_r"] + state.t\n')
    law = load_law(f, '{"k": 2}', RIG)
    assert law(S) == pytest.approx(2 * RIG.b_r)
    c = write(tmp_path, 'class Law:\n    def __init__(self, p):\n        self.n = 0\n'
                        '    def __call__(self, s):\n        self.n += 1\n        return float(self.n)\n', 'c.py')
    law = load_law(c, {}, RIG)
    assert [law(S), law(S)] == [1.0, 2.0]


@pytest.mark.parametrize('text, why', [
    ('def control(state params):\n    return 0\n', 'SyntaxError'),
    ('import no_such_module_xyz\n', 'ModuleNotFoundError'),
    ('x = 1\n', 'neither a class Law'),
    ('class Law:\n    def __init__(self, p):\n        raise KeyError("kpp")\n', 'KeyError'),
])
def test_a_file_that_does_not_load_is_refused_with_the_reason(tmp_path, text, why):
    with pytest.raises(LawError, match=why):
        load_law(write(tmp_path, text), '{}', RIG)
    with pytest.raises(LawError, match='does not exist'):
        load_law(str(tmp_path / 'missing.py'))
    with pytest.raises(LawError, match='JSON'):
        load_law(write(tmp_path, 'def control(s, p):\n    return 0\n', 'ok.py'), '{bad', RIG)


@pytest.mark.parametrize('body, why', [('return 1 / 0', r'ZeroDivisionError.*line 2'),
                                       ('return float("nan")', 'not a finite'),
                                       ('return "3"', 'not a finite'), ('return None', 'not a finite')])
def test_a_faulty_law_gives_u_0_and_mode_off_with_the_reason(tmp_path, body, why):
    law = load_law(write(tmp_path, f'def control(state, params):\n    {body}\n'), '{}', RIG)
    ctrl = Controller(RIG, user_law=law)
    ok, msg = ctrl.set_mode('law')
    assert ok, msg
    u, st = ctrl.update(0.0, 1, math.pi, 0.0, 0.0, 0.0)
    assert u == 0.0 and ctrl.mode == 'off'
    assert st.fault.startswith('law fault:') and st.event is not None
    import re
    assert re.search(why, st.fault), st.fault
    u, st = ctrl.update(0.001, 2, math.pi, 0.0, 0.0, 0.0)
    assert u == 0.0 and st.fault == ''


def test_law_mode_saturates_and_counts_time_from_its_start(tmp_path):
    law = load_law(write(tmp_path, 'def control(s, p):\n    return 100.0 if s.t > 0.0015 else s.t\n'), '{}', RIG)
    ctrl = Controller(RIG, user_law=law)
    assert ctrl.set_mode('law')[0]
    us = [ctrl.update(5.0 + k * 0.001, k, math.pi, 0.0, 0.0, 0.0)[0] for k in range(3)]
    assert us[0] == 0.0 and us[1] == pytest.approx(0.001) and us[2] == RIG.u_max


def test_mode_law_without_a_law_is_refused():
    ok, msg = Controller(RIG).set_mode('law')
    assert not ok and 'no law' in msg


def test_a_law_from_a_package():
    law = load_law('rwpend_control.laws:saturate', '{}', RIG)
    assert law.name == 'saturate'
