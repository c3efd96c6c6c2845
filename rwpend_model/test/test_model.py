"""Unit tests of the rig parameters and the plant model (no ROS)."""
from __future__ import annotations

import math

import pytest

from rwpend_model.plant import Plant
from rwpend_model.rig import BOOK_G, Rig, book_rig, load_rig, read_params_file


def test_book_values_are_derived_from_physical_data():
    """Section 2.6 / (2.15): a, b_p, b_r, omega_p as printed (78.4, 1.08, 198, 8.856) with g = 9.91."""
    r = book_rig()
    assert r.g == BOOK_G
    assert r.a == pytest.approx(78.4, abs=0.05)
    assert r.b_p == pytest.approx(1.08, abs=0.005)
    assert r.b_r == pytest.approx(198, abs=0.5)
    assert r.omega_p == pytest.approx(8.856, abs=0.001)
    assert r.omega_p ** 2 == pytest.approx(r.a)


def test_physical_g_is_the_default():
    """ERRATA E01: the shipped YAML has g = 9.81 and a follows from it."""
    r = load_rig()
    assert r.g == 9.81
    assert r.a == pytest.approx(r.mgl / r.J)
    assert r.a == pytest.approx(77.63, abs=0.01)


def test_shipped_yaml_is_a_ros_params_file():
    from rwpend_model.rig import default_rig_file
    params = read_params_file(default_rig_file(), '/rwpend/sim')
    assert params['rig.counts_per_rev'] == 4000
    assert params['rig.sample_period'] == 0.001
    assert params['rig.u_max'] == 10.0


@pytest.mark.parametrize('change', [dict(g=-1.0), dict(j_r=0.0), dict(m_p=float('nan')),
                                    dict(sample_period=1.0), dict(counts_per_rev=4000.5),
                                    dict(friction_coulomb_pos=-0.1)])
def test_invalid_rig_is_refused_with_reason(change):
    with pytest.raises(ValueError, match='rig.' + next(iter(change))):
        Rig().replace(**change)


def test_unknown_rig_parameter_is_refused():
    with pytest.raises(ValueError, match='unknown'):
        Rig.from_params({'rig.gg': 9.81})


def test_bad_params_file(tmp_path):
    f = tmp_path / 'x.yaml'
    f.write_text('just: text\n')
    with pytest.raises(ValueError, match='ros__parameters'):
        read_params_file(f)
    f.write_text('[unclosed\n')
    with pytest.raises(ValueError, match='cannot read'):
        read_params_file(f)
    # libyaml's refusal is reported with the pure-Python loader's message: the line and a caret
    f.write_text('a:\n  ros__parameters:\n    x: 1\n     y: 2\n')
    with pytest.raises(ValueError, match=r'line 4, column 7:\n\s+y: 2\n\s+\^'):
        read_params_file(f)


def test_load_yaml_is_yaml_safe_load():
    import yaml
    from rwpend_model.rig import default_rig_file, load_yaml
    for text in (default_rig_file().read_text(), 'x: 1e3\ny: .5\nz: 0x10\nw: yes\nv: ~\nu: [1, {a: b}]\n', '', '- 1\n'):
        assert load_yaml(text) == yaml.safe_load(text)


def test_energy_conserved_without_friction():
    """RK4 on (2.15): total energy drift over 60 s of free swing (no friction, no input)."""
    r = book_rig()
    p = Plant(r, theta=2.0, friction=False, motor_lag=False, pwm=False)
    e0 = p.total_energy()
    for _ in range(60000):
        p.step(0.0)
    assert abs(p.total_energy() - e0) / e0 < 1e-9


def test_small_swing_period_rotor_stuck():
    """Free swing with the rotor stuck: omega_p' = sqrt(mgl/(J+J_r)) (Section 2.3, Experiment 1)."""
    r = book_rig(pendulum_energy_time_constant=0.0)
    p = Plant(r, theta=0.05)
    crossings = []
    prev = p.state.theta
    for k in range(5000):
        p.step(0.0)
        th = p.state.theta
        if prev > 0 >= th:
            crossings.append((k + 1) * r.sample_period)
        prev = th
    period = (crossings[-1] - crossings[0]) / (len(crossings) - 1)
    assert period == pytest.approx(2 * math.pi / r.omega_p_stuck, rel=2e-3)


def test_wheel_acceleration_and_saturation():
    """theta_r'' = b_r (u - F); |u| <= 10, NaN -> 0 (the amplifier realises nothing else)."""
    r = book_rig()
    p = Plant(r, friction=False, motor_lag=False, pwm=False, back_emf=False)
    p.step(50.0)
    assert p.u_held == 10.0
    assert p.state.wheel_rate == pytest.approx(r.b_r * 10 * r.sample_period, rel=0.05)
    assert p.quantize_command(float('nan')) == 0.0
    assert p.quantize_command(-1e9) == -10.0


def test_back_emf_cutoff_limits_wheel_speed():
    r = book_rig()
    p = Plant(r, friction=False)
    for _ in range(10000):
        p.step(10.0)
    w_rel = p.state.wheel_rate - p.state.theta_dot
    assert w_rel == pytest.approx(r.omega_max, rel=0.02)


def test_friction_model_3_17():
    r = book_rig()
    assert r.friction(100.0) == pytest.approx(0.99 + 1.16)
    assert r.friction(-100.0) == pytest.approx(-0.97 - 1.17)
    assert r.friction(0.0) == 0.0


def test_counts_quantize_angles():
    r = book_rig()
    p = Plant(r, theta=math.pi, wheel_angle=math.pi + 2 * math.pi * 10)
    pc, mc = p.counts()
    assert pc == 2000
    assert mc == 40000


def test_tap_and_invalid_initial_state():
    p = Plant(book_rig())
    p.tap(1.5)
    assert p.state.theta_dot == 1.5
    with pytest.raises(ValueError):
        p.tap(float('inf'))
    with pytest.raises(ValueError):
        Plant(book_rig(), theta=float('nan'))


# ---------------------------------------------------------------- complete rig files (--rig, --plant-rig)
def _rig_text(drop: str = '', extra: str = '') -> str:
    from rwpend_model.rig import default_rig_file
    lines = [ln for ln in default_rig_file().read_text().splitlines()
             if not (drop and ln.strip().startswith(drop + ':'))]
    return '\n'.join(lines + ([f'      {extra}'] if extra else [])) + '\n'


def test_load_rig_file_reads_a_complete_file(tmp_path):
    from rwpend_model.rig import load_rig_file
    f = tmp_path / 'rig.yaml'
    f.write_text(_rig_text())
    assert load_rig_file(f) == load_rig()


@pytest.mark.parametrize('drop, extra, match', [('friction_breakaway', '', 'missing rig key.*friction_breakaway'),
                                                ('', 'm_wheel: 0.1', 'unknown key.*m_wheel')])
def test_load_rig_file_refuses_missing_and_unknown_keys(tmp_path, drop, extra, match):
    """A missing key would silently become the book's value in every node: refused, named."""
    from rwpend_model.rig import load_rig_file
    f = tmp_path / 'rig.yaml'
    f.write_text(_rig_text(drop, extra))
    with pytest.raises(ValueError, match=match):
        load_rig_file(f)


def test_rig_differences_name_data_and_derived_values():
    from rwpend_model.rig import format_differences, rig_differences
    base = load_rig()
    heavy = base.replace(m_p=base.m_p * 1.15)
    diffs = rig_differences(base, heavy)
    names = [d[0] for d in diffs]
    assert names[0] == 'm_p' and {'a', 'b_p'} <= set(names) and 'b_r' not in names
    assert 'm_p 0.2164 -> 0.24886 (+15.0 %)' in format_differences(diffs)
    assert rig_differences(base, base) == [] and format_differences([]) == ''


def test_a_hand_holds_the_pendulum_and_lets_go():
    p = Plant(book_rig(), wheel_rate=30.0)
    for _ in range(50):
        p.step(0.0)
    rel = p.state.wheel_angle - p.state.theta
    p.hold(0.35)
    s = p.state
    assert (s.theta, s.theta_dot, s.wheel_rate, s.stuck) == (0.35, 0.0, 0.0, True)
    assert s.wheel_angle - s.theta == pytest.approx(rel)
    p.step(0.0)
    assert p.state.theta < 0.35, 'released: it swings'
    with pytest.raises(ValueError):
        p.hold(float('nan'))


def _bits(values) -> list:
    """Floats as their exact bits (float.hex tells -0.0 from 0.0, which == does not)."""
    return [v.hex() if isinstance(v, float) else v for v in values]


@pytest.mark.parametrize('back_emf, friction', [(True, True), (False, True), (True, False)])
def test_free_run_is_the_plain_substeps_bit_for_bit(back_emf, friction):
    """Plant._free_run (the integrator's fast path: the RK4 sub-steps with (2.15) written out
    at each stage) gives exactly what the plain sub-steps through _deriv give: the states, the
    torque of the lag, where it stops at a zero of the relative speed; disturbance, the
    back-EMF cut-off (2.13) and zero relative speed included."""
    import random
    p = Plant(load_rig(), back_emf=back_emf, friction=friction)
    p.disturbance = 0.37
    fast = p._free_run()
    rnd = random.Random(3)
    stops = 0
    for _ in range(3000):
        th, thd, thr, thrd = (rnd.uniform(-7, 7), rnd.uniform(-30, 30), rnd.uniform(-50, 50),
                              rnd.uniform(-1000, 1000))
        if rnd.random() < 0.3:
            thrd = thd + rnd.uniform(-0.05, 0.05)     # about to cross zero relative speed
        if rnd.random() < 0.05:
            thrd = thd          # zero relative speed: no kinetic friction
        tau0, u = rnd.uniform(-12, 12), rnd.choice([0.0, rnd.uniform(-12, 12)])
        args = (th, thd, thr, thrd, tau0, u, rnd.randint(1, 5))
        got = fast(*args)
        assert _bits(got) == _bits(p._free_run_plain(*args))
        stops += got[-1]
    assert stops > 100 if friction else stops == 0


@pytest.mark.parametrize('kwargs', [{}, {'back_emf': False}, {'friction': False}, {'motor_lag': False},
                                    {'theta': 3.1, 'wheel_rate': 700.0}, {'wheel_rate': 900.0},
                                    {'bracket': True, 'wheel_rate': 5.0}])
def test_step_is_the_plain_integration_bit_for_bit(kwargs):
    """Plant.step through the fast sub-steps (made once per disturbance, the lag's decays made
    once) gives the states of the same step through the plain sub-steps, sample for sample:
    stick and slip (3.17), taps and torque pulses included."""
    import random
    rig = load_rig()
    fast, plain = Plant(rig, **kwargs), Plant(rig, **kwargs)
    plain._free_motion = lambda: plain._free_run_plain
    rnd = random.Random(5)
    for k in range(3000):
        u = rnd.choice([0.0, rnd.uniform(-12, 12), rnd.uniform(-0.5, 0.5)])
        if k % 500 == 250 and not kwargs.get('bracket'):
            for p in (fast, plain):
                p.tap(0.3)
        if k % 700 == 100 and not kwargs.get('bracket'):
            d = rnd.uniform(-3, 3)
            fast.disturbance, plain.disturbance = d, d
        if k % 700 == 300:
            fast.disturbance = plain.disturbance = 0.0
        fast.step(u)
        plain.step(u)
        assert _bits([*fast._x, fast._tau, fast._stuck, fast._friction, fast.t]) == \
            _bits([*plain._x, plain._tau, plain._stuck, plain._friction, plain.t])
