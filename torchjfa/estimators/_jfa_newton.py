"""One damped Newton step on the collapsed bound of (Bayesian) JFA, through its structure.

The derivatives and the step of ``_jfa_fit.run_newton``: the gradient and the factored Hessian
of `_jfa_bound.reduced_bound` in the packed coordinates of ``_jfa_fit._pack`` (`derivatives`,
`Curvature`), and the projected Levenberg-Marquardt step that solves the Newton system through
that structure (`newton_step`), ``O(d^3)`` for a problem of ``d`` inputs. `dense_hessian` gives
the same Hessian as a dense matrix (the tests' reference).
"""

from __future__ import annotations

from typing import NamedTuple

import torch

from . import _jfa_bound as jb
from ._jfa_bound import Hyper, Stats


class Curvature(NamedTuple):
    """The gradient ``g (B, P)`` of the bound at ``theta (B, P)`` (``P = r d + 1``, see
    ``_jfa_fit._pack``) and its Hessian in factored form ``H = blockdiag(hb, hpsy) + J^T G J``: ``hb
    (B, r, r, d)`` each input's own block, ``hpsy (B,)`` that of ``log psi_y``; ``J`` the
    Jacobian of ``(k, c)``, whose row ``k_m`` is ``jk (B, r, d)`` on input m's coordinates
    and whose row ``c`` is ``jq (B, r, d)`` and ``psy (B,)``; ``G`` the Hessian of
    ``g(k, c) = -N/2 log c - S_ee(k) / (2 c)``: ``-xx / c`` (``xx (B, d, d)`` the moments,
    not held here: ``dg (B, d)`` its diagonal; ``c (B,)``), ``gkc (B, d)``, ``gcc (B,)``."""

    g: torch.Tensor
    hb: torch.Tensor
    hpsy: torch.Tensor
    jk: torch.Tensor
    jq: torch.Tensor
    psy: torch.Tensor
    dg: torch.Tensor
    c: torch.Tensor
    gkc: torch.Tensor
    gcc: torch.Tensor


def derivatives(theta, S: Stats, psx_c, hp: Hyper) -> Curvature:
    """Gradient and factored Hessian (`Curvature`) of the bound at ``theta (B, P)``.

    The bound is ``sum_m f_m(theta_m) + g(k, c)`` where input m's own terms ``f_m``, predictor
    ``k_m`` and share ``q_m`` of ``c = psi_y + sum q`` depend on its coordinates ``theta_m``
    alone. So the Hessian is block-diagonal (each input's Hessian of ``f_m + g_k k_m + g_c
    q_m``, written out in `_jfa_bound.input_curvature`) plus ``J^T (d^2 g) J``. Cost: one
    ``d x d`` mat-vec and ``O(r^2 d)``.
    """
    B, P = theta.shape
    d = S.xy.shape[-1]
    r = (P - 1) // d
    terms = jb.input_terms(theta[:, : r * d].reshape(B, r, d), psx_c, hp)
    psy = torch.exp(theta[:, -1])
    c = psy + terms.q.sum(-1)
    s_xe = S.xy - jb.matvec(S.xx, terms.k)
    S_ee = S.yy - (terms.k * (S.xy + s_xe)).sum(-1)
    g_k = s_xe / c[:, None]  # (B, d)
    g_c = -0.5 * S.n / c + 0.5 * S_ee / (c * c)
    g_cc = 0.5 * S.n / (c * c) - S_ee / (c * c * c)
    grad, hb, jk, jq = jb.input_curvature(terms, g_k, g_c[:, None], S.n, S.dg, hp, r)
    g = torch.cat([grad.reshape(B, r * d), (g_c * psy)[:, None]], -1)
    return Curvature(g, hb, g_c * psy, jk, jq, psy, S.dg, c, -s_xe / (c * c)[:, None], g_cc)


def _jacobian(cv: Curvature) -> torch.Tensor:
    """``J`` of `Curvature` as a dense ``(B, d + 1, P)`` matrix."""
    B, r, d = cv.jk.shape
    Jk = torch.diag_embed(cv.jk).permute(0, 2, 1, 3).reshape(B, d, r * d)  # (m, (t, m))
    Jc = torch.cat([cv.jq.reshape(B, 1, r * d), cv.psy[:, None, None]], -1)
    return torch.cat([torch.nn.functional.pad(Jk, (0, 1)), Jc], -2)


def _coupling(cv: Curvature, xx) -> torch.Tensor:
    """``G`` of `Curvature` with its moments ``xx (B, d, d)``, ``(B, d + 1, d + 1)``."""
    top = torch.cat([-xx / cv.c[:, None, None], cv.gkc[..., None]], -1)
    return torch.cat([top, torch.cat([cv.gkc, cv.gcc[:, None]], -1)[:, None]], -2)


def dense_hessian(cv: Curvature, xx) -> torch.Tensor:
    """The Hessian of `Curvature` (moments ``xx (B, d, d)``) as a dense ``(B, P, P)`` matrix
    (the tests' reference)."""
    B, r, d = cv.jk.shape
    blk = torch.diag_embed(cv.hb).permute(0, 1, 3, 2, 4).reshape(B, r * d, r * d)
    H = torch.nn.functional.pad(blk, (0, 1, 0, 1))
    H[:, -1, -1] = cv.hpsy
    J = _jacobian(cv)
    return H + J.mT @ _coupling(cv, xx) @ J


def _damping(theta, cv: Curvature, lb, hold=None):
    """The free coordinates (``(B, P)`` bool: not held (``hold (B, P)`` bool, or None) and not
    at a lower bound with the gradient pointing below it) and Marquardt's damping ``lam
    diag|H|`` of the free ones, ``(B, P)``."""
    free = ~((theta <= lb) & (cv.g <= 0))
    if hold is not None:
        free = free & ~hold
    B, r, d = cv.jk.shape
    wcc = -cv.gcc[:, None, None]
    dk = -torch.diagonal(cv.hb, dim1=1, dim2=2).mT  # (B, r, d)
    dk = dk + cv.jk * cv.jk * (cv.dg / cv.c[:, None])[:, None]
    dk = dk - 2.0 * cv.gkc[:, None] * cv.jk * cv.jq + wcc * cv.jq * cv.jq
    diag = torch.cat([dk.reshape(B, r * d), (-cv.hpsy - cv.gcc * cv.psy * cv.psy)[:, None]], -1)
    diag = diag.abs() * free
    scale = diag.amax(-1, keepdim=True).clamp_min(1e-300)
    return free, torch.where(free, diag.clamp_min(1e-12 * scale), 1.0)


class _Undamped(NamedTuple):
    """The block part of the Newton matrix before damping (`_undamped`): ``A0 (B, d, r, r)``,
    ``a0_psy (B,)``, ``free, damp (B, P)`` (`_damping`)."""

    A0: torch.Tensor
    a0_psy: torch.Tensor
    free: torch.Tensor
    damp: torch.Tensor

    def take(self, idx: torch.Tensor) -> _Undamped:
        return _Undamped(*(t[idx] for t in self))


def _undamped(theta, cv: Curvature, lb, hold=None) -> _Undamped:
    free, damp = _damping(theta, cv, lb, hold)
    B, r, d = cv.jk.shape
    fb = free[:, : r * d].reshape(B, r, d)
    jk = cv.jk * fb
    w_kk = cv.dg / cv.c[:, None]  # (B, d)
    A0 = (-cv.hb + w_kk[:, None, None] * jk[:, :, None] * jk[:, None, :]) * (
        fb[:, :, None] & fb[:, None, :]
    )
    return _Undamped(A0.permute(0, 3, 1, 2), torch.where(free[:, -1], -cv.hpsy, 0.0), free, damp)


def _damped(base: _Undamped, lam):
    """``(A, a_psy, free, damp, lam_d)`` of `block_part` from its undamped part."""
    A0, a0_psy, free, damp = base
    B, d, r, _ = A0.shape
    lam_d = torch.where(free, lam[:, None] * damp, 1.0)
    A = A0 + torch.diag_embed(lam_d[:, : r * d].reshape(B, r, d).mT)
    return A, a0_psy + lam_d[:, -1], free, damp, lam_d


def block_part(theta, cv: Curvature, lam, lb, hold=None):
    """The block-diagonal part ``A`` of the damped Newton matrix (`newton_step`): ``A (B, d, r,
    r)`` each input's block, ``a_psy (B,)`` that of ``log psi_y``, with ``free (B, P)``,
    ``damp (B, P)`` (`_damping`, ``hold`` the coordinates held) and ``lam_d = lam damp`` on
    the free coordinates."""
    return _damped(_undamped(theta, cv, lb, hold), lam)


class Blocks(NamedTuple):
    """The block part of the damped Newton matrix (`block_part`) with its Cholesky factors:
    ``A (B, d, r, r)``, ``a_psy (B,)``, ``free, damp, lam_d (B, P)``, ``chol (B, d, r, r)``,
    ``info (B, d)`` (0 where a block is positive definite)."""

    A: torch.Tensor
    a_psy: torch.Tensor
    free: torch.Tensor
    damp: torch.Tensor
    lam_d: torch.Tensor
    chol: torch.Tensor
    info: torch.Tensor


def _blocks(base: _Undamped, lam) -> Blocks:
    part = _damped(base, lam)
    return Blocks(*part, *torch.linalg.cholesky_ex(part[0]))


def block_damping(theta, cv: Curvature, lam, nu, lb, lam_max: float, hold=None):
    """Raise the damping by Nielsen's rule (``lam <- lam nu``, ``nu <- 2 nu``) until the block
    part ``A`` of the damped Newton matrix (`block_part`) is positive definite, or ``lam``
    passes ``lam_max``: ``(lam, nu, raises, blocks)``, ``raises (B,)`` the number of raises,
    ``blocks`` (`Blocks`) at the returned ``lam``, for `newton_step`.

    `newton_step` refuses a step whose ``A`` is not positive definite, and the optimiser then
    raises the damping; raising it here first costs one ``r x r`` Cholesky per input and raise
    instead of a refused trial (a ``(d + 1) x (d + 1)`` Cholesky and a bound). On the Fig. 2
    cells (``scripts/bench_fit_cost.py``) such refusals were 44 % of the trials. Only the
    blocks still indefinite are refactored at each raise. ``hold``: the coordinates held
    (`_damping`).
    """
    lam, nu = lam.clone(), nu.clone()
    raises = torch.zeros(lam.shape, dtype=torch.int64, device=lam.device)
    base = _undamped(theta, cv, lb, hold)  # the same at every damping
    blocks = _blocks(base, lam)
    B, d, r, _ = base.A0.shape
    free_b = base.free[:, : r * d].reshape(B, r, d)
    damp_b = base.damp[:, : r * d].reshape(B, r, d)
    # more damping keeps a definite block definite: each raise refactors the blocks that were
    # not, and the problems raised are refactored whole once, at their last damping
    bad_blk, bad_psy = blocks.info != 0, ~(blocks.a_psy > 0)
    while True:
        bad = (bad_blk.any(-1) | bad_psy) & (lam <= lam_max)
        if not bool(bad.any()):
            break
        lam = torch.where(bad, lam * nu, lam)
        nu = torch.where(bad, 2.0 * nu, nu)
        raises = raises + bad.long()
        bi, mi = (bad_blk & bad[:, None]).nonzero(as_tuple=True)
        if bi.numel():
            lam_d = torch.where(free_b[bi, :, mi], lam[bi, None] * damp_b[bi, :, mi], 1.0)
            info = torch.linalg.cholesky_ex(base.A0[bi, mi] + torch.diag_embed(lam_d))[1]
            bad_blk[bi, mi] = info != 0
        a_psy = base.a0_psy + torch.where(base.free[:, -1], lam * base.damp[:, -1], 1.0)
        bad_psy = bad_psy & ~(a_psy > 0)
    raised = raises > 0
    if bool(raised.any()):
        idx = raised.nonzero()[:, 0]
        sub = _blocks(base.take(idx), lam[idx])
        for kept, fresh in zip(blocks, sub, strict=True):
            kept[idx] = fresh
    return lam, nu, raises, blocks


class Step(NamedTuple):
    """A trial of `newton_step`: ``trial (B, P)`` the coordinates after the step, ``ok (B,)``
    whether it was taken, ``gain (B,)`` its first-order gain, ``predicted (B,)`` the quadratic
    model's gain, ``size (B,)`` int64 the order of the dense system factored for each problem
    (at most ``d + 1``: `_order`)."""

    trial: torch.Tensor
    ok: torch.Tensor
    gain: torch.Tensor
    predicted: torch.Tensor
    size: torch.Tensor


_LADDER = 8  # the dense system's order is rounded up to a multiple of this (`_order`)


def _order(n: torch.Tensor, d: int) -> torch.Tensor:
    """The order the dense system of ``n`` coupled rows is factored at: ``n`` rounded up to a
    multiple of `_LADDER`, at most ``d + 1``. A problem's order so depends on its own state
    alone, never on the batch it is fitted in: LAPACK's Cholesky of a matrix padded with
    identity rows rounds otherwise than the unpadded one's, so padding each problem of a batch
    to the largest order would make a batch and a single fit part at round-off; problems of one
    order are factored together (`newton_step`), problem by problem as a single fit would."""
    return torch.clamp((n + _LADDER - 1) // _LADDER * _LADDER, max=d + 1)


def _coupled(kkk: torch.Tensor, n: int) -> torch.Tensor:
    """The rows of the dense system that couple, ``(B, n)``: the inputs whose predictor moves
    (``kkk > 0``), padded up to order ``n`` with the first inputs that do not (whose rows of
    ``C`` are the identity's), then ``d``, the row of ``c``. At the full order ``d + 1``, all
    inputs in their own order (`_capacitance_solve` then copies no entries of ``xx``)."""
    B, d = kkk.shape
    if n == d + 1:
        order = torch.arange(d, device=kkk.device).expand(B, d)
    else:
        order = torch.argsort((~(kkk > 0)).to(torch.int8), dim=-1, stable=True)[:, : n - 1]
    last = torch.full((B, 1), d, dtype=order.dtype, device=order.device)
    return torch.cat([order, last], -1)


def newton_step(
    theta, cv: Curvature, lam, lb, xx, blocks: Blocks | None = None, hold=None, bi=None
) -> Step:
    """The projected, damped Newton step (`Step`).

    Coordinates held (``hold (B, P)`` bool, or None) or at their lower bound with the gradient
    pointing below it stay; the others solve ``(-H + lam diag|H|) delta = g`` (Marquardt's
    scaling); ``ok`` is False where the structured solve below does not prove that matrix
    positive definite (then no step); ``gain = g . delta`` (the first-order gain of the
    step), ``predicted`` the gain of the quadratic model.

    The matrix is ``M = A + J^T W J`` (`Curvature`): ``A`` block-diagonal (each input's
    ``r x r`` block with the diagonal of the ``k``-``k`` coupling, ``(X^T X)_mm / c``
    ``jk jk^T``, moved into it; `block_part`), ``W`` the rest of ``-G``, ``(d + 1) x (d + 1)``.
    With ``K = J A^{-1} J^T = L L^T`` (``L`` lower-triangular arrowhead: ``K``'s ``k``-``k``
    part is diagonal), ``M^{-1} = A^{-1} - A^{-1} J^T (W - W L C^{-1} L^T W) J A^{-1}`` with
    ``C = I + L^T W L`` (Woodbury), and where ``A`` is positive definite, ``M`` is iff ``C`` is
    (the nonzero eigenvalues of ``L^T W L`` are those of ``A^{-1/2} J^T W J A^{-1/2}``): one
    Cholesky of ``r x r`` per input and one of ``C``, ``O(d^3)`` in all. An input whose
    predictor ``k_m`` no free coordinate moves (``jk = 0`` on its free rows: a pruned input,
    whose ``<w_z>`` is held at 0 or whose ``<w_z>`` and ``<w_x>`` are both 0) has a zero row
    in ``L`` and the identity's row in ``C``, and its part of ``u`` below multiplies zero: so
    ``C`` is factored on the rows of the other inputs and of ``c`` alone (`_coupled`, at the
    order `_order` gives, the problems of one order together), ``O(a^3 + r^3 d)`` for ``a``
    inputs left, where most inputs are pruned.
    Where ``A`` is not positive definite the step is refused (``ok`` False) although ``M``
    may be: the optimiser raises the damping until ``A`` is positive definite before it
    calls this (`block_damping`, no trial needed). A dense ``P x P`` Cholesky (``P = r d + 1``)
    to decide those cases would cost about ``P^3 / (6 d^2)`` mat-vecs (2,800 at ``d = 77``),
    two hundred trials' worth. ``blocks``: the block part at this ``lam``, if at hand
    (`block_damping`, with the same ``hold``). ``xx``: the moments, ``(B, d, d)``, or those of
    a whole batch of which ``bi (B,)`` are the problems stepped (not copied).
    """
    if blocks is None:
        blocks = _blocks(_undamped(theta, cv, lb, hold), lam)
    A, a_psy, free, damp, lam_d, chol, info = blocks
    g = cv.g * free
    B, r, d = cv.jk.shape
    fb = free[:, : r * d].reshape(B, r, d)
    fp = free[:, -1]
    jk, jq, psy = cv.jk * fb, cv.jq * fb, cv.psy * fp
    w_kk = cv.dg / cv.c[:, None]  # (B, d)
    rhs = torch.stack([g[:, : r * d].reshape(B, r, d), jk, jq], -1).permute(0, 2, 1, 3)
    z, yk, yq = torch.cholesky_solve(rhs, chol).unbind(-1)  # (B, d, r) each
    jk_t, jq_t = jk.mT, jq.mT  # (B, d, r)
    # K = J A^-1 J^T and b = J A^-1 g
    kkk, kkc = (jk_t * yk).sum(-1), (jk_t * yq).sum(-1)  # (B, d)
    kcc = (jq_t * yq).sum((-2, -1)) + psy * psy / a_psy
    b = torch.cat(
        [(jk_t * z).sum(-1), ((jq_t * z).sum((-2, -1)) + psy * g[:, -1] / a_psy)[:, None]], -1
    )
    s = torch.sqrt(kkk.clamp_min(0.0))
    lc = torch.where(kkk > 0, kkc / torch.where(kkk > 0, s, 1.0), 0.0)
    lcc = torch.sqrt((kcc - (lc * lc).sum(-1)).clamp_min(0.0))
    # the dense system on the coupled rows (`_coupled`), the problems of each order together
    size = _order((kkk > 0).sum(-1) + 1, d)
    u = torch.zeros((B, d + 1), dtype=b.dtype, device=b.device)
    info_c = torch.zeros((B,), dtype=torch.int32, device=b.device)
    for n in sorted(set(size.tolist())):
        rows = jb.Rows(size == n)
        bi_n = rows.idx if bi is None else rows.take(bi)
        G = (xx,) + tuple(rows.take(t) for t in (cv.c, cv.gkc, cv.gcc, w_kk))
        u_n, info_n = _capacitance_solve(
            G, bi_n, _coupled(rows.take(kkk), n), *(rows.take(t) for t in (s, lc, lcc, b))
        )
        rows.put(u, u_n)
        rows.put(info_c, info_n)
    step_in = z - yk * u[:, :d, None] - yq * u[:, d, None, None]  # (B, d, r)
    delta = torch.cat(
        [step_in.mT.reshape(B, r * d), ((g[:, -1] - psy * u[:, d]) / a_psy)[:, None]], -1
    )
    a_pd = (info == 0).all(-1) & (a_psy > 0)
    ok = a_pd & (info_c == 0) & torch.isfinite(delta).all(-1)
    delta = torch.where(ok[..., None], delta, 0.0)
    trial = torch.maximum(theta + delta, lb)
    step = trial - theta
    # the quadratic model's gain g.s - s^T M s / 2, with M s = g - lam D s on the free rows
    pred = 0.5 * ((g * step).sum(-1) + lam * (damp * step * step * free).sum(-1))
    return Step(trial, ok, (g * step).sum(-1), pred, size)


def _capacitance_solve(G, bi, idx, s, lc, lcc, b):
    """The Woodbury part of `newton_step` for the problems ``bi (Bn,)`` of the batch (None:
    all of them), on their coupled rows ``idx (Bn, n)`` (`_coupled`, the last one c's): ``u =
    W b - W L C^{-1} L^T W b`` scattered to ``(Bn, d + 1)``, and the Cholesky's ``info
    (Bn,)``. ``G = (xx, c, gkc, gcc, w_kk)``: ``xx (B, d, d)`` of the whole batch (only the
    coupled entries are copied), the others of these problems. ``W = -G`` (`Curvature`) less
    the diagonal ``w_kk`` moved into the blocks: its ``k``-``k`` part is ``X / c -
    diag(w_kk)`` with ``X`` the coupled rows and columns of ``xx``, its ``k``-``c`` part
    ``kc = -gkc`` and its ``c``-``c`` entry ``wcc = -gcc``. With ``L = diag(sf) + e_c l^T``
    (the arrowhead: ``l = (lc, 0)``, ``sf = (s, lcc)``), ``C = I + L^T W L`` is written out
    on its blocks, the ``k``-``k`` block ``K`` factored and c's row eliminated by its Schur
    complement (``C`` is positive definite iff ``K`` and that complement are), and ``W x``,
    ``L x``, ``L^T x`` cost ``O(n^2)``: a few ``n x n`` passes (a batch's cost is their memory
    traffic) to form ``K``, and two mat-vecs."""
    xx, c, gkc, gcc, w_kk = G
    Bn, n = idx.shape
    d = s.shape[-1]
    ki = idx[:, :-1]
    if bi is not None:
        xx = xx.index_select(0, bi)
    if n == d + 1:  # all inputs, in their order (`_coupled`)
        X = xx
    else:
        X = xx.reshape(Bn, d * d).gather(-1, (ki[:, :, None] * d + ki[:, None, :]).reshape(Bn, -1))
        X = X.reshape(Bn, n - 1, n - 1)
    sk, lk, bk, bc = s.gather(-1, ki), lc.gather(-1, ki), b.gather(-1, ki), b[:, d]
    kc, wk, wcc, ic = -gkc.gather(-1, ki), w_kk.gather(-1, ki), -gcc, 1.0 / c

    def w_times(vk, vc):  # W (vk, vc)
        top = jb.matvec(X, vk) * ic[:, None] - wk * vk + kc * vc[:, None]
        return top, (kc * vk).sum(-1) + wcc * vc

    # C = [[K, e], [e^T, g]]: K factored, c's row by its Schur complement g - e^T K^-1 e
    m = sk * kc + 0.5 * wcc[:, None] * lk
    K = X * sk[:, :, None]
    K.mul_((sk * ic[:, None])[:, None, :])
    K.addcmul_(m[:, :, None], lk[:, None, :]).addcmul_(lk[:, :, None], m[:, None, :])
    K.diagonal(dim1=-2, dim2=-1).add_(1.0 - sk * sk * wk)
    e = lcc[:, None] * (sk * kc + wcc[:, None] * lk)
    chol_k, info_k = torch.linalg.cholesky_ex(K)
    wbk, wbc = w_times(bk, bc)
    rk, rc = sk * wbk + lk * wbc[:, None], lcc * wbc  # L^T W b
    y, z = torch.cholesky_solve(torch.stack([e, rk], -1), chol_k).unbind(-1)
    schur = lcc * lcc * wcc + 1.0 - (e * y).sum(-1)
    xc = (rc - (e * z).sum(-1)) / schur
    xk = z - y * xc[:, None]  # x = C^-1 L^T W b
    info_c = torch.where(info_k != 0, info_k, torch.where(schur > 0, 0, n).to(info_k.dtype))
    wlk, wlc = w_times(sk * xk, lcc * xc + (lk * xk).sum(-1))  # W L x
    u_c = torch.cat([wbk - wlk, (wbc - wlc)[:, None]], -1)
    u = torch.zeros((Bn, d + 1), dtype=u_c.dtype, device=u_c.device).scatter(-1, idx, u_c)
    return u, info_c


def escapes(theta, cv: Curvature, lb, n, level: float) -> torch.Tensor:
    """The inputs whose ``<w_z>`` alone, moved by Newton, would gain more than ``level n``
    nats: ``g^2 / (2 |H|)`` along it (``g`` the gradient, ``|H|`` its Hessian diagonal of
    `_damping`), ``(B, d)`` bool; ``n (B,)`` the samples."""
    d = cv.jk.shape[-1]
    _, diag = _damping(theta, cv, lb)
    gain = cv.g[:, :d] ** 2 / (2.0 * diag[:, :d])
    return gain > level * n[:, None]
