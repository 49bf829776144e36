import math

import numpy as np
import pytest
import torch
from _bodies import VANISHING_MASSES, cloud_bodies, make_layout, vanishing_mass_theta

from torchjfa import Moments
from torchjfa.dynamics import ParameterLayout, inertial_vector, pseudo_inertia
from torchjfa.physical import LogCholeskyParameters, VirtualParameters, check, project

PARAMETRIZATIONS = ["virtual", "log-cholesky"]


def _cloud_theta(layout, g):
    """Fully consistent random bodies (point clouds), positive friction."""
    bodies = cloud_bodies(layout.n_joints, g, n_points=5, min_weight=0.2)
    friction = torch.rand(layout.n_joints, layout.n_friction, generator=g, dtype=torch.float64)
    return layout.join(bodies, friction + 0.05)


def _inconsistent(layout, g):
    """Consistent bodies damaged: negative masses, indefinite inertias, negative friction."""
    theta = _cloud_theta(layout, g).reshape(layout.n_joints, -1).clone()
    theta[::2, 0] = -0.5 * theta[::2, 0]
    theta[1::2, 4] -= 1.0
    theta[:, 10] -= 0.3
    return theta.reshape(-1)


def _metric(layout, g, rank_deficiency=3):
    """X^T X of random regressor-like rows that leave a few directions unexcited."""
    d = layout.n_params
    X = torch.randn(4 * d, d, generator=g, dtype=torch.float64)
    X = X * torch.logspace(0, -2, d, dtype=torch.float64)  # uneven scales
    X[:, :rank_deficiency] = 0.0
    return X.T @ X


def _clip_baseline(theta, layout):
    """A simple feasible point written with numpy: mass clipped to >= 1e-3, first moment kept
    (c = h / m), eigenvalues of I_c clipped at 0, friction clipped at 0."""
    out = []
    for row in theta.reshape(layout.n_joints, -1).numpy():
        m = max(row[0], 1e-3)
        c = row[1:4] / m
        io = np.array(
            [[row[4], row[5], row[7]], [row[5], row[6], row[8]], [row[7], row[8], row[9]]]
        )
        ic = io - m * ((c @ c) * np.eye(3) - np.outer(c, c))
        w, v = np.linalg.eigh(0.5 * (ic + ic.T))
        ic = (v * np.clip(w, 0, None)) @ v.T
        io = ic + m * ((c @ c) * np.eye(3) - np.outer(c, c))
        out.append(
            [m, *(m * c), io[0, 0], io[0, 1], io[1, 1], io[0, 2], io[1, 2], io[2, 2]]
            + list(np.clip(row[10:], 0, None))
        )
    return torch.tensor(np.concatenate(out), dtype=torch.float64)


def _cost(theta, theta_hat, M):
    delta = theta - theta_hat
    return float(delta @ M @ delta)


@pytest.mark.parametrize("parametrization", PARAMETRIZATIONS)
@pytest.mark.parametrize("n_joints", [1, 2, 4, 10])
def test_projection_is_consistent_and_beats_clipping(parametrization, n_joints):
    g = torch.Generator().manual_seed(n_joints)
    layout = make_layout(n_joints)
    theta_hat = _inconsistent(layout, g)
    M = _metric(layout, g, rank_deficiency=min(3, n_joints))
    assert not check(theta_hat, layout).weakly_ok
    result = project(theta_hat, layout=layout, metric=M, parametrization=parametrization)
    assert result.theta.shape == theta_hat.shape
    report = check(result.theta, layout)
    assert report.weakly_ok, str(report)
    if parametrization == "log-cholesky":
        assert report.ok, str(report)
    # cost definitions: eq. 8 recomputed here
    assert result.cost == pytest.approx(_cost(result.theta, theta_hat, M), rel=1e-9)
    assert result.cost <= result.initial_cost
    baseline = _clip_baseline(theta_hat, layout)
    assert check(baseline, layout).weakly_ok
    assert result.cost <= _cost(baseline, theta_hat, M)
    assert result.converged
    torch.testing.assert_close(result.virtual(), result.theta)


@pytest.mark.parametrize("parametrization", PARAMETRIZATIONS)
@pytest.mark.parametrize("friction", [("viscous",), ("viscous", "coulomb", "offset")])
def test_consistent_theta_comes_back_unchanged(parametrization, friction):
    g = torch.Generator().manual_seed(7)
    layout = make_layout(5, friction)
    theta_hat = _cloud_theta(layout, g)
    M = _metric(layout, g)
    result = project(theta_hat, layout=layout, metric=M, parametrization=parametrization)
    torch.testing.assert_close(result.theta, theta_hat, rtol=0, atol=1e-8)
    assert result.n_iter <= 1
    assert result.moved(1e-8) == ()
    assert result.cost < 1e-12


def test_virtual_keeps_triangle_violation_log_cholesky_removes_it():
    layout = make_layout(1)
    pi = inertial_vector(
        torch.tensor(2.0, dtype=torch.float64),
        torch.tensor([0.1, 0.0, 0.0], dtype=torch.float64),
        torch.diag(torch.tensor([0.1, 0.1, 0.3], dtype=torch.float64)),
    )
    theta_hat = torch.cat([pi, torch.tensor([0.2], dtype=torch.float64)])
    M = torch.eye(11, dtype=torch.float64)
    virtual = project(theta_hat, layout=layout, metric=M, parametrization="virtual")
    torch.testing.assert_close(virtual.theta, theta_hat, rtol=0, atol=1e-8)
    full = project(theta_hat, layout=layout, metric=M, parametrization="log-cholesky")
    assert full.after.ok and not full.before.ok
    assert full.cost > 1e-4


def test_log_cholesky_reaches_the_eigenvalue_clipped_pseudo_inertia():
    # with the metric that makes theta -> J an isometry onto (Frobenius) 4x4 matrices, the
    # closest positive semidefinite pseudo-inertia is the eigenvalue-clipped one
    layout = make_layout(1, ())
    T = torch.stack([pseudo_inertia(e).reshape(-1) for e in torch.eye(10, dtype=torch.float64)], 1)
    M = T.T @ T  # (theta - t)^T M (theta - t) = ||J(theta) - J(t)||_F^2
    theta_hat = inertial_vector(
        torch.tensor(1.0, dtype=torch.float64),
        torch.tensor([0.2, -0.1, 0.3], dtype=torch.float64),
        torch.diag(torch.tensor([0.05, 0.02, 0.09], dtype=torch.float64)),
    )  # violates the triangle inequality: J has one negative eigenvalue
    eig = torch.linalg.eigvalsh(pseudo_inertia(theta_hat))
    assert eig[0] < 0 < eig[1]
    optimum = float((eig.clamp_max(0) ** 2).sum())
    result = project(theta_hat, layout=layout, metric=M, parametrization="log-cholesky", ridge=0)
    assert result.cost == pytest.approx(optimum, rel=1e-3)
    assert result.cost >= optimum * (1 - 1e-9)


def test_virtual_reaches_written_out_optimum():
    # metric = identity, a body with centre of mass at the origin and diagonal inertia: the
    # closest PSD inertia clips the negative moment, friction is clipped at 0
    layout = make_layout(2)
    theta_hat = torch.tensor(
        [2.0, 0, 0, 0, 0.1, 0, 0.2, 0, 0, -0.05, -0.3]
        + [-1.0, 0, 0, 0, 0.1, 0, 0.1, 0, 0, 0.1, 0.4],
        dtype=torch.float64,
    )
    M = torch.eye(22, dtype=torch.float64)
    result = project(theta_hat, layout=layout, metric=M, ridge=0, parametrization="virtual")
    expected = theta_hat.clone()
    expected[[9, 10]] = 0.0  # Izz and friction of body 0
    expected[11] = 0.0  # mass of body 1
    torch.testing.assert_close(result.theta, expected, rtol=0, atol=1e-4)
    assert result.cost == pytest.approx(0.05**2 + 0.3**2 + 1.0, rel=1e-6)
    assert result.moved(1e-3) == ("j0", "j1")


def test_prior_fills_unexcited_parameters():
    g = torch.Generator().manual_seed(3)
    layout = make_layout(2)
    prior = _cloud_theta(layout, g)
    theta_hat = _inconsistent(layout, g)
    X = torch.randn(100, 22, generator=g, dtype=torch.float64)
    X[:, 11:] = 0.0  # body 1 never excited
    M = X.T @ X
    with_prior = project(
        theta_hat, layout=layout, metric=M, prior=prior, prior_weight=1e-3, ridge=0.0,
        parametrization="virtual",
    )  # fmt: skip
    # the prior term is 1e-3 of the data's curvature: converged to ~1e-5 in the parameters
    torch.testing.assert_close(with_prior.theta[11:], prior[11:], rtol=0, atol=1e-4)
    without = project(theta_hat, layout=layout, metric=M, parametrization="virtual")
    assert float((without.theta[11:] - prior[11:]).norm()) > 0.1
    # the prior is a small pull: the excited body is fitted to the data about as well
    assert with_prior.cost <= without.cost * 1.01 + 1e-9


def test_moments_with_input_noise_equal_the_written_metric():
    g = torch.Generator().manual_seed(4)
    layout = make_layout(2)
    X = torch.randn(300, 22, generator=g, dtype=torch.float64)
    theta_hat = _inconsistent(layout, g)
    y = X @ theta_hat
    moments = Moments.from_data(X, y)
    noise = torch.rand(22, generator=g, dtype=torch.float64) * 0.01
    a = project(theta_hat, layout=layout, moments=moments, input_noise=noise)
    b = project(theta_hat, layout=layout, metric=X.T @ X + 300 * torch.diag(noise))
    torch.testing.assert_close(a.theta, b.theta)
    assert a.cost == pytest.approx(b.cost)


def test_accepts_estimators_models_and_float32():
    g = torch.Generator().manual_seed(5)
    layout = make_layout(3)
    theta_hat = _inconsistent(layout, g)
    M = _metric(layout, g, rank_deficiency=0)

    class Fitted:
        coef_ = theta_hat

    class Model:
        pass

    model = Model()
    model.layout = layout
    a = project(Fitted(), layout=model, metric=M)
    b = project(theta_hat.float(), layout=layout, metric=M)
    assert b.theta.dtype == torch.float32 and a.theta.dtype == torch.float64
    torch.testing.assert_close(b.theta, a.theta.float(), rtol=1e-3, atol=1e-4)
    assert b.cost == pytest.approx(a.cost, rel=1e-4)
    assert isinstance(a.virtual, LogCholeskyParameters)  # the default, DEFAULT_PARAMETRIZATION
    c = project(theta_hat, layout=layout, metric=M, parametrization="virtual")
    assert isinstance(c.virtual, VirtualParameters)


def test_report_is_readable():
    g = torch.Generator().manual_seed(6)
    layout = ParameterLayout(("shoulder", "elbow"))
    theta_hat = _inconsistent(layout, g)
    result = project(theta_hat, layout=layout, metric=_metric(layout, g))
    text = str(result)
    assert "shoulder" in text and "elbow" in text
    assert "cost (eq. 8)" in text and "converged" in text
    assert result.relative_change.shape == (2,)
    assert set(result.moved()) <= {"shoulder", "elbow"}
    assert result.before.weakly_ok is False and result.after.weakly_ok is True


def test_bad_input_raises():
    layout = make_layout(2)
    theta = torch.zeros(22, dtype=torch.float64)
    M = torch.eye(22, dtype=torch.float64)
    moments = Moments.from_data(torch.randn(30, 22), torch.randn(30))
    with pytest.raises(ValueError, match="exactly one"):
        project(theta, layout=layout)
    with pytest.raises(ValueError, match="exactly one"):
        project(theta, layout=layout, metric=M, moments=moments)
    with pytest.raises(ValueError, match="input_noise"):
        project(theta, layout=layout, metric=M, input_noise=0.1)
    with pytest.raises(ValueError, match="input_noise"):
        project(theta, layout=layout, moments=moments, input_noise=-torch.ones(22))
    with pytest.raises(ValueError, match="metric must have shape"):
        project(theta, layout=layout, metric=torch.eye(3))
    with pytest.raises(ValueError, match="parametrization"):
        project(theta, layout=layout, metric=M, parametrization="cholesky")
    with pytest.raises(ValueError, match="prior"):
        project(theta, layout=layout, metric=M, prior_weight=1.0)
    with pytest.raises(ValueError, match="theta_hat must have shape"):
        project(torch.zeros(5), layout=layout, metric=M)
    with pytest.raises(TypeError, match="Moments"):
        project(theta, layout=layout, moments=M)
    with pytest.raises(ValueError, match="positive semidefinite"):
        project(theta, layout=layout, metric=-M)


@pytest.mark.parametrize("parametrization", PARAMETRIZATIONS)
@pytest.mark.parametrize("friction", [(), ("viscous", "coulomb", "offset")])
def test_friction_terms(parametrization, friction):
    g = torch.Generator().manual_seed(8)
    layout = make_layout(3, friction)
    theta_hat = _cloud_theta(layout, g).reshape(3, -1).clone()
    theta_hat[0, 0] = -1.0
    if friction:
        theta_hat[:, 11] = torch.tensor([-0.2, 0.3, -0.1], dtype=torch.float64)  # Coulomb
        theta_hat[:, 12] = torch.tensor([-2.0, 0.5, -0.7], dtype=torch.float64)  # offsets
    theta_hat = theta_hat.reshape(-1)
    # identity metric: friction terms are decoupled from the rest and from each other
    M = torch.eye(layout.n_params, dtype=torch.float64)
    result = project(theta_hat, layout=layout, metric=M, parametrization=parametrization)
    assert check(result.theta, layout).weakly_ok
    if friction:
        _, fr_hat = layout.split(theta_hat)
        _, fr = layout.split(result.theta)
        torch.testing.assert_close(fr[:, 2], fr_hat[:, 2], rtol=0, atol=1e-4)  # offsets kept
        torch.testing.assert_close(fr[:, :2], fr_hat[:, :2].clamp_min(0), rtol=0, atol=1e-3)


def test_verbose_prints_the_table(capsys):
    g = torch.Generator().manual_seed(9)
    layout = make_layout(2)
    project(_inconsistent(layout, g), layout=layout, metric=_metric(layout, g), verbose=True)
    out = capsys.readouterr().out
    assert "projection (log-cholesky)" in out and "j1" in out


@pytest.mark.parametrize("parametrization", PARAMETRIZATIONS)
def test_projection_is_scale_equivariant(parametrization):
    """Eq. 8 and the consistent set are invariant under theta -> s theta (s > 0), so the
    projection of s theta_hat is s times theta_hat's, however small or large s (at 1e12 the
    default 1 kg body once came back, "converged"; at 1e3 a 3e4 times larger cost)."""
    g = torch.Generator().manual_seed(11)
    layout = make_layout(4)
    theta_hat = _inconsistent(layout, g)
    M = _metric(layout, g, rank_deficiency=0)  # full rank: a unique optimum
    consistent = _cloud_theta(layout, g)
    ref = project(theta_hat, layout=layout, metric=M, parametrization=parametrization)
    assert ref.converged and ref.after.weakly_ok
    # the stopping test's resolution in eq. 8: tol (f + 1e-3 f(0)), with f(0) = theta_hat^T M
    # theta_hat; two ends within it of one minimum theta* of a convex problem are within
    # 2 sqrt(slack) of each other in the M-norm (f(theta) - f(theta*) >= |theta - theta*|_M^2)
    slack = 1e-5 * (ref.cost + 1e-3 * float(theta_hat @ M @ theta_hat))
    for s in (1e-3, 1.0, 1e3, 1e12):
        result = project(s * theta_hat, layout=layout, metric=M, parametrization=parametrization)
        assert result.converged and result.after.weakly_ok
        assert abs(result.cost / s / s - ref.cost) <= 2 * slack
        delta = result.theta / s - ref.theta
        assert float(delta @ M @ delta) <= 4 * slack
        # a consistent theta is its own projection at every scale (to rounding: 1e-12 relative)
        same = project(s * consistent, layout=layout, metric=M, parametrization=parametrization)
        torch.testing.assert_close(same.theta / s, consistent, rtol=1e-12, atol=1e-12)
        assert same.converged and same.n_iter == 0


@pytest.mark.parametrize("parametrization", PARAMETRIZATIONS)
def test_projection_of_a_huge_theta_is_finite(parametrization):
    # 1e300: eq. 8 (1e600) is beyond float64 and says so with inf; theta itself is finite
    g = torch.Generator().manual_seed(12)
    layout = make_layout(2)
    theta_hat = _inconsistent(layout, g)
    M = _metric(layout, g, rank_deficiency=0)
    ref = project(theta_hat, layout=layout, metric=M, parametrization=parametrization)
    big = project(1e300 * theta_hat, layout=layout, metric=M, parametrization=parametrization)
    assert bool(torch.isfinite(big.theta).all()) and big.converged and big.after.weakly_ok
    assert big.cost == float("inf") and not check(1e300 * theta_hat, layout).weakly_ok
    delta = big.theta / 1e300 - ref.theta
    slack = 1e-5 * (ref.cost + 1e-3 * float(theta_hat @ M @ theta_hat))  # as above
    assert float(delta @ M @ delta) <= 4 * slack


def test_a_stall_is_not_reported_as_convergence():
    """The optimiser on an unnormalised problem (theta_hat 1e6 times the default body's scale,
    as `project` once handed it over) creeps; the Newton model at its end still predicts a
    decrease, so it does not call that converged."""
    from torchjfa.physical._optimize import Problem, minimise

    g = torch.Generator().manual_seed(4)
    layout = make_layout(4)
    theta_hat = 1e6 * _inconsistent(layout, g)
    problem = Problem(theta_hat, _metric(layout, g, rank_deficiency=0), 1e-8, None, 0.0)
    _, _, _, converged = minimise(
        VirtualParameters(layout), problem, max_iter=1000, tol=1e-5, verbose=False
    )
    assert not converged


@pytest.mark.parametrize("parametrization", PARAMETRIZATIONS)
@pytest.mark.parametrize("m", VANISHING_MASSES)
def test_projection_of_a_vanishing_mass_with_a_first_moment(parametrization, m):
    # what a relevance prior leaves of an unidentifiable link: m ~ 0, h = O(1); no overflow
    g = torch.Generator().manual_seed(13)
    layout = make_layout(3)
    theta_hat = vanishing_mass_theta(layout, m, g)
    M = _metric(layout, g, rank_deficiency=0)
    result = project(theta_hat, layout=layout, metric=M, parametrization=parametrization)
    assert bool(torch.isfinite(result.theta).all()) and math.isfinite(result.cost)
    report = check(result.theta, layout)
    assert report.ok if parametrization == "log-cholesky" else report.weakly_ok, str(report)
    assert not result.before.weakly_ok and result.converged
    assert result.cost <= min(
        result.initial_cost, _cost(_clip_baseline(theta_hat, layout), theta_hat, M)
    )


def _prior_problem(g, n_joints=2):
    """Consistent theta_hat and prior (point clouds), a metric that never excites the last
    body, and per-parameter scales of mixed sizes."""
    layout = make_layout(n_joints)
    theta_hat, prior = _cloud_theta(layout, g), _cloud_theta(layout, g)
    X = torch.randn(200, layout.n_params, generator=g, dtype=torch.float64)
    k = layout.params_per_joint
    X[:, -k:] = 0.0
    scale = torch.rand(layout.n_params, generator=g, dtype=torch.float64) + 0.1
    return layout, theta_hat, prior, X.T @ X, scale


def test_scaled_prior_reaches_the_written_out_quadratic_optimum():
    """min (theta - theta_hat)^T M (theta - theta_hat) + w s_p sum ((theta - p) / p_k)^2 with
    s_p = sum_k p_k^2 M_kk / d has the closed form (M + w s_p W)^-1 (M theta_hat + w s_p W p),
    W = diag(p^-2); when that is consistent it is the projection."""
    layout, theta_hat, prior, M, scale = _prior_problem(torch.Generator().manual_seed(21))
    w = 1e-3
    s_p = float((scale.square() * torch.diagonal(M)).sum()) / layout.n_params
    W = torch.diag(scale.pow(-2))
    expected = torch.linalg.solve(M + w * s_p * W, M @ theta_hat + w * s_p * W @ prior)
    assert check(expected, layout).ok  # the closed form is inside the consistent set
    result = project(
        theta_hat,
        layout=layout,
        metric=M,
        prior=prior,
        prior_weight=w,
        prior_scale=scale,
        ridge=0.0,
        tol=1e-12,
        parametrization="log-cholesky",
    )
    # the stopping test resolves the objective to ~1e-12 of its value at 0; along the
    # unexcited body the curvature is only ~w = 1e-3 of the data's, so the parameters there are
    # resolved to ~sqrt(1e-12 / 1e-3) = 3e-5 of their size (~1): 2e-4
    torch.testing.assert_close(result.theta, expected, rtol=0, atol=2e-4)
    k = layout.params_per_joint
    torch.testing.assert_close(result.theta[-k:], prior[-k:], rtol=0, atol=2e-4)


def test_scaled_prior_leaves_the_data_directions_unchanged_to_first_order():
    """Along the excited body the shift from theta_hat is O(weight): ten times smaller weight,
    ten times smaller shift (to 10%: the next order is O(weight^2))."""
    layout, theta_hat, prior, M, scale = _prior_problem(torch.Generator().manual_seed(22))
    k = layout.params_per_joint
    shifts = []
    for w in (1e-3, 1e-4):
        r = project(
            theta_hat,
            layout=layout,
            metric=M,
            prior=prior,
            prior_weight=w,
            prior_scale=scale,
            ridge=0.0,
            tol=1e-12,
        )
        shifts.append(float((r.theta[:-k] - theta_hat[:-k]).norm()))
    assert shifts[0] > 0 and 9.0 < shifts[0] / shifts[1] < 11.0


def test_scaled_prior_limits_and_scale_equivariance():
    layout, theta_hat, prior, M, scale = _prior_problem(torch.Generator().manual_seed(23))
    bad = _inconsistent(layout, torch.Generator().manual_seed(24))
    # weight 0: the projection without a prior, exactly (the paper's virtual parameters here:
    # log-Cholesky's answer moves along directions the objective leaves flat, its objective
    # only is scale-equivariant to round-off)
    virtual = {"parametrization": "virtual"}
    ref = project(bad, layout=layout, metric=M, **virtual)
    zero = project(
        bad, layout=layout, metric=M, prior=prior, prior_weight=0.0, prior_scale=scale, **virtual
    )
    assert torch.equal(ref.theta, zero.theta)
    # scales all 1: the plain prior term
    kw = {"layout": layout, "metric": M, "prior": prior, "prior_weight": 1e-3, "tol": 1e-10,
          **virtual}  # fmt: skip
    plain = project(bad, **kw)
    ones = project(bad, **kw, prior_scale=torch.ones(layout.n_params, dtype=torch.float64))
    torch.testing.assert_close(ones.theta, plain.theta, rtol=0, atol=1e-9)
    # theta_hat, prior and scales x c: the answer x c. The normalised problem is the same up to
    # rounding, and so is the objective at the answer (1e-9 relative); theta itself is pinned
    # only as sharply as the stopping rule (tol 1e-10 of the objective) pins it along the
    # directions the prior alone holds, whose weight is 1e-3 of the data's: sqrt(1e-10 / 1e-3)
    # = 3e-4 relative
    base = project(bad, **{**kw, "prior_scale": scale})
    for c in (1e-3, 1e4):
        r = project(
            c * bad,
            layout=layout,
            metric=M,
            prior=c * prior,
            prior_weight=1e-3,
            prior_scale=c * scale,
            tol=1e-10,
            **virtual,
        )
        assert r.objective / c**2 == pytest.approx(base.objective, rel=1e-9)
        torch.testing.assert_close(r.theta / c, base.theta, rtol=3e-4, atol=1e-8)
    with pytest.raises(ValueError, match="prior_scale must be positive"):
        project(bad, **{**kw, "prior_scale": torch.zeros(layout.n_params, dtype=torch.float64)})


@pytest.mark.parametrize("ridge", [0.0, 1e-3])
def test_unconstrained_projection_minimises_the_written_out_objective(ridge):
    """The closed form is the stationary point of project's objective written from its
    docstring: eq. 8 in M = X^T X + N diag(noise), ridge r tr(M)/d ||theta||^2 and the scaled
    prior w s_p sum ((theta - prior) / p_k)^2, s_p = sum_k p_k^2 M_kk / d (autograd gradient
    zero to round-off), and a strict minimum (every random step raises it)."""
    from torchjfa.physical import unconstrained_projection

    g = torch.Generator().manual_seed(31)
    layout, theta_hat, prior, _, scale = _prior_problem(g)
    d = layout.n_params
    X = torch.randn(300, d, generator=g, dtype=torch.float64) * torch.logspace(0, -1, d)
    X[:, :3] = 0.0  # unexcited: only the prior (and the ridge) decide there
    noise = torch.rand(d, generator=g, dtype=torch.float64) * 1e-3
    moments = Moments.from_data(X, torch.randn(300, generator=g, dtype=torch.float64))
    w = 0.05
    theta = unconstrained_projection(
        theta_hat, layout=layout, moments=moments, input_noise=noise,
        prior=prior, prior_weight=w, prior_scale=scale, ridge=ridge,
    )  # fmt: skip
    M = X.T @ X + 300 * torch.diag(noise)
    s = torch.diagonal(M).sum() / d
    s_p = (scale.square() * torch.diagonal(M)).sum() / d

    def objective(t):
        delta = t - theta_hat
        prior_term = (((t - prior) / scale) ** 2).sum()
        return delta @ M @ delta + ridge * s * (t @ t) + w * s_p * prior_term

    t = theta.clone().requires_grad_(True)
    (grad,) = torch.autograd.grad(objective(t), t)
    # the gradient's terms are O(|M| |theta|); round-off of the solve is ~1e-16 of that
    size = float(torch.linalg.matrix_norm(M, 2) * theta.abs().max())
    assert float(grad.abs().max()) < 1e-10 * size
    f0 = float(objective(theta))
    for _ in range(5):
        step = 1e-3 * torch.randn(d, generator=g, dtype=torch.float64)
        assert float(objective(theta + step)) > f0
    # without a prior and a ridge on a full-rank metric it is theta_hat itself
    full = Moments.from_data(torch.randn(300, d, generator=g, dtype=torch.float64), X[:, 5])
    back = unconstrained_projection(theta_hat, layout=layout, moments=full, ridge=0.0)
    torch.testing.assert_close(back, theta_hat, rtol=1e-10, atol=1e-12)
