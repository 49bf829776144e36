"""Lasso against scikit-learn's Lasso, the optimality conditions, and brute-force CV."""

import warnings

import numpy as np
import pytest
import torch
from sklearn.linear_model import Lasso as SkLasso

from torchjfa import Moments, kfold_moments
from torchjfa.estimators import Lasso

RTOL = 1e-8


def _problem(n=100, d=10, seed=0, noise=0.5):
    """Three relevant inputs among ``d`` correlated ones, with an offset."""
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(n, d)) @ (np.eye(d) + 0.3 * rng.normal(size=(d, d))) + 1.0
    coef = np.zeros(d)
    coef[:3] = [2.0, -1.0, 0.5]
    y = X @ coef + 0.7 + noise * rng.normal(size=n)
    return X, y


def _assert_rel(actual, expected, rtol=RTOL):
    actual, expected = np.asarray(actual, np.float64), np.asarray(expected, np.float64)
    scale = max(np.abs(expected).max(), 1e-300)
    np.testing.assert_allclose(actual, expected, rtol=rtol, atol=rtol * scale)


def _sk_lasso(alpha, fit_intercept=True):
    return SkLasso(alpha=alpha, fit_intercept=fit_intercept, tol=1e-12, max_iter=1_000_000)


@pytest.mark.parametrize("fit_intercept", [True, False])
@pytest.mark.parametrize("alpha", [1e-3, 0.02, 0.3])
def test_lasso_matches_sklearn(alpha, fit_intercept):
    X, y = _problem()
    ours = Lasso(alpha=alpha, fit_intercept=fit_intercept).fit(torch.tensor(X), torch.tensor(y))
    ref = _sk_lasso(alpha, fit_intercept).fit(X, y)
    _assert_rel(ours.coef_, ref.coef_)
    _assert_rel(ours.intercept_, ref.intercept_ if fit_intercept else 0.0)
    # the same zeros, exactly
    np.testing.assert_array_equal(ours.coef_.numpy() == 0, ref.coef_ == 0)


def test_weighted_lasso_matches_sklearn_sample_weight():
    X, y = _problem(seed=1)
    w = np.random.default_rng(2).uniform(0.0, 2.0, size=len(y))
    ours = Lasso(alpha=0.05).fit(torch.tensor(X), torch.tensor(y), weights=torch.tensor(w))
    ref = _sk_lasso(0.05).fit(X, y, sample_weight=w)
    _assert_rel(ours.coef_, ref.coef_)
    _assert_rel(ours.intercept_, ref.intercept_)


@pytest.mark.parametrize("alpha", [1e-4, 0.01, 0.1])
def test_lasso_satisfies_optimality_conditions(alpha):
    X, y = _problem(seed=3, d=12)
    model = Lasso(alpha=alpha).fit(torch.tensor(X), torch.tensor(y))
    b = model.coef_.numpy()
    n = len(y)
    grad = X.T @ (y - X @ b - float(model.intercept_)) / n  # minus the smooth gradient
    active = b != 0
    np.testing.assert_allclose(grad[active], alpha * np.sign(b[active]), rtol=1e-9, atol=1e-12)
    assert np.all(np.abs(grad[~active]) <= alpha * (1 + 1e-9))
    assert abs(np.sum(y - X @ b - float(model.intercept_))) < 1e-9 * n  # intercept optimal


def test_lasso_cv_curve_equals_brute_force_sklearn():
    X, y = _problem(n=80, d=6, seed=4, noise=1.0)
    n_folds, n_alphas = 4, 15
    model = Lasso(cv=n_folds, n_alphas=n_alphas).fit(torch.tensor(X), torch.tensor(y))
    mse, alphas = model.mse_path_.numpy(), model.alphas_.numpy()
    assert mse.shape == (n_alphas, n_folds)
    # the grid: from max |Xc^T yc| / n down by eps = 1e-3, geometrically
    Xc, yc = X - X.mean(0), y - y.mean()
    alpha_max = np.abs(Xc.T @ yc).max() / len(y)
    np.testing.assert_allclose(alphas, np.geomspace(alpha_max, 1e-3 * alpha_max, n_alphas))
    assert model.alpha_ == alphas[int(np.argmin(mse.mean(1)))]
    bounds = [round(k * len(y) / n_folds) for k in range(n_folds + 1)]
    ref = np.empty_like(mse)
    for f, (a, b) in enumerate(zip(bounds[:-1], bounds[1:], strict=True)):
        train = np.r_[0:a, b : len(y)]
        for i, alpha in enumerate(alphas):
            sk = _sk_lasso(alpha).fit(X[train], y[train])
            ref[i, f] = np.mean((y[a:b] - sk.predict(X[a:b])) ** 2)
    np.testing.assert_allclose(mse, ref, rtol=RTOL)
    final = _sk_lasso(model.alpha_).fit(X, y)
    _assert_rel(model.coef_, final.coef_)
    _assert_rel(model.intercept_, final.intercept_)


def test_lasso_user_grid_and_fold_moments():
    X, y = _problem(seed=5)
    folds = kfold_moments(torch.tensor(X), torch.tensor(y), 3)
    model = Lasso(alphas=[0.01, 0.3, 0.1]).fit_moments(folds)
    np.testing.assert_array_equal(model.alphas_.numpy(), [0.3, 0.1, 0.01])  # sorted down
    assert model.alpha_ in (0.3, 0.1, 0.01)
    ref = _sk_lasso(model.alpha_).fit(X, y)
    _assert_rel(model.coef_, ref.coef_)


def test_alpha_at_or_above_alpha_max_gives_zero_coefficients():
    X, y = _problem(seed=6)
    Xc, yc = X - X.mean(0), y - y.mean()
    alpha_max = np.abs(Xc.T @ yc).max() / len(y)
    model = Lasso(alpha=alpha_max * 1.0001).fit(torch.tensor(X), torch.tensor(y))
    assert bool((model.coef_ == 0).all())
    np.testing.assert_allclose(float(model.intercept_), y.mean(), rtol=1e-12)
    model = Lasso(alpha=alpha_max * 0.99).fit(torch.tensor(X), torch.tensor(y))
    assert int((model.coef_ != 0).sum()) == 1


def test_lasso_single_moments_needs_alpha_and_progress_bar(capsys):
    X, y = _problem(seed=7)
    m = Moments.from_data(torch.tensor(X), torch.tensor(y))
    with pytest.raises(ValueError, match="needs fold moments"):
        Lasso().fit_moments(m)
    Lasso(n_alphas=5, verbose=True).fit(torch.tensor(X), torch.tensor(y))
    assert "lasso path" in capsys.readouterr().err


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda: Lasso(alpha=-0.1), "alpha must be finite and positive"),
        (lambda: Lasso(alpha=0.0), "alpha must be finite and positive"),
        (lambda: Lasso(alphas=[0.1, 0.0]), "alphas must be a non-empty sequence of positive"),
        (lambda: Lasso(n_alphas=0), "n_alphas must be a positive integer"),
        (lambda: Lasso(eps=2.0), r"eps must be in \(0, 1\)"),
        (lambda: Lasso(alpha=0.1, tol=-1.0), "tol must be finite and positive"),
        (lambda: Lasso(alpha=0.1, max_iter=0), "max_iter must be a positive integer"),
    ],
)
def test_invalid_hyper_parameters_raise_at_fit(make, match):
    X, y = _problem(n=30, d=4)
    with pytest.raises(ValueError, match=match):
        make().fit(torch.tensor(X), torch.tensor(y))


def test_duality_gap_from_moments_equals_primal_minus_dual_on_rows():
    from torchjfa.estimators._lasso import _duality_gap

    rng = np.random.default_rng(21)
    X = rng.normal(size=(80, 6))
    y = X @ rng.normal(size=6) + rng.normal(size=80)
    b = rng.normal(size=6) * 0.3
    for lam in (0.5, 5.0, 500.0):  # scaled dual point, and the unscaled case
        r = y - X @ b
        const = min(1.0, lam / np.abs(X.T @ r).max())
        primal = 0.5 * r @ r + lam * np.abs(b).sum()
        dual = const * r @ y - 0.5 * const**2 * r @ r
        gap = _duality_gap(
            (X.T @ y)[None], b[None], (X.T @ r)[None], np.array([lam]), np.array([y @ y])
        )
        np.testing.assert_allclose(gap[0], primal - dual, rtol=1e-10)
        assert gap[0] >= -1e-9


def test_exactly_collinear_inputs_reach_scikit_learns_objective():
    rng = np.random.default_rng(22)
    X = rng.normal(size=(300, 4))
    X = np.column_stack([X, X @ np.array([0.5, 0.5, 0.0, 0.0])])  # exact convex combination
    y = X[:, :4] @ np.array([1.0, 2.0, 0.0, -1.0]) + 0.1 * rng.normal(size=300)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no non-convergence warning
        model = Lasso(alpha=0.01, max_iter=2000).fit(torch.tensor(X), torch.tensor(y))
    ref = _sk_lasso(0.01).fit(X, y)
    objective = lambda c, i: 0.5 / 300 * np.sum((y - X @ c - i) ** 2) + 0.01 * np.abs(c).sum()  # noqa: E731
    ours = objective(model.coef_.numpy(), float(model.intercept_))
    assert ours <= objective(ref.coef_, ref.intercept_) * (1 + 1e-5)
