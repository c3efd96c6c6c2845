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
from .records import IdentError, Record, amplifier_step

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
#: A hand holding the pendulum before it lets go (Experiment 1 on the rig): still within
#: ``HOLD_COUNTS`` counts (the lab's ``held_at`` detector) for at least ``HOLD_S`` s, at least
#: ``LIFTED`` rad from hanging.  A free swing never stays that long on 2 counts so far out: at a
#: turning point of amplitude A counts it stays within 2 counts for 2 acos(1 - 2/A) / omega_p', 72 ms
#: at the 5 degrees (56 counts) of the threshold on the shipped rig, 42 ms at 20 degrees.
HOLD_S = 0.25
HOLD_COUNTS = 2
LIFTED = math.radians(5.0)
#: The free swing (2.15) with the rotor stuck fits a recording of it to the encoder quantization:
#: rms 0.99-1.00 in its units (QUANT, 0.29 counts) on the simulator and through the emulator.  A
#: model error of a real rig (a bearing's Coulomb friction: the amplitude decays linearly, not
#: exponentially) leaves of the order of a count.  A recording that is not one free swing (swinging
#: before the hand lifted it, held or pushed during the fit) leaves tens of counts: the open defect
#: of the emulated rig fitted a = 69.9 against 78.17 with 136 counts rms.  Refused above the larger
#: of ``SWING_RMS_COUNTS`` and ``SWING_RMS_SHARE`` of the swing's amplitude.
SWING_RMS_COUNTS = 3.0
SWING_RMS_SHARE = 0.02
#: Bounds of the swing fit: wp2 (1/s^2), damping c (1/s), theta0 (rad), theta_dot0 (rad/s).
SWING_BOUNDS = ([1.0, 0.0, -math.pi, -50.0], [1e4, 10.0, math.pi, 50.0])


def release_index(pc: np.ndarray, h: float, count_angle: float, hold_s: float = HOLD_S,
                  counts: int = HOLD_COUNTS, lifted: float = LIFTED) -> int:
    """The last sample of the last hold of the pendulum by a hand (still within ``counts`` counts
    for ``hold_s`` s, at least ``lifted`` rad from hanging): where the free swing of Experiment 1
    starts; 0 when nothing held it (the simulator starts the swing from the initial state).

    The pendulum may still swing from an earlier run when the student lifts it: what comes before
    the hold is not the free swing (the open defect of the emulated rig: a fit from a turning point
    of that earlier swing, through the lift and the hold, gave a = 62-70 against 78.17)."""
    pc = np.asarray(pc, float)
    n = max(2, int(round(hold_s / h)))
    if len(pc) < n:
        return 0
    win = np.lib.stride_tricks.sliding_window_view(pc, n)
    held = (win.max(axis=1) - win.min(axis=1) <= counts) & (np.abs(win).min(axis=1) * count_angle >= lifted)
    ends = np.nonzero(held)[0]
    return int(ends[-1]) + n - 1 if ends.size else 0


def swing_start(tp: np.ndarray, halves: int = 4, tol: float = 0.25) -> float | None:
    """The time of the first turning point of the free swing proper: the first one followed by
    ``halves`` half swings each within ``tol`` of the median half period (None without such).
    Used on the samples after the release (:func:`release_index`): the first half swing a tap or a
    push leaves irregular (the rotor slips) is skipped."""
    gaps = np.diff(tp)
    if len(gaps) < halves:
        return None
    half = float(np.median(gaps))
    regular = np.abs(gaps - half) <= tol * half
    for i in range(len(gaps) - halves + 1):
        if regular[i:i + halves].all():
            return float(tp[i])
    return None


def swing_problem(res: FitResult, amplitude: float, bounds=SWING_BOUNDS) -> str | None:
    """Why the fit of the free swing does not measure omega_p'^2 and the damping c (None: it does).

    * its rms residual is far above the encoder quantization (``SWING_RMS_COUNTS``,
      ``SWING_RMS_SHARE`` of the ``amplitude`` in counts): the recording is not one free swing;
    * an estimate ended on a bound of the fit: the least squares did not find the swing;
    * c is not resolved from 0 (its 95 % interval reaches 0) or not to within half of it: the
      energy time constant 1/(c (1 + b_p/b_r)) (Fig. 2.3) is not measured by this recording."""
    rms = res.rms * QUANT
    limit = max(SWING_RMS_COUNTS, SWING_RMS_SHARE * abs(amplitude))
    if not math.isfinite(rms) or rms > limit:
        return (f'the free swing (2.15) with the rotor stuck does not fit the recording: rms residual '
                f'{rms:.1f} counts against {QUANT:.2f} counts of the encoder quantization (limit {limit:.1f} '
                f'counts; omega_p\'^2 came out {res["wp2"]:.4g} 1/s^2): it was not one free swing -- hold the '
                'pendulum still at 20 degrees, then let go without pushing it, and do not touch it until the '
                'run ends')
    (wp2_lo, *_), (wp2_hi, c_hi, *_) = bounds
    c, ci = res['damping'], res.ci('damping')
    if not wp2_lo < res['wp2'] < wp2_hi or c >= c_hi:     # c on its lower bound 0: not resolved, below
        name, value = ('damping', c) if c >= c_hi else ('wp2', res['wp2'])
        return f'the fit of the free swing ended on its bound {name} = {value:.4g}: not measured'
    if not (c > 0 and math.isfinite(ci) and ci < 0.5 * c):
        return (f'the decay of the free swing is not measured: damping c = {c:.3g} +- {ci:.2g} 1/s (95 %), '
                'so the pendulum\'s energy time constant (Fig. 2.3) is unknown -- record a longer swing '
                f'(the energy time constant 1/c is {1 / c if c > 0 else math.inf:.3g} s)')
    return None


def fit_swing(rig, d, name: str = 'swing') -> FitResult:
    """omega_p'^2 ('wp2'), damping c ('damping'), theta0, theta_dot0 of the free swing of Experiment 1
    (Section 2.3: theta'' = -omega_p'^2 sin theta - c theta', the rotor stuck), from its first
    regular turning point after the hand let go (:func:`release_index`, :func:`swing_start`).
    IdentError with the reason when the pendulum hardly swung, the rotor slipped (then the stuck
    model does not hold), the motor was driven, or the fit does not measure the swing
    (:func:`swing_problem`): a bad swing gives no number."""
    dl, h = rig.count_angle, rig.sample_period
    pc = np.asarray(d.pc, float)
    missing = int(np.count_nonzero(np.isnan(pc) | np.isnan(np.asarray(d.mc, float))))
    if missing:
        raise IdentError(f'{name}: {missing} encoder samples missing in the recording')
    k_rel = release_index(pc, h, dl)
    tp, _ = M.turning_points(pc[k_rel:], np.arange(len(pc) - k_rel) * h)
    start = swing_start(tp)
    if np.ptp(pc[k_rel:]) < 40 or start is None:
        held = f' after the hand let go at t = {k_rel * h:.2f} s' if k_rel else ''
        raise IdentError(f'{name}: the pendulum did not swing{held} (range {np.ptp(pc[k_rel:]):.0f} counts, '
                         f'{len(tp)} turning points): lift it about 20 degrees and let go')
    k0 = k_rel + int(round(start / h))
    if np.ptp(d.mc[k0:]) > 3:
        raise IdentError(f'{name}: the rotor turned {np.ptp(d.mc[k0:]):.0f} counts relative to the pendulum '
                         'during the free swing (it should stick, Fig. 2.2): swing from a smaller angle, u = 0')
    driven = driven_samples(d, k0)
    if driven.size:
        raise IdentError(f'{name}: the motor was driven during the free swing (u = {driven[0][1]:g} at t = '
                         f'{driven[0][0] * h:.3f} s, {len(driven)} samples): the swing is not free (mode off, u = 0)')
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
    x0 = np.clip(x0, np.array(SWING_BOUNDS[0]) + 1e-9, np.array(SWING_BOUNDS[1]) - 1e-9)
    res = _fit(residuals, x0, ['wp2', 'damping', 'theta0', 'theta_dot0'], bounds=SWING_BOUNDS)
    res.extra.update(k0=k0, release=k_rel)
    why = swing_problem(res, float(np.max(np.abs(y))))
    if why:
        raise IdentError(f'{name}: {why} (fitted from t = {k0 * h:.2f} s, the hand let go at t = {k_rel * h:.2f} s)'
                         if k_rel else f'{name}: {why} (fitted from t = {k0 * h:.2f} s)')
    return res


def driven_samples(d, k0: int) -> np.ndarray:
    """(sample, u) of the samples from ``k0`` on where the plant held a command other than 0 (the
    device's applied command, else the recorded command; none recorded: none driven)."""
    held = getattr(d, 'u_held', None)
    u = np.asarray(d.u if held is None or np.all(np.isnan(held)) else held, float)[k0:]
    k = np.nonzero(np.nan_to_num(u) != 0.0)[0]
    return np.column_stack([k + k0, u[k]]) if k.size else np.zeros((0, 2))


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
def first_turn_torques(ramps: list[Record]) -> list[float]:
    """|u| at the sample each ramp's rotor count first changed."""
    return [abs(float(rec.u[int(np.nonzero(rec.mc != rec.mc[0])[0][0])])) for rec in ramps]


def breakaway_guess(base, ramps: list[Record]) -> float:
    """The applied torque one amplifier step below where each ramp's rotor count first moved
    (the rotor lets go some ms before it has turned half a count), mean over the ramps."""
    q = amplifier_step(base)
    return float(np.mean([u - q for u in first_turn_torques(ramps)]))


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
    q = amplifier_step(rig) or 0.01
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
