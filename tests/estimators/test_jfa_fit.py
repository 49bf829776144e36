"""The (Bayesian) JFA fit as tensor ops: identities of the bound, one answer whatever the
chunking or batching, and the closed form of maximum likelihood."""

import math

import pytest
import torch

from torchjfa.estimators import JFA, BayesianJFA
from torchjfa.estimators import _jfa_bound as jb
from torchjfa.estimators import _jfa_fit as jf
from torchjfa.estimators import _jfa_newton as jn
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
    return jb.Stats(Xs.T @ Xs, Xs.T @ ys, ys @ ys, n)


def _hyper(ard, fixed_x):
    if ard == "shared":
        return jb.Hyper(True, 1.0 + 1e-8, 1e-8, 1e-6, fixed_x, 1e-3, -1.0)
    return jb.Hyper(True, 0.5 + 1e-8, 1e-8, 1e-6, fixed_x, 1e-3, 1e-8)


@pytest.mark.parametrize("ard", ["shared", "output"])
@pytest.mark.parametrize("fixed_x", [False, True])
def test_reduced_bound_equals_the_estep_bound_and_its_derivatives_are_autograds(ard, fixed_x):
    X, y = _data(300, 4, seed=0, n_irrelevant=1)
    S = _standardised(X, y)
    hp = _hyper(ard, fixed_x)
    psx = torch.full((4,), 0.3, dtype=F64) if fixed_x else None
    st, psy = jf._first_sweep(S, *jf.initial_state(S, psx, hp), hp)
    for _ in range(6):
        es, R, c, S_ee, L = jb.estep(S, st, psy, hp)
        # two code paths, one bound: the E-step's (Q(z, t) explicit) and the collapsed one
        full = L + jb.bound_const(S.n, 4, hp)
        reduced = jb.reduced_bound(S, *st[[0, 1, 2, 3, 5, 6]].unbind(0), psy, hp)
        assert float(reduced) == pytest.approx(float(full), rel=1e-13)
        torch.testing.assert_close(jb.predictor(st), es[0], rtol=1e-12, atol=1e-14)
        st, psy = jb.update(S, es, R, c, S_ee, st, psy, hp)
    # the structured gradient and Hessian of the Newton optimiser against plain autograd, at
    # the EM state and at one moved off it (every coordinate, so no term of
    # `_jfa_bound.input_curvature` sits at a special value)
    theta0 = jf._pack(st, psy, hp)
    pc = st[jb.PX][None]
    batch = jb.Stats(*(t[None] for t in S))
    shift = 0.3 * torch.randn(theta0.shape, generator=torch.Generator().manual_seed(1), dtype=F64)

    def f(th):
        return jf._theta_bound(th[None], *batch, pc, hp)[0]

    for theta in (theta0, theta0 + shift):
        cv = jn.derivatives(theta[None], batch, pc, hp)
        g, H = cv.g, jn.dense_hessian(cv, batch.xx)
        g_ref = torch.func.grad(f)(theta)
        H_ref = torch.autograd.functional.hessian(f, theta)
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


@pytest.mark.parametrize("ard", ["shared", "output"])
@pytest.mark.parametrize("fixed_x", [False, True])
def test_a_batch_of_problems_gives_the_single_fits(ard, fixed_x):
    hp = _hyper(ard, fixed_x)
    problems = [_data(400 + 100 * i, 5, seed=10 + i, n_irrelevant=i % 3) for i in range(4)]
    stats = [_standardised(X, y) for X, y in problems]
    noise = [torch.full((5,), 0.3 + 0.05 * i, dtype=F64) for i in range(4)] if fixed_x else None
    kw = dict(method="newton", max_iter=500, tol=1e-12, coef_tol=1e-9)
    singles = [
        jf.fit(S, None if noise is None else noise[i], hp, **kw) for i, S in enumerate(stats)
    ]
    batch = jb.Stats(*(torch.stack(t).reshape(2, 2, *t[0].shape) for t in zip(*stats, strict=True)))
    psx = None if noise is None else torch.stack(noise).reshape(2, 2, 5)
    res = jf.fit(batch, psx, hp, **kw)
    assert res.st.shape == (2, 2, 7, 5) and res.n_iter.shape == (2, 2)
    for i, one in enumerate(singles):
        j = divmod(i, 2)
        assert int(one.reason) == 1 and int(res.reason[j]) == 1
        torch.testing.assert_close(res.st[j], one.st, rtol=1e-10, atol=1e-12)
        torch.testing.assert_close(res.psy[j], one.psy, rtol=1e-10, atol=0)
        last = res.history[j][int(res.n_iter[j]) - 1]
        assert float(last) == pytest.approx(float(one.history[-1]), rel=1e-12)


@pytest.mark.parametrize("variant", sorted(VARIANTS))
def test_newton_reaches_at_least_plain_ems_bound_at_a_stationary_point(variant):
    X, y = _data(1000, 6, seed=5, n_irrelevant=2, redundant=True)
    kw = dict(VARIANTS[variant])
    if kw.pop("input_noise", False):
        kw["input_noise"] = torch.full((6,), 0.5, dtype=F64)
    newton = BayesianJFA(**kw).fit(X, y)
    em = BayesianJFA(accelerate=False, max_iter=3000, **kw).fit(X, y)
    assert newton.converged_ and newton.n_iter_ < 100
    L = newton.lower_bound_
    # every kept step raised the bound, or (a step below the bound's resolution) did not lower
    # it by more than the bound's round-off
    assert float(L.diff().min()) >= -jf._ROUNDOFF * float(L.abs().max())
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
    em = JFA(accelerate=False, max_iter=1000, tol=0.0, coef_tol=0.0).fit(X, y)
    assert float(em.lower_bound_.max()) <= float(est.lower_bound_[-1]) + 1e-9 * abs(float(ll))
    # with the input noise known, the closed form de-attenuates OLS column by column (where
    # RSS / N leaves room for the noise the loadings carry into y; with the true 0.5 this
    # sample does not, the optimum is on the floors and plain EM fits it)
    noise = torch.full((5,), 0.3, dtype=F64)
    known = JFA(input_noise=noise).fit(X, y)
    assert known.n_iter_ == 2 and known.converged_
    torch.testing.assert_close(known.coef_, ols[:5] * v / (v - noise), rtol=1e-10, atol=1e-12)
    torch.testing.assert_close(known.noise_x_, noise)


def _early_states(d, seed, hp, fixed_x, sweeps):
    """``(S, st, psy)`` after each of the first ``sweeps`` plain EM sweeps that follow the
    first one, on 300 rows with two irrelevant inputs (one redundant if ``seed == 1``), psi_x
    fixed at 0.3 if ``fixed_x``: states early in a fit, where the Newton matrix is often
    indefinite at small damping."""
    X, y = _data(300, d, seed=seed, n_irrelevant=2, redundant=seed == 1)
    S = _standardised(X, y)
    psx = torch.full((d,), 0.3, dtype=F64) if fixed_x else None
    st, psy = jf._first_sweep(S, *jf.initial_state(S, psx, hp), hp)
    for _ in range(sweeps):
        es, R, c, S_ee, _ = jb.estep(S, st, psy, hp)
        st, psy = jb.update(S, es, R, c, S_ee, st, psy, hp)
        yield S, st, psy


def _along_ridge(theta, m, r, d, floor):
    """``theta (1, P)`` with input m moved to ``psi_x / v = r`` along its ridge (v, k, q and tau
    held, the posterior variances scaled with the noise variances): the reference the ridge
    move is checked against, written from the fitting note's formulas."""
    th = theta.clone()
    mz, mx = float(th[0, m]), float(th[0, d + m])
    vz, vx, psz, psx = (math.exp(float(th[0, i * d + m])) for i in (2, 3, 4, 5))
    tau = 1 + vz / psz + vx / psx
    v = mx * mx / tau + psx
    k = mz * mx / (tau * v)
    q = psz + mz * mz * psx / (tau * v)
    psz_n, psx_n = q - k * k * v * r / (1 - r), r * v
    if not (psz_n >= floor and psx_n >= floor):
        return None
    th[0, m] = math.copysign(math.sqrt(k * k * tau * v / (1 - r)), mz)
    th[0, d + m] = math.copysign(math.sqrt(tau * v * (1 - r)), mx)
    th[0, 2 * d + m] = math.log(vz / psz * psz_n)
    th[0, 3 * d + m] = math.log(vx / psx * psx_n)
    th[0, 4 * d + m] = math.log(psz_n)
    th[0, 5 * d + m] = math.log(psx_n)
    return th


@pytest.mark.parametrize("ard", ["shared", "output"])
def test_the_ridge_slope_is_autograds(ard):
    """`_ridge_slope` (written out by hand) against autograd's first and second derivatives of
    `_ridge_terms` in ``u = log(r / (1 - r))``, at states early in a fit."""
    d = 5
    hp = _hyper(ard, False)
    for _, st, _ in _early_states(d, 1, hp, False, 3):
        mz, mx, vz, vx, _, psz, psx = st.unbind(-2)
        tau = 1 + vz / psz + vx / psx
        v = mx * mx / tau + psx
        k = mz * mx / (tau * v)
        q = psz + mz * mz * psx / (tau * v)
        fixed = jf._Ridge(k * k * tau * v, tau * v, q, k * k * v, v, vz / psz, vx / psx)
        u = torch.log(psx / (v - psx)).detach().requires_grad_()
        f = jf._ridge_terms(torch.exp(u), fixed, hp)[0]
        (g_ref,) = torch.autograd.grad(f.sum(), u, create_graph=True)
        (h_ref,) = torch.autograd.grad(g_ref.sum(), u)  # the terms are separable in the inputs
        g, h = jf._ridge_slope(torch.exp(u.detach()), fixed, hp)
        torch.testing.assert_close(g, g_ref.detach(), rtol=1e-10, atol=1e-12)
        torch.testing.assert_close(h, h_ref, rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("ard", ["shared", "output"])
def test_the_ridge_move_keeps_the_fit_and_maximises_each_inputs_terms_along_its_ridge(
    ard, monkeypatch
):
    """`_ridge_move` (psi_x learned): the bound's change is the move's gain (the data's part,
    through v, k and c, stays: checked on the state), every input ends at the best point of
    its ridge (against a grid of 400 points along it, each input alone, the bound computed
    from scratch), and no input's noise variance falls below the floor."""
    d = 5
    hp = _hyper(ard, False)
    monkeypatch.setattr(jf, "_RIDGE_ROUNDS", 30)  # to the optimum, for the grid comparison
    checked = 0
    for seed in range(2):
        for S, st, psy in list(_early_states(d, seed, hp, False, 6))[::2]:
            theta = jf._pack(st, psy, hp)[None]
            batch = jb.Stats(*(t[None] for t in S))
            psx_c = st[jb.PX][None]
            L0 = jf._theta_bound(theta, *batch, psx_c, hp)
            new, gain = jf._ridge_move(theta, psx_c, hp)
            L1 = jf._theta_bound(new, *batch, psx_c, hp)
            assert float(gain) > 0
            assert float(L1 - L0) == pytest.approx(float(gain), rel=1e-6, abs=1e-9 * float(S.n))
            old_s, new_s = jf._state(theta, psx_c, hp)[0], jf._state(new, psx_c, hp)[0]
            torch.testing.assert_close(jb.predictor(new_s), jb.predictor(old_s), rtol=1e-10, atol=0)
            mz, mx, vz, vx, _, psz, psx = new_s[0].unbind(-2)
            assert bool((psz >= hp.floor).all() & (psx >= hp.floor).all())
            for m in range(d):
                best = -math.inf
                for r in torch.linspace(-8.0, 8.0, 400, dtype=F64).sigmoid().tolist():
                    th = _along_ridge(new, m, r, d, hp.floor)
                    if th is None:
                        continue
                    best = max(best, float(jf._theta_bound(th, *batch, psx_c, hp)))
                assert float(L1) >= best - 1e-9 * float(S.n)
                checked += 1
    assert checked >= 20


def _dense_newton_step(theta, g, H, lam, lb, hold=None):
    """The damped Newton step through the dense P x P matrix (the reference)."""
    free = ~((theta <= lb) & (g <= 0))
    if hold is not None:
        free = free & ~hold
    M = -H * (free[..., :, None] & free[..., None, :])
    diag = torch.diagonal(M, dim1=-2, dim2=-1)
    scale = diag.abs().amax(-1, keepdim=True)
    damp = torch.where(free, diag.abs().clamp_min(1e-12 * scale), 1.0)
    M = M + torch.diag_embed(torch.where(free, lam[..., None] * damp, 1.0))
    chol, info = torch.linalg.cholesky_ex(M)
    delta = torch.cholesky_solve((g * free)[..., None], chol)[..., 0]
    return delta, info == 0


@pytest.mark.parametrize("ard", ["shared", "output"])
@pytest.mark.parametrize("fixed_x", [False, True])
def test_the_structured_newton_step_is_the_dense_one(ard, fixed_x):
    """The per-input blocks + Woodbury solve against a dense Cholesky of -H + lam diag|H|:
    the same step, and the same verdict on positive definiteness wherever the block part is
    positive definite (elsewhere the structured step is refused), with coordinates held at
    their bounds, over damping from 1e-6 (often indefinite) to 1e2."""
    d = 5
    hp = _hyper(ard, fixed_x)
    verdicts = set()
    for seed in range(3):
        for it, (S, st, psy) in enumerate(_early_states(d, seed, hp, fixed_x, 4)):
            theta = jf._pack(st, psy, hp)[None]
            batch = jb.Stats(*(t[None] for t in S))
            cv = jn.derivatives(theta, batch, st[jb.PX][None], hp)
            H = jn.dense_hessian(cv, batch.xx)
            # hold a few coordinates: the bound at theta where the gradient points below it
            lb = torch.where(
                (cv.g <= 0) & (torch.arange(theta.shape[-1]) % 3 == it % 3), theta, -torch.inf
            )[0]
            for lam in (1e-6, 1e-3, 1.0, 1e2):
                lam_t = torch.full((1,), lam, dtype=F64)
                trial, ok, gain = jn.newton_step(theta, cv, lam_t, lb, batch.xx)[:3]
                delta, ok_ref = _dense_newton_step(theta, cv.g, H, lam_t, lb)
                A, a_psy = jn.block_part(theta, cv, lam_t, lb)[:2]
                blocks_pd = bool((torch.linalg.eigvalsh(A) > 0).all() & (a_psy > 0).all())
                assert bool(ok) == (bool(ok_ref) and blocks_pd)
                verdicts.add((bool(ok), bool(ok_ref)))
                if bool(ok):
                    ref = torch.maximum(theta + delta, lb)
                    scale = float((ref - theta).abs().max())
                    torch.testing.assert_close(trial, ref, rtol=1e-9, atol=1e-9 * scale)
    assert {(True, True), (False, False)} <= verdicts  # both verdicts were tested


@pytest.mark.parametrize("ard", ["shared", "output"])
@pytest.mark.parametrize("fixed_x", [False, True])
@pytest.mark.parametrize("ladder, orders", [(1, [5, 4]), (8, [7, 7])])
def test_the_step_with_inputs_held_is_the_dense_one_on_the_other_inputs(
    ard, fixed_x, ladder, orders, monkeypatch
):
    """Inputs whose <w_z> is held at 0 (`newton_step`'s ``hold``, the optimiser's pruned
    inputs) leave the dense system, which is then factored on the other inputs alone: in a
    batch of two problems with 4 and 3 inputs not held, the step is the dense Cholesky's with
    those coordinates held. Each system's order is its own count plus one, rounded up to the
    ladder (at most d + 1: with a ladder of 8 both are padded to 7), and each problem's step
    in the batch is bitwise the step it gets alone."""
    monkeypatch.setattr(jn, "_LADDER", ladder)
    d = 6
    hp = _hyper(ard, fixed_x)
    held = torch.zeros(2, d, dtype=torch.bool)
    held[0, [1, 4]] = True
    held[1, [0, 2, 3]] = True
    thetas, pxs, stats = [], [], []
    for seed in range(2):
        S, st, psy = list(_early_states(d, seed, hp, fixed_x, 3))[-1]
        st = st.clone()
        st[jb.MZ] = torch.where(held[seed], 0.0, st[jb.MZ])
        thetas.append(jf._pack(st, psy, hp))
        pxs.append(st[jb.PX])
        stats.append(S)
    theta, psx_c = torch.stack(thetas), torch.stack(pxs)
    batch = jb.Stats(*(torch.stack(t) for t in zip(*stats, strict=True)))
    cv = jn.derivatives(theta, batch, psx_c, hp)
    H = jn.dense_hessian(cv, batch.xx)
    P = theta.shape[-1]
    hold = torch.nn.functional.pad(held, (0, P - d))
    lb = torch.full((P,), -torch.inf, dtype=F64).expand(2, P)
    taken = 0
    for lam in (1e-3, 1.0, 1e2, 1e4, 1e6):
        lam_t = torch.full((2,), lam, dtype=F64)
        step = jn.newton_step(theta, cv, lam_t, lb, batch.xx, hold=hold)
        assert step.size.tolist() == orders
        for i in range(2):
            cv_i = type(cv)(*(t[i : i + 1] for t in cv))
            one = slice(i, i + 1)
            alone = jn.newton_step(
                theta[one], cv_i, lam_t[one], lb[:1], batch.xx[one], hold=hold[one]
            )
            for a, b in zip(alone, step, strict=True):
                assert torch.equal(a[0], b[i])
        delta, ok_ref = _dense_newton_step(theta, cv.g, H, lam_t, lb, hold)
        for i in range(2):
            if bool(step.ok[i]):
                taken += 1
                assert bool(ok_ref[i])
                ref = theta[i] + delta[i]
                assert bool((step.trial[i, :d][held[i]] == 0).all())
                scale = float((ref - theta[i]).abs().max())
                torch.testing.assert_close(step.trial[i], ref, rtol=1e-9, atol=1e-9 * scale)
    assert taken >= 5


def _blocks_definite(theta, cv, lam: float, lb) -> bool:
    A, a_psy = jn.block_part(theta, cv, torch.full((1,), lam, dtype=F64), lb)[:2]
    return bool((torch.linalg.eigvalsh(A) > 0).all() & (a_psy > 0).all())


@pytest.mark.parametrize("ard", ["shared", "output"])
def test_block_damping_is_the_first_damping_of_nielsens_sequence_with_a_definite_block_part(ard):
    """`block_damping` raises lam by Nielsen's rule (lam *= nu, nu *= 2) to the first value at
    which every input's block of the damped matrix is positive definite (checked here by
    eigenvalues, not Cholesky), where the raise before it was not; a lam that already gives
    definite blocks is returned unchanged; the raises are counted. Early states of redundant
    problems at small damping supply the indefinite cases."""
    d = 6
    hp = _hyper(ard, False)
    raised = 0
    for seed in range(3):
        X, y = _data(300, d, seed=seed, n_irrelevant=2, redundant=True)
        S = _standardised(X, y)
        st, psy = jf._first_sweep(S, *jf.initial_state(S, None, hp), hp)
        theta = jf._pack(st, psy, hp)[None]
        batch = jb.Stats(*(t[None] for t in S))
        cv = jn.derivatives(theta, batch, st[jb.PX][None], hp)
        lb = torch.full(theta.shape[-1:], -torch.inf, dtype=F64)

        for lam0 in (1e-9, 1e-6, 1e-3, 1.0):
            lam, nu, raises, _ = jn.block_damping(
                theta,
                cv,
                torch.full((1,), lam0, dtype=F64),
                torch.full((1,), 2.0, dtype=F64),
                lb,
                1e12,
            )
            seq, step = [lam0], 2.0
            for _ in range(int(raises)):
                seq.append(seq[-1] * step)
                step *= 2.0
            assert float(lam) == pytest.approx(seq[-1], rel=1e-14)
            assert float(nu) == step
            assert _blocks_definite(theta, cv, float(lam), lb)
            if int(raises):
                assert not _blocks_definite(theta, cv, seq[-2], lb)
            raised += int(raises)
    assert raised > 0  # the raising was exercised


@pytest.mark.parametrize("variant", sorted(VARIANTS) + ["ml"])
def test_fit_batch_gives_each_problem_its_single_fit(variant):
    """The public batched fit: problem by problem what fit_moments gives (1e-10), including a
    problem with a constant column (fitted in a batch of its own active columns)."""
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
    """The jackknife fits Bayesian JFA's K refits in one batch: the same spread as K refits."""
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
    hp = _hyper(ard, fixed_x)
    X, y = _data(400, d, seed=seed, n_irrelevant=3, redundant=True)
    S = _standardised(X, y)
    psx = torch.full((d,), 0.3, dtype=F64) if fixed_x else None
    res = jf.fit(S, psx, hp, method="em", max_iter=40, tol=0.0, coef_tol=0.0)
    return S, hp, jf._pack(res.st, res.psy, hp), res.st[jb.PX]


@pytest.mark.parametrize("ard", ["shared", "output"])
@pytest.mark.parametrize("fixed_x", [False, True])
def test_each_single_prunes_gain_is_the_change_of_the_bound(ard, fixed_x):
    """The prune candidates' closed-form gains (S_ee through k_m, the input's own terms with its
    variances moved) against the collapsed bound evaluated after each prune, to the bound's
    round-off; both signs occur."""
    S, hp, theta, psx_c = _mid_fit(ard, fixed_x)
    cand = jf._prune_candidates(theta, S, psx_c, hp)
    L0 = jf._theta_bound(theta, *S, psx_c, hp)
    d = S.xy.shape[-1]
    exact = torch.stack(
        [
            jf._theta_bound(jf._with_prunes(cand, torch.arange(d) == m, hp), *S, psx_c, hp) - L0
            for m in range(d)
        ]
    )
    tol = 4 * jf._ROUNDOFF * max(float(L0.abs()), float(S.n))
    torch.testing.assert_close(cand.gain, exact, rtol=0.0, atol=tol)
    assert bool((exact > 0).any()) and bool((exact < 0).any())


@pytest.mark.parametrize("ard", ["shared", "output"])
def test_greedy_prunes_are_the_sequence_of_best_exact_prunes(ard):
    """`_greedy_prunes` (O(d) updates of the gains) against a brute-force greedy: from the
    state, repeatedly add the input whose prune raises the collapsed bound most, while that
    rise exceeds thr."""
    for seed in (1, 2, 3):
        S, hp, theta, psx_c = _mid_fit(ard, False, seed=seed, d=7)
        d = 7
        cand = jf._prune_candidates(theta, S, psx_c, hp)
        thr = torch.tensor(0.01, dtype=F64)
        pick = torch.zeros(d, dtype=torch.bool)
        L = jf._theta_bound(theta, *S, psx_c, hp)
        while True:
            trial = [pick | (torch.arange(d) == m) for m in range(d)]
            gains = torch.stack(
                [jf._theta_bound(jf._with_prunes(cand, t, hp), *S, psx_c, hp) - L for t in trial]
            )
            gains = torch.where(pick, -torch.inf, gains)
            assert bool(((gains - thr).abs() > 1e-6).all())  # no call on round-off
            best = int(gains.argmax())
            if float(gains[best]) <= float(thr):
                break
            pick, L = trial[best], L + gains[best]
        greedy = jf._greedy_prunes(cand, S, thr)
        assert greedy.tolist() == pick.tolist()


def test_pruned_variances_are_stationary_where_both_loadings_are_pruned():
    """With alpha shared and psi_x free a prune zeroes both loadings, and `_pruned_variances`
    puts V_z, V_x where the bound's gradient in log V vanishes (autograd; it is of order 1/2
    before, the entropy's)."""
    S, hp, theta, psx_c = _mid_fit("shared", False)
    cand = jf._prune_candidates(theta, S, psx_c, hp)
    d = S.xy.shape[-1]
    th = jf._with_prunes(cand, torch.ones(d, dtype=torch.bool), hp).requires_grad_(True)
    (g,) = torch.autograd.grad(jf._theta_bound(th, *S, psx_c, hp), th)
    assert float(g[2 * d : 4 * d].abs().max()) < 1e-6


@pytest.mark.parametrize("fixed_x", [False, True])
def test_pruned_inputs_held_during_the_fit_end_at_the_full_bounds_stationary_point(fixed_x):
    """The optimiser holds a pruned input's <w_z> at 0 while Newton converges on the others,
    then frees it: the fit ends where no coordinate, the pruned inputs' <w_z> included, has a
    Newton gain of its own above 1e-9 nats (one coordinate's g^2 / (2 |H_ii|)), and no <w_z>
    is left at exactly 0 (held ones still would be)."""
    d, n_irr = 8, 5
    hp = _hyper("output", fixed_x)
    X, y = _data(2000, d, seed=3, n_irrelevant=n_irr)
    S = _standardised(X, y)
    psx = torch.full((d,), 0.5 / 1.5, dtype=F64) if fixed_x else None
    res = jf.fit(S, psx, hp, method="newton", max_iter=2000, tol=1e-12, coef_tol=1e-9)
    assert int(res.reason) == 1  # converged
    mz = res.st[jb.MZ]
    pruned = mz.abs() < 1e-2
    assert int(pruned.sum()) >= 3  # the irrelevant inputs were pruned
    assert bool((mz != 0).all())
    theta = jf._pack(res.st, res.psy, hp)[None]
    batch = jb.Stats(*(t[None] for t in S))
    cv = jn.derivatives(theta, batch, res.st[jb.PX][None], hp)
    H = jn.dense_hessian(cv, batch.xx)[0]
    lb = torch.full(theta.shape[-1:], -torch.inf, dtype=F64)  # the floors, as in the fit
    lb[4 * d : (5 if fixed_x else 6) * d] = math.log(hp.floor)
    lb[-1] = math.log(hp.floor_y)
    free = ~((theta[0] <= lb * (1 - 1e-12)) & (cv.g[0] <= 0))
    gains = cv.g[0] ** 2 / (2 * H.diagonal().abs().clamp_min(1e-300))
    assert float(gains[free].max()) <= 1e-9


@pytest.mark.parametrize("pick", [[True, True, True, True], [False, True, False, True]])
def test_the_optimisers_row_selection_is_plain_indexing(pick):
    mask = torch.tensor(pick)
    t = torch.arange(12.0).reshape(4, 3)
    rows = jb.Rows(mask)
    assert torch.equal(rows.take(t), t[mask])
    S = jb.Stats(*(torch.randn(4, *shape) for shape in ((2, 2), (2,), (), ())))
    assert all(torch.equal(a, b[mask]) for a, b in zip(rows.stats(S), S, strict=True))
    got, want = t.clone(), t.clone()
    rows.put(got, -t[mask])
    want[mask] = -t[mask]
    assert torch.equal(got, want)
    for inner in (torch.tensor([True, False] * (int(mask.sum()) // 2)), mask[mask]):
        assert torch.equal(rows.sub(jb.Rows(inner)).take(t), t[mask][inner])


def test_matvec_of_a_batch_is_each_problems_own_bitwise():
    g = torch.Generator().manual_seed(3)
    A = torch.randn(5, 33, 33, generator=g, dtype=F64)
    x = torch.randn(5, 33, generator=g, dtype=F64)
    full = jb.matvec(A, x)
    torch.testing.assert_close(full, (A @ x[..., None])[..., 0], rtol=1e-13, atol=1e-13)
    for i in range(5):
        assert torch.equal(jb.matvec(A[i : i + 1], x[i : i + 1])[0], full[i])
