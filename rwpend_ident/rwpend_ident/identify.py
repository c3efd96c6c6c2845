"""From the recorded runs to the identified rig: checks, fits, confidence intervals, validation.

Pure Python + numpy/scipy (no rclpy).  :func:`analyse` takes the data of the runs of
:func:`rwpend_ident.plan.plan` (from bags or the lab's twin) and the base rig (the rig file the
lab starts from: its g, k_u, lengths, rotor mass, motor and encoder data are kept) and returns an
:class:`Identification`: every identified quantity with its 95 % confidence interval, the rig
(physical data, ready for the rig YAML), the validation on the held-out run.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from .estimate import (DYNAMICS, breakaway_guess, first_turn_torques, fit_breakaway, fit_dynamics, fit_swing, model_rig,
                       with_initial_state)
from .fit import FitResult, derived, nrmse_fit
from .models import IDENTIFIED, UNITS, plant_response, rig_from_model
from .plan import Speeds
from .checks import Rest
from .records import (IdentError, Record, check_directions, check_rest_before, commands, first_input, hold_means,
                      ramps, refused, response)

#: name -> (how it is measured, the book's equation or experiment)
SOURCES = {
    'a': ('omega_p\'^2 (1 + b_p/b_r): free swing with the pulses', '(2.15), Section 2.3, Exp. 1'),
    'b_p': ('rho b_r: pulses and steps (the pendulum\'s share of the momentum)', '(2.15), Exp. 3, E06'),
    'b_r': ('pulses and steps with the friction curve', '(2.15), Exp. 3'),
    'omega_p': ('sqrt(a)', '(2.15)'),
    'omega_p_stuck': ('free swing, rotor stuck', 'Section 2.3, Exp. 1'),
    'friction_coulomb_pos': ('PI speed holds with the pulses', '(3.17), Exp. 8-9'),
    'friction_viscous_pos': ('PI speed holds with the pulses', '(3.17), Exp. 8-9'),
    'friction_coulomb_neg': ('PI speed holds with the pulses', '(3.17), Exp. 8-9'),
    'friction_viscous_neg': ('PI speed holds with the pulses', '(3.17), Exp. 8-9'),
    'friction_breakaway': ('slow torque ramps until the rotor breaks away', 'Fig. 2.4, Section 2.6'),
    'motor_time_constant': ('steps of the command', 'Section 2.4 (T_e)'),
    'pendulum_energy_time_constant': ('energy decay of the free swing', 'Fig. 2.3'),
    'm_p': ('from a and b_p with l_p, l_r, m_r of the base rig', '(2.3)'),
    'j_p': ('from b_p with l_p, l_r, m_r of the base rig', '(2.3)'),
    'j_r': ('k_u / b_r', '(2.15)'),
}
REPORTED = IDENTIFIED[:3] + ('omega_p', 'omega_p_stuck') + IDENTIFIED[3:] + ('m_p', 'j_p', 'j_r')


@dataclass
class Identification:
    base: object                      # Rig the lab started from (kept data)
    rig: object                       # the identified rig (physical data)
    values: dict[str, tuple[float, float]]     # name -> (value, 95 % half-width)
    fits: dict[str, FitResult]
    points: tuple                     # friction curve points (w, u, s)
    records: dict = field(default_factory=dict)   # the fitted stretches: 'swing' (counts), pulses, ramps
    validation: dict = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)

    def value(self, name: str) -> float:
        return self.values[name][0]

    def ci(self, name: str) -> float:
        return self.values[name][1]


def check_runs(base, data: dict, names: list[str]) -> None:
    """Every run there, none refused, the pulses from rest, the directions right (IdentError)."""
    missing = [n for n in names if n not in data]
    if missing:
        raise IdentError(f'no data for the run(s) {", ".join(missing)} (have: {", ".join(sorted(data)) or "none"})')
    for n in names:
        refused(n, data[n])
    pulses = [n for n in names if n.startswith(('pulse', 'step'))]
    for i, n in enumerate(pulses):
        k = first_input(n, data[n])
        check_rest_before(n, base, data[n], k)
        if i == 0:
            check_directions(n, base, data[n], k, float(commands(n, data[n])[k]))


def _combine(base, swing: FitResult, dyn: FitResult, brk: FitResult) -> tuple[np.ndarray, np.ndarray, Callable]:
    """The stacked estimates, their block-diagonal covariance (independent experiments) and the
    map from that vector to the identified values."""
    x = np.r_[swing['wp2'], swing['damping'], dyn.x, brk.x]
    cov = np.zeros((len(x), len(x)))
    cov[:2, :2] = swing.cov[:2, :2]
    cov[2:-1, 2:-1] = dyn.cov
    cov[-1, -1] = brk.cov[0, 0]

    def values(p: np.ndarray) -> dict[str, float]:
        wp2, damping, b_r, rho = p[0], p[1], p[2], p[3]
        out = {'a': wp2 * (1 + rho), 'b_p': rho * b_r, 'b_r': b_r, 'omega_p': math.sqrt(wp2 * (1 + rho)),
               'omega_p_stuck': math.sqrt(wp2), 'motor_time_constant': p[4],
               'pendulum_energy_time_constant': 1.0 / (damping * (1 + rho)) if damping > 0 else 0.0,
               'friction_breakaway': p[-1]}
        out.update(zip(DYNAMICS[3:], p[5:-1]))
        return out
    return x, cov, values


def _physical(base, model: dict):
    return rig_from_model(base, {k: v for k, v in model.items() if k in IDENTIFIED})


def analyse(base, data: dict, speeds: Speeds, names: list[str], log=lambda s: None) -> Identification:
    """The identification from the runs' data (IdentError with the reason if it cannot be made)."""
    check_runs(base, data, names)
    log('  fitting the free swing (Experiment 1) ...')
    swing = fit_swing(base, data['swing'])
    records = [response(n, base, data[n], first_input(n, data[n])) for n in names if n.startswith(('pulse', 'step'))]
    points = hold_means('friction', base, data['friction'], speeds.schedule()[2])
    stiction = ramps('stiction', base, data['stiction'], log=log)
    start = [swing['wp2'], swing['damping'], base.count_angle, base.sample_period]
    records = [with_initial_state(r, *start) for r in records]
    stiction = [with_initial_state(r, *start) for r in stiction]
    fixed = {'wp2': swing['wp2'], 'damping': swing['damping'], 'breakaway': breakaway_guess(base, stiction)}
    log(f'  fitting {len(records)} pulses and steps with {len(points[0])} friction-curve points jointly '
        '(Exp. 3, 8-9) ...')
    dyn = fit_dynamics(base, records, points, fixed)
    log('  fitting the stiction (torque ramps): the rotor first turned at |u| = '
        + ', '.join(f'{u:.3f}' for u in first_turn_torques(stiction)) + ' ...')
    brk = fit_breakaway(model_rig(base, dyn.x, fixed), stiction)
    if abs(brk.x[0] - fixed['breakaway']) > brk.half[0]:   # the pulses let go later or sooner: again
        fixed['breakaway'] = float(brk.x[0])
        dyn = fit_dynamics(base, records, points, fixed)
    x, cov, values = _combine(base, swing, dyn, brk)
    dof = min(swing.n, dyn.n) - len(x)
    est = {k: derived(lambda p, k=k: values(p)[k], x, cov, dof) for k in values(x)}
    for k in ('m_p', 'j_p', 'j_r'):
        try:
            est[k] = derived(lambda p, k=k: getattr(_physical(base, values(p)), k), x, cov, dof)
        except ValueError as exc:
            raise IdentError(str(exc)) from None
    rig = _physical(base, values(x))
    ident = Identification(base, rig, est, {'swing': swing, 'dynamics': dyn, 'stiction': brk}, points,
                           {'swing': data['swing'].pc[swing.extra['k0']:], 'pulses': records, 'ramps': stiction})
    if 'validation' in names:
        ident.validation = validate(rig, data['validation'], swing['wp2'], swing['damping'])
    return ident


def validate(rig, d, wp2: float, damping: float, name: str = 'validation') -> dict:
    """The identified model simulated against the held-out run (from the pendulum's state when the
    input starts, fitted to its rest window, with the recorded commands): the fit in %
    (100 (1 - |y - y_hat| / |y - mean y|)) of the pendulum angle and of the rotor angle relative to
    the pendulum, and the residuals (counts)."""
    refused(name, d)
    u = commands(name, d)
    k = first_input(name, d)
    check_rest_before(name, rig, d, k)
    h, dl = rig.sample_period, rig.count_angle
    s0 = max(0, k - int(round(0.02 / h)))
    pre = d.pc[max(0, k - int(round(Rest().still_s / h))):s0].copy()
    rec = with_initial_state(Record(name, s0, u[s0:], d.pc[s0:], d.mc[s0:], pre), wp2, damping, dl, h)
    th, phi = plant_response(rig, rec.u, rec.theta0, rec.theta_dot0)
    yp, ym = rec.pc - rec.pc[0], rec.mc - rec.mc[0]
    mp, mm = th / dl - th[0] / dl, phi / dl - phi[0] / dl
    mp += np.mean(yp - mp)     # the encoder offsets (rest position), nothing else from the data
    mm += np.mean(ym - mm)
    return {'fit_pendulum_pct': nrmse_fit(yp, mp), 'fit_rotor_pct': nrmse_fit(ym, mm),
            'rms_pendulum_counts': float(np.sqrt(np.mean((yp - mp) ** 2))),
            'rms_rotor_counts': float(np.sqrt(np.mean((ym - mm) ** 2))),
            't': d.t[s0:] - d.t[s0], 'pendulum': yp, 'pendulum_model': mp, 'rotor': ym, 'rotor_model': mm}


def table(ident: Identification, truth=None) -> list[dict]:
    """One row per reported quantity: value, CI, base (book) value, truth (if known)."""
    rows = []
    for k in REPORTED:
        v, ci = ident.values[k]
        row = {'name': k, 'unit': UNITS.get(k, ''), 'value': v, 'ci95': ci, 'base': float(getattr(ident.base, k)),
               'how': SOURCES[k][0], 'ref': SOURCES[k][1]}
        if truth is not None:
            t = float(getattr(truth, k))
            row.update(truth=t, error_pct=100 * (v - t) / t if t else None, within_ci=abs(v - t) <= ci)
        rows.append(row)
    return rows
