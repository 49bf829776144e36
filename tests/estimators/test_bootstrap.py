"""The parametric bootstrap (`bootstrap`, `redraw_moments`) against closed-form spreads."""

import math

import numpy as np
import pytest
import torch

from torchjfa.estimators import OLS, Ridge, bootstrap, redraw_moments
from torchjfa.stats import Moments

B = 400  # draws: the std of a std from B normal draws is 1 / sqrt(2 (B - 1)) of it, 3.5 %


def _moments(n=300, d=5, seed=0):
    rng = np.random.default_rng(seed)
    X = torch.from_numpy(rng.standard_normal((n, d)) @ rng.standard_normal((d, d)))
    return X, Moments.from_data(X, torch.zeros(n, dtype=torch.float64))


def _within_monte_carlo(got: torch.Tensor, exact: torch.Tensor) -> None:
    """Each bootstrap std within 4.5 of its Monte Carlo standard errors of the exact one (5
    entries: a false alarm about once in 10^4 runs)."""
    tol = 4.5 / math.sqrt(2 * (B - 1))
    ratio = got / exact
    assert bool(((ratio - 1).abs() < tol).all()), ratio


def test_ols_bootstrap_matches_the_least_squares_std():
    X, m = _moments()
    coef = torch.arange(1.0, 6.0, dtype=torch.float64)
    sigma2 = 0.7
    g = torch.Generator().manual_seed(1)
    coefs, std = bootstrap(
        OLS(fit_intercept=False), redraw_moments(m, coef, sigma2, B, generator=g)
    )
    assert coefs.shape == (B, 5) and std.shape == (5,) and std.dtype == torch.float64
    exact = (sigma2 * torch.linalg.inv(X.T @ X).diagonal()).sqrt()
    _within_monte_carlo(std, exact)
    # unbiased: the mean refit within 4.5 standard errors of the mean of the coefficient
    assert bool(((coefs.mean(0) - coef).abs() < 4.5 * exact / math.sqrt(B)).all())


def test_ridge_bootstrap_matches_its_sandwich_std():
    """Ridge with a fixed alpha: coef = A X^T y, A = (X^T X + alpha I)^-1, so its covariance
    under white noise is sigma^2 A X^T X A (written here, not taken from the code)."""
    X, m = _moments(seed=2)
    alpha, sigma2 = 50.0, 2.0
    G = X.T @ X
    A = torch.linalg.inv(G + alpha * torch.eye(5, dtype=torch.float64))
    exact = (sigma2 * (A @ G @ A).diagonal()).sqrt()
    g = torch.Generator().manual_seed(3)
    draws = redraw_moments(m, torch.ones(5, dtype=torch.float64), sigma2, B, generator=g)
    _, std = bootstrap(Ridge(alpha=alpha, fit_intercept=False), draws)
    _within_monte_carlo(std, exact)


def test_redrawn_moments_have_the_law_of_redrawn_data():
    """E[X^T y*] = G coef and E[y*^T y*] = coef^T G coef + n sigma^2 (a chi-square's mean),
    each within 4.5 Monte Carlo standard errors; X^T X is kept."""
    X, m = _moments(n=200, d=3, seed=4)
    coef = torch.tensor([0.5, -1.0, 2.0], dtype=torch.float64)
    sigma2, n = 0.3, 200
    draws = redraw_moments(m, coef, sigma2, B, generator=torch.Generator().manual_seed(5))
    G = X.T @ X
    assert all(torch.equal(d.xtx, m.xtx) and float(d.n) == n for d in draws)
    xty = torch.stack([d.xty for d in draws])
    se = (sigma2 * G.diagonal() / B).sqrt()
    assert bool(((xty.mean(0) - G @ coef).abs() < 4.5 * se).all())
    yty = torch.stack([d.yty for d in draws])
    mean = float(coef @ G @ coef) + n * sigma2
    # var(y^T y) = 4 sigma^2 coef^T G coef + 2 n sigma^4
    sd = math.sqrt((4 * sigma2 * float(coef @ G @ coef) + 2 * n * sigma2**2) / B)
    assert abs(float(yty.mean()) - mean) < 4.5 * sd
    # the same seed gives the same draws; no noise gives the noiseless moments
    again = redraw_moments(m, coef, sigma2, 2, generator=torch.Generator().manual_seed(5))
    assert torch.equal(again[1].xty, draws[1].xty)
    quiet = redraw_moments(m, coef, 0.0, 2)
    torch.testing.assert_close(quiet[0].xty, G @ coef, rtol=1e-12, atol=1e-12)


def test_bootstrap_leaves_the_estimator_alone_and_refuses_bad_input():
    X, m = _moments(n=50, d=2)
    est = OLS(fit_intercept=False).fit_moments(redraw_moments(m, [1.0, 2.0], 1.0, 2)[0])
    before = est.coef_.clone()
    bootstrap(est, redraw_moments(m, [1.0, 2.0], 1.0, 3))
    assert torch.equal(est.coef_, before)
    with pytest.raises(ValueError, match="at least 2 draws"):
        bootstrap(est, redraw_moments(m, [1.0, 2.0], 1.0, 2)[:1])
    with pytest.raises(TypeError, match="LinearEstimator"):
        bootstrap(object(), [])
    with pytest.raises(ValueError, match="n_draws"):
        redraw_moments(m, [1.0, 2.0], 1.0, 1)
    with pytest.raises(ValueError, match="coef must have shape"):
        redraw_moments(m, [1.0], 1.0, 2)
    with pytest.raises(ValueError, match="noise_var"):
        redraw_moments(m, [1.0, 2.0], -1.0, 2)
