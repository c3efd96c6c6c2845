"""rwpend_ident.fit: least squares with HAC confidence intervals, on synthetic data with known
parameters (no ROS)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from rwpend_ident.fit import FitError, derived, fit, hac_covariance, linear_fit, nrmse_fit


def _decay(t, x):
    return x[0] * np.exp(-t / x[1])


def _ar1(rng, n, rho, sigma=1.0):
    e = rng.normal(0, sigma, n)
    out = np.empty(n)
    out[0] = e[0]
    for i in range(1, n):
        out[i] = rho * out[i - 1] + math.sqrt(1 - rho * rho) * e[i]
    return out


def test_fit_recovers_known_parameters_with_ci():
    rng = np.random.default_rng(1)
    t = np.linspace(0, 5, 400)
    truth = np.array([2.0, 1.3])
    y = _decay(t, truth) + rng.normal(0, 0.01, t.size)
    res = fit(lambda x: _decay(t, x) - y, [1.0, 1.0], ['A', 'tau'])
    for i, name in enumerate(res.names):
        assert abs(res[name] - truth[i]) <= 2 * res.ci(name)   # one draw: within ~4 sigma
        assert res.ci(name) < 0.02 * truth[i]
    assert res.rms == pytest.approx(0.01, rel=0.15)


def test_hac_intervals_cover_with_correlated_residuals():
    """Residuals correlated over ~20 samples (like quantization of a slow signal): the HAC interval
    covers the truth about 95 % of the time, where the white-noise one would be too narrow."""
    rng = np.random.default_rng(7)
    n, hits, naive_hits = 2000, 0, 0
    x = np.linspace(-1, 1, n)
    X = np.column_stack([np.ones(n), x])
    for _ in range(60):
        e = _ar1(rng, n, 0.9)
        y = 0.5 + 2.0 * x + e
        b, *_ = np.linalg.lstsq(X, y, rcond=None)
        r = y - X @ b
        cov, lags = hac_covariance(X, r)
        hits += abs(b[0] - 0.5) <= 1.96 * math.sqrt(cov[0, 0])
        naive = np.linalg.inv(X.T @ X) * (r @ r) / (n - 2)
        naive_hits += abs(b[0] - 0.5) <= 1.96 * math.sqrt(naive[0, 0])
    assert hits >= 50, f'HAC coverage {hits}/60'
    assert naive_hits < hits
    assert lags > 5


def test_linear_fit_takes_the_wider_of_sigma_and_scatter():
    x = np.arange(6.0)
    y = 1.0 + 0.5 * x + np.array([0.1, -0.1, 0.1, -0.1, 0.1, -0.1])
    X = np.column_stack([np.ones(6), x])
    tight = linear_fit(X, y, np.full(6, 1e-4), ['c', 'v'])
    loose = linear_fit(X, y, np.full(6, 1.0), ['c', 'v'])
    assert tight.ci('c') > 0.05, 'the scatter, not the optimistic sigma'
    assert loose.ci('c') > tight.ci('c')
    with pytest.raises(FitError):
        linear_fit(X[:2], y[:2], np.ones(2), ['c', 'v'])


def test_derived_delta_method():
    cov = np.diag([0.01 ** 2, 0.02 ** 2])
    v, h = derived(lambda p: p[0] * p[1], np.array([2.0, 3.0]), cov, 1000)
    assert v == pytest.approx(6.0)
    assert h == pytest.approx(1.962 * math.hypot(3 * 0.01, 2 * 0.02), rel=1e-3)


def test_nrmse_fit():
    y = np.sin(np.linspace(0, 10, 100))
    assert nrmse_fit(y, y) == 100.0
    assert nrmse_fit(y, np.full(100, y.mean())) == pytest.approx(0.0)
