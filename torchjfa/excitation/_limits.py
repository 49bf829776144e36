"""The limits an excitation trajectory must respect.

`limits_from_model` reads position, velocity and effort limits from the robot description
(URDF ``<limit lower upper velocity effort>``, MJCF joint ``range``; an absent limit is
infinite, a joint without a position range gets ``(-pi, pi)``; joint limits are read through
the pytorch-kinematics chain, `RigidBodyModel.chain`), keeps a margin inside them and lets the
user override every limit. By default the excitation is safe to run:

* position: 5 % of each joint's range kept free at both ends (``position_margin``);
* velocity: 15 % of the description's velocity limit kept free (``velocity_margin``);
* acceleration: no description format has one, so the default is the velocity limit (with its
  margin) reached from rest in `DEFAULT_ACCELERATION_TIME` (0.5 s): 5.4 rad/s^2 for the UR5's
  3.15 rad/s, 3.7 rad/s^2 for the Franka Panda's 2.175 rad/s (Franka's published limits are
  7.5-20 rad/s^2). Joints without a velocity limit get none (give ``acceleration``);
* the mounting plane: no part of the arm below ``z = floor`` (0: the base's plane) of the root
  frame, with a clearance (`torchjfa.excitation._geometry`);
* self-collision: non-adjacent links apart by the clearance (capsules along the links in the
  optimisation; the description's collision geometry, through MuJoCo, in the final check where
  it has some).

Frame positions for workspace boxes come from `RigidBodyModel.forward_kinematics`.
`constraint_violations` gives, per sample, how far each limit is exceeded (normalised, > 0
means violated: the optimiser's penalty); `torchjfa.excitation._check` checks a trajectory on a
dense grid.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Sequence
from dataclasses import dataclass, field

import numpy as np
import torch

from ..dynamics import RigidBodyModel
from ._geometry import DEFAULT_CAPSULE_RADIUS, DEFAULT_CLEARANCE

__all__ = [
    "DEFAULT_ACCELERATION_TIME",
    "DEFAULT_VELOCITY_MARGIN",
    "Limits",
    "WorkspaceBox",
    "constraint_violations",
    "limits_from_model",
]

#: the kinds of limit, as `constraint_violations` names them
KINDS = ("position", "velocity", "acceleration", "torque", "workspace", "floor", "collision")
#: those that the joint states alone decide (no regressor, no kinematics)
JOINT_KINDS = KINDS[:3]
#: those of the arm's geometry (`torchjfa.excitation._geometry`), in metres
GEOMETRY_KINDS = KINDS[5:]
#: fraction of the description's velocity limits kept free by default
DEFAULT_VELOCITY_MARGIN = 0.15
#: s: the default acceleration limit takes a joint from rest to its velocity limit in this time
DEFAULT_ACCELERATION_TIME = 0.5


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
        floor: height of the mounting plane in the root frame, m, that no part of the arm may
            go below (None: none).
        self_collision: keep non-adjacent links apart.
        clearance: m, kept to the floor and between links.
        capsule_radius: m, of the capsules along the links.
    """

    joint_names: tuple[str, ...]
    position_low: np.ndarray
    position_high: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    torque: np.ndarray
    workspace: tuple[WorkspaceBox, ...] = field(default=())
    floor: float | None = None
    self_collision: bool = False
    clearance: float = DEFAULT_CLEARANCE
    capsule_radius: float = DEFAULT_CAPSULE_RADIUS

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
        if self.floor is not None and not math.isfinite(float(self.floor)):
            raise ValueError(f"Limits.floor must be a finite height in m, got {self.floor}")
        for name in ("clearance", "capsule_radius"):
            v = float(getattr(self, name))
            if not (v >= 0 and math.isfinite(v)):
                raise ValueError(f"Limits.{name} must be a length >= 0 m, got {v}")
            object.__setattr__(self, name, v)

    @property
    def has_geometry(self) -> bool:
        """Are the floor or self-collision checked (`torchjfa.excitation._geometry`)?"""
        return self.floor is not None or self.self_collision

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


def _description_limits(model: RigidBodyModel):
    """``(low, high, velocity, effort)`` per joint from the description (inf where absent)."""
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
    return lo, hi, vel, eff


def _fraction(value, name: str, high: float = 1.0) -> float:
    v = float(value)
    if not 0.0 <= v < high:
        raise ValueError(f"{name} must lie in [0, {high:g}), got {value}")
    return v


def limits_from_model(
    model: RigidBodyModel,
    *,
    position_margin: float = 0.05,
    velocity_margin: float = DEFAULT_VELOCITY_MARGIN,
    position=None,
    velocity=None,
    acceleration=None,
    torque=None,
    workspace: Sequence[WorkspaceBox] = (),
    floor: float | None = 0.0,
    self_collision: bool = True,
    clearance: float = DEFAULT_CLEARANCE,
    capsule_radius: float = DEFAULT_CAPSULE_RADIUS,
) -> Limits:
    """The description's limits with safety margins, overridden where the user gives them.

    Args:
        model: the robot.
        position_margin: fraction of each joint's range kept free at both ends, in [0, 0.5).
        velocity_margin: fraction of the description's velocity limits kept free, in [0, 1)
            (a velocity the user gives is used as it is).
        position: ``(n_dof, 2)`` ranges replacing the description's (before the margin).
        velocity: rad/s (m/s for prismatic joints): a number (every joint), ``n_dof`` numbers
            or a mapping joint -> number (NaN or a missing joint keeps the default); inf for
            none. Default: the description's velocity less ``velocity_margin``.
        acceleration: rad/s^2 (m/s^2), given as ``velocity`` is. Default: the velocity limit
            reached from rest in `DEFAULT_ACCELERATION_TIME` (none where there is no
            velocity limit).
        torque: N m (N), given as ``velocity`` is. Default: the description's effort.
        workspace: `WorkspaceBox` es.
        floor: height in the root frame, m, of the plane the arm is mounted on (0: the base's
            plane, z = 0); no part of the arm may come within ``clearance`` of it. None: none.
        self_collision: keep links that are not adjacent ``clearance`` apart.
        clearance: m, kept to the floor and between links (beyond the capsules' radius, or
            the collision geometry's surfaces).
        capsule_radius: m, the radius of the capsules along the links
            (`torchjfa.excitation._geometry`).

    Returns:
        `Limits` in the model's joint order.

    Raises:
        ValueError: on bad margins or lengths, bad shapes, unknown joints or empty ranges.
    """
    if not isinstance(model, RigidBodyModel):
        raise TypeError(f"model must be a RigidBodyModel, got {type(model)}")
    margin = _fraction(position_margin, "position_margin", 0.5)
    v_margin = _fraction(velocity_margin, "velocity_margin")
    names = model.joint_names
    n = len(names)
    lo, hi, vel, eff = _description_limits(model)
    vel = vel * (1.0 - v_margin)
    if position is not None:
        pos = np.asarray(position, dtype=np.float64)
        if pos.shape != (n, 2):
            raise ValueError(
                f"position must have shape ({n}, 2) (low, high per joint), got {pos.shape}"
            )
        lo, hi = pos[:, 0].copy(), pos[:, 1].copy()
    for arr, user, label in ((vel, velocity, "velocity"), (eff, torque, "torque")):
        given = _per_joint(user, n, label, names)
        if given is not None:
            keep = ~np.isnan(given)
            arr[keep] = given[keep]
    acc = vel / DEFAULT_ACCELERATION_TIME
    given = _per_joint(acceleration, n, "acceleration", names)
    if given is not None:
        acc[~np.isnan(given)] = given[~np.isnan(given)]
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
        floor=None if floor is None else float(floor),
        self_collision=bool(self_collision),
        clearance=clearance,
        capsule_radius=capsule_radius,
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
    geometry=None,
    exact: bool = False,
    kinds: Collection[str] = KINDS,
) -> dict[str, torch.Tensor]:
    """Normalised excess over each limit at each sample (> 0: violated); differentiable.

    Args:
        model: the robot.
        limits: its `Limits`.
        q: ``(n, n_dof)`` positions.
        qd: ``(n, n_dof)`` velocities.
        qdd: ``(n, n_dof)`` accelerations.
        theta: ``(n_params,)`` the nominal parameters for the torques (default the
            description's, ``model.nominal_theta``).
        tau: ``(n, n_dof)`` the nominal torques, N m, when already computed (else
            ``Y(q, qd, qdd) theta``).
        kinematics: forward kinematics for the workspace boxes (built when needed).
        geometry: the floor and self-collision constraints
            (`torchjfa.excitation._geometry.Geometry`); without it they are not evaluated.
        exact: the geometry's dense-grid check (`Geometry.check`: the description's collision
            geometry where it has some) instead of its differentiable capsules.
        kinds: the kinds of limit to evaluate (default all of `KINDS`; ``("position",
            "velocity", "acceleration")`` needs neither the regressor nor the kinematics).

    Returns:
        ``{"position", "velocity", "acceleration", "torque", "workspace", "floor",
        "collision"}`` (only the limits in use, and among ``kinds``) -> ``(n, m)`` tensors: the
        excess divided by the limit (position: by the range; workspace: by the box's size);
        floor and collision: the required distance less the actual one, m.
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
    if geometry is not None and any(k in kinds for k in GEOMETRY_KINDS):
        geo = geometry.check(q) if exact else geometry.violations(q)
        out.update({k: v for k, v in geo.items() if k in kinds})
    return out
