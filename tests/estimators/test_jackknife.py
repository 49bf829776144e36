"""The delete-one-block jackknife against the textbook OLS standard errors."""

import numpy as np
import pytest
import torch

from torchjfa.estimators import OLS, BayesianJFA, Ridge, jackknife
from torchjfa.stats import kfold_moments


def _data(n=4000, d=6, seed=0):
    rng = np.random.default_rng(seed)
    X = rng.standard_normal((n, d)) @ rng.standard_normal((d, d))
    y = X @ np.arange(1.0, d + 1) + 2.0 * rng.standard_normal(n)
    return X, y


def test_ols_jackknife_matches_the_classical_standard_error():
    X, y = _data()
    n, d = X.shape
    folds = kfold_moments(torch.from_numpy(X), torch.from_numpy(y), 20)
    coefs, std = jackknife(OLS(fit_intercept=False), folds)
    assert coefs.shape == (20, d)
    beta = np.linalg.lstsq(X, y, rcond=None)[0]
    s2 = ((y - X @ beta) ** 2).sum() / (n - d)
    se = np.sqrt(s2 * np.diag(np.linalg.inv(X.T @ X)))
    ratio = std.numpy() / se
    # a K = 20 jackknife has 19 degrees of freedom: each ratio within ~3 sigma of 1
    assert np.all((ratio > 0.5) & (ratio < 1.6)), ratio
    assert 0.85 < ratio.mean() < 1.2, ratio


def test_leaves_the_estimator_alone_and_handles_cross_validation():
    X, y = _data(n=600)
    folds = kfold_moments(torch.from_numpy(X), torch.from_numpy(y), 4)
    est = OLS(fit_intercept=False).fit_moments(sum(folds[1:], folds[0].copy()))
    before = est.coef_.clone()
    jackknife(est, folds)
    assert torch.equal(est.coef_, before)
    # Ridge(alpha=None) cross-validates on the 3 folds it is given each time
    coefs, std = jackknife(Ridge(fit_intercept=False), folds)
    assert torch.isfinite(std).all() and coefs.shape == (4, X.shape[1])
    with pytest.raises(ValueError, match="at least 2 folds"):
        jackknife(OLS(), folds[:1])


def test_bayesian_jfa_posterior_spread_shrinks_like_one_over_root_n():
    """coef_std_ is a posterior spread: 10x the data gives about 1/sqrt(10) of it."""
    rng = np.random.default_rng(1)
    wx = np.array([1.0, 2.0, 0.5, 1.5])
    wz = np.array([1.0, -2.0, 3.0, 0.5])
    stds = []
    for n in (1000, 10000):
        t = rng.standard_normal((n, 4))
        X = t * wx + rng.standard_normal((n, 4)) * np.sqrt(0.3) * wx
        y = t @ wz + 0.5 * rng.standard_normal(n)
        est = BayesianJFA(fit_intercept=False, input_noise=torch.from_numpy(0.3 * wx**2))
        est.fit(torch.from_numpy(X), torch.from_numpy(y))
        assert torch.isfinite(est.coef_std_).all() and (est.coef_std_ > 0).all()
        stds.append(est.coef_std_)
    ratio = (stds[0] / stds[1]).numpy()
    np.testing.assert_allclose(ratio, np.sqrt(10.0), rtol=0.3)


def test_the_jackknife_of_block_means_is_their_standard_error():
    """For the mean, leaving block k out gives ``(S - b_k) / (K - 1)``, so the jackknife
    standard deviation is exactly the blocks' standard deviation over sqrt(K), whatever the
    trailing shape; arrays and tensors alike."""
    from torchjfa.estimators._jackknife import jackknife_std

    rng = np.random.default_rng(2)
    b = rng.standard_normal((7, 3, 2))  # K = 7 block means of a (3, 2) estimate
    left_out = (b.sum(0) - b) / 6
    want = b.std(0, ddof=1) / np.sqrt(7)
    np.testing.assert_allclose(jackknife_std(left_out).numpy(), want, rtol=1e-12)
    assert torch.equal(jackknife_std(left_out), jackknife_std(torch.from_numpy(left_out)))
    with pytest.raises(ValueError, match="at least 2"):
        jackknife_std(left_out[:1])


def test_the_estimators_jackknife_uses_the_same_formula():
    from torchjfa.estimators._jackknife import jackknife_std

    X, y = _data(n=800)
    folds = kfold_moments(torch.from_numpy(X), torch.from_numpy(y), 5)
    coefs, std = jackknife(OLS(fit_intercept=False), folds)
    assert torch.equal(std, jackknife_std(coefs))
