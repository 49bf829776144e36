"""Forward kinematics: the pose in the root frame of every frame of a robot description.

The poses come from the `KinematicTree` (float64, read from the description: MuJoCo's compiled
body, joint and site placements for MJCF, each URDF joint's ``<origin>`` and ``<axis>``), so
they agree with MuJoCo's ``xpos``/``xmat`` and Pinocchio's frame placements to float64
round-off. Body i, moved by joint i about (revolute) or along (prismatic) the unit axis ``u``
through the point ``c`` of its own frame (MJCF joint ``pos``; zero for URDF), sits in the frame
of its parent body at

    T_i(q_i) = F_i Trans(c) Rot(u, q_i) Trans(-c)     (revolute)
    T_i(q_i) = F_i Trans(q_i u)                        (prismatic)

with ``F_i`` the joint frame before motion (``rot_fixed``, ``pos_fixed``) and ``Rot`` Rodrigues'
formula ``I + sin(q) K + (1 - cos(q)) K^2``, ``K = [u]x``: the same maths as the regressor's
forward pass (`torchjfa.dynamics._rnea`). A frame attached by fixed joints (a URDF tool link or
flange, an MJCF body without joints, a named MJCF site) sits at a fixed pose in the body that
carries it, which the tree keeps when it lumps the frame's inertia into that body.

`body_poses` and `frame_poses` are pure tensor functions, batched over the leading dimensions
of ``q``, differentiable, in its dtype and device; `FrameKinematics` gives `RigidBodyModel` its
`frame_names` and `forward_kinematics`.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from .._validation import as_tensor, check_finite
from ._rnea import TreeConstants

__all__ = ["FrameKinematics", "body_poses", "frame_poses"]


def _apply(R: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """``R v`` for ``R (..., 3, 3)`` and ``v (..., 3)`` or a constant ``(3,)``."""
    return (R @ v.unsqueeze(-1)).squeeze(-1)


def body_poses(
    q: torch.Tensor, c: TreeConstants, joints: Sequence[int] | None = None
) -> tuple[list[torch.Tensor | None], list[torch.Tensor | None]]:
    """The pose of each joint's body in the root frame.

    Args:
        q: ``(..., n)`` joint positions, rad (revolute) or m (prismatic).
        c: the tree's constants in q's dtype and device (`TreeConstants.from_tree`).
        joints: the joints whose bodies are needed (their ancestors are computed too);
            default all.

    Returns:
        ``(rotations, positions)``: per joint, ``(..., 3, 3)`` body-to-root rotation and
        ``(..., 3)`` body origin, m; None for the joints not computed.
    """
    n = c.n
    if joints is None:
        needed = set(range(n))
    else:
        needed = {j for k in joints for j in c.ancestors[k]}
    batch = q.shape[:-1]
    rots: list[torch.Tensor | None] = [None] * n
    poss: list[torch.Tensor | None] = [None] * n
    for k in sorted(needed):  # parents have smaller indices than their children
        p = c.parent[k]
        W = c.rot_fixed[k] if p < 0 else rots[p] @ c.rot_fixed[k]
        qk = q[..., k, None]
        if c.revolute[k]:
            s, co = torch.sin(qk)[..., None], torch.cos(qk)[..., None]
            R = W + s * (W @ c.skew_axis[k]) + (1.0 - co) * (W @ c.skew_axis2[k])
            o = c.pos_point[k] if p < 0 else poss[p] + _apply(rots[p], c.pos_point[k])
            pos = o - _apply(R, c.axis_point[k]) if c.has_point[k] else o
        else:
            R = W
            base = c.pos_fixed[k] if p < 0 else poss[p] + _apply(rots[p], c.pos_fixed[k])
            pos = base + _apply(W, c.axis[k]) * qk
        rots[k] = R.expand(*batch, 3, 3)
        poss[k] = pos.expand(*batch, 3)
    return rots, poss


def frame_poses(
    q: torch.Tensor,
    c: TreeConstants,
    owner: Sequence[int],
    rot: torch.Tensor,
    pos: torch.Tensor,
) -> torch.Tensor:
    """Homogeneous transforms, frame to root, of frames fixed in the joints' bodies.

    Args:
        q: ``(..., n)`` joint positions, rad or m.
        c: the tree's constants in q's dtype and device.
        owner: per frame, the joint whose body carries it, or -1 (fixed to the root).
        rot: ``(n_frames, 3, 3)`` each frame's rotation in its owner's body (or the root) frame.
        pos: ``(n_frames, 3)`` its position there, m.

    Returns:
        ``(..., n_frames, 4, 4)`` in q's dtype and device; rows ``[R p; 0 0 0 1]``.
    """
    batch = q.shape[:-1]
    rots, poss = body_poses(q, c, [j for j in owner if j >= 0])
    out = []
    for f, j in enumerate(owner):
        if j < 0:
            R, p = rot[f].expand(*batch, 3, 3), pos[f].expand(*batch, 3)
        else:
            R, p = rots[j] @ rot[f], poss[j] + _apply(rots[j], pos[f])
        out.append(torch.cat([R, p.unsqueeze(-1)], -1))
    bottom = q.new_tensor([0.0, 0.0, 0.0, 1.0]).expand(*batch, len(out), 1, 4)
    return torch.cat([torch.stack(out, -3), bottom], -2)


class FrameKinematics:
    """The forward kinematics of `RigidBodyModel` (a base class it takes its methods from).

    The class using it holds the tree as ``_tree`` and its constants per dtype and device in
    ``_consts(dtype, device)``, and names its joints and bodies (``joint_names``,
    ``body_names``).
    """

    @property
    def frame_names(self) -> tuple[str, ...]:
        """Every frame `forward_kinematics` places, root first, parents before children.

        URDF: every link. MJCF: every body (the world body first), then every named site.
        Among them: the bodies the joints move (`body_names`), the frames lumped into them by
        fixed joints (`lumped_bodies`, e.g. a URDF flange or tool link) and the frames fixed to
        the root.
        """
        return self._tree.frame_names

    def forward_kinematics(self, q, frames: str | Sequence[str] | None = None) -> torch.Tensor:
        """The pose of named frames in the root frame (the URDF root link, the MJCF world).

        Args:
            q: ``(*batch, n_dof)`` joint positions in `joint_names` order, rad (revolute) or m
                (prismatic); a tensor keeps its dtype and device, anything else becomes float64.
            frames: a frame name, a sequence of them (any of `frame_names`), or None for the
                bodies the joints move (`body_names`, in joint order).

        Returns:
            Homogeneous transforms frame to root, ``[R p; 0 0 0 1]`` (``R`` the frame's axes in
            root coordinates, ``p`` its origin, m): ``(*batch, n_frames, 4, 4)``, or
            ``(*batch, 4, 4)`` for a single name; in q's dtype and device, differentiable with
            respect to q.

        Raises:
            ValueError: if q's last dimension is not ``n_dof``, q has NaN or infinite entries,
                or a name is no frame of the description.
        """
        q = as_tensor(q, name="q")
        n = len(self.joint_names)
        if q.ndim == 0 or q.shape[-1] != n:
            raise ValueError(
                f"q must have shape (*batch, {n}) (one column per joint of "
                f"{tuple(self.joint_names)}), got {tuple(q.shape)}"
            )
        check_finite(q.detach(), "q")
        single = isinstance(frames, str)
        if single:
            index = self._frame_index([frames])
        else:
            index = self._frame_index(self.body_names if frames is None else frames)
        tree = self._tree
        kw = {"dtype": q.dtype, "device": q.device}
        T = frame_poses(
            q,
            self._consts(q.dtype, q.device),
            [tree.frame_owner[f] for f in index],
            torch.as_tensor(tree.frame_rot[index], **kw),
            torch.as_tensor(tree.frame_pos[index], **kw),
        )
        return T[..., 0, :, :] if single else T

    def _frame_index(self, frames: Sequence[str]) -> list[int]:
        """The indices in `frame_names` of the named frames."""
        try:
            asked = list(frames)
        except TypeError:
            asked = [None]
        if not all(isinstance(f, str) for f in asked):
            raise ValueError(f"frames must be a frame name or a sequence of names, got {frames!r}")
        if not asked:
            raise ValueError("frames is empty; name at least one frame (or None for the bodies)")
        names = self._tree.frame_names
        where: dict[str, int] = {}
        for i, name in enumerate(names):
            where.setdefault(name, i)
        unknown = [f for f in asked if f not in where]
        if unknown:
            raise ValueError(f"no frame named {unknown} in the description; frames: {names}")
        return [where[f] for f in asked]
