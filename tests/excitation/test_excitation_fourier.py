"""Fourier-series trajectories: rest at the posture, exact derivatives, the sinusoid form, files."""

import math

import numpy as np
import pytest
import torch

from torchjfa.excitation import FourierTrajectory, constrain_coefficients, fourier_states

NAMES = ("j0", "j1", "j2")


def _random(H=4, f0=0.2, seed=0):
    g = torch.Generator().manual_seed(seed)
    a, b = (torch.randn(3, H, generator=g, dtype=torch.float64) for _ in range(2))
    a, b = constrain_coefficients(a, b)
    q0 = np.array([0.3, -0.2, 1.0])
    return FourierTrajectory(f0, q0, a.numpy(), b.numpy(), NAMES)


@pytest.mark.parametrize("H", [2, 3, 6])
def test_rest_at_the_posture_at_the_start_of_every_period(H):
    traj = _random(H=H)
    t = torch.tensor([0.0, traj.period, 3 * traj.period], dtype=torch.float64)
    q, qd, qdd = traj(t)
    # sums of H terms of size ~1 at arguments k w T (multiples of 2 pi): rounding ~1e-15 x H
    for row in range(3):
        np.testing.assert_allclose(q[row].numpy(), traj.posture, atol=1e-12)
        np.testing.assert_allclose(qd[row].numpy(), 0.0, atol=1e-12)
        np.testing.assert_allclose(qdd[row].numpy(), 0.0, atol=1e-11)


def test_constraint_is_the_closest_projection():
    # written out: a - mean(a) and b - k (k.b) / (k.k) are orthogonal projections, so applying
    # them twice changes nothing and the removed part is orthogonal to the kept part
    g = torch.Generator().manual_seed(3)
    a, b = (torch.randn(2, 5, generator=g, dtype=torch.float64) for _ in range(2))
    a1, b1 = constrain_coefficients(a, b)
    a2, b2 = constrain_coefficients(a1, b1)
    torch.testing.assert_close(a2, a1, rtol=0, atol=1e-14)
    torch.testing.assert_close(b2, b1, rtol=0, atol=1e-14)
    assert float(((a - a1) * a1).sum().abs()) < 1e-12
    assert float(((b - b1) * b1).sum().abs()) < 1e-12


def test_derivatives_match_central_differences():
    traj = _random(H=5, f0=0.3)
    t = torch.linspace(0.1, 3.0, 17, dtype=torch.float64)
    h = 1e-5
    qp, qdp, _ = traj(t + h)
    qm, qdm, _ = traj(t - h)
    _, qd, qdd = traj(t)
    # central differences err by h^2 / 6 x the third derivative: coefficients ~3 times
    # (w H)^2 ~ 90 for qd and (w H)^3 ~ 850 for qdd, so ~5e-9 and ~4e-8; rounding ~1e-16 / h
    torch.testing.assert_close((qp - qm) / (2 * h), qd, rtol=0, atol=2e-8)
    torch.testing.assert_close((qdp - qdm) / (2 * h), qdd, rtol=0, atol=2e-7)


def test_sinusoid_form_is_the_same_trajectory():
    traj = _random(H=4)
    sin = traj.to_sinusoid()
    t = np.linspace(0.0, 2 * traj.period, 101)
    for mine, theirs in zip(traj.evaluate_numpy(t), sin.evaluate_numpy(t), strict=True):
        np.testing.assert_allclose(theirs, mine, rtol=0, atol=1e-12)
    assert sin.period == pytest.approx(traj.period)


def test_formula_written_out_for_one_joint():
    a = torch.tensor([[1.0, -1.0]], dtype=torch.float64)
    b = torch.tensor([[2.0, -1.0]], dtype=torch.float64)  # 1 * 2 + 2 * (-1) = 0
    f0, t = 0.5, torch.tensor([0.3], dtype=torch.float64)
    w = 2 * math.pi * f0
    q, qd, _ = fourier_states(t, torch.tensor([0.1], dtype=torch.float64), a, b, f0)
    c = 0.1 + 2.0 / w - 1.0 / (2 * w)
    expect = c + (1 / w) * math.sin(w * 0.3) - (2 / w) * math.cos(w * 0.3)
    expect += (-1 / (2 * w)) * math.sin(2 * w * 0.3) + (1 / (2 * w)) * math.cos(2 * w * 0.3)
    assert float(q[0, 0]) == pytest.approx(expect, abs=1e-14)
    expect_qd = math.cos(w * 0.3) + 2 * math.sin(w * 0.3)
    expect_qd += -math.cos(2 * w * 0.3) - math.sin(2 * w * 0.3)
    assert float(qd[0, 0]) == pytest.approx(expect_qd, abs=1e-14)


def test_save_load_round_trip(tmp_path):
    traj = _random()
    traj.save(tmp_path / "t.npz")
    back = FourierTrajectory.load(tmp_path / "t.npz")
    assert back.joint_names == NAMES
    np.testing.assert_array_equal(back.a, traj.a)
    np.testing.assert_array_equal(back.b, traj.b)
    np.testing.assert_array_equal(back.posture, traj.posture)
    np.savez(tmp_path / "other.npz", x=np.zeros(3))
    with pytest.raises(ValueError, match="not a trajectory written by torchjfa excite"):
        FourierTrajectory.load(tmp_path / "other.npz")


def test_bad_trajectories():
    with pytest.raises(ValueError, match="at least 2 harmonics"):
        FourierTrajectory(0.1, np.zeros(3), np.zeros((3, 1)), np.zeros((3, 1)), NAMES)
    with pytest.raises(ValueError, match="base_frequency"):
        FourierTrajectory(0.0, np.zeros(3), np.zeros((3, 2)), np.zeros((3, 2)), NAMES)
    with pytest.raises(ValueError, match="joint names"):
        FourierTrajectory(0.1, np.zeros(3), np.zeros((3, 2)), np.zeros((3, 2)), NAMES[:2])
