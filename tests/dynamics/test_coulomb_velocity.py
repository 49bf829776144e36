"""The smoothed Coulomb term: ``fc tanh(qd / v_c)`` in every regressor path, kept in saved models."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

import torchjfa.robots
from torchjfa.dynamics import RigidBodyModel
from torchjfa.io import identified_from_dict, identified_to_dict, read_identified, save_identified

FRICTION = ("viscous", "coulomb", "offset")
V_C = 0.05


@pytest.fixture(scope="module")
def panda():
    return RigidBodyModel.from_urdf(torchjfa.robots.path("panda_arm"), friction=FRICTION)


def _states(n=24, seed=0, speed=0.2):
    g = torch.Generator().manual_seed(seed)
    q, qd, qdd = (torch.randn(n, 7, generator=g, dtype=torch.float64) for _ in range(3))
    return q, speed * qd, qdd  # velocities of the order of v_c: tanh and sign differ


def _coulomb_columns(model):
    names = list(model.parameter_names)
    return [names.index(f"{j}.fc") for j in model.joint_names]


def test_the_coulomb_columns_are_tanh_and_the_rest_is_unchanged(panda):
    smooth = panda.with_coulomb_velocity(V_C)
    assert smooth.coulomb_velocity == V_C and panda.coulomb_velocity == 0.0
    assert smooth.parameter_names == panda.parameter_names and "coulomb_velocity=0.05" in repr(
        smooth
    )
    q, qd, qdd = _states()
    Y0 = panda.regressor(q, qd, qdd, compiled=False)
    Y1 = smooth.regressor(q, qd, qdd, compiled=False)
    cols = _coulomb_columns(panda)
    expected = np.tanh(qd.numpy() / V_C)  # numpy's tanh: an independent reference
    for j, c in enumerate(cols):
        np.testing.assert_allclose(Y1[:, j, c].numpy(), expected[:, j], rtol=0, atol=1e-15)
        np.testing.assert_array_equal(Y0[:, j, c].numpy(), np.sign(qd[:, j].numpy()))
    others = [i for i in range(panda.n_params) if i not in cols]
    assert torch.equal(Y0[..., others], Y1[..., others])
    # each joint's Coulomb column is zero in the other joints' rows
    off = Y1[..., cols].clone()
    off[:, range(7), range(7)] = 0.0
    assert torch.count_nonzero(off) == 0


def test_every_path_gives_the_same_smoothed_regressor(panda):
    smooth = panda.with_coulomb_velocity(V_C)
    q, qd, qdd = _states(seed=1)
    torch_path = smooth.regressor(q, qd, qdd, compiled=False)
    grad_path = smooth.regressor(q, qd.clone().requires_grad_(), qdd).detach()
    out = torch.empty_like(torch_path)
    smooth.regressor(q, qd, qdd, out=out, compiled=False)
    assert torch.equal(out, torch_path)
    scale = torch_path.abs().max()
    # the autograd path sums the same terms in another order: round-off of the largest entry
    assert (grad_path - torch_path).abs().max() <= 64 * torch.finfo(torch.float64).eps * scale
    try:
        compiled = smooth.regressor(q, qd, qdd, compiled=True)
    except RuntimeError:
        pytest.skip("no C++ compiler for the compiled path")
    assert (compiled - torch_path).abs().max() <= 64 * torch.finfo(torch.float64).eps * scale


def test_the_smoothed_column_has_the_finite_difference_gradient(panda):
    smooth = panda.with_coulomb_velocity(V_C)
    q, qd, qdd = _states(n=3, seed=2)
    col = _coulomb_columns(panda)

    def coulomb(qd_):
        return smooth.regressor(q, qd_, qdd)[:, range(7), col]

    assert torch.autograd.gradcheck(coulomb, (qd.clone().requires_grad_(),))


def test_a_tiny_smoothing_velocity_is_sign(panda):
    # tanh(x) rounds to 1 in float64 for x > 19.1: velocities beyond 1e-3 rad/s at v_c 1e-6
    q, qd, qdd = _states(seed=3)
    qd = torch.where(qd.abs() < 1e-3, torch.full_like(qd, 1e-3), qd)
    tiny = panda.with_coulomb_velocity(1e-6)
    assert torch.equal(
        tiny.regressor(q, qd, qdd, compiled=False), panda.regressor(q, qd, qdd, compiled=False)
    )


@pytest.mark.parametrize("bad", [-0.1, math.nan, math.inf, True, "fast", None])
def test_a_bad_smoothing_velocity_is_refused(panda, bad):
    with pytest.raises(ValueError, match="coulomb_velocity"):
        panda.with_coulomb_velocity(bad)
    with pytest.raises(ValueError, match="coulomb_velocity"):
        RigidBodyModel.from_urdf(
            torchjfa.robots.path("panda_arm"), friction=FRICTION, coulomb_velocity=bad
        )


def test_saved_models_keep_the_smoothing_velocity(panda, tmp_path):
    smooth = panda.with_coulomb_velocity(V_C)
    theta = smooth.nominal_theta.clone()
    theta[_coulomb_columns(smooth)] = 0.4
    save_identified(tmp_path / "m.npz", smooth, theta)
    back = read_identified(tmp_path / "m.npz")
    assert back.model.coulomb_velocity == V_C
    q, qd, qdd = _states(seed=4)
    assert torch.equal(
        back.model.inverse_dynamics(q, qd, qdd, back.theta),
        smooth.inverse_dynamics(q, qd, qdd, theta),
    )
    # a file written before the smoothing velocity existed reads as sign(qd)
    old = identified_to_dict(smooth, theta)
    del old["coulomb_velocity"]
    assert identified_from_dict(old).model.coulomb_velocity == 0.0
