"""Estimators by name (`make`, `register`, `available`) and the public fold protocol
(`LinearEstimator.needs_folds`, ``cv``): the command line's names make the command line's
estimators, and a third-party estimator registered by name gets fold moments from the flow."""

import pytest
import torch
from _flow import fit_logs
from _robots import TWO_LINK

from torchjfa import Moments, cli, estimators
from torchjfa.dynamics import RigidBodyModel
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
    _registry,
    jackknife,
)
from torchjfa.identification import stream_moments


@pytest.fixture
def registry(monkeypatch):
    """The registry as shipped, restored after the test (registering is process-wide)."""
    monkeypatch.setattr(_registry, "_FACTORIES", dict(_registry._FACTORIES))


def test_available_names_are_the_command_lines():
    assert estimators.available() == cli.ESTIMATORS


# what ``torchjfa identify --estimator NAME --max-iter 123 --ard output`` built before the
# command line called `make` (cli._estimator, written out)
CLI_BUILT = {
    "bayes-jfa": lambda: BayesianJFA(max_iter=123, ard="output", fit_intercept=False),
    "jfa": lambda: JFA(max_iter=123, fit_intercept=False),
    "ols": lambda: OLS(fit_intercept=False),
    "ridge": lambda: Ridge(fit_intercept=False),
    "tls": lambda: TLS(fit_intercept=False),
    "pls": lambda: PLS(fit_intercept=False),
    "lasso": lambda: Lasso(fit_intercept=False),
    "stepwise": lambda: Stepwise(fit_intercept=False),
}


@pytest.mark.parametrize("name", cli.ESTIMATORS)
def test_make_builds_what_the_command_line_builds(name):
    expected = CLI_BUILT[name]()
    extra = {"bayes-jfa": {"max_iter": 123, "ard": "output"}, "jfa": {"max_iter": 123}}
    made = estimators.make(name, fit_intercept=False, **extra.get(name, {}))
    assert type(made) is type(expected)
    assert vars(made) == vars(expected)
    assert made is not estimators.make(name, fit_intercept=False)  # a new one each call


@pytest.mark.parametrize(
    "name, options, cls",
    [
        ("ridge", {"alpha": 0.5}, Ridge),
        ("lasso", {"alpha": 0.2, "cv": 3, "max_iter": 50}, Lasso),
        ("pls", {"n_components": 2, "fit_intercept": False}, PLS),
        ("stepwise", {"p_enter": 0.01}, Stepwise),
        ("tls", {"fit_intercept": False}, TLS),
        ("bayes-jfa", {"a0": 2.0, "method": "em"}, BayesianJFA),
        ("jfa", {"tol": 1e-9}, JFA),
    ],
)
def test_make_applies_options(name, options, cls):
    est = estimators.make(name, **options)
    assert type(est) is cls
    for key, value in options.items():
        assert getattr(est, key) == value, key
    # the options left out keep the class's defaults
    defaults = cls()
    for key in set(vars(defaults)) - set(options):
        assert getattr(est, key) == getattr(defaults, key), key


def test_make_unknown_name_or_option():
    with pytest.raises(ValueError, match=r"unknown estimator 'olss'; available: bayes-jfa, jfa"):
        estimators.make("olss")
    with pytest.raises(ValueError, match=r"'ridge' has no option 'n_components'.*alpha"):
        estimators.make("ridge", n_components=3)
    with pytest.raises(ValueError, match=r"has no option 'bogus', 'other'"):
        estimators.make("ols", other=1, bogus=2)
    # a known option with a bad value is the estimator's own error, at fit time
    bad = estimators.make("lasso", alpha=-1.0)
    with pytest.raises(ValueError, match="alpha must be finite and positive"):
        bad.fit(torch.randn(20, 2, dtype=torch.float64), torch.randn(20, dtype=torch.float64))


class FoldAveragedOLS(LinearEstimator):
    """A third-party estimator written against the public protocol only: it needs fold moments
    (the average of the least-squares fits that leave out one fold each) and records the
    folds it was given."""

    def __init__(self, *, cv: int = 4, fit_intercept: bool = False) -> None:
        super().__init__(fit_intercept=fit_intercept, cv=cv)

    @property
    def needs_folds(self) -> bool:
        return True

    def _solve(self, moments, folds):
        self.seen_folds_ = list(folds)
        coefs = []
        for fold in folds:
            sxx, sxy, _ = (moments - fold).second_moments(center=self.fit_intercept)
            coefs.append(torch.linalg.pinv(sxx, rtol=1e-12, hermitian=True) @ sxy)
        return torch.stack(coefs).mean(0)


def _two_link_log(n=600, seed=0):
    model = RigidBodyModel.from_urdf(TWO_LINK)
    g = torch.Generator().manual_seed(seed)
    q, qd, qdd = (torch.randn(n, 2, generator=g, dtype=torch.float64) for _ in range(3))
    tau = model.regressor(q, qd, qdd) @ model.nominal_theta
    tau = tau + 0.01 * torch.randn(n, 2, generator=g, dtype=torch.float64)
    return model, {"q": q, "qd": qd, "qdd": qdd, "tau": tau}


def test_registered_estimator_gets_fold_moments_through_identify(registry):
    assert estimators.register("fold-ols", FoldAveragedOLS) is FoldAveragedOLS
    assert estimators.available()[-1] == "fold-ols"
    model, log = _two_link_log()
    result = fit_logs(model, log, estimator=estimators.make("fold-ols", cv=3), project=False)
    seen = result.estimator.seen_folds_
    assert len(seen) == 3  # cv folds, not one Moments
    # contiguous blocks of 200 samples x 2 joints, cut by hand from the regressor
    Y = model.regressor(log["q"], log["qd"], log["qdd"])
    active = Y.reshape(-1, model.n_params).abs().amax(0) > 0  # the columns the estimator sees
    for k, fold in enumerate(seen):
        a, b = 200 * k, 200 * (k + 1)
        ref = Moments.from_data(Y[a:b].reshape(-1, model.n_params), log["tau"][a:b].reshape(-1))
        assert fold.n_rows == ref.n_rows == 400
        torch.testing.assert_close(fold.xtx, ref.xtx[active][:, active], rtol=1e-12, atol=0)
    # the flow's answer is the estimator's own on the folds streamed by hand
    direct = FoldAveragedOLS(cv=3).fit_moments(stream_moments(model, log, n_folds=3))
    torch.testing.assert_close(result.theta_hat, direct.coef_, rtol=1e-12, atol=1e-12)
    # the jackknife gives it the K - 1 remaining folds each time
    folds = stream_moments(model, log, n_folds=4)
    coefs, _ = jackknife(estimators.make("fold-ols"), folds)
    assert coefs.shape == (4, model.n_params)
    assert torch.equal(coefs[0], FoldAveragedOLS().fit_moments(folds[1:]).coef_)


def test_register_errors(registry):
    with pytest.raises(ValueError, match="'ols' is already registered"):
        estimators.register("ols", FoldAveragedOLS)
    estimators.register("ols", FoldAveragedOLS, replace=True)
    assert type(estimators.make("ols")) is FoldAveragedOLS
    with pytest.raises(ValueError, match="without whitespace"):
        estimators.register("my ols", OLS)
    with pytest.raises(ValueError, match="without whitespace"):
        estimators.register("", OLS)
    with pytest.raises(TypeError, match="must be a string"):
        estimators.register(3, OLS)
    with pytest.raises(TypeError, match="callable"):
        estimators.register("thing", OLS())
    estimators.register("not-an-estimator", lambda **kw: object())
    with pytest.raises(TypeError, match="returned a object, not a .*LinearEstimator"):
        estimators.make("not-an-estimator")


def test_needs_folds_is_the_public_read_only_protocol():
    assert PLS().needs_folds and not PLS(n_components=2).needs_folds
    assert Lasso().needs_folds and not Lasso(alpha=0.1).needs_folds
    # ridge chooses alpha by generalised cross-validation from one Moments: no folds
    assert not Ridge().needs_folds and not Ridge(alpha=1.0).needs_folds
    for est in (OLS(), TLS(), Stepwise(), JFA(), BayesianJFA()):
        assert not est.needs_folds, type(est).__name__
    assert Lasso(cv=7).cv == 7
    with pytest.raises(AttributeError):
        PLS().needs_folds = False
    # one Moments for an estimator that needs folds is refused, with the way out
    X, y = torch.randn(40, 3, dtype=torch.float64), torch.randn(40, dtype=torch.float64)
    with pytest.raises(ValueError, match="needs fold moments"):
        FoldAveragedOLS().fit_moments(Moments.from_data(X, y))
    with pytest.raises(ValueError, match="at least 2 fold moments"):
        FoldAveragedOLS().fit_moments([Moments.from_data(X, y)])
