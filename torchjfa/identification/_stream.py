"""Streaming the logs through the batched regressor into `Moments`: the first stage of `identify`.

`stream_moments` reads one or more joint logs ``chunk_size`` samples at a time (``.npz`` members
straight from the zip archive, in-memory arrays sliced), forms the regressor of each chunk and
accumulates `Moments` (of the whole, of contiguous folds, or per joint), split between the
processes of ``torch.distributed`` when asked; `residual_joint_weights` uses it for the per-joint
weights of weighted least squares, which `joint_weights` computes from any per-joint `Moments`
(the payload's too) with one floor, `JOINT_WEIGHT_FLOOR`. `stream_moments` and
`residual_joint_weights` are re-exported by `torchjfa.identification`, the public place to
import them from; its `fit` stage's docstring gives the memory bound.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from .._util import progress_bar
from .._validation import check_finite, check_joint_weights
from ..data import log_sources
from ..distributed import all_reduce_moments, rank_and_world_size, shard_range
from ..dynamics import RigidBodyModel
from ..estimators import OLS
from ..stats import CHUNK_SIZE, Moments

__all__ = [
    "JOINT_WEIGHT_FLOOR",
    "inverse_variance_weights",
    "joint_weights",
    "mapped_moments",
    "residual_joint_weights",
    "stream_moments",
    "weighted_joints",
]

#: the smallest residual variance a joint's weight assumes, as a share of the largest joint's:
#: no joint weighs more than ``1 / JOINT_WEIGHT_FLOOR`` times another, so that a joint whose
#: residual is all but zero (a joint that barely moves, or one a fit reproduces exactly) does
#: not decide every parameter alone
JOINT_WEIGHT_FLOOR = 1e-3


# ---------------------------------------------------------------------------------- sources
def _as_sources(model: RigidBodyModel, logs) -> list:
    return log_sources(logs, model.joint_names)


# ---------------------------------------------------------------------------------- moments
def _plan(lengths: list[int], n_folds: int, rank: int, world: int, chunk: int) -> list[list]:
    """Per source, the ``(start, stop, fold)`` segments this process reads.

    Samples are numbered across the logs in order; this process takes the contiguous global
    range `shard_range` gives it; fold k holds global samples ``[round(k T / K),
    round((k + 1) T / K))`` (as `torchjfa.kfold_moments`); no segment crosses a fold boundary
    or exceeds ``chunk`` samples.
    """
    total = sum(lengths)
    lo, hi = shard_range(total, rank, world)
    bounds = [round(k * total / n_folds) for k in range(n_folds + 1)]
    plan, offset = [], 0
    for n in lengths:
        segs = []
        for k in range(n_folds):
            a = max(lo, bounds[k], offset)
            b = min(hi, bounds[k + 1], offset + n)
            for s in range(a, b, chunk):
                segs.append((s - offset, min(b, s + chunk) - offset, k))
        plan.append(segs)
        offset += n
    return plan


def stream_moments(
    model: RigidBodyModel,
    logs,
    *,
    chunk_size: int = CHUNK_SIZE,
    n_folds: int | None = None,
    distributed: bool = False,
    group=None,
    device: torch.device | str | None = None,
    progress: bool = False,
    joint_weights=None,
    per_joint: bool = False,
    compiled: bool | None = None,
) -> Moments | list[Moments]:
    """`Moments` of ``tau ~ Y(q, qd, qdd) theta`` over all samples of the logs, streamed.

    Args:
        model: the robot.
        logs: one log or a list of logs. A log is a path to an ``.npz`` file with arrays
            ``q, qd, qdd, tau`` of shape ``(n_samples, n_dof)`` (rad, rad/s, rad/s^2, N m; the
            `torchjfa.sim.SimulatedLog` format, compressed or not; an optional ``joint_names``
            array maps the columns onto the model's joints), a `SimulatedLog`, a mapping of
            those arrays, or any object with those attributes (numpy arrays, memory maps or
            tensors).
        chunk_size: samples per chunk; memory is about ``chunk_size * n_dof * n_params * 8``
            bytes of regressor rows (twice that while it is formed).
        n_folds: if given, return the `Moments` of ``n_folds`` contiguous folds of the
            samples, numbered across the logs in order (for estimators that choose a
            hyper-parameter by cross-validation).
        distributed: split the samples between the processes of ``torch.distributed``
            (initialised before the call) and all-reduce the result. Every process must make
            the same call with the same logs.
        group: the process group (default: the default group).
        device: where the regressor and the moments are computed (default CPU).
        progress: show a progress bar (in every process).
        joint_weights: ``(n_dof,)`` non-negative weight of each joint's rows (weighted least
            squares, see `residual_joint_weights`); default 1.
        per_joint: return, in place of each `Moments`, a list of ``n_dof`` `Moments` of each
            joint's rows alone (model joint order).
        compiled: which path forms the regressor (`RigidBodyModel.regressor`): None (the
            default) the C++ kernel generated for the robot where a C++ compiler is there
            (several times faster; the first call for a robot compiles it, once), the
            torch path otherwise; True insists on the kernel, False takes the torch path.

    Returns:
        One `Moments` with ``n_features = model.n_params`` and one row per sample and joint,
        or a list of ``n_folds`` of them (their sum is the whole); with ``per_joint``, each
        of those is a list of ``n_dof`` `Moments`.

    Raises:
        TypeError: on an unknown kind of log.
        ValueError: on logs with other joints than the model, mismatched shapes, NaN or
            infinite values (with the file and sample range), or bad arguments.
        FileNotFoundError: if a log file does not exist.
    """
    if not isinstance(model, RigidBodyModel):
        raise TypeError(f"model must be a torchjfa.dynamics.RigidBodyModel, got {type(model)}")
    if isinstance(chunk_size, bool) or not isinstance(chunk_size, int) or chunk_size < 1:
        raise ValueError(f"chunk_size must be a positive int, got {chunk_size!r}")
    folds = 1 if n_folds is None else n_folds
    if isinstance(folds, bool) or not isinstance(folds, int) or folds < 1:
        raise ValueError(f"n_folds must be a positive int or None, got {n_folds!r}")
    sources = _as_sources(model, logs)
    lengths = [src.shape[0] for src in sources]
    if folds > sum(lengths):
        raise ValueError(f"n_folds={folds} is more than the {sum(lengths)} samples of the logs")
    rank, world = rank_and_world_size(group) if distributed else (0, 1)
    if distributed and world == 1 and not _dist_initialized():
        raise ValueError(
            "distributed=True needs an initialised torch.distributed process group (torchrun, "
            "Lightning, or torchjfa.distributed.process_group)"
        )
    device = torch.device("cpu") if device is None else torch.device(device)
    plan = _plan(lengths, folds, rank, world, chunk_size)
    p, n_dof = model.n_params, model.n_dof
    weights = check_joint_weights(joint_weights, n_dof)
    parts = n_dof if per_joint else 1
    moments = [Moments.zeros(p, device=device) for _ in range(folds * parts)]
    todo = sum(b - a for segs in plan for a, b, _ in segs)
    bar = progress_bar(total=todo, desc="moments", enabled=progress, unit="sample")
    with bar, torch.no_grad():
        for src, segs in zip(sources, plan, strict=True):
            if not segs:
                continue
            for (a, b, k), arrays in src.read(segs):
                q, qd, qdd, tau = (
                    (v if src.perm is None else v[:, src.perm]).to(device) for v in arrays
                )
                try:
                    Y = model.regressor(q, qd, qdd, compiled=compiled)  # (b - a, n_dof, p)
                    check_finite(tau, "tau")
                except ValueError as err:
                    raise ValueError(f"{src.name}, samples [{a}, {b}): {err}") from err
                w = None if weights is None else weights.to(Y).expand(b - a, n_dof)
                if per_joint:
                    for j in range(n_dof):
                        wj = None if w is None else w[:, j]
                        moments[k * n_dof + j].update(Y[:, j], tau[:, j], wj)
                else:
                    moments[k].update(
                        Y.reshape(-1, p), tau.reshape(-1), None if w is None else w.reshape(-1)
                    )
                bar.update(b - a)
    if distributed:
        moments = all_reduce_moments(moments, group)
    if per_joint:
        moments = [moments[k * n_dof : (k + 1) * n_dof] for k in range(folds)]
    return moments[0] if n_folds is None else moments


def residual_joint_weights(
    model: RigidBodyModel,
    logs,
    *,
    floor: float = JOINT_WEIGHT_FLOOR,
    chunk_size: int = CHUNK_SIZE,
    **kwargs,
) -> torch.Tensor:
    """Per-joint weights ``1 / sigma_j^2`` for weighted least squares, scaled to mean 1.

    The classic two-step recipe of robot identification (Gautier and Poignet): fit ordinary
    least squares on all joints' equations, take each joint's residual variance ``sigma_j^2``
    (noise and model error of that joint together), and weight that joint's equations by its
    inverse. Without it the joints with the largest torques decide every parameter, the
    distal links included: on the simulated head the weighting lowers the held-out torque nMSE
    of the eye joints 2-3x (docs/report.md).

    Args:
        model: the robot.
        logs: as for `stream_moments`.
        floor: ``sigma_j^2`` is at least ``floor`` times the largest joint's (weights at most
            ``1 / floor`` times the smallest; `JOINT_WEIGHT_FLOOR`).
        chunk_size: as for `stream_moments`.
        **kwargs: more `stream_moments` options (``distributed``, ``group``, ``device``,
            ``progress``, ``compiled``).

    Returns:
        ``(n_dof,)`` float64 weights, mean 1, in the model's joint order.
    """
    parts = stream_moments(model, logs, chunk_size=chunk_size, per_joint=True, **kwargs)
    return joint_weights(parts, floor=floor)


def joint_weights(parts: Sequence[Moments], *, floor: float = JOINT_WEIGHT_FLOOR) -> torch.Tensor:
    """``(n_dof,)`` weights ``1 / sigma_j^2``, mean 1, from each joint's `Moments`.

    ``sigma_j^2`` is the residual variance of joint ``j``'s rows under the ordinary least
    squares fit of all the joints' rows together (`residual_joint_weights`, whose rows are the
    robot's; the payload's rows are its own).

    Args:
        parts: ``n_dof`` `Moments` of the same features, joint ``j``'s rows in the ``j``-th.
        floor: as for `residual_joint_weights` (`inverse_variance_weights`).

    Returns:
        ``(n_dof,)`` float64 weights on the moments' device.
    """
    total = sum(parts[1:], parts[0].copy())
    theta = OLS(fit_intercept=False).fit_moments(total).coef_
    var = torch.stack([m.rss(theta).clamp_min(0.0) / m.n for m in parts])
    return inverse_variance_weights(var, floor=floor)


def weighted_joints(blocks: Sequence[Sequence[Moments]], weighting: str = "residual"):
    """``(folds, w)``: per block the joints' `Moments` summed, joint ``j``'s weighted by
    ``w_j``: with ``weighting="residual"`` the `joint_weights` of the joints' moments over all
    blocks, with ``"none"`` w None (unweighted).

    Args:
        blocks: per contiguous block, ``n_dof`` `Moments` (``stream_moments(...,
            per_joint=True, n_folds=K)``, or moments mapped from them: `mapped_moments`).
        weighting: ``Options.weighting``.
    """
    if weighting not in ("residual", "none"):
        raise ValueError(f"weighting must be 'residual' or 'none', got {weighting!r}")
    w = None
    if weighting == "residual":
        w = joint_weights([sum(ms[1:], ms[0].copy()) for ms in zip(*blocks, strict=True)])
    folds = []
    for ms in blocks:
        if w is not None:
            ms = [_scaled(m, float(wj)) for m, wj in zip(ms, w, strict=True)]
        folds.append(sum(ms[1:], ms[0].copy()))
    return folds, w


def mapped_moments(m: Moments, T: torch.Tensor, shift: torch.Tensor | None = None) -> Moments:
    """The `Moments` of the rows ``(x^T T, y - x^T shift)`` from those of ``(x, y)``, without
    the rows: ``T`` ``(d, k)`` maps the features (a payload's columns are a linear map of the
    robot's regressor), ``shift`` ``(d,)`` (or None) moves a prediction to the right-hand
    side."""
    T = T.to(m.xtx)
    xty, yty, sum_y = m.xty, m.yty, m.sum_y
    if shift is not None:
        s = shift.to(m.xtx)
        xty = m.xty - m.xtx @ s
        yty = m.yty - 2 * s @ m.xty + s @ m.xtx @ s
        sum_y = m.sum_y - s @ m.sum_x
    xtx = T.T @ m.xtx @ T
    return Moments(m.n.clone(), T.T @ m.sum_x, sum_y, 0.5 * (xtx + xtx.T), T.T @ xty, yty,
                   n_rows=m.n_rows)  # fmt: skip


def _scaled(m: Moments, w: float) -> Moments:
    """The `Moments` of the same rows, each weighted ``w`` times more."""
    fields = (m.n, m.sum_x, m.sum_y, m.xtx, m.xty, m.yty)
    return Moments(*(w * f for f in fields), n_rows=m.n_rows)


def inverse_variance_weights(variances, *, floor: float = JOINT_WEIGHT_FLOOR) -> torch.Tensor:
    """``(n,)`` weights ``1 / max(v_j, floor * max_k v_k)``, scaled to mean 1; all ones when
    every variance is 0.

    Args:
        variances: ``(n,)`` non-negative variances (a tensor or an array).
        floor: the smallest variance assumed, as a share of the largest (> 0; 1 or more gives
            equal weights).

    Raises:
        ValueError: on a floor that is not a positive number.
    """
    if not 0.0 < float(floor) < float("inf"):
        raise ValueError(f"floor must be a positive number, got {floor!r}")
    var = torch.as_tensor(variances, dtype=torch.float64)
    if not bool(var.max() > 0):
        return torch.ones_like(var)
    w = 1.0 / var.clamp_min(float(floor) * float(var.max()))
    return w / w.mean()


def _dist_initialized() -> bool:
    import torch.distributed as dist

    return dist.is_available() and dist.is_initialized()
