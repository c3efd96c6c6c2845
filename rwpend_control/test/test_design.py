"""Gain designs vs the book's printed numbers (book_rig: g = 9.91, ERRATA E01)."""
import numpy as np
import pytest

from rwpend_model.rig import book_rig, load_rig
from rwpend_control import design
from rwpend_control.design import Gains


@pytest.fixture(scope='module')
def rig():
    return book_rig()


def close(g, ref, rel=0.005):
    for name, v in ref.items():
        assert getattr(g, name) == pytest.approx(v, rel=rel), (name, getattr(g, name), v)


def test_rig_matches_book(rig):
    assert rig.a == pytest.approx(78.42, abs=0.01)
    assert rig.b_p == pytest.approx(1.0805, abs=1e-4)
    assert rig.b_r == pytest.approx(198.0, abs=0.05)
    assert rig.omega_p == pytest.approx(8.856, abs=1e-3)


def test_parse_omega(rig):
    assert design.parse_omega('1.5wp', rig) == pytest.approx(1.5 * rig.omega_p)
    assert design.parse_omega('wp', rig) == pytest.approx(rig.omega_p)
    assert design.parse_omega(' 2 * wp ', rig) == pytest.approx(2 * rig.omega_p)
    assert design.parse_omega('20', rig) == 20.0
    assert design.parse_omega(12.5, rig) == 12.5
    for bad in ('', 'abc', '1.5xx', '-1wp', '0', float('nan'), float('inf'), -3.0, True, None, [1]):
        with pytest.raises(ValueError):
            design.parse_omega(bad, rig)


def test_pd_experiment12(rig):
    # E18: the book prints +145, +16.4; consistent values are negative
    g = design.pd_control(rig, 'wp', 1.0)
    close(g, {'kpp': -145.2, 'kdp': -16.39})
    ok, why = design.check_stable(rig, Gains(145.0, 16.4))
    assert not ok and 'unstable' in why
    assert not design.check_stable(rig, g)[0]                      # wheel drifts (4.6)
    assert design.check_stable(rig, g, allow_wheel_drift=True)[0]
    # up-down transformation (E21): kpp grows by 2a/b_p in magnitude going up
    down = design.up_down(rig, g)
    assert down.kpp - g.kpp == pytest.approx(2 * rig.a / rig.b_p)
    assert 2 * rig.a / rig.b_p == pytest.approx(145.2, abs=0.1)
    assert down.kdp == g.kdp


@pytest.mark.parametrize('w0, ref', [
    ('1.5wp', {'kpp': -282.0, 'kdp': -25.4, 'kdr': -0.0302}),     # Section 4.2 text
    ('2wp', {'kpp': -445.0, 'kdp': -39.6, 'kdr': -0.0716}),       # book -444 (E26)
    ('2.5wp', {'kpp': -654.0, 'kdp': -58.7, 'kdr': -0.1398}),     # book -59.8, -0.1405 (E26)
    ('wp', {'kpp': -165.7, 'kdp': -14.87, 'kdr': -0.00895}),      # E24: not the captions' set
])
def test_pddcontrol(rig, w0, ref):
    g = design.pddcontrol(rig, w0, 0.707, 0.2)
    close(g, ref)
    assert g.kpr == 0.0
    w = design.parse_omega(w0, rig)
    poles = design.closed_loop_poles(rig, g)
    want = np.concatenate([[-0.2 * w], np.roots([1, 2 * 0.707 * w, w * w])])
    assert np.sort_complex(poles) == pytest.approx(np.sort_complex(want), rel=1e-6)


def test_pddcontrol_book_printed_within_2_percent(rig):
    # E26: the book's 2.5 wp k_dp = -59.8 is 1.9 % off (4.11)
    g = design.pddcontrol(rig, '2.5wp', 0.707, 0.2)
    assert abs(g.kdp / -59.8 - 1) < 0.02


def test_pdpdcontrol_first_set_and_acker(rig):
    g = design.pdpdcontrol(rig, 'wp', 0.707, 'wp', 1.0)
    close(g, {'kpp': -496.0, 'kdp': -56.0, 'kpr': -0.396, 'kdr': -0.153})
    # Section 4.7 / E30: acker gives K = (-495.5568, -55.9593, -0.3961, -0.1527)
    wp = rig.omega_p
    poles = np.concatenate([np.roots([1, 2 * 0.707 * wp, wp ** 2]), np.roots([1, 2 * wp, wp ** 2])])
    k = design.acker_design(rig, poles)
    for got, want in zip((k.kpp, k.kdp, k.kpr, k.kdr), (-495.5568, -55.9593, -0.3961, -0.1527)):
        assert got == pytest.approx(want, abs=6e-5)
    assert k.kpp == pytest.approx(g.kpp, rel=1e-9) and k.kdr == pytest.approx(g.kdr, rel=1e-9)


def test_pdpdcontrol_second_set_E29(rig):
    g = design.pdpdcontrol(rig, 'wp', 1.0, '0.5wp', 0.707)
    close(g, {'kpp': -284.0, 'kdp': -32.0, 'kpr': -0.0990})
    # E29: (4.15) gives -0.0540, the listing's bug gives the printed -0.0763
    assert g.kdr == pytest.approx(-0.0540, abs=5e-5)
    wp = rig.omega_p
    poles = design.closed_loop_poles(rig, g)
    want = np.concatenate([[-wp, -wp], np.roots([1, 2 * 0.707 * 0.5 * wp, (0.5 * wp) ** 2])])
    assert np.sort_complex(poles) == pytest.approx(np.sort_complex(want), abs=1e-4)
    # with the printed (buggy) k_dr the loop is the badly damped one of E29
    bug = design.closed_loop_poles(rig, Gains(g.kpp, g.kdp, g.kpr, -0.0763))
    zeta = min(-p.real / abs(p) for p in bug)
    assert zeta == pytest.approx(0.45, abs=0.01)


@pytest.mark.parametrize('w0, ref', [
    ('wp', {'kpp': -248.0, 'kdp': -28.0, 'kdr': -0.0447}),
    ('1.5wp', {'kpp': -389.0, 'kdp': -44.0, 'kdr': -0.101}),
    ('2wp', {'kpp': -568.0, 'kdp': -64.1, 'kdr': -0.179}),
])
def test_patch_E39(rig, w0, ref):
    g = design.pddcontrolwpatch(rig, w0, 0.707)
    close(g, ref, rel=0.005)
    # E39: k_pp = +omega_p k_dp (both negative), the printed (6.4) sign is wrong
    assert g.kpp == pytest.approx(rig.omega_p * g.kdp, rel=1e-12)
    poles = design.closed_loop_poles(rig, g)
    assert min(abs(p + rig.omega_p) for p in poles) < 1e-9          # E40: pole at -omega_p
    assert design.check_stable(rig, g)[0]
    # with the printed sign (kpp = -omega_p kdp) the loop is unstable
    assert not design.check_stable(rig, Gains(-g.kpp, g.kdp, 0.0, g.kdr))[0]


def test_wheel_designs(rig):
    pi = design.pi_control(rig, 20.0, 1.0)
    assert pi.kdr == pytest.approx(2 * 20 / rig.b_r)
    assert pi.ki == pytest.approx(400 * 0.001 / rig.b_r)            # E15: per-sample gain
    pd = design.wheel_pd(rig, 10.0, 0.707)
    assert pd.kpr == pytest.approx(100 / rig.b_r)
    assert pd.kdr == pytest.approx(2 * 0.707 * 10 / rig.b_r)
    with pytest.raises(ValueError):
        design.pi_control(rig, 20.0, float('nan'))
    with pytest.raises(ValueError):
        design.pddcontrol(rig, '1.5wp', 0.707, -0.2)


def test_swingup_gains_E34(rig):
    c_e, c_v = design.swingup_gains(rig)
    assert c_e == pytest.approx(1.356e5, rel=1e-3)
    assert c_v == pytest.approx(1.6)
    assert design.switching_region_bound(rig) == pytest.approx(1.22, abs=0.005)   # E41


def test_check_stable_reasons(rig):
    ok, why = design.check_stable(rig, Gains(-282.0, -25.4, 0.0, +0.03))       # wrong kdr sign
    assert not ok and 'pole' in why
    ok, why = design.check_stable(rig, Gains(float('nan'), -25.4))
    assert not ok and 'not finite' in why
    ok, why = design.check_stable(rig, design.pddcontrol(rig, '1.5wp'))
    assert ok and why.startswith('stable')


def test_physical_g_differs_by_about_one_percent():
    g = design.pddcontrol(load_rig(), '1.5wp')
    assert abs(g.kpp / -282.06 - 1) < 0.015                              # E01
