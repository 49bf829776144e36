"""BayesianJFA: against a per-sample variational EM written out here, and its properties."""

import math

import pytest
import torch

from torchjfa.estimators import JFA, BayesianJFA
from torchjfa.stats import Moments

F64 = torch.float64
LOG2PI = math.log(2 * math.pi)


def _model_data(n, d, *, seed, psx=0.5, n_irrelevant=0, intercept=0.0):
    """Data drawn from the model: independent t, x = t + noise, y = sum_m b_m t_m + noise."""
    g = torch.Generator().manual_seed(seed)
    b = torch.linspace(1.0, 2.0, d, dtype=F64)
    b[d - n_irrelevant :] = 0.0
    t = torch.randn(n, d, generator=g, dtype=F64)
    X = t + math.sqrt(psx) * torch.randn(n, d, generator=g, dtype=F64) + 3.0
    y = t @ b + 0.3 * torch.randn(n, generator=g, dtype=F64) + intercept
    return X, y, b


def _hard_data(kind, seed=0):
    """Ill-conditioned and redundant designs."""
    g = torch.Generator().manual_seed(seed)
    n = 300
    if kind == "ill":
        base = torch.randn(n, 3, generator=g, dtype=F64)
        X = torch.cat([base, base @ torch.randn(3, 3, generator=g, dtype=F64) * 1e-3], 1)
        X = X + 1e-4 * torch.randn(n, 6, generator=g, dtype=F64)
        X[:, 1] *= 1e4  # badly scaled too
    elif kind == "redundant":
        base = torch.randn(n, 4, generator=g, dtype=F64)
        X = torch.cat([base, base[:, :2], base[:, :3].sum(1, keepdim=True)], 1)  # exact copies
    else:
        X = torch.randn(n, 5, generator=g, dtype=F64) * torch.tensor([1, 2, 3, 4, 5.0], dtype=F64)
    y = (X[:, :3] / X[:, :3].std(0)) @ torch.tensor([1.0, -2.0, 0.5], dtype=F64)
    y = y + 0.5 * torch.randn(n, generator=g, dtype=F64)
    return X, y


# ---------------------------------------------------------------- the per-sample reference
def _reference(X, y, n_iter, a0=1e-8, b0=1e-8, floor=1e-6, floor_y=1e-3, ard="shared", lam=1e-8):
    """Variational EM with an explicit 2d x 2d posterior of (z_i, t_i) per sample.

    Standardises like the library (centre, unit variance), starts from the note's
    initialisation, and returns per iteration the bound on log p(X, y) in the caller's units,
    plus the final parameters in the caller's units. ``ard="output"``: alpha_m is the prior
    precision of w_zm alone, and w_xm ~ N(0, 1 / lam).
    """
    shared = ard == "shared"
    N, d = X.shape
    mx_, my_ = X.mean(0), y.mean()
    sx = ((X - mx_) ** 2).mean(0).sqrt()
    sy = ((y - my_) ** 2).mean().sqrt()
    Xs, ys = (X - mx_) / sx, (y - my_) / sy
    a = a0 + (1.0 if shared else 0.5)  # the shape of Q(alpha): a0 + (loadings under it) / 2
    # initialisation (note): w_x = sqrt(.5 var), psi_x = .5 var, w_z = cov / w_x
    wx = torch.full((d,), math.sqrt(0.5), dtype=F64)
    psx = torch.full((d,), 0.5, dtype=F64)
    wz = (Xs * ys[:, None]).mean(0) / wx
    left = 1.0 - float((wz**2).sum())
    assert left > 0.05, "pick test data where the initial leftover variance is positive"
    psy = left / 2
    psz = torch.full((d,), left / (2 * d), dtype=F64)
    vz = torch.zeros(d, dtype=F64)
    vx = torch.zeros(d, dtype=F64)
    bq = b0 + 0.5 * (wz**2 + (wx**2 if shared else 0.0))  # Q(alpha) once before anything else

    def posterior():
        """Per sample: invert the (z_i, t_i) precision; return means (N, 2d) and covs."""
        means, covs = [], []
        for i in range(N):
            P = torch.zeros(2 * d, 2 * d, dtype=F64)
            P[:d, :d] = torch.diag(1 / psz) + torch.ones(d, d, dtype=F64) / psy
            P[d:, d:] = torch.diag(1 + (wz**2 + vz) / psz + (wx**2 + vx) / psx)
            P[:d, d:] = torch.diag(-wz / psz)
            P[d:, :d] = torch.diag(-wz / psz)
            h = torch.cat([torch.ones(d, dtype=F64) * ys[i] / psy, wx * Xs[i] / psx])
            cov = torch.linalg.inv(P)
            means.append(cov @ h)
            covs.append(cov)
        return torch.stack(means), torch.stack(covs)

    def expectations(mu, cov):
        zz = (mu[:, :d] ** 2 + torch.diagonal(cov[:, :d, :d], dim1=1, dim2=2)).sum(0)
        tt = (mu[:, d:] ** 2 + torch.diagonal(cov[:, d:, d:], dim1=1, dim2=2)).sum(0)
        zt = (mu[:, :d] * mu[:, d:] + torch.diagonal(cov[:, :d, d:], dim1=1, dim2=2)).sum(0)
        xt = (Xs * mu[:, d:]).sum(0)
        return zz, tt, zt, xt

    def elbo(mu, cov):
        """The bound from its definition: E[log joint] + entropies, summed over samples."""
        zz, tt, zt, xt = expectations(mu, cov)
        one = torch.ones(d, dtype=F64)
        L = 0.0
        for i in range(N):
            e_y = (ys[i] - one @ mu[i, :d]) ** 2 + one @ cov[i, :d, :d] @ one
            L += -0.5 * math.log(2 * math.pi * psy) - e_y / (2 * psy)
            L += 0.5 * torch.logdet(2 * math.pi * math.e * cov[i])  # entropy of Q(z_i, t_i)
        ezz = zz - 2 * wz * zt + (wz**2 + vz) * tt
        exx = (Xs**2).sum(0) - 2 * wx * xt + (wx**2 + vx) * tt
        L += (-0.5 * N * torch.log(2 * math.pi * psz) - ezz / (2 * psz)).sum()
        L += (-0.5 * N * torch.log(2 * math.pi * psx) - exx / (2 * psx)).sum()
        L += (-0.5 * N * LOG2PI - 0.5 * tt).sum()  # E log p(t)
        ea = a / bq
        elog = torch.special.digamma(torch.tensor(a, dtype=F64)) - torch.log(bq)
        for w2 in (wz**2 + vz, wx**2 + vx) if shared else (wz**2 + vz,):  # E log N(w; 0, 1/alpha)
            L += (0.5 * (elog - LOG2PI - ea * w2)).sum()
        if not shared:  # E log N(w_x; 0, 1 / lam)
            L += (0.5 * (math.log(lam) - LOG2PI - lam * (wx**2 + vx))).sum()
        L += (a0 * math.log(b0) - math.lgamma(a0) + (a0 - 1) * elog - b0 * ea).sum()
        L += (0.5 * torch.log(2 * math.pi * math.e * vz)).sum()
        L += (0.5 * torch.log(2 * math.pi * math.e * vx)).sum()
        dig = float(torch.special.digamma(torch.tensor(a, dtype=F64)))
        L += (a - torch.log(bq) + math.lgamma(a) + (1 - a) * dig).sum()  # entropy of Gamma
        return float(L) - N * float(torch.log(sx).sum() + torch.log(sy))

    bounds = []
    for it in range(n_iter + 1):
        mu, cov = posterior()
        if it > 0:  # the library records the bound from the first sweep on
            bounds.append(elbo(mu, cov))
        if it == n_iter:
            break
        zz, tt, zt, xt = expectations(mu, cov)
        ea = a / bq
        vz = 1 / (tt / psz + ea)
        wz = vz * zt / psz
        vx = 1 / (tt / psx + (ea if shared else lam))
        wx = vx * xt / psx
        bq = b0 + 0.5 * (wz**2 + vz + (wx**2 + vx if shared else 0.0))
        one = torch.ones(d, dtype=F64)
        e_y = ((ys - mu[:, :d] @ one) ** 2).sum() + N * (one @ cov[0, :d, :d] @ one)
        psz = ((zz - 2 * wz * zt + (wz**2 + vz) * tt) / N).clamp_min(floor)
        psx = (((Xs**2).sum(0) - 2 * wx * xt + (wx**2 + vx) * tt) / N).clamp_min(floor)
        psy = max(float(e_y) / N, floor_y)
    # eq. (3) of the paper, written with its matrices A, B (at the final state)
    one = torch.ones(d, dtype=F64)
    A = 1 + (wz**2 + vz) / psz + (wx**2 + vx) / psx
    B = torch.outer(one, one) / psy + torch.diag(1 / psz - (wz / psz) ** 2 / A)
    Bi1 = torch.linalg.solve(B, one)
    k = psy * Bi1 / (psy - one @ Bi1) * (wz / psz) / A * (wx / psx)
    wx2 = wx**2 + vx
    return {
        "lower_bound": torch.tensor(bounds, dtype=F64),
        "coef": wz * wx / wx2 * sy / sx,
        "coef_noisy": k * sy / sx,
        "noise_x": psx * sx**2,
        "noise_z": psz * sy**2,
        "noise_y": torch.as_tensor(psy * sy**2, dtype=F64),
        "relevance": a / bq,
    }


@pytest.mark.parametrize("ard", ["shared", "output"])
def test_matches_per_sample_reference(ard):
    X, y, _ = _model_data(40, 4, seed=3, psx=0.3)
    y = y + 6.0 * torch.randn(40, generator=torch.Generator().manual_seed(4), dtype=F64)
    n_iter = 4
    kw = dict(max_iter=n_iter, tol=0.0, coef_tol=0.0, method="em", ard=ard)
    est = BayesianJFA(**kw).fit(X, y)
    ref = _reference(X, y, n_iter, ard=ard)
    assert est.n_iter_ == n_iter and est.stop_reason_ == "max_iter" and not est.converged_
    torch.testing.assert_close(est.lower_bound_, ref["lower_bound"], rtol=1e-10, atol=0)
    for key in ("coef", "coef_noisy", "noise_x", "noise_z", "noise_y", "relevance"):
        got = getattr(est, key + "_")
        torch.testing.assert_close(got, ref[key], rtol=1e-10, atol=1e-12, msg=key)


@pytest.mark.parametrize(
    "kind", ["plain", "ill", "redundant", "model", "known_noise", "known_noise_output_ard"]
)
@pytest.mark.parametrize("method", ["em", "newton"])
def test_bound_never_decreases(kind, method):
    noise = None
    if kind.startswith(("model", "known_noise")):
        X, y, _ = _model_data(400, 6, seed=1, n_irrelevant=2)
        noise = torch.full((6,), 0.5, dtype=F64) if kind.startswith("known_noise") else None
    else:
        X, y = _hard_data(kind)
    est = BayesianJFA(
        max_iter=1500,
        tol=0.0,
        coef_tol=0.0,
        method=method,
        input_noise=noise,
        ard="output" if kind.endswith("output_ard") else "shared",
    ).fit(X, y)
    L = est.lower_bound_
    assert L.dtype == F64 and L.shape == (est.n_iter_,) and bool(torch.isfinite(L).all())
    assert float(L.diff().min()) >= -1e-9 * float(L.abs().max())
    assert float(L[-1]) > float(L[0])
    assert bool(torch.isfinite(est.coef_).all()) and bool(torch.isfinite(est.coef_noisy_).all())


def test_irrelevant_inputs_are_pruned():
    X, y, b = _model_data(1000, 8, seed=2, n_irrelevant=3)
    est = BayesianJFA(max_iter=5000).fit(X, y)
    rel, irr = est.relevance_[:5], est.relevance_[5:]
    assert float(irr.min()) > 1e3 * float(rel.max())
    assert float(est.coef_[5:].abs().max()) < 1e-3 * float(est.coef_[:5].abs().min())
    assert float(est.coef_noisy_[5:].abs().max()) < 1e-3 * float(est.coef_noisy_[:5].abs().min())
    assert bool((est.coef_[:5] > 0.5 * b[:5]).all())


def test_output_ard_prunes_what_shared_ard_cannot_with_known_noise():
    # with psi_x known, w_x of an irrelevant input is pinned to sqrt(var(x) - psi_x), so an
    # alpha shared with w_x stays O(1) and does not prune it; an alpha on w_z alone does
    X, y, b = _model_data(1000, 8, seed=2, n_irrelevant=3)
    noise = torch.full((8,), 0.5, dtype=F64)
    fits = {
        ard: BayesianJFA(input_noise=noise, ard=ard, max_iter=100_000).fit(X, y)
        for ard in ("shared", "output")
    }
    shared, output = fits["shared"], fits["output"]
    assert shared.converged_ and output.converged_
    assert float(shared.relevance_[5:].max()) < 10 * float(shared.relevance_[:5].min())
    assert float(shared.coef_[5:].abs().max()) > 0.01
    assert float(output.relevance_[5:].min()) > 1e5 * float(output.relevance_[:5].max())
    assert float(output.coef_[5:].abs().max()) < 1e-3 * float(output.coef_[:5].abs().min())
    err = {k: float(torch.linalg.vector_norm(e.coef_ - b)) for k, e in fits.items()}
    assert err["output"] < err["shared"]
    with pytest.raises(ValueError, match="ard must be"):
        BayesianJFA(ard="both").fit(X, y)


def test_known_input_noise_recovers_true_coefficients():
    psx = 0.5
    X, y, b = _model_data(4000, 8, seed=5, psx=psx)
    est = BayesianJFA(input_noise=torch.full((8,), psx, dtype=F64)).fit(X, y)
    A = torch.cat([X, torch.ones(4000, 1, dtype=F64)], 1)
    ols = torch.linalg.lstsq(A, y[:, None]).solution[:8, 0]
    err_ols = float(torch.linalg.vector_norm(ols - b) / torch.linalg.vector_norm(b))
    err = float(torch.linalg.vector_norm(est.coef_ - b) / torch.linalg.vector_norm(b))
    assert err_ols > 0.25  # OLS is attenuated by var(t) / (var(t) + psi_x) = 2/3
    assert err < 0.25 * err_ols
    torch.testing.assert_close(est.noise_x_, torch.full((8,), psx, dtype=F64))  # held fixed
    assert est.converged_ and est.stop_reason_ in ("bound", "coef")


def test_chunks_equal_whole():
    X, y, _ = _model_data(300, 5, seed=7, n_irrelevant=1)
    # plain EM for a fixed number of sweeps: the same path, step for step
    kw = dict(max_iter=100, tol=0.0, coef_tol=0.0, method="em")
    whole = BayesianJFA(**kw).fit(X, y)
    chunks = [Moments.from_data(X[a : a + 70], y[a : a + 70]) for a in range(0, 300, 70)]
    for other in (
        BayesianJFA(**kw).fit_moments(sum(chunks)),
        BayesianJFA(**kw).fit_moments(chunks),
    ):
        for key in ("coef_", "coef_noisy_", "noise_x_", "noise_z_", "relevance_", "intercept_"):
            torch.testing.assert_close(
                getattr(other, key), getattr(whole, key), rtol=1e-8, atol=1e-10, msg=key
            )
        torch.testing.assert_close(other.lower_bound_, whole.lower_bound_, rtol=1e-10, atol=0)
    # converged with the defaults (the Newton optimiser), every estimate agrees to round-off
    # (tests/estimators/test_jfa_fit.py splits one problem more ways, for every variant)
    for noise in (None, torch.full((5,), 0.5, dtype=F64)):
        a = BayesianJFA(input_noise=noise).fit(X, y)
        b = BayesianJFA(input_noise=noise).fit_moments(chunks)
        assert a.converged_ and b.converged_
        for key in ("coef_", "coef_noisy_", "noise_x_", "noise_y_"):
            ref = getattr(a, key)
            torch.testing.assert_close(
                getattr(b, key), ref, rtol=1e-8, atol=1e-8 * float(ref.abs().max()), msg=key
            )


def test_predict_switch_and_intercepts():
    X, y, _ = _model_data(300, 4, seed=8, intercept=2.0)
    est = BayesianJFA(max_iter=500).fit(X, y)
    torch.testing.assert_close(est.predict(X), X @ est.coef_noisy_ + est.intercept_noisy_)
    torch.testing.assert_close(est.predict(X, noiseless=True), X @ est.coef_ + est.intercept_)
    # each intercept makes its predictor pass through the means of the data
    for noiseless in (False, True):
        assert float(est.predict(X, noiseless=noiseless).mean()) == pytest.approx(float(y.mean()))
    assert est.predict(X.float()).dtype == torch.float32
    est0 = BayesianJFA(max_iter=50, fit_intercept=False).fit(X - X.mean(0), y - y.mean())
    assert float(est0.intercept_) == 0.0 and float(est0.intercept_noisy_) == 0.0
    with pytest.raises(RuntimeError, match="not fitted"):
        BayesianJFA().predict(X)


def test_float32_input_and_progress_bar():
    X, y, _ = _model_data(200, 3, seed=9)
    e32 = BayesianJFA(verbose=True).fit(X.float(), y.float())
    e64 = BayesianJFA().fit(X, y)
    assert e32.converged_ and e64.converged_
    assert e32.coef_.dtype == F64 and e32.noise_x_.dtype == F64
    torch.testing.assert_close(e32.coef_, e64.coef_, rtol=1e-3, atol=1e-4)


@pytest.mark.parametrize("method", ["em", "newton"])
def test_progress_bar_does_not_change_the_path(method):
    X, y, _ = _model_data(300, 5, seed=11, n_irrelevant=2)
    kw = dict(max_iter=700, tol=0.0, coef_tol=0.0, method=method)
    whole = BayesianJFA(**kw).fit(X, y)
    shown = BayesianJFA(verbose=True, **kw).fit(X, y)
    assert shown.n_iter_ == whole.n_iter_ == 700
    assert torch.equal(shown.lower_bound_, whole.lower_bound_)
    assert torch.equal(shown.coef_, whole.coef_)


def test_bad_input_raises():
    X, y, _ = _model_data(50, 3, seed=0)
    for value, what in ((float("nan"), "NaN"), (float("inf"), "infinite")):
        bad = X.clone()
        bad[3, 1] = value
        with pytest.raises(ValueError, match=what):
            BayesianJFA().fit(bad, y)
    bad_y = y.clone()
    bad_y[0] = float("nan")
    with pytest.raises(ValueError, match="y has 1 NaN"):
        BayesianJFA().fit(X, bad_y)
    with pytest.raises(ValueError, match="different numbers of samples"):
        BayesianJFA().fit(X, y[:-1])
    with pytest.raises(ValueError, match="2-D"):
        BayesianJFA().fit(X[:, 0], y)
    with pytest.raises(ValueError, match="1-D"):
        BayesianJFA().fit(X, torch.stack([y, y], 1))
    with pytest.raises(ValueError, match="input_noise must have shape"):
        BayesianJFA(input_noise=torch.ones(4)).fit(X, y)
    with pytest.raises(ValueError, match="input_noise must have shape"):
        BayesianJFA(input_noise=torch.ones(3, 1)).fit(X, y)
    with pytest.raises(ValueError, match="must be >= 0"):
        BayesianJFA(input_noise=[0.1, -1.0, 0.1]).fit(X, y)
    with pytest.raises(ValueError, match="input_noise has 1 NaN"):
        BayesianJFA(input_noise=[0.1, float("nan"), 0.1]).fit(X, y)
    with pytest.raises(ValueError, match="a0"):
        BayesianJFA(a0=0.0).fit(X, y)
    with pytest.raises(ValueError, match="method must be one of 'newton', 'em'"):
        BayesianJFA(method="closed_form").fit(X, y)
    with pytest.raises(ValueError, match="tol"):
        BayesianJFA(tol=-1.0).fit(X, y)
    with pytest.raises(ValueError, match="y is constant"):
        BayesianJFA().fit(X, torch.ones(50, dtype=F64))
    with pytest.raises(ValueError, match="predict|features"):
        BayesianJFA(max_iter=5).fit(X, y).predict(X[:, :2])


def test_constant_column_gets_zero():
    X, y, _ = _model_data(300, 3, seed=0)
    X = torch.cat([X[:, :1], torch.full((300, 1), 7.0, dtype=F64), X[:, 1:]], 1)
    noise = torch.tensor([0.5, 0.0, 0.5, 0.5], dtype=F64)
    for kw in ({}, {"input_noise": noise}):
        est = BayesianJFA(max_iter=500, **kw).fit(X, y)
        assert est.coef_[1] == 0 and est.coef_noisy_[1] == 0
        assert est.relevance_[1] == math.inf and not bool(est.active_[1])
        assert bool(torch.isfinite(est.coef_).all()) and bool(
            torch.isfinite(est.lower_bound_).all()
        )
        assert bool((est.coef_[[0, 2, 3]] != 0).all())


@pytest.mark.parametrize("cls", [BayesianJFA, JFA])
def test_input_noise_at_or_above_a_columns_variance_is_refused(cls):
    """Noise >= var(x_m) leaves no signal in column m (psi_x + w_x^2 = var): the loop clamped
    it and returned [0.84, -3.20, 0.57, -0.02, 3.85, 0.03] for the truth [1, -2, 0.5, 0, 3, 0]."""
    g = torch.Generator().manual_seed(0)
    t = torch.randn(3000, 6, generator=g, dtype=F64)
    X = t + 0.3 * torch.randn(3000, 6, generator=g, dtype=F64)
    y = t @ torch.tensor([1, -2, 0.5, 0, 3, 0], dtype=F64)
    noise = torch.full((6,), 0.09, dtype=F64)
    # the variance itself is refused too; the estimator takes it from the moments
    # (sum x^2 / N - mean^2), which differs from torch.var by round-off, of order N eps = 7e-13
    # relative here (the BLAS's summation order decides the sign), so 1e-9 above it
    noise[1] = float(X[:, 1].var(correction=0)) * (1 + 1e-9)
    noise[4] = 2.0  # ~2x the variance
    with pytest.raises(ValueError, match=r"column 1: noise .* >= variance .*column 4: noise 2 "):
        cls(input_noise=noise).fit(X, y)
    noise[[1, 4]] = 0.09  # the true noise: fine
    est = cls(input_noise=noise).fit(X, y)
    # standard error of each slope ~ sqrt(0.09 |b|^2 / 3000) = 0.02 (input noise only): 5 of them
    assert float((est.coef_ - torch.tensor([1, -2, 0.5, 0, 3, 0], dtype=F64)).abs().max()) < 0.1
    # a column of round-off (a structurally zero regressor column, 1e-17) whose noise estimate,
    # round-off too, exceeds its variance is not refused: it carries nothing either way
    X = torch.cat([X, 1e-17 * torch.randn(3000, 1, generator=g, dtype=F64)], 1)
    noise = torch.cat([noise, torch.tensor([2e-34], dtype=F64)])
    est = cls(input_noise=noise).fit(X, y)
    assert float((est.coef_[:6] - torch.tensor([1, -2, 0.5, 0, 3, 0], dtype=F64)).abs().max()) < 0.1


def test_irrelevant_column_correlated_with_a_noisy_one_is_amplified_by_the_unidentified_split():
    """Why the default BayesianJFA() gives a large coef_ to an irrelevant column.

    Column 3 is irrelevant (truth 0) but correlated (0.5) with column 4, and every input is
    noisy: E[y | x] puts a small weight on x_3 (it carries information about t_4 that the noisy
    x_4 lost), which OLS and the noisy-input predictor share. Eq. (4) then divides that weight
    by the reliability 1 - psi_x / var(x) that the model attributes to the column; without
    input_noise this split is not identified (docs/theory.md), and the shared relevance
    prior, shrinking w_x of a column that matters little, puts ~90% of column 3's variance
    into psi_x (the truth: 8%): its coef_ comes out ~10x the predictor's. Given the input
    noise, the split is identified and the amplification is gone.
    """
    g = torch.Generator().manual_seed(1)
    n = 3000
    t = torch.randn(n, 6, generator=g, dtype=F64)
    t[:, 3] = 0.5 * t[:, 4] + math.sqrt(0.75) * t[:, 3]
    X = t + 0.3 * torch.randn(n, 6, generator=g, dtype=F64)  # noise variance 0.09, SNR ~11
    y = t @ torch.tensor([1, -2, 0.5, 0, 3, 1.5], dtype=F64) + 0.5 * torch.randn(
        n, generator=g, dtype=F64
    )
    ols = torch.linalg.lstsq(torch.cat([X, torch.ones(n, 1, dtype=F64)], 1), y[:, None]).solution
    est = BayesianJFA().fit(X, y)
    var = X.var(0, correction=0)
    k = est.coef_noisy_
    assert abs(float(ols[3])) < 0.2 and abs(float(k[3] - ols[3])) < 0.05  # the proxy weight
    reliability = 1 - est.noise_x_ / var
    assert float(reliability[3]) < 0.2 and bool((reliability[[0, 1, 4, 5]] > 0.8).all())
    assert abs(float(est.coef_[3])) > 5 * abs(float(k[3]))  # ~1.4, where OLS says 0.14
    # the mechanism: coef_ is the predictor divided by the reliability, column by column (to
    # 1%: <w_z><w_x>/<w_x^2> and k differ by the posterior spreads and the cross terms)
    torch.testing.assert_close(est.coef_, k / reliability, rtol=1e-2, atol=0)
    informed = BayesianJFA(input_noise=torch.full((6,), 0.09, dtype=F64)).fit(X, y)
    assert abs(float(informed.coef_[3])) < 1.5 * abs(float(informed.coef_noisy_[3]))
    assert abs(float(informed.coef_[3])) < 0.2
