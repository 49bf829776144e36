"""`InverseDynamics(..., trainable=True)` trains a physically consistent theta: every optimiser
step keeps `torchjfa.physical.check` satisfied, where training theta itself does not."""

from __future__ import annotations

import pytest
import torch

from torchjfa.dynamics import InverseDynamics, RigidBodyModel
from torchjfa.physical import check
from torchjfa.sim import model_path

TERMS = ("viscous", "coulomb", "offset", "armature")


@pytest.fixture(scope="module")
def head():
    return RigidBodyModel.from_mjcf(model_path("head"), friction=TERMS)


def _theta(model: RigidBodyModel) -> torch.Tensor:
    """The nominal inertials with positive viscous, Coulomb and armature terms, signed offsets."""
    inertial, _ = model.layout.split(model.nominal_theta)
    terms = torch.tensor([0.05, 0.01, -0.003, 0.002], dtype=torch.float64)
    return model.layout.join(inertial, terms.expand(model.n_dof, 4))


def _data(model: RigidBodyModel, n: int = 256, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    q, qd, qdd = (torch.randn(n, model.n_dof, dtype=torch.float64, generator=g) for _ in range(3))
    # a target no rigid body fits: random torques of the size of the model's own
    tau = InverseDynamics(model, _theta(model))(q, qd, qdd)
    target = tau.std(0) * torch.randn(n, model.n_dof, dtype=torch.float64, generator=g)
    return q, qd, qdd, target


def _train(idyn: InverseDynamics, data, steps: int = 20, lr: float = 0.05):
    """Adam steps on the mean squared torque error; the losses and the consistency after each
    step."""
    q, qd, qdd, target = data
    opt = torch.optim.Adam([p for p in idyn.parameters() if p.requires_grad], lr=lr)
    losses, consistent = [], []
    for _ in range(steps):
        opt.zero_grad()
        loss = (idyn(q, qd, qdd) - target).square().mean()
        loss.backward()
        opt.step()
        losses.append(float(loss.detach()))
        consistent.append(check(idyn.theta.detach(), idyn.model).ok)
    return losses, consistent


def test_adam_steps_keep_theta_consistent_and_lower_the_loss(head):
    data = _data(head)
    idyn = InverseDynamics(head, _theta(head), trainable=True)
    assert idyn.parametrization == "consistent" and idyn.trainable
    theta0 = idyn.theta.detach().clone()
    losses, consistent = _train(idyn, data)
    assert all(consistent)
    assert losses[-1] < 0.9 * losses[0], losses
    assert not torch.allclose(idyn.theta.detach(), theta0)
    # the same steps on theta itself leave the consistent set: the check above can fail
    free = InverseDynamics(head, _theta(head), trainable="unconstrained")
    free_losses, free_consistent = _train(free, data)
    assert not free_consistent[-1]
    assert free_losses[-1] < free_losses[0]


def test_starts_at_the_given_consistent_theta(head):
    theta = _theta(head)
    idyn = InverseDynamics(head, theta, trainable=True)
    # the log-Cholesky factor and softplus inverted and applied again: rounding of a few eps
    # per entry, relative to each body's largest entry (the inertia entries are 1e-4 of the mass)
    got = idyn.theta.detach()
    per_body = theta.reshape(head.n_dof, -1).abs().amax(-1, keepdim=True)
    err = ((got - theta).reshape(head.n_dof, -1).abs() / per_body).max()
    assert float(err) < 1e-12
    q, qd, qdd, _ = _data(head, n=8)
    frozen = InverseDynamics(head, theta)
    torch.testing.assert_close(
        idyn(q, qd, qdd).detach(), frozen(q, qd, qdd), rtol=1e-10, atol=1e-12
    )


def test_zero_terms_start_small_and_positive_and_inconsistent_bodies_are_moved(head, notes):
    theta = head.nominal_theta  # zero joint terms
    idyn = InverseDynamics(head, theta, trainable=True)
    _, terms = head.layout.split(idyn.theta.detach())
    signed = [k for k, kind in enumerate(head.friction) if kind != "offset"]
    assert bool((terms[:, signed] > 0).all()) and bool((terms[:, signed] <= 1e-6 * 1.001).all())
    assert bool((terms[:, head.friction.index("offset")] == 0).all())
    assert not notes.records  # a consistent start says nothing
    bad = _theta(head)
    bad[head.layout.index(2, "m")] = -1.0  # a negative mass
    idyn = InverseDynamics(head, bad, trainable=True)
    assert check(idyn.theta.detach(), head).ok
    assert any("not physically consistent" in r.getMessage() for r in notes.records)
    assert head.joint_names[2] in notes.records[-1].getMessage()


def test_state_dict_round_trip_and_freezing(head):
    data = _data(head, n=32)
    a = InverseDynamics(head, _theta(head), trainable=True)
    _train(a, data, steps=3)
    b = InverseDynamics(head, trainable=True)
    b.load_state_dict(a.state_dict())
    assert set(a.state_dict()) == {"consistent.inertial.phi", "consistent.joint_terms"}
    torch.testing.assert_close(b.theta, a.theta, rtol=0, atol=0)
    b.requires_grad_(False)
    assert not b.trainable and not b.theta.requires_grad


def test_bad_trainable_values(head):
    for value in ("yes", 1, None):
        with pytest.raises(ValueError, match="trainable must be"):
            InverseDynamics(head, trainable=value)
