"""Per-sample control laws: signs and conventions of the book + ERRATA."""
import math

import pytest

from rwpend_model.rig import book_rig
from rwpend_control import design
from rwpend_control.laws import (Balance, EnergySwingUp, FrictionCompensation, PendulumPD, WheelAnglePD,
                                 WheelVelocityPI, saturate, scaled_energy, upright_deviation, wrap)

rig = book_rig()


def test_wrap():
    assert wrap(0.0) == 0.0
    assert wrap(math.pi) == pytest.approx(math.pi)
    assert wrap(-math.pi) == pytest.approx(math.pi)           # (-pi, pi]
    assert wrap(3 * math.pi + 0.1) == pytest.approx(-math.pi + 0.1)
    assert upright_deviation(math.pi + 0.2) == pytest.approx(0.2)
    assert upright_deviation(-math.pi + 0.2) == pytest.approx(0.2)
    assert upright_deviation(5 * math.pi - 0.3) == pytest.approx(-0.3)


def test_energy_and_saturation():
    assert scaled_energy(0.0, 0.0, rig.omega_p) == 0.0
    assert scaled_energy(math.pi, 0.0, rig.omega_p) == pytest.approx(2.0)
    assert scaled_energy(0.3, 1.2, rig.omega_p) == pytest.approx(rig.energy(0.3, 1.2))
    assert saturate(12.0, 10.0) == 10.0 and saturate(-12.0, 10.0) == -10.0 and saturate(3.0, 10.0) == 3.0


def test_wheel_pi_integral_per_sample_E15():
    law = WheelVelocityPI(kdr=0.2, ki=0.01, ref=10.0)
    assert law(0.0) == pytest.approx(0.2 * 10 + 0.01 * 10)
    assert law(0.0) == pytest.approx(0.2 * 10 + 0.02 * 10)
    law.reset()
    assert law.integral == 0.0
    p = WheelVelocityPI(kdr=0.5, ki=0.0, ref=0.0)               # P law (3.13)
    assert p(4.0) == -2.0
    wind = WheelVelocityPI(kdr=0.0, ki=1.0, ref=100.0, i_max=10.0)
    for _ in range(50):
        wind(0.0)
    assert wind.integral == 10.0                                 # anti-windup clamp


def test_wheel_angle_pd():
    law = WheelAnglePD(kpr=0.5, kdr=0.1, ref=2.0)
    assert law(1.0, 3.0) == pytest.approx(0.5 * 1.0 - 0.3)


def test_upright_laws_push_back():
    # model (2.15): theta'' = -a sin(theta) - b_p u; upright with x > 0 needs u < 0 ... with the
    # book's negative gains u = -kpp x = |kpp| x > 0 gives theta'' = -b_p u: pushes back (x -> 0)
    g = design.pddcontrol(rig, '1.5wp')
    law = Balance(g.kpp, g.kdp, g.kpr, g.kdr)
    u = law(math.pi + 0.01, 0.0, 0.0, 0.0)
    acc = -rig.a * math.sin(math.pi + 0.01) - rig.b_p * u
    assert u > 0 and acc < 0
    # wheel-rate feedback: u = kdr (rate_ref - omega) with kdr < 0 (4.9)
    law = Balance(g.kpp, g.kdp, 0.0, g.kdr, rate_ref=5.0)
    assert law(math.pi, 0.0, 123.0, 0.0) == pytest.approx(g.kdr * (5.0 - 0.0))
    # wheel-angle feedback with reference (E28)
    law = Balance(-1.0, 0.0, kpr=-0.1, kdr=0.0, wheel_ref=2.0)
    assert law(math.pi, 0.0, 3.0, 0.0) == pytest.approx(0.1)


def test_pendulum_pd_up_down():
    g = design.pd_control(rig, '1.5wp', 0.707)
    up = PendulumPD(g.kpp, g.kdp)
    down = PendulumPD(g.kpp, g.kdp, down=True, a=rig.a, b_p=rig.b_p)
    # the deviation accelerations are identical up and down (E21)
    x, v = 0.01, -0.02
    acc_up = -rig.a * math.sin(math.pi + x) - rig.b_p * up(math.pi + x, v)
    acc_down = -rig.a * math.sin(x) - rig.b_p * down(x, v)
    assert acc_up == pytest.approx(acc_down, rel=1e-4)


def test_swingup_sign_E35():
    c_e, c_v = design.swingup_gains(rig)
    law = EnergySwingUp(c_e, c_v, rig.omega_p)
    # below the reference energy the law must pump: dE/dt = -(b_p/a) u theta' > 0
    for theta, thd in ((0.3, 1.0), (-0.5, -2.0), (2.0, 3.0), (-2.5, 1.0)):
        u = law(theta, thd, 0.0)
        assert rig.energy(theta, thd) < 2.0
        assert -(rig.b_p / rig.a) * u * thd > 0
    # above it: removes energy
    assert law(math.pi - 0.1, 5.0, 0.0) * 5.0 > 0
    # wheel damping term: u = -c_v theta_r' at E = E_ref
    assert law(math.pi, 0.0, 10.0) == pytest.approx(-c_v * 10.0)


def test_swingup_kick_from_rest():
    law = EnergySwingUp(1e5, 1.6, rig.omega_p, kick=10.0)
    assert law(0.0, 0.0, 0.0) == 10.0
    assert law(-0.001, 0.0, 0.0) == -10.0
    assert law(0.001, 0.0, 0.0) == 10.0
    # the kick (u = +10) accelerates theta'' = -b_p u < 0; the energy law then continues
    # with the same sign of u, i.e. u theta' < 0: pumping
    thd = -rig.b_p * 10.0 * 0.01
    assert law(0.5 * thd * 0.01, thd, 0.0) > 0


def test_friction_compensation_modes():
    off = FrictionCompensation('off', rig)
    model = FrictionCompensation('model', rig, deadband=1.0)
    est = FrictionCompensation('estimate', rig)
    assert off(0.0, 100.0, 3.0) == 0.0
    # (3.17) at the relative speed w_rel = theta_r' - theta' (E46)
    assert model(1.0, 101.0, 0.0) == pytest.approx(rig.friction(100.0))
    assert model(0.0, -50.0, 0.0) == pytest.approx(rig.friction(-50.0))
    assert model(0.0, 0.5, 0.0) == 0.0
    assert est(0.0, 100.0, 2.5) == 2.5
    with pytest.raises(ValueError):
        FrictionCompensation('on', rig)
