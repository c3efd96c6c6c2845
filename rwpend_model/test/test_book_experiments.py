"""The book's modelling experiments (Chapter 2 of Block, Astrom & Spong) run on the plant model.

Each test does what the book asks the student to do on the rig -- swing the pendulum, apply a
torque pulse, watch the energy decay -- on :class:`rwpend_model.plant.Plant`, measures with the
quantized encoders (4000 counts/rev, Section 3.1) wherever the book measures, and compares the
result with the book's numbers and with the rig's derived parameters (:class:`Rig`).

Book values (Section 2.6; ERRATA E01: they need the listing's g = 9.91, the shipped rig has the
physical g = 9.81): omega_p = 8.856 rad/s, omega_p' = 8.832 rad/s, a = 78.4, b_p = 1.08,
b_r = 198.  The complements of rwpend_model/test/test_model.py (omega_p' of a small swing vs
Rig.omega_p_stuck, saturation, back-EMF cut-off, energy conservation) are not repeated here.

Total runtime about 3 s (the plant integrates about 40 000 samples per second).
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from rwpend_model.plant import Plant
from rwpend_model.rig import BOOK_G, book_rig, load_rig

#: The book's printed values (Section 2.6), with g = 9.91 (ERRATA E01).
BOOK_OMEGA_P = 8.856
BOOK_OMEGA_P_STUCK = 8.832
BOOK_B_P = 1.08
BOOK_B_R = 198.0


# ============================================================================ helpers
def record(plant: Plant, commands) -> dict:
    """Run the plant sample by sample with the given commands (ZOH); the encoder counts and the
    true state are recorded at every sample instant t_k = k h, k = 0..len(commands)."""
    pc, mc, stuck, states = [], [], [], []
    for u in list(commands) + [None]:
        p, m = plant.counts()
        pc.append(p)
        mc.append(m)
        s = plant.state
        stuck.append(s.stuck)
        states.append(s)
        if u is not None:
            plant.step(u)
    h = plant.h
    return {'t': np.arange(len(pc)) * h, 'pc': np.array(pc), 'mc': np.array(mc),
            'stuck': np.array(stuck), 'states': states, 'h': h}


def downward_crossing_times(counts: np.ndarray, h: float) -> np.ndarray:
    """Times of the samples at which the pendulum count passes from > 0 to <= 0 (always the same
    quantization level, so the bias of the level cancels in the differences)."""
    k = np.nonzero((counts[:-1] > 0) & (counts[1:] <= 0))[0] + 1
    return k * h


def measured_frequency(counts: np.ndarray, h: float) -> float:
    """Angular frequency of the swing from the mean period between downward crossings."""
    tc = downward_crossing_times(counts, h)
    assert len(tc) >= 5, 'too few periods to measure'
    return 2 * math.pi * (len(tc) - 1) / (tc[-1] - tc[0])


def half_cycle_peaks(counts: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(times, |counts|) of the turning points: the largest |count| of each complete half
    swing between zero crossings, timed at the middle of its plateau."""
    pos = counts > 0
    edges = np.nonzero(pos[1:] != pos[:-1])[0] + 1
    peak_t, peak_c = [], []
    for a, b in zip(np.r_[0, edges], np.r_[edges, len(counts)]):
        if b - a < 10 or b == len(counts):
            continue
        seg = np.abs(counts[a:b])
        top = np.nonzero(seg == seg.max())[0]
        peak_t.append(t[a + int(round(top.mean()))])
        peak_c.append(seg.max())
    return np.array(peak_t), np.array(peak_c)


def amplitude_factor(theta0: float) -> float:
    """Period of a pendulum of amplitude theta0 over the small-oscillation period (series to theta0^4)."""
    return 1 + theta0 ** 2 / 16 + 11 * theta0 ** 4 / 3072


def cumtrapz(x: np.ndarray, h: float) -> np.ndarray:
    out = np.zeros(len(x))
    out[1:] = np.cumsum(0.5 * (x[1:] + x[:-1])) * h
    return out


def lagged_input_integral(commands, h: float, te: float) -> np.ndarray:
    """U2(t_k) = double integral of the motor torque: the ZOH command through the current loop's
    first-order lag T_e (Section 2.4, data sheet), integrated exactly over each sample."""
    x = v = tau = 0.0
    out = [0.0]
    e = math.exp(-h / te) if te > 0 else 0.0
    for u in commands:
        i1 = u * h + (tau - u) * te * (1 - e)                 # integral of tau over the sample
        i2 = u * h * h / 2 + (tau - u) * te * (h - te * (1 - e))
        x += v * h + i2
        v += i1
        tau = u + (tau - u) * e
        out.append(x)
    return np.array(out)


# ============================================================ (a) omega_p, rotor free
@pytest.mark.parametrize('g, omega_expected', [(BOOK_G, BOOK_OMEGA_P), (9.81, 8.811)])
def test_small_oscillation_frequency_rotor_free(g, omega_expected):
    """(2.10): with no rotor friction (F = 0 in (2.15)) the rotor keeps theta_r'' = 0 and the
    pendulum swings at omega_p = sqrt(m g l / J) (Section 2.3), 8.856 rad/s in the book
    (Section 2.6, with g = 9.91; 8.811 with g = 9.81, ERRATA E01).  Measured from the pendulum
    encoder over 20 periods of a 0.05 rad swing, amplitude-corrected."""
    rig = load_rig().replace(g=g)
    theta0 = 0.05
    plant = Plant(rig, theta=theta0, friction=False, pendulum_friction=False)
    n = int(20.5 * 2 * math.pi / rig.omega_p / rig.sample_period)
    rec = record(plant, [0.0] * n)
    omega = measured_frequency(rec['pc'], rec['h']) * amplitude_factor(theta0)
    assert omega == pytest.approx(rig.omega_p, rel=3e-4)
    assert omega == pytest.approx(omega_expected, abs=0.004)
    # and it is not the stuck-rotor frequency omega_p' (0.27 % lower)
    assert abs(omega - rig.omega_p_stuck) > 0.015
    # free rotor: theta_r stays 0, so the motor encoder reads -theta (2.1)-(2.2)
    assert np.max(np.abs(rec['mc'] + rec['pc'])) <= 1
    assert max(abs(s.wheel_rate) for s in rec['states']) == 0.0


# ======================================================== (b) Experiment 1, Fig. 2.2
def test_experiment1_free_swing_from_20deg_rotor_stays_stuck():
    """Experiment 1 (Section 2.3): released at 20 deg with no control, the rotor angle is
    'nearly identical to the pendulum angle' (Fig. 2.2) -- the rotor friction holds it: the
    motor encoder (theta_r - theta, (2.2)) never leaves 0, and the pair swings as one body at
    omega_p' = sqrt(m g l / (J + J_r)) (book 8.832 rad/s with g = 9.91)."""
    rig = book_rig()
    theta0 = math.radians(20)
    # encoders zeroed hanging at rest, then the pendulum raised by hand: the rotor comes along
    plant = Plant(rig, theta=theta0, wheel_angle=theta0)
    n = 10_000                                      # 10 s, ~14 periods
    rec = record(plant, [0.0] * n)
    assert rec['stuck'].all()
    assert np.count_nonzero(rec['mc']) == 0
    assert max(abs(s.wheel_rate - s.theta_dot) for s in rec['states']) == 0.0
    assert max(abs(s.wheel_angle - s.theta) for s in rec['states']) < 1e-9
    # the holding friction needed stays well below breakaway (Section 2.6: ~1 unit)
    held = max(abs(s.friction) for s in rec['states'])
    assert held == pytest.approx(rig.a * math.sin(theta0) / (rig.b_r + rig.b_p), rel=0.02)
    assert held < 0.2 * rig.friction_breakaway
    # the pendulum swings with the pair's frequency; the period of a 20 deg swing is 0.77 %
    # longer than the small-oscillation one, so correct with the measured mean amplitude (the
    # axis friction lowers it by ~8 % over the 10 s)
    assert rec['pc'].max() == round(theta0 / rig.count_angle)
    _, peaks = half_cycle_peaks(rec['pc'], rec['t'])
    amplitude = float(np.mean(peaks)) * rig.count_angle
    omega = measured_frequency(rec['pc'], rec['h']) * amplitude_factor(amplitude)
    assert omega == pytest.approx(rig.omega_p_stuck, rel=5e-4)
    assert omega == pytest.approx(BOOK_OMEGA_P_STUCK, abs=0.005)


def test_experiment1_without_rotor_friction_the_rotor_does_not_follow():
    """The model (2.10) without friction predicts theta_r = 0 -- what the book says is *not*
    observed (Fig. 2.2); the plant with friction off reproduces that prediction."""
    rig = book_rig()
    plant = Plant(rig, theta=math.radians(20), friction=False)
    rec = record(plant, [0.0] * 2000)
    thr = np.array([s.wheel_angle for s in rec['states']])
    assert np.max(np.abs(thr)) == 0.0
    assert np.max(np.abs(rec['mc'] + rec['pc'])) <= 1    # motor encoder = -theta
    assert rec['pc'].min() < -200                        # the pendulum does swing


# ====================================================== (c) Experiment 3, torque pulse
def torque_pulse(rig, u0: float, pulse: int = 20, total: int = 300) -> tuple[dict, list]:
    """Experiment 3 (Section 2.6): from rest hanging down, u = u0 for `pulse` samples, then 0."""
    commands = [u0] * pulse + [0.0] * (total - pulse)
    return record(Plant(rig), commands), commands


def fit_b_r(rig, rec: dict, commands, u0: float) -> tuple[float, float, float]:
    """Least-squares fit of the wheel equation of (2.15), theta_r'' = b_r (u - F), with the
    friction F = sgn(w) F_c + f_v w of (3.17) (w = theta_r' - theta', the motor encoder's rate),
    integrated twice from rest:

        theta_r(t) = b_r U2(t) - b_r F_c sgn(u0) t^2/2 - b_r f_v Int_0^t phi_r dt,

    phi_r = motor encoder angle (2.2), U2 = double integral of the lagged torque.  Only the
    samples while the rotor still slips (before the motor count reaches its extreme, ERRATA E06:
    it re-sticks) are used.  Returns (b_r, F_c, f_v)."""
    h, dl = rec['h'], rig.count_angle
    theta = rec['pc'] * dl
    phi = rec['mc'] * dl
    theta_r = theta + phi
    k_end = (int(np.argmax(rec['mc'])) if u0 > 0 else int(np.argmin(rec['mc']))) - 3
    t = rec['t']
    U2 = lagged_input_integral(commands, h, rig.motor_time_constant)
    S2 = math.copysign(0.5, u0) * t ** 2
    P = cumtrapz(phi, h)
    sl = slice(0, k_end + 1)
    X = np.column_stack([U2[sl], -S2[sl], -P[sl]])
    c, *_ = np.linalg.lstsq(X, theta_r[sl], rcond=None)
    return c[0], c[1] / c[0], c[2] / c[0]


def fit_b_p_over_b_r(rig, rec: dict) -> float:
    """Least-squares fit of b_p / b_r from the sum of the two equations (2.11) -- as Section 2.3
    adds them to eliminate the rotor friction T_r:  J theta'' + J_r theta_r'' + m g l sin(theta)
    = -T_p, i.e. with (2.15)  theta'' + a sin(theta) = -(b_p/b_r) theta_r''  (pendulum-axis
    friction neglected, as the book does).  Integrated twice from rest:

        theta(t) + a Int Int sin(theta) = -(b_p / b_r) theta_r(t),

    valid whether the rotor slips or sticks, and for any friction; a = omega_p^2 from the swing."""
    h, dl = rec['h'], rig.count_angle
    theta = rec['pc'] * dl
    theta_r = theta + rec['mc'] * dl
    y = theta + rig.a * cumtrapz(cumtrapz(np.sin(theta), h), h)
    return -float(np.dot(theta_r, y) / np.dot(theta_r, theta_r))


@pytest.mark.parametrize('u0', [10.0, -10.0, 5.0])
def test_experiment3_torque_pulse_recovers_b_p_and_b_r(u0):
    """Experiment 3 (Section 2.6): a 20 ms pulse of u0 from rest; b_r and b_p (2.15) are
    identified from the encoder counts within 2 % (book 198 and 1.08; here b_p = k_u/J,
    b_r = k_u/J_r of the rig).  The friction constants of (3.17) come out of the same fit.

    ERRATA E06: the velocities do not 'remain constant' (friction makes the rotor re-stick) and
    the pendulum moves about one count during the pulse, so b_p cannot come from the quadratic
    growth of theta during the pulse: it is fitted from the summed equation over 0.3 s instead.
    """
    rig = load_rig()
    rec, commands = torque_pulse(rig, u0)
    b_r, f_c, f_v = fit_b_r(rig, rec, commands, u0)
    b_p = fit_b_p_over_b_r(rig, rec) * b_r
    assert b_r == pytest.approx(rig.b_r, rel=0.02)
    assert b_p == pytest.approx(rig.b_p, rel=0.02)
    assert b_r == pytest.approx(BOOK_B_R, rel=0.02)
    assert b_p == pytest.approx(BOOK_B_P, rel=0.02)
    coulomb = rig.friction_coulomb_pos if u0 > 0 else rig.friction_coulomb_neg
    viscous = rig.friction_viscous_pos if u0 > 0 else rig.friction_viscous_neg
    assert f_c == pytest.approx(coulomb, abs=0.05)
    assert f_v == pytest.approx(viscous, rel=0.2)


def test_experiment3_pulse_facts_of_errata_e06():
    """ERRATA E06, checked: with u0 = 5, h = 20 ms the pendulum moves less than one encoder count
    during the pulse; the rotor re-sticks to the pendulum roughly b_r (u0 - F) h /
    ((b_r + b_p) F) (~80 ms) after the pulse; afterwards the velocities are equal, not constant."""
    rig = load_rig()
    u0, pulse = 5.0, 20
    rec, _ = torque_pulse(rig, u0, pulse=pulse, total=300)
    assert np.max(np.abs(rec['pc'][:pulse + 1])) <= 1
    w_end = rec['states'][pulse].wheel_rate - rec['states'][pulse].theta_dot
    assert w_end == pytest.approx((rig.b_r + rig.b_p) * (u0 - 1.1) * pulse * rig.sample_period, rel=0.05)
    restick = int(np.argmax(rec['stuck'][pulse:])) + pulse
    assert rec['stuck'][restick:].all()
    predicted = rig.b_r * (u0 - 1.0) * pulse * rig.sample_period / ((rig.b_r + rig.b_p) * 1.0)
    # viscous friction (3.17) stops it a little earlier than the Coulomb-only estimate
    assert 0.6 * predicted < (restick - pulse) * rig.sample_period <= 1.05 * predicted


# =================================================== (d) pendulum-axis friction, Fig. 2.3
def test_pendulum_axis_energy_time_constant_about_one_minute():
    """Fig. 2.3 (Section 2.3): the energy E = (J + J_r) theta'^2 / 2 + m g l (1 - cos theta) of
    the free swing with the rotor stuck decays with a time constant of 'nearly 1 min'.  The
    energy at each turning point (theta' = 0) is m g l (1 - cos theta_max), theta_max from the
    pendulum encoder; an exponential fitted over 60 s of swing from 20 deg.

    The model's axis damping is theta'' = ... - theta'/tau_E on the pendulum alone, so with the
    rotor stuck the pair's energy decays with tau_E (J + J_r) / J (60.3 s for tau_E = 60 s)."""
    rig = load_rig()
    theta0 = math.radians(20)
    plant = Plant(rig, theta=theta0, wheel_angle=theta0)
    rec = record(plant, [0.0] * 60_000)
    assert rec['stuck'].all() and np.count_nonzero(rec['mc']) == 0
    peak_t, peak_c = half_cycle_peaks(rec['pc'], rec['t'])
    peak_e = rig.mgl * (1 - np.cos(peak_c * rig.count_angle))     # (2.5) at theta' = 0
    slope, _ = np.polyfit(peak_t, np.log(peak_e), 1)
    tau = -1.0 / slope
    expected = rig.pendulum_energy_time_constant * (rig.J + rig.j_r) / rig.J
    assert len(peak_t) > 150
    assert tau == pytest.approx(expected, rel=0.03)
    assert 50.0 < tau < 70.0                                       # "nearly 1 min"


# ===================================== (e) encoder, motor lag, PWM, disturbance torque
def test_encoder_step_is_one_4000th_of_a_turn():
    """Section 3.1: both encoders have 4000 counts/rev, one count = 2 pi/4000 = 0.00157 rad
    (0.09 deg, ERRATA E07); counts are rounded angles, the motor encoder measures theta_r - theta
    (2.1)-(2.2)."""
    rig = load_rig()
    dl = rig.count_angle
    assert dl == 2 * math.pi / 4000
    assert dl == pytest.approx(0.00157, abs=5e-6)
    assert math.degrees(dl) == pytest.approx(0.09)
    eps = 1e-6 * dl
    for n in (-2001, -1, 0, 1, 17, 1999):
        for frac, expect in ((0.5 - 1e-3, n), (0.5 + 1e-3, n + 1)):
            theta = (n + frac) * dl
            p = Plant(rig, theta=theta, wheel_angle=theta + (n + frac) * dl + eps)
            assert p.counts() == (expect, expect)


@pytest.mark.parametrize('u0', [10.0, -6.0])
def test_motor_current_lag_reaches_63_percent_after_te(u0):
    """Section 2.4: the current (torque) follows the command with the time constant
    L/R = T_e = 0.5 ms: after a step in u the torque reaches 63 % after 0.5 ms (sampled at
    0.1 ms), 86.5 % after one 1 ms sample, and the wheel integrates the lagged torque exactly."""
    rig = load_rig().replace(sample_period=0.0001)
    te = rig.motor_time_constant
    assert te == 0.0005
    p = Plant(rig, friction=False, pwm=False)
    torques = []
    for _ in range(20):
        p.step(u0)
        torques.append(p.state.torque)
    k63 = next(k for k, tq in enumerate(torques) if abs(tq) >= 0.632 * abs(u0)) + 1
    assert k63 * rig.sample_period == pytest.approx(te, abs=0.5 * rig.sample_period)
    assert torques[4] == pytest.approx(u0 * (1 - math.exp(-1)), rel=1e-9)

    rig1 = load_rig()
    h = rig1.sample_period
    p = Plant(rig1, friction=False, pwm=False)
    p.step(u0)
    assert p.state.torque == pytest.approx(u0 * (1 - math.exp(-h / te)), rel=1e-9)
    integral = u0 * (h - te * (1 - math.exp(-h / te)))          # int_0^h tau dt
    assert p.state.wheel_rate == pytest.approx(rig1.b_r * integral, rel=1e-4)   # RK4 on the lag
    # without the lag the torque is there at once
    q = Plant(rig1, friction=False, pwm=False, motor_lag=False)
    q.step(u0)
    assert q.state.torque == u0
    assert q.state.wheel_rate == pytest.approx(rig1.b_r * u0 * h, rel=1e-6)


def test_pwm_duty_quantization_500_steps():
    """Section 2.5: each PWM cycle has 500 segments, so the amplifier realises u in steps of
    u_max / 500 = 0.02 units (per polarity); saturation |u| <= 10 first (2.14)."""
    rig = load_rig()
    assert rig.pwm_steps == 500
    q = rig.u_max / rig.pwm_steps
    p = Plant(rig)
    levels = set()
    for u in np.linspace(-10.5, 10.5, 4_201):               # steps of q / 4
        v = p.quantize_command(float(u))
        n = v / q
        assert abs(v) <= rig.u_max and abs(n - round(n)) < 1e-9
        assert abs(v - min(max(u, -rig.u_max), rig.u_max)) <= q / 2 + 1e-12
        levels.add(round(n))
    assert levels == set(range(-500, 501))
    assert p.quantize_command(3.013) == pytest.approx(3.02)
    p.step(3.013)
    assert p.u_held == pytest.approx(3.02)
    free = Plant(rig, pwm=False)
    assert free.quantize_command(3.013) == 3.013
    assert Plant(rig.replace(pwm_steps=0)).quantize_command(3.013) == 3.013


def test_disturbance_torque_enters_as_plus_b_p_d():
    """ERRATA E20: an external torque d on the pendulum, in control units, enters (2.15) as
    +b_p d.  Rotor free: theta'' = b_p d, theta_r'' = 0; rotor stuck: the pair accelerates
    with k_u d / (J + J_r); the pendulum rests where a sin(theta) = b_p d."""
    rig = load_rig()
    h = rig.sample_period
    d = 4.0
    p = Plant(rig, friction=False, pendulum_friction=False)
    p.disturbance = d
    for _ in range(10):
        p.step(0.0)
    t = 10 * h
    s = p.state
    w = rig.omega_p
    # small angles: theta'' + a theta = b_p d  =>  theta' = b_p d sin(omega_p t) / omega_p
    assert s.theta_dot == pytest.approx(rig.b_p * d * math.sin(w * t) / w, rel=1e-6)
    assert s.theta_dot == pytest.approx(rig.b_p * d * t, rel=2e-3)
    assert s.wheel_rate == 0.0 and s.wheel_angle == 0.0
    stuck = Plant(rig, pendulum_friction=False)
    stuck.disturbance = d
    stuck.step(0.0)
    assert stuck.state.stuck
    assert stuck.state.theta_dot == pytest.approx(rig.k_u * d / (rig.J + rig.j_r) * h, rel=1e-3)
    assert stuck.state.wheel_rate == stuck.state.theta_dot
    # static deflection: at rest at asin(b_p d / a) it stays (within one count) for 1 s
    th0 = math.asin(rig.b_p * d / rig.a)
    still = Plant(rig, theta=th0)
    still.disturbance = d
    c0 = still.counts()
    for _ in range(1000):
        still.step(0.0)
    assert abs(still.counts()[0] - c0[0]) <= 1 and abs(still.state.theta - th0) < 1e-9
    # and the sign: a positive torque turns the pendulum to positive theta
    assert th0 > 0
