"""The `fit` and `make_consistent` stages on prepared logs: npz/in-memory logs -> Moments ->
estimator -> projection.

References are independent of the streaming code: the regressor of the whole log at once with
`Moments.from_data` (the in-memory path), folds cut by hand, and torques computed directly.
"""

import math
import shutil
import tracemalloc

import numpy as np
import pytest
import torch
from _flow import fit_logs
from _robots import TWO_LINK

from torchjfa.data import log_length
from torchjfa.dynamics import InverseDynamics, RigidBodyModel
from torchjfa.estimators import OLS, BayesianJFA, Ridge
from torchjfa.identification import IdentificationResult, residual_joint_weights, stream_moments
from torchjfa.physical import check, project
from torchjfa.sim import SimulatedLog, generate_log, model_path
from torchjfa.stats import Moments

N_SAMPLES = 1500
FIELDS = ("n", "sum_x", "sum_y", "xtx", "xty", "yty")


def rel(a, b) -> float:
    return float((a - b).abs().max() / b.abs().max().clamp_min(1e-300))


def assert_moments_equal(a: Moments, b: Moments, rtol: float = 1e-12) -> None:
    assert a.n_rows == b.n_rows
    for k in FIELDS:
        assert rel(getattr(a, k), getattr(b, k)) <= rtol, k


@pytest.fixture(scope="module")
def head():
    model = RigidBodyModel.from_mjcf(model_path("head"))
    log = generate_log("head", n_samples=N_SAMPLES, seed=3)
    Y = model.regressor(log.q, log.qd, log.qdd)  # (n, 7, 77): the in-memory path
    return model, log, Y


@pytest.fixture(scope="module")
def reference(head):
    model, log, Y = head
    return Moments.from_data(Y.reshape(-1, model.n_params), log.tau.reshape(-1))


@pytest.fixture(scope="module")
def files(head, tmp_path_factory):
    """The log as a compressed SimulatedLog file, and split in two uncompressed npz files with
    the joints in another order (and one array stored in Fortran order)."""
    _, log, _ = head
    d = tmp_path_factory.mktemp("logs")
    compressed = d / "log.npz"
    log.save(compressed)
    perm = [3, 0, 6, 1, 5, 2, 4]
    names = np.array([log.joint_names[j] for j in perm])
    parts = []
    for i, (a, b) in enumerate(((0, 600), (600, N_SAMPLES))):
        arrays = {k: getattr(log, k)[a:b, perm].numpy() for k in ("q", "qd", "qdd", "tau")}
        arrays["qd"] = np.asfortranarray(arrays["qd"])
        path = d / f"part{i}.npz"
        np.savez(path, joint_names=names, **arrays)
        parts.append(path)
    return compressed, parts


def test_stream_compressed_npz_equals_in_memory(head, reference, files):
    model, _, _ = head
    m = stream_moments(model, files[0], chunk_size=256)
    assert isinstance(m, Moments) and m.n_features == model.n_params
    assert m.n_rows == N_SAMPLES * model.n_dof
    assert_moments_equal(m, reference)


def test_stream_with_the_compiled_regressor_equals_in_memory(
    head, reference, files, tmp_path, monkeypatch
):
    if not any(shutil.which(c) for c in ("g++", "c++", "clang++")):
        pytest.skip("no C++ compiler")
    monkeypatch.setenv("TORCHJFA_CACHE_DIR", str(tmp_path))
    model, _, _ = head
    m = stream_moments(model, files[1], chunk_size=256, compiled=True)
    assert_moments_equal(m, reference)


def test_stream_split_permuted_uncompressed_files_equal_in_memory(head, reference, files):
    model, log, _ = head
    compressed, parts = files
    assert [log_length(p) for p in parts] == [600, N_SAMPLES - 600]
    assert_moments_equal(stream_moments(model, parts, chunk_size=333), reference)
    # mixing kinds of logs: a file, a SimulatedLog slice as a dict of tensors
    tail = {k: getattr(log, k)[600:] for k in ("q", "qd", "qdd", "tau")}
    assert_moments_equal(stream_moments(model, [parts[0], tail], chunk_size=1000), reference)


def test_stream_simulated_log_and_memmap(head, reference, tmp_path):
    model, log, _ = head
    assert_moments_equal(stream_moments(model, log, chunk_size=100), reference)
    maps = {}
    for k in ("q", "qd", "qdd", "tau"):
        np.save(tmp_path / f"{k}.npy", getattr(log, k).numpy())
        maps[k] = np.load(tmp_path / f"{k}.npy", mmap_mode="r")
    assert_moments_equal(stream_moments(model, maps, chunk_size=512), reference)


def test_fold_moments_match_hand_cut_folds(head, files):
    model, log, Y = head
    _, parts = files
    folds = stream_moments(model, parts, n_folds=4, chunk_size=200)
    assert isinstance(folds, list) and len(folds) == 4
    for k, fold in enumerate(folds):
        a, b = round(k * N_SAMPLES / 4), round((k + 1) * N_SAMPLES / 4)
        ref = Moments.from_data(Y[a:b].reshape(-1, model.n_params), log.tau[a:b].reshape(-1))
        assert_moments_equal(fold, ref)


def test_identify_ols_equals_in_memory_fit(head, reference, files):
    model, _, _ = head
    result = fit_logs(
        model, files[0], estimator=OLS(fit_intercept=False), project=False, chunk_size=300
    )
    assert isinstance(result, IdentificationResult)
    expected = OLS(fit_intercept=False).fit_moments(reference).coef_
    assert rel(result.theta_hat, expected) <= 1e-10
    assert result.theta is result.theta_hat and result.projection is None
    assert result.n_samples == N_SAMPLES and result.world_size == 1
    assert "n_samples=1500" in repr(result) and "OLS" in repr(result)


def test_identify_bayesian_jfa_equals_in_memory_fit(head, reference, files):
    model, _, _ = head
    # the defaults, fitted to convergence: the streamed moments (summed in another order)
    # give the in-memory fit's answer to round-off (the optimiser does not depend on the path)
    kw = {"fit_intercept": False}
    result = fit_logs(model, files[1], estimator=BayesianJFA(**kw), project=False)
    expected = BayesianJFA(**kw).fit_moments(reference)
    assert expected.converged_
    assert rel(result.theta_hat, expected.coef_) <= 1e-8
    # no input_noise given: the metric would take the estimator's psi_x
    assert rel(result.input_noise, expected.noise_x_) <= 1e-10


class _FoldOLS(OLS):
    """OLS that asks for cross-validation folds (as Lasso does without alpha), recording them;
    Lasso's own path is too slow on this ill-conditioned regressor for a unit test."""

    def __init__(self, *, cv: int) -> None:
        super().__init__(fit_intercept=False)
        self.cv = cv

    @property
    def needs_folds(self) -> bool:
        return True

    def _solve(self, moments, folds):
        self.seen_folds_ = folds
        return super()._solve(moments, folds)


def test_identify_gives_cross_validating_estimators_sample_folds(head, files):
    model, log, Y = head
    result = fit_logs(model, files[1], estimator=_FoldOLS(cv=3), project=False)
    assert len(result.folds) == 3 and len(result.estimator.seen_folds_) == 3
    bounds = [round(k * N_SAMPLES / 3) for k in range(4)]
    for k, (a, b) in enumerate(zip(bounds[:-1], bounds[1:], strict=True)):
        ref = Moments.from_data(Y[a:b].reshape(-1, model.n_params), log.tau[a:b].reshape(-1))
        assert_moments_equal(result.folds[k], ref)
    whole = Moments.from_data(Y.reshape(-1, model.n_params), log.tau.reshape(-1))
    assert_moments_equal(result.moments, whole)
    assert rel(result.theta_hat, OLS(fit_intercept=False).fit_moments(whole).coef_) <= 1e-10


def test_identify_projects_and_returns_inverse_dynamics(head, reference, files):
    model, log, Y = head
    noise = torch.full((model.n_params,), 1e-6, dtype=torch.float64)
    options = {"max_iter": 60, "warm_start": False}
    result = fit_logs(
        model,
        files[0],
        estimator=OLS(fit_intercept=False),
        input_noise=noise,
        projection_options=options,
    )
    assert check(result.theta, model).weakly_ok
    assert result.projection.cost <= result.projection.initial_cost
    direct = project(
        result.theta_hat, layout=model, moments=reference, input_noise=noise, **options,
        parametrization="virtual",  # fit_logs' (tests/_flow.py)
    )  # fmt: skip
    assert rel(result.theta, direct.theta) <= 1e-6
    # the module's torques and the training error, against the regressor written out
    idyn = result.inverse_dynamics()
    assert isinstance(idyn, InverseDynamics) and not idyn.trainable
    tau = idyn(log.q[:50], log.qd[:50], log.qdd[:50])
    assert rel(tau, Y[:50] @ result.theta) <= 1e-12
    residual = Y @ result.theta - log.tau
    assert result.rmse() == pytest.approx(float(residual.square().mean().sqrt()), rel=1e-8)
    assert rel(result.inverse_dynamics(projected=False).theta.detach(), result.theta_hat) == 0


@pytest.mark.parametrize("save", [np.savez, np.savez_compressed])
def test_npz_reader_memory_does_not_grow_with_the_log(tmp_path, save, monkeypatch):
    """numpy reports its allocations to tracemalloc: the traced peak while streaming a log 16x
    longer must stay that of a few chunks (torch's regressor rows are not traced; their bound
    is the regressor's batch, checked in the next test, so the regressor is stubbed here)."""
    model = RigidBodyModel.from_urdf(TWO_LINK)
    monkeypatch.setattr(
        model, "regressor", lambda q, qd, qdd, **kw: torch.ones(q.shape[0], 2, model.n_params)
    )
    g = torch.Generator().manual_seed(0)
    peaks = {}
    for n in (4_000, 64_000):
        path = tmp_path / f"log{n}.npz"
        sig = {k: torch.randn(n, 2, generator=g, dtype=torch.float64).numpy() for k in "abcd"}
        save(path, q=sig["a"], qd=sig["b"], qdd=sig["c"], tau=sig["d"])
        del sig
        tracemalloc.start()
        try:
            m = stream_moments(model, path, chunk_size=1000)
            _, peaks[n] = tracemalloc.get_traced_memory()
        finally:
            tracemalloc.stop()
        assert m.n_rows == 2 * n
    assert peaks[64_000] < 1.5 * peaks[4_000]
    assert peaks[64_000] < 4 * 64_000 * 2 * 8 / 8  # an eighth of the log's arrays


def test_regressor_never_sees_more_than_a_chunk(head, files, monkeypatch):
    model, _, _ = head
    seen = []
    original = model.regressor

    def counting(q, qd, qdd, **kw):
        seen.append(q.shape[0])
        return original(q, qd, qdd, **kw)

    monkeypatch.setattr(model, "regressor", counting)
    stream_moments(model, files[1], chunk_size=400)
    assert max(seen) <= 400 and sum(seen) == N_SAMPLES


def test_bad_input_raises(head, files, tmp_path):
    model, log, _ = head
    compressed, parts = files
    with pytest.raises(ValueError, match="fit_intercept"):
        fit_logs(model, compressed, estimator=OLS())
    with pytest.raises(TypeError, match="estimator"):
        fit_logs(model, compressed, estimator=object())
    with pytest.raises(TypeError, match="RigidBodyModel"):
        fit_logs("head", compressed)
    with pytest.raises(ValueError, match="input_noise"):
        fit_logs(model, compressed, input_noise=torch.ones(3))
    with pytest.raises(ValueError, match="input_noise"):
        fit_logs(model, compressed, input_noise=-1.0)
    with pytest.raises(ValueError, match="projection_options"):
        fit_logs(model, compressed, projection_options={"moments": None})
    with pytest.raises(ValueError, match="process group"):
        stream_moments(model, compressed, distributed=True)
    with pytest.raises(ValueError, match="chunk_size"):
        stream_moments(model, compressed, chunk_size=0)
    with pytest.raises(ValueError, match="n_folds"):
        stream_moments(model, compressed, n_folds=0)
    with pytest.raises(FileNotFoundError):
        stream_moments(model, tmp_path / "missing.npz")
    with pytest.raises(TypeError, match="log 0"):
        stream_moments(model, [np.zeros((3, 7))])
    with pytest.raises(ValueError, match="no logs"):
        stream_moments(model, [])
    no_qdd = tmp_path / "no_qdd.npz"
    np.savez(no_qdd, q=np.zeros((3, 7)), qd=np.zeros((3, 7)), tau=np.zeros((3, 7)))
    with pytest.raises(ValueError, match="qdd"):
        stream_moments(model, no_qdd)
    other = tmp_path / "other_joints.npz"
    z = np.zeros((3, 7))
    np.savez(other, q=z, qd=z, qdd=z, tau=z, joint_names=np.array([f"j{i}" for i in range(7)]))
    with pytest.raises(ValueError, match="joints"):
        stream_moments(model, other)
    with pytest.raises(ValueError, match="joint columns"):
        stream_moments(model, {"q": z[:, :3], "qd": z[:, :3], "qdd": z[:, :3], "tau": z[:, :3]})
    bad = {k: getattr(log, k)[:300].clone() for k in ("q", "qd", "qdd", "tau")}
    bad["qd"][250, 2] = math.nan
    with pytest.raises(ValueError, match=r"samples \[200, 300\)"):
        stream_moments(model, bad, chunk_size=100)
    assert isinstance(SimulatedLog.load(compressed), SimulatedLog)  # the fixture file is valid


def test_identify_jackknife_spread_matches_hand_cut_blocks(head, files):
    """theta_hat_std is the delete-one-block jackknife over K contiguous blocks of the samples
    (cut by hand here from the in-memory regressor), and the estimator still sees them all."""
    model, log, Y = head
    K = 3
    ridge = Ridge(alpha=1e-3, fit_intercept=False)  # well posed despite the unidentifiable columns
    result = fit_logs(model, files[1], estimator=ridge, project=False, jackknife=K)
    bounds = [round(k * N_SAMPLES / K) for k in range(K + 1)]
    eps = torch.finfo(torch.float64).eps

    def cond(m: Moments) -> float:  # of the system Ridge solves: X^T X + alpha 1, used columns
        a = torch.diagonal(m.xtx) > 0
        return float(torch.linalg.cond(m.xtx[a][:, a] + 1e-3 * torch.eye(int(a.sum())).to(m.xtx)))

    coefs, conds = [], []
    for k in range(K):
        keep = torch.ones(N_SAMPLES, dtype=torch.bool)
        keep[bounds[k] : bounds[k + 1]] = False
        m = Moments.from_data(Y[keep].reshape(-1, model.n_params), log.tau[keep].reshape(-1))
        coefs.append(Ridge(alpha=1e-3, fit_intercept=False).fit_moments(m).coef_)
        conds.append(cond(m))
    C = torch.stack(coefs)
    std = ((K - 1) / K * (C - C.mean(0)).pow(2).sum(0)).sqrt()
    # Tolerances from the arithmetic, not from one machine: the streamed moments are summed in
    # another order (chunks, joint permutation) than Moments.from_data, so they differ by a few
    # eps, and each backward-stable solve adds a few eps of backward error; a system of condition
    # number kappa turns that into a relative error of up to ~kappa * eps in its solution (kappa
    # ~1.6e9 here: the head's unidentifiable directions are held only by alpha = 1e-3). Two
    # solutions (streamed, in-memory), each with its moments' and its solver's error: 4 kappa eps
    # (~1.4e-6; 1e-7 was seen on one install, 7e-9 on another, depending on the BLAS).
    whole = Moments.from_data(Y.reshape(-1, model.n_params), log.tau.reshape(-1))
    full = Ridge(alpha=1e-3, fit_intercept=False).fit_moments(whole).coef_
    assert rel(result.theta_hat, full) <= 4 * cond(whole) * eps
    # the spread is a difference of the K refits: their errors, ~kappa_k eps * max|C| each, are
    # measured against max(std), which is ~17 times smaller than max|C| here
    tol_std = 4 * max(conds) * eps * float(C.abs().max() / std.max())
    assert rel(result.theta_hat_std, std) <= tol_std
    with pytest.raises(ValueError, match="jackknife"):
        fit_logs(model, files[1], estimator=OLS(fit_intercept=False), jackknife=1)


def test_joint_weights_weight_each_joints_rows(head, files):
    model, log, Y = head
    w = torch.tensor([0.5, 2.0, 1.0, 3.0, 0.25, 1.0, 0.25], dtype=torch.float64)
    got = stream_moments(model, files[1], joint_weights=w, chunk_size=256)
    rows = w.repeat(N_SAMPLES)  # row (sample i, joint j) has weight w_j
    ref = Moments.from_data(Y.reshape(-1, model.n_params), log.tau.reshape(-1), rows)
    assert_moments_equal(got, ref)
    parts = stream_moments(model, files[1], per_joint=True, chunk_size=256)
    assert len(parts) == model.n_dof
    for j, part in enumerate(parts):
        assert_moments_equal(part, Moments.from_data(Y[:, j], log.tau[:, j]))
    with pytest.raises(ValueError, match="joint_weights"):
        stream_moments(model, files[1], joint_weights=-w)


def test_residual_joint_weights_are_inverse_ols_residual_variances(head, files):
    model, log, Y = head
    w = residual_joint_weights(model, files[1])
    X = Y.reshape(-1, model.n_params).numpy()
    theta = np.linalg.lstsq(X, log.tau.reshape(-1).numpy(), rcond=None)[0]
    res = log.tau.numpy() - (Y.numpy() @ theta)
    inv = 1.0 / (res**2).mean(0)
    # the head's regressor is rank deficient: the normal-equation solve and lstsq's minimum-norm
    # solution leave residuals that differ by ~0.1 %
    np.testing.assert_allclose(w.numpy(), inv / inv.mean(), rtol=5e-3)
    assert float(w.mean()) == pytest.approx(1.0)
    result = fit_logs(
        model, files[1], estimator=OLS(fit_intercept=False), joint_weights=w, project=False
    )
    torch.testing.assert_close(result.joint_weights, w)


def _two_link_log(n=600, seed=0):
    model = RigidBodyModel.from_urdf(TWO_LINK)
    g = torch.Generator().manual_seed(seed)
    q, qd, qdd = (torch.randn(n, 2, generator=g, dtype=torch.float64) for _ in range(3))
    Y = model.regressor(q, qd, qdd)
    theta = model.nominal_theta.clone()
    theta[model.parameter_names.index("j1.fv")] = 0.1
    tau = Y @ theta + 0.01 * torch.randn(n, 2, generator=g, dtype=torch.float64)
    return model, {"q": q, "qd": qd, "qdd": qdd, "tau": tau}


def test_auto_prior_scores_each_block_by_the_closed_form_written_out():
    """``description_prior="auto"``'s scores, recomputed from the rows: per block, least squares
    on the other blocks' rows, the prior's posterior mean ``(M + w s^2 diag(p^-2))^-1 (M
    theta_hat + w s^2 diag(p^-2) nominal)`` (``s^2`` the residual variance per row, ``p`` the
    description's parameter scales; a 1e-8 ridge at w = 0), the held-out block's squared error;
    the RMS over all rows."""
    from torchjfa.estimators import OLS
    from torchjfa.identification import PRIOR_BLOCKS, PRIOR_WEIGHTS
    from torchjfa.physical import parameter_scales

    model, log = _two_link_log()
    auto = fit_logs(model, log, estimator=OLS(fit_intercept=False), description_prior="auto")
    Y, tau = model.regressor(log["q"], log["qd"], log["qdd"]), log["tau"]
    n, d = Y.shape[0], model.n_params
    bounds = [round(k * n / PRIOR_BLOCKS) for k in range(PRIOR_BLOCKS + 1)]
    rss = dict.fromkeys(PRIOR_WEIGHTS, 0.0)
    for a, b in zip(bounds, bounds[1:], strict=False):
        rest = torch.ones(n, dtype=torch.bool)
        rest[a:b] = False
        X, y = Y[rest].reshape(-1, d).numpy(), tau[rest].reshape(-1).numpy()
        Xk, yk = Y[a:b].reshape(-1, d).numpy(), tau[a:b].reshape(-1).numpy()
        theta_hat = np.linalg.lstsq(X, y, rcond=None)[0]
        M = X.T @ X
        s2 = float(((y - X @ theta_hat) ** 2).sum()) / len(y)
        scale = parameter_scales(
            model.parameter_names, model.nominal_theta, Moments.from_data(X, y)
        ).numpy()
        nominal = model.nominal_theta.numpy()
        for w in PRIOR_WEIGHTS:
            lam = w * s2 / scale**2
            A = M + np.diag(lam) + (1e-8 * np.trace(M) / d * np.eye(d) if w == 0 else 0.0)
            theta = np.linalg.lstsq(A, M @ theta_hat + lam * nominal, rcond=None)[0]
            rss[w] += float(((yk - Xk @ theta) ** 2).sum())
    expected = {w: math.sqrt(v / (n * model.n_dof)) for w, v in rss.items()}
    # at w = 0 the 1e-8 ridge alone holds the null direction of this model's columns (an exact
    # linear dependency): the system's condition number is up to d / 1e-8 = 2.2e9, and two
    # solvers agree to its product with the round-off, 2.2e9 * 2.2e-16 = 5e-7
    for w in PRIOR_WEIGHTS:
        assert auto.prior_choice[w] == pytest.approx(expected[w], rel=1e-6 if w == 0 else 1e-8), w


def test_auto_prior_reuses_the_jackknifes_refits(monkeypatch):
    """With the jackknife on the same blocks, the prior's choice takes its leave-one-block-out
    estimates instead of refitting: the same scores as the refits give (round-off)."""
    import torchjfa.identification._prior
    from torchjfa.identification import PRIOR_BLOCKS

    model, log = _two_link_log()
    refit = fit_logs(model, log, estimator=OLS(fit_intercept=False), description_prior="auto")

    def no_refit(*args):
        raise AssertionError("refitted although the jackknife's estimates were at hand")

    monkeypatch.setattr(torchjfa.identification._prior, "refit_without", no_refit)
    reuse = fit_logs(
        model, log, estimator=OLS(fit_intercept=False), description_prior="auto",
        jackknife=PRIOR_BLOCKS,
    )  # fmt: skip
    assert reuse.theta_hat_jackknife.shape[0] == PRIOR_BLOCKS
    for w, v in refit.prior_choice.items():
        assert reuse.prior_choice[w] == pytest.approx(v, rel=1e-9), w


def test_description_prior_options():
    from torchjfa.estimators import OLS
    from torchjfa.identification import PRIOR_WEIGHTS

    model, log = _two_link_log()
    plain = fit_logs(model, log, estimator=OLS(fit_intercept=False), jackknife=3)
    assert plain.prior_weight is None and plain.prior_choice is None
    assert plain.theta_hat_jackknife.shape == (3, model.n_params)
    # weight 0: the plain projection, exactly (same moments, no prior term)
    zero = fit_logs(
        model, log, estimator=OLS(fit_intercept=False), jackknife=3, description_prior=0
    )
    assert torch.equal(zero.theta, plain.theta) and zero.prior_weight == 0.0
    auto = fit_logs(model, log, estimator=OLS(fit_intercept=False), description_prior="auto")
    assert set(auto.prior_choice) == set(PRIOR_WEIGHTS) and auto.prior_weight in PRIOR_WEIGHTS
    assert auto.folds is None  # the blocks of the choice are not the result's folds
    assert all(v > 0 for v in auto.prior_choice.values())
    # an out-of-plane parameter (a zero column) goes towards the description with a prior
    # (not all the way at the default tol: the prior's curvature is ~1/N of the data's, below
    # the stopping test's resolution; tol=1e-10 gets within 0.1% with "virtual")
    strong = fit_logs(model, log, estimator=OLS(fit_intercept=False), description_prior=1.0)
    i = model.parameter_names.index("j2.Ixx")
    nominal = float(model.nominal_theta[i])
    assert abs(float(strong.theta[i]) - nominal) < 0.2 * nominal
    assert abs(float(strong.theta[i]) - nominal) < 0.5 * abs(float(plain.theta[i]) - nominal)
    # and the fit is the data's: the training error within 1% of the plain projection's
    assert strong.rmse() <= plain.rmse() * 1.01
    for bad, match in ((-1.0, "weight >= 0"), ("best", "'auto'"), (True, "weight >= 0")):
        with pytest.raises(ValueError, match=match):
            fit_logs(model, log, estimator=OLS(fit_intercept=False), description_prior=bad)
    with pytest.raises(ValueError, match="project=True"):
        fit_logs(model, log, project=False, description_prior=1.0)
    with pytest.raises(ValueError, match="do not also pass"):
        fit_logs(model, log, description_prior=1.0, projection_options={"prior_weight": 1.0})
