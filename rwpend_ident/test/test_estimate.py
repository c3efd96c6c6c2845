"""The grey-box fits on synthetic data with known parameters: the plant model run with the heavy
example rig as truth (no ROS).  Tolerances per parameter are stated beside each assertion; each
true value must also lie within the fit's 95 % confidence interval."""
from __future__ import annotations

import math

import numpy as np
import pytest

from rwpend_ident import estimate as E
from rwpend_ident.fit import FitResult
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


# ------------------------------------------------------------------ the free swing on the rig (the open defect)
C_TRUE = TRUTH.pendulum_damping * TRUTH.J / (TRUTH.J + TRUTH.j_r)


def lifted_swing(n: int = 12000, before: float = math.radians(7.5), lift_at: int = 2300, hold_s: float = 1.5,
                 shaky: int = 0, rig=TRUTH) -> RunData:
    """The swing run as the emulated rig recorded it: the pendulum still swinging ``before`` rad from the
    run before, lifted to 20 degrees at ``lift_at`` and held ``hold_s`` s (``shaky``: a hand that
    moves it by that many counts), then let go."""
    th0, dl = math.radians(20), rig.count_angle
    hold = range(lift_at, lift_at + int(round(hold_s / H)))

    def hand(k, p):
        if k in hold:
            p.hold(th0 + (shaky * dl * math.sin(k / 37.0) if shaky else 0.0))
        return 0.0
    return run_data(hand, n, rig=rig, theta=before, wheel_angle=before)


def test_a_swing_left_from_the_run_before_the_lift_is_not_fitted():
    """The open defect of the emulated rig: the pendulum swung 85 counts from the validation run when
    the hand lifted it; the fit started at a turning point of that swing, through the lift and the
    hold (a = 69.9 / 77.8 against 78.17, an energy time constant of 5.7 s or 1e31 s against 40 s,
    136 counts rms), without being refused.  Now the swing starts after the hold."""
    d = lifted_swing()
    let_go = 2300 + 1500
    release = E.release_index(d.pc, H, TRUTH.count_angle)
    assert let_go <= release < let_go + 30        # the count moves by 2 some ms after the hand let go
    res = E.fit_swing(TRUTH, d)
    assert res.extra['release'] == release and res.extra['k0'] > release
    assert res['wp2'] == pytest.approx(TRUTH.omega_p_stuck ** 2, rel=1e-4)
    assert abs(res['damping'] - C_TRUE) <= min(0.01 * C_TRUE, res.ci('damping'))
    assert res.rms * E.QUANT < 0.5


def test_a_swing_fitted_through_a_shaky_hold_is_refused_with_the_reason():
    """A hand that does not hold still (3 counts of jitter: no hold found) after an earlier swing:
    the fit covers the earlier swing and the lift; refused (the rms residual), no number."""
    d = lifted_swing(shaky=3)
    assert E.release_index(d.pc, H, TRUTH.count_angle) == 0
    with pytest.raises(IdentError, match=r'swing: the free swing \(2.15\) with the rotor stuck does not fit the '
                                         r'recording: rms residual \d+\.\d counts'):
        E.fit_swing(TRUTH, d)


def test_a_pendulum_stopped_by_a_hand_during_the_swing_is_refused():
    """Grabbed for 50 ms in the middle of the swing and let go again (too short to be the hold)."""
    th0 = math.radians(20)
    stop = {}

    def hand(k, p):
        if 5000 <= k < 5050:
            stop.setdefault('at', p.state.theta)
            p.hold(stop['at'])
        return 0.0
    d = run_data(hand, 9000, theta=th0, wheel_angle=th0)
    with pytest.raises(IdentError, match='does not fit the recording'):
        E.fit_swing(TRUTH, d)


def test_a_swing_with_the_motor_driven_is_refused():
    """A command below the breakaway keeps the rotor stuck (the torque is internal), but the swing
    is not the experiment's: refused."""
    th0 = math.radians(20)
    d = run_data(lambda k, p: 0.2 if 3000 <= k < 3100 else 0.0, 8000, theta=th0, wheel_angle=th0)
    with pytest.raises(IdentError, match=r'motor was driven during the free swing \(u = 0.2 at t = 3.000 s, '
                                         r'100 samples\)'):
        E.fit_swing(TRUTH, d)


def test_a_swing_that_does_not_decay_measurably_is_refused():
    """An energy time constant of 1e6 s on an 8 s record: the damping is not resolved from 0 (the
    open defect reported 3.5e25 s instead), refused: the time constant is not measured."""
    rig = TRUTH.replace(pendulum_energy_time_constant=1e6)
    th0 = math.radians(20)
    d = run_data(lambda k, p: 0.0, 8000, rig=rig, theta=th0, wheel_angle=th0)
    with pytest.raises(IdentError, match=r'decay of the free swing is not measured: damping c = .* energy time '
                                         r'constant \(Fig. 2.3\) is unknown'):
        E.fit_swing(rig, d)


def test_release_index():
    """No hold: 0; still hanging at rest is not a hold (it is not lifted); the turning points of a
    free swing of 5 degrees and more are not holds; the last of two holds counts."""
    dl = TRUTH.count_angle
    lifted = round(math.radians(20) / dl)
    assert E.release_index(np.zeros(3000), H, dl) == 0
    d = run_data(lambda k, p: 0.0, 6000, theta=math.radians(5), wheel_angle=math.radians(5))
    assert E.release_index(d.pc, H, dl) == 0
    pc = np.r_[np.zeros(500), np.full(400, lifted), np.zeros(500), np.full(300, -lifted) + np.arange(300) % 3,
               np.zeros(200)]
    assert E.release_index(pc, H, dl) == 500 + 400 + 500 + 300 - 1
    assert E.release_index(np.full(200, lifted), H, dl) == 0          # held 0.2 s: shorter than HOLD_S


def swing_result(rms: float, c: float, c_ci: float, wp2: float = 77.7) -> FitResult:
    return FitResult(['wp2', 'damping', 'theta0', 'theta_dot0'], np.array([wp2, c, 0.35, 0.0]), np.eye(4),
                     np.array([0.001, c_ci, 1e-5, 1e-4]), 10000, rms, 10)


def test_swing_problem_says_what_is_not_measured():
    assert E.swing_problem(swing_result(1.0, 0.025, 1e-5), 222) is None
    # the open defect's fits: 136 counts rms (a = 69.9), 80 counts with the damping on its bound 0
    assert 'rms residual 136.0 counts' in E.swing_problem(swing_result(136 / E.QUANT, 0.17, 0.01), 222)
    assert 'does not fit' in E.swing_problem(swing_result(80 / E.QUANT, 1e-26, 1e-3), 222)
    # the limit: 3 counts, or 2 % of the amplitude
    assert E.swing_problem(swing_result(2.9 / E.QUANT, 0.025, 1e-5), 100) is None
    assert E.swing_problem(swing_result(3.1 / E.QUANT, 0.025, 1e-5), 100) is not None
    assert E.swing_problem(swing_result(3.1 / E.QUANT, 0.025, 1e-5), 200) is None
    assert 'not measured: damping c = 1e-06 +- 2e-05' in E.swing_problem(swing_result(1.0, 1e-6, 2e-5), 222)
    assert 'not measured' in E.swing_problem(swing_result(1.0, 0.0, 1e-5), 222)
    assert 'bound damping = 10' in E.swing_problem(swing_result(1.0, 10.0, 1e-3), 222)
    assert 'bound wp2 = 1e+04' in E.swing_problem(swing_result(1.0, 0.025, 1e-5, wp2=1e4), 222)


def test_a_swing_with_samples_missing_says_how_many():
    """As every run's check (records.commands): the count, which tells the real-time path's shortfall."""
    th0 = math.radians(20)
    d = run_data(lambda k, p: 0.0, 4000, theta=th0, wheel_angle=th0)
    d.pc[1000:1204] = np.nan
    with pytest.raises(IdentError, match='swing: 204 encoder samples missing in the recording'):
        E.fit_swing(TRUTH, d)


def test_a_ramp_whose_rotor_was_not_stuck_is_left_out_and_said():
    """A rotor count that changes as a ramp begins (|u| under 3 amplifier steps) is no break-away:
    that ramp is left out and said, the other one kept; with none left, the reason."""
    d = ramp_run()
    u = commands('stiction', d)
    on = np.nonzero(u != 0)[0]
    second = int(on[np.nonzero(np.diff(on) > 0.2 / H)[0][0] + 1])
    d.mc[second + 2:] += 1.0                       # the second ramp's count flickers at its start
    said = []
    kept = ramps('stiction', BASE, d, log=said.append)
    assert len(kept) == 1 and kept[0].k0 < second
    assert len(said) == 1 and '1 of 2 ramps left out' in said[0] and 'not stuck' in said[0]
    assert E.first_turn_torques(kept)[0] > 1.5     # the kept ramp broke away near the truth's 1.6
    d.mc[on[0] + 2:] += 1.0                        # the first one too: nothing left to fit
    with pytest.raises(IdentError, match='not stuck when it began'):
        ramps('stiction', BASE, d)


# ------------------------------------------------------------------ a refusal judged on commands that came late
def _refused_at(d: RunData, t: float, held) -> RunData:
    d.faults = [(t, 4, 'law fault: procedures.py: NotReady: saturation reached at a wheel speed of -199 rad/s')]
    d.u_held = held
    return d


def test_a_refusal_the_motor_saw_is_the_rigs():
    from rwpend_ident.records import refused
    d = run_data(lambda k, p: -10.0 if k >= 200 else 0.0, 1000)
    with pytest.raises(IdentError, match='friction: the step was refused at t = 0.90 s: saturation reached'):
        refused('friction', _refused_at(d, 0.9, d.u.copy()))


def test_a_refusal_judged_while_the_plant_held_0_for_late_commands_says_the_pc_fell_behind():
    # the emulated rig's friction run: the device held 0 (hold limit) for half of the saturated
    # samples, the wheel slowed down, the procedure refused as if the amplifier were too weak
    from rwpend_ident.records import refused
    d = run_data(lambda k, p: -10.0 if k >= 200 else 0.0, 1000)
    held = d.u.copy()
    held[300::2] = 0.0
    with pytest.raises(IdentError, match=r'friction: the commands did not reach the motor whole before the '
                       r'refusal: the plant held the commanded u in 250 of 500 samples .*PC fell behind.*'
                       r'\(the procedure refused the step at t = 0.90 s: saturation reached'):
        refused('friction', _refused_at(d, 0.9, held))
    # a bag without the plant's report: the procedure's verdict as it is
    with pytest.raises(IdentError, match='the step was refused at t = 0.90 s'):
        refused('friction', _refused_at(d, 0.9, None))
