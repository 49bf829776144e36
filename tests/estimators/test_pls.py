"""PLS1 against scikit-learn's PLSRegression, a written-out NIPALS, and brute-force CV."""

import numpy as np
import pytest
import torch
from sklearn.cross_decomposition import PLSRegression

from torchjfa import Moments, kfold_moments
from torchjfa.estimators import OLS, PLS

RTOL = 1e-8


def _problem(n=90, d=7, seed=0, noise=1.0):
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(n, d)) @ rng.normal(size=(d, d)) + rng.uniform(-3, 3, size=d)
    y = X @ rng.normal(size=d) - 2.0 + noise * rng.normal(size=n)
    return X, y


def _assert_rel(actual, expected, rtol=RTOL):
    actual, expected = np.asarray(actual, np.float64), np.asarray(expected, np.float64)
    scale = max(np.abs(expected).max(), 1e-300)
    np.testing.assert_allclose(actual, expected, rtol=rtol, atol=rtol * scale)


def _sk_pls(X, y, k):
    """sklearn's PLS1 coefficients and the equivalent intercept of ``y = X coef + c``."""
    model = PLSRegression(n_components=k, scale=False).fit(X, y)
    coef = model.coef_.ravel()
    intercept = float(model.predict(np.zeros((1, X.shape[1]))).ravel()[0])
    return coef, intercept, model


@pytest.mark.parametrize("k", [1, 2, 4, 7])
def test_pls_matches_sklearn(k):
    X, y = _problem()
    ours = PLS(n_components=k).fit(torch.tensor(X), torch.tensor(y))
    coef, intercept, _ = _sk_pls(X, y, k)
    _assert_rel(ours.coef_, coef)
    _assert_rel(ours.intercept_, intercept)
    assert ours.n_components_ == k


def _nipals_pls1(X, y, k):
    """Textbook NIPALS PLS1 with deflation of the data (no centring)."""
    Xk, yk = X.copy(), y.copy()
    W, P, q = [], [], []
    for _ in range(k):
        w = Xk.T @ yk
        w /= np.linalg.norm(w)
        t = Xk @ w
        tt = t @ t
        p = Xk.T @ t / tt
        qk = yk @ t / tt
        Xk = Xk - np.outer(t, p)
        yk = yk - qk * t
        W.append(w), P.append(p), q.append(qk)
    W, P = np.array(W).T, np.array(P).T
    return W @ np.linalg.solve(P.T @ W, np.array(q))


@pytest.mark.parametrize("k", [1, 3])
def test_pls_without_intercept_matches_nipals(k):
    X, y = _problem(seed=1)
    ours = PLS(n_components=k, fit_intercept=False).fit(torch.tensor(X), torch.tensor(y))
    _assert_rel(ours.coef_, _nipals_pls1(X, y, k))
    assert float(ours.intercept_) == 0.0


def test_pls_with_all_components_is_ols():
    X, y = _problem(seed=2)
    X, y = torch.tensor(X), torch.tensor(y)
    pls = PLS(n_components=7).fit(X, y)
    ols = OLS().fit(X, y)
    torch.testing.assert_close(pls.coef_, ols.coef_, rtol=1e-8, atol=1e-10)


def _fold_bounds(n, n_folds):
    return [round(k * n / n_folds) for k in range(n_folds + 1)]


def test_pls_cv_curve_equals_brute_force_sklearn():
    X, y = _problem(n=70, d=6, seed=3, noise=4.0)
    n_folds = 4
    model = PLS(cv=n_folds).fit(torch.tensor(X), torch.tensor(y))
    mse = model.mse_path_.numpy()
    assert mse.shape == (6, n_folds)
    assert model.n_components_ == int(np.argmin(mse.mean(1))) + 1
    bounds = _fold_bounds(len(y), n_folds)
    ref = np.empty_like(mse)
    for f, (a, b) in enumerate(zip(bounds[:-1], bounds[1:], strict=True)):
        train = np.r_[0:a, b : len(y)]
        for k in range(1, 7):
            sk = PLSRegression(n_components=k, scale=False).fit(X[train], y[train])
            ref[k - 1, f] = np.mean((y[a:b] - sk.predict(X[a:b]).ravel()) ** 2)
    np.testing.assert_allclose(mse, ref, rtol=RTOL)
    # the final model is sklearn's with the chosen number of components, on all rows
    coef, intercept, _ = _sk_pls(X, y, model.n_components_)
    _assert_rel(model.coef_, coef)
    _assert_rel(model.intercept_, intercept)


def test_pls_cv_max_components_and_verbose(capsys):
    X, y = _problem(n=60, d=6, seed=4)
    model = PLS(max_components=3, verbose=True).fit(torch.tensor(X), torch.tensor(y))
    assert model.mse_path_.shape == (3, 5)
    assert 1 <= model.n_components_ <= 3
    assert "PLS CV" in capsys.readouterr().err


def test_pls_stops_early_when_fit_is_exact():
    # y lies in the span of the first Krylov direction: one component is already exact
    rng = np.random.default_rng(5)
    X = rng.normal(size=(40, 2))
    X[:, 1] -= X[:, 1] @ X[:, 0] / (X[:, 0] @ X[:, 0]) * X[:, 0]  # orthogonal columns
    y = 3.0 * X[:, 0]
    model = PLS(n_components=2, fit_intercept=False).fit(torch.tensor(X), torch.tensor(y))
    assert model.n_components_ == 1
    _assert_rel(model.coef_, [3.0, 0.0])


def test_pls_single_moments_needs_given_components():
    X, y = _problem(seed=6)
    m = Moments.from_data(torch.tensor(X), torch.tensor(y))
    with pytest.raises(ValueError, match="needs fold moments"):
        PLS().fit_moments(m)
    a = PLS(n_components=2).fit_moments(m)
    b = PLS(n_components=2).fit(torch.tensor(X), torch.tensor(y))
    torch.testing.assert_close(a.coef_, b.coef_)
    folds = kfold_moments(torch.tensor(X), torch.tensor(y), 5)
    torch.testing.assert_close(
        PLS().fit_moments(folds).coef_, PLS().fit(torch.tensor(X), torch.tensor(y)).coef_
    )


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda: PLS(n_components=0), "n_components must be between 1 and the number of inputs"),
        (lambda: PLS(n_components=8), r"n_components must be between 1 and .* \(7\), got 8"),
        (lambda: PLS(n_components=2.5), "n_components must be an integer"),
        (lambda: PLS(max_components=0), "max_components must be between 1"),
        (lambda: PLS(cv=1), "cv must be an integer of at least 2"),
    ],
)
def test_invalid_hyper_parameters_raise_at_fit(make, match):
    X, y = _problem()
    with pytest.raises(ValueError, match=match):
        make().fit(torch.tensor(X), torch.tensor(y))
