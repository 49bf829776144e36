"""`FloatingBaseModel`: a robot whose root body moves freely (legged robots, humanoids).

The state follows Pinocchio's free flyer, so that its numbers can be checked against Pinocchio
and a state estimator's output used as it is:

* configuration ``q (*batch, 7 + n)``: the base position in the world ``x, y, z`` (m), the base
  orientation as a unit quaternion ``qx, qy, qz, qw``, then the joint positions;
* velocity ``v (*batch, 6 + n)``: the base origin's linear velocity and the base's angular
  velocity, both in base axes (m/s, rad/s), then the joint velocities;
* acceleration ``a (*batch, 6 + n)``: the time derivatives of ``v``'s components.

The generalised forces ``(*batch, 6 + n)`` are the wrench the base's free joint would transmit,
force then moment at the base origin in base axes (N, N m; zero for a robot that no contact
pushes on), then the joint torques. theta holds the base body's 10 inertial parameters (about
the base frame origin, in base axes, Pinocchio's order) and then the joints' layout of the
fixed-base `RigidBodyModel` of the same description.
"""

from __future__ import annotations

import os
from collections.abc import Sequence

import numpy as np
import torch

from .._validation import as_tensor
from ._inputs import check_state
from ._kinematics import body_poses
from ._mjcf import fixed_base_mjcf
from ._model import RigidBodyModel
from ._parameters import INERTIAL_NAMES
from ._rnea import floating_regressor_into, skew
from ._tree import read_description
from ._writeback import write_floating_mjcf, write_floating_urdf

__all__ = ["FloatingBaseModel", "quaternion_matrix"]

_BASE_Q = ("base_x", "base_y", "base_z", "base_qx", "base_qy", "base_qz", "base_qw")
_BASE_V = ("base_vx", "base_vy", "base_vz", "base_wx", "base_wy", "base_wz")
_QUAT_TOL = 1e-3  # a quaternion whose norm is further than this from 1 is refused


def quaternion_matrix(quat: torch.Tensor) -> torch.Tensor:
    """Rotation matrices ``(*batch, 3, 3)`` of unit quaternions ``(*batch, 4)`` in ``(x, y, z,
    w)`` order (Pinocchio's and ROS's), normalised first."""
    x, y, z, w = (quat / quat.norm(dim=-1, keepdim=True)).unbind(-1)
    rows = [
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ]  # fmt: skip
    return torch.stack(rows, -1).reshape(*quat.shape[:-1], 3, 3)


class FloatingBaseModel:
    """A tree of rigid bodies on a free-flying base, with revolute and prismatic joints.

    Build it with `from_urdf` (the URDF's root link is the base). `regressor` gives
    ``Y (*batch, 6 + n, n_params)`` with ``[base wrench; joint torques] = Y theta`` in the state
    convention of the module (Pinocchio's free flyer), `inverse_dynamics` and `mass_matrix`
    the same quantities for one theta.

    Attributes:
        joints: the fixed-base `RigidBodyModel` of the same description (its joints, joint
            terms, kinematics and parameter layout after the base's 10 parameters).
        base_name: the base body (the URDF's root link).
        parameter_names: ``base.m, ...`` then the joints' `RigidBodyModel.parameter_names`.
    """

    def __init__(self, joints: RigidBodyModel, base_name: str | None = None) -> None:
        if joints.transmission is not None:
            raise ValueError("a floating-base model takes its joint terms on the joints")
        self.joints = joints
        tree = joints._tree
        self.base_name = base_name or (tree.frame_names[0] if tree.frame_names else "base")
        self._base_inertial = torch.as_tensor(tree.base_inertial, dtype=torch.float64)

    @classmethod
    def from_urdf(
        cls,
        source: str | bytes | os.PathLike,
        *,
        friction: str | Sequence[str] = ("viscous",),
        gravity: Sequence[float] = (0.0, 0.0, -9.81),
        fixed_joints: str | Sequence[str] = (),
        coulomb_velocity: float = 0.0,
    ) -> FloatingBaseModel:
        """Read a URDF whose root link is the free-flying base.

        Args are those of `RigidBodyModel.from_urdf`; ``gravity`` is in the world frame.

        Raises:
            FileNotFoundError, ValueError: as `RigidBodyModel.from_urdf`.
        """
        return cls(
            RigidBodyModel.from_urdf(
                source,
                friction=friction,
                gravity=gravity,
                fixed_joints=fixed_joints,
                coulomb_velocity=coulomb_velocity,
            )
        )

    @classmethod
    def from_mjcf(
        cls,
        source: str | bytes | os.PathLike,
        *,
        friction: str | Sequence[str] = ("viscous",),
        gravity: Sequence[float] | None = None,
        coulomb_velocity: float = 0.0,
    ) -> FloatingBaseModel:
        """Read an MJCF whose robot hangs from one body with a ``<freejoint>`` (the base).

        The base's pose in the file (its starting placement) is not part of the model; other
        bodies of the world without joints (a floor, a table) are scenery and left out.

        Args are those of `RigidBodyModel.from_mjcf`.

        Raises:
            FileNotFoundError: if the file does not exist.
            ValueError: without exactly one free joint on a body of the world, or as
                `RigidBodyModel.from_mjcf`.
        """
        text, path = read_description(source, "MJCF")
        text, base = fixed_base_mjcf(text, path)
        joints = RigidBodyModel.from_mjcf(
            text, friction=friction, gravity=gravity, coulomb_velocity=coulomb_velocity
        )
        joints.source_path = path
        return cls(joints, base_name=base)

    # ------------------------------------------------------------------ description
    @property
    def joint_names(self) -> tuple[str, ...]:
        return self.joints.joint_names

    @property
    def n_dof(self) -> int:
        """The number of joints (the velocity has ``6 + n_dof`` entries)."""
        return self.joints.n_dof

    @property
    def parameter_names(self) -> tuple[str, ...]:
        base = tuple(f"{self.base_name}.{p}" for p in INERTIAL_NAMES)
        return base + self.joints.parameter_names

    @property
    def n_params(self) -> int:
        return 10 + self.joints.n_params

    @property
    def nominal_theta(self) -> torch.Tensor:
        """``(n_params,)`` float64: the description's inertials (the base's first), zero joint
        terms."""
        return torch.cat([self._base_inertial.clone(), self.joints.nominal_theta])

    @property
    def description_theta(self) -> torch.Tensor:
        """``(n_params,)`` float64: the description with the damping, dry friction and armature
        it states in the joint terms (`RigidBodyModel.description_theta`)."""
        return torch.cat([self._base_inertial.clone(), self.joints.description_theta])

    @property
    def gravity(self) -> torch.Tensor:
        """``(3,)`` float64, m/s^2, in the world frame."""
        return self.joints.gravity

    def __repr__(self) -> str:
        return (
            f"FloatingBaseModel(base={self.base_name!r}, n_dof={self.n_dof}, "
            f"n_params={self.n_params}, friction={self.joints.friction})"
        )

    # ------------------------------------------------------------------ dynamics
    def _check_q(self, q) -> torch.Tensor:
        (q,) = check_state(q, joint_names=(*_BASE_Q, *self.joint_names), names=("q",))
        if not torch.compiler.is_compiling():
            norm = q[..., 3:7].norm(dim=-1)
            bad = (norm - 1.0).abs() > _QUAT_TOL
            if bool(bad.any()):
                k = int(bad.reshape(-1).nonzero()[0])
                raise ValueError(
                    "the base orientation (q[..., 3:7], qx qy qz qw) must be a unit quaternion; "
                    f"sample {k} has norm {float(norm.reshape(-1)[k]):.6g}"
                )
        return q

    def _check(self, q, v, a) -> list[torch.Tensor]:
        q = self._check_q(q)
        v, a = check_state(v, a, joint_names=(*_BASE_V, *self.joint_names), names=("v", "a"))
        if q.shape[:-1] != v.shape[:-1] or q.device != v.device:
            raise ValueError(
                f"q {tuple(q.shape)} and v {tuple(v.shape)} must have the same batch shape and "
                "device"
            )
        dtype = torch.promote_types(q.dtype, v.dtype)
        return [q.to(dtype), v.to(dtype), a.to(dtype)]

    def _regressor(self, q, v, a, *, gravity: bool = True) -> torch.Tensor:
        batch, n = q.shape[:-1], self.n_dof
        q2, v2, a2 = q.reshape(-1, 7 + n), v.reshape(-1, 6 + n), a.reshape(-1, 6 + n)
        B = q2.shape[0]
        c = self.joints._consts(q2.dtype, q2.device)
        R = quaternion_matrix(q2[:, 3:7])
        g = c.gravity if gravity else torch.zeros_like(c.gravity)
        g_base = (R.transpose(1, 2) @ g).contiguous()  # (B, 3) gravity in base axes
        Y = q2.new_zeros(B, 6 + n, self.n_params)
        base = (v2[:, :3], v2[:, 3:6], a2[:, :6], g_base)
        floating_regressor_into(Y, base, q2[:, 7:], v2[:, 6:], a2[:, 6:], c, self.joints.friction)
        self.joints._joint_terms(Y[:, 6:, 10:], v2[:, 6:], a2[:, 6:])
        return Y.reshape(*batch, 6 + n, self.n_params)

    def regressor(self, q, v, a) -> torch.Tensor:
        """The floating-base regressor: ``[base wrench; joint torques] = Y(q, v, a) @ theta``.

        Args:
            q: ``(*batch, 7 + n_dof)`` base position (m), base quaternion ``(x, y, z, w)``,
                joint positions (rad or m).
            v: ``(*batch, 6 + n_dof)`` base linear and angular velocity in base axes (m/s,
                rad/s), joint velocities.
            a: ``(*batch, 6 + n_dof)`` their time derivatives.

        Returns:
            ``(*batch, 6 + n_dof, n_params)`` in the inputs' dtype and device (float64 for
            non-tensor input); differentiable with respect to q, v and a. Rows: the base's
            force (N) and moment (N m) at its origin in base axes, then the joint torques.

        Raises:
            ValueError: on wrong shapes, mismatched devices, NaN or infinite entries, or a base
                quaternion whose norm is not 1 (within 1e-3; it is normalised otherwise).
        """
        return self._regressor(*self._check(q, v, a))

    def _check_theta(self, theta, like: torch.Tensor) -> torch.Tensor:
        theta = as_tensor(theta, name="theta").to(like)
        if theta.shape != (self.n_params,):
            raise ValueError(f"theta must have shape ({self.n_params},), got {tuple(theta.shape)}")
        return theta

    def inverse_dynamics(self, q, v, a, theta) -> torch.Tensor:
        """``Y(q, v, a) @ theta``: ``(*batch, 6 + n_dof)``, the base wrench (what contacts and
        supports must supply) and the joint torques."""
        Y = self.regressor(q, v, a)
        return Y @ self._check_theta(theta, Y)

    def mass_matrix(self, q, theta=None) -> torch.Tensor:
        """The joint-space inertia matrix ``M(q)``, ``(*batch, 6 + n_dof, 6 + n_dof)``, for
        ``theta`` (default `nominal_theta`), in the velocity coordinates of the module. An
        armature term adds to the joints' diagonal."""
        q = self._check_q(q)
        theta = self._check_theta(self.nominal_theta if theta is None else theta, q)
        n, batch = self.n_dof, q.shape[:-1]
        eye = torch.eye(6 + n, dtype=q.dtype, device=q.device)
        acc = torch.cat([eye, torch.zeros_like(eye[:1])])  # (7 + n, 6 + n): each unit, then none
        k = acc.shape[0]
        q3 = q.reshape(-1, 1, 7 + n).expand(-1, k, 7 + n)
        acc3 = acc.expand(q3.shape[0], k, 6 + n)
        tau = self._regressor(q3, torch.zeros_like(acc3), acc3, gravity=False) @ theta
        M = (tau[:, :-1] - tau[:, -1:]).transpose(1, 2)  # column j: tau(e_j) - tau(0)
        return M.reshape(*batch, 6 + n, 6 + n)

    def center_of_mass(self, q, theta=None) -> torch.Tensor:
        """The whole robot's centre of mass in the world frame, m.

        Args:
            q: ``(*batch, 7 + n_dof)``, as in `regressor`.
            theta: ``(n_params,)``; default `nominal_theta`.

        Returns:
            ``(*batch, 3)``.

        Raises:
            ValueError: on a bad q or theta, or a total mass that is not positive.
        """
        q = self._check_q(q)
        theta = self.nominal_theta.to(q) if theta is None else self._check_theta(theta, q)
        inertial, _ = self.joints.layout.split(theta[10:])
        total = theta[0] + inertial[:, 0].sum()
        if not bool(total > 0):
            raise ValueError(f"the total mass is {float(total)} kg; it must be positive")
        rots, poss = body_poses(q[..., 7:], self.joints._consts(q.dtype, q.device))
        h = theta[1:4].expand(*q.shape[:-1], 3)
        for k in range(self.n_dof):
            h = h + poss[k] * inertial[k, 0] + rots[k] @ inertial[k, 1:4]
        R = quaternion_matrix(q[..., 3:7])
        return q[..., :3] + (R @ (h / total)[..., None])[..., 0]

    def write_urdf(self, theta, path: str | os.PathLike) -> None:
        """Write the URDF this model was read from with theta's inertials (the base's on the
        root link, whose fixed children keep none) and joint friction; as
        `torchjfa.dynamics.write_urdf`.

        Raises:
            ValueError: for a model read from MJCF, a theta of the wrong shape, a body that
                is not physically consistent.
        """
        write_floating_urdf(self, theta, path)

    def write_mjcf(self, theta, path: str | os.PathLike) -> None:
        """Write the description as MJCF with theta's inertials and a ``<freejoint>`` on the
        base body (a URDF through MuJoCo's URDF importer), which MuJoCo simulates and
        `from_mjcf` reads back; as `torchjfa.dynamics.RigidBodyModel.write_mjcf`.

        Raises:
            ValueError: on a theta of the wrong shape, a body that is not physically
                consistent, or a description MuJoCo cannot compile.
        """
        write_floating_mjcf(self, theta, path)

    # ------------------------------------------------------------------ contacts
    def base_frame(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """A frame fixed to the base (an IMU's, say): its ``(3, 3)`` rotation and ``(3,)``
        position, m, in the base frame.

        Raises:
            ValueError: on an unknown frame, or one that a joint moves.
        """
        (index,) = self.joints._frame_index([name])
        tree = self.joints._tree
        if tree.frame_owner[index] >= 0:
            raise ValueError(
                f"frame {name!r} moves with joint {self.joint_names[tree.frame_owner[index]]!r}: "
                "an IMU must be fixed to the base"
            )
        return np.array(tree.frame_rot[index]), np.array(tree.frame_pos[index])

    def frame_jacobian(self, q, frames: str | Sequence[str]) -> torch.Tensor:
        """The Jacobians of frames (feet, sensors) in world axes: ``J v`` is the frame origin's
        linear velocity and the frame's angular velocity in the world frame, so that a wrench
        ``w = [f; m]`` applied there (force in N and moment in N m about the frame origin,
        world axes) enters the generalised forces as ``J^T w``; Pinocchio's
        ``LOCAL_WORLD_ALIGNED`` frame Jacobian.

        Args:
            q: ``(*batch, 7 + n_dof)``, as in `regressor`.
            frames: a frame of the description (`RigidBodyModel.frame_names`) or several.

        Returns:
            ``(*batch, 6, 6 + n_dof)``, or ``(*batch, n_frames, 6, 6 + n_dof)`` for a sequence.

        Raises:
            ValueError: on a bad q or an unknown frame.
        """
        q = self._check_q(q)
        single = isinstance(frames, str)
        names = [frames] if single else list(frames)
        index = self.joints._frame_index(names)
        tree, n = self.joints._tree, self.n_dof
        qj = q[..., 7:]
        c = self.joints._consts(q.dtype, q.device)
        kw = {"dtype": q.dtype, "device": q.device}
        rots, poss = body_poses(
            qj, c, [tree.frame_owner[f] for f in index if tree.frame_owner[f] >= 0]
        )
        R_wb = quaternion_matrix(q[..., 3:7])
        batch = q.shape[:-1]
        out = []
        for f in index:
            j = tree.frame_owner[f]
            pos = torch.as_tensor(tree.frame_pos[f], **kw)
            p = pos.expand(*batch, 3) if j < 0 else poss[j] + rots[j] @ pos
            lin = [torch.eye(3, **kw).expand(*batch, 3, 3), -skew(p)]
            ang = [torch.zeros(*batch, 3, 3, **kw), torch.eye(3, **kw).expand(*batch, 3, 3)]
            chain = set(c.ancestors[j]) if j >= 0 else set()
            for k in range(n):
                if k not in chain:
                    zero = torch.zeros(*batch, 3, 1, **kw)
                    lin.append(zero)
                    ang.append(zero)
                    continue
                z = rots[k] @ c.axis[k]  # the joint's axis in base axes
                if c.revolute[k]:
                    o = poss[k] + rots[k] @ c.axis_point[k]  # a point on the axis
                    lin.append(torch.linalg.cross(z, p - o)[..., None])
                    ang.append(z[..., None])
                else:
                    lin.append(z[..., None])
                    ang.append(torch.zeros_like(z)[..., None])
            J = torch.cat([torch.cat(lin, -1), torch.cat(ang, -1)], -2)  # base axes
            out.append(torch.cat([R_wb @ J[..., :3, :], R_wb @ J[..., 3:, :]], -2))
        return out[0] if single else torch.stack(out, -3)
