"""The limits an excitation trajectory must respect, and their check on a dense time grid.

`limits_from_model` reads position, velocity and effort limits from the robot description
(URDF ``<limit lower upper velocity effort>``, MJCF joint ``range``; an absent limit is
infinite, a joint without a position range gets ``(-pi, pi)``), shrinks the position range by
a margin and lets the user override every limit (joint limits are read through the
pytorch-kinematics chain, `RigidBodyModel.chain`; frame positions for workspace boxes come from
`RigidBodyModel.forward_kinematics`). `constraint_violations` gives, per sample,
how far each limit is exceeded (normalised, > 0 means violated: the optimiser's penalty), and
`check_limits` evaluates a trajectory on a grid finer than its output rate and raises a
``ValueError`` listing every violated limit.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Sequence
from dataclasses import dataclass, field

import numpy as np
import torch

from ..dynamics import RigidBodyModel

__all__ = ["Limits", "WorkspaceBox", "limits_from_model", "constraint_violations", "check_limits"]

#: the kinds of limit, as `constraint_violations` names them
KINDS = ("position", "velocity", "acceleration", "torque", "workspace")
#: those that the joint states alone decide (no regressor, no kinematics)
JOINT_KINDS = KINDS[:3]


@dataclass(frozen=True)
class WorkspaceBox:
    """An axis-aligned box, in the root frame, that a frame's origin must stay inside.

    Attributes:
        frame: a frame of the robot (`RigidBodyModel.frame_names`): a URDF link, an MJCF body
            or named site, including frames fixed to a moving body (a flange, a tool link).
        low: ``(3,)`` lower corner, m.
        high: ``(3,)`` upper corner, m.
    """

    frame: str
    low: tuple[float, float, float]
    high: tuple[float, float, float]

    def __post_init__(self) -> None:
        lo = np.asarray(self.low, dtype=np.float64)
        hi = np.asarray(self.high, dtype=np.float64)
        if lo.shape != (3,) or hi.shape != (3,) or np.any(np.isnan(lo)) or np.any(np.isnan(hi)):
            raise ValueError(f"workspace box of {self.frame!r}: low and high must be 3 numbers")
        if np.any(lo >= hi):
            raise ValueError(
                f"workspace box of {self.frame!r}: low {lo.tolist()} must be below high "
                f"{hi.tolist()} on every axis"
            )
        object.__setattr__(self, "low", tuple(float(v) for v in lo))
        object.__setattr__(self, "high", tuple(float(v) for v in hi))


@dataclass(frozen=True)
class Limits:
    """Per-joint limits of an excitation (the position range already shrunk by the margin).

    Attributes:
        joint_names: the joints, in the model's order.
        position_low, position_high: ``(n_dof,)`` allowed positions, rad (m).
        velocity: ``(n_dof,)`` |qd| limits, rad/s (inf: none).
        acceleration: ``(n_dof,)`` |qdd| limits, rad/s^2 (inf: none).
        torque: ``(n_dof,)`` |tau| limits of the nominal model's inverse dynamics, N m (inf: none).
        workspace: boxes that frames' origins must stay in.
    """

    joint_names: tuple[str, ...]
    position_low: np.ndarray
    position_high: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    torque: np.ndarray
    workspace: tuple[WorkspaceBox, ...] = field(default=())

    def __post_init__(self) -> None:
        n = len(self.joint_names)
        for name in ("position_low", "position_high", "velocity", "acceleration", "torque"):
            v = np.asarray(getattr(self, name), dtype=np.float64)
            if v.shape != (n,) or np.any(np.isnan(v)):
                raise ValueError(f"Limits.{name} must be {n} numbers (one per joint), got {v}")
            object.__setattr__(self, name, v)
        for name in ("velocity", "acceleration", "torque"):
            if np.any(getattr(self, name) <= 0):
                raise ValueError(f"Limits.{name} must be positive, got {getattr(self, name)}")
        bad = [j for j, lo, hi in zip(self.joint_names, self.position_low, self.position_high,
                                      strict=True) if not lo < hi]  # fmt: skip
        if bad:
            raise ValueError(f"empty position range (low >= high) for joints {bad}")
        object.__setattr__(self, "workspace", tuple(self.workspace))

    @property
    def n_dof(self) -> int:
        return len(self.joint_names)


def _per_joint(value, n: int, name: str, names) -> np.ndarray | None:
    if value is None:
        return None
    if isinstance(value, dict):
        unknown = sorted(set(value) - set(names))
        if unknown:
            raise ValueError(f"{name}: unknown joints {unknown}; the robot has {list(names)}")
        return np.array([float(value.get(j, math.nan)) for j in names])
    arr = np.asarray(value, dtype=np.float64)
    if arr.ndim == 0:
        arr = np.full(n, float(arr))
    if arr.shape != (n,):
        raise ValueError(f"{name} must be a number or {n} numbers (one per joint), got {arr.shape}")
    return arr


def limits_from_model(
    model: RigidBodyModel,
    *,
    position_margin: float = 0.05,
    position=None,
    velocity=None,
    acceleration=None,
    torque=None,
    workspace: Sequence[WorkspaceBox] = (),
) -> Limits:
    """The description's limits, overridden where the user gives them.

    Args:
        model: the robot.
        position_margin: fraction of each joint's range kept free at both ends, in [0, 0.5).
        position: ``(n_dof, 2)`` ranges replacing the description's (before the margin).
        velocity, acceleration, torque: a number (every joint), ``n_dof`` numbers or a mapping
            joint -> number (NaN or a missing joint keeps the description's value); inf for none.
        workspace: `WorkspaceBox` es.

    Returns:
        `Limits` in the model's joint order.

    Raises:
        ValueError: on a bad margin, bad shapes, unknown joints or empty ranges.
    """
    if not isinstance(model, RigidBodyModel):
        raise TypeError(f"model must be a RigidBodyModel, got {type(model)}")
    margin = float(position_margin)
    if not 0.0 <= margin < 0.5:
        raise ValueError(f"position_margin must lie in [0, 0.5), got {position_margin}")
    names = model.joint_names
    n = len(names)
    joints = {j.name: j for j in model.chain.get_joints()}
    lo, hi = np.full(n, -math.pi), np.full(n, math.pi)
    vel, eff = np.full(n, math.inf), np.full(n, math.inf)
    for i, name in enumerate(names):
        j = joints.get(name)
        if j is None:
            continue
        if j.limits is not None and float(j.limits[0]) < float(j.limits[1]):
            lo[i], hi[i] = float(j.limits[0]), float(j.limits[1])
        if j.velocity_limits is not None and float(j.velocity_limits[1]) > 0:
            vel[i] = float(j.velocity_limits[1])
        if j.effort_limits is not None and float(j.effort_limits[1]) > 0:
            eff[i] = float(j.effort_limits[1])
    if position is not None:
        pos = np.asarray(position, dtype=np.float64)
        if pos.shape != (n, 2):
            raise ValueError(
                f"position must have shape ({n}, 2) (low, high per joint), got {pos.shape}"
            )
        lo, hi = pos[:, 0].copy(), pos[:, 1].copy()
    acc = np.full(n, math.inf)
    for arr, user, label in ((vel, velocity, "velocity"), (acc, acceleration, "acceleration"),
                             (eff, torque, "torque")):  # fmt: skip
        given = _per_joint(user, n, label, names)
        if given is not None:
            keep = ~np.isnan(given)
            arr[keep] = given[keep]
    bad = [names[i] for i in range(n) if not lo[i] < hi[i]]
    if bad:
        raise ValueError(f"empty position range (low >= high) for joints {bad}")
    span = hi - lo
    frames = model.frame_names
    for box in workspace:
        if not isinstance(box, WorkspaceBox):
            raise TypeError(f"workspace must hold WorkspaceBox es, got {type(box)}")
        if box.frame not in frames:
            raise ValueError(f"workspace box: no frame {box.frame!r}; frames: {frames}")
    return Limits(
        joint_names=names,
        position_low=lo + margin * span,
        position_high=hi - margin * span,
        velocity=vel,
        acceleration=acc,
        torque=eff,
        workspace=tuple(workspace),
    )


class _Kinematics:
    """Frame origins by the model's forward kinematics (`RigidBodyModel.forward_kinematics`)."""

    def __init__(self, model: RigidBodyModel, frames: Sequence[str]) -> None:
        self.model, self.frames = model, tuple(frames)

    def origins(self, q: torch.Tensor) -> torch.Tensor:
        """``(n, n_frames, 3)`` origins, m, for ``q (n, n_dof)``, in q's dtype and device."""
        return self.model.forward_kinematics(q, self.frames)[..., :3, 3]


def constraint_violations(
    model: RigidBodyModel,
    limits: Limits,
    q: torch.Tensor,
    qd: torch.Tensor,
    qdd: torch.Tensor,
    *,
    theta: torch.Tensor | None = None,
    tau: torch.Tensor | None = None,
    kinematics: _Kinematics | None = None,
    kinds: Collection[str] = KINDS,
) -> dict[str, torch.Tensor]:
    """Normalised excess over each limit at each sample (> 0: violated); differentiable.

    Args:
        model, limits: the robot and its `Limits`.
        q, qd, qdd: ``(n, n_dof)`` states.
        theta: ``(n_params,)`` the nominal parameters for the torques (default the
            description's, ``model.nominal_theta``).
        tau: ``(n, n_dof)`` the nominal torques, N m, when already computed (else
            ``Y(q, qd, qdd) theta``).
        kinematics: forward kinematics for the workspace boxes (built when needed).
        kinds: the kinds of limit to evaluate (default all of `KINDS`; ``("position",
            "velocity", "acceleration")`` needs neither the regressor nor the kinematics).

    Returns:
        ``{"position", "velocity", "acceleration", "torque", "workspace"}`` (only the limits in
        use, and among ``kinds``) -> ``(n, m)`` tensors: the excess divided by the limit
        (position: by the range; workspace: by the box's size).
    """
    unknown = set(kinds) - set(KINDS)
    if unknown:
        raise ValueError(f"unknown kinds of limit {sorted(unknown)}; known: {KINDS}")
    kw = {"dtype": q.dtype, "device": q.device}
    out = {}
    if "position" in kinds:
        lo = torch.as_tensor(limits.position_low, **kw)
        hi = torch.as_tensor(limits.position_high, **kw)
        span = hi - lo
        out["position"] = torch.cat([(q - hi) / span, (lo - q) / span], -1)
    for name, x in (("velocity", qd), ("acceleration", qdd)):
        lim = getattr(limits, name)
        use = np.isfinite(lim)
        if name in kinds and use.any():
            idx = torch.as_tensor(np.flatnonzero(use), device=q.device)
            out[name] = x[:, idx].abs() / torch.as_tensor(lim[use], **kw) - 1.0
    use = np.isfinite(limits.torque)
    if "torque" in kinds and use.any():
        if tau is None:
            theta = model.nominal_theta if theta is None else theta
            tau = model.regressor(q, qd, qdd) @ torch.as_tensor(theta, **kw)
        idx = torch.as_tensor(np.flatnonzero(use), device=q.device)
        out["torque"] = tau[:, idx].abs() / torch.as_tensor(limits.torque[use], **kw) - 1.0
    if "workspace" in kinds and limits.workspace:
        if kinematics is None:
            kinematics = _Kinematics(model, [b.frame for b in limits.workspace])
        p = kinematics.origins(q)  # (n, n_boxes, 3)
        blo = torch.as_tensor(np.array([b.low for b in limits.workspace]), **kw)
        bhi = torch.as_tensor(np.array([b.high for b in limits.workspace]), **kw)
        size = bhi - blo
        # columns: every box's excess above its high corner (x, y, z), then below its low one
        out["workspace"] = torch.cat([(p - bhi) / size, (blo - p) / size], 1).flatten(1)
    return out


def check_limits(
    model: RigidBodyModel,
    trajectory,
    limits: Limits,
    *,
    rate: float,
    refine: int = 10,
    theta=None,
    raise_error: bool = True,
) -> dict[str, float]:
    """Check a trajectory against the limits on a grid ``refine`` times finer than ``rate``.

    One period is checked (the trajectory is periodic), at ``rate * refine`` Hz.

    Args:
        model, limits: the robot and its `Limits`.
        trajectory: a `FourierTrajectory` or `torchjfa.sim.SinusoidTrajectory` in the model's
            joint order.
        rate: the output (sampling) rate, Hz.
        refine: grid points per output sample.
        theta: nominal parameters for the torques (default ``model.nominal_theta``).
        raise_error: raise on a violation (else only return the margins).

    Returns:
        The smallest margin of each kind of limit in use, as a fraction of the limit (position:
        of the range; 0 = at the limit, negative = violated).

    Raises:
        ValueError: listing every violated limit (joint, kind, worst value, the limit, when).
    """
    if trajectory.n_dof != limits.n_dof:
        raise ValueError(f"the trajectory has {trajectory.n_dof} joints, the limits {limits.n_dof}")
    step = 1.0 / (float(rate) * int(refine))
    t = torch.arange(int(math.ceil(trajectory.period / step)) + 1, dtype=torch.float64) * step
    q, qd, qdd = trajectory(t)
    with torch.no_grad():
        viol = constraint_violations(model, limits, q, qd, qdd, theta=theta)
    margins = {k: float(-v.max()) for k, v in viol.items()}
    if not raise_error:
        return margins
    lines = []
    names = limits.joint_names
    n = limits.n_dof
    for kind, v in viol.items():
        worst, at = v.max(0)
        for col in torch.nonzero(worst > 1e-9).flatten().tolist():
            when = float(t[at[col]])
            if kind == "position":
                j = col % n
                side = "upper" if col < n else "lower"
                bound = limits.position_high[j] if col < n else limits.position_low[j]
                value = float(q[at[col], j])
                lines.append(f"{names[j]}: position {value:.4g} beyond the {side} limit "
                             f"{bound:.4g} (margin included) at t = {when:.3f} s")  # fmt: skip
            elif kind == "workspace":
                nb = len(limits.workspace)
                box = limits.workspace[(col // 3) % nb]
                side = "above" if col < 3 * nb else "below"
                lines.append(f"{box.frame}: origin {side} its workspace box on axis "
                             f"{'xyz'[col % 3]} at t = {when:.3f} s")  # fmt: skip
            else:
                lim = getattr(limits, kind)
                joints = [j for j in range(n) if np.isfinite(lim[j])]
                j = joints[col]
                value = float(worst[col] + 1.0) * lim[j]
                unit = {"velocity": "rad/s", "acceleration": "rad/s^2", "torque": "N m"}[kind]
                lines.append(f"{names[j]}: |{kind}| {value:.4g} > limit {lim[j]:.4g} {unit} "
                             f"at t = {when:.3f} s")  # fmt: skip
    if lines:
        raise ValueError(
            f"the trajectory violates {len(lines)} limit(s) on a {1 / step:g} Hz grid:\n  "
            + "\n  ".join(lines)
        )
    return margins
