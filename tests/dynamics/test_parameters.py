import pytest
import torch

from torchjfa.dynamics import (
    ParameterLayout,
    inertial_from_vector,
    inertial_vector,
    pseudo_inertia,
)


def _random_body(g, batch=()):
    mass = torch.rand(batch, generator=g, dtype=torch.float64) + 0.5
    com = torch.randn(*batch, 3, generator=g, dtype=torch.float64) * 0.2
    L = torch.randn(*batch, 3, 3, generator=g, dtype=torch.float64) * 0.1
    return mass, com, L @ L.transpose(-1, -2) + 1e-3 * torch.eye(3, dtype=torch.float64)


@pytest.mark.parametrize("batch", [(), (4,), (2, 3)])
def test_inertial_round_trip(batch):
    g = torch.Generator().manual_seed(0)
    mass, com, inertia = _random_body(g, batch)
    pi = inertial_vector(mass, com, inertia)
    assert pi.shape == (*batch, 10)
    m2, c2, i2 = inertial_from_vector(pi)
    torch.testing.assert_close(m2, mass)
    torch.testing.assert_close(c2, com)
    torch.testing.assert_close(i2, inertia)


def test_parallel_axis_theorem_written_out():
    mass, com = (
        torch.tensor(2.0, dtype=torch.float64),
        torch.tensor([0.1, -0.2, 0.3], dtype=torch.float64),
    )
    ic = torch.diag(torch.tensor([0.01, 0.02, 0.03], dtype=torch.float64))
    pi = inertial_vector(mass, com, ic)
    cx, cy, cz = com.tolist()
    # Pinocchio order: Ixx, Ixy, Iyy, Ixz, Iyz, Izz
    expected = [
        0.01 + 2 * (cy**2 + cz**2),
        -2 * cx * cy,
        0.02 + 2 * (cx**2 + cz**2),
        -2 * cx * cz,
        -2 * cy * cz,
        0.03 + 2 * (cx**2 + cy**2),
    ]
    torch.testing.assert_close(pi[4:], torch.tensor(expected, dtype=torch.float64))
    torch.testing.assert_close(pi[1:4], mass * com)


def test_pseudo_inertia_is_second_moment_of_mass():
    # a point mass m at p: J = m [p; 1][p; 1]^T
    m, p = 1.5, torch.tensor([0.3, -0.1, 0.2], dtype=torch.float64)
    pi = inertial_vector(
        torch.tensor(m, dtype=torch.float64), p, torch.zeros(3, 3, dtype=torch.float64)
    )
    v = torch.cat([p, torch.ones(1, dtype=torch.float64)])
    torch.testing.assert_close(pseudo_inertia(pi), m * torch.outer(v, v))


def test_layout_names_split_join():
    layout = ParameterLayout(("a", "b"), ("coulomb", "viscous"))
    assert layout.friction == ("viscous", "coulomb")
    assert layout.n_params == 24
    assert layout.parameter_names[:3] == ("a.m", "a.mcx", "a.mcy")
    assert layout.parameter_names[10:12] == ("a.fv", "a.fc")
    assert layout.index("b", "fc") == 23
    theta = torch.arange(24.0)
    inertial, friction = layout.split(theta)
    assert inertial.shape == (2, 10) and friction.shape == (2, 2)
    torch.testing.assert_close(layout.join(inertial, friction), theta)


def test_layout_bad_input():
    with pytest.raises(ValueError, match="unknown friction"):
        ParameterLayout(("a",), ("sticky",))
    with pytest.raises(ValueError, match="unique"):
        ParameterLayout(("a", "a"))
    with pytest.raises(ValueError, match="positive mass"):
        inertial_from_vector(torch.zeros(10))
