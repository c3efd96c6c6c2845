"""Chapters 5-7: swing-up (16), observer (17), swing-up with the observer (18), friction limit
cycles with the describing function (19) and friction compensation (20)."""
from __future__ import annotations

import math

import numpy as np

from rwpend_control import design

from . import measure as M
from .chapter4 import UP, xdev
from .experiment import Analysis, Prompt, Run, within
from .figures import finish, panels, time_plot

OBSERVER = {'estimator': 'nonlinear', 'pendulum_omega0': 100.0, 'pendulum_zeta': 0.707}
FILTER = {'estimator': 'filtered', 'T': 0.01}


def patch_params(rig) -> dict:
    g = design.pddcontrolwpatch(rig, '1.5wp', 0.707)          # the gains of Figs. 6.3, 7.1, 7.2
    return {'patch.kpp': g.kpp, 'patch.kdp': g.kdp, 'patch.kdr': g.kdr}


def energy(rig, theta, theta_dot) -> np.ndarray:
    return 1 - np.cos(theta) + 0.5 * (np.asarray(theta_dot) / rig.omega_p) ** 2


# ============================================================ Experiment 16: energy swing-up
def runs_16(rig, options) -> list[Run]:
    c_e, c_v = design.swingup_gains(rig, 4000.0, 4.0, 0.4)     # Section 5.3.1 read per ERRATA E34
    return [Run('swingup', 'energy control (5.21)/(6.1), E_ref = 2 (scaled), from a slight push', 10.0,
                mode='swingup', sim={'initial.theta': 0.1, 'initial.wheel_angle': 0.1},
                controller={'swingup.c_e': c_e, 'swingup.c_v': c_v}, student=True,
                law_params={'c_e': c_e, 'c_v': c_v, 'e_ref': 2.0},
                # on the rig: still first (a swing left over from an earlier run), the
                # controller on once the push is seen (energy control gives u = 0 at rest)
                prompts=(Prompt('Let the pendulum hang still.', 'still', {'still_s': 1.0}),
                         Prompt('Give the pendulum a slight push.', 'released', {})), arm_after=2)]


def averaged_swingup_time(rig, e0: float, e1: float) -> float:
    """Time for the energy to grow from e0 to e1 with |u| = u_max always pumping (bang-bang, (5.21)):
    dE/dt = (b_p u_max / a) <|theta'|>, averaged over a swing of energy E (friction neglected)."""
    k = rig.b_p * rig.u_max / rig.a
    es = np.linspace(e0, e1, 200)
    rates = []
    for e in es:
        tm = math.acos(1 - e)                       # amplitude of a swing with scaled energy e
        th = np.linspace(0, tm, 2001)[:-1]
        speed = rig.omega_p * np.sqrt(np.maximum(2 * (e - 1 + np.cos(th)), 1e-12))
        quarter = np.trapezoid(1 / speed, th)
        rates.append(k * tm / quarter)              # <|theta'|> = 4 tm / (4 quarter)
    return float(np.trapezoid(1 / np.array(rates), es))


def analyze_16(rig, data) -> Analysis:
    d = data['swingup']
    e = energy(rig, d.theta, d.theta_dot)
    k = np.nonzero(e >= 1.9)[0]
    t_up = float(d.t[k[0]]) if k.size else None
    e0 = float(energy(rig, 0.1, 0.0))
    tail = d.window(d.t[-1] - 3.0, d.t[-1] + 1)
    a = Analysis()
    a.quantities += [
        within(16, 'time to reach E = 1.9', 's', t_up, averaged_swingup_time(rig, e0, 1.9), rel=0.35,
               ref='averaged (5.15) with |u| = u_max (friction neglected: it slows the pump)', run='swingup'),
        within(16, 'energy at the end (E_ref = 2 = 2 m g l)', '-', float(np.mean(e[tail])), 2.0, abs_tol=0.1,
               book='E_ref = 2 m g l (Section 5.3.1)', ref='(5.19)-(5.20): E -> E_ref (ERRATA E34-E36)', run='swingup'),
        within(16, 'closest approach to upright in the last 3 s', 'rad', float(np.min(np.abs(xdev(d.theta[tail])))),
               0.0, abs_tol=0.2, book='"comes close to the inverted position"', ref='homoclinic orbit E = 2',
               run='swingup')]
    a.notes.append('Without a push the law gives u = 0 at rest (theta\' = 0): hence "a slight push"; the energy '
                   'controller cannot balance: upright is reached only along the homoclinic orbit.')
    a.figures.append(time_plot('fig5_7', 'Fig. 5.7: pendulum response (theta)', d.t, [('theta (rad)', [(d.theta, '')])]))
    a.figures.append(time_plot('fig5_8', 'Fig. 5.8: disk (wheel) velocity', d.t, [('w (rad/s)', [(d.wheel_rate, '')])]))
    a.figures.append(time_plot('fig5_9', 'Fig. 5.9: pendulum energy (scaled, E_ref = 2)', d.t, [('E', [(e, '')])]))
    fig, (ax,) = panels(1, 3.5, 4.5)
    ax.plot(np.remainder(d.theta, 2 * np.pi), d.theta_dot, lw=0.5)
    ax.set_xlabel('theta mod 2 pi (rad)')
    ax.set_ylabel("theta' (rad/s)")
    a.figures.append(finish(fig, 'fig5_10', 'Fig. 5.10: pendulum phase portrait'))
    return a


# ============================================================ Experiment 17: observer (7.1)
E17_TAP = (2.0, 0.5)


def runs_17(rig, options) -> list[Run]:
    g = design.pddcontrolwpatch(rig, '1.5wp', 0.707)
    ctrl = {'balance.kpp': g.kpp, 'balance.kdp': g.kdp, 'balance.kpr': 0.0, 'balance.kdr': g.kdr}
    sim = {'initial.theta': UP, 'initial.wheel_angle': UP, 'taps.times': [E17_TAP[0]], 'taps.sizes': [E17_TAP[1]]}
    prompts = (Prompt('Raise the pendulum upright by hand.', 'upright', {'tol': 0.05}),
               Prompt('Tap the pendulum.', 'tap', {}, wait_s=E17_TAP[0], at=E17_TAP[0]))
    return [Run('filter', 'balance, velocity by the filtered difference T = 10 ms', 6.0, mode='balance', sim=sim,
                estimator=FILTER, controller=ctrl, prompts=prompts, arm_after=1),
            Run('observer', 'balance, velocity from the observer (7.1), omega0 = 100', 10.0, mode='balance', sim=sim,
                estimator=OBSERVER, controller=ctrl, prompts=prompts, arm_after=1)]


def quantization_limit_cycle(rig, g, k1: float, k2: float) -> float:
    """Frequency (rad/s) of the describing-function intersection of Section 7.3.2 (listing, ERRATA E51):
    the loop of the quantizer and G(s) = -C (sI - A)^-1 B, the higher crossing of the negative real axis."""
    import control as ct
    a_, bp, br = rig.a, rig.b_p, rig.b_r
    kpp, kdp, kdr = g.kpp, g.kdp, g.kdr
    A = np.array([[0, 1, 0, 0, 0, 0], [a_, 0, 0, bp * kdr, 0, bp * kdp], [0, 0, 0, 1, 0, 0],
                  [0, 0, 0, -br * kdr, 0, -br * kdp], [0, 0, 0, 0, -k1, 1], [0, 0, 0, bp * kdr, -k2, bp * kdp]])
    B = np.array([[0], [bp * kpp], [0], [-br * kpp], [k1], [a_ + k2 + bp * kpp]])
    C = -np.array([[1.0, 0, 0, 0, 0, 0]])
    sys = ct.ss(A, B, C, 0)
    w = np.linspace(50, 400, 20000)
    resp = ct.frequency_response(sys, w)
    G = np.asarray(resp.complex).ravel()
    cross = np.nonzero((G.imag[:-1] * G.imag[1:] < 0) & (G.real[:-1] < 0))[0]
    return float(w[cross[-1]]) if cross.size else float('nan')


def toggle_frequency(d, sl) -> float | None:
    """Dominant angular frequency of the pendulum count's motion (FFT peak above 20 rad/s)."""
    x = d.pc[sl] - np.mean(d.pc[sl])
    if not np.any(x):
        return None
    f = np.fft.rfftfreq(len(x), d.h) * 2 * np.pi
    p = np.abs(np.fft.rfft(x))
    p[f < 20] = 0
    return float(f[int(np.argmax(p))])


def analyze_17(rig, data) -> Analysis:
    from .chapter4 import count_jumps
    g = design.pddcontrolwpatch(rig, '1.5wp', 0.707)
    dl, h = rig.count_angle, rig.sample_period
    k1, k2 = 2 * 0.707 * 100.0, 100.0 ** 2
    a = Analysis()
    quiet = data['filter'].window(E17_TAP[0] + 1.5, 6.0)
    a.quantities.append(within(17, 'jump of u per pendulum count, filtered difference T = 10 ms', 'units',
                               count_jumps(data['filter'], quiet), (abs(g.kpp) + abs(g.kdp) / (0.01 + h)) * dl,
                               rel=0.15, ref='(4.12) with (3.3)', run='filter'))
    d = data['observer']
    dp = np.abs(np.diff(d.pc[quiet]))
    du2 = np.abs(d.u[quiet][2:] - d.u[quiet][:-2])
    j = du2[dp[:-1] == 1]
    a.quantities.append(within(17, 'jump of u over the two samples after a count, observer', 'units',
                               float(np.median(j)) if j.size else None,
                               (abs(g.kpp) + abs(g.kdp) * h * k2) * dl, rel=0.35,
                               book='h omega0^2 Delta = 0.016 rad/s in theta\'',
                               ref='Section 7.1.1: the estimate jumps by h k2 Delta', run='observer'))
    a.quantities.append(within(17, 'quantization limit cycle, observer (pendulum near a mark)', 'rad/s',
                               toggle_frequency(d, d.window(6.0, 10.0)), quantization_limit_cycle(rig, g, k1, k2),
                               rel=0.2, book=120, ref='Section 7.3.2: describing function of the quantizer, continuous '
                               'loop (ERRATA E49-E52: the sampled loop gives 115)',
                               run='observer'))
    for name in ('filter', 'observer'):
        dd = data[name]
        sl = dd.window(1.0, 4.0)
        a.figures.append(time_plot(f'fig7_1_{name}', ('Fig. 7.1: stabilization with the observer (7.1), omega0 = 100'
                                                     if name == 'observer' else 'Fig. 4.4-like: the same with the '
                                                     'filtered difference, T = 10 ms') + '; tap at 2 s', dd.t[sl],
                                   [('theta - pi (counts)', [(xdev(dd.theta[sl]) / dl, '')]),
                                    ("theta' (rad/s)", [(dd.theta_dot[sl], '')]), ('u', [(dd.u[sl], '')])]))
    return a


# ============================================================ Experiment 18: swing-up + catch
def runs_18(rig, options) -> list[Run]:
    prompts = (Prompt('Let the pendulum hang still.', 'still', {'still_s': 1.0}),)
    return [Run(name, f'auto (Chapter 6): swing-up, catch with the patched stabilizer, velocities from the {what}',
                10.0, mode='auto', estimator=est, controller=patch_params(rig), prompts=prompts, arm_after=1)
            for name, what, est in (('filter', 'filtered difference T = 10 ms (Fig. 6.3)', FILTER),
                                    ('observer', 'observer (7.1), omega0 = 100 (Fig. 7.2)', OBSERVER))]


def lag(est: np.ndarray, true: np.ndarray, h: float, max_lag: int = 30) -> float:
    """Delay (s) of est behind true: the shift minimizing the squared difference."""
    n = len(true)
    errs = [np.mean((est[k:] - true[:n - k]) ** 2) for k in range(max_lag)]
    return int(np.argmin(errs)) * h


def analyze_18(rig, data) -> Analysis:
    a = Analysis()
    bound = design.switching_region_bound(rig)
    h = rig.sample_period
    for name in ('filter', 'observer'):
        d = data[name]
        catches = [t for t, _, law, _ in d.switches if law == 'catch']
        x = xdev(d.theta)
        xi = None
        if catches:
            k = int(round(catches[-1] / h))
            xi = float(d.theta_dot[k] + rig.omega_p * x[k])
        swing = d.window(0.0, catches[0] if catches else d.t[-1])
        a.quantities += [
            within(18, f'xi = theta\' + omega_p (theta - pi) at the catch ({name})', 'rad/s', xi, 0.0, abs_tol=bound,
                   book='on the homoclinic orbit', ref='(6.4)-(6.6): |xi| < b_p u_max / omega_p', run=name),
            within(18, f'|theta - pi| at the end ({name})', 'rad', float(np.max(np.abs(x[d.window(9.0, 10.0)]))), 0.0,
                   abs_tol=0.05, ref='caught and balanced (Section 6.5)', run=name),
            within(18, f'delay of the velocity estimate during the swing ({name})', 's',
                   lag(d.theta_dot[swing], d.truth['true_theta_dot'][swing], h) if d.truth else None,
                   0.01 if name == 'filter' else 0.0, abs_tol=0.003,
                   book='the observer leads the filter (Fig. 7.4)',
                   ref='(3.3): delay T; (7.1) with ERRATA E42: none', run=name)]
    for name, figs in (('filter', ('6.3', '6.5')), ('observer', ('7.2', '7.3'))):
        d = data[name]
        a.figures.append(time_plot(f'fig{figs[0].replace(".", "_")}', f'Fig. {figs[0]}: swing-up and catch, velocity '
                                   f'from the {name}', d.t, [('theta (rad)', [(d.theta, '')]),
                                                            ("theta' (rad/s)", [(d.theta_dot, '')]), ('u', [(d.u, '')])]))
        fig, (ax,) = panels(1, 3.5, 4.5)
        ax.plot(np.remainder(d.theta, 2 * np.pi), d.theta_dot, lw=0.5)
        ax.set_xlabel('theta mod 2 pi (rad)')
        ax.set_ylabel("theta' (rad/s)")
        a.figures.append(finish(fig, f'fig{figs[1].replace(".", "_")}', f'Fig. {figs[1]}: phase portrait ({name})'))
    d = data['filter']
    a.figures.append(time_plot('fig6_4', 'Fig. 6.4: scaled energy E, theta\' and u (filter)', d.t,
                               [('E', [(energy(rig, d.theta, d.theta_dot), '')]), ("theta'", [(d.theta_dot, '')]),
                                ('u', [(d.u, '')])]))
    o, f = data['observer'], data['filter']
    a.figures.append(time_plot('fig7_4', 'Fig. 7.4: velocity from the observer and the filter, and their difference',
                               o.t, [("theta' (rad/s)", [(o.theta_dot, 'observer'), (f.theta_dot, 'filter')]),
                                     ('difference', [(o.theta_dot - f.theta_dot, '')])]))
    return a


# ============================================================ Experiments 19-20: friction limit cycle
def pdpd_set1(rig):
    return design.pdpdcontrol(rig, 'wp', 0.707, 'wp', 1.0)      # (-496, -56, -0.396, -0.153) of Fig. 7.5


def runs_19(rig, options, compensation: str = 'off') -> list[Run]:
    g = pdpd_set1(rig)
    return [Run(f'friction_{compensation}', f'(4.13) with (4.15) at omega_p; friction compensation {compensation}',
                20.0, mode='balance', estimator=FILTER,
                # a small tap starts the cycle (exactly upright at rest the stiction holds everything)
                sim={'initial.theta': UP, 'initial.wheel_angle': UP, 'taps.times': [1.0], 'taps.sizes': [0.3]},
                controller={'balance.kpp': g.kpp, 'balance.kdp': g.kdp, 'balance.kpr': g.kpr, 'balance.kdr': g.kdr,
                            'friction_compensation': compensation},
                prompts=(Prompt('Raise the pendulum upright by hand.', 'upright', {'tol': 0.05}),), arm_after=1)]


def runs_20(rig, options) -> list[Run]:
    return runs_19(rig, options, 'off') + runs_19(rig, options, 'model')


def friction_loop(rig, g):
    """G(s) from the friction F to theta' - theta_r' (Section 7.2, ERRATA E45-E47)."""
    import control as ct
    a_, bp, br = rig.a, rig.b_p, rig.b_r
    den = [1, -bp * g.kdp + br * g.kdr, -a_ - bp * g.kpp + br * g.kpr, -a_ * br * g.kdr, -a_ * br * g.kpr]
    return ct.tf([br + bp, 0, -br * a_, 0], den)


def friction_df(c: float, v: float):
    import control as ct

    class CoulombViscous(ct.DescribingFunctionNonlinearity):
        """F = c sgn(w) + v w (3.17): N(a) = 4 c / (pi a) + v."""

        def __call__(self, x):
            return c * np.sign(x) + v * x

        def describing_function(self, A):
            return 4 * c / (np.pi * A) + v
    return CoulombViscous()


def df_prediction(rig, g, viscous: bool = True) -> tuple[float, float]:
    """(period s, wheel-angle amplitude rad) of the friction limit cycle by the describing function
    (python-control describing_function_response): G(i w) N(a) = -1 (7.4)."""
    import control as ct
    v = rig.friction_viscous_pos if viscous else 0.0
    resp = ct.describing_function_response(friction_loop(rig, g), friction_df(rig.friction_coulomb_pos, v),
                                           np.logspace(-1, 3, 400), omega=np.logspace(-1, 2, 2000))
    amp, w = resp.intersections[0]
    return 2 * math.pi / w, amp / w


def wheel_cycle(d, t0: float = 5.0):
    from rwpend_bag.analysis import limit_cycle
    sl = d.window(t0, d.t[-1] + 1)
    return limit_cycle(d.t[sl], d.wheel_angle[sl])


def analyze_19(rig, data) -> Analysis:
    g = pdpd_set1(rig)
    period, amp = df_prediction(rig, g)
    _, amp_c = df_prediction(rig, g, viscous=False)
    lc = wheel_cycle(data['friction_off']) or {}
    a = Analysis()
    a.quantities += [
        within(19, 'period of the wheel limit cycle', 's', lc.get('period_s'), period, rel=0.15, book=1.5,
               ref='(7.4): describing function of (3.17) on G of Section 7.2 (book experiment 1.33 s)',
               run='friction_off'),
        within(19, 'amplitude of the wheel angle', 'rad', lc.get('amplitude_rad'), amp, rel=0.2, book=3.14,
               ref=f'(7.4) with N = 4c/(pi a) + v (Coulomb only: {amp_c:.3f} rad; ERRATA E48)', run='friction_off')]
    d = data['friction_off']
    a.figures.append(time_plot('fig7_5', 'Fig. 7.5: stabilization with (4.13) at omega_p: the friction limit cycle '
                               'of the wheel', d.t, [('theta_r (rad)', [(d.wheel_angle - np.mean(d.wheel_angle), '')]),
                                                     ('theta - pi (rad)', [(xdev(d.theta), '')])]))
    a.figures.append(nyquist_figure(rig, g))
    return a


def nyquist_figure(rig, g):
    import control as ct
    G = friction_loop(rig, g)
    w = np.logspace(-1, 2.5, 3000)
    z = np.asarray(ct.frequency_response(G, w).complex).ravel()
    fig, (ax,) = panels(1, 3.5, 5.0)
    ax.plot(z.real, z.imag, lw=0.9, label='G(i w)')
    amps = np.logspace(-0.5, 2.5, 200)
    n = friction_df(rig.friction_coulomb_pos, rig.friction_viscous_pos).describing_function(amps)
    ax.plot(-1 / n, 0 * amps, 'r', lw=2, label='-1/N(a)')
    ax.set_xlim(-40, 10)
    ax.set_ylim(-25, 25)
    ax.set_xlabel('Re')
    ax.set_ylabel('Im')
    ax.legend(fontsize=7)
    return finish(fig, 'fig7_7', 'Fig. 7.7: Nyquist curve of G (friction to theta\' - theta_r\') and the '
                  'describing function of the friction')


def analyze_20(rig, data) -> Analysis:
    off = wheel_cycle(data['friction_off']) or {}
    on = wheel_cycle(data['friction_model']) or {}
    ratio = (on.get('amplitude_rad', 0.0) / off['amplitude_rad']) if off.get('amplitude_rad') else None
    a = Analysis()
    a.quantities += [
        within(20, 'amplitude of the wheel limit cycle without compensation', 'rad', off.get('amplitude_rad'),
               df_prediction(rig, pdpd_set1(rig))[1], rel=0.2, book=3.0, ref='as Experiment 19', run='friction_off'),
        within(20, 'amplitude with / without friction compensation', '-', ratio, 0.0, abs_tol=0.5,
               book=round(0.8 / 3.0, 2),
               ref='Section 7.2.1: compensated friction leaves no limit cycle; the dead band and the estimate '
               'leave a residue', run='friction_model')]
    d0, d1 = data['friction_off'], data['friction_model']
    a.figures.append(time_plot('fig7_8', 'Fig. 7.8: the wheel angle without and with friction compensation (3.17)',
                               d0.t, [('theta_r (rad)', [(d0.wheel_angle - np.mean(d0.wheel_angle), 'off'),
                                                         (d1.wheel_angle - np.mean(d1.wheel_angle), 'compensated')])]))
    return a
