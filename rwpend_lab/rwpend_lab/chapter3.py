"""Chapter 3, the wheel on the fixed bracket (Fig. 3.1): Experiments 4-11.

Velocity estimates of the recorded encoder data are computed offline with the project's own
estimators (rwpend_estimation.estimators), as the book asks ("using the data of Experiment 4").
"""
from __future__ import annotations

import math

import numpy as np

from rwpend_control import design
from rwpend_estimation.estimators import EstimatorConfig, make_estimator

from . import measure as M
from . import theory as TH
from .experiment import Analysis, Prompt, Run, within
from .figures import finish, panels, time_plot

PROC = 'rwpend_lab.procedures:'
BRACKET = {'bracket': True}
MOUNT = Prompt('Mount the motor and the wheel on the fixed bracket (Fig. 3.1).', 'bracket', {})

# ============================================================ Experiments 4-6: open-loop speeds
E4_U = (2.0, 3.6, 5.0)       # control levels: ~87, ~225 (Section 3.4) and ~346 rad/s
E4_HOLD = 4.0      # s: the wheel settles with 1/(b_r f_v) = 0.43 s
E4_T = (0.0025, 0.005, 0.01)


def runs_speeds(rig, options) -> list[Run]:
    times = [E4_HOLD * i for i in range(len(E4_U))]
    return [Run('speeds', f'open loop u = {", ".join(f"{u:g}" for u in E4_U)}, {E4_HOLD:g} s each',
                E4_HOLD * len(E4_U), mode='law', law=PROC + 'OpenLoop',
                law_params={'times': times, 'values': list(E4_U)}, sim=BRACKET, prompts=(MOUNT,))]


def offline(rig, d, name: str, **cfg) -> np.ndarray:
    """Wheel speed of the recorded counts and commands by one of the project's estimators."""
    est = make_estimator(name, rig, EstimatorConfig(**cfg))
    out = np.zeros(d.n)
    u_prev = 0.0
    for k in range(d.n):
        out[k] = est.step(int(d.pc[k]), int(d.mc[k]), u_prev).wheel_rate
        u_prev = float(np.clip(d.u[k], -rig.u_max, rig.u_max))
    return out


def steady(d, i: int):
    """The last second of level i of the speed staircase."""
    return d.window(E4_HOLD * (i + 1) - 1.0, E4_HOLD * (i + 1))


def analyze_4(rig, data) -> Analysis:
    d = data['speeds']
    h, dl = rig.sample_period, rig.count_angle
    diff = offline(rig, d, 'difference')
    a = Analysis()
    res = M.smallest_nonzero_step(diff)
    a.quantities.append(within(4, 'velocity resolution of the difference (3.2)', 'rad/s', res, dl / h,
                               rel=1e-6, book=1.57, ref='Section 3.2: Delta/h', run='speeds'))
    for i, u in enumerate(E4_U):
        sl = steady(d, i)
        w = TH.wheel_steady_speed(rig, u)
        a.quantities.append(within(4, f'steady speed at u = {u:g}', 'rad/s', float(np.mean(diff[sl])), w,
                                   rel=0.01, book='(3.17)', ref='u = F(w), (3.12) with (3.17)', run='speeds'))
        a.quantities.append(within(4, f'ripple of the difference at u = {u:g} (peak-to-peak)', 'rad/s',
                                   float(np.ptp(diff[sl])), dl / h, rel=0.01, book=1.57,
                                   ref='Section 3.2: one count per sample', run='speeds'))
    i = 1
    sl = steady(d, i)
    filt = {}
    for T in E4_T:
        filt[T] = offline(rig, d, 'filtered', T=T)
        a.quantities.append(within(
            4, f'largest step of the filter T = {T * 1e3:g} ms at u = {E4_U[i]:g}', 'rad/s',
            M.largest_step(filt[T][sl]), dl / (T + h), rel=0.15, book=f'{dl / (T + h):.3g} (3.3)',
            ref='(3.3): Delta/(T+h), an upper bound reached when the rate lags a full count',
            run='speeds'))
    zoom = d.window(E4_HOLD * 2 - 0.1, E4_HOLD * 2)
    t = d.t[zoom]
    a.figures.append(time_plot('fig3_3', 'Fig. 3.3: average velocity (3.2) versus velocity from the '
                               'first-order filter (3.3), wheel at constant speed', t,
                               [('w (rad/s)', [(diff[zoom], 'difference (3.2)')]
                                 + [(filt[T][zoom], f'filter T = {T * 1e3:g} ms') for T in E4_T])]))
    a.figures.append(time_plot('exp4_speeds', 'Experiment 4: the open-loop staircase', d.t,
                               [('w (rad/s)', [(filt[E4_T[-1]], 'filtered, T = 10 ms')]), ('u', [(d.u, '')])]))
    return a


def analyze_5(rig, data) -> Analysis:
    d = data['speeds']
    h, dl = rig.sample_period, rig.count_angle
    w0, zeta = 100.0, 0.707          # the observer of Section 3.4 (ERRATA E10)
    k1, k2 = 2 * zeta * w0, w0 ** 2
    obs = offline(rig, d, 'observer2', omega0=w0, zeta=zeta, friction_source='none')
    filt = offline(rig, d, 'filtered', T=0.009)
    a = Analysis()
    for i, u in enumerate(E4_U):
        sl = steady(d, i)
        w = TH.wheel_steady_speed(rig, u)
        a.quantities.append(within(5, f'observer bias x2_hat - w at u = {u:g} (w = {w:.0f} rad/s)', 'rad/s',
                                   float(np.mean(obs[sl]) - np.mean(filt[sl])), rig.b_r * k1 / k2 * rig.friction(w),
                                   rel=0.05, book=10.36 if i == 1 else None,
                                   ref='Section 3.4: b_r k1 F / k2 (ERRATA E10, E11: the observer over-estimates)',
                                   run='speeds'))
    sl = steady(d, 1)
    a.quantities.append(within(5, 'largest step of the observer / of the filter T = 9 ms', '-',
                               M.largest_step(obs[sl]) / M.largest_step(filt[sl]), k2 * h * (0.009 + h),
                               rel=0.6, book='k2 < 1e5 gives less ripple', ref='(3.7) vs (3.3): k2 h (T + h)',
                               run='speeds'))
    zoom = d.window(E4_HOLD * 2 - 0.15, E4_HOLD * 2)
    a.figures.append(time_plot('fig3_4', 'Fig. 3.4: first-order filter (top) and the second-order observer '
                               'that neglects friction (bottom), constant speed', d.t[zoom],
                               [('filter (rad/s)', [(filt[zoom], 'T = 9 ms')]),
                                ('observer (rad/s)', [(obs[zoom], 'omega0 = 100, F = 0')])]))
    return a


def analyze_6(rig, data) -> Analysis:
    d = data['speeds']
    filt = offline(rig, d, 'filtered', T=0.009)
    est = make_estimator('observer3', rig, EstimatorConfig(omega0=100.0, zeta=0.707, alpha=1.0))
    w3, f3 = np.zeros(d.n), np.zeros(d.n)
    u_prev = 0.0
    for k in range(d.n):
        e = est.step(int(d.pc[k]), int(d.mc[k]), u_prev)
        w3[k], f3[k] = e.wheel_rate, e.friction
        u_prev = float(np.clip(d.u[k], -rig.u_max, rig.u_max))
    a = Analysis()
    for i, u in enumerate(E4_U):
        sl = steady(d, i)
        w = TH.wheel_steady_speed(rig, u)
        a.quantities += [
            within(6, f'third-order observer bias at u = {u:g}', 'rad/s', float(np.mean(w3[sl]) - np.mean(filt[sl])),
                   0.0, abs_tol=0.3, book='removed (Fig. 3.5)', ref='(3.8)-(3.11)', run='speeds'),
            within(6, f'friction estimate -x3_hat/b_r at u = {u:g}', 'units', float(np.mean(f3[sl])),
                   rig.friction(w), rel=0.03, book='(3.17)', ref='(3.8): x3 = -b_r F (ERRATA E12)', run='speeds')]
    sl = steady(d, 1)
    a.quantities.append(within(6, 'std of the 3rd-order observer / std of the filter T = 9 ms', '-',
                               float(np.std(w3[sl]) / np.std(filt[sl])), 0.5, abs_tol=0.5,
                               book='"much smoother"', ref='Fig. 3.5: below 1', run='speeds'))
    zoom = d.window(E4_HOLD * 2 - 0.15, E4_HOLD * 2)
    a.figures.append(time_plot('fig3_5', 'Fig. 3.5: the third-order observer (3.11) beside the filter', d.t[zoom],
                               [('w (rad/s)', [(filt[zoom], 'filter T = 9 ms'), (w3[zoom], 'observer3')]),
                                ('F_hat (units)', [(f3[zoom], '')])]))
    return a


# ============================================================ Experiment 7: P speed control
E7_CASES = ((0.1, 100.0), (0.1, 50.0), (0.5, 100.0), (2.5, 100.0))


def runs_7(rig, options) -> list[Run]:
    return [Run(f'kdr{k:g}_w{w:g}', f'P control (3.13), k_dr = {k:g}, step to {w:g} rad/s', 0.6,
                mode='wheel_velocity', sim=BRACKET, estimator={'estimator': 'difference'},
                controller={'wheel.kp': design.wheel_p(rig, k).kdr, 'wheel.ki': 0.0, 'wheel.ref': w},
                law='', student=True, law_params={'kdr': k, 'ref': w}, prompts=(MOUNT,))
            for k, w in E7_CASES]


def analyze_7(rig, data) -> Analysis:
    a = Analysis()
    h, dl = rig.sample_period, rig.count_angle
    v, c = rig.friction_viscous_pos, rig.friction_coulomb_pos
    curves = []
    for k, w in E7_CASES:
        name = f'kdr{k:g}_w{w:g}'
        d = data[name]
        ws = M.cumtrapz(np.zeros(1), h)  # noqa: F841 - keep numpy warm
        wr = d.wheel_rate
        tail = d.window(0.4, 0.6)
        e_ss = w - float(np.mean(wr[tail]))
        a.quantities.append(within(7, f'steady error, k_dr = {k:g}, w_r = {w:g}', 'rad/s', e_ss,
                                   (c + v * w) / (k + v), rel=0.05, book=round(1.0 / k, 3),
                                   ref='Section 3.5: e = F/k_dr with F = c + v w (3.17; ERRATA E16)', run=name))
        if k * w <= rig.u_max:     # the linear step response (u does not saturate)
            final = float(np.mean(wr[tail]))
            k63 = np.nonzero(wr >= 0.632 * final)[0]
            a.quantities.append(within(7, f'time constant, k_dr = {k:g}, w_r = {w:g}', 's',
                                       float(d.t[k63[0]]) if k63.size else None, 1 / ((k + v) * rig.b_r),
                                       rel=0.15, book=round(1 / (k * 198), 4),
                                       ref='T = 1/((k_dr + f_v) b_r) (ERRATA E16; book 1/(k_dr b_r))', run=name))
        curves.append((wr, f'k_dr = {k:g}, w_r = {w:g}'))
    a.notes.append('Gain limit (Section 3.5): the book lumps T_e = 0.5 ms + h/2 and gets k_dr < 2.5 for '
                   'zeta > 0.707; with the motor lag and the ZOH the sampled loop has zeta = 0.45 at k_dr = 2.5 '
                   '(ERRATA E14), the controller refuses k_dr > 1/(b_r T_e).')
    a.figures.append(time_plot('exp7_steps', 'Experiment 7: step responses of the P speed loop (3.13)',
                               data[f'kdr{E7_CASES[0][0]:g}_w{E7_CASES[0][1]:g}'].t,
                               [('w (rad/s)', curves)]))
    return a


# ============================================================ Experiment 8: PI speed control
E8_OMEGA0 = (20.0, 40.0)
E8_REFS = ((0.0, 100.0), (1.0, 120.0))   # a step that does not saturate u


def runs_8(rig, options) -> list[Run]:
    out = []
    for w0 in E8_OMEGA0:
        g = design.pi_control(rig, w0, 1.0)
        out.append(Run(f'w0_{w0:g}', f'PI (3.14)-(3.16), omega0 = {w0:g}, zeta = 1: 100 then 120 rad/s', 2.0,
                       mode='law', law=PROC + 'WheelSpeedSteps', student=True, sim=BRACKET,
                       estimator={'estimator': 'filtered', 'T': 0.005},
                       law_params={'kdr': g.kdr, 'ki': g.ki, 'times': [t for t, _ in E8_REFS],
                                   'refs': [r for _, r in E8_REFS]}, prompts=(MOUNT,)))
    return out


def analyze_8(rig, data) -> Analysis:
    a = Analysis()
    curves = []
    for w0 in E8_OMEGA0:
        name = f'w0_{w0:g}'
        d = data[name]
        g = design.pi_control(rig, w0, 1.0)
        t_step, r1 = E8_REFS[1]
        r0 = E8_REFS[0][1]
        sl = d.window(t_step, d.t[-1] + 1)
        y = d.wheel_rate[sl]
        tt, yt = TH.wheel_loop_step(rig, 0.0, g.kdr, g.ki, 1.0, 1.0, 'filtered', 0.005)
        a.quantities += [
            within(8, f'overshoot of the 100 -> 120 rad/s step, omega0 = {w0:g}', '%',
                   100 * (float(np.max(y)) - r1) / (r1 - r0), 100 * TH.overshoot(yt, 1.0), abs_tol=4.0,
                   book='14 % for zeta = 1 (E15)', ref='(3.14)-(3.16); PI with its zero, sampled loop', run=name),
            within(8, f'steady error after the step, omega0 = {w0:g}', 'rad/s',
                   r1 - float(np.mean(d.wheel_rate[d.window(d.t[-1] - 0.4, d.t[-1] + 1)])), 0.0, abs_tol=0.5,
                   book='zero (integral action)', ref='Section 3.6', run=name)]
        curves.append((d.wheel_rate, f'omega0 = {w0:g}'))
    a.figures.append(time_plot('exp8_pi', 'Experiment 8: PI speed control, zeta = 1', data[f'w0_{E8_OMEGA0[0]:g}'].t,
                               [('w (rad/s)', curves)]))
    return a


# ============================================================ Experiment 9: friction curve
E9_REFS = (50.0, 100.0, 200.0, 300.0, 400.0, -50.0, -100.0, -200.0, -300.0, -400.0)
E9_HOLD = 1.5


def runs_9(rig, options) -> list[Run]:
    g = design.pi_control(rig, 20.0, 1.0)
    return [Run('curve', 'PI speed control at +-50..400 rad/s, 1.5 s each', E9_HOLD * len(E9_REFS), mode='law',
                law=PROC + 'WheelSpeedSteps', sim=BRACKET, estimator={'estimator': 'filtered', 'T': 0.005},
                law_params={'kdr': g.kdr, 'ki': g.ki, 'times': [E9_HOLD * i for i in range(len(E9_REFS))],
                            'refs': list(E9_REFS)}, prompts=(MOUNT,))]


def friction_points(d) -> tuple[np.ndarray, np.ndarray]:
    ws, us = [], []
    for i in range(len(E9_REFS)):
        sl = d.window(E9_HOLD * (i + 1) - 0.7, E9_HOLD * (i + 1))
        ws.append(float(np.mean(d.wheel_rate[sl])))
        us.append(float(np.mean(d.u[sl])))
    return np.array(ws), np.array(us)


def analyze_9(rig, data) -> Analysis:
    w, u = friction_points(data['curve'])
    pos, neg = w > 0, w < 0
    vp, cp = M.line_fit(w[pos], u[pos])
    vn, cn = M.line_fit(w[neg], u[neg])
    a = Analysis()
    a.quantities += [
        within(9, 'Coulomb friction, w > 0', 'units', cp, rig.friction_coulomb_pos, abs_tol=0.05, book=0.99,
               ref='(3.17), Fig. 3.6', run='curve'),
        within(9, 'viscous friction, w > 0', 'units/(rad/s)', vp, rig.friction_viscous_pos, rel=0.05, book=0.0116,
               ref='(3.17)', run='curve'),
        within(9, 'Coulomb friction, w < 0', 'units', -cn, rig.friction_coulomb_neg, abs_tol=0.05, book=0.97,
               ref='(3.17)', run='curve'),
        within(9, 'viscous friction, w < 0', 'units/(rad/s)', vn, rig.friction_viscous_neg, rel=0.05, book=0.0117,
               ref='(3.17)', run='curve')]
    fig, (ax,) = panels(1, 3.2)
    ax.plot(w, u, 'o', ms=4, label='mean control')
    x = np.linspace(0, 450, 10)
    ax.plot(x, cp + vp * x, 'k--', lw=0.8)
    ax.plot(-x, cn - vn * x, 'k--', lw=0.8)
    ax.set_xlabel('w (rad/s)')
    ax.set_ylabel('u (units)')
    a.figures.append(finish(fig, 'fig3_6', 'Fig. 3.6: control signal u as a function of the wheel speed '
                            '(the friction curve), lines fitted'))
    return a


# ============================================================ Experiment 10: friction compensation
E10_SPIN = 200.0


def runs_10(rig, options) -> list[Run]:
    spun = {**BRACKET, 'initial.wheel_rate': E10_SPIN}
    prompt = Prompt('Spin the wheel by hand to about 200 rad/s and let go.', 'spun', {'speed': E10_SPIN})
    base = {'wheel.kp': 0.0, 'wheel.ki': 0.0, 'wheel.ref': 0.0}
    est = {'estimator': 'filtered', 'T': 0.005}
    return [Run('off', 'wheel spun by hand, no compensation', 2.0, mode='off', sim=spun, estimator=est,
                prompts=(MOUNT, prompt)),
            Run('on', 'wheel spun by hand, friction compensation (3.17) on', 2.0, mode='wheel_velocity', sim=spun,
                estimator=est, controller={**base, 'friction_compensation': 'model'}, student=True,
                law_params={}, prompts=(MOUNT, prompt))]


def analyze_10(rig, data) -> Analysis:
    c, v = rig.friction_coulomb_pos, rig.friction_viscous_pos
    off, on = data['off'], data['on']
    w_off = off.wheel_rate
    stop = np.nonzero((w_off < 1.0) & (off.t > 0.02))[0]    # the estimate starts at 0
    t_stop = math.log(1 + v * E10_SPIN / c) / (rig.b_r * v)
    a = Analysis()
    a.quantities += [
        within(10, 'coast-down time without compensation', 's', float(off.t[stop[0]]) if stop.size else None,
               t_stop, rel=0.05, ref='w\' = -b_r (c + v w) (3.12, 3.17)', run='off'),
        within(10, 'speed kept after 2 s with compensation', '%',
               100 * float(np.mean(on.wheel_rate[on.window(1.8, 2.0)])) / E10_SPIN, 100.0, abs_tol=10.0,
               book='"observe the differences"', ref='Section 3.8: u = F(w) cancels the friction', run='on')]
    a.figures.append(time_plot('exp10', 'Experiment 10: the hand-spun wheel with and without friction '
                               'compensation', off.t, [('w (rad/s)', [(w_off, 'off'), (on.wheel_rate, 'compensated')]),
                                                       ('u', [(on.u, 'compensated')])]))
    return a


# ============================================================ Experiment 11: wheel angle PD
E11_OMEGA0 = (20.0, 50.0, 120.0)


def _e11_ref(rig, w0: float) -> float:
    return 5.0 / design.wheel_pd(rig, w0, 0.707).kpr       # a step that asks for u = 5 at first


def runs_11(rig, options) -> list[Run]:
    out = []
    for w0 in E11_OMEGA0:
        g = design.wheel_pd(rig, w0, 0.707)
        out.append(Run(f'w0_{w0:g}', f'wheel-angle PD (3.18), omega0 = {w0:g}, zeta = 0.707', 1.0,
                       mode='wheel_angle', sim=BRACKET, estimator={'estimator': 'difference'},
                       controller={'wheel_angle.kpr': g.kpr, 'wheel_angle.kdr': g.kdr,
                                   'wheel_angle.ref': _e11_ref(rig, w0)}, student=True,
                       law_params={'kpr': g.kpr, 'kdr': g.kdr, 'ref': _e11_ref(rig, w0)}, prompts=(MOUNT,)))
    return out


def analyze_11(rig, data) -> Analysis:
    a = Analysis()
    h, dl = rig.sample_period, rig.count_angle
    curves = []
    for w0 in E11_OMEGA0:
        name = f'w0_{w0:g}'
        d = data[name]
        g = design.wheel_pd(rig, w0, 0.707)
        ref = _e11_ref(rig, w0)
        tt, yt = TH.wheel_loop_step(rig, g.kpr, g.kdr, 0.0, ref, 1.0)
        y = d.wheel_angle
        a.quantities.append(within(11, f'overshoot, omega0 = {w0:g}', '%', 100 * TH.overshoot(y, ref),
                                   100 * TH.overshoot(yt, ref), abs_tol=8.0, book='4.3 % (zeta = 0.707)',
                                   ref='(3.19); sampled loop with lag and the difference estimate', run=name))
        a.quantities.append(within(11, f'steady error within the friction band, omega0 = {w0:g}', 'rad',
                                   abs(ref - float(np.mean(y[d.window(0.8, 1.0)]))), 0.0,
                                   abs_tol=rig.friction_breakaway / g.kpr + dl,
                                   ref='(3.19): |e| <= F / k_pr', run=name))
        curves.append((y / ref, f'omega0 = {w0:g}'))
    a.notes.append('How large can omega0 be: the controller refuses k_dr > 1/(b_r T_e) (Section 3.5); with '
                   'the difference estimate every count adds k_dr Delta/h to u (sensor noise).')
    a.figures.append(time_plot('exp11', 'Experiment 11: wheel-angle steps (normalised) for three omega0',
                               data[f'w0_{E11_OMEGA0[0]:g}'].t, [('theta_r / ref', curves)]))
    return a
