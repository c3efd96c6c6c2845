"""The refusal checks and the procedures that use them, sample by sample (no ROS)."""
from __future__ import annotations

import math

import pytest

from rwpend_control.user_law import LawError, LawState, load_law
from rwpend_ident.checks import (NotReady, Rest, direction_problem, late_commands_problem, rest_problem,
                                 saturation_problem)
from rwpend_model.rig import load_rig

COUNT = 2 * math.pi / 4000
RIG = load_rig()


def test_rest_problem():
    r = Rest()
    assert rest_problem([0.0] * 300, [1.0] * 300, r) is None
    assert 'pendulum not at rest' in rest_problem([0.0, 0.01], [0.0, 0.0], r)
    assert 'not hanging' in rest_problem([0.3] * 10, [0.0] * 10, r)
    assert 'wheel spinning' in rest_problem([0.0] * 10, [0.0, 0.5], r)


def test_a_spread_of_two_counts_is_at_rest_however_it_is_rounded():
    # 231 * COUNT - 229 * COUNT is above 2 * COUNT in floating point: a recorded rest the
    # controller had accepted was refused by the bag's check for that
    r = Rest()
    for c in (229, 1000, -517, 3998):
        rel = [c * COUNT, (c + 1) * COUNT, (c + 2) * COUNT]
        assert rest_problem([0.0] * 3, rel, r) is None, c
        assert rest_problem([0.0, 2 * COUNT, 0.0], [0.0] * 3, r) is None
        assert 'wheel spinning' in rest_problem([0.0] * 4, rel + [(c + 3) * COUNT], r)


def test_direction_problem_tells_which_one_is_reversed():
    assert direction_problem(3.0, -5 * COUNT, 500 * COUNT, COUNT) is None
    assert direction_problem(-3.0, 5 * COUNT, -500 * COUNT, COUNT) is None
    assert 'motor turns against u' in direction_problem(3.0, 5 * COUNT, -500 * COUNT, COUNT)
    assert 'motor encoder counts backwards' in direction_problem(3.0, -5 * COUNT, -500 * COUNT, COUNT)
    assert 'pendulum encoder counts backwards' in direction_problem(3.0, 5 * COUNT, 500 * COUNT, COUNT)
    assert 'did not turn' in direction_problem(3.0, -5 * COUNT, 2 * COUNT, COUNT)


def test_saturation_problem():
    assert saturation_problem(12.0, 10.0, 0.3, 'x') is None
    assert 'saturation reached at 400 rad/s' in saturation_problem(3.0, 10.0, 0.3, 'at 400 rad/s')


def test_late_commands_problem_counts_the_samples_the_plant_held():
    nan = float('nan')
    v = [-7.0] * 100
    assert late_commands_problem(v, [-7.0] * 80 + [0.0] * 20) is None               # 80 %: the rig's verdict
    assert '79 of 100 samples' in late_commands_problem(v, [-7.0] * 79 + [0.0] * 21)
    # at the limit the verdict is on full torque: 98 % of those samples held
    u = [-10.0] * 100
    assert late_commands_problem(u, [-10.0] * 98 + [0.0] * 2) is None
    why = late_commands_problem(u, [-10.0] * 85 + [0.0] * 15)
    assert 'saturated u (|u| = 10) in 85 of 100 samples' in why and 'did not reach the motor whole' in why
    assert late_commands_problem(v[:50] + u[:50], [-7.0] * 50 + [-10.0] * 49 + [0.0]) is None   # 49 of 50
    assert '79 of 100' in late_commands_problem(u, [-10.0] * 79 + [0.0] * 21), 'the overall share first'
    # the amplifier's quantized value is the command held; samples without a report are not counted
    assert late_commands_problem([3.01] * 50, [3.0] * 50) is None
    assert late_commands_problem(u, [nan] * 95 + [0.0] * 5) is None                # 5 samples: too few to say
    assert '0 of 10 samples' in late_commands_problem(v, [nan] * 90 + [0.0] * 10)


def _state(t, theta=0.0, theta_dot=0.0, wheel=0.0, rate=0.0):
    return LawState(t, theta, theta_dot, wheel, rate, 0.0)


def _law(name, **params):
    return load_law(f'rwpend_ident.procedures:{name}', params, RIG)


def test_pulses_wait_for_rest_then_play_the_schedule():
    law = _law('Pulses', times=[0.0, 0.02], values=[5.0, 0.0])
    h = RIG.sample_period
    us = [law(_state(k * h)) for k in range(700)]
    start = next(k for k, u in enumerate(us) if u)
    assert start == pytest.approx(round(Rest().still_s / h) - 1, abs=1)
    assert us[start:start + 20] == [5.0] * 20 and us[start + 20] == 0.0


def test_pulses_refuse_a_swinging_pendulum():
    """A pendulum that does not come to rest: the step is refused with the reason (NotReady)."""
    law = _law('Pulses', times=[0.0, 0.02], values=[5.0, 0.0], rest_timeout=1.0)
    h = RIG.sample_period
    with pytest.raises(LawError, match='NotReady: pendulum not at rest'):
        for k in range(3000):
            law(_state(k * h, theta=0.05 * math.sin(8.8 * k * h)))


def test_wheel_speeds_stop_at_saturation():
    """Saturated while the wheel does not speed up (the friction takes all the torque): refused."""
    law = _law('WheelSpeeds', kdr=0.2, ki=0.002, times=[0.0], refs=[5000.0], max_saturation_s=0.1)
    h = RIG.sample_period
    with pytest.raises(LawError, match='saturation reached'):
        for k in range(2000):
            law(_state(k * h))


def test_wheel_speeds_carry_on_while_a_saturated_command_still_accelerates():
    """Saturated for 1 s while the wheel catches up at 60 rad/s^2 (after a late loop held the
    motor at 0): no refusal."""
    law = _law('WheelSpeeds', kdr=0.2, ki=0.002, times=[0.0], refs=[5000.0], max_saturation_s=0.1)
    h = RIG.sample_period
    rest = round(Rest().still_s / h) + 5
    us = [law(_state(k * h, rate=60.0 * max(0, k - rest) * h)) for k in range(rest + 1000)]
    assert min(us[rest:]) == us[-1] > 0


def test_breakaway_ramps_stop_when_the_rotor_slips():
    law = _law('BreakawayRamps', signs=[1.0, -1.0], rate=2.0, slip_speed=5.0, u_limit=4.0)
    h = RIG.sample_period
    us, slip = [], False
    for k in range(3000):
        t = k * h
        us.append(law(_state(t, rate=10.0 if slip else 0.0)))
        slip = abs(us[-1]) > 1.5
    assert max(us) == pytest.approx(1.5, abs=0.01) and min(us) == pytest.approx(-1.5, abs=0.01)
    assert us[-1] == 0.0, 'both ramps done'


def test_breakaway_ramps_refuse_a_blocked_wheel():
    law = _law('BreakawayRamps', rate=2.0, u_limit=1.0)
    with pytest.raises(LawError, match='did not break away'):
        for k in range(3000):
            law(_state(k * RIG.sample_period))


def test_not_ready_is_an_exception_with_the_reason():
    assert issubclass(NotReady, Exception) and str(NotReady('why')) == 'why'


def test_a_pulse_that_did_not_reach_the_motor_is_said_so():
    from rwpend_ident.checks import delivery_problem
    pulse = [6.0] * 30 + [0.0] * 10
    assert delivery_problem(pulse, [0.0] + [6.0] * 30 + [0.0] * 9) is None          # one sample later: whole
    assert delivery_problem(pulse, [5.998] * 30 + [0.0] * 10) is None               # quantized by the amplifier
    fragments = [0.0] * 6 + [6.0] * 3 + [0.0] * 6 + [6.0] * 3 + [0.0] * 22           # the device's hold limit
    why = delivery_problem(pulse, fragments)
    assert 'did not reach the motor whole' in why and '6 of the 30' in why
    assert delivery_problem([], []) is None


def test_a_pulse_short_of_a_few_samples_is_enough_only_when_the_pendulum_moved():
    """A pulse held in 46 of its 51 samples (two gaps of the device's hold limit) is the rig's
    response when the pendulum moved 2 counts or more; with 1 count the check of its encoder
    cannot tell a short pulse from a missing encoder, and says the pulse was short."""
    from rwpend_ident.checks import delivery_problem
    pulse = [3.0] * 51 + [0.0] * 10
    held = [0.0] + [3.0] * 25 + [0.0] * 3 + [3.0] * 3 + [0.0] * 3 + [3.0] * 18 + [0.0] * 8
    assert delivery_problem(pulse, held) is None
    assert delivery_problem(pulse, held, pendulum_counts=2.0) is None
    why = delivery_problem(pulse, held, pendulum_counts=-1.0)
    assert 'did not reach the motor whole' in why and '46 of the 51' in why and 'moved 1 count' in why
    whole = [0.0] + [3.0] * 51 + [0.0] * 9
    assert delivery_problem(pulse, whole, pendulum_counts=1.0) is None, 'whole: the encoder is judged'
