"""Fitting (Bayesian) JFA regression from moments: plain EM, a monotone Newton optimiser of the
bound, and the closed form of maximum-likelihood JFA.

Tensor functions for any leading batch shape of problems (``_jfa_bound.py`` has the model and
the state); `fit` is the entry point. Three methods:

- ``"em"``: the plain (variational) EM sweeps of ``docs/bayesian-jfa.md``. Each iteration costs
  one E-step; along the unidentified ``psi_x / w_x^2`` ridge and the pruning paths its rate is
  ``1 - O(1/N)`` (``docs/bayesian-jfa-fitting.md``), so it crawls. Kept as the reference.
- ``"newton"``: Levenberg-Marquardt-damped Newton steps on the bound with Q(z, t) and Q(alpha)
  optimised out (`_jfa_bound.reduced_bound`), in the coordinates ``<w_z>, <w_x>, log V_z,
  log V_x, log psi_z, log psi_x, log psi_y`` (the floors as bounds of a projected step), with
  the exact Hessian from ``torch.func``. When Newton has converged, the prune move of the
  fitting note is tried on every input at once (``<w_zm> = 0``, and ``<w_xm> = 0`` with
  ``psi_xm = v_m`` when alpha is shared and psi_x free; ``v``, ``tau`` and ``c`` unchanged);
  the improving prunes are kept together (or the best one alone) and Newton resumes. Every
  step, damped or a prune, is kept only if the bound does not fall, so the recorded bound never
  decreases; near the optimum the steps converge quadratically, so the answer does not depend
  on the path to it (the chunking of the data, a batch or a single fit) beyond round-off.
- ``"closed"`` (maximum likelihood only): the likelihood depends on the state only through
  each input's variance ``v = diag(X^T X) / N``, the predictor ``k`` (OLS) and the residual
  variance ``c = RSS / N``, so its maximum is known; the state returned is one point of the
  flat ridge of states with those ``(v, k, c)``.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch

from .._threads import single_thread
from . import _jfa_bound as jb
from ._jfa_bound import MX, MZ, PX, PZ, VX, VZ, Hyper, Stats

REASONS = ("max_iter", "bound", "coef")
_LM_START = 1e-3  # Levenberg-Marquardt damping, relative to the Hessian's diagonal
_LM_MAX = 1e12


class Result(NamedTuple):
    """A fit of a batch: ``st (*batch, 7, d)``, ``psy (*batch,)``, ``history (*batch, T)`` the
    bound after each iteration (NaN after a problem stopped), ``n_iter``, ``reason`` (index in
    `REASONS`), ``n_accepted`` (accepted Newton steps and prunes), ``n_estep`` (E-step
    equivalents, the cost in ``d x d`` mat-vecs: one per bound evaluation and per gradient
    and Hessian, ``(d + 1)^3 / (6 d^2)`` per structured Newton solve, ``P^3 / (6 d^2)`` per
    dense one (a Cholesky's flops over a mat-vec's)), all ``(*batch,)`` int64."""

    st: torch.Tensor
    psy: torch.Tensor
    history: torch.Tensor
    n_iter: torch.Tensor
    reason: torch.Tensor
    n_accepted: torch.Tensor
    n_estep: torch.Tensor


def initial_state(S: Stats, psx_fixed: torch.Tensor | None, hp: Hyper):
    """The note's initialisation in standardised units: ``psi_x = 1/2`` (or the given noise),
    ``<w_x> = sqrt(1 - psi_x)``, ``<w_z> = cov(x, y) / <w_x>``, the leftover variance of y split
    equally between psi_y and sum psi_z, Q(alpha) updated once. Returns ``(st, psy)``."""
    xy, n = S.xy, S.n[..., None]
    d = xy.shape[-1]
    if psx_fixed is None:
        psx = torch.full_like(xy, 0.5)
    else:
        psx = psx_fixed.clamp_min(hp.floor)
    mx = torch.sqrt((1.0 - psx).clamp_min(0.01))
    mz = (xy / n) / mx
    # when the w_z above already explain more than var(y) (correlated inputs), keep 1% of it
    left = (1.0 - (mz * mz).sum(-1)).clamp_min(0.01)
    zero = torch.zeros_like(xy)
    st = torch.stack([mz, mx, zero, zero, zero, (0.5 * left / d)[..., None].expand_as(xy), psx], -2)
    st[..., PZ, :] = st[..., PZ, :].clamp_min(hp.floor)
    if hp.bayes:
        st[..., jb.B, :] = jb.optimal_rate(st, hp)
    return st, (0.5 * left).clamp_min(hp.floor_y)


def coef(st: torch.Tensor, hp: Hyper) -> torch.Tensor:
    """Eq. (4): ``<w_z><w_x> / <w_x^2>`` (0, not 0/0, when pruned); ``w_z / w_x`` for ML."""
    if hp.bayes:
        return st[..., MZ, :] * st[..., MX, :] / (st[..., MX, :] ** 2 + st[..., VX, :])
    return st[..., MZ, :] / st[..., MX, :]


def _first_sweep(S: Stats, st, psy, hp: Hyper):
    """One sweep from the initial state (whose variances are 0, so no bound there)."""
    es, R, c, S_ee, _ = jb.estep(S, st, psy, hp)
    return jb.update(S, es, R, c, S_ee, st, psy, hp)


def fit(
    S: Stats,
    psx_fixed: torch.Tensor | None,
    hp: Hyper,
    *,
    method: str,
    max_iter: int,
    tol: float,
    coef_tol: float,
    bar=None,
) -> Result:
    """Fit a batch of problems from standardised moments (see the module docstring).

    Args:
        S: ``xx (*batch, d, d)``, ``xy (*batch, d)``, ``yy, n (*batch,)``, every column of
            ``X`` and ``y`` scaled to unit variance (``diag(xx) = n``).
        psx_fixed: ``(*batch, d)`` psi_x to hold fixed (standardised), or None.
        hp: the settings; ``hp.fixed_x`` must say whether ``psx_fixed`` is given.
        method: ``"em"``, ``"newton"`` (Bayesian only) or ``"closed"`` (ML only).
        max_iter: iteration cap. tol, coef_tol: the stopping rule (`run_em`, `run_newton`).
        bar: an optional progress bar (``update(k)``, ``set_postfix``).
    """
    st, psy = _first_sweep(S, *initial_state(S, psx_fixed, hp), hp)
    if method == "em":
        return run_em(S, st, psy, hp, max_iter=max_iter, tol=tol, coef_tol=coef_tol, bar=bar)
    if method == "newton" and hp.bayes:
        return run_newton(S, st, psy, hp, max_iter=max_iter, tol=tol, coef_tol=coef_tol, bar=bar)
    if method == "closed" and not hp.bayes:
        return ml_closed_form(S, st, psy, hp, max_iter=max_iter, tol=tol, coef_tol=coef_tol)
    raise ValueError(f"no method {method!r} for {'Bayesian' if hp.bayes else 'ML'} JFA")


def _int(like: torch.Tensor, value: int = 0) -> torch.Tensor:
    return torch.full(like.shape, value, dtype=torch.int64, device=like.device)


def run_em(S: Stats, st, psy, hp: Hyper, *, max_iter, tol, coef_tol, bar=None) -> Result:
    """Plain (variational) EM sweeps from ``(st, psy)``, each problem until its rule holds.

    A problem stops when its bound changes by at most ``tol * max(|L|, N)`` in a sweep
    (``"bound"``), else when ``||delta coef|| <= coef_tol ||coef||`` (``"coef"``), or after
    ``max_iter`` recorded bounds (the first is the bound at ``(st, psy)``).
    """
    const = jb.bound_const(S.n, S.xy.shape[-1], hp)
    scale = S.n.clamp_min(1.0)
    es, R, c, S_ee, L = jb.estep(S, st, psy, hp)
    L = L + const
    hist, cf = [L], coef(st, hp)
    live = torch.ones_like(L, dtype=torch.bool)
    reason, n_iter = _int(L), _int(L, 1)
    while bool(live.any()) and len(hist) < max_iter:
        st1, psy1 = jb.update(S, es, R, c, S_ee, st, psy, hp)
        es1, R1, c1, S1, L1 = jb.estep(S, st1, psy1, hp)
        L1 = L1 + const
        cf1 = coef(st1, hp)
        dL = (L1 - L).abs()
        dc = torch.linalg.vector_norm(cf1 - cf, dim=-1)
        on_bound = dL <= tol * torch.maximum(L1.abs(), scale)
        on_coef = dc <= coef_tol * torch.linalg.vector_norm(cf1, dim=-1)
        keep = live[..., None, None]
        st, es = torch.where(keep, st1, st), torch.where(keep, es1, es)
        psy, R, c = torch.where(live, psy1, psy), torch.where(live, R1, R), torch.where(live, c1, c)
        S_ee, L, cf = torch.where(live, S1, S_ee), torch.where(live, L1, L), cf1
        hist.append(torch.where(live, L1, torch.nan))
        n_iter = n_iter + live.long()
        reason = torch.where(live & on_bound, 1, torch.where(live & on_coef, 2, reason))
        live = live & ~on_bound & ~on_coef
        if bar is not None:
            bar.update(1)
    history = torch.stack(hist, -1)
    return Result(st, psy, history, n_iter, reason, _int(L), n_iter + 1)


# ---------------------------------------------------------------------- the Newton optimiser
def _pack(st: torch.Tensor, psy: torch.Tensor, hp: Hyper) -> torch.Tensor:
    """The free coordinates ``(*batch, P)``: ``<w_z>, <w_x>, log V_z, log V_x, log psi_z``,
    ``log psi_x`` (unless fixed), each ``d`` long, then ``log psi_y``."""
    rows = [st[..., MZ, :], st[..., MX, :]]
    rows += [torch.log(st[..., r, :]) for r in (VZ, VX, PZ) + (() if hp.fixed_x else (PX,))]
    return torch.cat(rows + [torch.log(psy)[..., None]], -1)


def _unpack(theta: torch.Tensor, psx_c: torch.Tensor, hp: Hyper):
    """Inverse of `_pack`: ``(mz, mx, vz, vx, psz, psx, psy)``; psi_x from ``psx_c`` if fixed."""
    d = psx_c.shape[-1]
    mz, mx = theta[..., :d], theta[..., d : 2 * d]
    vz, vx, psz = (torch.exp(theta[..., i * d : (i + 1) * d]) for i in (2, 3, 4))
    psx = psx_c if hp.fixed_x else torch.exp(theta[..., 5 * d : 6 * d])
    return mz, mx, vz, vx, psz, psx, torch.exp(theta[..., -1])


def _state(theta: torch.Tensor, psx_c: torch.Tensor, hp: Hyper):
    """``(st, psy)`` of packed coordinates, Q(alpha)'s rate at its optimum."""
    mz, mx, vz, vx, psz, psx, psy = _unpack(theta, psx_c, hp)
    st = torch.stack([mz, mx, vz, vx, torch.zeros_like(mz), psz, psx], -2)
    st[..., jb.B, :] = jb.optimal_rate(st, hp)
    return st, psy


def _theta_bound(theta, xx, xy, yy, n, psx_c, hp: Hyper) -> torch.Tensor:
    return jb.reduced_bound(Stats(xx, xy, yy, n), *_unpack(theta, psx_c, hp), hp)


class Curvature(NamedTuple):
    """The gradient ``g (B, P)`` of the bound at ``theta (B, P)`` (``P = r d + 1``, see
    `_pack`) and its Hessian in factored form ``H = blockdiag(hb, hpsy) + J^T G J``: ``hb
    (B, r, r, d)`` each input's own block, ``hpsy (B,)`` that of ``log psi_y``; ``J`` the
    Jacobian of ``(k, c)``, whose row ``k_m`` is ``jk (B, r, d)`` on input m's coordinates
    and whose row ``c`` is ``jq (B, r, d)`` and ``psy (B,)``; ``G`` the Hessian of
    ``g(k, c) = -N/2 log c - S_ee(k) / (2 c)``: ``-xx / c`` (``xx (B, d, d)``, ``c (B,)``),
    ``gkc (B, d)``, ``gcc (B,)``."""

    g: torch.Tensor
    hb: torch.Tensor
    hpsy: torch.Tensor
    jk: torch.Tensor
    jq: torch.Tensor
    psy: torch.Tensor
    xx: torch.Tensor
    c: torch.Tensor
    gkc: torch.Tensor
    gcc: torch.Tensor


def _derivatives(theta, S: Stats, psx_c, hp: Hyper) -> Curvature:
    """Gradient and factored Hessian (`Curvature`) of the bound at ``theta (B, P)``.

    The bound is ``sum_m f_m(theta_m) + g(k, c)`` where input m's own terms ``f_m``, predictor
    ``k_m`` and share ``q_m`` of ``c = psi_y + sum q`` depend on its coordinates ``theta_m``
    alone. So the Hessian is block-diagonal (each input's Hessian of ``f_m + g_k k_m + g_c
    q_m``, in second-order forward mode, `_jfa_bound.Jet`) plus ``J^T (d^2 g) J``. Cost: one
    ``d x d`` mat-vec and ``O(r^2 d)``.
    """
    B, P = theta.shape
    d = S.xy.shape[-1]
    r = (P - 1) // d
    own, k, q = jb.input_jets(theta[:, : r * d].reshape(B, r, d), psx_c, S.n, S.dg, hp)
    psy = torch.exp(theta[:, -1])
    c = psy + q.v.sum(-1)
    s_xe = S.xy - (S.xx @ k.v[..., None])[..., 0]
    S_ee = S.yy - (k.v * (S.xy + s_xe)).sum(-1)
    g_k = s_xe / c[:, None]  # (B, d)
    g_c = -0.5 * S.n / c + 0.5 * S_ee / (c * c)
    g_cc = 0.5 * S.n / (c * c) - S_ee / (c * c * c)
    grad = own.g + g_k[:, None] * k.g + g_c[:, None, None] * q.g
    hb = own.h + g_k[:, None, None] * k.h + g_c[:, None, None, None] * q.h
    g = torch.cat([grad.expand(B, r, d).reshape(B, r * d), (g_c * psy)[:, None]], -1)
    return Curvature(
        g,
        hb.expand(B, r, r, d),
        g_c * psy,
        k.g.expand(B, r, d),
        q.g.expand(B, r, d),
        psy,
        S.xx,
        c,
        -s_xe / (c * c)[:, None],
        g_cc,
    )


def _jacobian(cv: Curvature) -> torch.Tensor:
    """``J`` of `Curvature` as a dense ``(B, d + 1, P)`` matrix."""
    B, r, d = cv.jk.shape
    Jk = torch.diag_embed(cv.jk).permute(0, 2, 1, 3).reshape(B, d, r * d)  # (m, (t, m))
    Jc = torch.cat([cv.jq.reshape(B, 1, r * d), cv.psy[:, None, None]], -1)
    return torch.cat([torch.nn.functional.pad(Jk, (0, 1)), Jc], -2)


def _coupling(cv: Curvature) -> torch.Tensor:
    """``G`` of `Curvature`, ``(B, d + 1, d + 1)``."""
    top = torch.cat([-cv.xx / cv.c[:, None, None], cv.gkc[..., None]], -1)
    return torch.cat([top, torch.cat([cv.gkc, cv.gcc[:, None]], -1)[:, None]], -2)


def dense_hessian(cv: Curvature) -> torch.Tensor:
    """The Hessian of `Curvature` as a dense ``(B, P, P)`` matrix (a reference for the tests
    and for `_newton_step` where the structured solve does not apply)."""
    B, r, d = cv.jk.shape
    blk = torch.diag_embed(cv.hb).permute(0, 1, 3, 2, 4).reshape(B, r * d, r * d)
    H = torch.nn.functional.pad(blk, (0, 1, 0, 1))
    H[:, -1, -1] = cv.hpsy
    J = _jacobian(cv)
    return H + J.mT @ _coupling(cv) @ J


def _damping(theta, cv: Curvature, lam, lb):
    """The free coordinates (``(B, P)`` bool: not at a lower bound with the gradient pointing
    below it) and Marquardt's damping ``lam diag|H|`` of the free ones, ``(B, P)``."""
    free = ~((theta <= lb) & (cv.g <= 0))
    B, r, d = cv.jk.shape
    wcc = -cv.gcc[:, None, None]
    dk = -torch.diagonal(cv.hb, dim1=1, dim2=2).mT  # (B, r, d)
    dk = dk + cv.jk * cv.jk * (cv.xx.diagonal(dim1=-2, dim2=-1) / cv.c[:, None])[:, None]
    dk = dk - 2.0 * cv.gkc[:, None] * cv.jk * cv.jq + wcc * cv.jq * cv.jq
    diag = torch.cat([dk.reshape(B, r * d), (-cv.hpsy - cv.gcc * cv.psy * cv.psy)[:, None]], -1)
    diag = diag.abs() * free
    scale = diag.amax(-1, keepdim=True).clamp_min(1e-300)
    return free, torch.where(free, diag.clamp_min(1e-12 * scale), 1.0)


def _newton_step(theta, cv: Curvature, lam, lb):
    """The projected, damped Newton step: ``(theta_trial, ok, gain, predicted, dense)``.

    Coordinates at their lower bound with the gradient pointing below it are held; the others
    solve ``(-H + lam diag|H|) delta = g`` (Marquardt's scaling); ``ok`` is False where that
    matrix is not positive definite; ``gain = g . delta`` (the first-order gain of the step),
    ``predicted`` the gain of the quadratic model.

    The matrix is ``M = A + J^T W J`` (`Curvature`): ``A`` block-diagonal (each input's
    ``r x r`` block with the diagonal of the ``k``-``k`` coupling, ``(X^T X)_mm / c``
    ``jk jk^T``, moved into it), ``W`` the rest of ``-G``, ``(d + 1) x (d + 1)``. With ``K =
    J A^{-1} J^T = L L^T`` (``L`` lower-triangular arrowhead: ``K``'s ``k``-``k`` part is
    diagonal), ``M^{-1} = A^{-1} - A^{-1} J^T (W - W L C^{-1} L^T W) J A^{-1}`` with ``C = I
    + L^T W L`` (Woodbury), and where ``A`` is positive definite, ``M`` is iff ``C`` is (the
    nonzero eigenvalues of ``L^T W L`` are those of ``A^{-1/2} J^T W J A^{-1/2}``): one
    Cholesky of ``r x r`` per input and one of ``(d + 1) x (d + 1)``, ``O(d^3)`` in all.
    Where ``A`` is not positive definite, the eigenvector ``x`` of each input's lowest block
    eigenvalue (and the ``log psi_y`` axis) is tried: ``x^T M x <= 0`` proves ``M`` indefinite
    (``x^T M x`` needs only ``J x``, two numbers per input). Problems without such proof take the
    dense ``P x P`` solve (``dense``, ``(B,)`` bool, says which).
    """
    free, damp = _damping(theta, cv, lam, lb)
    g = cv.g * free
    B, r, d = cv.jk.shape
    fb = free[:, : r * d].reshape(B, r, d)
    fp = free[:, -1]
    jk, jq, psy = cv.jk * fb, cv.jq * fb, cv.psy * fp
    w_kk = cv.xx.diagonal(dim1=-2, dim2=-1) / cv.c[:, None]  # (B, d)
    A = (-cv.hb + w_kk[:, None, None] * jk[:, :, None] * jk[:, None, :]) * (
        fb[:, :, None] & fb[:, None, :]
    )
    lam_d = torch.where(free, lam[:, None] * damp, 1.0)
    A = A.permute(0, 3, 1, 2) + torch.diag_embed(lam_d[:, : r * d].reshape(B, r, d).mT)
    a_psy = torch.where(fp, -cv.hpsy, 0.0) + lam_d[:, -1]  # (B,)
    chol, info = torch.linalg.cholesky_ex(A)  # (B, d, r, r)
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
    Lm = torch.diag_embed(torch.cat([s, lcc[:, None]], -1))
    Lm[:, d, :d] = lc
    W = -_coupling(cv)
    W.diagonal(dim1=-2, dim2=-1)[:, :d] -= w_kk
    C = Lm.mT @ W @ Lm
    C.diagonal(dim1=-2, dim2=-1).add_(1.0)
    chol_c, info_c = torch.linalg.cholesky_ex(C)
    Wb = (W @ b[..., None])[..., 0]
    u = Wb - (W @ (Lm @ torch.cholesky_solve((Lm.mT @ Wb[..., None]), chol_c)))[..., 0]
    step_in = z - yk * u[:, :d, None] - yq * u[:, d, None, None]  # (B, d, r)
    delta = torch.cat(
        [step_in.mT.reshape(B, r * d), ((g[:, -1] - psy * u[:, d]) / a_psy)[:, None]], -1
    )
    a_pd = (info == 0).all(-1) & (a_psy > 0)
    ok = a_pd & (info_c == 0) & torch.isfinite(delta).all(-1)
    finite = torch.isfinite(A).all((-3, -2, -1)) & torch.isfinite(W).all((-2, -1))
    dense = ~a_pd & finite  # (not finite: no step)
    if bool(dense.any()):  # x^T M x <= 0 for a block's lowest eigenvector: M is not p.d.
        evals, evecs = torch.linalg.eigh(torch.where(finite[:, None, None, None], A, 0.0))
        x = evecs[..., 0]  # (B, d, r)
        a, c = (jk_t * x).sum(-1), (jq_t * x).sum(-1)
        w_kc, w_cc = W[:, :d, d], W[:, d, d]
        curv = evals[..., 0] + 2.0 * w_kc * a * c + w_cc[:, None] * c * c
        indefinite = (curv <= 0).any(-1) | (a_psy + w_cc * psy * psy <= 0)
        dense = dense & ~indefinite
    if bool(dense.any()):  # the dense solve decides the rest
        idx = dense.nonzero()[:, 0]
        sub = Curvature(*(t[idx] for t in cv))
        M = -dense_hessian(sub) * (free[idx, :, None] & free[idx, None, :])
        M = M + torch.diag_embed(lam_d[idx])
        chol_m, info_m = torch.linalg.cholesky_ex(M)
        delta[idx] = torch.cholesky_solve(g[idx, :, None], chol_m)[..., 0]
        ok[idx] = (info_m == 0) & torch.isfinite(delta[idx]).all(-1)
    delta = torch.where(ok[..., None], delta, 0.0)
    trial = torch.maximum(theta + delta, lb)
    step = trial - theta
    # the quadratic model's gain g.s - s^T M s / 2, with M s = g - lam D s on the free rows
    pred = 0.5 * ((g * step).sum(-1) + lam * (damp * step * step * free).sum(-1))
    return trial, ok, (g * step).sum(-1), pred, dense


def _prune_trial(theta, S: Stats, psx_c, hp: Hyper, thr):
    """The prune move on every input (module docstring): ``(theta_trial, L_trial, any)``.

    Each candidate keeps ``v``, ``tau`` and ``c``, so its gain is the change of ``S_ee`` and of
    its own KL terms; the candidates that gain more than ``thr`` are tried together and the
    best alone, and the better of the two is returned (``any``: some candidate gained).
    """
    mz, mx, vz, vx, psz, psx, psy = _unpack(theta, psx_c, hp)
    tau = 1.0 + vz / psz + vx / psx
    v = mx * mx / tau + psx
    k = mz * mx / (tau * v)
    q = psz + mz * mz * psx / (tau * v)
    c = psy + q.sum(-1)
    s_xe = S.xy - (S.xx @ k[..., None])[..., 0]
    both = hp.shared and not hp.fixed_x  # prune w_x too (psi_x takes v), else w_z alone
    zero = torch.zeros_like(mz)
    new = {"mz": zero, "psz": q, "vz": vz * q / psz}
    new.update(
        {"mx": zero, "psx": v, "vx": vx * v / psx} if both else {"mx": mx, "psx": psx, "vx": vx}
    )
    gain = -(2.0 * k * s_xe + k * k * S.dg) / (2.0 * c[..., None])
    gain = gain + jb.kl_terms(new["mz"], new["mx"], new["vz"], new["vx"], hp)
    gain = gain - jb.kl_terms(mz, mx, vz, vx, hp)
    good = gain > thr[..., None]
    best = torch.nn.functional.one_hot(gain.argmax(-1), gain.shape[-1]).bool() & good
    trials, bounds = [], []
    for pick in (good, best):
        cols = {"mz": mz, "mx": mx, "vz": vz, "vx": vx, "psz": psz, "psx": psx}
        cols = {key: torch.where(pick, new[key], val) for key, val in cols.items()}
        st = torch.stack([cols[r] for r in ("mz", "mx", "vz", "vx", "psz", "psx")], -2)
        st = torch.cat([st[..., :4, :], torch.zeros_like(st[..., :1, :]), st[..., 4:, :]], -2)
        th = _pack(st, psy, hp)
        trials.append(th)
        bounds.append(_theta_bound(th, *S, psx_c, hp))
    first = bounds[0] >= bounds[1]
    return (
        torch.where(first[..., None], trials[0], trials[1]),
        torch.where(first, bounds[0], bounds[1]),
        good.any(-1),
    )


def run_newton(S: Stats, st, psy, hp: Hyper, *, max_iter, tol, coef_tol, bar=None) -> Result:
    """`_run_newton` on one thread (`torchjfa._threads.single_thread`): the optimiser's kernels
    are small (``r x r`` blocks, ``(d + 1) x (d + 1)`` matrices); on a busy 2-core machine,
    MKL's two threads took 1.9 s of Cholesky calls in a d = 8 fit that one thread does in
    0.01 s."""
    with single_thread():
        return _run_newton(S, st, psy, hp, max_iter=max_iter, tol=tol, coef_tol=coef_tol, bar=bar)


def _run_newton(S: Stats, st, psy, hp: Hyper, *, max_iter, tol, coef_tol, bar=None) -> Result:
    """The monotone Newton optimiser with prune moves (module docstring) from ``(st, psy)``.

    An iteration is one damped Newton trial or one prune trial, and the bound after it is
    recorded (the first record is the bound at ``(st, psy)``); a trial is kept only if the
    bound rises. Newton has converged when a kept step changes the bound by at most
    ``tol * max(|L|, N)`` and no coordinate by more than ``coef_tol`` (means in standardised
    units, log-variances), or when the next step's first-order gain is at round-off level, or
    when no damping finds an ascent; then the prune trial runs, and the problem stops
    (``"bound"``) when no prune gains. With ``tol = coef_tol = 0`` it runs ``max_iter``
    iterations: once a whole cycle left the state as it was (a fixed point of the iteration),
    the remaining ones repeat it and are recorded without being recomputed.
    """
    batch, d = S.xy.shape[:-1], S.xy.shape[-1]
    flat = Stats(*(t.reshape(-1, *t.shape[len(batch) :]) for t in S))
    psx_c = st[..., PX, :].reshape(-1, d)
    theta = _pack(st.reshape(-1, 7, d), psy.reshape(-1), hp)
    B, P = theta.shape
    lb = torch.full((P,), -torch.inf, dtype=theta.dtype, device=theta.device)
    lb[4 * d : (5 if hp.fixed_x else 6) * d] = torch.log(torch.tensor(hp.floor))
    lb[-1] = torch.log(torch.tensor(hp.floor_y))
    lb = torch.minimum(lb, theta)  # the start is feasible (floors are clamps of the updates)
    stops = tol > 0 or coef_tol > 0
    scale = flat.n.clamp_min(1.0)
    L = _theta_bound(theta, *flat, psx_c, hp)
    cv = None
    stale = torch.ones(B, dtype=torch.bool, device=theta.device)
    lam, nu = torch.full_like(L, _LM_START), torch.full_like(L, 2.0)
    live, settled, fixed = torch.ones_like(stale), torch.zeros_like(stale), torch.zeros_like(stale)
    reason, n_iter, n_acc, n_estep = _int(L), _int(L, 1), _int(L), _int(L, 1)
    solve_cost, dense_cost = (math.ceil(m**3 / (6 * d * d)) for m in (d + 1, P))
    hist = [L]
    while bool(live.any()) and len(hist) < max_iter:
        was_live = live
        newton, pruning = live & ~settled, live & settled
        need = newton & stale
        if bool(need.any()):
            idx = need.nonzero()[:, 0]
            sub = Stats(*(t[idx] for t in flat))
            new = _derivatives(theta[idx], sub, psx_c[idx], hp)
            if cv is None:  # the first iteration differentiates every problem
                cv = Curvature(*(t.contiguous() for t in new))
            else:
                for kept, fresh in zip(cv, new, strict=True):
                    kept[idx] = fresh
            stale = stale & ~need
            n_estep = n_estep + need.long()
        thr = tol * torch.maximum(L.abs(), scale)
        th_t, L_t = theta, L
        accept = torch.zeros_like(live)
        tiny = torch.zeros_like(live)
        if bool(newton.any()):
            th_n, ok, gain, pred, dense = _newton_step(theta, cv, lam, lb)
            n_estep = n_estep + newton.long() * torch.where(dense, dense_cost, solve_cost)
            L_n = _theta_bound(th_n, *flat, psx_c, hp)
            tiny = newton & ok & (gain <= 1e-15 * torch.maximum(L.abs(), scale))
            accept = newton & ok & ~tiny & (L_n > L)  # NaN fails
            th_t = torch.where(newton[..., None], th_n, th_t)
            L_t = torch.where(newton, L_n, L_t)
            n_estep = n_estep + newton.long()
        found = torch.zeros_like(live)
        if bool(pruning.any()):
            th_p, L_p, found = _prune_trial(theta, flat, psx_c, hp, thr)
            found = pruning & found & (L_p > L)
            accept = accept | found
            th_t = torch.where(pruning[..., None], th_p, th_t)
            L_t = torch.where(pruning, L_p, L_t)
            n_estep = n_estep + pruning.long() * 3
        dL, dth = L_t - L, (th_t - theta).abs().amax(-1)
        theta = torch.where(accept[..., None], th_t, theta)
        L = torch.where(accept, L_t, L)
        stale = stale | accept
        n_acc = n_acc + accept.long()
        # Levenberg-Marquardt damping, Nielsen's rule: less after a kept step the quadratic
        # model predicted well, more (and faster each time) after a rejected one
        rejected = newton & ~accept & ~tiny
        if bool(newton.any()):
            rho = dL / pred.clamp_min(1e-300)
            down = torch.clamp(1.0 - (2.0 * rho - 1.0) ** 3, min=1.0 / 3.0, max=1.0)
            lam = torch.where(newton & accept, (lam * down).clamp_min(1e-12), lam)
        lam = torch.where(rejected, lam * nu, lam)
        nu = torch.where(rejected, 2.0 * nu, torch.where(newton & accept, 2.0, nu))
        converged = newton & accept & (dL <= thr) & (dth <= coef_tol) & stops
        stuck = rejected & (lam > _LM_MAX)  # no damping finds an ascent: stationary
        failed = pruning & ~found  # no prune gains: the optimum
        settled = (settled & ~pruning) | tiny | converged | stuck
        lam = torch.where(found | stuck | failed | tiny, _LM_START, lam)
        if stops:
            reason = torch.where(failed, 1, reason)
        else:  # a cycle that ends in a failed prune left the state unchanged: a fixed point
            fixed = fixed | failed
        live = live & ~failed
        n_iter = n_iter + was_live.long()
        hist.append(torch.where(was_live, L, torch.nan))
        if bar is not None:
            bar.update(1)
            bar.set_postfix(bound=f"{float(L.max()):.10g}")
    if bool(fixed.any()):  # the remaining iterations of a fixed point repeat it
        rest = max_iter - len(hist)
        hist = [torch.where(fixed & torch.isnan(h), L, h) for h in hist]
        hist += [torch.where(fixed, L, torch.nan)] * rest
        n_iter = torch.where(fixed, max_iter, n_iter)
        if bar is not None:
            bar.update(rest)
    st, psy = _state(theta, psx_c, hp)
    out = Result(st, psy, torch.stack(hist, -1), n_iter, reason, n_acc, n_estep)
    return Result(*(t.reshape(batch + t.shape[1:]) for t in out))


# ------------------------------------------------------------ maximum likelihood, closed form
def ml_closed_form(S: Stats, st, psy, hp: Hyper, *, max_iter, tol, coef_tol) -> Result:
    """Maximum-likelihood JFA at its optimum ``v = diag(X^T X) / N``, ``k`` = OLS,
    ``c = RSS / N`` (``docs/bayesian-jfa-fitting.md``), from the state after the first sweep.

    The point returned on the flat ridge of states with those ``(v, k, c)``: the noise share
    ``r = psi_x / v`` is the given one (psi_x fixed) or 1/2 (the initialisation's), lowered
    where the floors need it; of ``c``, what the loadings do not explain is split equally
    between psi_y and sum psi_z. Two bounds are recorded: at the first sweep and at the
    optimum. Problems whose optimum the floors or a fixed psi_x at or above a column's
    variance make unreachable are fitted by plain EM instead (`run_em`).
    """
    d = S.xy.shape[-1]
    es, R, c0, S0, L0 = jb.estep(S, st, psy, hp)
    L0 = L0 + jb.bound_const(S.n, d, hp)
    n = S.n[..., None]
    v = S.dg / n
    evals, evecs = torch.linalg.eigh(S.xx)  # k = OLS, the minimum-norm one if X^T X is singular
    cut = evals.amax(-1, keepdim=True) * d * torch.finfo(evals.dtype).eps
    inv = torch.where(evals > cut, 1.0 / evals, 0.0)
    k = (evecs @ (inv * (evecs.mT @ S.xy[..., None])[..., 0])[..., None])[..., 0]
    rss = S.yy - 2.0 * (k * S.xy).sum(-1) + (k * (S.xx @ k[..., None])[..., 0]).sum(-1)
    c = rss.clamp_min(0.0) / S.n
    need = max(hp.floor_y + d * hp.floor, 2 * d * hp.floor) * (1.0 + 1e-9)
    K = (k * k * v).sum(-1)
    if hp.fixed_x:
        r = st[..., PX, :] / v
    else:  # r / (1 - r) <= t keeps c - sum k^2 v r / (1 - r) >= need
        t = ((c - need) / K.clamp_min(1e-300)).clamp_min(0.0)
        r = torch.minimum(torch.full_like(v, 0.5), (t / (1.0 + t))[..., None])
    ok = (r > 0).all(-1) & (r < 1).all(-1)
    r = r.clamp(1e-300, 1.0 - 1e-12)
    left = c - (k * k * v * r / (1.0 - r)).sum(-1)  # psi_y + sum psi_z
    ok = ok & (left >= need)
    psy1 = torch.maximum(0.5 * left, torch.full_like(left, hp.floor_y))
    mx = torch.sqrt(v * (1.0 - r))
    mz = k * v / mx
    psz = ((left - psy1) / d)[..., None].expand_as(mz)
    zero = torch.zeros_like(mz)
    st1 = torch.stack([mz, mx, zero, zero, zero, psz, r * v], -2)
    L1 = jb.reduced_bound(S, mz, mx, zero, zero, psz, r * v, psy1, hp)
    ok = ok & (L1 >= L0)
    two = _int(L0, 2)
    out = Result(st1, psy1, torch.stack([L0, L1], -1), two, _int(L0, 1), _int(L0), two + 1)
    if bool(ok.all()):
        return out
    em = run_em(S, st, psy, hp, max_iter=max_iter, tol=tol, coef_tol=coef_tol)
    T = max(2, em.history.shape[-1])
    pad = [
        torch.nn.functional.pad(h, (0, T - h.shape[-1]), value=torch.nan)
        for h in (out.history, em.history)
    ]
    parts = [out._replace(history=pad[0]), em._replace(history=pad[1])]
    return Result(
        *(
            torch.where(ok.reshape(ok.shape + (1,) * (a.ndim - ok.ndim)), a, b)
            for a, b in zip(*parts, strict=True)
        )
    )
