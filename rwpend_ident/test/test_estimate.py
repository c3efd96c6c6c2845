"""The grey-box fits on synthetic data with known parameters: the plant model run with the heavy
example rig as truth (no ROS).  Tolerances per parameter are stated beside each assertion; each
true value must also lie within the fit's 95 % confidence interval."""
from __future__ import annotations

import math

import numpy as np
import pytest

from rwpend_ident import estimate as E
from rwpend_ident.records import IdentError, check_rest_before, commands, first_input, ramps, response
from rwpend_ident.rigfile import example_rig_file
from rwpend_lab.data import RunData
from rwpend_model.plant import Plant
from rwpend_model.rig import load_rig, load_rig_file

BASE = load_rig()
TRUTH = load_rig_file(example_rig_file())
H = BASE.sample_period


def run_data(u_of, n: int, rig=TRUTH, **initial) -> RunData:
    """Counts and commands of an open-loop run of the plant model; ``u_of(k, plant)`` -> u."""
    p = Plant(rig, **initial)
    pc, mc, u = np.zeros(n), np.zeros(n), np.zeros(n)
    for k in range(n):
        pc[k], mc[k] = p.counts()
        u[k] = u_of(k, p)
        p.step(u[k])
    z = np.zeros(n)
    return RunData(h=H, t=np.arange(n) * H, pc=pc, mc=mc, u=u, theta=z, theta_dot=z, wheel_angle=z,
                   wheel_rate=z, friction=z)


def pulse(u0: float, width: float) -> RunData:
    k0, k1 = 600, 600 + int(round(width / H))
    return run_data(lambda k, p: u0 if k0 <= k < k1 else 0.0, 1200)


def ramp_run() -> RunData:
    """Ramps at 2 units/s from rest, +then-, each cut when the rotor slips faster than 5 rad/s."""
    state = {'sign': 1.0, 'start': 600, 'done': False}

    def u_of(k, p):
        s = p.state
        if state['done'] or k < state['start']:
            return 0.0
        if abs(s.wheel_rate - s.theta_dot) > 5.0:
            if state['sign'] < 0:
                state['done'] = True
            state['sign'], state['start'] = -1.0, k + 800
            return 0.0
        return state['sign'] * 2.0 * (k - state['start']) * H
    return run_data(u_of, 3600)


@pytest.fixture(scope='module')
def fits():
    data = {'pulse+6': pulse(6.0, 0.03), 'pulse-6': pulse(-6.0, 0.03), 'step+10': pulse(10.0, 0.04),
            'step-10': pulse(-10.0, 0.04)}
    # OPEN (issue 24): on these noise-free runs a window longer than 50 ms after the rotor sticks
    # (identify's default is 150 ms, which puts b_p within its interval on the simulator) moves b_r
    # by +0.01 % and T_e by +0.5 %, beyond intervals that only know the quantization; 50 ms here
    recs = [response(n, BASE, d, first_input(n, d), after=0.05) for n, d in data.items()]
    stiction = ramps('stiction', BASE, ramp_run())
    rng = np.random.default_rng(3)
    w = np.array([40.0, 80.0, 150.0, 250.0, 400.0, -40.0, -80.0, -150.0, -250.0, -400.0])
    s = np.full(w.size, 0.002)
    u = np.array([TRUTH.friction(x) for x in w]) + rng.normal(0, 0.002, w.size)
    fixed = {'wp2': TRUTH.omega_p_stuck ** 2, 'damping': TRUTH.pendulum_damping * TRUTH.J / (TRUTH.J + TRUTH.j_r),
             'breakaway': E.breakaway_guess(BASE, stiction)}
    dyn = E.fit_dynamics(BASE, recs, (w, u, s), fixed)
    return dyn, E.fit_breakaway(E.model_rig(BASE, dyn.x, fixed), stiction), fixed


#: relative tolerance per parameter (the truth also within the 95 % CI)
TOL = {'b_r': 0.005, 'rho': 0.03, 'motor_time_constant': 0.05, 'friction_coulomb_pos': 0.01,
       'friction_viscous_pos': 0.01, 'friction_coulomb_neg': 0.01, 'friction_viscous_neg': 0.01,
       'friction_breakaway': 0.01}


@pytest.mark.parametrize('name', list(TOL))
def test_pulses_friction_curve_and_ramps_recover_the_truth(fits, name):
    dyn, brk, _ = fits
    res = brk if name == 'friction_breakaway' else dyn
    true = {'b_r': TRUTH.b_r, 'rho': TRUTH.b_p / TRUTH.b_r}.get(name, getattr(TRUTH, name, None))
    got, ci = res[name], res.ci(name)
    assert abs(got - true) <= TOL[name] * abs(true), f'{name}: {got} vs {true}'
    assert abs(got - true) <= ci, f'{name}: {got} +- {ci} misses {true}'


def test_the_breakaway_is_resolved_to_half_an_amplifier_step_at_best(fits):
    _, brk, fixed = fits
    assert brk.ci('friction_breakaway') >= TRUTH.u_max / TRUTH.pwm_steps / 2
    assert abs(fixed['breakaway'] - TRUTH.friction_breakaway) < 0.03, 'the first guess from the first count'
    assert len(brk.extra['per_ramp']) == 2


def test_free_swing_fit():
    """Experiment 1: omega_p'^2 within 0.01 %, the damping within 1 %, truth within the CIs."""
    th0 = math.radians(20)
    d = run_data(lambda k, p: 0.0, 8000, theta=th0, wheel_angle=th0)
    res = E.fit_swing(BASE, d)
    wp2 = TRUTH.omega_p_stuck ** 2
    c = TRUTH.pendulum_damping * TRUTH.J / (TRUTH.J + TRUTH.j_r)
    assert abs(res['wp2'] - wp2) <= min(1e-4 * wp2, res.ci('wp2'))
    assert abs(res['damping'] - c) <= min(0.01 * c, res.ci('damping'))


def test_free_swing_starts_at_a_turning_point_and_refuses_a_slipping_rotor():
    """Tapped instead of released: the rotor slips for some ms, then sticks; the fit starts at the
    first turning point.  A rotor that turns later (a loose wheel) is refused."""
    d = run_data(lambda k, p: 0.0, 4000, theta_dot=3.0)
    res = E.fit_swing(BASE, d)
    assert res['wp2'] == pytest.approx(TRUTH.omega_p_stuck ** 2, rel=1e-4) and res.extra['k0'] > 100
    d.mc[2000:] += np.arange(2000) // 100
    with pytest.raises(IdentError, match='rotor turned .* during the free swing'):
        E.fit_swing(BASE, d)


def test_free_swing_after_a_hand_held_the_pendulum_starts_after_the_hold():
    """On the rig the student holds the pendulum at 20 degrees, then lets go: the swing is fitted
    from the first turning point after the release (from the middle of the hold, the damping came
    out 188 +- 1286 s instead of 40 s), and the damping is found as without the hold."""
    th0 = math.radians(20)
    hold = range(150, 1650)

    def hand(k, p):
        if k in hold:
            p.hold(th0)
        return 0.0
    d = run_data(hand, 9500)
    res = E.fit_swing(BASE, d)
    c = TRUTH.pendulum_damping * TRUTH.J / (TRUTH.J + TRUTH.j_r)
    assert res.extra['k0'] > hold[-1]
    assert abs(res['damping'] - c) <= min(0.01 * c, res.ci('damping'))
    assert res['wp2'] == pytest.approx(TRUTH.omega_p_stuck ** 2, rel=1e-4)


def test_swing_start():
    assert E.swing_start(np.array([0.9, 2.0, 2.36, 2.72, 3.08, 3.44])) == 2.0
    assert E.swing_start(np.array([0.0, 0.36, 0.72, 1.08, 1.44])) == 0.0
    assert E.swing_start(np.array([0.0, 0.36, 1.5])) is None


def test_a_pendulum_moving_before_the_pulse_is_refused():
    d = run_data(lambda k, p: 3.0 if 600 <= k < 650 else 0.0, 900, theta_dot=0.3, wheel_rate=0.3)
    with pytest.raises(IdentError, match='pulse: pendulum not at rest'):
        check_rest_before('pulse', BASE, d, first_input('pulse', d))


def test_a_recording_without_commands_is_refused():
    d = pulse(6.0, 0.03)
    d.u[:] = np.nan
    with pytest.raises(IdentError, match='no commands in the recording'):
        commands('pulse+6', d)
