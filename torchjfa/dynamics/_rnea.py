"""The batched recursive Newton-Euler regressor: pure tensor functions.

For joint positions, velocities and accelerations, the joint torques of a tree of rigid bodies
are linear in the 10 inertial parameters of each body (Atkeson, An and Hollerbach, 1986;
Khalil and Dombre, 2002). With Featherstone's spatial algebra (Featherstone, *Rigid Body
Dynamics Algorithms*, 2008) the torque of joint ``j`` is

    tau_j = sum over bodies i in the subtree of j of  s_ji^T A_i(v_i, a_i) pi_i,

where ``s_ji = iX0 S_j`` is joint j's motion axis expressed in body i's frame, ``A_i`` the
``6 x 10`` matrix with ``A_i pi_i = I_i a_i + v_i x* I_i v_i`` (the body's wrench, linear in its
parameters), and ``v_i``, ``a_i`` the body's spatial velocity and acceleration (gravity enters as
a base acceleration ``-g``). The forward pass runs once over the joints (a Python loop,
vectorised over the batch) and computes, in world coordinates at the world origin, each joint's
Plücker axis and each body's velocity and acceleration; the projection then handles every
(ancestor joint j, body i) pair at once, with ``s_ji^T A_i`` written out column by column
(mass, first moments, the six inertia entries), so no ``6 x 10`` matrix is ever formed.

Layout: inside this module tensors are components first and batch last (``(3, n, B)``), so that
every small product is a few broadcast multiply-adds over long contiguous rows; tiny batched
matrix products (``bmm`` on 3 x 3 blocks) are several times slower on CPU.

`RigidBodyModel.regressor` is the public entry point; this module only holds the maths (with
autograd); `torchjfa.dynamics._rnea_fast` runs the same maths through reused buffers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ._tree import KinematicTree

__all__ = ["TreeConstants", "regressor_into", "floating_regressor_into", "skew"]


@dataclass
class TreeConstants:
    """The tree's constants as tensors of one dtype and device.

    Attributes:
        parent: per joint, the parent joint's index or -1.
        revolute: per joint, True for revolute, False for prismatic.
        has_point: per joint, True when the axis point is not the body origin.
        ancestors: per body i, the joints that move it (ancestors and i itself), in order.
        rot_fixed: ``(n, 3, 3)``; pos_fixed: ``(n, 3)``; axis, axis_point: ``(n, 3)``.
        pos_point: ``(n, 3)`` ``pos_fixed + rot_fixed @ axis_point``.
        skew_axis, skew_axis2: ``(n, 3, 3)`` ``K = [u]x`` and ``K @ K`` (Rodrigues' formula).
        gravity: ``(3,)``.
        pairs: ``(jj, ii)`` long tensors: every (ancestor-or-self joint, body) pair.
    """

    parent: tuple[int, ...]
    revolute: tuple[bool, ...]
    has_point: tuple[bool, ...]
    ancestors: tuple[tuple[int, ...], ...]
    rot_fixed: torch.Tensor
    pos_fixed: torch.Tensor
    axis: torch.Tensor
    axis_point: torch.Tensor
    pos_point: torch.Tensor
    skew_axis: torch.Tensor
    skew_axis2: torch.Tensor
    gravity: torch.Tensor
    pairs: tuple[torch.Tensor, torch.Tensor]

    @property
    def n(self) -> int:
        return len(self.parent)

    @classmethod
    def from_tree(
        cls, tree: KinematicTree, dtype: torch.dtype, device: torch.device
    ) -> TreeConstants:
        """The constants of ``tree`` (float64 numpy) as tensors of ``dtype`` on ``device``."""
        kw = {"dtype": dtype, "device": device}
        K = skew(torch.as_tensor(tree.axis, dtype=torch.float64))
        ancestors = tree.ancestors()
        pos_point = tree.pos_fixed + np.einsum("nij,nj->ni", tree.rot_fixed, tree.axis_point)
        return cls(
            parent=tuple(tree.parent),
            revolute=tuple(jt == "revolute" for jt in tree.joint_types),
            has_point=tuple(bool(np.any(p != 0.0)) for p in tree.axis_point),
            ancestors=ancestors,
            rot_fixed=torch.as_tensor(tree.rot_fixed, **kw),
            pos_fixed=torch.as_tensor(tree.pos_fixed, **kw),
            axis=torch.as_tensor(tree.axis, **kw),
            axis_point=torch.as_tensor(tree.axis_point, **kw),
            pos_point=torch.as_tensor(pos_point, **kw),
            skew_axis=K.to(**kw),
            skew_axis2=(K @ K).to(**kw),
            gravity=torch.as_tensor(tree.gravity, **kw),
            pairs=(
                torch.tensor([j for a in ancestors for j in a], device=device),
                torch.tensor([i for i, a in enumerate(ancestors) for _ in a], device=device),
            ),
        )


def skew(p: torch.Tensor) -> torch.Tensor:
    """``[p]x``, ``(..., 3, 3)``, of ``p (..., 3)``: ``[p]x v = p x v``."""
    x, y, z = p.unbind(-1)
    o = torch.zeros_like(x)
    return torch.stack([o, -z, y, z, o, -x, -y, x, o], -1).reshape(*p.shape[:-1], 3, 3)


def _cross(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Cross product over dim 0 (components first, batch last: ``(3, ..., B)``)."""
    a0, a1, a2 = a[0], a[1], a[2]
    b0, b1, b2 = b[0], b[1], b[2]
    return torch.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])


def _mat_const(A: torch.Tensor, C: torch.Tensor) -> torch.Tensor:
    """``A @ C`` for ``A (3, 3, B)`` and a constant ``C (3, 3)``."""
    return (
        A[:, 0:1] * C[0, None, :, None]
        + A[:, 1:2] * C[1, None, :, None]
        + A[:, 2:3] * C[2, None, :, None]
    )


def _mv(A: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """``A @ v`` for ``A (3, 3, B)`` and a constant ``v (3,)``."""
    v = v[:, None]
    return A[:, 0] * v[0] + A[:, 1] * v[1] + A[:, 2] * v[2]


def _rotate_t(R: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """``R^T v`` for ``R (3, 3, ..., B)`` and ``v (3, ..., B)``."""
    return R[0] * v[0] + R[1] * v[1] + R[2] * v[2]


def _forward_pass(q, qd, qdd, c: TreeConstants, root=None):
    """World-frame kinematics of every body, components first and batch last.

    Tiny batched matrix products are slow on CPU; with the batch as the last, contiguous
    dimension every product below is a few broadcast multiply-adds over long rows.

    Args:
        q, qd, qdd: ``(n, B)``.
        root: None for a fixed root (at rest, gravity entering as the acceleration ``-g``), or
            the root's spatial velocity and acceleration at the world origin ``(w, v, dw, dv)``,
            ``(3, B)`` each, gravity included (a floating base: the world frame is then the
            base frame at this instant).

    Returns:
        Lists over joints: rotations ``(3, 3, B)`` body to world, body origins ``(3, B)``, the
        joints' Plücker axes at the world origin split in angular ``(3, B)`` (zero for
        prismatic joints) and linear parts, and each body's spatial velocity (w, v) and
        acceleration (dw, dv) at the world origin, ``(3, B)`` each.
    """
    n, B = q.shape
    rots, poss, sw, sv, vw, vv, aw, av = ([] for _ in range(8))
    s, co = torch.sin(q), torch.cos(q)
    if root is None:
        zero3 = q.new_zeros(3, B)
        root = (zero3, zero3, zero3, (-c.gravity)[:, None].expand(3, B))
    for k in range(n):
        p = c.parent[k]
        qdk, qddk = qd[k], qdd[k]
        if p < 0:
            W = c.rot_fixed[k][..., None].expand(3, 3, B)
            w_p, v_p, dw_p, dv_p = root
        else:
            W = _mat_const(rots[p], c.rot_fixed[k])
            w_p, v_p, dw_p, dv_p = vw[p], vv[p], aw[p], av[p]
        z = _mv(W, c.axis[k])  # (3, B) world axis
        if c.revolute[k]:
            R = (
                W
                + s[k] * _mat_const(W, c.skew_axis[k])
                + (1.0 - co[k]) * _mat_const(W, c.skew_axis2[k])
            )
            if p < 0:
                o = c.pos_point[k][:, None].expand(3, B)
            else:
                o = poss[p] + _mv(rots[p], c.pos_point[k])
            pos = o - _mv(R, c.axis_point[k]) if c.has_point[k] else o
            m = _cross(o, z)  # moment of the axis about the world origin
            zq, mq = z * qdk, m * qdk
            w, v = w_p + zq, v_p + mq
            dw = dw_p + z * qddk + _cross(w_p, zq)
            dv = dv_p + m * qddk + _cross(w_p, mq) + _cross(v_p, zq)
            sw.append(z)
            sv.append(m)
        else:
            R = W
            base = c.pos_fixed[k][:, None] if p < 0 else poss[p] + _mv(rots[p], c.pos_fixed[k])
            pos = base + z * q[k]
            zq = z * qdk
            w, v, dw = w_p, v_p + zq, dw_p
            dv = dv_p + z * qddk + _cross(w_p, zq)
            sw.append(torch.zeros_like(z))
            sv.append(z)
        rots.append(R)
        poss.append(pos)
        vw.append(w)
        vv.append(v)
        aw.append(dw)
        av.append(dv)
    return rots, poss, sw, sv, vw, vv, aw, av


def _bodies(q, qd, qdd, c: TreeConstants, root=None):
    """Each body's motion from `_forward_pass`, stacked: rotations ``(3, 3, n, B)``, origins,
    angular velocities and accelerations and the classical acceleration of the origin (gravity
    included as ``-g``) in world axes, the joints' Plücker axes (angular, linear) and the
    angular velocity and acceleration in body axes, ``(3, n, B)`` each."""
    rots, poss, sw, sv, vw, vv, aw, av = _forward_pass(q, qd, qdd, c, root)
    R = torch.stack(rots, 2)  # (3, 3, n, B) body-to-world
    pos = torch.stack(poss, 1)  # (3, n, B)
    w = torch.stack(vw, 1)
    dw = torch.stack(aw, 1)
    v_o = torch.stack(vv, 1) + _cross(w, pos)
    acc = torch.stack(av, 1) + _cross(dw, pos) + _cross(w, v_o)
    Sw = torch.stack(sw, 1)  # (3, n, B) joint axes (zero for prismatic)
    Sv = torch.stack(sv, 1)  # (3, n, B) moments (the axis for prismatic)
    return R, pos, w, dw, acc, Sw, Sv, _rotate_t(R, w), _rotate_t(R, dw)


def _blocks(sa, sl, Rp, wp, dwp, accp, o_b, a_b) -> torch.Tensor:
    """``s^T A_i`` for (axis, body) pairs, ``(10, P, B)``: the axis's angular part ``sa`` and
    its linear part at the body origin ``sl`` (world axes), the body's rotation ``Rp``, angular
    velocity ``wp``, acceleration ``dwp`` and origin acceleration ``accp`` (world axes), and
    its angular velocity ``o_b`` and acceleration ``a_b`` in body axes; written out column by
    column (m, h, I), ``(3, P, B)`` each."""
    y_m = (sl * accp).sum(0)  # (P, B)
    y_h = _cross(accp, sa) + _cross(sl, dwp) + _cross(wp, _cross(wp, sl))
    x = _cross(sa, wp)
    sa_b, x_b, yh_b = _rotate_t(Rp, sa), _rotate_t(Rp, x), _rotate_t(Rp, y_h)
    return torch.stack(
        [
            y_m,
            yh_b[0],
            yh_b[1],
            yh_b[2],
            sa_b[0] * a_b[0] + x_b[0] * o_b[0],
            sa_b[0] * a_b[1] + sa_b[1] * a_b[0] + x_b[0] * o_b[1] + x_b[1] * o_b[0],
            sa_b[1] * a_b[1] + x_b[1] * o_b[1],
            sa_b[0] * a_b[2] + sa_b[2] * a_b[0] + x_b[0] * o_b[2] + x_b[2] * o_b[0],
            sa_b[1] * a_b[2] + sa_b[2] * a_b[1] + x_b[1] * o_b[2] + x_b[2] * o_b[1],
            sa_b[2] * a_b[2] + x_b[2] * o_b[2],
        ]
    )


def _joint_rows(out, qd, qdd, motion, c: TreeConstants, friction: tuple[str, ...]) -> None:
    """Write the joints' rows ``(B, n, n * per)`` of the bodies' ``motion`` into ``out``."""
    B, n = qd.shape
    per = 10 + len(friction)
    R, pos, w, dw, acc, Sw, Sv, w_b, dw_b = motion
    jj, ii = c.pairs  # every (ancestor-or-self joint j, body i) pair
    sa = Sw[:, jj]  # (3, P, B) joint j's axis at body i's origin, world axes
    sl = Sv[:, jj] + _cross(sa, pos[:, ii])
    blk = _blocks(sa, sl, R[:, :, ii], w[:, ii], dw[:, ii], acc[:, ii], w_b[:, ii], dw_b[:, ii])
    cols = (jj * (n * per) + ii * per)[:, None] + torch.arange(10, device=jj.device)  # (P, 10)
    out.view(B, -1).index_copy_(1, cols.reshape(-1), blk.permute(2, 1, 0).reshape(B, -1))
    col = 10
    for kind in friction:
        if kind == "viscous":
            vals = qd
        elif kind == "coulomb":
            vals = torch.sign(qd)
        elif kind == "armature":
            vals = qdd
        else:
            vals = torch.ones_like(qd)
        out.view(B, n, n, per).diagonal(0, 1, 2)[:, col] = vals
        col += 1


def regressor_into(
    out: torch.Tensor,
    q: torch.Tensor,
    qd: torch.Tensor,
    qdd: torch.Tensor,
    c: TreeConstants,
    friction: tuple[str, ...],
) -> torch.Tensor:
    """Write the regressor of a flat batch into ``out``.

    Args:
        out: ``(B, n, n * (10 + len(friction)))``, zero-filled, same dtype/device as q.
        q, qd, qdd: ``(B, n)`` joint positions (rad or m), velocities and accelerations.
        c: the tree's constants in q's dtype and device.
        friction: the friction terms per joint, in the layout's order.

    Returns:
        ``out``.
    """
    qT, qdT, qddT = q.T.contiguous(), qd.T.contiguous(), qdd.T.contiguous()  # (n, B)
    _joint_rows(out, qd, qdd, _bodies(qT, qdT, qddT, c), c, friction)
    return out


def floating_regressor_into(
    out: torch.Tensor,
    base: tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor],
    q: torch.Tensor,
    qd: torch.Tensor,
    qdd: torch.Tensor,
    c: TreeConstants,
    friction: tuple[str, ...],
) -> torch.Tensor:
    """Write the regressor of a floating-base tree into ``out``.

    Everything is computed in the base frame at this instant (an inertial frame that coincides
    with the base): the base body moves with its twist, and the six base rows are the wrench
    the base's free joint transmits, ``[force; moment]`` at the base origin in base axes, as
    in Pinocchio's free flyer. The base body's 10 parameters come first, then the joints'.

    Args:
        out: ``(B, 6 + n, 10 + n * (10 + len(friction)))``, zero-filled, same dtype/device as q.
        base: the base's twist and spatial acceleration in base axes and gravity there,
            ``(v, w, a, g)`` with ``v, w (B, 3)`` the linear velocity of the base origin and
            the angular velocity, ``a (B, 6)`` their derivatives ``[dv, dw]`` (Pinocchio's
            free-flyer acceleration), ``g (B, 3)`` gravity in base axes, m/s^2.
        q, qd, qdd: ``(B, n)`` joint positions (rad or m), velocities and accelerations.
        c: the tree's constants in q's dtype and device.
        friction: the friction terms per joint, in the layout's order.

    Returns:
        ``out``.
    """
    B, n = q.shape
    per = 10 + len(friction)
    v, w, a, g = (x.T.contiguous() for x in base)  # (3, B) and (6, B)
    root = (w, v, a[3:], a[:3] - g)  # Plücker at the base origin; gravity as -g
    motion = _bodies(q.T.contiguous(), qd.T.contiguous(), qdd.T.contiguous(), c, root)
    joints = q.new_zeros(B, n, n * per)
    _joint_rows(joints, qd, qdd, motion, c, friction)
    out[:, 6:, 10:] = joints
    # the base rows: six unit axes (3 forces, then 3 moments about the base origin) against
    # every body, the base (index 0: identity pose, the root's motion) and the n others
    R, pos, wb, dwb, acc, _, _, w_b, dw_b = motion
    eye = torch.eye(3, dtype=q.dtype, device=q.device)
    R_all = torch.cat([eye[:, :, None, None].expand(3, 3, 1, B), R], 2)  # (3, 3, n + 1, B)
    pos_all = torch.cat([torch.zeros_like(pos[:, :1]), pos], 1)
    w_all = torch.cat([w[:, None], wb], 1)
    dw_all = torch.cat([root[2][:, None], dwb], 1)
    acc_all = torch.cat([(root[3] + _cross(w, v))[:, None], acc], 1)
    wb_all = torch.cat([w[:, None], w_b], 1)  # the base's own axes are the world's here
    dwb_all = torch.cat([root[2][:, None], dw_b], 1)
    m = n + 1
    unit = eye[:, :, None, None].expand(3, 3, m, B)  # (3 components, 3 axes, m, B)
    zero = torch.zeros_like(unit)
    sa = torch.cat([zero, unit], 1)  # (3, 6, m, B)
    sl = torch.cat([unit, _cross(unit, pos_all[:, None].expand(3, 3, m, B))], 1)
    flat = lambda x: x.reshape(3, 6 * m, B)
    blk = _blocks(
        flat(sa),
        flat(sl),
        R_all[:, :, None].expand(3, 3, 6, m, B).reshape(3, 3, 6 * m, B),
        *(flat(x[:, None].expand(3, 6, m, B)) for x in (w_all, dw_all, acc_all, wb_all, dwb_all)),
    )  # (10, 6 * m, B)
    width = out.shape[2]
    body_col = torch.tensor([0, *(10 + i * per for i in range(n))], device=q.device)
    rows = torch.arange(6, device=q.device)
    cols = (rows[:, None] * width + body_col[None, :]).reshape(-1, 1) + torch.arange(
        10, device=q.device
    )  # (6 m, 10)
    out.view(B, -1).index_copy_(1, cols.reshape(-1), blk.permute(2, 1, 0).reshape(B, -1))
    return out
