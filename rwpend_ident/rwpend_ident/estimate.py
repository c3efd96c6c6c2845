"""The grey-box fits of the identification: the nonlinear model (2.15) with the friction (3.17)
against the recorded encoder counts (scipy least_squares, rwpend_ident.fit), numpy/scipy only.

* :func:`fit_swing` -- Experiment 1: the free swing with the rotor stuck, theta'' = -omega_p'^2
  sin theta - c theta' (Section 2.3), initial state fitted too.
* :func:`fit_dynamics` -- Experiments 3 and 9 jointly: the pulses and steps from rest simulated by
  the plant model (stick-slip, current lag, PWM steps) against both encoders, and the
  friction-curve points u = F(w) of the PI speed holds; parameters b_r, rho = b_p/b_r = J_r/J,
  T_e and the friction (3.17) per direction.  Each record's encoder offsets are eliminated
  (variable projection): the pendulum hangs at 0 physically, the encoder zero may be off by a
  fraction of a count.
* :func:`fit_breakaway` -- the slow torque ramps: the static friction at which the rotor lets go.

Every function takes the parameters it does not fit as arguments; :mod:`rwpend_ident.identify`
chains them.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from rwpend_lab import measure as M

from .fit import FitError, FitResult, fit, linear_fit
from .models import free_swing, plant_response, rig_from_model, swing_state
from .records import IdentError, Record

#: Standard deviation of the quantization error of one encoder reading (counts).
QUANT = 1.0 / math.sqrt(12.0)
DYNAMICS = ('b_r', 'rho', 'motor_time_constant', 'friction_coulomb_pos', 'friction_viscous_pos',
            'friction_coulomb_neg', 'friction_viscous_neg')
FRICTION = DYNAMICS[3:7]


def _fit(residuals, x0, names, **kw) -> FitResult:
    try:
        return fit(residuals, x0, names, **kw)
    except FitError as exc:
        raise IdentError(str(exc)) from None


# ------------------------------------------------------------------ Experiment 1
def swing_start(tp: np.ndarray, halves: int = 4, tol: float = 0.25) -> float | None:
    """The time of the first turning point of the free swing proper: the first one followed by
    ``halves`` half swings each within ``tol`` of the median half period (None without such).
    A hand that held the pendulum still before it let go (on the rig) makes the first 'turning
    point' the middle of the hold, a whole hold before the next one: the swing starts after it."""
    gaps = np.diff(tp)
    if len(gaps) < halves:
        return None
    half = float(np.median(gaps))
    regular = np.abs(gaps - half) <= tol * half
    for i in range(len(gaps) - halves + 1):
        if regular[i:i + halves].all():
            return float(tp[i])
    return None


def fit_swing(rig, d, name: str = 'swing') -> FitResult:
    """omega_p'^2 ('wp2'), damping c ('damping'), theta0, theta_dot0 of the free swing, from its first
    turning point on (:func:`swing_start`: where the hand let go, or later).  IdentError when the
    pendulum hardly swung or the rotor slipped in the swing (then the stuck model does not hold)."""
    dl, h = rig.count_angle, rig.sample_period
    pc = np.asarray(d.pc, float)
    if np.any(np.isnan(pc)) or np.any(np.isnan(d.mc)):
        raise IdentError(f'{name}: encoder samples missing in the recording')
    tp, _ = M.turning_points(pc, np.arange(len(pc)) * h)
    start = swing_start(tp)
    if np.ptp(pc) < 40 or start is None:
        raise IdentError(f'{name}: the pendulum did not swing (range {np.ptp(pc):.0f} counts, {len(tp)} '
                         f'turning points): lift it about 20 degrees and let go')
    k0 = int(round(start / h))
    if np.ptp(d.mc[k0:]) > 3:
        raise IdentError(f'{name}: the rotor turned {np.ptp(d.mc[k0:]):.0f} counts relative to the pendulum '
                         'during the free swing (it should stick, Fig. 2.2): swing from a smaller angle, u = 0')
    t = (np.arange(len(pc) - k0)) * h
    y = pc[k0:]
    w = M.swing_frequency(y, h)
    tp, px = M.turning_points(y, t)
    amp = float(np.mean(px)) * dl if len(px) else 0.3
    wp2_0 = (w * M.amplitude_factor(amp)) ** 2 if w else rig.omega_p_stuck ** 2
    tau = M.exp_time_constant(tp, 1 - np.cos(px * dl)) if len(tp) > 3 else None
    x0 = [wp2_0, 1.0 / tau if tau else 0.01, y[0] * dl, 0.0]

    def residuals(x):
        return (free_swing(t, x[0], x[1], x[2], x[3]) / dl - y) / QUANT
    res = _fit(residuals, x0, ['wp2', 'damping', 'theta0', 'theta_dot0'],
               bounds=([1.0, 0.0, -math.pi, -50.0], [1e4, 10.0, math.pi, 50.0]))
    res.extra['k0'] = k0
    return res


# ------------------------------------------------------------------ Experiments 3, 8-9 and the stiction
def model_rig(base, x: np.ndarray, fixed: dict):
    """The rig (split for simulation) of the dynamics parameters ``x`` (DYNAMICS) with the
    pendulum's wp2, damping and the breakaway in ``fixed``."""
    b_r, rho = float(x[0]), float(x[1])
    values = dict(zip(FRICTION, map(float, x[3:7])))
    values.update(a=fixed['wp2'] * (1 + rho), b_p=rho * b_r, b_r=b_r, motor_time_constant=float(x[2]),
                  friction_breakaway=float(fixed['breakaway']),
                  pendulum_energy_time_constant=1.0 / (fixed['damping'] * (1 + rho)) if fixed['damping'] > 0 else 0.0)
    return rig_from_model(base, values, physical=False)


def with_initial_state(rec: Record, wp2: float, damping: float, count: float, h: float) -> Record:
    """The record with the pendulum's state at its start fitted to its rest window (``rec.pre``):
    the free swing with the rotor stuck (Section 2.3) plus an encoder offset.  'At rest' allows a
    count or two of swing, which the pendulum keeps for a minute (Fig. 2.3); near the breakaway it
    decides the sample on which the rotor lets go, so the model starts from the state, not from 0."""
    n = len(rec.pre)
    if n < 50:
        return rec
    t = np.arange(n + 1) * h

    def residuals(x):
        return (free_swing(t, wp2, damping, x[0], x[1])[:n] + x[2]) / count - rec.pre
    fit0 = _fit(residuals, [0.0, 0.0, float(np.mean(rec.pre)) * count], ['theta', 'theta_dot', 'offset'])
    th, v = swing_state(t, wp2, damping, fit0['theta'], fit0['theta_dot'])
    return dataclasses.replace(rec, theta0=float(th[-1]), theta_dot0=float(v[-1]))


def record_residuals(rig, rec: Record) -> tuple[np.ndarray, np.ndarray]:
    """(pendulum, rotor) residuals of a record from its initial state, in quantization standard
    deviations, each with its mean removed (the encoder offsets)."""
    th, phi = plant_response(rig, rec.u, rec.theta0, rec.theta_dot0)
    dl = rig.count_angle
    rp = th / dl - rec.pc
    rm = phi / dl - rec.mc
    return (rp - rp.mean()) / QUANT, (rm - rm.mean()) / QUANT


def friction_curve(w: np.ndarray, x: np.ndarray) -> np.ndarray:
    """F(w) of (3.17) with x = (c+, v+, c-, v-), units."""
    cp, vp, cn, vn = x
    return np.where(w > 0, cp + vp * w, -cn + vn * w)


def fit_friction_points(w: np.ndarray, u: np.ndarray, s: np.ndarray) -> FitResult:
    """(3.17) from the PI holds alone (Experiment 9): u = c+ + v+ w (w > 0), u = -c- + v- w (w < 0)."""
    pos = (w > 0).astype(float)
    neg = 1.0 - pos
    X = np.column_stack([pos, pos * w, -neg, neg * w])
    try:
        return linear_fit(X, u, s, list(FRICTION))
    except (FitError, np.linalg.LinAlgError) as exc:
        raise IdentError(f'friction: the friction curve cannot be fitted: {exc}') from None


def first_guess(base, pulses: list[Record], curve: FitResult) -> np.ndarray:
    """Start of the joint fit: b_r and b_p/b_r of the lab's Experiment 3 regression (median over
    the pulses), T_e of the base rig, the friction of the PI holds."""
    from rwpend_lab.data import RunData
    br, rho = [], []
    h = base.sample_period
    for rec in pulses:
        k = int(np.nonzero(rec.u)[0][0])
        n = rec.n - k
        z = np.zeros(n)
        d = RunData(h=h, t=np.arange(n) * h, pc=rec.pc[k:] - rec.pc[k], mc=rec.mc[k:] - rec.mc[k], u=rec.u[k:],
                    theta=z, theta_dot=z, wheel_angle=z, wheel_rate=z, friction=z)
        f = M.fit_pulse(base, d, float(rec.u[k]), 0.0, fit_s=n * h)
        if f['b_r'] > 0 and f['b_p'] > 0:
            br.append(f['b_r'])
            rho.append(f['b_p'] / f['b_r'])
    b_r = float(np.median(br)) if br else base.b_r
    r = float(np.median(rho)) if rho else base.b_p / base.b_r
    return np.array([b_r, r, base.motor_time_constant, *curve.x])


def fit_dynamics(base, pulses: list[Record], points: tuple, fixed: dict) -> FitResult:
    """b_r, rho, T_e and the friction (3.17) from the pulse and step records and the friction-curve
    points jointly (the breakaway, which sets when the rotor lets go at the start of a pulse, and
    the pendulum's wp2, damping in ``fixed``)."""
    w, u, s = points
    curve = fit_friction_points(w, u, s)
    x0 = first_guess(base, pulses, curve)
    groups = np.concatenate([[2 * i] * rec.n + [2 * i + 1] * rec.n for i, rec in enumerate(pulses)]
                            + [np.arange(len(w)) + 2 * len(pulses)])

    def residuals(x):
        rig = model_rig(base, x, fixed)
        parts = []
        for rec in pulses:
            parts += list(record_residuals(rig, rec))
        parts.append((u - friction_curve(w, x[3:7])) / s)
        return np.concatenate(parts)
    lo = [1.0, 1e-5, 0.0, 0.0, 0.0, 0.0, 0.0]
    hi = [1e5, 1.0, 0.02, 10.0, 1.0, 10.0, 1.0]
    x0 = np.clip(x0, np.array(lo) + 1e-9, np.array(hi) - 1e-9)
    res = _fit(residuals, x0, list(DYNAMICS), bounds=(lo, hi), groups=groups, tol=1e-7)
    res.extra['curve'] = curve
    return res


# ------------------------------------------------------------------ stiction
def breakaway_guess(base, ramps: list[Record]) -> float:
    """The applied torque one amplifier step below where each ramp's rotor count first moved
    (the rotor lets go some ms before it has turned half a count), mean over the ramps."""
    q = base.u_max / base.pwm_steps if base.pwm_steps else 0.0
    levels = [abs(float(rec.u[int(np.nonzero(rec.mc != rec.mc[0])[0][0])])) - q for rec in ramps]
    return float(np.mean(levels))


def breakaway_profile(rig, rec: Record, grid: np.ndarray) -> np.ndarray:
    """Sum of squared residuals of one ramp for each breakaway of ``grid``."""
    return np.array([float(np.sum(np.concatenate(record_residuals(rig.replace(friction_breakaway=float(f)),
                                                                  rec)) ** 2)) for f in grid])


def fit_breakaway(rig, ramps: list[Record]) -> FitResult:
    """The static friction (friction_breakaway) from the slow torque ramps, by the plant model with
    everything else identified.  The rotor lets go on the first amplifier step (u_max/pwm_steps,
    Section 2.5) of the ramp above the breakaway, so the residuals change in steps: each ramp's
    sum of squares is scanned over a grid of a quarter step, its estimate the middle of the values
    within 10 % of its minimum; the estimate is the mean of the ramps, its 95 % half-width the larger
    of half an amplifier step and the ramps' spread (which also covers a ramp that started with the
    pendulum swinging by a count: near a step that decides the sample the rotor lets go on)."""
    q = rig.u_max / rig.pwm_steps if rig.pwm_steps else 0.01
    f0 = rig.friction_breakaway
    grid = np.arange(f0 - 2 * q, f0 + 2 * q + 1e-9, q / 4)
    per_ramp = []
    for rec in ramps:
        ssr = breakaway_profile(rig, rec, grid)
        best = grid[ssr <= 1.1 * ssr.min() + 1.0]
        per_ramp.append(0.5 * (best.min() + best.max()))
    est = float(np.mean(per_ramp))
    half = max(q / 2, 0.5 * (max(per_ramp) - min(per_ramp)) + q / 8)
    n = sum(2 * rec.n for rec in ramps)
    res = FitResult(['friction_breakaway'], np.array([est]), np.array([[(half / 1.96) ** 2]]), np.array([half]),
                    n, 0.0, 0)
    res.extra['per_ramp'] = per_ramp
    return res
