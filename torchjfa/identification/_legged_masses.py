"""Which bodies' masses a floating-base log determines, and how well.

A standing robot's rows leave much to the description: with every foot down and contact flags
only, the total mass is partly in the null space of the projected rows, and a leg that never
leaves the ground shares its weight with the contact forces. For each body, `mass_spread`
says whether its mass lies in the space the training rows span (the share of its unit
direction outside the span, below `NULL_SHARE`) and its spread from the data alone: the delete-one-
block jackknife of the weighted least-squares estimate over the training data's blocks (the
description prior's cross-validation blocks, contiguous in time, so that the filter's
correlation between neighbouring samples stays inside a block). A mass is *determined* where
it lies in the rows' span and its spread is at most `DETERMINED_SPREAD` of its value.

In a tree of revolute joints no single body's mass is: a point mass at a joint's axis can be
moved between the two bodies it joins without changing any torque or contact force (the
regrouping of the base parameters). What the rows can determine is the total mass (where the
weight is seen: measured contact forces, or a foot in the air), and each body's mass leans on
the description prior.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch

from ..dynamics import FloatingBaseModel
from ._contacts import RowMoments

__all__ = ["DETERMINED_SPREAD", "NULL_SHARE", "mass_index", "mass_spread"]

#: a body's mass counts as determined where its spread is at most this fraction of it
DETERMINED_SPREAD = 0.03
#: a mass direction's share outside the rows' span above which it is not determined whatever
#: its spread
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
