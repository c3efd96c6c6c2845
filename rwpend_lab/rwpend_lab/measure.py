"""Measurements on sampled signals (numpy only): crossings, turning points, fits, steps, jumps."""
from __future__ import annotations

import math

import numpy as np


def downward_crossings(x: np.ndarray, h: float) -> np.ndarray:
    """Times of the samples at which x passes from > 0 to <= 0 (the same quantization level each
    time, so its bias cancels in differences)."""
    x = np.asarray(x)
    k = np.nonzero((x[:-1] > 0) & (x[1:] <= 0))[0] + 1
    return k * h


def swing_frequency(x: np.ndarray, h: float) -> float | None:
    """Angular frequency (rad/s) from the mean period between downward crossings (None: < 3)."""
    tc = downward_crossings(x, h)
    if len(tc) < 3:
        return None
    return 2 * math.pi * (len(tc) - 1) / (tc[-1] - tc[0])


def amplitude_factor(theta0: float) -> float:
    """Period of a pendulum swinging with amplitude theta0 over the small-swing period (to theta0^4)."""
    return 1 + theta0 ** 2 / 16 + 11 * theta0 ** 4 / 3072


def turning_points(x: np.ndarray, t: np.ndarray, min_len: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """(times, |x|) of the largest |x| of each complete half swing between sign changes."""
    x = np.asarray(x)
    pos = x > 0
    edges = np.nonzero(pos[1:] != pos[:-1])[0] + 1
    pt, px = [], []
    for a, b in zip(edges[:-1], edges[1:]):
        if b - a < min_len:
            continue
        seg = np.abs(x[a:b])
        top = np.nonzero(seg == seg.max())[0]
        pt.append(t[a + int(round(top.mean()))])
        px.append(seg.max())
    return np.array(pt), np.array(px)


def exp_time_constant(t: np.ndarray, y: np.ndarray) -> float | None:
    """tau of y ~ exp(-t/tau), least squares on log y (None if not decaying)."""
    ok = y > 0
    if ok.sum() < 3:
        return None
    slope = np.polyfit(t[ok], np.log(y[ok]), 1)[0]
    return -1.0 / slope if slope < 0 else None


def cumtrapz(x: np.ndarray, h: float) -> np.ndarray:
    out = np.zeros(len(x))
    out[1:] = np.cumsum(0.5 * (x[1:] + x[:-1])) * h
    return out


def levels(u: np.ndarray, t: np.ndarray, min_len: int = 5) -> list[tuple[float, float, float]]:
    """(start time, end time, value) of the runs of a piecewise constant signal."""
    u = np.asarray(u)
    change = np.nonzero(np.diff(u) != 0)[0] + 1
    starts = np.r_[0, change]
    ends = np.r_[change, len(u)]
    return [(float(t[a]), float(t[b - 1]), float(u[a])) for a, b in zip(starts, ends) if b - a >= min_len]


def step_response(t: np.ndarray, y: np.ndarray, y0: float, y1: float) -> dict:
    """Overshoot (fraction of the step), 63 % time, final value (mean of the last 20 %) of a step
    from y0 towards y1 starting at t[0]."""
    step = y1 - y0
    n = len(y)
    final = float(np.mean(y[int(0.8 * n):]))
    rel = (y - y0) / step
    k63 = np.nonzero(rel >= 0.632 * (final - y0) / step)[0]
    peak = float(np.max(rel))
    return {'final': final, 't63': float(t[k63[0]] - t[0]) if k63.size else None,
            'overshoot': max(0.0, peak - (final - y0) / step) / ((final - y0) / step)
            if final != y0 else None}


def largest_step(y: np.ndarray) -> float:
    """Largest sample-to-sample change |y_k - y_(k-1)|."""
    return float(np.max(np.abs(np.diff(y)))) if len(y) > 1 else 0.0


def smallest_nonzero_step(y: np.ndarray, eps: float = 1e-9) -> float | None:
    d = np.abs(np.diff(y))
    d = d[d > eps]
    return float(d.min()) if d.size else None


def line_fit(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """(slope, intercept) of the least-squares line."""
    a, b = np.polyfit(np.asarray(x, float), np.asarray(y, float), 1)
    return float(a), float(b)


# ---------------------------------------------------------------- Experiment 3 and the identification
def lagged_double_integral(u: np.ndarray, h: float, te: float) -> np.ndarray:
    """Double integral of the motor torque: the ZOH command through the current lag T_e (2.12),
    integrated exactly over each sample; value at t_k."""
    x = v = tau = 0.0
    out = [0.0]
    e = math.exp(-h / te) if te > 0 else 0.0
    for uk in u[:-1]:
        i1 = uk * h + (tau - uk) * te * (1 - e)
        i2 = uk * h * h / 2 + (tau - uk) * te * (h - te * (1 - e))
        x += v * h + i2
        v += i1
        tau = uk + (tau - uk) * e
        out.append(x)
    return np.array(out)


def fit_pulse(rig, d, u0: float, width: float, fit_s: float = 0.3) -> dict:
    """A torque pulse u0 of ``width`` s at t = 0, from rest (Experiment 3; used by the lab and by
    rwpend_ident for its first guess): b_r, F_c, f_v from
    theta_r(t) = b_r (U2 - F_c sgn(u0) t^2/2 - f_v Int phi) while the rotor slips (2.15, 3.17);
    b_p/b_r from the summed equation theta + a Int Int sin theta = -(b_p/b_r) theta_r over the
    first ``fit_s`` s (Section 2.3, valid slipping or stuck); the re-stick time after the pulse."""
    h, dl = rig.sample_period, rig.count_angle
    theta, phi = d.pc * dl, d.mc * dl
    theta_r = theta + phi
    k_end = (int(np.argmax(d.mc)) if u0 > 0 else int(np.argmin(d.mc))) - 3
    t = d.t
    # the command the plant held (the rig's device reports it; a real-time command may come late
    # or be refused as old), where the bag has it; else the commands sent
    held = getattr(d, 'u_held', None)
    u = d.u if held is None else np.where(np.isfinite(held), held, d.u)
    u2 = lagged_double_integral(np.nan_to_num(u), h, rig.motor_time_constant)
    sl = slice(0, k_end + 1)
    X = np.column_stack([u2[sl], -math.copysign(0.5, u0) * t[sl] ** 2, -cumtrapz(phi, h)[sl]])
    c, *_ = np.linalg.lstsq(X, theta_r[sl], rcond=None)
    n = min(len(t), int(round(fit_s / h)))    # the first swing: a few counts of pendulum motion
    y = theta[:n] + rig.a * cumtrapz(cumtrapz(np.sin(theta[:n]), h), h)
    ratio = -float(np.dot(theta_r[:n], y) / np.dot(theta_r[:n], theta_r[:n]))
    # re-stick: the motor count stops changing for good
    moving = np.nonzero(np.diff(d.mc) != 0)[0]
    restick = float(t[moving[-1] + 1]) - width if moving.size else None
    return {'b_r': c[0], 'F_c': c[1] / c[0], 'f_v': c[2] / c[0], 'b_p': ratio * c[0], 'restick': restick}
