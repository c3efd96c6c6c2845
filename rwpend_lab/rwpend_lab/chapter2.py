"""Chapter 2, modelling: Experiments 1 (free swing), 2 (static torque), 3 (torque pulse).

Theory from the rig (rwpend_model.rig.Rig: a, b_p, b_r, omega_p' computed from the YAML data);
the book's printed numbers (Section 2.6, computed with g = 9.91, ERRATA E01) beside them.
"""
from __future__ import annotations

import math

import numpy as np

from . import measure as M
from .experiment import Analysis, Prompt, Run, within
from .figures import finish, panels, time_plot

PROC = 'rwpend_lab.procedures:'


# ============================================================================ Experiment 1
def runs_1(rig, options) -> list[Run]:
    th0 = math.radians(20.0)
    return [Run('swing', 'free swing from 20 deg, no control', 20.0, mode='off',
                # the encoders were zeroed hanging at rest; raised by hand, the rotor came along
                sim={'initial.theta': th0, 'initial.wheel_angle': th0},
                prompts=(Prompt('Lift the pendulum to about 20 degrees and hold it still.', 'held_at',
                                {'angle': th0, 'tol': math.radians(8), 'still_s': 0.5}),
                         Prompt('Let go of the pendulum now (do not push it).', 'released', {})))]


def analyze_1(rig, data) -> Analysis:
    d = data['swing']
    dl, h = rig.count_angle, rig.sample_period
    pc, mc = d.pc, d.mc
    _, peaks = M.turning_points(pc, d.t)
    amp = float(np.mean(peaks)) * dl if len(peaks) else 0.0
    w = M.swing_frequency(pc, h)
    omega = None if w is None else w * M.amplitude_factor(amp)
    tp, px = M.turning_points(pc, d.t)
    energy = rig.mgl * (1 - np.cos(px * dl))           # (2.5) at the turning points (theta' = 0)
    tau = M.exp_time_constant(tp, energy)
    tau_theory = rig.pendulum_energy_time_constant * (rig.J + rig.j_r) / rig.J
    a = Analysis()
    a.quantities += [
        within(1, "swing frequency omega_p' (rotor stuck)", 'rad/s', omega, rig.omega_p_stuck, rel=0.003,
               book=8.832, ref="Section 2.3: omega_p' = sqrt(m g l / (J + J_r)); amplitude-corrected",
               run='swing'),
        within(1, 'rotor angle relative to the pendulum (max |motor counts|)', 'counts',
               float(np.nanmax(np.abs(mc))), 0.0, abs_tol=2.0, book='"nearly identical" (Fig. 2.2)',
               ref='Section 2.3: the rotor sticks to the pendulum (friction > holding torque)', run='swing'),
        within(1, 'energy decay time constant', 's', tau, tau_theory, rel=0.1, book='nearly 1 min (Fig. 2.3)',
               ref='Fig. 2.3; pendulum-axis friction of the rig data, tau_E (J + J_r)/J', run='swing'),
    ]
    a.notes.append(f"The model without friction (2.10) predicts a rotor at rest and omega_p = "
                   f"{rig.omega_p:.4f} rad/s; the stuck rotor swings at omega_p' = {rig.omega_p_stuck:.4f}.")
    th = pc * dl
    thr = (pc + mc) * dl
    a.figures.append(time_plot('fig2_2', 'Fig. 2.2: free motion of the pendulum (top) and the wheel '
                               '(bottom), no control', d.t, [('theta (deg)', [(np.degrees(th), '')]),
                                                             ('theta_r (deg)', [(np.degrees(thr), '')])]))
    e_t = 0.5 * (rig.J + rig.j_r) * np.nan_to_num(d.theta_dot) ** 2 + rig.mgl * (1 - np.cos(th))
    fig, (ax,) = panels(1, 2.6)
    ax.plot(d.t, e_t * 1e3, lw=0.6, label='E (from the estimate)')
    ax.plot(tp, energy * 1e3, 'o', ms=2, label='m g l (1 - cos theta_max)')
    if tau:
        ax.plot(tp, energy[0] * np.exp(-(tp - tp[0]) / tau) * 1e3, 'k--', lw=0.8, label=f'exp fit, tau = {tau:.1f} s')
    ax.set_ylabel('E (mJ)')
    ax.set_xlabel('t (s)')
    ax.legend(fontsize=7)
    a.figures.append(finish(fig, 'fig2_3', 'Fig. 2.3: total energy versus time for the data of Fig. 2.2'))
    return a


# ============================================================================ Experiment 2
#: Levels of the control signal for the torque characteristic, and how long each is held (s).
E2_LEVELS = [round(-10.0 + 0.5 * i, 2) for i in range(41)]
E2_HOLD = 0.25


def runs_2(rig, options) -> list[Run]:
    times = [E2_HOLD * i for i in range(len(E2_LEVELS))]
    return [Run('meter', 'u stepped -10..10, wheel held by the torque meter', E2_HOLD * len(E2_LEVELS),
                mode='law', law=PROC + 'OpenLoop', law_params={'times': times, 'values': E2_LEVELS},
                sim={'bracket': True, 'torque_meter': True},
                prompts=(Prompt('Mount the motor on the bracket and connect the torque meter to the '
                                'rotor axis (the lab reads it on the simulator only).', 'bracket', {}),))]


def meter_levels(rig, d, hold: float = E2_HOLD) -> tuple[np.ndarray, np.ndarray]:
    """(u, mean meter torque in Nm) per level: the second half of each level."""
    meter = rig.k_u * (d.truth['torque'] - d.truth['true_friction'])
    us, ts = [], []
    for t0, t1, u in M.levels(d.u, d.t):
        sl = d.window(t0 + 0.5 * (t1 - t0), t1)
        us.append(u)
        ts.append(float(np.mean(meter[sl])))
    return np.array(us), np.array(ts)


def analyze_2(rig, data) -> Analysis:
    d = data['meter']
    u, tq = meter_levels(rig, d)
    pos, neg = u >= 2.0, u <= -2.0
    sp, ip = M.line_fit(u[pos], tq[pos])
    sn, i_n = M.line_fit(u[neg], tq[neg])
    dead = float(np.max(np.abs(u[np.abs(tq) < 0.02 * np.max(np.abs(tq))]))) if len(tq) else None
    ku_data = rig.k_m * rig.i_max / 10
    a = Analysis()
    a.quantities += [
        within(2, 'k_u, slope for u > 0', 'Nm/unit', sp, ku_data, rel=0.015, book=0.00494,
               ref='(2.14): k_u = k I_max / 10 (data sheet); Fig. 2.4', run='meter'),
        within(2, 'k_u, slope for u < 0', 'Nm/unit', sn, ku_data, rel=0.015, book=0.00494,
               ref='(2.14); Fig. 2.4', run='meter'),
        within(2, 'dead zone half-width', 'units', dead, rig.friction_breakaway, abs_tol=0.51,
               book='approximately one unit (Section 2.6)',
               ref='Fig. 2.4: friction; rig friction_breakaway', run='meter'),
        within(2, 'Coulomb friction from the line (u at zero torque)', 'units', -ip / sp,
               rig.friction_breakaway, rel=0.1, book=1.0, ref='Section 2.6: F about 1 unit = 0.005 Nm',
               run='meter'),
    ]
    fig, (ax,) = panels(1, 3.2)
    ax.plot(u, tq * 1e3, 'o', ms=3, label='meter')
    for s, i, m in ((sp, ip, pos), (sn, i_n, neg)):
        ax.plot(u[m], (s * u[m] + i) * 1e3, 'k--', lw=0.8)
    ax.set_xlabel('u (control units)')
    ax.set_ylabel('torque (mNm)')
    a.figures.append(finish(fig, 'fig2_4', 'Fig. 2.4: measured torque as a function of the control signal u; '
                            'maximum torque at u = 10'))
    return a


# ============================================================================ Experiment 3
E3_PULSES = (5.0, -5.0, 10.0)
E3_WIDTH = 0.02
E3_FIT_S = 0.3     # s of the record used for b_p / b_r


def runs_3(rig, options) -> list[Run]:
    return [Run(f'pulse{u0:+g}', f'torque pulse u0 = {u0:+g} for {E3_WIDTH * 1e3:g} ms from rest', 0.6,
                mode='law', law=PROC + 'OpenLoop',
                law_params={'times': [0.0, E3_WIDTH], 'values': [u0, 0.0]},
                prompts=(Prompt('Let the pendulum hang still; the pulse follows.', 'still', {'still_s': 1.0}),),
                arm_after=1)
            for u0 in E3_PULSES]


def restick_time(rig, u0: float, width: float) -> float:
    """Time from the end of the pulse until the rotor sticks again (ERRATA E06 with (3.17)): the
    relative speed grows as w' = (b_r + b_p)(u0 - c - v w) during the pulse and then decays as
    w' = -(b_r + b_p)(c + v w), the pendulum hardly moving."""
    k = rig.b_r + rig.b_p
    c, v = ((rig.friction_coulomb_pos, rig.friction_viscous_pos) if u0 > 0
            else (rig.friction_coulomb_neg, rig.friction_viscous_neg))
    w0 = (abs(u0) - c) / v * (1 - math.exp(-k * v * width))
    return math.log(1 + v * w0 / c) / (k * v)


def analyze_3(rig, data) -> Analysis:
    a = Analysis()
    for u0 in E3_PULSES:
        name = f'pulse{u0:+g}'
        d = data[name]
        f = M.fit_pulse(rig, d, u0, E3_WIDTH, E3_FIT_S)
        c = rig.friction_coulomb_pos if u0 > 0 else rig.friction_coulomb_neg
        a.quantities += [
            within(3, f'b_r ({name})', 'rad/s^2/unit', f['b_r'], rig.b_r, rel=0.02, book=198,
                   ref='(2.15): b_r = k_u / J_r', run=name),
            within(3, f'b_p ({name})', 'rad/s^2/unit', f['b_p'], rig.b_p, rel=0.03, book=1.08,
                   ref='(2.15): b_p = k_u / J; from the summed equation (ERRATA E06)', run=name),
            within(3, f'Coulomb friction ({name})', 'units', f['F_c'], c, abs_tol=0.1, book='about 1',
                   ref='(3.17)', run=name),
            within(3, f'rotor re-sticks after the pulse ({name})', 's', f['restick'],
                   restick_time(rig, u0, E3_WIDTH), rel=0.15, book='"velocities remain constant" (E06)',
                   ref='ERRATA E06 with (3.17)', run=name),
        ]
    d = data[f'pulse{E3_PULSES[0]:+g}']
    dl = rig.count_angle
    a.figures.append(time_plot('exp3', f'Experiment 3: pendulum and rotor angles after a pulse u0 = '
                               f'{E3_PULSES[0]:g} of {E3_WIDTH * 1e3:g} ms', d.t,
                               [('theta (rad)', [(d.pc * dl, '')]), ('theta_r (rad)', [((d.pc + d.mc) * dl, '')]),
                                ('u', [(d.u, '')])]))
    a.notes.append('ERRATA E06: the pendulum moves about one count during the pulse, so b_p is fitted '
                   'from theta + a Int Int sin(theta) = -(b_p/b_r) theta_r over the whole record.')
    return a
