"""Stepwise selection: the right inputs, F statistics against written-out RSS ratios and scipy."""

import numpy as np
import pytest
import scipy.special
import scipy.stats
import torch
from sklearn.linear_model import LinearRegression

from torchjfa.estimators import Stepwise
from torchjfa.estimators._stepwise import f_sf


def _sparse_problem(n=200, seed=0):
    """3 relevant inputs (columns 2, 5, 8) among 10, mildly correlated."""
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(n, 10)) @ (np.eye(10) + 0.2 * rng.normal(size=(10, 10))) + 0.5
    coef = np.zeros(10)
    coef[[2, 5, 8]] = [1.5, -1.0, 0.7]
    y = X @ coef + 2.0 + 0.5 * rng.normal(size=n)
    return X, y


def _rss(X, y, cols, fit_intercept=True):
    """RSS of least squares on the columns ``cols``, from the raw rows."""
    if not cols:
        return np.sum((y - (y.mean() if fit_intercept else 0.0)) ** 2)
    model = LinearRegression(fit_intercept=fit_intercept).fit(X[:, cols], y)
    return np.sum((y - model.predict(X[:, cols])) ** 2)


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_forward_selection_finds_the_relevant_inputs(seed):
    X, y = _sparse_problem(seed=seed)
    # a strict threshold: at 0.05 one of the 7 irrelevant inputs enters ~30% of the time
    model = Stepwise(p_enter=1e-3).fit(torch.tensor(X), torch.tensor(y))
    assert sorted(model.selected_) == [2, 5, 8]
    # coefficients are least squares on the selected inputs, zero elsewhere
    ref = LinearRegression().fit(X[:, model.selected_], y)
    coef = model.coef_.numpy()
    np.testing.assert_allclose(coef[model.selected_], ref.coef_, rtol=1e-9)
    assert np.all(np.delete(coef, model.selected_) == 0)
    np.testing.assert_allclose(float(model.intercept_), ref.intercept_, rtol=1e-9)


@pytest.mark.parametrize("fit_intercept", [True, False])
def test_entry_statistics_equal_partial_f_tests(fit_intercept):
    X, y = _sparse_problem(n=120, seed=3)
    n = len(y)
    model = Stepwise(p_enter=0.2, fit_intercept=fit_intercept).fit(torch.tensor(X), torch.tensor(y))
    assert len(model.steps_) >= 3
    current: list[int] = []
    for action, j, f, p in model.steps_:
        assert action == "enter"
        before = _rss(X, y, current, fit_intercept)
        after = _rss(X, y, current + [j], fit_intercept)
        dfd = n - len(current) - 1 - int(fit_intercept)
        f_ref = (before - after) / (after / dfd)
        np.testing.assert_allclose(f, f_ref, rtol=1e-8)
        np.testing.assert_allclose(p, scipy.stats.f.sf(f_ref, 1, dfd), rtol=1e-7)
        # the entered input has the largest F among the candidates
        others = [k for k in range(10) if k not in current + [j]]
        assert all(_rss(X, y, current + [k], fit_intercept) >= after - 1e-9 for k in others)
        current.append(j)
    assert current == model.selected_
    # the next candidate's p-value is not below p_enter (that is why selection stopped)
    dfd = n - len(current) - 1 - int(fit_intercept)
    best = min(_rss(X, y, current + [k], fit_intercept) for k in range(10) if k not in current)
    rss = _rss(X, y, current, fit_intercept)
    assert scipy.stats.f.sf((rss - best) / (best / dfd), 1, dfd) >= 0.2


def test_bidirectional_removes_an_input_made_redundant():
    # x0 = x1 + x2 + noise enters first, then x1 and x2 make it redundant
    rng = np.random.default_rng(0)
    n = 200
    x1, x2 = rng.normal(size=(2, n))
    X = np.column_stack([x1 + x2 + 0.5 * rng.normal(size=n), x1, x2, rng.normal(size=(n, 3))])
    y = x1 + x2 + 0.5 * rng.normal(size=n)
    forward = Stepwise().fit(torch.tensor(X), torch.tensor(y))
    assert forward.selected_[0] == 0 and sorted(forward.selected_) == [0, 1, 2]
    both = Stepwise(p_remove=0.1).fit(torch.tensor(X), torch.tensor(y))
    assert sorted(both.selected_) == [1, 2]
    removal = [s for s in both.steps_ if s[0] == "remove"]
    assert [s[1] for s in removal] == [0]
    f_ref = (_rss(X, y, [1, 2]) - _rss(X, y, [0, 1, 2])) / (_rss(X, y, [0, 1, 2]) / (n - 4))
    np.testing.assert_allclose(removal[0][2], f_ref, rtol=1e-8)
    np.testing.assert_allclose(removal[0][3], scipy.stats.f.sf(f_ref, 1, n - 4), rtol=1e-7)
    assert both.coef_[0] == 0


def test_max_features_and_nothing_selected():
    X, y = _sparse_problem(seed=4)
    model = Stepwise(max_features=2).fit(torch.tensor(X), torch.tensor(y))
    assert len(model.selected_) == 2
    # y unrelated to X: nothing enters at a strict threshold, the model is the mean
    rng = np.random.default_rng(5)
    y = rng.normal(size=len(y))
    model = Stepwise(p_enter=1e-6).fit(torch.tensor(X), torch.tensor(y))
    assert model.selected_ == []
    assert bool((model.coef_ == 0).all())
    np.testing.assert_allclose(float(model.intercept_), y.mean(), rtol=1e-12)


@pytest.mark.parametrize("dfd", [1.0, 3.0, 12.0, 250.0, 1e4])
def test_f_survival_function_matches_scipy(dfd):
    f = np.array([0.0, 1e-6, 0.05, 0.7, 1.0, 2.5, 8.0, 40.0, 300.0])
    for dfn in (1.0, 2.0, 5.0):
        ours = f_sf(torch.tensor(f, dtype=torch.float64), dfn, dfd).numpy()
        np.testing.assert_allclose(ours, scipy.stats.f.sf(f, dfn, dfd), rtol=1e-10, atol=1e-300)
    # and the incomplete beta identity it rests on
    x = dfd / (dfd + f[1:])
    np.testing.assert_allclose(
        f_sf(torch.tensor(f[1:]), 1.0, dfd).numpy(),
        scipy.special.betainc(dfd / 2, 0.5, x),
        rtol=1e-10,
    )


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda: Stepwise(p_enter=0.0), r"p_enter must be in the open interval \(0, 1\)"),
        (lambda: Stepwise(p_enter=1.0), r"p_enter must be in the open interval \(0, 1\)"),
        (lambda: Stepwise(p_enter=-0.5), r"p_enter must be in the open interval \(0, 1\)"),
        (lambda: Stepwise(p_remove=1.5), r"p_remove must be in the open interval \(0, 1\)"),
        (lambda: Stepwise(p_enter=0.1, p_remove=0.05), "p_remove .* must be larger than p_enter"),
        (lambda: Stepwise(max_features=0), "max_features must be a positive integer"),
    ],
)
def test_invalid_hyper_parameters_raise_at_fit(make, match):
    X, y = _sparse_problem(n=30)
    with pytest.raises(ValueError, match=match):
        make().fit(torch.tensor(X), torch.tensor(y))
