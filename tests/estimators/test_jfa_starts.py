"""Bayesian JFA's answer does not depend on where it stops: the bound converges, the relevance
decisions hold past convergence, several starts give one answer, and where the bound has
several optima the fit keeps the start whose bound ends highest."""

import pytest
import torch
from experiments.synthetic import make_problem

from torchjfa.estimators import BayesianJFA
from torchjfa.estimators import _jfa as jfa
from torchjfa.estimators import _jfa_model as jm
from torchjfa.estimators import _jfa_newton as jn
from torchjfa.stats import Moments

ROUNDOFF = 64 * 2.0**-52  # the bound's relative round-off (a sum of O(d) terms of size O(N))


@pytest.fixture(scope="module")
def cell():
    """One trial of the paper's Fig. 2 cell with 30 redundant and 60 irrelevant inputs at input
    SNR 5, where the bound of the paper's model (no input noise given) has several optima."""
    return make_problem(30, 60, input_snr=5.0, n_train=1000, n_test=1000, seed=0)


def _each_start(est: BayesianJFA, X, y):
    """Each start of ``est`` fitted on its own, outside the estimator: ``[(final bound in
    standardised units, coef_ in the caller's units, relevant inputs)]``."""
    S, psx_fixed, active, sx, sy, *_ = est._prepare(Moments.from_data(X, y))
    cfg = est._settings()
    out = []
    for start in range(est.n_starts):
        gen = torch.Generator().manual_seed(start) if start else None
        res = jn.run_newton(
            S, jm.first_sweep(S, psx_fixed, cfg, gen), cfg, max_iter=est.max_iter,
            tol=est.tol, coef_tol=est.coef_tol,
        )  # fmt: skip
        relevant = cfg.shape / res.state.rate < 1e4
        out.append((float(res.history[-1]), jm.coef(res.state, cfg) * sy / sx, relevant))
    return out


def test_the_rule_keeps_the_highest_bound_and_start_0_on_ties():
    n = 1000.0
    level = 1.0e5  # max(|L|, N) for bounds near -1e5
    # another start higher by less than the bound's round-off: start 0's answer stays
    assert jfa._best_start([torch.tensor(-1.0e5), torch.tensor(-1.0e5 + 1e-9)], 0.0, n) == 0
    # higher by more than tol * level: the highest wins, the first of equal ones
    bounds = [torch.tensor(v) for v in (-1.0e5, -1.0e5 + 2.0, -1.0e5 + 5.0, -1.0e5 + 5.0)]
    assert jfa._best_start(bounds, 1e-12, n) == 2
    # within tol * level (1e-8 * 1e5 = 1e-3 nats) of start 0: start 0
    assert jfa._best_start([torch.tensor(-1.0e5), torch.tensor(-1.0e5 + 0.5e-3)], 1e-8, n) == 0
    assert level * 1e-8 > 0.5e-3


def test_several_optima_the_highest_bound_is_kept(cell):
    est = BayesianJFA(max_iter=100_000, n_starts=4).fit(cell.X_train, cell.y_train)
    starts = _each_start(est, cell.X_train, cell.y_train)
    bounds = torch.tensor([b for b, _, _ in starts], dtype=torch.float64)
    # this problem's bound has several optima: the starts end nats apart
    assert float(bounds.max() - bounds.min()) > 1.0
    best = int(bounds.argmax())
    assert est.best_start_ == best
    # the starts' bounds as the estimator reports them (shifted by the units' Jacobian)
    shift = est.start_bounds_ - bounds
    assert float(shift.max() - shift.min()) <= 4 * ROUNDOFF * float(bounds.abs().max())
    L = float(est.lower_bound_[-1])
    assert L == pytest.approx(float(est.start_bounds_.max()), rel=ROUNDOFF, abs=0)
    coef = starts[best][1]
    scale = float(coef.abs().max())
    torch.testing.assert_close(est.coef_, coef, rtol=0, atol=1e-12 * scale)
    assert torch.equal(est.relevant_, starts[best][2])


def test_one_optimum_several_starts_one_answer(cell):
    """With the input noise known, the paper's shared prior has one optimum on this problem:
    every start ends at it, to the stopping rule's precision."""
    kw = dict(max_iter=100_000, input_noise=cell.input_noise, n_starts=4)
    est = BayesianJFA(**kw).fit(cell.X_train, cell.y_train)
    starts = _each_start(est, cell.X_train, cell.y_train)
    level = max(abs(starts[0][0]), 1000.0)
    for b, coef, relevant in starts[1:]:
        # each fit stops with its last step gaining at most tol * level, and Newton converges
        # quadratically: the remaining gap is below that
        assert abs(b - starts[0][0]) <= est.tol * level + ROUNDOFF * level
        # coordinates within coef_tol (1e-9, standardised) of the optimum: coef_ (at most
        # about 10 in standardised units here) within 1e-6 of the largest
        torch.testing.assert_close(coef, starts[0][1], rtol=0, atol=1e-6 * float(coef.abs().max()))
        assert torch.equal(relevant, starts[0][2])
    assert est.best_start_ == 0


@pytest.mark.parametrize(
    "kw", [{}, {"ard": "output", "known": True}], ids=["paper's model", "ARD on w_z, known noise"]
)
def test_past_convergence_the_bound_and_the_decisions_stay(cell, kw):
    """Run on past the stopping rule (tol = coef_tol = 0, 40 more iterations): the bound gains
    no more than the stopping rule allows, and coef_ and the relevance decisions stay."""
    kw = dict(kw)
    noise = cell.input_noise if kw.pop("known", False) else None
    base = dict(max_iter=100_000, input_noise=noise, n_starts=1, **kw)
    est = BayesianJFA(**base).fit(cell.X_train, cell.y_train)
    assert est.converged_ and est.stop_reason_ == "bound"
    more = BayesianJFA(**{**base, "max_iter": est.n_iter_ + 40, "tol": 0.0, "coef_tol": 0.0})
    more.fit(cell.X_train, cell.y_train)
    L, L_more = float(est.lower_bound_[-1]), float(more.lower_bound_[-1])
    level = max(abs(L), 1000.0)
    assert L - ROUNDOFF * level <= L_more <= L + 10 * est.tol * level
    assert bool((more.lower_bound_.diff() >= -ROUNDOFF * level).all())
    assert torch.equal(more.relevant_, est.relevant_)
    # a converged step moves no coordinate by more than coef_tol (1e-9, standardised)
    scale = float(est.coef_.abs().max())
    torch.testing.assert_close(more.coef_, est.coef_, rtol=0, atol=1e-8 * scale)


def test_relevance_decisions_are_clear_cut(cell):
    """At convergence every input's relevance is either O(1)-O(100) or pruned far above the
    threshold 1e4: no decision sits near it."""
    for kw in ({}, {"input_noise": cell.input_noise, "ard": "output"}):
        est = BayesianJFA(max_iter=100_000, **kw).fit(cell.X_train, cell.y_train)
        rel = est.relevance_
        assert int(((rel > 1e3) & (rel < 1e5)).sum()) == 0
        assert 0 < int(est.relevant_.sum()) < rel.numel()
        # an input the prior pruned does not enter the predictor
        assert float(est.coef_noisy_[~est.relevant_].abs().max()) < 1e-3 * float(
            est.coef_noisy_[est.relevant_].abs().max()
        )


def test_n_starts_checked():
    X = torch.randn(50, 3, dtype=torch.float64)
    y = X.sum(1)
    with pytest.raises(ValueError, match="n_starts"):
        BayesianJFA(n_starts=0).fit(X, y)
    with pytest.raises(TypeError, match="n_starts"):
        BayesianJFA(n_starts=1.5).fit(X, y)
