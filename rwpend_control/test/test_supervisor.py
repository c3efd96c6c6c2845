"""Controller: validation, mode switching, and closed-loop runs on the Plant (1 ms steps)."""
import math

import pytest

from rwpend_model.plant import Plant
from rwpend_model.rig import load_rig
from rwpend_control import design
from support.closed_loop import balanced_since, simulate
from rwpend_control.supervisor import Controller, ControllerConfig, gains_from_design

rig = load_rig()
PI = math.pi


def ctrl(mode='off', **cfg):
    return Controller(rig, ControllerConfig.designed(rig, **cfg), mode=mode)


# --------------------------------------------------------------------------- configuration
def test_designed_defaults():
    c = ControllerConfig.designed(rig)
    b = design.pddcontrol(rig, '1.5wp', 0.707, 0.2)
    p = design.pddcontrolwpatch(rig, '1.5wp', 0.707)
    assert (c.balance_kpp, c.balance_kdp, c.balance_kdr) == (b.kpp, b.kdp, b.kdr)
    assert (c.patch_kpp, c.patch_kdp, c.patch_kdr) == (p.kpp, p.kdp, p.kdr)
    assert c.patch_kpp == pytest.approx(rig.omega_p * c.patch_kdp)      # E39


def test_set_gains_refuses_unstable_and_keeps_old():
    c = ctrl()
    old = c.config
    ok, why = c.set_gains('balance', kpp=145.0, kdp=16.4)                # E18's printed signs
    assert not ok and 'balance gains refused' in why and 'unstable' in why
    assert c.config is old
    ok, why = c.set_gains('patch', kdr=float('nan'))
    assert not ok and 'finite' in why and c.config is old
    ok, why = c.set_gains('balance', kpp=-1e6)
    assert not ok and 'out of range' in why
    ok, why = c.set_params({'theta_0': 0.3})                              # < theta_s
    assert not ok and 'theta_0' in why
    ok, why = c.set_params({'friction_compensation': 'sometimes'})
    assert not ok and 'friction_compensation' in why
    ok, why = c.set_params({'nonsense': 1.0})
    assert not ok and 'unknown' in why
    ok, why = c.set_params({'wheel.kp': 50.0})                            # far beyond Section 3.5
    assert not ok and 'wheel.kp' in why
    assert c.config is old
    g = design.pdpdcontrol(rig, 'wp', 0.707, 'wp', 1.0)
    ok, why = c.set_gains('balance', kpp=g.kpp, kdp=g.kdp, kpr=g.kpr, kdr=g.kdr)
    assert ok, why
    assert c.config.balance_kpr == g.kpr
    # the PD of (4.2) needs allow_wheel_drift
    pd = design.pd_control(rig, 'wp', 1.0)
    assert not c.set_params({'balance.kpp': pd.kpp, 'balance.kdp': pd.kdp, 'balance.kpr': 0,
                             'balance.kdr': 0})[0]
    assert c.set_params({'balance.kpp': pd.kpp, 'balance.kdp': pd.kdp, 'balance.kpr': 0,
                         'balance.kdr': 0, 'allow_wheel_drift': True})[0]


def test_gains_from_design():
    v = gains_from_design(rig, 'balance', {'kind': 'pdpd', 'omega0': 'wp', 'zeta': 1.0,
                                           'omega2': '0.5wp', 'zeta2': 0.707})
    assert v['balance.kdr'] == pytest.approx(design.pdpdcontrol(rig, 'wp', 1, '0.5wp', 0.707).kdr)
    with pytest.raises(ValueError):
        gains_from_design(rig, 'balance', {'kind': 'lqr'})
    with pytest.raises(ValueError):
        gains_from_design(rig, 'patch', {'omega0': 'fast'})


def test_modes_and_events():
    c = ctrl()
    ok, msg = c.set_mode('dance')
    assert not ok and 'unknown mode' in msg
    u, st = c.update(0.0, 0, 0.0, 0.0, 0.0, 0.0)                          # hanging
    assert u == 0.0 and st.mode == 'off' and st.event is None
    ok, msg = c.set_mode('balance')
    assert not ok and 'balance refused' in msg and c.mode == 'off'
    ok, _ = c.set_mode('swingup', t=0.5)
    assert ok
    u, st = c.update(1.0, 1, 0.0, 0.0, 0.0, 0.0)
    assert st.event is not None and st.event.to == 'swingup/swingup' and st.event.t == 0.5
    assert st.switch_count == 1 and st.last_switch == 0.5 and st.law == 'swingup'
    assert u == rig.u_max                                                  # the kick from rest
    u, st = c.update(1.001, 2, 0.0, 0.0, 0.0, 0.0)
    assert st.event is None
    # auto near upright: catch at once (|x| < theta_s), fall back beyond theta_0
    c.set_mode('auto', t=2.0)
    u, st = c.update(2.0, 3, PI + 0.3, 0.0, 0.0, 0.0)
    assert st.law == 'catch' and 'catch' in st.reason
    u, st = c.update(2.001, 4, PI + 0.7, 0.0, 0.0, 0.0)                    # hysteresis
    assert st.law == 'catch'
    u, st = c.update(2.002, 5, PI + 0.9, 0.0, 0.0, 0.0)
    assert st.law == 'swingup' and st.event is not None and 'fall' in st.reason
    events = c.pop_events()
    assert [e.to for e in events] == ['swingup/swingup', 'auto/swingup', 'auto/catch', 'auto/swingup']
    # balance falls -> off
    c.set_mode('off')
    c.update(3.0, 6, PI + 0.1, 0.0, 0.0, 0.0)
    assert c.set_mode('balance')[0]
    u, st = c.update(3.001, 7, PI + 0.1, 0.0, 0.0, 0.0)
    assert st.law == 'balance' and u != 0.0
    u, st = c.update(3.002, 8, PI + 1.0, 0.0, 0.0, 0.0)
    assert st.mode == 'off' and u == 0.0 and 'fell' in st.reason


def test_bad_state_gives_zero_and_fault():
    c = ctrl('auto')
    c.update(0.0, 0, PI, 0.0, 0.0, 0.0)
    for bad in ((float('nan'), 0.0, 0.0, 0.0, 0.0), (PI, float('inf'), 0.0, 0.0, 0.0),
                (PI, 500.0, 0.0, 0.0, 0.0), (PI, 0.0, 0.0, 1e5, 0.0), (PI, 0.0, 0.0, 0.0, float('nan'))):
        u, st = c.update(0.001, 1, *bad)
        assert u == 0.0 and st.fault.startswith('bad state') and st.mode == 'auto'
    assert c.bad_state_count == 5
    u, st = c.update(0.002, 2, PI + 0.01, 0.0, 0.0, 0.0)
    assert st.fault == '' and u != 0.0


def test_friction_compensation_in_u():
    c = ctrl('wheel_velocity', friction_compensation='model', wheel_ref=0.0, wheel_ki=0.0)
    u, st = c.update(0.0, 0, 0.0, 0.0, 0.0, 50.0)
    assert st.friction_compensation == pytest.approx(rig.friction(50.0))
    assert st.u_unsaturated == pytest.approx(-c.config.wheel_kp * 50.0 + rig.friction(50.0))
    c.set_params({'friction_compensation': 'estimate'})
    u, st = c.update(0.001, 1, 0.0, 0.0, 0.0, 50.0, 1.7)
    assert st.friction_compensation == 1.7


# --------------------------------------------------------------------------- closed loop
@pytest.mark.parametrize('feed', ['counts', 'true'])
def test_auto_swings_up_and_balances(feed):
    c = ctrl('auto')
    tr = simulate(c, Plant(rig), 15.0, feed=feed)
    t_bal = balanced_since(tr, tol=0.05, hold=5.0)
    assert t_bal is not None and t_bal < 10.0, t_bal
    assert any(ev.to == 'auto/catch' for _, ev, _, _ in tr.events)


def test_catch_jump_matches_patched_design():
    """At the swing-up -> catch switch the patched law's pendulum part -kpp x - kdp theta' equals
    -kdp xi with xi = theta' + omega_p x (k_pp = omega_p k_dp, E39): on the homoclinic orbit
    (E = 2) at |x| = theta_s that is |kdp| omega_p (theta_s - 2 sin(theta_s/2)) ~ 2 units,
    plus the energy mismatch; an unpatched stabilizer would jump by tens of units."""
    c = ctrl('auto')
    tr = simulate(c, Plant(rig), 8.0, feed='true')
    catches = [e for e in tr.events if e[1].to == 'auto/catch']
    assert catches
    cfg = c.config
    wp = rig.omega_p
    for k, ev, st, (th, thd, thr, wr) in catches:
        x = math.remainder(th - PI, 2 * PI)
        E = rig.energy(th, thd)
        pend = st.u_unsaturated - (-cfg.patch_kdr * wr)
        assert pend == pytest.approx(-cfg.patch_kdp * (thd + wp * x), rel=1e-9)
        if abs(E - 2.0) < 0.01:
            on_orbit = abs(cfg.patch_kdp) * wp * (abs(x) - 2 * math.sin(abs(x) / 2))
            energy_err = abs(cfg.patch_kdp) * wp ** 2 * abs(E - 2.0) / abs(thd)
            assert abs(pend) <= on_orbit + energy_err + 0.1, (pend, on_orbit, energy_err)
            assert on_orbit < 2.5
            b = design.pddcontrol(rig, '1.5wp')
            unpatched = -b.kpp * x - b.kdp * thd
            assert abs(unpatched) > 10 * abs(pend)
    # and the successful catch is one with the energy on the reference
    last = catches[-1]
    assert abs(rig.energy(last[3][0], last[3][1]) - 2.0) < 0.01


@pytest.mark.parametrize('dv', [1.0, -1.0])
def test_tap_while_balancing_is_recovered(dv):
    """A 1 rad/s tap exceeds what the saturated patched stabilizer holds (E41: ~0.9 rad/s), so in
    auto the pendulum falls past theta_0 and is swung up and caught again."""
    c = ctrl('auto')
    p = Plant(rig, theta=PI)
    tap_k = 2000

    def tap(k, plant):
        if k == tap_k:
            plant.tap(dv)
    tr = simulate(c, p, 14.0, feed='counts', before_step=tap)
    assert balanced_since(tr, 0.05, 1.5) == pytest.approx(0.0, abs=0.01)   # balanced before the tap
    after = type(tr)(t=tr.t[tap_k:], theta=tr.theta[tap_k:])
    t_rec = balanced_since(after, 0.05, 5.0)
    assert t_rec is not None and t_rec - tr.t[tap_k] < 6.0


def test_small_tap_held_by_catch_law():
    c = ctrl('auto')
    tr = simulate(c, Plant(rig, theta=PI), 5.0, feed='counts',
                  before_step=lambda k, p: p.tap(0.5) if k == 1000 else None)
    assert [ev.to for _, ev, _, _ in tr.events] == ['auto/catch']
    assert balanced_since(tr, 0.1, 4.9) is not None


@pytest.mark.parametrize('mode, extra', [('auto', {}), ('balance', {}),
                                          ('balance', {'friction_compensation': 'model'})])
def test_wheel_speed_bounded_over_60s(mode, extra):
    c = ctrl(**extra)
    p = Plant(rig, theta=PI)
    c.update(0.0, 0, PI, 0.0, 0.0, 0.0)
    assert c.set_mode(mode)[0]
    tr = simulate(c, p, 60.0, feed='counts')
    assert max(abs(w) for w in tr.wheel_rate) < 60.0
    assert max(abs(math.remainder(th - PI, 2 * PI)) for th in tr.theta) < 0.02
    assert len(tr.events) <= 1


def test_balance_with_wheel_angle_feedback_holds_angle():
    g = design.pdpdcontrol(rig, 'wp', 0.707, 'wp', 1.0)
    c = ctrl()
    assert c.set_gains('balance', kpp=g.kpp, kdp=g.kdp, kpr=g.kpr, kdr=g.kdr)[0]
    p = Plant(rig, theta=PI, wheel_angle=50.0)
    c.update(0.0, 0, PI, 0.0, 50.0, 0.0)
    c.set_mode('balance')
    tr = simulate(c, p, 10.0, feed='counts')
    assert max(abs(math.remainder(th - PI, 2 * PI)) for th in tr.theta) < 0.02
    # reference = the wheel angle when balance started: no runaway (limit cycle of 7.2 allowed)
    assert max(abs(w - 50.0) for w in tr.wheel_angle) < 10.0


def test_wheel_velocity_pi_reaches_reference():
    c = ctrl('wheel_velocity', wheel_ref=100.0)
    tr = simulate(c, Plant(rig), 3.0, feed='counts')
    tail = tr.wheel_rate[-500:]
    assert sum(tail) / len(tail) == pytest.approx(100.0, abs=1.5)


def test_wheel_angle_pd_reaches_reference():
    c = ctrl('wheel_angle', wheel_angle_ref=10.0, friction_compensation='model')
    tr = simulate(c, Plant(rig), 3.0, feed='counts')
    assert tr.wheel_angle[-1] == pytest.approx(10.0, abs=0.3)


def test_estop_switches_off_and_a_cleared_estop_stays_off_until_a_mode_is_set():
    from rwpend_control.supervisor import ESTOP_CLEARED, ESTOP_RAISED
    c = ctrl('auto')
    c.update(0.0, 0, 0.1, 0.0, 0.0, 0.0)
    assert c.estop(True) and (c.mode, c.law, c.reason) == ('off', 'off', ESTOP_RAISED)
    assert not c.estop(True), 'raised twice changes nothing'
    ok, msg = c.set_mode('auto')
    assert not ok and 'e-stop is raised' in msg and c.mode == 'off'
    u, st = c.update(0.001, 1, 0.1, 0.0, 0.0, 0.0)
    assert u == 0.0 and st.event is not None and st.reason == ESTOP_RAISED
    assert c.estop(False) and (c.mode, c.reason) == ('off', ESTOP_CLEARED)
    u, _ = c.update(0.002, 2, 0.1, 0.0, 0.0, 0.0)
    assert u == 0.0, 'still zero torque after the clear'
    assert c.set_mode('auto')[0] and c.mode == 'auto'
    assert not c.estop(False), 'a clear without a raise changes nothing'
