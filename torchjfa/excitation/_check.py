"""Every constraint of an excitation, checked on a grid finer than its output rate.

`check_limits` evaluates one period of a trajectory at ``refine`` times its output rate:
the joint limits from the Fourier (or sinusoid) series itself, the torques by the nominal
model's inverse dynamics, workspace boxes and the floor by forward kinematics, and the floor
and self-collision on the description's collision geometry through MuJoCo where it has some
(else on the capsules along the links; `torchjfa.excitation._geometry`). It raises a
``ValueError`` listing every violated constraint (what, by how much, when).
`physical_margins` gives what is left to each constraint in physical units (rad, rad/s,
rad/s^2, N m, m), the numbers of ``torchjfa excite``'s report.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from ..dynamics import RigidBodyModel
from ._geometry import Geometry
from ._limits import Limits, constraint_violations
from ._meshes import _REACH

__all__ = ["check_limits", "physical_margins", "trajectory_geometry"]

_UNITS = {
    "position": ("rad", "m"),
    "velocity": ("rad/s", "m/s"),
    "acceleration": ("rad/s^2", "m/s^2"),
    "torque": ("N m", "N"),
}


def _start(trajectory) -> np.ndarray:
    """The posture a trajectory moves about: a `FourierTrajectory`'s posture (where it starts
    at rest), a sinusoid's offset."""
    posture = getattr(trajectory, "posture", None)
    return np.asarray(trajectory.offset if posture is None else posture, dtype=np.float64)


def trajectory_geometry(model: RigidBodyModel, trajectory, limits: Limits) -> Geometry | None:
    """The `Geometry` (floor, self-collision) of ``limits`` at the trajectory's posture, or
    None when the limits check neither."""
    if not limits.has_geometry:
        return None
    return Geometry(model, limits, _start(trajectory))


def _dense(model, trajectory, limits, rate, refine, theta, geometry):
    """``(t, (q, qd, qdd), violations)`` on the grid of ``rate * refine`` Hz over one period."""
    if trajectory.n_dof != limits.n_dof:
        raise ValueError(f"the trajectory has {trajectory.n_dof} joints, the limits {limits.n_dof}")
    if geometry is None:
        geometry = trajectory_geometry(model, trajectory, limits)
    step = 1.0 / (float(rate) * int(refine))
    t = torch.arange(int(math.ceil(trajectory.period / step)) + 1, dtype=torch.float64) * step
    q, qd, qdd = trajectory(t)
    with torch.no_grad():
        viol = constraint_violations(model, limits, q, qd, qdd, theta=theta, geometry=geometry,
                                     exact=True)  # fmt: skip
    return t, (q, qd, qdd), viol, geometry


def check_limits(
    model: RigidBodyModel,
    trajectory,
    limits: Limits,
    *,
    rate: float,
    refine: int = 10,
    theta=None,
    raise_error: bool = True,
    geometry: Geometry | None = None,
) -> dict[str, float]:
    """Check a trajectory against the limits on a grid ``refine`` times finer than ``rate``.

    One period is checked (the trajectory is periodic), at ``rate * refine`` Hz.

    Args:
        model: the robot.
        limits: its `Limits`.
        trajectory: a `FourierTrajectory` or `torchjfa.sim.SinusoidTrajectory` in the model's
            joint order.
        rate: the output (sampling) rate, Hz.
        refine: grid points per output sample.
        theta: nominal parameters for the torques (default ``model.nominal_theta``).
        raise_error: raise on a violation (else only return the margins).
        geometry: the floor and self-collision constraints (`trajectory_geometry`, built at
            the trajectory's posture when not given).

    Returns:
        The smallest margin of each kind of limit in use: joint limits and torques as a
        fraction of the limit (position: of the range), workspace of the box's size; floor
        and collision in m beyond the clearance. 0 = at the limit, negative = violated.

    Raises:
        ValueError: listing every violated limit (joint or part, kind, worst value, the limit,
            when).
    """
    t, states, viol, geometry = _dense(model, trajectory, limits, rate, refine, theta, geometry)
    margins = {k: float(-v.max()) for k, v in viol.items()}
    if not raise_error:
        return margins
    lines = []
    for kind, v in viol.items():
        worst, at = v.max(0)
        for col in torch.nonzero(worst > 1e-9).flatten().tolist():
            when = float(t[at[col]])
            lines.append(_message(kind, col, float(worst[col]), when, states[0][at[col]],
                                  limits, geometry))  # fmt: skip
    if lines:
        raise ValueError(
            f"the trajectory violates {len(lines)} limit(s) on a {rate * refine:g} Hz grid:\n  "
            + "\n  ".join(lines)
        )
    return margins


def _message(kind, col, worst, when, q, limits, geometry) -> str:
    """One line on a violated limit: column ``col`` of ``kind``, exceeded by ``worst``."""
    names, n = limits.joint_names, limits.n_dof
    at = f"at t = {when:.3f} s"
    if kind == "position":
        j = col % n
        side = "upper" if col < n else "lower"
        bound = limits.position_high[j] if col < n else limits.position_low[j]
        return (f"{names[j]}: position {float(q[j]):.4g} beyond the {side} limit {bound:.4g} "
                f"(margin included) {at}")  # fmt: skip
    if kind == "workspace":
        nb = len(limits.workspace)
        box = limits.workspace[(col // 3) % nb]
        side = "above" if col < 3 * nb else "below"
        return f"{box.frame}: origin {side} its workspace box on axis {'xyz'[col % 3]} {at}"
    if kind in ("floor", "collision"):
        what = geometry.labels(kind)[col]
        need = geometry.required(kind)[col]
        if kind == "floor":
            return (f"{what}: {worst:.3g} m too close to the floor at z = {limits.floor:g} m "
                    f"(clearance {need:.3g} m) {at}")  # fmt: skip
        return f"{what}: {worst:.3g} m closer than the {need:.3g} m required between them {at}"
    lim = getattr(limits, kind)
    j = [i for i in range(n) if np.isfinite(lim[i])][col]
    unit = {"velocity": "rad/s", "acceleration": "rad/s^2", "torque": "N m"}[kind]
    return f"{names[j]}: |{kind}| {(worst + 1.0) * lim[j]:.4g} > limit {lim[j]:.4g} {unit} {at}"


def physical_margins(
    model: RigidBodyModel,
    trajectory,
    limits: Limits,
    *,
    rate: float,
    refine: int = 10,
    theta=None,
    geometry: Geometry | None = None,
) -> dict:
    """What the trajectory leaves of each limit, in physical units, on the dense grid.

    Returns:
        ``{"joints": {joint: {"position": room to the nearer limit (margin included),
        "velocity", "acceleration", "torque": peak |value| (torque: where limited)}},
        "units": {kind: unit of the joints' values (revolute; prismatic in brackets)},
        kind: {"margin": the smallest margin, "where": the joint, frame or pair,
        "unit": its unit, "t": when}}`` for each kind of limit in use; floor and collision
        margins are in m beyond the distance required there (``"required"``: the clearance,
        or less for parts that are that close at the posture), ``"distance"`` the distance
        itself (collision geometry is measured up to 0.1 m: ``"at_least": True`` when it is
        that far).
    """
    t, (q, qd, qdd), viol, geometry = _dense(model, trajectory, limits, rate, refine, theta,
                                             geometry)  # fmt: skip
    names, n = limits.joint_names, limits.n_dof
    prismatic = [tp == "prismatic" for tp in model.joint_types]
    lo, hi = (torch.as_tensor(x) for x in (limits.position_low, limits.position_high))
    room = torch.minimum(hi - q, q - lo).amin(0)
    peaks = {"velocity": qd.abs().amax(0), "acceleration": qdd.abs().amax(0)}
    joints = {
        j: {"position": float(room[i]), "velocity": float(peaks["velocity"][i]),
            "acceleration": float(peaks["acceleration"][i])}
        for i, j in enumerate(names)
    }  # fmt: skip
    out: dict = {"joints": joints}
    for kind, v in viol.items():
        per = _physical(kind, v, limits)  # (n_samples, m) margins in physical units
        low, at = per.min(0)
        col = int(torch.argmin(low))
        entry = {"margin": float(low[col]), "t": float(t[at[col]])}
        if kind in _UNITS:
            lim = getattr(limits, kind, None)
            idx = (
                col % n if kind == "position" else [i for i in range(n) if np.isfinite(lim[i])][col]
            )
            entry |= {"where": names[idx], "unit": _UNITS[kind][int(prismatic[idx])]}
            if kind == "torque":
                for c, i in enumerate(i for i in range(n) if np.isfinite(lim[i])):
                    joints[names[i]]["torque"] = float(lim[i] - low[c])
        elif kind == "workspace":
            box = limits.workspace[(col // 3) % len(limits.workspace)]
            entry |= {"where": box.frame, "unit": "m"}
        else:
            need = geometry.required(kind)[col]
            entry |= {"where": geometry.labels(kind)[col], "unit": "m", "required": need,
                      "distance": need + entry["margin"]}  # fmt: skip
            if geometry.meshes is not None and entry["distance"] >= _REACH - 1e-12:
                entry["at_least"] = True  # the collision geometry is measured up to _REACH
        out[kind] = entry
    return out


def _physical(kind: str, v: torch.Tensor, limits: Limits) -> torch.Tensor:
    """The margins ``-v`` of `constraint_violations` in physical units."""
    if kind == "position":
        span = torch.as_tensor(limits.position_high - limits.position_low)
        return -v * torch.cat([span, span])
    if kind == "workspace":
        size = torch.as_tensor(np.array([np.subtract(b.high, b.low) for b in limits.workspace]))
        return -v * torch.cat([size, size]).flatten()
    if kind in ("floor", "collision"):
        return -v
    lim = getattr(limits, kind)
    return -v * torch.as_tensor(lim[np.isfinite(lim)])
