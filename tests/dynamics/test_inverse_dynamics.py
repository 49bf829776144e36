"""InverseDynamics: an nn.Module around the regressor."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from dyn_robots import mujoco_inverse, mujoco_model, random_state

import torchjfa.robots
from torchjfa.dynamics import InverseDynamics, RigidBodyModel

TREE = torchjfa.robots.path("branched_tree")


@pytest.fixture(scope="module")
def model():
    return RigidBodyModel.from_mjcf(TREE)


def test_forward_equals_mujoco_for_the_nominal_theta(model):
    idyn = InverseDynamics(model)
    q, qd, qdd = random_state(model.n_dof, (2, 3), seed=0)
    tau = idyn(q, qd, qdd)
    assert tau.shape == (2, 3, model.n_dof)
    expected = mujoco_inverse(
        mujoco_model("mjcf", TREE), *(v.reshape(-1, model.n_dof).numpy() for v in (q, qd, qdd))
    )
    np.testing.assert_allclose(
        tau.reshape(-1, model.n_dof).detach().numpy(), expected, rtol=1e-9, atol=1e-9
    )


def test_state_dict_round_trip(model, tmp_path):
    theta = model.nominal_theta * 1.5
    a = InverseDynamics(model, theta)
    torch.save(a.state_dict(), tmp_path / "idyn.pt")
    b = InverseDynamics(model)
    b.load_state_dict(torch.load(tmp_path / "idyn.pt"))
    torch.testing.assert_close(b.theta.detach(), theta, rtol=0, atol=0)
    q, qd, qdd = random_state(model.n_dof, (4,), seed=1)
    torch.testing.assert_close(a(q, qd, qdd), b(q, qd, qdd), rtol=0, atol=0)
    assert list(a.state_dict()) == ["theta"]


def test_gradients_flow_to_theta_only_when_trainable(model):
    q, qd, qdd = random_state(model.n_dof, (6,), seed=2)
    target = torch.zeros(6, model.n_dof, dtype=torch.float64)
    trainable = InverseDynamics(model, trainable="unconstrained")
    loss = ((trainable(q, qd, qdd) - target) ** 2).sum()
    loss.backward()
    Y = model.regressor(q, qd, qdd).reshape(-1, model.n_params)
    expected = 2 * Y.T @ (Y @ model.nominal_theta)  # d/dtheta |Y theta|^2, written out
    torch.testing.assert_close(trainable.theta.grad, expected)
    frozen = InverseDynamics(model)
    assert not frozen.theta.requires_grad
    qg = q.clone().requires_grad_(True)
    frozen(qg, qd, qdd).sum().backward()
    assert frozen.theta.grad is None
    assert qg.grad is not None and bool(qg.grad.abs().sum() > 0)


def test_float32_inputs(model):
    idyn = InverseDynamics(model)
    q, qd, qdd = random_state(model.n_dof, (3,), seed=3, dtype=torch.float32)
    tau = idyn(q, qd, qdd)
    assert tau.dtype == torch.float32
    ref = idyn(q.double(), qd.double(), qdd.double())
    torch.testing.assert_close(tau.double(), ref, rtol=1e-4, atol=1e-4)


def test_bad_arguments(model):
    with pytest.raises(ValueError, match="shape"):
        InverseDynamics(model, torch.zeros(3))
    with pytest.raises(TypeError, match="RigidBodyModel"):
        InverseDynamics("panda")
    with pytest.raises(ValueError, match="NaN"):
        InverseDynamics(model, torch.full((model.n_params,), float("nan")))
