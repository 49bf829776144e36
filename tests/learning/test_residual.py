"""`ResidualDynamics`, `MLP` and `JointResidual`: written-out formulas, shapes, gradients,
consistency when fine-tuning, the joint residual's least squares against scikit-learn; `nmse`
against scikit-learn's R^2."""

import pytest
import torch
from torch import nn

from torchjfa.dynamics import InverseDynamics, RigidBodyModel
from torchjfa.learning import MLP, JointResidual, ResidualDynamics, nmse, state_features
from torchjfa.physical import check
from torchjfa.sim import model_path


@pytest.fixture(scope="module")
def head():
    return RigidBodyModel.from_mjcf(model_path("head"))


def _states(shape, seed=0):
    g = torch.Generator().manual_seed(seed)
    return [torch.randn(*shape, generator=g, dtype=torch.float64) for _ in range(3)]


def _mlp_by_hand(mlp: MLP, x):
    z = (x - mlp.in_mean) / mlp.in_std
    layers = [m for m in mlp.net if isinstance(m, nn.Linear)]
    for k, layer in enumerate(layers):
        z = z @ layer.weight.T + layer.bias
        if k < len(layers) - 1:
            z = torch.tanh(z)
    return z * mlp.out_std + mlp.out_mean


@pytest.mark.parametrize("batch", [(5,), (2, 3)])
def test_forward_is_rigid_body_plus_mlp(head, batch):
    idyn = InverseDynamics(head)
    model = ResidualDynamics(idyn, hidden=(16, 8))
    q, qd, qdd = _states((*batch, head.n_dof))
    tau = model(q, qd, qdd)
    assert tau.shape == (*batch, head.n_dof) and tau.dtype == torch.float64
    Y = head.regressor(q, qd, qdd)
    expected = Y @ head.nominal_theta + _mlp_by_hand(model.residual, torch.cat([q, qd, qdd], -1))
    torch.testing.assert_close(tau, expected, rtol=1e-12, atol=1e-12)
    # a precomputed regressor gives the same
    torch.testing.assert_close(model(q, qd, qdd, regressor=Y), tau, rtol=0, atol=0)
    torch.testing.assert_close(model.rigid_body_torque(q, qd, qdd), Y @ head.nominal_theta)


def test_frozen_theta_gets_no_gradient_and_the_residual_does(head):
    mlp = MLP(3 * head.n_dof, head.n_dof, hidden=(8,), zero_output=False)
    model = ResidualDynamics(InverseDynamics(head, trainable=True), mlp)
    q, qd, qdd = _states((4, head.n_dof))
    model(q, qd, qdd).square().sum().backward()
    assert model.inverse_dynamics.theta.grad is None
    assert not model.inverse_dynamics.theta.requires_grad
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in model.residual.parameters())
    names = [n for n, p in model.named_parameters() if p.requires_grad]
    assert all(n.startswith("residual.") for n in names)


def test_fine_tuning_starts_at_the_identified_theta_and_stays_consistent(head):
    theta0 = head.nominal_theta.clone()
    theta0.reshape(head.n_dof, -1)[:, 10] = 0.05
    model = ResidualDynamics(InverseDynamics(head, theta0), fine_tune=True, hidden=(8,))
    torch.testing.assert_close(model.theta(), theta0, rtol=1e-10, atol=1e-12)
    q, qd, qdd = _states((64, head.n_dof))
    target = 3.0 * head.regressor(q, qd, qdd) @ theta0  # pulls the masses up hard
    opt = torch.optim.Adam(model.parameters(), lr=0.05)
    for _ in range(20):
        opt.zero_grad()
        loss = (model(q, qd, qdd) - target).square().mean()
        loss.backward()
        assert model.virtual.phi.grad.abs().sum() > 0
        opt.step()
    theta = model.theta().detach()
    assert not torch.allclose(theta, theta0)
    assert check(theta, head).weakly_ok
    # the InverseDynamics' own theta never changes
    assert torch.equal(model.inverse_dynamics.theta.detach(), theta0)


def test_purely_learned_model_and_custom_parts():
    model = ResidualDynamics(None, n_dof=3, hidden=(4,))
    q, qd, qdd = _states((6, 3))
    torch.testing.assert_close(model(q, qd, qdd), model.residual(state_features(q, qd, qdd)))
    assert model.theta() is None

    def feats(q, qd, qdd):
        return torch.cat([torch.sin(q), torch.cos(q), qd.sign(), qdd], -1)

    lin = nn.Linear(12, 3, dtype=torch.float64)
    model = ResidualDynamics(None, lin, features=feats, n_dof=3)
    torch.testing.assert_close(model(q, qd, qdd), lin(feats(q, qd, qdd)))
    model = ResidualDynamics(None, features=feats, n_features=12, n_dof=3, hidden=(4,))
    assert model.residual.in_features == 12
    assert model(q, qd, qdd).shape == (6, 3)


def test_mlp_normalization_and_seeded_initialisation():
    g = torch.Generator().manual_seed(0)
    x = 5 + 3 * torch.randn(100, 4, generator=g, dtype=torch.float64)
    y = -2 + 0.1 * torch.randn(100, 2, generator=g, dtype=torch.float64)
    a, b = MLP(4, 2, hidden=(8,), seed=3), MLP(4, 2, hidden=(8,), seed=3)
    assert all(torch.equal(p, r) for p, r in zip(a.parameters(), b.parameters(), strict=True))
    assert a.net[-1].weight.abs().sum() == 0 and a.net[0].weight.abs().sum() > 0
    torch.testing.assert_close(a(x), a.out_mean.expand(100, 2))  # zero output layer
    a = MLP(4, 2, hidden=(8,), seed=3, zero_output=False)
    a.fit_normalization(x, y)
    torch.testing.assert_close(a.in_mean, x.mean(0))
    torch.testing.assert_close(a.in_std, x.std(0))
    torch.testing.assert_close(a.out_mean, y.mean(0))
    torch.testing.assert_close(a(x), _mlp_by_hand(a, x), rtol=1e-12, atol=1e-12)
    assert "in_std" in a.state_dict()


def _joint_by_hand(m: JointResidual, q, qd, qdd):
    """Joint by joint, with ordinary matrix products: the written-out forward."""
    out = []
    for j in range(m.n_dof):
        f = torch.stack([q[:, j], qd[:, j], qdd[:, j], torch.tanh(qd[:, j] / m.friction_velocity)])
        phi = (f.T - m.in_mean[j]) / m.in_std[j]
        h = phi
        for i, (w, b) in enumerate(zip(m.weights, m.biases, strict=True)):
            h = h @ w[j] + b[j]
            if i < len(m.weights) - 1:
                h = torch.tanh(h)
        r = h[:, 0] + phi @ m.linear[j]
        out.append(r * m.out_std[j] + m.out_mean[j])
    return torch.stack(out, -1)


def test_joint_residual_forward_is_joint_local_and_as_written_out():
    q, qd, qdd = _states((40, 3))
    m = JointResidual(3, hidden=(5, 4), seed=1, zero_output=False)
    m.fit_normalization(state_features(q, qd, qdd), torch.randn(40, 3, dtype=torch.float64))
    with torch.no_grad():
        m.linear.copy_(torch.randn(m.linear.shape, dtype=torch.float64))
    x = state_features(q, qd, qdd)
    torch.testing.assert_close(m(x), _joint_by_hand(m, q, qd, qdd), rtol=1e-12, atol=1e-12)
    # joint j's output does not depend on any other joint's q, qd or qdd
    jac = torch.autograd.functional.jacobian(lambda z: m(z).sum(0), x[:6])  # (3, 6, 9)
    feature_joint = torch.arange(9) % 3
    for j in range(3):
        assert jac[j][:, feature_joint != j].abs().max() == 0
        assert jac[j][:, feature_joint == j].abs().max() > 0
    # the untrained residual with a zero last layer is its output mean: zero before fitting
    assert torch.equal(JointResidual(3)(x), torch.zeros(40, 3, dtype=torch.float64))


def test_joint_residual_least_squares_equals_sklearn_ridge_per_joint():
    linear_model = pytest.importorskip("sklearn.linear_model")
    g = torch.Generator().manual_seed(4)
    n, v = 400, 0.05
    q, qd, qdd = (torch.randn(n, 2, generator=g, dtype=torch.float64) for _ in range(3))
    q[:, 1] = 0.7  # a constant feature: no crash, the fit is the same as without it
    truth = torch.tensor([[0.3, -0.2, 1.5, 0.4], [0.0, 0.1, 0.02, 0.05]], dtype=torch.float64)
    feats = torch.stack([q, qd, qdd, torch.tanh(qd / v)], -1)  # (n, 2, 4)
    y = (feats * truth).sum(-1) + torch.tensor([0.5, -1.0]) + 0.01 * torch.randn(n, 2, generator=g)
    m = JointResidual(2, friction_velocity=v, ridge=1e-2)
    m.fit_normalization(state_features(q, qd, qdd), y)
    with torch.no_grad():
        pred = m(state_features(q, qd, qdd))
    for j in range(2):
        f = feats[:, j]
        std = f.std(0)
        phi = ((f - f.mean(0)) / torch.where(std > 0, std, torch.ones_like(std))).numpy()
        ref = linear_model.Ridge(alpha=1e-2 * n).fit(phi, y[:, j].numpy())
        torch.testing.assert_close(
            pred[:, j], torch.as_tensor(ref.predict(phi)), rtol=1e-10, atol=1e-10
        )
    # the fit itself is close to the truth: a well-excited feature is hardly shrunk
    assert nmse(pred, y) < 1e-2
    assert m.no_weight_decay() == {"linear"}


def test_joint_residual_does_not_blow_up_on_a_feature_constant_in_training():
    # the joint never reverses in training (its friction feature is +1 throughout, up to
    # rounding) and does on the new data: the prediction stays of the training torques' size
    g = torch.Generator().manual_seed(5)
    n = 200
    q, qdd = (torch.randn(n, 1, generator=g, dtype=torch.float64) for _ in range(2))
    qd = 0.1 + 0.05 * torch.rand(n, 1, generator=g, dtype=torch.float64)
    y = 0.2 * qdd + 0.3 + 0.01 * torch.randn(n, 1, generator=g, dtype=torch.float64)
    m = JointResidual(1)
    m.fit_normalization(state_features(q, qd, qdd), y)
    new = state_features(q, -qd, qdd)
    with torch.no_grad():
        assert m(new).abs().max() < 10 * y.abs().max()


def test_residual_kind_joint_builds_a_joint_residual(head):
    model = ResidualDynamics(InverseDynamics(head), residual_kind="joint", hidden=(4,))
    assert isinstance(model.residual, JointResidual) and model.residual.n_inputs == 3
    q, qd, qdd = _states((5, head.n_dof))
    torch.testing.assert_close(model(q, qd, qdd), model.rigid_body_torque(q, qd, qdd))


def test_bad_input_is_rejected(head):
    with pytest.raises(ValueError, match="n_dof is required"):
        ResidualDynamics(None)
    with pytest.raises(ValueError, match="fine_tune"):
        ResidualDynamics(None, n_dof=2, fine_tune=True)
    with pytest.raises(TypeError, match="InverseDynamics"):
        ResidualDynamics(head)
    with pytest.raises(ValueError, match="n_features"):
        ResidualDynamics(None, n_dof=2, features=state_features)
    with pytest.raises(ValueError, match="activation"):
        MLP(2, 2, activation="sigmoid")
    with pytest.raises(ValueError, match="hidden"):
        MLP(2, 2, hidden=(0,))
    with pytest.raises(ValueError, match="residual_kind"):
        ResidualDynamics(None, n_dof=2, residual_kind="gru")
    with pytest.raises(ValueError, match="multiple of n_dof"):
        ResidualDynamics(
            None, n_dof=2, features=state_features, n_features=5, residual_kind="joint"
        )
    with pytest.raises(ValueError, match="friction_velocity"):
        JointResidual(2, friction_velocity=0.0)
    with pytest.raises(ValueError, match="ridge"):
        JointResidual(2, ridge=0.0)
    with pytest.raises(ValueError, match="velocity_index"):
        JointResidual(2, velocity_index=3)
    with pytest.raises(ValueError, match="inputs"):
        JointResidual(2)(torch.zeros(4, 5, dtype=torch.float64))
    model = ResidualDynamics(InverseDynamics(head), hidden=(4,))
    q, qd, qdd = _states((3, head.n_dof))
    with pytest.raises(ValueError, match="shape"):
        model(q[:, :3], qd[:, :3], qdd[:, :3])
    with pytest.raises(TypeError, match="torch.Tensor"):
        model(q.numpy(), qd, qdd)
    bad = ResidualDynamics(None, nn.Linear(6, 1, dtype=torch.float64), n_dof=2)
    with pytest.raises(ValueError, match="residual returned"):
        bad(*_states((3, 2)))


def test_nmse_is_one_minus_sklearn_r2():
    metrics = pytest.importorskip("sklearn.metrics")
    g = torch.Generator().manual_seed(0)
    y = torch.randn(50, 3, generator=g, dtype=torch.float64) * torch.tensor([1.0, 10.0, 0.1])
    p = y + 0.3 * torch.randn(50, 3, generator=g, dtype=torch.float64)
    r2 = metrics.r2_score(y.numpy(), p.numpy(), multioutput="raw_values")
    torch.testing.assert_close(nmse(p, y, per_joint=True), torch.as_tensor(1 - r2))
    torch.testing.assert_close(nmse(p, y), torch.as_tensor(1 - r2).mean())
    with pytest.raises(ValueError, match="constant"):
        nmse(p, torch.ones_like(p))
