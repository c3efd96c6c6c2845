"""The figures of one run, from its per-sample arrays (pure, numpy).

x = wrap(theta - pi), the deviation from upright of the plant's truth (Chapter 4's x).

* ``success``: |x| < tolerance over the last ``last`` s (and, with ``never_beyond``, |x| never
  above it during the run) -- :class:`rwpend_sweep.spec.Success`.
* ``time_to_balance`` (s): the start of the final stretch with |x| < tolerance that lasts to the
  end (nan when the run does not end balanced).
* ``balance_rms`` (rad): RMS of x over the last ``last`` s.
* ``control_rms`` (control units): RMS of the command over the run.
* ``saturation_share``: share of the samples whose law asked for |u| > u_max.
* ``max_wheel_speed`` (rad/s): largest |theta_r' - theta'|, the motor's speed (the back-EMF limit
  (2.13) and the overspeed limit judge it).
* ``reason``: why a run failed ('' when it succeeded).
"""
from __future__ import annotations

import math

import numpy as np


def upright_deviation(theta: np.ndarray) -> np.ndarray:
    """wrap(theta - pi) into [-pi, pi)."""
    return np.mod(theta, 2 * math.pi) - math.pi


def metrics(a, ctrl, setup, success) -> dict:
    """The row of one run: ``a`` a rwpend_sweep.run.Trace, ``ctrl`` the run's Controller."""
    h = setup.truth.sample_period
    n = len(a.theta)
    x = upright_deviation(a.theta)
    ax = np.abs(x)
    tol = success.tolerance
    n_last = max(1, min(n, int(round(success.last / h))))
    end_ok = bool(n and np.all(ax[-n_last:] < tol))
    out_idx = np.flatnonzero(ax >= tol)
    if not end_ok:
        ttb = float('nan')
    elif out_idx.size == 0:
        ttb = 0.0
    else:
        ttb = (int(out_idx[-1]) + 1) * h
    beyond = success.never_beyond is not None and bool(n) and float(ax.max()) > success.never_beyond
    ok = end_ok and not beyond
    u = a.u
    w = np.abs(a.wheel_rate - a.theta_dot)
    row = {
        'success': ok,
        'time_to_balance': ttb,
        'balance_rms': float(np.sqrt(np.mean(x[-n_last:] ** 2))) if n else float('nan'),
        'control_rms': float(np.sqrt(np.mean(u ** 2))) if n else float('nan'),
        'saturation_share': float(np.mean(a.saturated)) if n else float('nan'),
        'max_wheel_speed': float(w.max()) if n else float('nan'),
        'reason': '' if ok else failure_reason(x, h, success, beyond, ctrl),
    }
    return row


def failure_reason(x: np.ndarray, h: float, success, beyond: bool, ctrl) -> str:
    """Why the run did not succeed, in words (the controller's own trips named)."""
    ax = np.abs(x)
    tol = success.tolerance
    trips = []
    for name, count in (('overspeed', ctrl.overspeed_trips), ('fall', ctrl.fall_trips),
                        ('saturation', ctrl.saturation_trips)):
        if count:
            trips.append(f'{count} {name} trip{"s" if count > 1 else ""}')
    if ctrl.mode == 'off' and ctrl.reason:
        trips.append(f'controller off: {ctrl.reason}')
    tail = ('; ' + '; '.join(trips)) if trips else ''
    if beyond:
        k = int(np.argmax(ax > success.never_beyond))
        return f'left |theta-pi| <= {success.never_beyond:g} at t = {k * h:.3f} s{tail}'
    if not np.any(ax < tol):
        return f'never within {tol:g} rad of upright (closest {ax.min():.3f} rad){tail}'
    return f'not balanced at the end: |theta-pi| = {ax[-1]:.3f} rad, largest {ax[-int(round(success.last / h)):].max():.3f} ' \
           f'in the last {success.last:g} s{tail}'
