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
