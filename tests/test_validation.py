"""`torchjfa._validation.check_joint_weights`: the one check of per-joint weights, and the
places that use it (the input-noise estimate, the excitation design) refusing bad weights."""

from types import SimpleNamespace

import numpy as np
import pytest
import torch

from torchjfa._validation import check_joint_weights


def test_joint_weights_pass_through_as_float64():
    assert check_joint_weights(None, 3) is None
    w = check_joint_weights([0.5, 0, 2], 3)
    assert w.dtype == torch.float64 and w.tolist() == [0.5, 0.0, 2.0]
    f32 = check_joint_weights(np.array([1.0, 2.0]), 2, positive=True, dtype=torch.float32)
    assert f32.dtype == torch.float32 and f32.tolist() == [1.0, 2.0]


@pytest.mark.parametrize(
    "w, kw, match",
    [
        ([1.0, 2.0], {}, r"shape \(3,\), got \(2,\)"),
        ([[1.0, 2.0, 3.0]], {}, r"shape \(3,\), got \(1, 3\)"),
        ([1.0, float("nan"), 1.0], {}, "NaN"),
        ([1.0, float("inf"), 1.0], {}, "infinite"),
        ([1.0, -1.0, 1.0], {}, "non-negative"),
        ([0.0, 0.0, 0.0], {}, "not all zero"),
        ([1.0, 0.0, 1.0], {"positive": True}, "positive"),
    ],
)
def test_bad_joint_weights(w, kw, match):
    with pytest.raises(ValueError, match=match):
        check_joint_weights(w, 3, **kw)
    with pytest.raises(TypeError, match="joint_weights must be a tensor or array of numbers"):
        check_joint_weights("heavy", 3)


def test_the_noise_estimate_and_the_design_refuse_bad_weights():
    from torchjfa.dynamics import RigidBodyModel
    from torchjfa.excitation import information_matrix
    from torchjfa.sim import model_path, regressor_noise

    model = RigidBodyModel.from_mjcf(model_path("arm"))
    n = model.n_dof
    q = torch.zeros(4, n, dtype=torch.float64)
    basis = torch.eye(model.n_params, dtype=torch.float64)[:, :3]
    with pytest.raises(ValueError, match="joint_weights must be positive"):  # W must be > 0
        information_matrix(model, q, q, q, basis, joint_weights=[0.0] + [1.0] * (n - 1))
    g = torch.Generator().manual_seed(0)
    x = {k: torch.randn(10, n, generator=g, dtype=torch.float64) for k in ("q", "qd", "qdd", "tau")}
    log = SimpleNamespace(**x, joint_names=model.joint_names, period_samples=5)  # two periods
    with pytest.raises(ValueError, match="non-negative"):  # a negative weight gave NaN noise
        regressor_noise(model, log, joint_weights=[-1.0] + [1.0] * (n - 1))
