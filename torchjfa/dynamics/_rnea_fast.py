"""The fast path of the regressor (no autograd): `_rnea`'s maths through reused buffers.

The same maths as `torchjfa.dynamics._rnea.regressor_into` with every intermediate written into
buffers that are allocated once per call and reused chunk after chunk (``out=`` and in-place ops
only), the chunk's regressor assembled batch-last in a cache-sized buffer and transposed into
``out`` block by block. Allocating temporaries of a few hundred kB per op (page faults) and the
strided scatter into the batch-first output were most of the time of `regressor_into`.

`RigidBodyModel.regressor` runs this when no input requires grad and the compiled kernel
(`torchjfa.dynamics._codegen`) is not used.
"""

from __future__ import annotations

import torch

from ._rnea import TreeConstants

__all__ = ["regressor_fast"]

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
    torch.sin(q.T, out=ws["s"])
    torch.cos(q.T, out=ws["omc"])
    ws["omc"].neg_().add_(1.0)
    ws["qd"].copy_(qd.T)
    ws["qdd"].copy_(qdd.T)
    for k in range(plan.n):
        if c.revolute[k]:
            _revolute_frame(ws, k, plan, c)
        else:
            _prismatic_frame(ws, k, q, plan, c)
    _motion(ws, plan, c)
    _body_terms(ws)
    _pair_columns(ws, plan)
    _scatter(ws, plan)


def _revolute_frame(ws, k: int, plan: _Plan, c: TreeConstants) -> None:
    """Rotation, origin and Plücker axis (world, about the world origin) of revolute joint k."""
    R, pos, o, M, s, omc = ws["R"], ws["pos"], ws["o"], ws["M"], ws["s"], ws["omc"]
    p = c.parent[k]
    Rk, posk, z = R[:, :, k], pos[:, k], ws["sw"][:, k]
    u, Rp = plan.u[k], (R[:, :, p] if p >= 0 else None)
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
    _cross_into(ws["sv"][:, k], o, z)


def _prismatic_frame(ws, k: int, q, plan: _Plan, c: TreeConstants) -> None:
    """Rotation, origin and axis (world) of prismatic joint k; q ``(b, n)``."""
    R, pos = ws["R"], ws["pos"]
    p = c.parent[k]
    Rk, posk, z = R[:, :, k], pos[:, k], ws["sv"][:, k]
    u, Rp = plan.u[k], (R[:, :, p] if p >= 0 else None)
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


def _motion(ws, plan: _Plan, c: TreeConstants) -> None:
    """Velocities and accelerations at the world origin: sums over the ancestors."""
    sw, sv = ws["sw"], ws["sv"]
    swq, svq, w, v, dw, dv, t1, t2 = (
        ws[k] for k in ("swq", "svq", "w", "v", "dw", "dv", "t1", "t2")
    )
    torch.mul(sw, ws["qd"], out=swq)
    torch.mul(sv, ws["qd"], out=svq)
    for k in range(plan.n):
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
    for k in range(plan.n):
        p = c.parent[k]
        if p < 0:
            dw[:, k].copy_(t1[:, k])
            for m in range(3):
                torch.sub(t2[m, k], g[m], out=dv[m, k])
        else:
            torch.add(dw[:, p], t1[:, k], out=dw[:, k])
            torch.add(dv[:, p], t2[:, k], out=dv[:, k])


def _body_terms(ws) -> None:
    """Each body's velocity, acceleration (gravity in) and origin acceleration, body axes."""
    R, pos, w, v, dw, dv = ws["R"], ws["pos"], ws["w"], ws["v"], ws["dw"], ws["dv"]
    vo, acc, body = ws["vo"], ws["acc"], ws["body"]
    vo.copy_(v)
    _cross_into(vo, w, pos, acc=True)
    acc.copy_(dv)
    _cross_into(acc, dw, pos, acc=True)
    _cross_into(acc, w, vo, acc=True)
    _rot_t_into(body[0:3], R, w)
    _rot_t_into(body[3:6], R, dw)
    _rot_t_into(body[6:9], R, acc)


def _pair_columns(ws, plan: _Plan) -> None:
    """The 10 inertial columns of every (ancestor joint j, body i) pair at once, in ``blk``."""
    n, jj, ii = plan.n, plan.jj, plan.ii
    gb, gR, sa, svp, posp = ws["gb"], ws["gR"], ws["sa"], ws["svp"], ws["posp"]
    torch.index_select(ws["body"], 1, ii, out=gb)
    torch.index_select(ws["R"].view(9, n, -1), 1, ii, out=gR)
    torch.index_select(ws["sw"], 1, jj, out=sa)
    torch.index_select(ws["sv"], 1, jj, out=svp)
    torch.index_select(ws["pos"], 1, ii, out=posp)
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


def _scatter(ws, plan: _Plan) -> None:
    """Write the pairs' columns and the joint (friction) terms into ``ws["Yt"]``."""
    Yt = ws["Yt"]
    Yt.index_copy_(0, plan.rows, ws["blk"].view(10 * plan.P, -1))
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
