"""The Chapter 3 configuration of the plant (Fig. 3.1: pendulum locked on the fixed bracket, wheel
free) and the torque meter of Experiment 2 (Fig. 2.4)."""
from __future__ import annotations

import math

import pytest

from rwpend_model.plant import Plant
from rwpend_model.rig import load_rig

RIG = load_rig()


def run(plant: Plant, u: float, n: int) -> None:
    for _ in range(n):
        plant.step(u)


def test_bracket_pendulum_never_moves_and_the_wheel_obeys_3_1():
    """(3.1): theta_r'' = b_r (u - F); the pendulum encoder stays 0, the motor encoder is theta_r."""
    p = Plant(RIG, bracket=True, pwm=False, motor_lag=False)
    run(p, 5.0, 50)
    s = p.state
    assert s.theta == 0.0 and s.theta_dot == 0.0
    w = s.wheel_rate
    # from rest, accelerating: w' = b_r (u - c - v w) -> w(t) = (u - c)/v (1 - exp(-b_r v t))
    c, v = RIG.friction_coulomb_pos, RIG.friction_viscous_pos
    t = 50 * RIG.sample_period
    assert w == pytest.approx((5.0 - c) / v * (1 - math.exp(-RIG.b_r * v * t)), rel=1e-3)
    pc, mc = p.counts()
    assert pc == 0 and mc == round(s.wheel_angle / RIG.count_angle)


def test_bracket_wheel_reaches_the_friction_speed_and_coasts_to_rest():
    p = Plant(RIG, bracket=True)
    run(p, 3.6, 4000)
    c, v = RIG.friction_coulomb_pos, RIG.friction_viscous_pos
    assert p.state.wheel_rate == pytest.approx((3.6 - c) / v, rel=0.01)   # ~225 rad/s (Section 3.4)
    run(p, 0.0, 2000)
    assert p.state.wheel_rate == 0.0 and p.state.stuck


def test_bracket_stiction_below_breakaway_and_hand_spun_wheel():
    p = Plant(RIG, bracket=True)
    run(p, 0.9 * RIG.friction_breakaway, 100)
    assert p.state.wheel_rate == 0.0 and p.state.stuck
    spun = Plant(RIG, bracket=True, wheel_rate=200.0)      # Experiment 10: spun by hand
    run(spun, 0.0, 10)
    assert 0.0 < spun.state.wheel_rate < 200.0
    with pytest.raises(ValueError):
        spun.tap(1.0)
    with pytest.raises(ValueError):
        Plant(RIG, bracket=True, theta=0.1)


def test_torque_meter_reads_the_torque_beyond_the_friction_dead_zone():
    """Fig. 2.4: the wheel held, the meter reads k_u (u - F): 0 in the dead zone |u| <= breakaway,
    then a line of slope k_u."""
    for u in (-8.0, -0.5, 0.0, 0.7, 3.0, 10.0):
        p = Plant(RIG, bracket=True, rotor_locked=True)
        run(p, u, 20)
        fb = RIG.friction_breakaway
        expect = RIG.k_u * (u - max(-fb, min(fb, u)))
        assert p.meter_torque() == pytest.approx(expect, abs=RIG.k_u * 0.02)
        assert p.state.wheel_rate == 0.0 and p.counts() == (0, 0)
    with pytest.raises(ValueError):
        Plant(RIG, rotor_locked=True)
