"""Chapter 4, the inverted pendulum: Experiments 12 (PD only), 13 (PD + wheel rate), 14 (wheel angle),
15 (disturbance torque).  Gains from rwpend_control.design (the book's pole specifications)."""
from __future__ import annotations

import math

import numpy as np

from rwpend_control import design

from . import measure as M
from .experiment import Analysis, Prompt, Run, within
from .figures import time_plot

PROC = 'rwpend_lab.procedures:'
UP = math.pi
#: on the rig the controller is switched on once the pendulum is upright (Run.arm_after = 1):
#: balance, started hanging down, turns itself off at once (|theta - pi| > theta_0)
RAISE = Prompt('Raise the pendulum upright by hand and hold it there; the controller takes over within '
               '3 degrees of upright.', 'upright', {'tol': 0.05})


def xdev(theta: np.ndarray) -> np.ndarray:
    """wrap(theta - pi): the deviation from upright (ERRATA E38)."""
    return np.remainder(np.asarray(theta), 2 * np.pi) - np.pi


def gain_params(g) -> dict:
    return {'balance.kpp': g.kpp, 'balance.kdp': g.kdp, 'balance.kpr': g.kpr, 'balance.kdr': g.kdr}


# ============================================================ Experiment 12: PD only (4.2)
E12_THETA0 = 0.02
E12_D0 = 1.0      # units: the pendulum then leans ~9 counts (fewer would be quantized away)


def runs_12(rig, options) -> list[Run]:
    g = design.pd_control(rig, 'wp', 1.0)       # (4.3), omega0 = omega_p, zeta = 1 (ERRATA E18)
    ctrl = {**gain_params(g), 'allow_wheel_drift': True}
    lp = {'kpp': g.kpp, 'kdp': g.kdp}
    est = {'estimator': 'filtered', 'T': 0.01}      # no model-based bias from the unmodelled torque
    start = {'initial.theta': UP + E12_THETA0, 'initial.wheel_angle': UP + E12_THETA0}
    return [Run('ideal', f'PD (4.2), released {E12_THETA0} rad off upright, no friction', 2.0, mode='balance',
                sim={**start, 'friction': False}, controller=ctrl, estimator=est, student=True, law_params=lp, prompts=(RAISE,), arm_after=1),
            Run('friction', 'PD (4.2), released off upright, with friction (3.17)', 2.0, mode='balance',
                sim=start, controller=ctrl, estimator=est, student=True, law_params=lp, prompts=(RAISE,), arm_after=1),
            Run('cable', f'PD (4.2), no friction, a torque {E12_D0} units (the cables) from 0.5 s', 1.6,
                mode='balance', sim={'initial.theta': UP, 'initial.wheel_angle': UP, 'friction': False,
                                     'torques.times': [0.5], 'torques.sizes': [E12_D0], 'torques.durations': [100.0]},
                controller=ctrl, estimator=est, student=True, law_params=lp, prompts=(RAISE,), arm_after=1)]


def runaway_rate(rig, g) -> float:
    """Growth rate of the wheel speed under the PD law with the viscous friction v w_rel of (3.17):
    the positive eigenvalue of the linearized loop x'' = a x - b_p (u - F), w' = b_r (u - F),
    u = -k_pp x - k_dp x', F = v (w - x')."""
    a_, bp, br, v = rig.a, rig.b_p, rig.b_r, rig.friction_viscous_pos
    # state (x, x', w); u - F = -k_pp x - k_dp x' - v w + v x'
    row = np.array([-g.kpp, -g.kdp + v, -v])
    A = np.vstack([[0.0, 1.0, 0.0], np.array([a_, 0.0, 0.0]) - bp * row, br * row])
    return float(max(np.linalg.eigvals(A).real))


def analyze_12(rig, data) -> Analysis:
    g = design.pd_control(rig, 'wp', 1.0)
    a_, bp, br = rig.a, rig.b_p, rig.b_r
    p0 = a_ + bp * g.kpp
    a = Analysis()
    d = data['ideal']
    w_end = float(np.mean(d.wheel_rate[d.window(0.5, 0.8)]))   # later the quantized loop random-walks (E19)
    a.quantities.append(within(12, 'wheel speed after the release (no friction)', 'rad/s', w_end,
                               br * a_ * g.kdp * E12_THETA0 / p0, rel=0.05,
                               book=round(bp * br * a_ * g.kdp * g.kpp * E12_THETA0 / p0, 0),
                               ref='(4.6) corrected (ERRATA E19): b_r a k_dp theta0 / (a + b_p k_pp)', run='ideal'))
    d = data['friction']
    w = np.abs(d.wheel_rate)
    c, v = rig.friction_coulomb_pos, rig.friction_viscous_pos
    fell = min([t for t, mode, _, _ in d.switches if mode == 'off'] + [d.t[-1]])
    ok = (w > 100) & (w < 300) & (d.t < fell)
    rate = M.line_fit(d.t[ok], np.log(w[ok] + c / v))[0] if ok.sum() > 10 else None
    a.quantities.append(within(12, 'runaway rate of the wheel with friction', '1/s', rate, runaway_rate(rig, g),
                               rel=0.1, book='"the PD controller will fail after a short time"',
                               ref='(4.1) with (4.2) and F = c + v w_rel (3.17): unstable eigenvalue', run='friction'))
    d = data['cable']
    sl = d.window(1.0, 1.6)
    acc = M.line_fit(d.t[sl], d.wheel_rate[sl])[0]
    a.quantities.append(within(12, 'wheel acceleration under a constant torque d0', 'rad/s^2', acc,
                               br * bp * g.kpp * E12_D0 / p0, rel=0.1, book='b_r b_p k_pp d0/(a + b_p k_pp)',
                               ref='Section 4 after (4.6) (ERRATA E20: d in control units)', run='cable'))
    a.notes.append(f'Gains (4.3) for omega0 = omega_p, zeta = 1: k_pp = {g.kpp:.1f}, k_dp = {g.kdp:.2f} '
                   '(the book prints them positive, ERRATA E18).')
    curves = [(data[n].wheel_rate, n) for n in ('ideal', 'friction', 'cable')]
    a.figures.append(time_plot('exp12', 'Experiment 12: wheel speed under the PD law (4.2)', data['friction'].t,
                               [('w (rad/s)', curves),
                                ('theta - pi (rad)', [(xdev(data[n].theta), n) for n in ('ideal', 'friction', 'cable')])]))
    return a


# ============================================================ Experiment 13: (4.9), three pole sets
E13_OMEGA = ('1.5wp', '2wp', '2.5wp')     # the three sets of Section 4.2 (ERRATA E24)
E13_T = 0.02                              # filter of the book's figures (ERRATA E27)
E13_TAP = (2.0, 0.8)


def runs_13(rig, options) -> list[Run]:
    out = []
    for w0 in E13_OMEGA:
        g = design.pddcontrol(rig, w0, 0.707, 0.2)
        out.append(Run(f'w0_{w0}', f'(4.9) with (4.11) at omega0 = {w0}, zeta = 0.707, alpha = 0.2; tap at '
                       f'{E13_TAP[0]:g} s', 7.0, mode='balance',
                       sim={'initial.theta': UP, 'initial.wheel_angle': UP, 'taps.times': [E13_TAP[0]],
                            'taps.sizes': [E13_TAP[1]]},
                       estimator={'estimator': 'filtered', 'T': E13_T}, controller=gain_params(g), student=True,
                       law_params={'kpp': g.kpp, 'kdp': g.kdp, 'kdr': g.kdr},
                       prompts=(RAISE, Prompt('Tap the pendulum lightly with a ruler.', 'tap', {},
                                              wait_s=E13_TAP[0], at=E13_TAP[0])),
                       arm_after=1))
    return out


def count_jumps(d, sl) -> float | None:
    """Median |u_k - u_(k-1)| at the samples where the pendulum count moves by one."""
    dp = np.abs(np.diff(d.pc[sl]))
    du = np.abs(np.diff(d.u[sl]))
    j = du[dp == 1]
    return float(np.median(j)) if j.size else None


def linear_peak(rig, g, dv: float, duration: float = 2.0) -> float:
    """Peak |theta - pi| of the linearized closed loop (4.8) after a tap theta' += dv."""
    from scipy.linalg import expm
    A, B = design.upright_model(rig)
    K = g.vector()
    Acl = A - np.outer(B, K)
    h = 0.001
    Ad = expm(Acl * h)
    x = np.array([0.0, dv, 0.0, 0.0])
    peak = 0.0
    for _ in range(int(duration / h)):
        x = Ad @ x
        peak = max(peak, abs(x[0]))
    return peak


def friction_speed(rig, kdr: float, sign: float) -> float:
    """Wheel speed where the wheel-rate term of (4.9) holds the friction (3.17): -k_dr w = F(w)."""
    c, v = ((rig.friction_coulomb_pos, rig.friction_viscous_pos) if sign > 0
            else (rig.friction_coulomb_neg, rig.friction_viscous_neg))
    return sign * c / (abs(kdr) - v)


def analyze_13(rig, data) -> Analysis:
    a = Analysis()
    dl, h = rig.count_angle, rig.sample_period
    for w0, book_du in zip(E13_OMEGA, (2.37, 3.81, 5.72)):
        name = f'w0_{w0}'
        d = data[name]
        g = design.pddcontrol(rig, w0, 0.707, 0.2)
        quiet = d.window(E13_TAP[0] + 2.0, d.t[-1] + 1)   # the wheel turns, the count moves
        w_end = float(np.mean(d.wheel_rate[d.window(6.0, 7.0)]))
        x = xdev(d.theta)
        after = d.window(E13_TAP[0] + 1.5, E13_TAP[0] + 2.0)
        a.quantities += [
            within(13, f'jump of u per pendulum count, omega0 = {w0}', 'units', count_jumps(d, quiet),
                   (abs(g.kpp) + abs(g.kdp) / (E13_T + h)) * dl, rel=0.1, book=book_du,
                   ref='(4.12) with the filter (3.3): (|k_pp| + |k_dp|/(T + h)) Delta (ERRATA E27)', run=name),
            within(13, f'wheel speed held against friction, omega0 = {w0}', 'rad/s', w_end,
                   friction_speed(rig, g.kdr, math.copysign(1.0, w_end or 1.0)), rel=0.15,
                   book='"approximately constant speed"', ref='-k_dr w = F(w) at rest upright (3.17)', run=name),
            within(13, f'largest deviation 1.5-2 s after the tap, omega0 = {w0}', 'counts',
                   float(np.max(np.abs(x[after]))) / dl, 0.0, abs_tol=5.0,
                   ref='recovered: the closed loop of (4.11) decays as exp(-alpha omega0 t), exp(-zeta omega0 t)',
                   run=name)]
    for i, w0 in enumerate(E13_OMEGA):
        d = data[f'w0_{w0}']
        sl = d.window(1.0, 5.0)
        a.figures.append(time_plot(f'fig4_{i + 1}', f'Fig. 4.{i + 1}: tap response with (4.9), omega0 = {w0}, '
                                   'zeta = 0.707, alpha = 0.2', d.t[sl],
                                   [('theta - pi (rad)', [(xdev(d.theta)[sl], '')]), ("theta' (rad/s)", [(d.theta_dot[sl], '')]),
                                    ('w (rad/s)', [(d.wheel_rate[sl], '')]), ('u', [(d.u[sl], '')])]))
        q = d.window(1.0, 2.0)
        a.figures.append(time_plot(f'fig4_{i + 4}', f'Fig. 4.{i + 4}: local behaviour, omega0 = {w0}: one count '
                                   'moves u by (4.12)', d.t[q],
                                   [('theta - pi (counts)', [(xdev(d.theta)[q] / dl, '')]), ("theta' (rad/s)", [(d.theta_dot[q], '')]),
                                    ('u', [(d.u[q], '')])]))
    return a


# ============================================================ Experiment 14: wheel angle (4.13)
E14_SETS = (('set1', ('wp', 0.707, 'wp', 1.0)), ('set2', ('wp', 1.0, '0.5wp', 0.707)))
E14_STEP = (2.0, 2 * math.pi)
E14_D0 = (9.0, 0.3)


def runs_14(rig, options) -> list[Run]:
    out = []
    for name, spec in E14_SETS:
        g = design.pdpdcontrol(rig, *spec)
        out.append(Run(name, f'(4.13) with (4.15) poles {spec}; wheel reference +2 pi at {E14_STEP[0]:g} s, '
                       f'torque {E14_D0[1]:g} from {E14_D0[0]:g} s', 16.0, mode='law', law=PROC + 'BalanceWheelSteps',
                       law_params={'kpp': g.kpp, 'kdp': g.kdp, 'kpr': g.kpr, 'kdr': g.kdr,
                                   'times': [0.0, E14_STEP[0]], 'refs': [0.0, E14_STEP[1]]},
                       sim={'initial.theta': UP, 'initial.wheel_angle': UP, 'torques.times': [E14_D0[0]],
                            'torques.sizes': [E14_D0[1]], 'torques.durations': [100.0]},
                       estimator={'estimator': 'filtered', 'T': 0.01},
                       prompts=(RAISE, Prompt('Hook a rubber band to the pendulum.', 'torque', {},
                                              wait_s=E14_D0[0], at=E14_D0[0])),
                       arm_after=1))
    return out


def analyze_14(rig, data) -> Analysis:
    a = Analysis()
    for name, spec in E14_SETS:
        d = data[name]
        g = design.pdpdcontrol(rig, *spec)
        rel = d.wheel_angle - d.wheel_angle[0]
        ref_err = float(np.mean(rel[d.window(4.0, E14_D0[0])])) - E14_STEP[1]
        off = float(np.mean(rel[d.window(12.0, 16.0)])) - E14_STEP[1]
        if name == 'set1':
            a.quantities.append(within(14, f'wheel angle error after the reference step ({name})', 'rad', ref_err,
                                       0.0, abs_tol=1.0, book='zero', run=name,
                                       ref='(4.16): Theta_r / Theta_rref = 1 at s = 0 (mean over the limit cycle)'))
        a.quantities += [
            within(14, f'wheel angle offset under the torque ({name})', 'rad', off,
                   rig.b_p * g.kpp * E14_D0[1] / (rig.a * g.kpr), rel=0.25, abs_tol=0.5,
                   book='b_p k_pp d0 / (a k_pr), called a drift rate',
                   ref='(4.17): an angle offset, the speed goes to 0 (ERRATA E31)', run=name)]
    a.notes.append('The second set has k_dr from (4.15), not the listing (ERRATA E29: -0.0540, not -0.0763).')
    d = data['set1']
    a.figures.append(time_plot('exp14', 'Experiment 14: wheel-angle control (4.13): reference step, then a torque',
                               d.t, [('theta_r (rad)', [(d.wheel_angle - d.wheel_angle[0], 'set 1'),
                                                        (data['set2'].wheel_angle - data['set2'].wheel_angle[0], 'set 2')]),
                                     ('theta - pi (rad)', [(xdev(d.theta), 'set 1')]), ('u', [(d.u, 'set 1')])]))
    return a


# ============================================================ Experiment 15: disturbance torque
E15_D0 = (2.0, 0.5)


def runs_15(rig, options) -> list[Run]:
    g = design.pddcontrol(rig, '2wp', 0.707, 0.2)
    return [Run('torque', f'(4.9) at omega0 = 2 omega_p; torque {E15_D0[1]:g} units from {E15_D0[0]:g} s', 8.0,
                mode='balance', controller=gain_params(g), estimator={'estimator': 'filtered', 'T': 0.01},
                sim={'initial.theta': UP, 'initial.wheel_angle': UP, 'torques.times': [E15_D0[0]],
                     'torques.sizes': [E15_D0[1]], 'torques.durations': [100.0]},
                prompts=(RAISE, Prompt('Apply a small torque with a rubber band.', 'torque', {},
                                       wait_s=E15_D0[0], at=E15_D0[0])),
                arm_after=1)]


def wheel_speed_under_torque(rig, g, d0: float) -> float:
    """Steady wheel speed with a torque d0: x = -b_p d0/a and -k_pp x - k_dr w = F(w) (3.17)."""
    A0 = g.kpp * rig.b_p * d0 / rig.a
    wp = (A0 - rig.friction_coulomb_pos) / (rig.friction_viscous_pos + g.kdr)
    if wp > 0:
        return wp
    return (A0 + rig.friction_coulomb_neg) / (rig.friction_viscous_neg + g.kdr)


def analyze_15(rig, data) -> Analysis:
    d = data['torque']
    g = design.pddcontrol(rig, '2wp', 0.707, 0.2)
    d0 = E15_D0[1]
    x = xdev(d.theta)
    tail = d.window(6.0, 8.0)
    a = Analysis()
    a.quantities += [
        within(15, 'pendulum offset under the torque (against it)', 'rad', float(np.mean(x[tail])),
               -rig.b_p * d0 / rig.a, rel=0.2, abs_tol=rig.count_angle, book='-b_p d0 / a (Section 4.6)',
               ref='(4.18); ERRATA E31: the sign of 4.5 is wrong', run='torque'),
        within(15, 'wheel speed under the torque', 'rad/s', float(np.mean(d.wheel_rate[tail])),
               wheel_speed_under_torque(rig, g, d0), rel=0.1,
               book=round(rig.b_p * g.kpp * d0 / (rig.a * g.kdr), 1),
               ref='(4.18) with the friction (3.17); the book: b_p k_pp d0/(a k_dr) without friction', run='torque')]
    a.figures.append(time_plot('exp15', 'Experiment 15: a torque on the pendulum from 2 s: the pendulum moves '
                               'against it', d.t, [('theta - pi (rad)', [(x, '')]), ('w (rad/s)', [(d.wheel_rate, '')]),
                                                   ('u', [(d.u, '')])]))
    return a
