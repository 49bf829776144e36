"""Random rigid bodies for the tests of `torchjfa.physical`: a layout and point-cloud bodies."""

import torch

from torchjfa.dynamics import ParameterLayout, inertial_vector


def make_layout(n_joints, friction=("viscous",)):
    """A `ParameterLayout` of ``n_joints`` joints named ``j0, j1, ...``."""
    return ParameterLayout(tuple(f"j{i}" for i in range(n_joints)), friction)


def cloud_bodies(n_joints, g, *, n_points, min_weight):
    """``(n_joints, 10)`` inertial vectors of weighted point clouds: fully consistent bodies
    (positive definite pseudo-inertia), points ``N(0, 0.2^2)``, weights ``min_weight + U(0, 1)``."""
    bodies = []
    for _ in range(n_joints):
        points = torch.randn(n_points, 3, generator=g, dtype=torch.float64) * 0.2
        weights = torch.rand(n_points, generator=g, dtype=torch.float64) + min_weight
        mass = weights.sum()
        com = (weights[:, None] * points).sum(0) / mass
        rel = points - com
        inertia = sum(
            w * ((r @ r) * torch.eye(3, dtype=torch.float64) - torch.outer(r, r))
            for w, r in zip(weights, rel, strict=True)
        )
        bodies.append(inertial_vector(mass, com, inertia))
    return torch.stack(bodies)


#: masses the data leave undetermined: exactly 0, shrunk by a relevance prior to 5e-181 kg (a
#: real Panda log), and 1e-300; each with a first moment h that stayed O(1)
VANISHING_MASSES = (0.0, 5e-181, 1e-300)


def vanishing_mass_theta(layout, m, g):
    """Point-cloud bodies and viscous friction 0.1, body 1's mass set to ``m`` with its first
    moment ``h = (0.3, -0.2, 0.1)`` kg m kept: the centre of mass ``h / m`` is 1e180 m or more."""
    bodies = cloud_bodies(layout.n_joints, g, n_points=5, min_weight=0.2)
    bodies[1, 0] = m
    bodies[1, 1:4] = torch.tensor([0.3, -0.2, 0.1], dtype=torch.float64)
    friction = torch.full((layout.n_joints, layout.n_friction), 0.1, dtype=torch.float64)
    return layout.join(bodies, friction)
