"""The (Bayesian) JFA fit as tensor ops: identities of the bound, the Newton optimiser's step
and prune move against dense and brute-force references, one answer whatever the chunking,
and the closed form of maximum likelihood."""

import math

import pytest
import torch

from torchjfa.estimators import JFA, BayesianJFA
from torchjfa.estimators import _jfa_em as je
from torchjfa.estimators import _jfa_model as jm
from torchjfa.estimators import _jfa_newton as jn
from torchjfa.estimators import _jfa_prune as jp
from torchjfa.stats import Moments

F64 = torch.float64


def _data(n, d, *, seed, n_irrelevant=0, psx=0.5, redundant=False):
    """x = t + noise (one column a noisy copy of another if ``redundant``), y = sum b t + noise."""
    g = torch.Generator().manual_seed(seed)
    b = torch.linspace(1.0, 2.0, d, dtype=F64)
    b[d - n_irrelevant :] = 0.0
    t = torch.randn(n, d, generator=g, dtype=F64)
    if redundant:
        t[:, -1] = t[:, 0] + 0.1 * torch.randn(n, generator=g, dtype=F64)
    X = t + math.sqrt(psx) * torch.randn(n, d, generator=g, dtype=F64) + 1.0
    y = t @ b + 0.5 * torch.randn(n, generator=g, dtype=F64) - 2.0
    return X, y


def _standardised(X, y):
    Xc, yc = X - X.mean(0), y - y.mean()
    sx, sy = (Xc**2).mean(0).sqrt(), (yc**2).mean().sqrt()
    Xs, ys = Xc / sx, yc / sy
    n = torch.tensor(float(X.shape[0]), dtype=F64)
    return jm.Stats(Xs.T @ Xs, Xs.T @ ys, ys @ ys, n)


def _settings(ard, fixed_x):
    return jm.Settings(
        bayes=True,
        noise_floor=1e-6,
        noise_y_floor=1e-3,
        fixed_x=fixed_x,
        shared_ard=ard == "shared",
    )


def _batch(S):
    """One problem's moments as a batch of one."""
    return jm.Stats(*(t[None] for t in S))


def _one(st):
    """One problem's state as a batch of one."""
    return jm.State(*(t[None] for t in st))


def _dense_hessian(cv, xx):
    """The Hessian of eq. 14 as a dense ``(B, P, P)`` matrix from `Curvature` and the moments
    ``xx (B, d, d)``: each input's block plus ``J^T G J`` (the reference of the structured
    solve)."""
    B, r, d = cv.jk.shape
    blocks = torch.diag_embed(cv.hb).permute(0, 1, 3, 2, 4).reshape(B, r * d, r * d)
    H = torch.nn.functional.pad(blocks, (0, 1, 0, 1))
    H[:, -1, -1] = cv.hpsy
    Jk = torch.diag_embed(cv.jk).permute(0, 2, 1, 3).reshape(B, d, r * d)
    Jc = torch.cat([cv.jq.reshape(B, 1, r * d), cv.psy[:, None, None]], -1)
    J = torch.cat([torch.nn.functional.pad(Jk, (0, 1)), Jc], -2)
    G = torch.zeros(B, d + 1, d + 1, dtype=xx.dtype)  # the Hessian of h(k, c)
    G[:, :d, :d] = -xx / cv.c[:, None, None]
    G[:, :d, d] = G[:, d, :d] = cv.gkc
    G[:, d, d] = cv.gcc
    return H + J.mT @ G @ J


@pytest.mark.parametrize("ard", ["shared", "output"])
@pytest.mark.parametrize("fixed_x", [False, True])
def test_reduced_bound_equals_the_estep_bound_and_its_derivatives_are_autograds(ard, fixed_x):
    X, y = _data(300, 4, seed=0, n_irrelevant=1)
    S = _standardised(X, y)
    cfg = _settings(ard, fixed_x)
    psx = torch.full((4,), 0.3, dtype=F64) if fixed_x else None
    st = jm.first_sweep(S, psx, cfg)
    for _ in range(6):
        es, full = jm.estep(S, st, cfg)
        # two code paths, one bound: the E-step's (Q(z, t) explicit) and the collapsed one
        reduced = jm.collapsed_bound(S, st.mz, st.mx, st.vz, st.vx, st.psz, st.psx, st.psy, cfg)
        assert float(reduced) == pytest.approx(float(full), rel=1e-13)
        torch.testing.assert_close(jm.predictor(st), es.k, rtol=1e-12, atol=1e-14)
        st = jm.update(S, st, es, cfg)
    # the structured gradient and Hessian of the Newton optimiser against plain autograd, at
    # the EM state and at one moved off it (every coordinate, so no term of
    # `_jfa_newton.input_curvature` sits at a special value)
    x0 = jm.to_coords(_one(st), cfg)[0]
    pc = st.psx[None]
    batch = _batch(S)
    shift = 0.3 * torch.randn(x0.shape, generator=torch.Generator().manual_seed(1), dtype=F64)

    def f(x):
        return jm.coords_bound(x[None], batch, pc, cfg)[0]

    for x in (x0, x0 + shift):
        cv = jn.derivatives(x[None], batch, pc, cfg)
        g, H = cv.g, _dense_hessian(cv, batch.xx)
        g_ref = torch.func.grad(f)(x)
        H_ref = torch.autograd.functional.hessian(f, x)
        torch.testing.assert_close(g[0], g_ref, rtol=1e-12, atol=1e-12 * float(g_ref.abs().max()))
        torch.testing.assert_close(H[0], H_ref, rtol=1e-12, atol=1e-12 * float(H_ref.abs().max()))


VARIANTS = {
    "seed": {},
    "noise_informed": {"input_noise": True},
    "output_ard": {"ard": "output"},
    "output_ard_noise_informed": {"ard": "output", "input_noise": True},
}


@pytest.mark.parametrize("variant", sorted(VARIANTS))
def test_any_chunking_gives_one_answer_at_default_settings(variant):
    """fit(X, y) and fit_moments of several chunkings: 1e-8 relative (round-off of the sums
    only: the Newton optimiser converges quadratically to one optimum)."""
    n, d = 3000, 8
    X, y = _data(n, d, seed=3, n_irrelevant=3, redundant=True)
    kw = dict(VARIANTS[variant])
    if kw.pop("input_noise", False):
        kw["input_noise"] = torch.full((d,), 0.5, dtype=F64)
    whole = BayesianJFA(**kw).fit(X, y)
    assert whole.converged_ and whole.n_iter_ < 200
    fits = [BayesianJFA(**kw).fit_moments(Moments.from_data(X, y))]
    for size in (1000, 64):
        chunks = [Moments.from_data(X[a : a + size], y[a : a + size]) for a in range(0, n, size)]
        fits.append(BayesianJFA(**kw).fit_moments(chunks))
    reversed_rows = Moments.from_data(X.flip(0), y.flip(0))  # another order of the sums
    fits.append(BayesianJFA(**kw).fit_moments(reversed_rows))
    for other in fits:
        assert other.converged_
        for key in ("coef_", "coef_noisy_", "noise_x_", "noise_z_", "noise_y_"):
            ref = getattr(whole, key)
            torch.testing.assert_close(
                getattr(other, key),
                ref,
                rtol=1e-8,
                atol=1e-8 * float(ref.abs().max()),
                msg=key,
            )
        assert float(other.lower_bound_[-1]) == pytest.approx(
            float(whole.lower_bound_[-1]), rel=1e-8
        )


@pytest.mark.parametrize("variant", sorted(VARIANTS))
def test_newton_reaches_at_least_plain_ems_bound_at_a_stationary_point(variant):
    X, y = _data(1000, 6, seed=5, n_irrelevant=2, redundant=True)
    kw = dict(VARIANTS[variant])
    if kw.pop("input_noise", False):
        kw["input_noise"] = torch.full((6,), 0.5, dtype=F64)
    newton = BayesianJFA(**kw).fit(X, y)
    em = BayesianJFA(method="em", max_iter=3000, **kw).fit(X, y)
    assert newton.converged_ and newton.n_iter_ < 100
    L = newton.lower_bound_
    # every kept step raised the bound, or (a step below the bound's resolution) did not lower
    # it by more than the bound's round-off
    assert float(L.diff().min()) >= -jn._ROUNDOFF * float(L.abs().max())
    assert float(L[-1]) >= float(em.lower_bound_[-1]) - 1e-9 * abs(float(L[-1]))
    # the noisy-input predictor is where EM heads (it is identified): agree to EM's accuracy
    torch.testing.assert_close(newton.coef_noisy_, em.coef_noisy_, rtol=0, atol=2e-2)


def test_ml_closed_form_is_the_likelihoods_maximum():
    """JFA's closed form: E[y | x] is OLS, and no EM state has a higher likelihood."""
    X, y = _data(800, 5, seed=2, n_irrelevant=1)
    est = JFA().fit(X, y)
    A = torch.cat([X, torch.ones(800, 1, dtype=F64)], 1)
    ols = torch.linalg.lstsq(A, y[:, None]).solution[:, 0]
    torch.testing.assert_close(est.coef_noisy_, ols[:5], rtol=1e-10, atol=1e-12)
    torch.testing.assert_close(est.intercept_noisy_, ols[5], rtol=1e-10, atol=1e-12)
    assert est.n_iter_ == 2 and est.converged_
    # the likelihood of (x, y): independent N(0, v_m) inputs, y | x ~ N(k^T x, c)
    Xc, yc = X - X.mean(0), y - y.mean()
    v = (Xc**2).mean(0)
    rss = ((yc - Xc @ ols[:5]) ** 2).sum()
    ll = -0.5 * 800 * (torch.log(2 * math.pi * v).sum() + 5) - 0.5 * 800 * (
        math.log(2 * math.pi * float(rss) / 800) + 1
    )
    assert float(est.lower_bound_[-1]) == pytest.approx(float(ll), rel=1e-12)
    em = JFA(method="em", max_iter=1000, tol=0.0, coef_tol=0.0).fit(X, y)
    assert float(em.lower_bound_.max()) <= float(est.lower_bound_[-1]) + 1e-9 * abs(float(ll))
    # with the input noise known, the closed form de-attenuates OLS column by column (where
    # RSS / N leaves room for the noise the loadings carry into y; with the true 0.5 this
    # sample does not, the optimum is on the floors and plain EM fits it)
    noise = torch.full((5,), 0.3, dtype=F64)
    known = JFA(input_noise=noise).fit(X, y)
    assert known.n_iter_ == 2 and known.converged_
    torch.testing.assert_close(known.coef_, ols[:5] * v / (v - noise), rtol=1e-10, atol=1e-12)
    torch.testing.assert_close(known.noise_x_, noise)


def _early_states(d, seed, cfg, fixed_x, sweeps):
    """``(S, st)`` after each of the first ``sweeps`` plain EM sweeps that follow the first
    one, on 300 rows with two irrelevant inputs (one redundant if ``seed == 1``), psi_x fixed at
    0.3 if ``fixed_x``: states early in a fit, where the Newton matrix is often indefinite at
    small damping."""
    X, y = _data(300, d, seed=seed, n_irrelevant=2, redundant=seed == 1)
    S = _standardised(X, y)
    psx = torch.full((d,), 0.3, dtype=F64) if fixed_x else None
    st = jm.first_sweep(S, psx, cfg)
    for _ in range(sweeps):
        st = jm.update(S, st, jm.estep(S, st, cfg)[0], cfg)
        yield S, st


def _dense_newton_step(x, g, H, lam, lb):
    """The damped Newton step through the dense P x P matrix (the reference)."""
    free = ~((x <= lb) & (g <= 0))
    M = -H * (free[..., :, None] & free[..., None, :])
    diag = torch.diagonal(M, dim1=-2, dim2=-1)
    scale = diag.abs().amax(-1, keepdim=True)
    damp = torch.where(free, diag.abs().clamp_min(1e-12 * scale), 1.0)
    M = M + torch.diag_embed(torch.where(free, lam[..., None] * damp, 1.0))
    chol, info = torch.linalg.cholesky_ex(M)
    delta = torch.cholesky_solve((g * free)[..., None], chol)[..., 0]
    return delta, info == 0


def _blocks_definite(x, cv, lam: float, lb) -> bool:
    free, damp = jn._free_and_damping(x, cv, lb)
    lam_d = torch.where(free, lam * damp, 1.0)
    A, a_psy = jn.block_part(cv, free, lam_d)
    return bool((torch.linalg.eigvalsh(A) > 0).all() & (a_psy > 0).all())


@pytest.mark.parametrize("ard", ["shared", "output"])
@pytest.mark.parametrize("fixed_x", [False, True])
def test_the_structured_newton_step_is_the_dense_one(ard, fixed_x):
    """The per-input blocks + Woodbury solve against a dense Cholesky of -H + lam diag|H|:
    the same step, and the same verdict on positive definiteness wherever the block part is
    positive definite (elsewhere the structured step is refused), with coordinates held at
    their bounds, over damping from 1e-6 (often indefinite) to 1e2."""
    d = 5
    cfg = _settings(ard, fixed_x)
    verdicts = set()
    for seed in range(3):
        for it, (S, st) in enumerate(_early_states(d, seed, cfg, fixed_x, 4)):
            x = jm.to_coords(_one(st), cfg)
            batch = _batch(S)
            cv = jn.derivatives(x, batch, st.psx[None], cfg)
            H = _dense_hessian(cv, batch.xx)
            # hold a few coordinates: the bound at x where the gradient points below it
            lb = torch.where(
                (cv.g <= 0) & (torch.arange(x.shape[-1]) % 3 == it % 3), x, -torch.inf
            )[0]
            for lam in (1e-6, 1e-3, 1.0, 1e2):
                lam_t = torch.full((1,), lam, dtype=F64)
                trial, ok, gain = jn.newton_step(x, cv, batch.xx, lam_t, lb)[:3]
                delta, ok_ref = _dense_newton_step(x, cv.g, H, lam_t, lb)
                blocks_pd = _blocks_definite(x, cv, lam, lb)
                assert bool(ok) == (bool(ok_ref) and blocks_pd)
                verdicts.add((bool(ok), bool(ok_ref)))
                if bool(ok):
                    ref = torch.maximum(x + delta, lb)
                    scale = float((ref - x).abs().max())
                    torch.testing.assert_close(trial, ref, rtol=1e-9, atol=1e-9 * scale)
    assert {(True, True), (False, False)} <= verdicts  # both verdicts were tested


@pytest.mark.parametrize("ard", ["shared", "output"])
def test_the_damping_is_the_first_of_nielsens_sequence_with_a_definite_matrix(ard):
    """`damped_step` raises lam by Nielsen's rule (lam *= nu, nu *= 2) to the first value at
    which the structured solve proves the damped matrix positive definite, where the raise
    before it did not; a lam that already gives a definite matrix is returned unchanged.
    Early states of redundant problems at small damping supply the indefinite cases."""
    d = 6
    cfg = _settings(ard, False)
    raised = 0
    for seed in range(3):
        X, y = _data(300, d, seed=seed, n_irrelevant=2, redundant=True)
        S = _standardised(X, y)
        st = jm.first_sweep(S, None, cfg)
        x = jm.to_coords(_one(st), cfg)
        batch = _batch(S)
        cv = jn.derivatives(x, batch, st.psx[None], cfg)
        lb = torch.full(x.shape[-1:], -torch.inf, dtype=F64)

        def definite(lam, x=x, cv=cv, xx=batch.xx, lb=lb):
            return bool(jn.newton_step(x, cv, xx, torch.full((1,), lam, dtype=F64), lb).ok)

        for lam0 in (1e-9, 1e-6, 1e-3, 1.0):
            two = torch.full((1,), 2.0, dtype=F64)
            step, lam, nu = jn.damped_step(
                x, cv, batch.xx, torch.full((1,), lam0, dtype=F64), two, lb
            )
            seq, factor = [lam0], 2.0
            while float(nu) > factor:
                seq.append(seq[-1] * factor)
                factor *= 2.0
            assert float(lam) == pytest.approx(seq[-1], rel=1e-14)
            assert bool(step.ok) and definite(float(lam))
            if len(seq) > 1:
                assert not definite(seq[-2])
            raised += len(seq) - 1
    assert raised > 0  # the raising was exercised


@pytest.mark.parametrize("variant", sorted(VARIANTS) + ["ml"])
def test_fit_batch_gives_each_problem_its_single_fit(variant):
    """The public batched fit: problem by problem what fit_moments gives (1e-10), including a
    problem with a constant column."""
    d = 6
    kw = dict(VARIANTS.get(variant, {}))
    if kw.pop("input_noise", False):
        kw["input_noise"] = torch.full((d,), 0.4, dtype=F64)
    make = (lambda: JFA(**kw)) if variant == "ml" else (lambda: BayesianJFA(**kw))
    problems = []
    for i in range(5):
        X, y = _data(300 + 50 * i, d, seed=20 + i, n_irrelevant=i % 3, redundant=i == 2)
        if i == 4:
            X[:, 3] = 1.5  # constant: not an active column of this problem
        problems.append(Moments.from_data(X, y))
    template = make()
    fits = template.fit_batch(problems)
    assert not hasattr(template, "coef_")  # the template is not fitted
    assert [type(f) for f in fits] == [type(template)] * 5
    for problem, batched in zip(problems, fits, strict=True):
        single = make().fit_moments(problem)
        assert batched.n_iter_ == single.n_iter_ and batched.converged_
        for key in ("coef_", "coef_noisy_", "noise_x_", "noise_y_", "lower_bound_"):
            ref = getattr(single, key)
            torch.testing.assert_close(
                getattr(batched, key), ref, rtol=1e-10, atol=1e-12 * float(ref.abs().max())
            )
    assert bool(fits[4].active_[3]) is False and float(fits[4].coef_[3]) == 0.0


def test_fit_batch_refuses_mixed_widths_and_nothing():
    X, y = _data(200, 4, seed=0)
    with pytest.raises(ValueError, match="one width"):
        BayesianJFA().fit_batch([Moments.from_data(X, y), Moments.from_data(X[:, :3], y)])
    with pytest.raises(ValueError, match="at least one problem"):
        BayesianJFA().fit_batch([])


def test_the_jackknife_of_bayesian_jfa_is_its_single_refits():
    """The jackknife fits Bayesian JFA's K refits with fit_batch: the same spread as K refits."""
    from torchjfa.estimators import jackknife
    from torchjfa.estimators._jackknife import refit_without

    X, y = _data(1200, 5, seed=7, n_irrelevant=1)
    folds = [Moments.from_data(X[a : a + 200], y[a : a + 200]) for a in range(0, 1200, 200)]
    est = BayesianJFA()
    coefs, std = jackknife(est, folds)
    singles = torch.stack([refit_without(est, folds, k)[0].coef_ for k in range(len(folds))])
    torch.testing.assert_close(coefs, singles, rtol=1e-10, atol=1e-12)
    K = len(folds)
    ref = ((K - 1) / K * (singles - singles.mean(0)).pow(2).sum(0)).sqrt()
    torch.testing.assert_close(std, ref, rtol=1e-9, atol=1e-12)


def _mid_fit(ard, fixed_x, seed=1, d=6):
    """A state 40 plain EM sweeps into a redundant problem with irrelevant inputs: inputs on
    their way to the prior's zero, so that some prunes gain and others lose."""
    cfg = _settings(ard, fixed_x)
    X, y = _data(400, d, seed=seed, n_irrelevant=3, redundant=True)
    S = _standardised(X, y)
    psx = torch.full((d,), 0.3, dtype=F64) if fixed_x else None
    res = je.run_em(S, jm.first_sweep(S, psx, cfg), cfg, max_iter=40, tol=0.0, coef_tol=0.0)
    return _batch(S), cfg, jm.to_coords(_one(res.state), cfg), res.state.psx[None]


@pytest.mark.parametrize("ard", ["shared", "output"])
@pytest.mark.parametrize("fixed_x", [False, True])
def test_each_single_prunes_gain_is_the_change_of_the_bound(ard, fixed_x):
    """The prune candidates' closed-form gains (S_ee through k_m, the input's own terms with its
    variances moved) against the collapsed bound evaluated after each prune, to the bound's
    round-off; both signs occur."""
    S, cfg, x, psx = _mid_fit(ard, fixed_x)
    cand = jp.candidates(x, S, psx, cfg)
    L0 = jm.coords_bound(x, S, psx, cfg)
    d = S.xy.shape[-1]
    exact = torch.stack(
        [
            jm.coords_bound(jp.with_prunes(cand, torch.arange(d) == m, cfg), S, psx, cfg) - L0
            for m in range(d)
        ],
        -1,
    )
    tol = 4 * jn._ROUNDOFF * max(float(L0.abs()), float(S.n))
    torch.testing.assert_close(cand.gain, exact, rtol=0.0, atol=tol)
    assert bool((exact > 0).any()) and bool((exact < 0).any())


@pytest.mark.parametrize("ard", ["shared", "output"])
def test_greedy_prunes_are_the_sequence_of_best_exact_prunes(ard):
    """`greedy_pick` (O(d) updates of the gains) against a brute-force greedy: from the state,
    repeatedly add the input whose prune raises the collapsed bound most, while that rise
    exceeds thr."""
    for seed in (1, 2, 3):
        S, cfg, x, psx = _mid_fit(ard, False, seed=seed, d=7)
        d = 7
        cand = jp.candidates(x, S, psx, cfg)
        thr = torch.tensor([0.01], dtype=F64)
        pick = torch.zeros(d, dtype=torch.bool)
        L = jm.coords_bound(x, S, psx, cfg)[0]
        while True:
            trial = [pick | (torch.arange(d) == m) for m in range(d)]
            gains = torch.stack(
                [jm.coords_bound(jp.with_prunes(cand, t, cfg), S, psx, cfg)[0] - L for t in trial]
            )
            gains = torch.where(pick, -torch.inf, gains)
            assert bool(((gains - thr).abs() > 1e-6).all())  # no call on round-off
            best = int(gains.argmax())
            if float(gains[best]) <= float(thr):
                break
            pick, L = trial[best], L + gains[best]
        greedy = jp.greedy_pick(cand, S, thr)
        assert greedy[0].tolist() == pick.tolist()


def test_pruned_variances_are_stationary_where_both_loadings_are_pruned():
    """With alpha shared and psi_x free a prune zeroes both loadings, and `pruned_variances`
    puts V_z, V_x where the bound's gradient in log V vanishes (autograd; it is of order 1/2
    before, the entropy's)."""
    S, cfg, x, psx = _mid_fit("shared", False)
    cand = jp.candidates(x, S, psx, cfg)
    d = S.xy.shape[-1]
    xp = jp.with_prunes(cand, torch.ones(d, dtype=torch.bool), cfg).requires_grad_(True)
    (g,) = torch.autograd.grad(jm.coords_bound(xp, S, psx, cfg).sum(), xp)
    assert float(g[0, 2 * d : 4 * d].abs().max()) < 1e-6


@pytest.mark.parametrize("fixed_x", [False, True])
def test_a_fit_with_prunes_ends_at_a_stationary_point_of_the_whole_bound(fixed_x):
    """After its prunes the optimiser ends where no coordinate, the pruned inputs' <w_z>
    included, has a Newton gain of its own above 1e-9 nats (one coordinate's g^2 / (2 |H_ii|)),
    and no <w_z> is left at exactly 0 (Newton moved the pruned ones too)."""
    d, n_irr = 8, 5
    cfg = _settings("output", fixed_x)
    X, y = _data(2000, d, seed=3, n_irrelevant=n_irr)
    S = _standardised(X, y)
    psx = torch.full((d,), 0.5 / 1.5, dtype=F64) if fixed_x else None
    st = jm.first_sweep(S, psx, cfg)
    res = jn.run_newton(S, st, cfg, max_iter=2000, tol=1e-12, coef_tol=1e-9)
    assert res.reason == 1  # converged
    mz = res.state.mz
    pruned = mz.abs() < 1e-2
    assert int(pruned.sum()) >= 3  # the irrelevant inputs were pruned
    assert bool((mz != 0).all())
    x = jm.to_coords(_one(res.state), cfg)
    batch = _batch(S)
    cv = jn.derivatives(x, batch, res.state.psx[None], cfg)
    H = _dense_hessian(cv, batch.xx)[0]
    lb = torch.full(x.shape[-1:], -torch.inf, dtype=F64)  # the floors, as in the fit
    lb[4 * d : (5 if fixed_x else 6) * d] = math.log(cfg.noise_floor)
    lb[-1] = math.log(cfg.noise_y_floor)
    free = ~((x[0] <= lb * (1 - 1e-12)) & (cv.g[0] <= 0))
    gains = cv.g[0] ** 2 / (2 * H.diagonal().abs().clamp_min(1e-300))
    assert float(gains[free].max()) <= 1e-9
