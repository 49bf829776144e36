"""Which bodies' masses a floating-base log sees at all, and their spread from the data.

A standing robot's rows leave much to the description: with every foot down and contact flags
only, the total mass is partly in the null space of the projected rows, and in a tree of
revolute joints no single body's mass is in the rows' span: a point mass on a joint's axis can
move between the two bodies it joins without changing any torque or contact force (the
regrouping of the base parameters). What the rows can see is the total mass (where they see
the weight: measured contact forces, or a foot in the air); the bodies' masses lean on the
description prior.

For each body and the total, `mass_spread` says whether the mass lies in the space the
training rows span (the share of its unit direction outside the span below `NULL_SHARE`) and
gives its spread from the data: the delete-one-block jackknife of the weighted least-squares
estimate over the training data's blocks (the description prior's cross-validation blocks,
contiguous in time, so that the filter's correlation between neighbouring samples stays inside
a block). The spread is the estimate's variance only: the bias of noisy, filtered base
accelerations (errors in the variables) and of the contact model is not in it, and in
simulation it can be ten times smaller than the error.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch

from ..dynamics import FloatingBaseModel
from ._contacts import RowMoments

__all__ = ["NULL_SHARE", "mass_index", "mass_spread"]

#: a mass direction's share outside the rows' span above which the rows do not see it
NULL_SHARE = 1e-6
#: the rows' null space: the eigenvalues of their weighted Gram matrix below this fraction of
#: the largest (round-off)
_NULL_EIGEN = 1e-10


def mass_index(model: FloatingBaseModel) -> torch.Tensor:
    """The positions of the bodies' masses in theta, the base's first."""
    inertial, _ = model.joints.layout.split(torch.arange(model.joints.n_params))
    return torch.cat([torch.tensor([0]), 10 + inertial[:, 0].long()])


def _solve(xtx: torch.Tensor, xty: torch.Tensor) -> torch.Tensor:
    return torch.linalg.lstsq(xtx, xty[:, None], driver="gelsd").solution[:, 0]


def mass_spread(
    model: FloatingBaseModel, blocks: Sequence[RowMoments], weights: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """``(spread (n_bodies + 1,) kg, in_span (n_bodies + 1,) bool)``: each body's mass and,
    last, the total mass: its spread (the delete-one-block jackknife over ``blocks`` of the
    weighted least-squares estimate; NaN with fewer than two blocks) and whether its
    direction lies in the rows' span."""
    index = mass_index(model)
    directions = torch.zeros(len(index) + 1, model.n_params, dtype=torch.float64)
    directions[torch.arange(len(index)), index] = 1.0
    directions[-1, index] = 1.0  # the total mass
    parts = [b.combined(weights) for b in blocks]
    total_xtx = sum(p.xtx for p in parts)
    total_xty = sum(p.xty for p in parts)
    evals, evecs = torch.linalg.eigh(total_xtx)
    null = evecs[:, evals <= _NULL_EIGEN * float(evals.max())]
    unit = directions / directions.norm(dim=1, keepdim=True)
    in_span = (unit @ null).pow(2).sum(-1) < NULL_SHARE  # each direction's share outside
    K = len(parts)
    if K < 2:
        return torch.full((len(directions),), math.nan, dtype=torch.float64), in_span
    masses = torch.stack(
        [directions @ _solve(total_xtx - p.xtx, total_xty - p.xty) for p in parts]
    )  # (K, n_bodies + 1)
    spread = ((K - 1) / K * (masses - masses.mean(0)).pow(2).sum(0)).sqrt()
    return spread, in_span
