"""Nonlinear least squares with honest 95 % confidence intervals (numpy/scipy, no rclpy).

:func:`fit` wraps ``scipy.optimize.least_squares``.  The residuals of the identification are
encoder quantization errors of slowly varying signals: not white (a pendulum near a turning
point stays on one count for tens of samples).  The covariance is therefore the
heteroscedasticity-and-autocorrelation-consistent (Newey-West) sandwich

    cov = (J'J)^-1  S  (J'J)^-1,   S = sum_l w_l sum_t (g_t g_(t-l)' + g_(t-l) g_t'),
    g_t = J_t r_t,  w_l = 1 - l / (L + 1)  (Bartlett),

with products taken only within one record (``groups``), and L chosen from the residuals'
own autocorrelation (:func:`bandwidth`).  For white residuals it equals the usual s^2 (J'J)^-1.
The interval is +-t(0.975, n - p) sqrt(cov_ii).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
from scipy import optimize, stats


class FitError(ValueError):
    """A fit could not be made (too little data, no convergence): the reason."""


@dataclass
class FitResult:
    """Estimates, their covariance and 95 % half-widths, in the order of ``names``."""

    names: list[str]
    x: np.ndarray
    cov: np.ndarray
    half: np.ndarray            # 95 % confidence half-widths
    n: int                      # residuals
    rms: float                  # rms of the (weighted) residuals
    lags: int                   # HAC bandwidth used
    message: str = ''
    extra: dict = field(default_factory=dict)

    def __getitem__(self, name: str) -> float:
        return float(self.x[self.names.index(name)])

    def ci(self, name: str) -> float:
        """95 % half-width of ``name``."""
        return float(self.half[self.names.index(name)])

    def as_dict(self) -> dict:
        return {n: {'value': float(v), 'ci95': float(h)} for n, v, h in zip(self.names, self.x, self.half)}


def bandwidth(r: np.ndarray, groups: np.ndarray | None = None, max_lag: int = 400) -> int:
    """HAC bandwidth: twice the first lag at which the residual autocorrelation (within the
    groups) falls below 0.1, at least 1, at most ``max_lag``."""
    r = np.asarray(r, float)
    g = np.zeros(len(r), int) if groups is None else np.asarray(groups)
    var = float(np.dot(r, r))
    if var == 0 or len(r) < 4:
        return 1
    for lag in range(1, min(max_lag, len(r) - 1) + 1):
        same = g[lag:] == g[:-lag]
        rho = float(np.dot(r[lag:][same], r[:-lag][same])) / var
        if rho < 0.1:
            return int(min(max_lag, max(1, 2 * lag)))
    return max_lag


def hac_covariance(J: np.ndarray, r: np.ndarray, groups: np.ndarray | None = None,
                   lags: int | None = None) -> tuple[np.ndarray, int]:
    """(covariance of the least-squares estimate, bandwidth used); see the module docstring."""
    J, r = np.asarray(J, float), np.asarray(r, float)
    n, p = J.shape
    if n <= p:
        raise FitError(f'{n} residuals for {p} parameters')
    g_ids = np.zeros(n, int) if groups is None else np.asarray(groups)
    L = bandwidth(r, g_ids) if lags is None else int(lags)
    G = J * r[:, None]
    S = G.T @ G
    for lag in range(1, L + 1):
        same = (g_ids[lag:] == g_ids[:-lag])[:, None]
        gamma = (G[lag:] * same).T @ G[:-lag]
        S += (1.0 - lag / (L + 1.0)) * (gamma + gamma.T)
    try:
        A = np.linalg.inv(J.T @ J)
    except np.linalg.LinAlgError:
        raise FitError('the parameters are not identifiable from these data (singular J\'J)') from None
    return A @ S @ A * (n / (n - p)), L


def fit(residuals: Callable[[np.ndarray], np.ndarray], x0: Sequence[float], names: Sequence[str], *,
        bounds=(-np.inf, np.inf), groups: np.ndarray | None = None, diff_step=None,
        x_scale='jac', max_nfev: int | None = None, tol: float = 1e-8) -> FitResult:
    """Minimise sum(residuals(x)^2) from ``x0``; FitResult with HAC confidence intervals."""
    x0 = np.asarray(x0, float)
    try:
        res = optimize.least_squares(residuals, x0, bounds=bounds, x_scale=x_scale, diff_step=diff_step,
                                     max_nfev=max_nfev, method='trf', ftol=tol, xtol=tol)
    except ValueError as exc:
        raise FitError(f'least squares failed: {exc}') from None
    if not np.all(np.isfinite(res.fun)):
        raise FitError('the model gives non-finite residuals at the solution')
    return result_from(res.x, res.fun, res.jac, names, groups, res.message)


def result_from(x, r, J, names, groups=None, message: str = '') -> FitResult:
    """FitResult at ``x`` from its residuals ``r`` and Jacobian ``J``."""
    r = np.asarray(r, float)
    cov, L = hac_covariance(J, r, groups)
    n, p = np.shape(J)
    t = stats.t.ppf(0.975, n - p)
    half = t * np.sqrt(np.clip(np.diag(cov), 0.0, None))
    return FitResult(list(names), np.asarray(x, float), cov, half, n, math.sqrt(float(np.mean(r * r))), L,
                     str(message))


def linear_fit(X: np.ndarray, y: np.ndarray, sigma: np.ndarray, names: Sequence[str]) -> FitResult:
    """Weighted linear least squares y ~ X b (each row with its standard deviation ``sigma``).
    The covariance is the larger of the one implied by ``sigma`` and the one from the scatter
    of the residuals, so neither too few points nor too optimistic sigmas make it narrow."""
    X, y, sigma = np.asarray(X, float), np.asarray(y, float), np.asarray(sigma, float)
    n, p = X.shape
    if n <= p:
        raise FitError(f'{n} points for {p} parameters')
    Xw, yw = X / sigma[:, None], y / sigma
    b, *_ = np.linalg.lstsq(Xw, yw, rcond=None)
    r = yw - Xw @ b
    A = np.linalg.inv(Xw.T @ Xw)
    s2 = float(r @ r) / (n - p)
    cov = A * max(1.0, s2)
    half = stats.t.ppf(0.975, n - p) * np.sqrt(np.diag(cov))
    return FitResult(list(names), b, cov, half, n, math.sqrt(float(np.mean(r * r))), 0)


def derived(f: Callable[[np.ndarray], float], x: np.ndarray, cov: np.ndarray, dof: int) -> tuple[float, float]:
    """(f(x), 95 % half-width) of a function of the estimates, by the delta method (numerical
    gradient); ``dof`` residual degrees of freedom for the t quantile."""
    x = np.asarray(x, float)
    v = float(f(x))
    grad = np.zeros(len(x))
    for i in range(len(x)):
        step = 1e-6 * max(abs(x[i]), 1e-9)
        xp, xm = x.copy(), x.copy()
        xp[i] += step
        xm[i] -= step
        grad[i] = (f(xp) - f(xm)) / (2 * step)
    var = float(grad @ cov @ grad)
    return v, float(stats.t.ppf(0.975, max(dof, 1)) * math.sqrt(max(var, 0.0)))


def nrmse_fit(y: np.ndarray, y_hat: np.ndarray) -> float:
    """Fit in %: 100 (1 - |y - y_hat| / |y - mean(y)|) (100 = perfect, 0 = no better than the mean)."""
    y, y_hat = np.asarray(y, float), np.asarray(y_hat, float)
    den = float(np.linalg.norm(y - np.mean(y)))
    if den == 0:
        return float('nan')
    return 100.0 * (1.0 - float(np.linalg.norm(y - y_hat)) / den)
