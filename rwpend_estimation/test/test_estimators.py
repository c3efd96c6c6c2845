"""Pure tests of the estimators against the book's numbers (no ROS)."""
import math

import numpy as np
import pytest

from rwpend_model.plant import Plant
from rwpend_model.rig import book_rig, load_rig
from rwpend_estimation.estimators import (
    ESTIMATORS, CountJumpError, Estimate, EstimatorConfig, joint5_gains, make_estimator,
    observer2_gains, observer3_gains, switch_estimator)

RIG = load_rig()
DELTA = RIG.count_angle
H = RIG.sample_period


def spin_stream(w, n, h=H):
    """Motor counts of a wheel spinning at w rad/s on a pendulum held at 0."""
    return [math.floor(w * k * h / DELTA + 0.5) for k in range(n)]


# ---------------------------------------------------------------- Section 3.4: bias and its removal
def run_spin(name, source, w=225.0, n=3000):
    f = RIG.friction(w)        # u0 = F(w) keeps the speed constant: theta_r'' = b_r (u - F) = 0
    est = make_estimator(name, RIG, EstimatorConfig(friction_source=source))
    rates = [est.step(0, mc, f).wheel_rate for mc in spin_stream(w, n)]
    return float(np.mean(rates[-1000:])) - w, est


def test_observer2_bias_matches_section_3_4():
    w = 225.0
    bias, _ = run_spin('observer2', 'none', w)
    k1, k2 = observer2_gains(100.0, 0.707)
    predicted = RIG.b_r * k1 * RIG.friction(w) / k2          # E10/E11: +10.08 rad/s (over-estimates)
    assert predicted == pytest.approx(10.08, abs=0.01)
    assert bias == pytest.approx(predicted, rel=1e-3)
    assert bias > 0


@pytest.mark.parametrize('name', ['observer3', 'nonlinear', 'joint5'])
def test_third_order_observer_removes_bias(name):
    w = 225.0
    bias, est = run_spin(name, 'observer', w)
    k1, k2 = observer2_gains(100.0, 0.707)
    predicted = RIG.b_r * k1 * RIG.friction(w) / k2
    assert abs(bias) < 0.01 * predicted
    assert est.last.friction == pytest.approx(RIG.friction(w), rel=0.01)   # E12: F = -x3/b_r


def test_observer2_with_friction_model_has_no_bias():
    bias, _ = run_spin('observer2', 'model')
    assert abs(bias) < 0.1


# ---------------------------------------------------------------- ripple (3.3), (3.7)
def one_count_jump(est):
    """Largest change of the wheel-rate estimate after the wheel angle steps by one count."""
    for _ in range(50):
        est.step(0, 0, 0.0)
    r0 = est.last.wheel_rate
    jumps = []
    for _ in range(3):
        jumps.append(abs(est.step(0, 1, 0.0).wheel_rate - r0))
        r0 = est.last.wheel_rate
    return max(jumps)


@pytest.mark.parametrize('T', [0.0025, 0.009, 0.01])
def test_filtered_difference_ripple(T):
    est = make_estimator('filtered', RIG, EstimatorConfig(T=T, friction_source='none'))
    assert one_count_jump(est) == pytest.approx(DELTA / (T + H), rel=1e-9)


def test_filtered_difference_book_example():
    rig = RIG.replace(sample_period=0.0005)                  # Section 3.3: h = 0.5 ms, T = 2.5 ms
    est = make_estimator('filtered', rig, EstimatorConfig(T=0.0025, friction_source='none'))
    assert one_count_jump(est) == pytest.approx(0.52, abs=0.005)


@pytest.mark.parametrize('omega0', [100.0, 316.0])
def test_observer_ripple(omega0):
    est = make_estimator('observer2', RIG, EstimatorConfig(omega0=omega0, friction_source='none'))
    k1, k2 = observer2_gains(omega0, 0.707)
    assert one_count_jump(est) == pytest.approx(k2 * H * DELTA, rel=1e-9)    # (3.7)
    if omega0 == 100.0:
        assert k2 * H * DELTA == pytest.approx(0.016, abs=0.0005)            # Section 7.1.1


def test_ripple_at_slow_constant_speed():
    """Peak-to-peak ripple of the estimates at 0.3 counts/sample is the one-count jump."""
    w = 0.3 * DELTA / H
    T = 0.009
    filt = make_estimator('filtered', RIG, EstimatorConfig(T=T, friction_source='none'))
    obs = make_estimator('observer2', RIG, EstimatorConfig(friction_source='none'))
    rf, ro = [], []
    for mc in spin_stream(w, 4000):
        rf.append(filt.step(0, mc, 0.0).wheel_rate)
        ro.append(obs.step(0, mc, 0.0).wheel_rate)
    ripple_f = max(rf[2000:]) - min(rf[2000:])
    ripple_o = max(ro[2000:]) - min(ro[2000:])
    assert ripple_f == pytest.approx(DELTA / (T + H), rel=0.15)
    # k2 = 1e4 < 1/(h (T + h)) = 1e5: the observer ripples less than the filter (Section 3.4);
    # at this speed the responses to successive counts overlap, so it is ~1.7 one-count jumps
    assert ripple_o < 0.25 * ripple_f


# ---------------------------------------------------------------- Section 7.1.2 K' tables
BOOK_K = {  # (omega0, zeta, alpha): (scale, K')
    (100.0, 0.707, 1.0): (1e3, [[0.1414, 1.1381, -0.0005, -0.0087, 0.0276],
                                [-0.0005, -0.0087, 0.2414, 2.7259, -5.0505]]),
    (100.0, 0.707, 0.2): (1e3, [[0.1414, 1.1381, -0.0001, -0.0017, 0.0055],
                                [-0.0001, -0.0017, 0.1614, 1.4486, -1.0101]]),
    (300.0, 0.707, 1.0): (1e5, [[0.0042, 0.1017, -0.0000, -0.0008, 0.0074],
                                [-0.0000, -0.0008, 0.0072, 0.2453, -1.3636]]),
    (300.0, 0.707, 0.2): (1e4, [[0.0424, 1.0172, -0.0000, -0.0016, 0.0149],
                                [-0.0000, -0.0016, 0.0484, 1.3037, -2.7272]]),
}


@pytest.mark.parametrize('spec', list(BOOK_K))
def test_joint5_gains_match_book(spec):
    scale, table = BOOK_K[spec]
    Kt = joint5_gains(book_rig(), *spec).T / scale
    book = np.array(table)
    # every printed entry to its last printed digit (4 decimals of the scaled table)
    assert np.all(np.abs(Kt - book) <= 0.5e-4 + 1e-9), (Kt, book)
    # 3 significant digits wherever the table prints at least 3
    big = np.abs(book) >= 0.01
    assert np.all(np.abs(Kt[big] - book[big]) <= 5e-3 * np.abs(book[big]))


def test_joint5_couplings_and_kapprox():
    """E44: the small couplings -0.5457, -8.7137, 27.5624 and Kapprox for omega0=100, alpha=1."""
    rig = book_rig()
    K = joint5_gains(rig, 100.0, 0.707, 1.0)
    assert K.T[0, 2:] == pytest.approx([-0.5457, -8.7137, 27.5624], abs=1e-4)
    wp, br = rig.omega_p, rig.b_r
    approx_row1 = [2 * 0.707 * 100, wp + 100 ** 2 / wp]
    approx_row2 = [(1 + 2 * 0.707) * 100, (1 + 2 * 0.707) * 100 ** 2 / wp, -100 ** 3 / br]
    assert K.T[0, :2] == pytest.approx(approx_row1, rel=1e-3)
    assert K.T[1, 2:] == pytest.approx(approx_row2, rel=1e-3)
    k1, k2, k3 = observer3_gains(100.0, 0.707, 1.0)            # (3.10) = Kapprox row 2 unscaled
    assert (k1, k2 / wp, -k3 / br) == pytest.approx(approx_row2)


# ---------------------------------------------------------------- swing-up tracking (7.1, E42)
def swing_up(name, source='observer', seconds=6.0):
    rig = RIG
    p = Plant(rig, theta=0.1)
    est = make_estimator(name, rig, EstimatorConfig(friction_source=source))
    u = 0.0
    errors, peak, theta_max = [], 0.0, 0.0
    for k in range(int(seconds / rig.sample_period)):
        e = est.step(*p.counts(), u)
        s = p.state
        if k * rig.sample_period > 0.2:          # after the initial transient
            errors.append(abs(e.theta_dot - s.theta_dot))
        peak = max(peak, abs(s.theta_dot))
        theta_max = max(theta_max, abs(s.theta))
        energy = rig.energy(s.theta, s.theta_dot)
        # E34/E35: u = sat(1.356e5 (E - 2) theta' - 1.6 theta_r')
        u = max(-10.0, min(10.0, 1.356e5 * (energy - 2.0) * s.theta_dot - 1.6 * s.wheel_rate))
        p.step(u)
    return max(errors), peak, theta_max


@pytest.mark.parametrize('name', ['nonlinear', 'joint5'])
def test_nonlinear_observer_tracks_swing_up(name):
    err, peak, theta_max = swing_up(name)
    assert theta_max > math.pi - 0.1             # swung up to (the homoclinic orbit through) pi
    assert peak > 15.0
    assert err < 0.02 * peak


def test_filtered_difference_lags_in_swing_up():
    """The T = 10 ms filter lags (E42: 10 ms), the observer does not."""
    err_f, peak, _ = swing_up('filtered', seconds=3.0)
    err_o, _, _ = swing_up('nonlinear', seconds=3.0)
    assert err_f > 3 * err_o


# ---------------------------------------------------------------- validation
@pytest.mark.parametrize('changes, word', [
    ({'T': float('nan')}, 'T must be finite'),
    ({'T': -0.01}, 'T must be in'),
    ({'omega0': 0.0}, 'omega0 must be in'),
    ({'omega0': float('inf')}, 'omega0 must be finite'),
    ({'zeta': -1.0}, 'zeta must be in'),
    ({'alpha': float('nan')}, 'alpha must be finite'),
    ({'pendulum_omega0': -5.0}, 'pendulum_omega0'),
    ({'estimator': 'kalman'}, 'estimator must be one of'),
    ({'friction_source': 'magic'}, 'friction_source must be one of'),
    ({'theta_offset': 100.0}, 'theta_offset'),
    ({'max_rate': 0.0}, 'max_rate'),
    ({'omega0': 'fast'}, 'omega0 must be a number'),
    ({'zeta': True}, 'zeta must be a number'),
])
def test_config_validation_refuses(changes, word):
    cfg = EstimatorConfig().replace(**changes)
    reasons = cfg.validate(RIG)
    assert reasons and any(word in r for r in reasons), reasons
    with pytest.raises(ValueError, match=word.split()[0]):
        make_estimator(None, RIG, cfg)
    with pytest.raises(ValueError):
        EstimatorConfig.from_values(changes, rig=RIG)


def test_config_validation_sampled_stability():
    assert EstimatorConfig().validate(RIG) == []
    for name in ('observer2', 'observer3', 'nonlinear', 'joint5'):
        bad = EstimatorConfig(estimator=name, omega0=3000.0, pendulum_omega0=3000.0)
        assert any('unstable' in r for r in bad.validate(RIG)), name
    assert EstimatorConfig(estimator='filtered', omega0=3000.0).validate(RIG) == []
    # zeta = 1: a real pole of multiplicity 4 > rank C cannot be placed
    assert any('cannot be placed' in r for r in
               EstimatorConfig(estimator='joint5', zeta=1.0).validate(RIG))


def test_from_values_coerces_and_keeps_base():
    base = EstimatorConfig(estimator='filtered', T=0.02)
    cfg = EstimatorConfig.from_values({'omega0': 150}, base=base, rig=RIG)
    assert cfg.omega0 == 150.0 and isinstance(cfg.omega0, float) and cfg.T == 0.02
    with pytest.raises(ValueError, match='unknown'):
        EstimatorConfig.from_values({'omega_0': 1.0})


# ---------------------------------------------------------------- counting
def test_multiturn_across_int32_wraparound():
    est = make_estimator('difference', RIG, EstimatorConfig(friction_source='none'))

    def i32(n):
        return ((n + 2 ** 31) % 2 ** 32) - 2 ** 31

    start = 2 ** 31 - 1500
    step_p, step_m = 7, -900      # pendulum forward, wheel spinning relative to it
    pend0 = start * DELTA
    est.step(i32(start), i32(-start), 0.0)
    for k in range(1, 4001):
        pc, mc = start + k * step_p, -start + k * step_m
        e = est.step(i32(pc), i32(mc), 0.0)
        assert e.theta_dot == pytest.approx(step_p * DELTA / H)
        assert e.wheel_rate == pytest.approx((step_p + step_m) * DELTA / H)
    assert e.theta == pytest.approx(pc * DELTA, abs=1e-9)
    assert e.theta > pend0 and pc > 2 ** 31                       # counted past the int32 limit
    assert e.wheel_angle == pytest.approx((pc + mc) * DELTA, abs=1e-9)


def test_hours_of_spinning_are_exact():
    est = make_estimator('difference', RIG, EstimatorConfig(friction_source='none'))
    est.step(0, 0, 0.0)
    total = 0
    per_sample = 500                                # ~785 rad/s relative
    raw = 0
    for _ in range(20):                             # jump ahead in big strides of raw counts
        for _ in range(10):
            total += per_sample
            raw = ((total + 2 ** 31) % 2 ** 32) - 2 ** 31
            est.step(0, raw, 0.0)
    assert est.last.wheel_angle == pytest.approx(total * DELTA)


def test_theta_offset_and_counts_are_angles():
    est = make_estimator('filtered', RIG, EstimatorConfig(theta_offset=math.pi))
    e = est.step(10, 20, 0.0)
    assert e.theta == pytest.approx(math.pi + 10 * DELTA)
    assert e.wheel_angle == pytest.approx(30 * DELTA)                  # theta_r = phi + phi_r (2.2)
    assert e.energy == pytest.approx(RIG.energy(e.theta, 0.0))


def test_absurd_jump_refused_state_unchanged():
    est = make_estimator('nonlinear', RIG)
    est.step(0, 0, 0.0)
    before = est.step(1, 5, 1.0)
    with pytest.raises(CountJumpError):
        est.step(100000, 5, 1.0)
    with pytest.raises(ValueError):
        est.step(1, 5, float('nan'))
    with pytest.raises(ValueError):
        est.step(1.5, 5, 0.0)
    assert est.last == before and est.raw_counts == (1, 5)
    est.step(2, 6, 1.0)                                                 # continues normally


def test_reset_rezeros_at_current_counts():
    est = make_estimator('observer3', RIG)
    for k in range(100):
        est.step(1000 + k, 50 + 3 * k, 0.5)
    est.reset()
    assert est.last.theta == 0.0 and est.last.wheel_angle == 0.0
    e = est.step(1100, 50 + 300, 0.0)
    assert e.theta == pytest.approx(DELTA) and e.wheel_angle == pytest.approx(4 * DELTA)
    fresh = make_estimator('difference', RIG)
    fresh.reset()                                                       # before any sample
    assert fresh.step(777, 888, 0.0).theta == 0.0


@pytest.mark.parametrize('new_name', ESTIMATORS)
def test_switch_without_jump(new_name):
    p = Plant(RIG, theta=0.5)
    old = make_estimator('difference', RIG, EstimatorConfig(estimator='difference'))
    for _ in range(300):
        p.step(2.0)
        old.step(*p.counts(), 2.0)
    last = old.last
    new = switch_estimator(old, EstimatorConfig(estimator=new_name))
    assert new.name == new_name and new.last.theta == last.theta
    p.step(2.0)
    e = new.step(*p.counts(), 2.0)
    assert abs(e.theta - last.theta) < 3 * DELTA
    assert abs(e.wheel_angle - last.wheel_angle - H * last.wheel_rate) < 0.01
    assert abs(e.theta_dot - last.theta_dot) < 2.0      # starts from the old velocity estimate


def test_switch_offset_shifts_theta():
    old = make_estimator('filtered', RIG)
    old.step(5, 0, 0.0)
    new = switch_estimator(old, EstimatorConfig(estimator='filtered', theta_offset=math.pi))
    assert new.last.theta == pytest.approx(5 * DELTA + math.pi)
    assert new.step(6, 0, 0.0).theta == pytest.approx(6 * DELTA + math.pi)


def test_init_from_refuses_nonfinite():
    est = make_estimator('joint5', RIG)
    with pytest.raises(ValueError):
        est.init_from(Estimate(float('nan'), 0, 0, 0, 0, 0), 0, 0)
    assert est.last is None
