"""JFA (maximum-likelihood EM): against a per-sample EM and the exact Gaussian likelihood."""

import math

import pytest
import torch

from torchjfa.estimators import JFA
from torchjfa.stats import Moments

F64 = torch.float64


def _model_data(n, d, *, seed, psx=0.5, noise_y=0.3):
    """Data drawn from the model: independent t, x = t + noise, y = sum_m b_m t_m + noise."""
    g = torch.Generator().manual_seed(seed)
    b = torch.linspace(1.0, 2.0, d, dtype=F64)
    t = torch.randn(n, d, generator=g, dtype=F64)
    X = 2.0 * (t + math.sqrt(psx) * torch.randn(n, d, generator=g, dtype=F64)) - 1.0
    y = t @ b + noise_y * torch.randn(n, generator=g, dtype=F64) + 0.5
    return X, y, b / 2.0  # the slope per unit of x (x = 2 t + ...)


def _hard_data(kind, seed=0):
    g = torch.Generator().manual_seed(seed)
    n = 300
    if kind == "ill":
        base = torch.randn(n, 3, generator=g, dtype=F64)
        X = torch.cat([base, base @ torch.randn(3, 3, generator=g, dtype=F64) * 1e-3], 1)
        X = X + 1e-4 * torch.randn(n, 6, generator=g, dtype=F64)
        X[:, 1] *= 1e4
    elif kind == "redundant":
        base = torch.randn(n, 4, generator=g, dtype=F64)
        X = torch.cat([base, base[:, :2], base[:, :3].sum(1, keepdim=True)], 1)
    else:
        X = torch.randn(n, 5, generator=g, dtype=F64) * torch.tensor([1, 2, 3, 4, 5.0], dtype=F64)
    y = (X[:, :3] / X[:, :3].std(0)) @ torch.tensor([1.0, -2.0, 0.5], dtype=F64)
    return X, y + 0.5 * torch.randn(n, generator=g, dtype=F64)


def _loglik(X, y, wz, wx, psz, psx, psy, mean_x, mean_y):
    """Exact log p(X, y) of the model: (x, y) Gaussian with the covariance the model implies."""
    d = X.shape[1]
    cov = torch.zeros(d + 1, d + 1, dtype=F64)
    cov[:d, :d] = torch.diag(wx**2 + psx)
    cov[:d, d] = cov[d, :d] = wx * wz
    cov[d, d] = (wz**2 + psz).sum() + psy
    mean = torch.cat([mean_x, mean_y.reshape(1)])
    dist = torch.distributions.MultivariateNormal(mean, covariance_matrix=cov)
    return float(dist.log_prob(torch.cat([X, y[:, None]], 1)).sum())


def _reference(X, y, n_updates, floor=1e-6):
    """EM with an explicit 2d x 2d posterior of (z_i, t_i) for every sample (standardised data)."""
    N, d = X.shape
    mx_, my_ = X.mean(0), y.mean()
    sx, sy = ((X - mx_) ** 2).mean(0).sqrt(), ((y - my_) ** 2).mean().sqrt()
    Xs, ys = (X - mx_) / sx, (y - my_) / sy
    wx = torch.full((d,), math.sqrt(0.5), dtype=F64)
    psx = torch.full((d,), 0.5, dtype=F64)
    wz = (Xs * ys[:, None]).mean(0) / wx
    left = 1.0 - float((wz**2).sum())
    assert left > 0.05
    psy, psz = left / 2, torch.full((d,), left / (2 * d), dtype=F64)
    one = torch.ones(d, dtype=F64)
    for _ in range(n_updates):
        P = torch.zeros(2 * d, 2 * d, dtype=F64)
        P[:d, :d] = torch.diag(1 / psz) + torch.outer(one, one) / psy
        P[d:, d:] = torch.diag(1 + wz**2 / psz + wx**2 / psx)
        P[:d, d:] = P[d:, :d] = torch.diag(-wz / psz)
        zz, tt, zt, xt = (torch.zeros(d, dtype=F64) for _ in range(4))
        e_y = 0.0
        for i in range(N):
            cov = torch.linalg.inv(P)
            mu = cov @ torch.cat([one * ys[i] / psy, wx * Xs[i] / psx])
            zz = zz + mu[:d] ** 2 + torch.diagonal(cov[:d, :d])
            tt = tt + mu[d:] ** 2 + torch.diagonal(cov[d:, d:])
            zt = zt + mu[:d] * mu[d:] + torch.diagonal(cov[:d, d:])
            xt = xt + Xs[i] * mu[d:]
            e_y = e_y + (ys[i] - one @ mu[:d]) ** 2 + one @ cov[:d, :d] @ one
        wz, wx = zt / tt, xt / tt
        psz = ((zz - 2 * wz * zt + wz**2 * tt) / N).clamp_min(floor)
        psx = (((Xs**2).sum(0) - 2 * wx * xt + wx**2 * tt) / N).clamp_min(floor)
        psy = max(float(e_y) / N, floor)
    return wz * sy, wx * sx, psz * sy**2, psx * sx**2, psy * sy**2


def test_matches_per_sample_reference_and_exact_likelihood():
    X, y, _ = _model_data(40, 3, seed=1, noise_y=5.0)
    n_iter = 5
    est = JFA(max_iter=n_iter, tol=0.0, coef_tol=0.0, method="em").fit(X, y)
    wz, wx, psz, psx, psy = _reference(X, y, n_iter)  # the library's n_iter updates
    torch.testing.assert_close(est.weights_z_, wz, rtol=1e-10, atol=1e-12)
    torch.testing.assert_close(est.weights_x_, wx, rtol=1e-10, atol=1e-12)
    torch.testing.assert_close(est.noise_z_, psz, rtol=1e-10, atol=1e-12)
    torch.testing.assert_close(est.noise_x_, psx, rtol=1e-10, atol=1e-12)
    assert float(est.noise_y_) == pytest.approx(float(psy), rel=1e-10)
    # for maximum likelihood the recorded bound is the exact log-likelihood at the state
    ll = _loglik(X, y, wz, wx, psz, psx, psy, X.mean(0), y.mean())
    assert float(est.lower_bound_[-1]) == pytest.approx(ll, rel=1e-10)
    # eq. (4): w_z / w_x; eq. (3): E[y | x] of the model, per input since t's are independent
    torch.testing.assert_close(est.coef_, wz / wx, rtol=1e-10, atol=1e-12)
    torch.testing.assert_close(est.coef_noisy_, wz * wx / (wx**2 + psx), rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("kind", ["plain", "ill", "redundant"])
@pytest.mark.parametrize("method", ["em", "closed_form"])
def test_likelihood_never_decreases(kind, method):
    X, y = _hard_data(kind)
    est = JFA(max_iter=400, tol=0.0, coef_tol=0.0, method=method).fit(X, y)
    L = est.lower_bound_
    assert L.shape == (est.n_iter_,) and bool(torch.isfinite(L).all())
    assert float(L.diff().min()) >= -1e-9 * float(L.abs().max())
    assert float(L[-1]) > float(L[0])


def test_converged_noisy_predictor_is_ols_and_bound_is_loglik():
    """With psi_x free, the ML fit of y | x is unconstrained: E[y | x] is the OLS fit."""
    X, y, _ = _model_data(500, 4, seed=2)
    est = JFA(max_iter=20000, tol=0.0, coef_tol=0.0).fit(X, y)  # until the bound stalls
    assert est.converged_ and est.stop_reason_ == "bound" and est.n_iter_ < 20000
    A = torch.cat([X, torch.ones(500, 1, dtype=F64)], 1)
    ols = torch.linalg.lstsq(A, y[:, None]).solution[:, 0]
    torch.testing.assert_close(est.coef_noisy_, ols[:4], rtol=1e-4, atol=0)
    torch.testing.assert_close(est.intercept_noisy_, ols[4], rtol=1e-4, atol=1e-6)
    ll = _loglik(
        X, y, est.weights_z_, est.weights_x_, est.noise_z_, est.noise_x_, est.noise_y_,
        X.mean(0), y.mean(),
    )  # fmt: skip
    assert float(est.lower_bound_[-1]) == pytest.approx(ll, rel=1e-10)


def test_known_input_noise_beats_ols():
    psx = 0.5
    X, y, b = _model_data(4000, 6, seed=5, psx=psx)
    noise = torch.full((6,), 4.0 * psx, dtype=F64)  # x = 2 (t + e): noise variance 4 psx
    est = JFA(input_noise=noise).fit(X, y)
    A = torch.cat([X, torch.ones(4000, 1, dtype=F64)], 1)
    ols = torch.linalg.lstsq(A, y[:, None]).solution[:6, 0]
    err_ols = float(torch.linalg.vector_norm(ols - b) / torch.linalg.vector_norm(b))
    err = float(torch.linalg.vector_norm(est.coef_ - b) / torch.linalg.vector_norm(b))
    assert err_ols > 0.25  # attenuated by var t / (var t + psi_x) = 2/3
    assert err < 0.3 * err_ols
    torch.testing.assert_close(est.noise_x_, noise)  # held fixed


def test_chunks_equal_whole():
    X, y, _ = _model_data(300, 4, seed=7)
    kw = dict(max_iter=50, tol=0.0, coef_tol=0.0, method="em")
    whole = JFA(**kw).fit(X, y)
    chunks = [Moments.from_data(X[a : a + 70], y[a : a + 70]) for a in range(0, 300, 70)]
    parts = JFA(**kw).fit_moments(sum(chunks))
    folds = JFA(**kw).fit_moments(chunks)
    for other in (parts, folds):
        torch.testing.assert_close(other.coef_, whole.coef_, rtol=1e-8, atol=1e-10)
        torch.testing.assert_close(other.lower_bound_, whole.lower_bound_, rtol=1e-10, atol=0)


def test_bad_input_raises():
    X, y, _ = _model_data(50, 3, seed=0)
    bad = X.clone()
    bad[3, 1] = float("nan")
    with pytest.raises(ValueError, match="NaN"):
        JFA().fit(bad, y)
    with pytest.raises(ValueError, match="different numbers of samples"):
        JFA().fit(X, y[:-1])
    with pytest.raises(ValueError, match="2-D"):
        JFA().fit(X[:, 0], y)
    with pytest.raises(ValueError, match="input_noise must have shape"):
        JFA(input_noise=torch.ones(2)).fit(X, y)
    with pytest.raises(ValueError, match=">= 0"):
        JFA(input_noise=torch.tensor([0.1, -0.1, 0.1])).fit(X, y)
    with pytest.raises(ValueError, match="max_iter"):
        JFA(max_iter=0).fit(X, y)


def test_constant_column_gets_zero():
    X, y, _ = _model_data(200, 3, seed=0)
    X = torch.cat([X[:, :1], torch.full((200, 1), 7.0, dtype=F64), X[:, 1:]], 1)
    est = JFA(max_iter=300).fit(X, y)
    assert est.coef_[1] == 0 and est.coef_noisy_[1] == 0 and est.noise_x_[1] == 0
    assert bool(torch.isfinite(est.coef_).all()) and bool(torch.isfinite(est.lower_bound_).all())
    assert est.predict(X).shape == (200,)
