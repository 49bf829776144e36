"""What a trajectory tells about the identifiable parameters: the information and its criteria.

The information a trajectory carries about the identifiable (base) parameters is the weighted
moment matrix of the regressor restricted to the identifiable directions,
``M = V^T (1/N sum_i Y_i^T W Y_i) V`` over the N grid points ``t_i``, with ``V (n_params, r)`` an
orthonormal basis of the regressor's row space (`base_directions`); the criteria (`CRITERIA`,
`criterion_value`) are described in `torchjfa.excitation._design`, which optimises them.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from .._validation import check_joint_weights
from ..dynamics import RigidBodyModel
from ._limits import Limits

__all__ = [
    "CRITERIA",
    "base_directions",
    "payload_directions",
    "information_matrix",
    "criterion_value",
    "soft_condition",
    "trajectory_information",
]

CRITERIA = ("d+condition", "d", "condition", "e")


def base_directions(
    model: RigidBodyModel,
    limits: Limits,
    *,
    n_samples: int | None = None,
    joint_weights=None,
    rtol: float = 1e-9,
    generator: torch.Generator | None = None,
) -> torch.Tensor:
    """An orthonormal basis of the identifiable parameter directions.

    The regressor at ``n_samples`` random states (positions uniform in the limits, velocities
    and accelerations uniform in +-min(limit, 2 rad/s) and +-min(limit, 10 rad/s^2)) is
    stacked and decomposed; right singular vectors with singular values above
    ``rtol * s_max`` span what any motion can identify.

    Args:
        model: the robot.
        limits: its `Limits`.
        n_samples: random states (default ``max(200, 4 * n_params)``).
        joint_weights: ``(n_dof,)`` weights of each joint's equations (default 1).
        rtol: relative rank tolerance.
        generator: the random draws' `torch.Generator`.

    Returns:
        ``(n_params, r)`` float64 basis V.
    """
    Y = _random_regressor(model, limits, n_samples, joint_weights, generator)
    _, s, Vh = torch.linalg.svd(Y, full_matrices=False)
    r = int((s > rtol * s[0]).sum())
    return Vh[:r].T.contiguous()


def payload_directions(
    model: RigidBodyModel,
    limits: Limits,
    link: str,
    *,
    n_samples: int | None = None,
    joint_weights=None,
    rtol: float = 1e-9,
    generator: torch.Generator | None = None,
) -> torch.Tensor:
    """The parameter directions of a payload fixed to ``link``, for an excitation that
    identifies the payload alone (the robot's model given).

    A payload's 10 parameters ``pi`` in ``link``'s frame enter the torques as ``E A pi``
    (``E`` the carrying body's 10 columns of theta, ``A`` the rigid map of
    `torchjfa.identification._payload.payload_regressor`). Of the payload's directions, those
    some motion reveals are the right singular vectors of ``Y E A`` at random states (as
    `base_directions` draws them) above ``rtol * s_max``; the basis returned is ``E A B``,
    ``(n_params, r)``, so that the information ``V^T Y^T W Y V`` is the payload's.

    Raises:
        ValueError: if ``link`` is no frame of the robot or is fixed to its base.
    """
    from ..identification._errors import IdentificationError
    from ..identification._payload import payload_regressor

    try:
        j, A = payload_regressor(model, link)
    except IdentificationError as exc:
        raise ValueError(str(exc)) from None
    cols = model.layout.split(torch.arange(model.n_params))[0][j]
    EA = torch.zeros(model.n_params, 10, dtype=torch.float64)
    EA[cols] = A
    Z = _random_regressor(model, limits, n_samples, joint_weights, generator) @ EA
    _, s, Vh = torch.linalg.svd(Z, full_matrices=False)
    r = int((s > rtol * s[0]).sum())
    return EA @ Vh[:r].T


def _random_regressor(model, limits, n_samples, joint_weights, generator) -> torch.Tensor:
    """``(n_samples n_dof, n_params)`` the weighted regressor at random states (see
    `base_directions`)."""
    n, P = model.n_dof, model.n_params
    B = max(200, 4 * P) if n_samples is None else int(n_samples)
    g = generator
    kw = {"dtype": torch.float64}
    lo = torch.as_tensor(limits.position_low, **kw)
    hi = torch.as_tensor(limits.position_high, **kw)
    vmax = torch.as_tensor(np.minimum(limits.velocity, 2.0), **kw)
    amax = torch.as_tensor(np.minimum(limits.acceleration, 10.0), **kw)
    q = lo + (hi - lo) * torch.rand(B, n, generator=g, **kw)
    qd = vmax * (2 * torch.rand(B, n, generator=g, **kw) - 1)
    qdd = amax * (2 * torch.rand(B, n, generator=g, **kw) - 1)
    Y = model.regressor(q, qd, qdd) * _sqrt_weights(joint_weights, n)[:, None]
    return Y.reshape(-1, P)


def _sqrt_weights(joint_weights, n: int, like: torch.Tensor | None = None) -> torch.Tensor:
    kw = {"dtype": torch.float64} if like is None else {"dtype": like.dtype, "device": like.device}
    if joint_weights is None:
        return torch.ones(n, **kw)
    return check_joint_weights(joint_weights, n, positive=True, **kw).sqrt()


def information_matrix(
    model: RigidBodyModel, q, qd, qdd, basis: torch.Tensor, *, joint_weights=None
) -> torch.Tensor:
    """``M = V^T (1/N sum_i Y_i^T W Y_i) V``, ``(r, r)``, differentiable in the states.

    Args:
        model: the robot.
        q: ``(N, n_dof)`` positions.
        qd: ``(N, n_dof)`` velocities.
        qdd: ``(N, n_dof)`` accelerations.
        basis: ``(n_params, r)`` V from `base_directions`.
        joint_weights: ``(n_dof,)`` W's diagonal (default 1).
    """
    return weighted_information(model.regressor(q, qd, qdd), basis, joint_weights)


def weighted_information(Y: torch.Tensor, basis: torch.Tensor, joint_weights) -> torch.Tensor:
    """M from the regressor ``Y (N, n_dof, n_params)``."""
    Yb = (Y * _sqrt_weights(joint_weights, Y.shape[-2], Y)[:, None]) @ basis.to(Y)  # (N, n, r)
    Yb = Yb.reshape(-1, Yb.shape[-1])
    return Yb.T @ Yb / Y.shape[0]


def criterion_value(M: torch.Tensor, kind: str = "d") -> torch.Tensor:
    """The criterion of an information matrix (smaller is better; see the module).

    Args:
        M: ``(r, r)`` symmetric positive definite information matrix.
        kind: ``"d"``, ``"condition"`` or ``"e"``; ``"d+condition"`` (D-optimal, then the
            condition number: the design's default) is valued as ``"condition"``.

    Returns:
        A 0-d tensor; +inf when M is singular (a direction not excited).
    """
    if kind not in CRITERIA:
        raise ValueError(f"criterion must be one of {CRITERIA}, got {kind!r}")
    ev = torch.linalg.eigvalsh(0.5 * (M + M.T))
    if not bool(ev[0] > 0):
        return ev.new_tensor(math.inf)
    if kind == "d":
        return -torch.log(ev).mean()
    if kind in ("condition", "d+condition"):
        return 0.5 * (torch.log(ev[-1]) - torch.log(ev[0]))
    return -torch.log(ev[0])


def soft_condition(M: torch.Tensor, p: float) -> torch.Tensor:
    """A smooth upper bound of ``log cond(Y V) = log(lambda_max / lambda_min) / 2``.

    The ratio of the eigenvalues' p-norms, ``(sum_i l_i^p)^(1/p) (sum_i l_i^-p)^(1/p)``, in
    logs and halved: ``(logsumexp(p log l) + logsumexp(-p log l)) / (2 p)``. It lies between
    ``log cond(Y V)`` and ``log cond(Y V) + log(r) / p`` (r eigenvalues), so it tends to the
    condition criterion as p grows, and, unlike it, is differentiable where the extreme
    eigenvalues are repeated (the minimax's optimum: LBFGS on the plain ratio stalls there).

    Args:
        M: ``(r, r)`` symmetric positive definite information matrix.
        p: the exponent, > 0 (raised over rounds by the design: 2, 8, 32, 128).

    Returns:
        A 0-d tensor; +inf when M is singular.
    """
    if not p > 0:
        raise ValueError(f"p must be positive, got {p}")
    ev = torch.linalg.eigvalsh(0.5 * (M + M.T))
    if not bool(ev[0] > 0):
        return ev.new_tensor(math.inf)
    log_ev = torch.log(ev)
    return (torch.logsumexp(p * log_ev, 0) + torch.logsumexp(-p * log_ev, 0)) / (2 * p)


def period_grid(period: float, n: int) -> torch.Tensor:
    """``(n,)`` float64 times ``k period / n``, s: n even steps over one period."""
    return torch.arange(n, dtype=torch.float64) * (period / n)


def trajectory_information(
    model: RigidBodyModel,
    trajectory,
    basis: torch.Tensor,
    *,
    n_grid: int = 1000,
    joint_weights=None,
) -> dict:
    """Criteria, condition number and singular values of a trajectory's base regressor.

    Args:
        model: the robot.
        trajectory: `FourierTrajectory` or `torchjfa.sim.SinusoidTrajectory` (model joint order).
        basis: ``(n_params, r)`` V.
        n_grid: samples over one period.
        joint_weights: W's diagonal.

    Returns:
        ``{"d", "condition", "e"}`` criterion values, ``"condition_number"`` (cond of Y V) and
        ``"singular_values"`` (of ``Y V / sqrt(N)``, descending, numpy).
    """
    with torch.no_grad():
        M = information_matrix(
            model,
            *trajectory(period_grid(trajectory.period, n_grid)),
            basis,
            joint_weights=joint_weights,
        )
        ev = torch.linalg.eigvalsh(M).clamp_min(0.0).flip(0)
        out = {k: float(criterion_value(M, k)) for k in CRITERIA}
    out["condition_number"] = float((ev[0] / ev[-1]).sqrt()) if ev[-1] > 0 else math.inf
    out["singular_values"] = ev.sqrt().numpy()
    return out
