"""OLS, Ridge and TLS against scikit-learn, an SVD of [X y], and written-out GCV."""

import numpy as np
import pytest
import torch
from sklearn.linear_model import LinearRegression
from sklearn.linear_model import Ridge as SkRidge

from torchjfa import Moments
from torchjfa.estimators import OLS, TLS, Ridge

RTOL = 1e-8


def _problem(n=120, d=6, seed=0, noise=0.5):
    """Correlated, differently scaled inputs with an offset; numpy float64."""
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(n, d)) @ rng.normal(size=(d, d)) * rng.uniform(0.1, 10, size=d) + 2.0
    coef = rng.normal(size=d)
    y = X @ coef + 1.5 + noise * rng.normal(size=n)
    return X, y


def _assert_rel(actual, expected, rtol=RTOL):
    actual = np.asarray(actual, dtype=np.float64)
    expected = np.asarray(expected, dtype=np.float64)
    scale = max(np.abs(expected).max(), 1e-300)
    np.testing.assert_allclose(actual, expected, rtol=rtol, atol=rtol * scale)


@pytest.mark.parametrize("fit_intercept", [True, False])
def test_ols_matches_sklearn(fit_intercept):
    X, y = _problem()
    ours = OLS(fit_intercept=fit_intercept).fit(torch.tensor(X), torch.tensor(y))
    ref = LinearRegression(fit_intercept=fit_intercept).fit(X, y)
    _assert_rel(ours.coef_, ref.coef_)
    _assert_rel(ours.intercept_, ref.intercept_ if fit_intercept else 0.0)
    assert ours.rank_ == X.shape[1]


@pytest.mark.parametrize("fit_intercept", [True, False])
@pytest.mark.parametrize("alpha", [1e-3, 1.0, 250.0])
def test_ridge_fixed_alpha_matches_sklearn(alpha, fit_intercept):
    X, y = _problem(seed=1)
    ours = Ridge(alpha=alpha, fit_intercept=fit_intercept).fit(torch.tensor(X), torch.tensor(y))
    ref = SkRidge(alpha=alpha, fit_intercept=fit_intercept, solver="svd").fit(X, y)
    _assert_rel(ours.coef_, ref.coef_)
    _assert_rel(ours.intercept_, ref.intercept_ if fit_intercept else 0.0)
    assert ours.alpha_ == alpha


def test_weighted_ridge_matches_sklearn_sample_weight():
    X, y = _problem(seed=2)
    w = np.random.default_rng(3).uniform(0.0, 3.0, size=len(y))
    ours = Ridge(alpha=5.0).fit(torch.tensor(X), torch.tensor(y), weights=torch.tensor(w))
    ref = SkRidge(alpha=5.0, solver="svd").fit(X, y, sample_weight=w)
    _assert_rel(ours.coef_, ref.coef_)
    _assert_rel(ours.intercept_, ref.intercept_)
    # and weighted OLS against sklearn too
    ols = OLS().fit(torch.tensor(X), torch.tensor(y), weights=torch.tensor(w))
    ref = LinearRegression().fit(X, y, sample_weight=w)
    _assert_rel(ols.coef_, ref.coef_)
    _assert_rel(ols.intercept_, ref.intercept_)


def test_ridge_alpha_zero_is_ols():
    X, y = _problem(seed=4)
    X, y = torch.tensor(X), torch.tensor(y)
    torch.testing.assert_close(Ridge(alpha=0.0).fit(X, y).coef_, OLS().fit(X, y).coef_)


def _brute_force_gcv(X, y, alphas, fit_intercept):
    """GCV of sklearn ridge fits, with the hat matrix written out on the raw rows."""
    n = len(y)
    Xc = X - X.mean(0) if fit_intercept else X
    out = []
    for a in alphas:
        model = SkRidge(alpha=a, fit_intercept=fit_intercept, solver="svd").fit(X, y)
        rss = np.sum((y - model.predict(X)) ** 2)
        hat = Xc @ np.linalg.solve(Xc.T @ Xc + a * np.eye(X.shape[1]), Xc.T)
        trace = np.trace(hat) + (1.0 if fit_intercept else 0.0)
        out.append((rss / n) / (1 - trace / n) ** 2)
    return np.array(out)


@pytest.mark.parametrize("fit_intercept", [True, False])
def test_ridge_gcv_curve_equals_brute_force(fit_intercept):
    X, y = _problem(n=60, d=8, seed=5, noise=3.0)
    model = Ridge(fit_intercept=fit_intercept, n_alphas=40).fit(torch.tensor(X), torch.tensor(y))
    gcv = model.gcv_.numpy()
    assert gcv.shape == (40,)
    assert model.alpha_ == float(model.alphas_[int(np.argmin(gcv))])
    ref = _brute_force_gcv(X, y, model.alphas_.numpy(), fit_intercept)
    np.testing.assert_allclose(gcv, ref, rtol=RTOL)
    # the chosen model is sklearn's ridge at alpha_
    sk = SkRidge(alpha=model.alpha_, fit_intercept=fit_intercept, solver="svd").fit(X, y)
    _assert_rel(model.coef_, sk.coef_)


def test_ridge_gcv_user_grid_and_single_moments():
    X, y = _problem(n=50, d=4, seed=6, noise=5.0)
    grid = [1e-2, 1e-1, 1.0, 10.0, 100.0, 1e3]
    model = Ridge(alphas=grid).fit_moments(Moments.from_data(torch.tensor(X), torch.tensor(y)))
    ref = _brute_force_gcv(X, y, grid, True)
    np.testing.assert_allclose(model.gcv_.numpy(), ref, rtol=RTOL)
    assert model.alpha_ == grid[int(np.argmin(ref))]


def test_ols_rank_deficient_duplicated_column():
    X, y = _problem(n=80, d=4, seed=7)
    Xd = np.column_stack([X, X[:, 1]])  # column 4 duplicates column 1
    model = OLS().fit(torch.tensor(Xd), torch.tensor(y))
    assert model.rank_ == 4
    # the minimum-norm least-squares solution of the centred problem, written out
    Xc, yc = Xd - Xd.mean(0), y - y.mean()
    ref = np.linalg.lstsq(Xc, yc, rcond=None)[0]
    _assert_rel(model.coef_, ref)
    assert abs(float(model.coef_[1] - model.coef_[4])) < 1e-10 * abs(ref[1])
    # same predictions as the full-rank fit without the duplicate
    full = LinearRegression().fit(X, y)
    np.testing.assert_allclose(model.predict(torch.tensor(Xd)).numpy(), full.predict(X), rtol=1e-9)


def _tls_reference(X, y, fit_intercept):
    """TLS from the SVD of the stacked [X y] (centred when fitting an intercept)."""
    Z = np.column_stack([X, y])
    mean = Z.mean(0) if fit_intercept else np.zeros(Z.shape[1])
    v = np.linalg.svd(Z - mean)[2][-1]
    coef = -v[:-1] / v[-1]
    return coef, mean[-1] - mean[:-1] @ coef


@pytest.mark.parametrize("fit_intercept", [True, False])
def test_tls_matches_svd_of_stacked_data(fit_intercept):
    rng = np.random.default_rng(8)
    X = rng.normal(size=(150, 3)) + 1.0
    y = X @ np.array([1.0, -2.0, 0.5]) + 0.3 + 0.2 * rng.normal(size=150)
    model = TLS(fit_intercept=fit_intercept).fit(torch.tensor(X), torch.tensor(y))
    coef, intercept = _tls_reference(X, y, fit_intercept)
    _assert_rel(model.coef_, coef)
    _assert_rel(model.intercept_, intercept)
    sigma_min = np.linalg.svd(
        np.column_stack([X, y]) - (np.column_stack([X, y]).mean(0) if fit_intercept else 0)
    )[1][-1]
    np.testing.assert_allclose(model.noise_variance_, sigma_min**2 / 150, rtol=1e-8)


def test_tls_beats_ols_with_equal_input_and_output_noise():
    rng = np.random.default_rng(9)
    n, truth = 3000, np.array([1.0, -1.5, 2.0])
    X_true = rng.normal(size=(n, 3))
    y = X_true @ truth + 0.6 * rng.normal(size=n)
    X = X_true + 0.6 * rng.normal(size=(n, 3))
    tls = TLS().fit(torch.tensor(X), torch.tensor(y))
    ols = OLS().fit(torch.tensor(X), torch.tensor(y))
    err_tls = np.linalg.norm(tls.coef_.numpy() - truth)
    err_ols = np.linalg.norm(ols.coef_.numpy() - truth)
    # OLS is attenuated by 1 / (1 + 0.36) (error ~0.7); TLS is consistent
    assert err_ols > 0.5
    assert err_tls < 0.25 * err_ols


def test_tls_degenerate_raises():
    # y is orthogonal to x and varies more: the smallest singular direction is x itself
    X = torch.tensor([[1.0], [-1.0], [1.0], [-1.0]], dtype=torch.float64)
    y = torch.tensor([2.0, 2.0, -2.0, -2.0], dtype=torch.float64)
    with pytest.raises(ValueError, match="TLS is degenerate"):
        TLS().fit(X, y)


def test_tls_repeated_singular_value_gives_minimum_norm_solution():
    # two orthogonal inputs and y of the same spread: every direction of [X y] is a minimiser;
    # the minimum-norm coefficient is 0
    X = torch.tensor([[1.0, 1.0], [1.0, -1.0], [-1.0, 1.0], [-1.0, -1.0]], dtype=torch.float64)
    y = torch.tensor([1.0, -1.0, -1.0, 1.0], dtype=torch.float64)
    torch.testing.assert_close(TLS().fit(X, y).coef_, torch.zeros(2, dtype=torch.float64))


def test_tls_with_duplicated_input_skips_the_exact_collinearity():
    # [x1, x1] spans the direction of sqrt(2) x1 with orthogonal distances measured along it, so
    # TLS on [x1, x2, x3, x1] equals TLS on [sqrt(2) x1, x2, x3] with the coefficient split evenly
    rng = np.random.default_rng(10)
    X = rng.normal(size=(200, 3))
    y = X @ np.array([1.0, -2.0, 0.5]) + 0.3 * rng.normal(size=200)
    scaled = X * np.array([np.sqrt(2.0), 1.0, 1.0])
    base, _ = _tls_reference(scaled, y, fit_intercept=True)
    dup = TLS().fit(torch.tensor(np.column_stack([X, X[:, 0]])), torch.tensor(y))
    coef = dup.coef_.numpy()
    np.testing.assert_allclose(coef[0], coef[3], rtol=1e-8)
    np.testing.assert_allclose(coef[0] + coef[3], np.sqrt(2.0) * base[0], rtol=1e-8)
    np.testing.assert_allclose(coef[1:3], base[1:], rtol=1e-8)


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda: Ridge(alpha=-1.0), "alpha must be finite and non-negative"),
        (lambda: Ridge(alpha=float("nan")), "alpha must be finite"),
        (lambda: Ridge(alphas=[1.0, -2.0]), "alphas must be a non-empty sequence of positive"),
        (lambda: Ridge(n_alphas=0), "n_alphas must be a positive integer"),
        (lambda: OLS(rcond=0.0), "rcond must be finite and positive"),
    ],
)
def test_invalid_hyper_parameters_raise_at_fit(make, match):
    X, y = _problem(n=20, d=3)
    est = make()  # construction never fails
    with pytest.raises(ValueError, match=match):
        est.fit(torch.tensor(X), torch.tensor(y))
