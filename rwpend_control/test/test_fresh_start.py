"""Issue 21 on the controller side (pure, no ROS): a re-synchronised estimate or a state stream
that resumes after stale starts the current mode afresh; ``auto`` never dies (a fall or an
overspeed leads back to a swing-up)."""
import math

import pytest

from rwpend_model.plant import Plant
from rwpend_model.rig import load_rig
from rwpend_control import design
from support.closed_loop import CountsState, simulate
from rwpend_control.safety import BRAKE_DONE_SPEED
from rwpend_control.supervisor import Controller, ControllerConfig

rig = load_rig()
PI = math.pi
H = rig.sample_period


def ctrl(mode='off', **cfg):
    return Controller(rig, ControllerConfig.designed(rig, **cfg), mode=mode)


def feed(c, k, theta, theta_dot=0.0, wheel_angle=0.0, wheel_rate=0.0, resyncs=0):
    return c.update(k * H, k, theta, theta_dot, wheel_angle, wheel_rate, 0.0, now=k * H, resyncs=resyncs)


# --------------------------------------------------------------------------- each mode
def test_auto_fresh_start_catches_inside_theta_s_and_swings_up_outside():
    c = ctrl('auto')
    feed(c, 0, PI + 0.02)
    assert c.law == 'catch'
    _, st = feed(c, 1, PI + 0.03, resyncs=1)                  # still up: catch again
    assert st.event is not None and (st.mode, st.law) == ('auto', 'catch')
    assert st.reason.startswith('fresh start of auto: estimator re-synchronised (resyncs 0 -> 1)')
    _, st = feed(c, 2, PI + 0.6, resyncs=1)                   # no new resync: hysteresis holds
    assert st.event is None and st.law == 'catch'
    _, st = feed(c, 3, PI + 0.6, resyncs=2)                   # a new one, beyond theta_s: swing up
    assert (st.mode, st.law) == ('auto', 'swingup') and st.reason.startswith('fresh start of auto')
    _, st = feed(c, 4, 0.3, resyncs=0)                        # the estimator restarted (count back)
    assert st.law == 'swingup' and st.event is not None and c.fresh_starts == 3


def test_balance_fresh_start_recaptures_the_wheel_reference_or_goes_off():
    g = design.pdpdcontrol(rig, 'wp', 0.707, '0.5wp', 1.0)         # wheel-angle feedback kpr != 0
    c = ctrl('balance', balance_kpp=g.kpp, balance_kdp=g.kdp, balance_kpr=g.kpr, balance_kdr=g.kdr)
    feed(c, 0, PI, wheel_angle=5.0)
    assert c._balance.wheel_ref == 5.0
    u_ref, st = feed(c, 1, PI, wheel_angle=60.0, resyncs=1)         # counts re-zeroed elsewhere
    assert st.reason.startswith('fresh start of balance') and c._balance.wheel_ref == 60.0
    assert u_ref == pytest.approx(0.0, abs=1e-12)                   # no kick from the old reference
    _, st = feed(c, 2, PI + 1.0, wheel_angle=60.0, resyncs=2)
    assert (st.mode, st.law) == ('off', 'off') and st.reason.startswith('fell') and 'fresh start' in st.reason
    assert c.fall_trips == 1


def test_wheel_velocity_fresh_start_resets_the_integrator():
    c = ctrl('wheel_velocity', wheel_ref=100.0)
    for k in range(200):
        feed(c, k, 0.0, wheel_rate=50.0)
    assert c._wheel_pi.integral != 0.0
    _, st = feed(c, 200, 0.0, wheel_rate=50.0, resyncs=1)
    assert st.reason.startswith('fresh start of wheel_velocity')
    assert c._wheel_pi.integral == pytest.approx(c.config.wheel_ki * 50.0)   # this sample's only


@pytest.mark.parametrize('mode', ['swingup', 'wheel_angle'])
def test_memoryless_modes_report_the_fresh_start(mode):
    c = ctrl(mode)
    feed(c, 0, 0.2)
    _, st = feed(c, 1, 0.2, resyncs=1)
    assert st.event is not None and (st.mode, st.law) == (mode, mode) and c.fresh_starts == 1


def test_off_has_nothing_to_start():
    c = ctrl('off')
    feed(c, 0, 0.2)
    _, st = feed(c, 1, 0.2, resyncs=1)
    assert st.event is None and c.fresh_starts == 0


def test_stream_resuming_after_stale_is_a_fresh_start():
    c = ctrl('auto')
    feed(c, 0, PI + 0.01)
    assert c.check_stale(0.1) is not None
    _, st = c.update(0.2, 200, PI + 1.5, 0.0, 0.0, 0.0, now=0.2)     # fell meanwhile
    assert st.note.startswith('state resumed') and (st.mode, st.law) == ('auto', 'swingup')
    assert 'state resumed' in st.reason and c.fresh_starts == 1


def test_a_few_stale_samples_resume_the_law_without_a_fresh_start():
    """A stream silent for less than FRESH_START_GAP (a dropped or late state) goes on with its
    law: a fresh start of a holding catch would itself throw the pendulum off."""
    from rwpend_control.supervisor import FRESH_START_GAP
    c = ctrl('auto')
    feed(c, 0, PI + 0.01)
    assert c.check_stale(0.005) is not None                              # stale after 5 ms
    gap = 0.6 * FRESH_START_GAP
    _, st = c.update(gap, round(gap / H), PI + 0.01, 0.0, 0.0, 0.0, now=gap)
    assert st.note.startswith('state resumed') and st.event is None and c.fresh_starts == 0


# --------------------------------------------------------------------------- closed loop
def test_auto_balancing_through_resyncs_stays_up():
    """Re-synchronisations while balancing (the state itself unchanged): auto catches again at
    once each time; the pendulum stays up."""
    c = ctrl('auto')
    p = Plant(rig, theta=PI + 0.02)
    resyncs = 0
    simulate(c, p, 0.5)
    cs = CountsState(rig, *p.counts())
    for k in range(3000):
        if k % 500 == 250:
            resyncs += 1
        th, thd, thr, wr = cs.update(*p.counts())
        u, st = c.update(p.t, 10_000 + k, th, thd, thr, wr, p.state.friction, resyncs=resyncs)
        p.step(u)
    assert c.fresh_starts == 6 and c.law == 'catch'
    assert abs(math.remainder(p.state.theta - PI, 2 * PI)) < 0.05


@pytest.mark.parametrize('action, law', [('brake', 'brake'), ('off', 'off')])
def test_auto_overspeed_stops_the_wheel_then_swings_up_again(action, law):
    """The swing-up drives the wheel to about 610 rad/s: with a limit of 450 it trips; auto
    stays auto, stops the wheel (brake or coast), swings up again, and is still alive."""
    c = ctrl('auto', wheel_speed_limit=450.0, wheel_speed_action=action)
    tr = simulate(c, Plant(rig), 12.0)
    laws = [ev.to for _, ev, _, _ in tr.events]
    reasons = [ev.reason for _, ev, _, _ in tr.events]
    assert c.overspeed_trips >= 1 and c.mode == 'auto'
    assert f'auto/{law}' in laws
    i = laws.index(f'auto/{law}')
    assert reasons[i].startswith('overspeed') and 'auto again' in reasons[i]
    assert any(r.startswith('wheel stopped') for r in reasons[i:])
    assert laws[i + 1] in ('auto/swingup', 'auto/catch')
    assert all(m.startswith('auto/') for m in laws)                   # never left auto
    assert abs(max(tr.wheel_rate, key=abs)) < rig.omega_max


def test_auto_overspeed_event_while_braking_is_not_counted_twice():
    c = ctrl('auto', wheel_speed_limit=300.0)
    feed(c, 0, 0.5, wheel_rate=400.0)
    assert (c.mode, c.law) == ('auto', 'brake') and c.overspeed_trips == 1
    u, _ = feed(c, 1, 0.5, wheel_rate=380.0)
    assert u == -rig.u_max and c.overspeed_trips == 1
    _, st = feed(c, 2, 0.5, wheel_rate=380.0, resyncs=1)            # a gap while braking: brake on
    assert st.law == 'brake' and st.reason.startswith('fresh start of auto')
    _, st = feed(c, 3, 0.5, wheel_rate=0.5 * BRAKE_DONE_SPEED, resyncs=1)
    assert (st.mode, st.law) == ('auto', 'swingup') and st.reason.startswith('wheel stopped')
