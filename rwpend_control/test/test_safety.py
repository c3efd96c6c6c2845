"""Safety logic of the controller (pure, no ROS): stale-state watchdog, refused states, wheel-speed
limit and brake, saturation fall-back, leaving the balance region, parameter validation, fuzz."""
import math
import random

import numpy as np
import pytest

from rwpend_model.plant import Plant
from rwpend_model.rig import load_rig
from support.closed_loop import CountsState, simulate
from rwpend_control.safety import BRAKE_DONE_SPEED, StateWatchdog, brake, motor_speed
from rwpend_control.supervisor import Controller, ControllerConfig

rig = load_rig()
PI = math.pi
H = rig.sample_period


def ctrl(mode='off', **cfg):
    return Controller(rig, ControllerConfig.designed(rig, **cfg), mode=mode)


# --------------------------------------------------------------------------- watchdog
def test_watchdog_order_silence_restart():
    wd = StateWatchdog(3 * H)
    assert not wd.check(100.0)                        # nothing before the first state
    assert wd.admit(10, 0.000) == (True, '')
    assert wd.admit(11, 0.001) == (True, '')
    ok, why = wd.admit(11, 0.0015)                    # duplicate
    assert not ok and 'out-of-order' in why and wd.out_of_order == 1
    ok, why = wd.admit(5, 0.002)                      # older
    assert not ok and wd.out_of_order == 2
    assert wd.admit(14, 0.0025)[0]                    # a jump ahead (lost samples) is fine
    assert not wd.check(0.0025 + 2.9 * H)
    assert wd.check(0.0025 + 3.1 * H) and wd.stale and wd.episodes == 1
    assert not wd.check(0.0025 + 10 * H)              # reported once
    ok, note = wd.admit(15, 0.02)
    assert ok and note.startswith('state resumed after') and not wd.stale and wd.gaps == 1
    # after a silence a lower seq is a restart (e.g. the simulator started again)
    ok, note = wd.admit(0, 0.03)
    assert ok and 'restarted' in note and wd.restarts == 1 and wd.last_seq == 0
    # the clock going back re-bases instead of reporting
    assert not wd.check(0.01) and wd.last_arrival == 0.01
    with pytest.raises(ValueError):
        StateWatchdog(0.0)


def test_watchdog_uses_a_stamp_ahead_of_a_late_clock():
    """Lockstep: state k can arrive before the controller has /clock k; the silence counts
    from the stamp then.  A stamp far ahead (another clock, garbage) is not trusted."""
    wd = StateWatchdog(3 * H)
    assert wd.admit(1, now=0.010, stamp=0.012)[0]
    assert not wd.check(0.0145) and wd.check(0.0151)
    wd2 = StateWatchdog(3 * H)
    assert wd2.admit(1, now=0.010, stamp=5e8)[0]
    assert wd2.check(0.0131)
    wd3 = StateWatchdog(3 * H)
    assert wd3.admit(1, now=0.010, stamp=0.001)[0]          # a late state (delay): arrival counts
    assert not wd3.check(0.0125)


def test_stale_state_gives_one_zero_command_then_resumes_the_mode():
    c = ctrl('auto')
    for k in range(5):
        u, st = c.update(k * H, 100 + k, PI + 0.05, 0.0, 0.0, 0.0, now=50.0 + k * H)
        assert st.answer and u != 0.0
    last = 50.0 + 4 * H
    assert c.check_stale(last + 3.4 * H) is None
    st = c.check_stale(last + 3.6 * H)
    assert st is not None and st.u == 0.0 and st.seq == 105 and st.fault.startswith('stale state')
    assert 'seq 104' in st.fault and st.mode == 'auto' and c.stale
    assert c.check_stale(last + 50 * H) is None      # once per episode
    u, st = c.update(0.1, 160, PI + 0.05, 0.0, 0.0, 0.0, now=last + 60 * H)
    assert st.note.startswith('state resumed') and st.fault == '' and u != 0.0
    assert st.mode == 'auto' and not c.stale


def test_stale_after_the_largest_seq_does_not_overflow():
    """Found by the fuzz test: the zero command answers seq + 1, which must stay a uint64."""
    c = ctrl('auto')
    c.update(0.0, 2**64 - 1, PI, 0.0, 0.0, 0.0, now=0.0)
    st = c.check_stale(0.01)
    assert st is not None and st.seq == 2**64 - 1


def test_out_of_order_state_is_not_answered():
    c = ctrl('auto')
    c.update(0.0, 7, PI, 0.0, 0.0, 0.0, now=0.0)
    u, st = c.update(0.0, 7, PI, 0.0, 0.0, 0.0, now=0.0005)
    assert not st.answer and u == 0.0 and 'out-of-order' in st.fault
    assert c.watchdog.out_of_order == 1


def test_bad_state_is_answered_with_zero_and_does_not_feed_the_watchdog():
    c = ctrl('auto')
    c.update(0.0, 0, PI, 0.0, 0.0, 0.0, now=0.0)
    for k in range(1, 10):
        u, st = c.update(k * H, k, PI, float('nan'), 0.0, 0.0, now=k * H)
        assert u == 0.0 and st.answer and st.fault.startswith('bad state')
    assert c.check_stale(9 * H) is not None          # no valid state for 9 samples: stale


def test_fuzz_update_never_gives_a_bad_command():
    """10 000 random states (NaN, inf, huge, wrong sign, random seq and times): no exception,
    |u| <= u_max and finite, refusals counted."""
    rnd = random.Random(7)
    specials = [float('nan'), float('inf'), -float('inf'), 1e308, -1e308, 1e9, -1e9, 0.0, -0.0, 5e-324]
    c = ctrl('auto', catch_region=True, friction_compensation='estimate')

    def val():
        r = rnd.random()
        if r < 0.3:
            return rnd.choice(specials)
        if r < 0.6:
            return rnd.uniform(-1e4, 1e4)
        return rnd.gauss(0.0, 5.0)
    refused = 0
    for k in range(10_000):
        if k % 1000 == 0:
            c.set_mode(rnd.choice(['auto', 'balance', 'swingup', 'wheel_velocity', 'wheel_angle', 'off']))
        seq = rnd.choice([k, k, k, rnd.randrange(0, 2**64), 0])
        t = rnd.choice([k * H, val()])
        u, st = c.update(t, seq, val(), val(), val(), val(), val(), now=k * H)
        assert math.isfinite(u) and abs(u) <= rig.u_max
        refused += bool(st.fault) or not st.answer
        c.check_stale(k * H + rnd.choice([0.0, 0.01]))
    assert refused > 3000 and c.bad_state_count > 3000


# --------------------------------------------------------------------------- wheel speed
def test_overspeed_brakes_then_off_and_reports():
    c = ctrl('wheel_velocity', wheel_ki=0.0, wheel_ref=600.0)
    u, st = c.update(0.0, 0, 0.0, 0.0, 0.0, 700.0)
    assert st.mode == 'wheel_velocity' and c.overspeed_trips == 0
    u, st = c.update(0.001, 1, 0.0, 2.0, 0.0, 760.0)           # w = 758 > 750
    assert st.mode == 'off' and st.law == 'brake' and st.event is not None
    assert st.reason.startswith('overspeed') and 'braking' in st.reason and c.overspeed_trips == 1
    assert u == -rig.u_max                                      # full braking torque against w
    u, st = c.update(0.002, 2, 0.0, 0.0, 0.0, -300.0)
    assert st.law == 'brake' and u == pytest.approx(brake(c.config.wheel_kp, -300.0, 10.0)) and u > 0
    u, st = c.update(0.003, 3, 0.0, 1.0, 0.0, 1.0 + 0.5 * BRAKE_DONE_SPEED)
    assert st.mode == 'off' and st.law == 'off' and u == 0.0 and st.reason.startswith('wheel braked')


def test_overspeed_off_action_and_no_trip_when_off():
    c = ctrl('swingup', wheel_speed_action='off', wheel_speed_limit=500.0)
    u, st = c.update(0.0, 0, 1.0, 0.0, 0.0, -520.0)
    assert st.mode == 'off' and st.law == 'off' and u == 0.0 and 'u = 0' in st.reason
    c2 = ctrl('off')
    u, st = c2.update(0.0, 0, 0.0, 0.0, 0.0, 800.0)
    assert u == 0.0 and c2.overspeed_trips == 0                 # nothing driven, nothing to stop
    assert motor_speed(2.0, 10.0) == 8.0


def test_set_mode_off_stops_the_brake():
    c = ctrl('wheel_velocity', wheel_ref=100.0)
    c.update(0.0, 0, 0.0, 0.0, 0.0, 800.0)
    assert c.law == 'brake'
    assert c.set_mode('off')[0] and c.law == 'off'
    u, _ = c.update(0.001, 1, 0.0, 0.0, 0.0, 700.0)
    assert u == 0.0


def test_swingup_stays_below_the_wheel_speed_limit():
    """The energy swing-up of Chapter 6 with the designed gains reaches about 610 rad/s: the
    default limit (750 rad/s) must not trip it."""
    c = ctrl('auto')
    tr = simulate(c, Plant(rig), 8.0)
    assert c.overspeed_trips == 0 and c.mode == 'auto' and c.law == 'catch'
    assert 500.0 < max(abs(w) for w in tr.wheel_rate) < c.config.wheel_speed_limit


# --------------------------------------------------------------------------- saturation
@pytest.mark.parametrize('action,mode,law', [('off', 'off', 'off'), ('swingup', 'swingup', 'swingup'),
                                             ('auto', 'auto', 'catch')])
def test_balance_saturated_too_long_falls_back(action, mode, law):
    c = ctrl('balance', saturation_action=action, max_saturation_time=0.2)
    k = 0
    st = None
    while k < 400:                               # x = 0.3 rad held: |u| = 282 * 0.3 >> 10
        u, st = c.update(k * H, k, PI + 0.3, 0.0, 0.0, 0.0)
        if st.event is not None and k > 0:          # (k = 0 reports set_mode balance)
            break
        assert st.saturated and abs(u) == 10.0
        k += 1
    assert 199 <= k <= 202, k
    assert (st.mode, st.law) == (mode, law) and st.reason.startswith('saturated')
    assert c.saturation_trips == 1


def test_recoverable_tap_does_not_trip_the_saturation_limit():
    """A tap of 0.6 rad/s in balance saturates about 0.09 s and recovers; 1.0 rad/s saturates
    0.5 s without recovering (the pendulum falls), so the default 0.5 s separates them."""
    for dv, survives in ((0.6, True), (1.0, False)):
        c = ctrl('balance')
        p = Plant(rig, theta=PI)
        simulate(c, p, 3.0, before_step=lambda k, pl: pl.tap(dv) if k == 500 else None)
        if survives:
            assert c.mode == 'balance' and c.saturation_trips == 0
        else:
            assert c.mode == 'off' and (c.saturation_trips or c.fall_trips)


def test_balance_leaving_the_region_goes_off_auto_swings_up():
    c = ctrl('balance')
    c.update(0.0, 0, PI + 0.2, 0.0, 0.0, 0.0)
    u, st = c.update(0.001, 1, PI + 0.9, 0.0, 0.0, 0.0)
    assert u == 0.0 and (st.mode, st.law) == ('off', 'off') and st.reason.startswith('fell')
    assert c.fall_trips == 1
    a = ctrl('auto')
    a.update(0.0, 0, PI + 0.2, 0.0, 0.0, 0.0)
    _, st = a.update(0.001, 1, PI + 0.9, 0.0, 0.0, 0.0)
    assert (st.mode, st.law) == ('auto', 'swingup') and st.reason.startswith('fall')


# --------------------------------------------------------------------------- dead estimator
def test_dead_estimator_then_restart_auto_swings_up_again():
    """Balanced in auto; the state stops for 2 s (the plant's timeout holds u = 0 and the
    pendulum falls); states resume -> the controller carries on in auto, swings up, catches."""
    c = ctrl('auto')
    p = Plant(rig)
    cs = CountsState(rig, *p.counts())
    u = 0.0
    k = 0
    stale_at = None
    law_after, notes = [], []
    for k in range(int(14.0 / H)):
        t = k * H
        th, thd, thr, wr = cs.update(*p.counts())
        dead = 6.0 <= t < 8.0 - 1e-9
        if dead:
            st = c.check_stale(t)
            if st is not None:
                stale_at = t
                assert st.u == 0.0
            u = 0.0                                   # the plant's command timeout
        else:
            u, st = c.update(t, k, th, thd, thr, wr, p.state.friction, now=t)
            if t >= 8.0 - 1e-9:
                law_after.append(st.law)
                if st.note:
                    notes.append(st.note)
        p.step(u)
    assert stale_at is not None and 6.0 < stale_at <= 6.0 + 4 * H
    assert notes and notes[0] == 'state resumed after 2001.0 ms'
    assert 'swingup' in law_after and law_after[-1] == 'catch'   # fell, swung up, caught
    x = math.remainder(p.state.theta - PI, 2 * PI)
    assert abs(x) < 0.1 and c.mode == 'auto'


# --------------------------------------------------------------------------- parameters
@pytest.mark.parametrize('values,text', [
    ({'wheel_speed_limit': 830.0}, 'back-EMF'),
    ({'wheel_speed_limit': float('nan')}, 'finite'),
    ({'wheel_speed_limit': 0.0}, 'wheel_speed_limit'),
    ({'wheel_speed_limit': 300.0, 'wheel.ref': 400.0}, 'wheel.ref'),
    ({'state_timeout_samples': 0}, 'state_timeout_samples'),
    ({'state_timeout_samples': 2.5}, 'integer'),
    ({'state_timeout_samples': True}, 'integer'),
    ({'wheel_speed_action': 'explode'}, 'brake, off'),
    ({'saturation_action': 3}, 'saturation_action'),
    ({'max_saturation_time': 0.0}, 'max_saturation_time'),
    ({'max_saturation_time': -float('inf')}, 'finite'),
])
def test_safety_parameters_validated(values, text):
    c = ctrl()
    old = c.config
    ok, why = c.set_params(values)
    assert not ok and text in why, why
    assert c.config is old


def test_safety_parameters_applied():
    c = ctrl()
    assert c.set_params({'state_timeout_samples': 10, 'wheel_speed_limit': 700, 'saturation_action': 'auto'})[0]
    assert c.watchdog.timeout == pytest.approx(10.5 * H) and c.config.wheel_speed_limit == 700.0


def test_fuzz_parameters_never_raise():
    rnd = random.Random(3)
    c = ctrl()
    names = ['balance.kpp', 'patch.kdr', 'wheel_speed_limit', 'state_timeout_samples', 'saturation_action',
             'theta_s', 'friction_compensation', 'wheel.ref', 'max_saturation_time', 'catch_region', 'bogus']
    pool = [float('nan'), float('inf'), -1e308, 0, -1, 3, 1e6, 'auto', '', None, True, [1.0, 2.0], 'brake']
    ok_count = 0
    for _ in range(2000):
        ok, why = c.set_params({rnd.choice(names): rnd.choice(pool)})
        assert isinstance(why, str)
        ok_count += ok
    assert np.isfinite(c.config.balance_kpp) and ok_count < 2000
