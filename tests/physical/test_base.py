"""Base parameters from the moments, against written-out counts and numpy/scipy decompositions."""

import numpy as np
import pytest
import scipy.linalg
import torch
from _robots import TWO_LINK

import torchjfa
from torchjfa.dynamics import RigidBodyModel
from torchjfa.physical import BaseParameters, base_parameters, parameter_scales
from torchjfa.stats import Moments


def _random_moments(model, n, noise=0.01, seed=0):
    g = torch.Generator().manual_seed(seed)
    q, qd, qdd = (torch.randn(n, model.n_dof, generator=g, dtype=torch.float64) for _ in range(3))
    Y = model.regressor(q, qd, qdd).reshape(-1, model.n_params)
    tau = Y @ model.nominal_theta + noise * torch.randn(
        Y.shape[0], generator=g, dtype=torch.float64
    )
    return Y, tau, Moments.from_data(Y, tau)


@pytest.fixture(scope="module")
def two_link():
    return RigidBodyModel.from_urdf(TWO_LINK)


def test_planar_two_link_has_the_textbook_base_parameters(two_link):
    """Khalil and Dombre's regrouping for a planar 2R arm in a vertical plane, axes along y:
    YY1 + m2 l1^2, MX1 + m2 l1, MZ1, YY2, MX2, MZ2 and the two viscous terms: 8 of 22."""
    _, _, m = _random_moments(two_link, 400)
    b = base_parameters(m, two_link)
    assert isinstance(b, BaseParameters) and b.rank == 8 and b.n_determined == 8
    combos = set(b.combinations())
    assert "j1.Iyy + 0.16 j2.m" in combos and "j1.mcx + 0.4 j2.m" in combos
    assert {"j1.mcz", "j2.Iyy", "j2.mcx", "j2.mcz", "j1.fv", "j2.fv"} <= combos
    status = dict(zip(b.names, b.status, strict=True))
    assert status["j2.m"] == status["j1.Iyy"] == status["j1.mcx"] == "combination"
    assert status["j2.Iyy"] == status["j1.fv"] == "determined"
    assert status["j1.Ixx"] == status["j2.mcy"] == "not excited"  # out-of-plane: zero columns
    assert b.counts() == {"determined": 6, "combination": 3, "poorly excited": 0, "not excited": 13}
    assert np.isfinite(b.condition_number) and b.condition_number >= 1


def test_panda_rank_and_regrouping_against_numpy_and_scipy():
    """Random states excite everything a 7R arm can show: the rank equals numpy's SVD rank of
    the regressor, the singular values of the column-scaled regressor agree with numpy's, the
    independent columns are independent for scipy's pivoted QR, and X_dep = X_B beta."""
    model = RigidBodyModel.from_urdf(
        torchjfa.robots.path("panda_arm"), friction=("viscous", "coulomb", "offset")
    )
    Y, _, m = _random_moments(model, 300)
    b = base_parameters(m, model)
    X = Y.numpy()
    norms = np.linalg.norm(X, axis=0)
    # columns that cancel in exact arithmetic come out at ~eps of the largest (joint 2's mcz
    # here, ~1e-17): zero them, as base_parameters does (a genuine column is > 1e-3)
    X = np.where(norms > 1e-12 * norms.max(), X, 0.0)
    norms = np.where(norms > 1e-12 * norms.max(), norms, 0.0)
    Xs = X / np.where(norms > 0, norms, 1.0)
    s = np.linalg.svd(Xs, compute_uv=False)
    # a structural null direction of the scaled X has a singular value of rounding size,
    # ~1e-14 here; the smallest genuine one is above 1e-4: the threshold 1e-8 separates them
    rank = int((s > 1e-8 * s[0]).sum())
    assert b.rank == rank
    # the eigenvalues of the scaled X^T X carry an absolute error ~ d eps s_1^2, so the singular
    # values agree to ~1e-14 / s_i relative: 1e-9 for the base ones (s_i / s_1 > 1e-4)
    np.testing.assert_allclose(b.singular_values[:rank].numpy(), s[:rank] / s[0], rtol=1e-6)
    assert b.condition_number == pytest.approx(s[0] / s[rank - 1], rel=1e-6)
    ind, dep = list(b.independent), list(b.dependent)
    _, R, _ = scipy.linalg.qr(Xs[:, ind], pivoting=True, mode="economic")
    assert abs(R[-1, -1]) > 1e-8 * abs(R[0, 0])  # the chosen columns are independent
    beta = b.beta.numpy()
    ref, *_ = np.linalg.lstsq(X[:, ind], X[:, dep], rcond=None)
    np.testing.assert_allclose(X[:, ind] @ beta, X[:, dep], atol=1e-8 * np.abs(X).max())
    np.testing.assert_allclose(beta, ref, atol=1e-6 * max(1.0, np.abs(ref).max()))
    # Y theta = X_B (base values of theta) for any theta: the base parameters are all the data see
    theta = torch.randn(
        model.n_params, generator=torch.Generator().manual_seed(1), dtype=torch.float64
    )
    np.testing.assert_allclose(
        X[:, ind] @ b.values(theta).numpy(),
        Y.numpy() @ theta.numpy(),
        rtol=1e-9,
        atol=1e-9 * np.abs(X @ theta.numpy()).max(),
    )
    # moving theta along the null space leaves the base values unchanged
    null = b.null_space[:, 0] / torch.from_numpy(np.where(norms > 0, norms, 1.0))
    np.testing.assert_allclose(
        b.values(theta + 10 * null).numpy(), b.values(theta).numpy(), atol=1e-8
    )
    assert set(b.status) <= {"determined", "combination", "not excited"}


def test_a_weakly_excited_direction_is_poorly_excited_not_structural():
    """Columns z0, z1, z1 + delta z2 with noise 1: the direction (0, -1, 1) has eigenvalue
    ~ delta^2 N, so least squares estimates it to 1 / (delta sqrt N); with delta = 1e-2 and
    N = 1e4 that is 1, above a tenth of the scale 1: poorly excited; with delta = 1 it is 0.01."""
    g = torch.Generator().manual_seed(0)
    n = 10_000
    z = torch.randn(n, 3, generator=g, dtype=torch.float64)
    names = ("a.m", "b.m", "c.m")
    for delta, expected in ((1e-2, "poorly excited"), (1.0, "determined")):
        X = torch.stack([z[:, 0], z[:, 1], z[:, 1] + delta * z[:, 2]], 1)
        y = X @ torch.ones(3, dtype=torch.float64) + torch.randn(
            n, generator=g, dtype=torch.float64
        )
        b = base_parameters(Moments.from_data(X, y), names=names, description=torch.ones(3))
        assert b.rank == 3 and b.status[0] == "determined"
        assert b.status[1] == b.status[2] == expected
        assert b.noise_var == pytest.approx(1.0, rel=0.05)  # 5%: ~7 sigma of a chi^2 with 1e4 dof
        # the least-squares std of each base parameter, against numpy's (X^T X)^-1
        cov = np.linalg.inv((X.T @ X).numpy()) * b.noise_var
        order = list(b.independent)
        np.testing.assert_allclose(b.std.numpy(), np.sqrt(np.diag(cov))[order], rtol=1e-8)


def test_jackknife_std_of_base_values_by_hand(two_link):
    _, _, m = _random_moments(two_link, 200)
    b = base_parameters(m, two_link)
    coefs = torch.randn(
        4, two_link.n_params, generator=torch.Generator().manual_seed(2), dtype=torch.float64
    )
    vals = b.values(coefs).numpy()
    expected = np.sqrt(3 / 4 * ((vals - vals.mean(0)) ** 2).sum(0))
    np.testing.assert_allclose(b.jackknife_std(coefs).numpy(), expected, rtol=1e-12)


def test_parameter_scales_by_kind():
    names = ("a.m", "a.mcx", "a.Ixx", "a.fv", "b.m", "b.mcx", "b.Ixx", "b.fv")
    desc = torch.tensor([1.0, 0.3, 0.0, 0.0, 7.0, 0.4, 0.02, 0.0], dtype=torch.float64)
    X = torch.eye(8, dtype=torch.float64).repeat(2, 1) * 2.0
    y = torch.ones(16, dtype=torch.float64) * 3.0
    p = parameter_scales(names, desc, Moments.from_data(X, y))
    assert float(p[0]) == pytest.approx(5.0) and float(p[4]) == pytest.approx(5.0)  # rms(1, 7)
    assert float(p[1]) == pytest.approx(float(np.sqrt((0.09 + 0.16) / 2)))
    assert float(p[2]) == pytest.approx(float(np.sqrt(0.0004 / 2)))
    # friction: sqrt(y^T y / X_k^T X_k) = sqrt(144 / 8)
    assert float(p[3]) == pytest.approx(float(np.sqrt(144 / 8)))


def test_bad_input():
    with pytest.raises(TypeError, match="Moments"):
        base_parameters(torch.eye(3), names=("a", "b", "c"))
    with pytest.raises(ValueError, match="excite no parameter"):
        base_parameters(Moments.zeros(2), names=("a.m", "b.m"))
    with pytest.raises(ValueError, match="names"):
        base_parameters(Moments.zeros(2), names=("a.m",))


def test_units_do_not_change_what_the_data_determine(two_link):
    """Measuring parameters in other units (X columns times c_k, theta_k and the description
    divided by c_k, one c per kind) changes no rank, status or condition number (the column scaling removes the units), and the
    regrouping coefficients by the unit ratios c_dep / c_ind."""
    Y, tau, _ = _random_moments(two_link, 300)
    # one unit per kind (the physical scales are per kind): g, cm-ish, odd units for I and fv
    from torchjfa.physical._base import parameter_kind

    unit = {"m": 1e3, "mc": 1e-2, "I": 3e4, "fv": 0.1}
    c = torch.tensor(
        [unit[parameter_kind(n)] for n in two_link.parameter_names], dtype=torch.float64
    )
    ref = base_parameters(Moments.from_data(Y, tau), two_link)
    new = base_parameters(  # the description in the new units too
        Moments.from_data(Y * c, tau), names=two_link.parameter_names,
        description=two_link.nominal_theta / c,
    )  # fmt: skip
    assert new.rank == ref.rank and new.status == ref.status
    assert new.condition_number == pytest.approx(ref.condition_number, rel=1e-9)
    assert new.independent == ref.independent
    ind, dep = list(ref.independent), list(ref.dependent)
    expected = ref.beta * c[dep].unsqueeze(0) / c[ind].unsqueeze(1)  # X_dep c_dep = X_B c_B beta'
    torch.testing.assert_close(new.beta, expected, rtol=1e-8, atol=1e-12)
