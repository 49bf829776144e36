import math

import pytest
import torch
from _bodies import VANISHING_MASSES, cloud_bodies, make_layout, vanishing_mass_theta

from torchjfa.dynamics import inertial_vector, pseudo_inertia
from torchjfa.physical import LogCholeskyParameters, VirtualParameters, check

PARAMETRIZATIONS = [VirtualParameters, LogCholeskyParameters]
FRICTIONS = [("viscous",), ("viscous", "coulomb", "offset"), ()]


def _consistent_theta(layout, g):
    """Random bodies with a positive definite pseudo-inertia (point clouds), positive friction,
    any offset."""
    bodies = cloud_bodies(layout.n_joints, g, n_points=6, min_weight=0.1)
    friction = torch.rand(layout.n_joints, layout.n_friction, generator=g, dtype=torch.float64)
    for k, kind in enumerate(layout.friction):
        if kind == "offset":
            friction[:, k] -= 0.5
    return layout.join(bodies, friction + 0.05)


def _eq5_written_out(phi):
    """The seed paper's eq. 5 for one joint, typed in from the paper (1-based phi)."""
    p = [None] + [float(v) for v in phi]
    m = p[1] ** 2
    return torch.tensor(
        [
            m,
            p[2] * m,
            p[3] * m,
            p[4] * m,
            p[5] ** 2 + (p[4] ** 2 + p[3] ** 2) * m,  # Ixx
            p[5] * p[6] - p[2] * p[3] * m,  # Ixy
            p[6] ** 2 + p[8] ** 2 + (p[2] ** 2 + p[4] ** 2) * m,  # Iyy
            p[5] * p[7] - p[2] * p[4] * m,  # Ixz
            p[6] * p[7] + p[8] * p[9] - p[3] * p[4] * m,  # Iyz
            p[7] ** 2 + p[9] ** 2 + p[10] ** 2 + (p[2] ** 2 + p[3] ** 2) * m,  # Izz
            p[11] ** 2,
        ],
        dtype=torch.float64,
    )


def test_virtual_parameters_match_eq5_of_the_paper():
    g = torch.Generator().manual_seed(0)
    layout = make_layout(3)
    phi = torch.randn(3, 11, generator=g, dtype=torch.float64)
    theta = VirtualParameters(layout, phi=phi)()
    expected = torch.cat([_eq5_written_out(row) for row in phi])
    torch.testing.assert_close(theta, expected, rtol=1e-12, atol=1e-12)


def test_log_cholesky_matches_written_out_factor():
    g = torch.Generator().manual_seed(1)
    layout = make_layout(2, ())
    phi = torch.randn(2, 10, generator=g, dtype=torch.float64)
    theta = LogCholeskyParameters(layout, phi=phi)()
    for j in range(2):
        a, d1, d2, d3, s12, s23, s13, t1, t2, t3 = phi[j].tolist()
        U = math.exp(a) * torch.tensor(
            [
                [math.exp(d1), s12, s13, t1],
                [0, math.exp(d2), s23, t2],
                [0, 0, math.exp(d3), t3],
                [0, 0, 0, 1],
            ],
            dtype=torch.float64,
        )
        torch.testing.assert_close(pseudo_inertia(theta[10 * j : 10 * j + 10]), U @ U.T)
        assert theta[10 * j].item() == pytest.approx(math.exp(2 * a))


@pytest.mark.parametrize("cls", PARAMETRIZATIONS)
@pytest.mark.parametrize("friction", FRICTIONS)
def test_every_phi_is_consistent(cls, friction):
    g = torch.Generator().manual_seed(2)
    layout = make_layout(5, friction)
    for _ in range(5):
        phi = 2 * torch.randn(5, layout.params_per_joint, generator=g, dtype=torch.float64)
        theta = cls(layout, phi=phi)()
        assert theta.shape == (layout.n_params,)
        report = check(theta, layout)
        assert report.weakly_ok, str(report)
        if cls is LogCholeskyParameters:
            assert report.ok, str(report)
            assert bool((report.pseudo_inertia_min_eig > 0).all())


def test_virtual_parameters_can_violate_triangle_inequality():
    # eq. 5 only makes I_c positive semidefinite: I_c = diag(1, 1, 9) m^2 kg breaks 1 + 1 >= 9
    layout = make_layout(1)
    phi = torch.tensor([[1.0, 0, 0, 0, 1.0, 0, 0, 1.0, 0, 3.0, 0.5]], dtype=torch.float64)
    report = check(VirtualParameters(layout, phi=phi)(), layout)
    assert report.weakly_ok and not report.ok
    assert not bool(report.triangle_ok[0]) and not bool(report.pseudo_inertia_ok[0])


@pytest.mark.parametrize("cls", PARAMETRIZATIONS)
@pytest.mark.parametrize("friction", FRICTIONS)
def test_from_theta_is_exact_on_consistent_parameters(cls, friction):
    g = torch.Generator().manual_seed(3)
    layout = make_layout(4, friction)
    theta = _consistent_theta(layout, g)
    module = cls.from_theta(theta, layout)
    torch.testing.assert_close(module(), theta, rtol=1e-10, atol=1e-10)


def test_virtual_from_theta_is_exact_on_singular_inertia():
    # a point mass and a thin rod: I_c singular but PSD, representable exactly by eq. 5
    layout = make_layout(2, ())
    m = torch.tensor([1.5, 2.0], dtype=torch.float64)
    com = torch.tensor([[0.1, 0.2, -0.1], [0.0, 0.3, 0.0]], dtype=torch.float64)
    rod = torch.diag(torch.tensor([0.04, 0.0, 0.04], dtype=torch.float64))
    inertia = torch.stack([torch.zeros(3, 3, dtype=torch.float64), rod])
    theta = layout.join(inertial_vector(m, com, inertia))
    torch.testing.assert_close(VirtualParameters.from_theta(theta, layout)(), theta)


@pytest.mark.parametrize("cls", PARAMETRIZATIONS)
def test_from_theta_repairs_inconsistent_parameters(cls):
    g = torch.Generator().manual_seed(4)
    layout = make_layout(6, ("viscous", "coulomb", "offset"))
    theta = torch.randn(layout.n_params, generator=g, dtype=torch.float64)
    assert not check(theta, layout).weakly_ok
    out = cls.from_theta(theta, layout)().detach()
    report = check(out, layout)
    assert report.weakly_ok, str(report)
    if cls is LogCholeskyParameters:
        assert report.ok, str(report)
    # bodies that were already fine stay put; offsets are never changed
    inertial_in, friction_in = layout.split(theta)
    _, friction_out = layout.split(out)
    torch.testing.assert_close(friction_out[:, 2], friction_in[:, 2])
    pos = friction_in[:, :2] >= 0
    torch.testing.assert_close(friction_out[:, :2][pos], friction_in[:, :2][pos])


@pytest.mark.parametrize("cls", PARAMETRIZATIONS)
def test_gradient_matches_finite_differences(cls):
    g = torch.Generator().manual_seed(5)
    layout = make_layout(2, ("viscous", "coulomb", "offset"))
    module = cls(layout)
    phi = 0.5 * torch.randn(2, layout.params_per_joint, generator=g, dtype=torch.float64)

    def f(p):
        return torch.func.functional_call(module, {"phi": p}, ())

    assert torch.autograd.gradcheck(f, (phi.requires_grad_(True),))


@pytest.mark.parametrize("cls", PARAMETRIZATIONS)
def test_dtype_follows_module_and_layout_from_model(cls):
    class Model:
        layout = make_layout(3)

    module = cls(Model())
    assert module().dtype == torch.float64
    assert module.to(torch.float32)().dtype == torch.float32
    assert len(module.variable_names) == 11
    # the default body is consistent and identical for both parametrisations
    torch.testing.assert_close(module.double()(), VirtualParameters(Model.layout)())
    assert check(module.double()(), Model.layout).ok


@pytest.mark.parametrize("cls", PARAMETRIZATIONS)
def test_bad_input_raises(cls):
    layout = make_layout(2)
    with pytest.raises(TypeError, match="ParameterLayout"):
        cls("not a layout")
    with pytest.raises(ValueError, match="phi must have shape"):
        cls(layout, phi=torch.zeros(2, 10))
    with pytest.raises(ValueError, match="theta must have shape"):
        cls.from_theta(torch.zeros(5), layout)
    with pytest.raises(ValueError, match="NaN"):
        cls.from_theta(torch.full((22,), float("nan")), layout)


@pytest.mark.parametrize("cls", PARAMETRIZATIONS)
@pytest.mark.parametrize("m", VANISHING_MASSES)
def test_from_theta_of_a_vanishing_mass_is_a_finite_consistent_start(cls, m):
    layout = make_layout(3)
    theta = vanishing_mass_theta(layout, m, torch.Generator().manual_seed(2))
    module = cls.from_theta(theta, layout)
    out = module().detach()
    assert bool(torch.isfinite(module.phi).all()) and bool(torch.isfinite(out).all())
    report = check(out, layout)
    assert report.weakly_ok, str(report)
    if cls is LogCholeskyParameters:
        assert report.ok, str(report)
    # the consistent bodies stay put
    torch.testing.assert_close(out[:10], theta[:10], rtol=1e-10, atol=1e-12)
    torch.testing.assert_close(out[22:], theta[22:], rtol=1e-10, atol=1e-12)
    if cls is VirtualParameters:
        # the mass is raised to 4 |h|^2 / tr(I_o), which keeps h (the centre of mass at
        # 1/sqrt(2) of the radius sqrt(tr(I_o) / (2 m)) beyond which tr(I_c) < 0)
        trace = float(theta[11 + 4] + theta[11 + 6] + theta[11 + 9])
        assert float(out[11]) == pytest.approx(4 * 0.14 / trace, rel=1e-12)
        torch.testing.assert_close(out[12:15], theta[12:15], rtol=1e-12, atol=0)


@pytest.mark.parametrize("cls", PARAMETRIZATIONS)
@pytest.mark.parametrize("scale", [1e-300, 1e300])
def test_from_theta_is_exact_at_any_scale(cls, scale):
    g = torch.Generator().manual_seed(3)
    layout = make_layout(4, ("viscous", "coulomb", "offset"))
    theta = scale * _consistent_theta(layout, g)
    out = cls.from_theta(theta, layout)().detach()
    assert bool(torch.isfinite(out).all())
    torch.testing.assert_close(out / scale, theta / scale, rtol=1e-10, atol=1e-10)
