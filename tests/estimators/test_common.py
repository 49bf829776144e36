"""Interface tests shared by every standard linear estimator.

Each estimator is tried with its hyper-parameter given and, where it has one, chosen by
cross-validation (GCV for ridge).
"""

import math

import pytest
import torch

from torchjfa import Moments, kfold_moments
from torchjfa.estimators import (
    JFA,
    OLS,
    PLS,
    TLS,
    BayesianJFA,
    Lasso,
    LinearEstimator,
    Ridge,
    Stepwise,
)

FACTORIES = {
    "OLS": lambda **kw: OLS(**kw),
    "Ridge": lambda **kw: Ridge(alpha=2.0, **kw),
    "RidgeGCV": lambda **kw: Ridge(n_alphas=30, **kw),
    "TLS": lambda **kw: TLS(**kw),
    "PLS": lambda **kw: PLS(n_components=2, **kw),
    "PLSCV": lambda **kw: PLS(cv=4, **kw),
    "Lasso": lambda **kw: Lasso(alpha=0.05, **kw),
    "LassoCV": lambda **kw: Lasso(n_alphas=20, cv=4, **kw),
    "Stepwise": lambda **kw: Stepwise(**kw),
}
CV = {"PLSCV", "LassoCV"}


def _data(n=80, d=5, seed=0, dtype=torch.float64):
    g = torch.Generator().manual_seed(seed)
    f64 = torch.float64
    X = torch.randn(n, d, generator=g, dtype=f64)
    X = X @ (torch.eye(d, dtype=f64) + 0.3 * torch.randn(d, d, generator=g, dtype=f64)) + 1.5
    coef = torch.tensor([1.0, -2.0, 0.0, 0.5, 0.0], dtype=torch.float64)[:d]
    y = X @ coef + 0.3 + 0.4 * torch.randn(n, generator=g, dtype=torch.float64)
    return X.to(dtype), y.to(dtype)


@pytest.fixture(params=sorted(FACTORIES))
def name(request):
    return request.param


def test_is_a_linear_estimator_and_fit_returns_self(name):
    est = FACTORIES[name]()
    assert isinstance(est, LinearEstimator)
    X, y = _data()
    assert est.fit(X, y) is est
    assert est.coef_.shape == (5,) and est.coef_.dtype == torch.float64
    assert est.intercept_.shape == () and est.n_features_in_ == 5
    pred = est.predict(X)
    assert pred.shape == (80,) and pred.dtype == torch.float64
    torch.testing.assert_close(pred, X @ est.coef_ + est.intercept_)
    # the fit explains most of the variance (signal 1..2, noise 0.4)
    assert float(((y - pred) ** 2).mean()) < 0.5 * float(y.var())


def test_predict_keeps_float32(name):
    X, y = _data()
    est = FACTORIES[name]().fit(X, y)
    X32 = X.to(torch.float32)
    pred = est.predict(X32)
    assert pred.dtype == torch.float32
    torch.testing.assert_close(pred, est.predict(X).to(torch.float32), rtol=1e-5, atol=1e-5)


def test_float32_training_data_is_accumulated_in_float64(name):
    X, y = _data()
    X32, y32 = X.float(), y.float()
    a = FACTORIES[name]().fit(X32, y32)
    b = FACTORIES[name]().fit(X32.double(), y32.double())
    assert a.coef_.dtype == torch.float64
    torch.testing.assert_close(a.coef_, b.coef_, rtol=1e-12, atol=1e-12)


def _chunked(X, y, bounds, weights=None):
    """Moments of rows ``bounds[0]:bounds[-1]`` accumulated in uneven chunks, then added."""
    a, b = bounds
    cuts = [a, a + (b - a) // 3, a + (b - a) // 2, b]
    parts = []
    for lo, hi in zip(cuts[:-1], cuts[1:], strict=True):
        w = None if weights is None else weights[lo:hi]
        m = Moments.zeros(X.shape[1])
        m.update(X[lo : lo + 2], y[lo : lo + 2], None if w is None else w[:2])
        m.update(X[lo + 2 : hi], y[lo + 2 : hi], None if w is None else w[2:])
        parts.append(m)
    return sum(parts[1:], parts[0])


@pytest.mark.parametrize("fit_intercept", [True, False])
def test_fit_equals_fit_moments_of_chunks(name, fit_intercept):
    X, y = _data(n=83)
    w = torch.rand(83, generator=torch.Generator().manual_seed(1), dtype=torch.float64) + 0.5
    direct = FACTORIES[name](fit_intercept=fit_intercept).fit(X, y, weights=w)
    est = FACTORIES[name](fit_intercept=fit_intercept)
    if name in CV:
        k = est.cv
        edges = [round(i * 83 / k) for i in range(k + 1)]
        folds = [_chunked(X, y, (a, b), w) for a, b in zip(edges[:-1], edges[1:], strict=True)]
        est.fit_moments(folds)
        torch.testing.assert_close(est.mse_path_, direct.mse_path_, rtol=1e-9, atol=1e-12)
    else:
        est.fit_moments(_chunked(X, y, (0, 83), w))
    torch.testing.assert_close(est.coef_, direct.coef_, rtol=1e-9, atol=1e-11)
    torch.testing.assert_close(est.intercept_, direct.intercept_, rtol=1e-9, atol=1e-11)
    if hasattr(direct, "alpha_"):  # the default grids are relative to the data: rounding
        assert est.alpha_ == pytest.approx(direct.alpha_, rel=1e-12)
    for attr in ("n_components_", "selected_"):
        if hasattr(direct, attr):
            assert getattr(est, attr) == getattr(direct, attr)
    if not fit_intercept:
        assert float(est.intercept_) == 0.0


def test_cv_estimators_need_folds_from_single_moments(name):
    X, y = _data()
    est = FACTORIES[name]()
    if name in CV:
        with pytest.raises(ValueError, match="needs fold moments"):
            est.fit_moments(Moments.from_data(X, y))
    else:
        assert est.fit_moments(Moments.from_data(X, y)) is est


def test_constant_column_gets_exactly_zero(name):
    X, y = _data()
    X = X.clone()
    X[:, 2] = 4.0  # constant: no information beyond the intercept
    est = FACTORIES[name]().fit(X, y)
    assert float(est.coef_[2]) == 0.0
    assert bool(torch.isfinite(est.coef_).all())
    # without intercept an all-zero column is the uninformative one
    X[:, 2] = 0.0
    est = FACTORIES[name](fit_intercept=False).fit(X, y)
    assert float(est.coef_[2]) == 0.0


def test_duplicated_column_does_not_crash(name):
    X, y = _data()
    X = torch.cat([X, X[:, :1]], dim=1)
    est = FACTORIES[name]().fit(X, y)
    assert bool(torch.isfinite(est.coef_).all())
    assert float(((y - est.predict(X)) ** 2).mean()) < 0.5 * float(y.var())


def _nan_row(X, y):
    X = X.clone()
    X[3] = math.nan
    return X, y


def _inf_entry(X, y):
    y = y.clone()
    y[7] = math.inf
    return X, y


BAD_INPUTS = [
    (_nan_row, r"X has 5 NaN and 0 infinite entries \(first at index \(3, 0\)\)"),
    (_inf_entry, r"y has 0 NaN and 1 infinite entries \(first at index \(7,\)\)"),
    (lambda X, y: (X, y[:-1]), "different numbers of samples: 80 and 79"),
    (lambda X, y: (X[:0], y[:0]), "X has no rows"),
    (lambda X, y: (X[:, 0], y), r"X must be 2-D .* got shape \(80,\)"),
    (lambda X, y: (X[None], y), r"X must be 2-D .* got shape \(1, 80, 5\)"),
    (lambda X, y: (X, torch.stack([y, y], 1)), r"y must be 1-D .* got shape \(80, 2\)"),
    (lambda X, y: (X[:, :0], y), "X has no columns"),
]


@pytest.mark.parametrize("bad", range(len(BAD_INPUTS)))
def test_bad_input_raises_value_error(name, bad):
    make, match = BAD_INPUTS[bad]
    X, y = make(*_data())
    with pytest.raises(ValueError, match=match):
        FACTORIES[name]().fit(X, y)


def test_bad_predict_input_and_unfitted(name):
    est = FACTORIES[name]()
    X, y = _data()
    with pytest.raises(RuntimeError, match="not fitted"):
        est.predict(X)
    est.fit(X, y)
    with pytest.raises(ValueError, match="has 4 features, expected 5"):
        est.predict(X[:, :4])
    with pytest.raises(ValueError, match="NaN"):
        est.predict(torch.full((2, 5), math.nan))
    with pytest.raises(ValueError, match="negative"):
        FACTORIES[name]().fit(X, y, weights=-torch.ones(80))


def test_all_constant_inputs_raise(name):
    X = torch.ones(20, 3, dtype=torch.float64)
    y = torch.arange(20.0, dtype=torch.float64)
    with pytest.raises(ValueError, match="every input column is constant"):
        FACTORIES[name]().fit(X, y)


def test_invalid_cv_and_fit_intercept_raise(name):
    X, y = _data()
    with pytest.raises(ValueError, match="cv must be an integer of at least 2"):
        est = FACTORIES[name]()
        est.cv = 1
        est.fit(X, y)
    with pytest.raises(TypeError, match="fit_intercept must be a bool"):
        FACTORIES[name](fit_intercept="yes").fit(X, y)


def test_repr_round_trips(name):
    est = FACTORIES[name]()
    namespace = {"OLS": OLS, "Ridge": Ridge, "TLS": TLS, "PLS": PLS}
    namespace.update({"Lasso": Lasso, "Stepwise": Stepwise})
    again = eval(repr(est), namespace)  # noqa: S307 - our own repr
    assert repr(again) == repr(est)
    assert type(again) is type(est)


ALL = {
    **FACTORIES,
    "JFA": lambda **kw: JFA(max_iter=200, **kw),
    "BayesianJFA": lambda **kw: BayesianJFA(max_iter=200, **kw),
}


@pytest.mark.parametrize("which", sorted(ALL))
@pytest.mark.parametrize("fit_intercept", [True, False])
def test_fewer_rows_than_parameters_warns_once(which, fit_intercept):
    """4 rows for 5 columns (+ intercept): the moments have rank <= 4, and every estimator
    returns one of infinitely many equally good answers (minimum norm, or everything shrunk:
    Bayesian JFA put ~1e-179 everywhere); it must say so, once per fit, naming the counts."""
    X, y = _data(n=4)
    est = ALL[which](fit_intercept=fit_intercept)
    n_params = 5 + int(fit_intercept)
    with pytest.warns(UserWarning, match=rf"4 rows for {n_params} parameters") as record:
        est.fit(X, y)
    assert len([w for w in record if "rows for" in str(w.message)]) == 1
    assert record[0].filename == __file__  # points at the caller's fit, not the internals
    # from moments too, and not with enough rows
    with pytest.warns(UserWarning, match="cannot determine"):
        ALL[which](fit_intercept=fit_intercept).fit_moments(
            Moments.from_data(X, y) if "CV" not in which else kfold_moments(X, y, 2)
        )
    X, y = _data(n=n_params)
    ALL[which](fit_intercept=fit_intercept).fit(X, y)  # no warning (filterwarnings = error)


@pytest.mark.parametrize("which", ["PLSCV", "LassoCV"])
def test_cross_validation_on_one_row_says_so(which):
    X, y = _data(n=1)
    parameter = "n_components" if which == "PLSCV" else "alpha"
    with pytest.raises(ValueError, match=rf"chooses {parameter} by 4-fold cross-valid.*2 rows"):
        FACTORIES[which](fit_intercept=False).fit(X, y)
