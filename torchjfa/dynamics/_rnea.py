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

`RigidBodyModel.regressor` is the public entry point; this module only holds the maths.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

__all__ = ["TreeConstants", "regressor_into"]


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


def _forward_pass(q, qd, qdd, c: TreeConstants):
    """World-frame kinematics of every body, components first and batch last.

    Tiny batched matrix products are slow on CPU; with the batch as the last, contiguous
    dimension every product below is a few broadcast multiply-adds over long rows.

    Args:
        q, qd, qdd: ``(n, B)``.

    Returns:
        Lists over joints: rotations ``(3, 3, B)`` body to world, body origins ``(3, B)``, the
        joints' Plücker axes at the world origin split in angular ``(3, B)`` (zero for
        prismatic joints) and linear parts, and each body's spatial velocity (w, v) and
        acceleration (dw, dv) at the world origin, ``(3, B)`` each.
    """
    n, B = q.shape
    rots, poss, sw, sv, vw, vv, aw, av = ([] for _ in range(8))
    s, co = torch.sin(q), torch.cos(q)
    zero3 = q.new_zeros(3, B)
    a_base = (-c.gravity)[:, None].expand(3, B)
    for k in range(n):
        p = c.parent[k]
        qdk, qddk = qd[k], qdd[k]
        if p < 0:
            W = c.rot_fixed[k][..., None].expand(3, 3, B)
            w_p, v_p, dw_p, dv_p = zero3, zero3, zero3, a_base
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
    B, n = q.shape
    per = 10 + len(friction)
    qT, qdT, qddT = q.T.contiguous(), qd.T.contiguous(), qdd.T.contiguous()  # (n, B)
    rots, poss, sw, sv, vw, vv, aw, av = _forward_pass(qT, qdT, qddT, c)
    R = torch.stack(rots, 2)  # (3, 3, n, B) body-to-world
    pos = torch.stack(poss, 1)  # (3, n, B)
    w = torch.stack(vw, 1)
    dw = torch.stack(aw, 1)
    # classical acceleration of each body origin (gravity included as -g), world frame
    v_o = torch.stack(vv, 1) + _cross(w, pos)
    acc = torch.stack(av, 1) + _cross(dw, pos) + _cross(w, v_o)
    Sw = torch.stack(sw, 1)  # (3, n, B) joint axes (zero for prismatic)
    Sv = torch.stack(sv, 1)  # (3, n, B) moments (the axis for prismatic)
    w_b = _rotate_t(R, w)  # (3, n, B) body frame
    dw_b = _rotate_t(R, dw)
    jj, ii = c.pairs  # every (ancestor-or-self joint j, body i) pair
    Rp, wp, dwp, accp = R[:, :, ii], w[:, ii], dw[:, ii], acc[:, ii]
    sa = Sw[:, jj]  # (3, P, B) joint j's axis at body i's origin, world axes
    sl = Sv[:, jj] + _cross(sa, pos[:, ii])
    # tau_j = s^T A_i pi_i, written out column by column (m, h, I) in world axes first
    y_m = (sl * accp).sum(0)  # (P, B)
    y_h = _cross(accp, sa) + _cross(sl, dwp) + _cross(wp, _cross(wp, sl))
    x = _cross(sa, wp)
    sa_b, x_b, yh_b = _rotate_t(Rp, sa), _rotate_t(Rp, x), _rotate_t(Rp, y_h)
    a_b, o_b = dw_b[:, ii], w_b[:, ii]
    blk = torch.stack(
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
    )  # (10, P, B)
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
    return out


# ---------------------------------------------------------------------------------------------
# The fast path (no autograd): the same maths with every intermediate written into buffers that
# are allocated once per call and reused chunk after chunk (``out=`` and in-place ops only), the
# chunk's regressor assembled batch-last in a cache-sized buffer and transposed into ``out``
# block by block. Allocating temporaries of a few hundred kB per op (page faults) and the
# strided scatter into the batch-first output were most of the time of `regressor_into`.
# ---------------------------------------------------------------------------------------------

_TRANSPOSE_BLOCK = 128  # samples per block of the final transposed copy (fits L1/L2)


def _cross_into(o: torch.Tensor, a: torch.Tensor, b: torch.Tensor, acc: bool = False) -> None:
    """``o = a x b`` (or ``o += a x b`` with ``acc``) over dim 0, in place."""
    for i, j, k in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
        if acc:
            o[i].addcmul_(a[j], b[k])
        else:
            torch.mul(a[j], b[k], out=o[i])
        o[i].addcmul_(a[k], b[j], value=-1.0)


def _rot_t_into(o: torch.Tensor, R: torch.Tensor, v: torch.Tensor) -> None:
    """``o = R^T v`` for ``R (3, 3, ...)`` and ``v (3, ...)``, in place."""
    torch.mul(R[0], v[0], out=o)
    o.addcmul_(R[1], v[1])
    o.addcmul_(R[2], v[2])


class _Plan:
    """Per-call constants of the fast path: Python floats and index tensors, built once."""

    def __init__(self, c: TreeConstants, n_per: int, friction: tuple[str, ...]) -> None:
        n = c.n
        self.n, self.per = n, n_per
        F = c.rot_fixed
        self.M0 = F[..., None]  # (n, 3, 3, 1)
        self.M1 = (F @ c.skew_axis)[..., None]
        self.M2 = (F @ c.skew_axis2)[..., None]
        self.u = (F @ c.axis[..., None])[..., 0].tolist()  # joint axis in the parent frame
        self.F = F.tolist()
        self.pp = c.pos_point.tolist()
        self.pf = c.pos_fixed.tolist()
        self.ap = c.axis_point.tolist()
        self.g = c.gravity.tolist()
        jj, ii = c.pairs
        self.jj, self.ii = jj, ii
        P = int(jj.numel())
        self.P = P
        cols = (jj * (n * n_per) + ii * n_per)[None, :] + torch.arange(10, device=jj.device)[
            :, None
        ]
        self.rows = cols.reshape(-1)  # (10 * P,) rows of the batch-last regressor, col-major
        diag = torch.arange(n, device=jj.device) * (n * n_per + n_per)
        self.fric_rows = [diag + 10 + f for f in range(len(friction))]
        self.friction = friction


def _buffers(plan: _Plan, b: int, like: torch.Tensor) -> dict[str, torch.Tensor]:
    n, P = plan.n, plan.P

    def e(*shape):
        return like.new_empty(*shape, b)

    ws = {
        "s": e(n),
        "omc": e(n),
        "qd": e(n),
        "qdd": e(n),
        "R": e(3, 3, n),
        "pos": e(3, n),
        "o": e(3),
        "M": e(3, 3),
        "sw": e(3, n),
        "sv": e(3, n),
        "swq": e(3, n),
        "svq": e(3, n),
        "w": e(3, n),
        "v": e(3, n),
        "dw": e(3, n),
        "dv": e(3, n),
        "t1": e(3, n),
        "t2": e(3, n),
        "body": e(9, n),
        "vo": e(3, n),
        "acc": e(3, n),
        "gb": e(9, P),
        "gR": e(9, P),
        "sa": e(3, P),
        "svp": e(3, P),
        "posp": e(3, P),
        "sl": e(3, P),
        "sab": e(3, P),
        "slb": e(3, P),
        "xb": e(3, P),
        "tp": e(3, P),
        "blk": e(10, P),
        "Yt": like.new_zeros(n * n * plan.per, b),
    }
    ws["sw"].zero_()  # prismatic joints keep a zero angular axis
    return ws


def _fast_chunk(ws, q, qd, qdd, plan: _Plan, c: TreeConstants) -> None:
    """Fill ``ws["Yt"]`` (batch last) with the regressor of one chunk; q etc. ``(b, n)``."""
    n = plan.n
    s, omc, R, pos, o, M = ws["s"], ws["omc"], ws["R"], ws["pos"], ws["o"], ws["M"]
    sw, sv = ws["sw"], ws["sv"]
    qT = q.T
    torch.sin(qT, out=s)
    torch.cos(qT, out=omc)
    omc.neg_().add_(1.0)
    ws["qd"].copy_(qd.T)
    ws["qdd"].copy_(qdd.T)
    # ---- kinematics: rotations, origins and Plücker axes (world, about the world origin)
    for k in range(n):
        p = c.parent[k]
        Rk, posk, z = R[:, :, k], pos[:, k], sw[:, k] if c.revolute[k] else sv[:, k]
        u, Rp = plan.u[k], (R[:, :, p] if p >= 0 else None)
        if c.revolute[k]:
            dst = Rk if p < 0 else M
            torch.addcmul(plan.M0[k], plan.M1[k], s[k], out=dst)
            dst.addcmul_(plan.M2[k], omc[k])
            if p >= 0:
                torch.mul(Rp[:, 0:1], M[0:1], out=Rk)
                Rk.addcmul_(Rp[:, 1:2], M[1:2])
                Rk.addcmul_(Rp[:, 2:3], M[2:3])
            pp = plan.pp[k]
            if p < 0:
                z.copy_(torch.tensor(u, dtype=z.dtype, device=z.device)[:, None])
                o.copy_(torch.tensor(pp, dtype=o.dtype, device=o.device)[:, None])
            else:
                torch.mul(Rp[:, 0], u[0], out=z)
                z.add_(Rp[:, 1], alpha=u[1]).add_(Rp[:, 2], alpha=u[2])
                torch.add(pos[:, p], Rp[:, 0], alpha=pp[0], out=o)
                o.add_(Rp[:, 1], alpha=pp[1]).add_(Rp[:, 2], alpha=pp[2])
            posk.copy_(o)
            if c.has_point[k]:
                ap = plan.ap[k]
                for m in range(3):
                    posk.add_(Rk[:, m], alpha=-ap[m])
            _cross_into(sv[:, k], o, z)
        else:
            Fk, pf = plan.F[k], plan.pf[k]
            if p < 0:
                Rk.copy_(torch.tensor(Fk, dtype=R.dtype, device=R.device)[..., None])
                z.copy_(torch.tensor(u, dtype=z.dtype, device=z.device)[:, None])
                posk.copy_(torch.tensor(pf, dtype=z.dtype, device=z.device)[:, None])
            else:
                Fc = plan.M0[k]
                torch.mul(Rp[:, 0:1], Fc[0:1], out=Rk)
                Rk.addcmul_(Rp[:, 1:2], Fc[1:2])
                Rk.addcmul_(Rp[:, 2:3], Fc[2:3])
                torch.mul(Rp[:, 0], u[0], out=z)
                z.add_(Rp[:, 1], alpha=u[1]).add_(Rp[:, 2], alpha=u[2])
                torch.add(pos[:, p], Rp[:, 0], alpha=pf[0], out=posk)
                posk.add_(Rp[:, 1], alpha=pf[1]).add_(Rp[:, 2], alpha=pf[2])
            posk.addcmul_(z, q[:, k])
    # ---- velocities and accelerations at the world origin: sums over the ancestors
    swq, svq, w, v, dw, dv, t1, t2 = (
        ws[k] for k in ("swq", "svq", "w", "v", "dw", "dv", "t1", "t2")
    )
    torch.mul(sw, ws["qd"], out=swq)
    torch.mul(sv, ws["qd"], out=svq)
    for k in range(n):
        p = c.parent[k]
        if p < 0:
            w[:, k].copy_(swq[:, k])
            v[:, k].copy_(svq[:, k])
        else:
            torch.add(w[:, p], swq[:, k], out=w[:, k])
            torch.add(v[:, p], svq[:, k], out=v[:, k])
    torch.mul(sw, ws["qdd"], out=t1)
    _cross_into(t1, w, swq, acc=True)
    torch.mul(sv, ws["qdd"], out=t2)
    _cross_into(t2, w, svq, acc=True)
    _cross_into(t2, v, swq, acc=True)
    g = plan.g
    for k in range(n):
        p = c.parent[k]
        if p < 0:
            dw[:, k].copy_(t1[:, k])
            for m in range(3):
                torch.sub(t2[m, k], g[m], out=dv[m, k])
        else:
            torch.add(dw[:, p], t1[:, k], out=dw[:, k])
            torch.add(dv[:, p], t2[:, k], out=dv[:, k])
    # ---- each body's velocity, acceleration (gravity in) and origin acceleration, body axes
    vo, acc, body = ws["vo"], ws["acc"], ws["body"]
    vo.copy_(v)
    _cross_into(vo, w, pos, acc=True)
    acc.copy_(dv)
    _cross_into(acc, dw, pos, acc=True)
    _cross_into(acc, w, vo, acc=True)
    _rot_t_into(body[0:3], R, w)
    _rot_t_into(body[3:6], R, dw)
    _rot_t_into(body[6:9], R, acc)
    # ---- every (ancestor joint j, body i) pair at once
    jj, ii = plan.jj, plan.ii
    gb, gR, sa, svp, posp = ws["gb"], ws["gR"], ws["sa"], ws["svp"], ws["posp"]
    torch.index_select(body, 1, ii, out=gb)
    torch.index_select(R.view(9, n, -1), 1, ii, out=gR)
    torch.index_select(sw, 1, jj, out=sa)
    torch.index_select(sv, 1, jj, out=svp)
    torch.index_select(pos, 1, ii, out=posp)
    sl, sab, slb, xb, tp, blk = ws["sl"], ws["sab"], ws["slb"], ws["xb"], ws["tp"], ws["blk"]
    sl.copy_(svp)
    _cross_into(sl, sa, posp, acc=True)
    Rp3 = gR.view(3, 3, *gR.shape[1:])
    _rot_t_into(sab, Rp3, sa)
    _rot_t_into(slb, Rp3, sl)
    wb, dwb, accb = gb[0:3], gb[3:6], gb[6:9]
    torch.mul(slb[0], accb[0], out=blk[0])
    blk[0].addcmul_(slb[1], accb[1]).addcmul_(slb[2], accb[2])
    yh = blk[1:4]
    _cross_into(yh, accb, sab)
    _cross_into(yh, slb, dwb, acc=True)
    _cross_into(tp, wb, slb)
    _cross_into(yh, wb, tp, acc=True)
    _cross_into(xb, sab, wb)
    a, x = sab, xb
    for col, terms in (
        (4, ((a, 0, dwb, 0), (x, 0, wb, 0))),
        (5, ((a, 0, dwb, 1), (a, 1, dwb, 0), (x, 0, wb, 1), (x, 1, wb, 0))),
        (6, ((a, 1, dwb, 1), (x, 1, wb, 1))),
        (7, ((a, 0, dwb, 2), (a, 2, dwb, 0), (x, 0, wb, 2), (x, 2, wb, 0))),
        (8, ((a, 1, dwb, 2), (a, 2, dwb, 1), (x, 1, wb, 2), (x, 2, wb, 1))),
        (9, ((a, 2, dwb, 2), (x, 2, wb, 2))),
    ):
        (l0, i0, r0, k0), *rest = terms
        dst = blk[col]
        torch.mul(l0[i0], r0[k0], out=dst)
        for lt, il, rt, kr in rest:
            dst.addcmul_(lt[il], rt[kr])
    Yt = ws["Yt"]
    Yt.index_copy_(0, plan.rows, blk.view(10 * plan.P, -1))
    for rows, kind in zip(plan.fric_rows, plan.friction, strict=True):
        if kind == "viscous":
            Yt.index_copy_(0, rows, ws["qd"])
        elif kind == "coulomb":
            Yt.index_copy_(0, rows, torch.sign(ws["qd"]))
        elif kind == "armature":
            Yt.index_copy_(0, rows, ws["qdd"])
        else:
            Yt.index_fill_(0, rows, 1.0)


def regressor_fast(
    out: torch.Tensor,
    q: torch.Tensor,
    qd: torch.Tensor,
    qdd: torch.Tensor,
    c: TreeConstants,
    friction: tuple[str, ...],
    *,
    chunk_size: int,
) -> torch.Tensor:
    """`regressor_into` without autograd, chunk by chunk through reused buffers.

    Args:
        out: ``(B, n, n * (10 + len(friction)))``, any content (every entry is written), same
            dtype/device as q; contiguous.
        q, qd, qdd: ``(B, n)``.
        c: the tree's constants in q's dtype and device.
        friction: the friction terms per joint, in the layout's order.
        chunk_size: samples per chunk.

    Returns:
        ``out``.
    """
    B, n = q.shape
    per = 10 + len(friction)
    plan = _Plan(c, per, friction)
    flat = out.view(B, n * n * per)
    ws = None
    with torch.no_grad():
        for s0 in range(0, B, chunk_size):
            e0 = min(B, s0 + chunk_size)
            b = e0 - s0
            if ws is None or ws["Yt"].shape[1] != b:
                ws = _buffers(plan, b, q)
            _fast_chunk(ws, q[s0:e0], qd[s0:e0], qdd[s0:e0], plan, c)
            Yt = ws["Yt"]
            for t0 in range(0, b, _TRANSPOSE_BLOCK):
                t1 = min(b, t0 + _TRANSPOSE_BLOCK)
                flat[s0 + t0 : s0 + t1].copy_(Yt[:, t0:t1].T)
    return out
