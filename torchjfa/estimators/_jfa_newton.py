"""Bayesian JFA's default optimiser: damped Newton steps on the collapsed bound, with prunes.

`run_newton` fits one problem (``method="newton"``); ``_jfa_em.py`` has plain EM, the slow
reference. The bound with Q(z, t) and Q(alpha) optimised out (``docs/theory.md``, eq. 12) is a
smooth function of the coordinates of ``_jfa_model.to_coords`` (each input's ``<w_z>, <w_x>``
and log-variances, and ``log psi_y``: ``(B, P)`` with ``P = r d + 1``). It is a sum of each
input's own terms plus a function of the predictor ``k`` and of ``c`` (eq. 14), so its Hessian
is block-diagonal plus a ``(d + 1) x (d + 1)`` coupling; `newton_step` solves the damped
Newton system through that structure (eq. 15) in ``O(r^3 d + d^3)``. `run_newton` takes
Levenberg-Marquardt steps that raise the bound, and prune moves (``_jfa_prune.py``, eq. 17)
that set an input's ``<w_z>`` (and ``<w_x>``) to the prior's zero, which Newton approaches
only geometrically (eq. 16 has the rules). The step's functions take a batch of ``B``
problems; `run_newton` gives them a batch of one.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch

from .._util import single_thread
from . import _jfa_model as jm
from ._jfa_model import Result, Settings, State, Stats
from ._jfa_prune import prune_trial

_LM_START, _LM_FLOOR, _LM_MAX = 1e-3, 1e-12, 1e12  # damping, relative to |diag H|
_LM_POLISH = 1e-9  # a convergence with more damping than this is re-checked at the floor
_ROUNDOFF = 64 * 2.0**-52  # relative round-off of the bound (a sum of O(d) terms of size O(N))
# a prune trial also follows a kept Newton step that gained at most _PRUNE_GAIN nats a sample,
# at most once in _PRUNE_EVERY Newton iterations (docs/theory.md, eq. 16)
_PRUNE_GAIN = 1e-3
_PRUNE_EVERY = 3


# ------------------------------------------------------------------ gradient and Hessian
class Curvature(NamedTuple):
    """The gradient ``g (B, P)`` and the factored Hessian of eq. 14: ``hb (B, r, r, d)`` each
    input's own block, ``hpsy (B,)`` that of ``log psi_y``; the Jacobian of ``(k, c)``: ``jk,
    jq (B, r, d)`` (``dk_m``, ``dq_m`` on input m's coordinates), ``psy (B,)`` (``dc / d log
    psi_y``); the Hessian of the data term ``h(k, c)``: ``-X^T X / c`` (``dg (B, d)`` its
    diagonal's ``X^T X``, ``c (B,)``), ``gkc (B, d)``, ``gcc (B,)``."""

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


def derivatives(x: torch.Tensor, S: Stats, psx: torch.Tensor, cfg: Settings) -> Curvature:
    """The gradient and factored Hessian of the collapsed bound at ``x (B, P)`` (eq. 14).

    One ``d x d`` matrix-vector product and ``O(r^2 d)`` elementwise work.
    """
    B, P = x.shape
    d = psx.shape[-1]
    r = (P - 1) // d
    c_in = x[:, : r * d].reshape(B, r, d)
    psy = torch.exp(x[:, -1])
    mz, mx = c_in[:, 0], c_in[:, 1]
    vz, vx, psz = torch.exp(c_in[:, 2]), torch.exp(c_in[:, 3]), torch.exp(c_in[:, 4])
    psx = psx if cfg.fixed_x else torch.exp(c_in[:, 5])
    _, _, k, q = jm.data_terms(mz, mx, vz, vx, psz, psx)
    c = psy + q.sum(-1)
    s_xe = S.xy - (S.xx @ k[..., None])[..., 0]
    S_ee = S.yy - (k * (S.xy + s_xe)).sum(-1)
    h_k = s_xe / c[:, None]  # dh / dk, (B, d)
    h_c = -0.5 * S.n / c + 0.5 * S_ee / (c * c)
    h_cc = 0.5 * S.n / (c * c) - S_ee / (c * c * c)
    own = (mz, mx, vz, vx, psz, psx)
    grad, hb, jk, jq = input_curvature(own, h_k, h_c[:, None], S.n[:, None], S.dg, cfg, r)
    g = torch.cat([grad.reshape(B, r * d), (h_c * psy)[:, None]], -1)
    return Curvature(g, hb, h_c * psy, jk, jq, psy, S.dg, c, -s_xe / (c * c)[:, None], h_cc)


def input_curvature(own, h_k, h_c, n, dg, cfg: Settings, r: int):
    """Each input's gradient and Hessian block of ``F_m = f_m + h_k k_m + h_c q_m`` in its ``r``
    coordinates, written out (eq. 14), with the gradients of ``k_m`` and ``q_m``.

    With ``T = kappa v = <w_x>^2 + psi_x + V_z psi_x / psi_z + V_x`` and ``M = -(X^T X)_mm
    kappa / 2 + h_k <w_z><w_x> + h_c <w_z>^2 psi_x``, ``F = -N/2 log T + M / T + h_c psi_z`` plus
    the loading terms (eq. 13); ``T``, ``M``, ``kappa`` and Q(alpha)'s rate are sums of
    monomials in the means and exponentials of the log-variances, so the Hessian is a few
    sparse terms plus two rank-one terms (of ``1 / T`` and of ``log rate``).

    Args:
        own: ``(mz, mx, vz, vx, psz, psx)``, ``(B, d)`` each. h_k: ``(B, d)``. h_c, n:
            ``(B, 1)``. dg: ``(B, d)``. r: 6, or 5 with psi_x fixed.

    Returns:
        ``grad (B, r, d)``, ``hess (B, r, r, d)``, ``jk (B, r, d)``, ``jq (B, r, d)``.
    """
    mz, mx, vz, vx, psz, psx = own
    a, beta = vz / psz, vx / psx
    c1 = a * psx
    iT = 1.0 / (mx * mx + psx + c1 + vx)
    k, q = mz * mx * iT, psz + mz * mz * psx * iT
    hdg, zero = 0.5 * dg, torch.zeros_like(mz)
    M = (h_k * mx + h_c * mz * psx) * mz - hdg * (1.0 + a + beta)
    phi = (0.5 * n + M * iT) * iT  # -dF/dT
    chi = (0.5 * n + 2.0 * M * iT) * iT * iT  # d2F/dT2
    gT = torch.stack([zero, 2.0 * mx, c1, vx, -c1, psx + c1][:r], 1)
    gM = [h_k * mx + 2.0 * h_c * mz * psx, h_k * mz, -hdg * a, -hdg * beta, hdg * a]
    gM = torch.stack((gM + [hdg * beta + h_c * mz * mz * psx])[:r], 1)
    extra = [zero, zero, zero, zero, h_c * psz, zero]  # the gradient beyond -N/2 log T + M / T
    diag = [  # the Hessian's diagonal beyond the rank-one terms
        2.0 * h_c * psx * iT,
        -2.0 * phi,
        -hdg * a * iT - phi * c1,
        -hdg * beta * iT - phi * vx,
        -hdg * a * iT - phi * c1 + h_c * psz,
        (h_c * mz * mz * psx - hdg * beta) * iT - phi * (c1 + psx),
    ]
    off = {  # and off it, (i, j) with i < j
        (0, 1): h_k * iT,
        (0, 5): 2.0 * h_c * mz * psx * iT,
        (2, 4): hdg * a * iT + phi * c1,
        (2, 5): -phi * c1,
        (4, 5): phi * c1,
        (3, 5): hdg * beta * iT,
    }
    p = 0.5 * chi[:, None] * gT - (iT * iT)[:, None] * gM
    hess = gT[:, :, None] * p[:, None] + p[:, :, None] * gT[:, None]
    if cfg.bayes:  # the loading terms (eq. 13): -a log(rate) + (log V_z + log V_x) / 2
        s = 1.0 if cfg.shared_ard else 0.0
        i_rate = 1.0 / jm.optimal_rate(mz, mx, vz, vx, cfg)
        g_rate = torch.stack([mz, s * mx, 0.5 * vz, 0.5 * s * vx, zero, zero][:r], 1)
        rank1 = g_rate * (math.sqrt(cfg.shape) * i_rate)[:, None]
        hess = hess + rank1[:, :, None] * rank1[:, None]
        ai = cfg.shape * i_rate
        lam = 0.0 if cfg.shared_ard else cfg.wx_precision  # w_x's fixed prior
        extra[0] = -ai * mz
        extra[1] = -(ai * s + lam) * mx
        extra[2] = 0.5 - 0.5 * ai * vz
        extra[3] = 0.5 - 0.5 * (ai * s + lam) * vx
        diag[0] = diag[0] - ai
        diag[1] = diag[1] - ai * s - lam
        diag[2] = diag[2] - 0.5 * ai * vz
        diag[3] = diag[3] - 0.5 * (ai * s + lam) * vx
    grad = gM * iT[:, None] - phi[:, None] * gT + torch.stack(extra[:r], 1)
    hess.diagonal(dim1=1, dim2=2).add_(torch.stack(diag[:r], -1))
    for (i, j), h in off.items():
        if j < r:
            hess[:, i, j] += h
            hess[:, j, i] += h
    jk = torch.stack([mx * iT, mz * iT, zero, zero, zero, zero][:r], 1) - (k * iT)[:, None] * gT
    jq = torch.stack([2.0 * mz * psx * iT, zero, zero, zero, psz, mz * mz * psx * iT][:r], 1)
    jq = jq - ((q - psz) * iT)[:, None] * gT
    return grad, hess, jk, jq


def _coupling(cv: Curvature, xx: torch.Tensor) -> torch.Tensor:
    """``W`` of eq. 15: minus the Hessian of ``h(k, c)`` without its ``k``-``k`` diagonal (moved
    into the blocks), ``(B, d + 1, d + 1)``."""
    top = xx / cv.c[:, None, None] - torch.diag_embed(cv.dg / cv.c[:, None])
    top = torch.cat([top, -cv.gkc[..., None]], -1)
    return torch.cat([top, torch.cat([-cv.gkc, -cv.gcc[:, None]], -1)[:, None]], -2)


# ------------------------------------------------------------------------- the Newton step
class Step(NamedTuple):
    """A trial (`newton_step`): ``trial (B, P)`` the coordinates after the step, ``ok (B,)``
    whether the damped matrix was positive definite, ``gain`` its first-order gain ``g . s``,
    ``predicted`` the quadratic model's gain, ``(B,)`` each."""

    trial: torch.Tensor
    ok: torch.Tensor
    gain: torch.Tensor
    predicted: torch.Tensor


def _free_and_damping(x, cv: Curvature, lb):
    """The free coordinates, ``(B, P)`` bool (not at a floor with the gradient pointing below
    it), and Marquardt's scale ``|diag H|`` of the free ones (``1`` elsewhere), ``(B, P)``."""
    free = ~((x <= lb) & (cv.g <= 0))
    B, r, d = cv.jk.shape
    w_kk = (cv.dg / cv.c[:, None])[:, None]
    diag = -torch.diagonal(cv.hb, dim1=1, dim2=2).mT + cv.jk * cv.jk * w_kk
    diag = diag - 2.0 * cv.gkc[:, None] * cv.jk * cv.jq - cv.gcc[:, None, None] * cv.jq * cv.jq
    diag = torch.cat([diag.reshape(B, r * d), (-cv.hpsy - cv.gcc * cv.psy * cv.psy)[:, None]], -1)
    diag = diag.abs() * free
    scale = diag.amax(-1, keepdim=True).clamp_min(1e-300)
    return free, torch.where(free, diag.clamp_min(1e-12 * scale), 1.0)


def block_part(cv: Curvature, free: torch.Tensor, lam_d: torch.Tensor):
    """``A`` of eq. 15 on the free coordinates ``free (B, P)`` with the damping ``lam_d (B,
    P)`` added: each input's ``r x r`` block, ``(B, d, r, r)``, and that of ``log psi_y``,
    ``(B,)``."""
    B, r, d = cv.jk.shape
    fb = free[:, : r * d].reshape(B, r, d)
    jk = cv.jk * fb
    A = -cv.hb + (cv.dg / cv.c[:, None])[:, None, None] * jk[:, :, None] * jk[:, None]
    A = (A * (fb[:, :, None] & fb[:, None])).permute(0, 3, 1, 2)
    A = A + torch.diag_embed(lam_d[:, : r * d].reshape(B, r, d).mT)
    return A, torch.where(free[:, -1], -cv.hpsy, 0.0) + lam_d[:, -1]


def newton_step(x, cv: Curvature, xx, lam, lb) -> Step:
    """The projected, damped Newton step: ``(-H + lam |diag H|) s = g`` on the free
    coordinates (`_free_and_damping`), then ``x + s`` raised to the floors ``lb (P,)``.

    The matrix is ``A + J^T W J`` (eq. 15): ``A`` block-diagonal (each input's ``r x r`` block,
    with the diagonal of the data coupling moved into it), ``J`` the Jacobian of ``(k, c)``.
    With ``J A^{-1} J^T = L L^T`` (``L`` an arrowhead: each ``k_m`` moves with its own input
    only), Woodbury's identity solves it with ``C = I + L^T W L``; where ``A`` is positive
    definite, the whole matrix is iff ``C`` is. ``ok`` is False where ``A`` or ``C`` is not.
    """
    free, damp = _free_and_damping(x, cv, lb)
    B, r, d = cv.jk.shape
    fb, fp = free[:, : r * d].reshape(B, r, d), free[:, -1]
    g, jk, jq, psy = cv.g * free, cv.jk * fb, cv.jq * fb, cv.psy * fp
    A, a_psy = block_part(cv, free, torch.where(free, lam[:, None] * damp, 1.0))
    chol, info = torch.linalg.cholesky_ex(A)
    rhs = torch.stack([g[:, : r * d].reshape(B, r, d), jk, jq], -1).permute(0, 2, 1, 3)
    z, yk, yq = torch.cholesky_solve(rhs, chol).unbind(-1)  # A^-1 (g, J^T), (B, d, r) each
    jk_t, jq_t = jk.mT, jq.mT
    s = torch.sqrt((jk_t * yk).sum(-1).clamp_min(0.0))  # the arrowhead L
    l_c = torch.where(s > 0, (jk_t * yq).sum(-1) / torch.where(s > 0, s, 1.0), 0.0)
    k_cc = (jq_t * yq).sum((-2, -1)) + psy * psy / a_psy
    l_cc = torch.sqrt((k_cc - (l_c * l_c).sum(-1)).clamp_min(0.0))
    # L = diag(s, l_cc) + e_d (l_c, 0)^T: its products in O(d^2), not as dense matrices
    diag_l = torch.cat([s, l_cc[:, None]], -1)  # (B, d + 1)
    row_l = torch.nn.functional.pad(l_c, (0, 1))  # (B, d + 1), row d of L off its diagonal
    b_c = (jq_t * z).sum((-2, -1)) + psy * g[:, -1] / a_psy
    b = torch.cat([(jk_t * z).sum(-1), b_c[:, None]], -1)  # J A^-1 g
    W = _coupling(cv, xx)
    WL = W * diag_l[:, None, :] + W[:, :, d:] * row_l[:, None, :]  # W L

    def lt(v):  # L^T v for v (B, d + 1, k)
        return diag_l[..., None] * v + row_l[..., None] * v[:, d:]

    C = torch.eye(d + 1, dtype=W.dtype, device=W.device) + lt(WL)
    chol_c, info_c = torch.linalg.cholesky_ex(C)
    Wb = (W @ b[..., None])[..., 0]
    u = Wb - (WL @ torch.cholesky_solve(lt(Wb[..., None]), chol_c))[..., 0]
    step_in = z - yk * u[:, :d, None] - yq * u[:, d, None, None]  # (B, d, r)
    d_psy = (g[:, -1] - psy * u[:, d]) / a_psy
    delta = torch.cat([step_in.mT.reshape(B, r * d), d_psy[:, None]], -1)
    ok = (info == 0).all(-1) & (a_psy > 0) & (info_c == 0) & torch.isfinite(delta).all(-1)
    trial = torch.maximum(x + torch.where(ok[:, None], delta, 0.0), lb)
    moved = trial - x
    # the quadratic model's gain g.s - s^T M s / 2, with M s = g - lam D s on the free rows
    pred = 0.5 * ((g * moved).sum(-1) + lam * (damp * moved * moved * free).sum(-1))
    return Step(trial, ok, (g * moved).sum(-1), pred)


def damped_step(x, cv: Curvature, xx, lam, nu, lb):
    """`newton_step` at the first damping of Nielsen's sequence (``lam *= nu``, ``nu *= 2``)
    from ``lam`` at which the matrix is positive definite, or past ``_LM_MAX``:
    ``(Step, lam, nu)``. The blocks ``A`` (eq. 15) are made definite first, alone: their
    Cholesky factors are cheap next to a whole step's."""

    def raise_(bad, lam, nu):
        return torch.where(bad, lam * nu, lam), torch.where(bad, 2.0 * nu, nu)

    free, damp = _free_and_damping(x, cv, lb)
    while True:
        A, a_psy = block_part(cv, free, torch.where(free, lam[:, None] * damp, 1.0))
        definite = (torch.linalg.cholesky_ex(A)[1] == 0).all(-1) & (a_psy > 0)
        bad = ~definite & (lam <= _LM_MAX)
        if not bool(bad.any()):
            break
        lam, nu = raise_(bad, lam, nu)
    while True:  # then the whole matrix
        step = newton_step(x, cv, xx, lam, lb)
        bad = ~step.ok & (lam <= _LM_MAX)
        if not bool(bad.any()):
            return step, lam, nu
        lam, nu = raise_(bad, lam, nu)


# ------------------------------------------------------------------------------ the loop
def run_newton(S: Stats, st: State, cfg: Settings, *, max_iter, tol, coef_tol, bar=None) -> Result:
    """The Newton optimiser with prune moves from ``st`` (eq. 16), on one thread (its kernels
    are small: threads would only wait on each other).

    An iteration is one damped Newton trial or one prune trial; the bound after it is recorded
    (the first record is the bound at ``st``) and never falls. Newton has converged when a kept
    step changes the bound by at most ``tol * max(|L|, N)`` and no coordinate by more than
    ``coef_tol``, when its step's first-order gain is below the bound's round-off, or when no
    damping makes the Newton matrix definite; a convergence with the damping above
    ``_LM_POLISH`` is re-checked once at the floor. Then a prune trial runs: if it gains,
    Newton resumes, else the fit stops (``"bound"``). A prune trial also follows a kept step
    that gained little (``_PRUNE_GAIN``), and Newton goes on if it finds nothing. With ``tol =
    coef_tol = 0`` a fit that stops is at a fixed point of the iteration, recorded up to
    ``max_iter``.

    Args:
        S: one problem's standardised moments (no batch dimension). st: its starting state.
        cfg: the settings. max_iter, tol, coef_tol: the stopping rule.
        bar: an optional progress bar (``update(k)``).
    """
    S, st = Stats(*(t[None] for t in S)), State(*(t[None] for t in st))  # a batch of one
    psx, d = st.psx, st.psx.shape[-1]
    x = jm.to_coords(st, cfg)
    lb = torch.full(x.shape[-1:], -torch.inf, dtype=x.dtype, device=x.device)
    lb[4 * d : (5 if cfg.fixed_x else 6) * d] = torch.log(torch.tensor(cfg.noise_floor))
    lb[-1] = torch.log(torch.tensor(cfg.noise_y_floor))
    lb = torch.minimum(lb, x)  # the start is feasible
    L = jm.coords_bound(x, S, psx, cfg)
    lam, nu = torch.full_like(L, _LM_START), torch.full_like(L, 2.0)
    hist, since = [L], 0
    pruning = scheduled = polished = stop = False  # a prune trial next; after a slow step
    any_tol = tol > 0 or coef_tol > 0
    with single_thread():
        while not stop and len(hist) < max_iter:
            level = torch.maximum(L.abs(), S.n.clamp_min(1.0))
            if pruning:  # eq. 17: Newton resumes after a prune that gains
                x_p, L_p, found = prune_trial(x, S, psx, cfg, tol * level)
                found = bool(found & (L_p > L))
                if found:
                    x, L, polished = x_p, L_p, False
                    lam, nu = torch.full_like(L, _LM_START), torch.full_like(L, 2.0)
                stop = not found and not scheduled
                pruning = scheduled = False
                since = 0
            else:  # a damped Newton trial
                cv = derivatives(x, S, psx, cfg)
                step, lam, nu = damped_step(x, cv, S.xx, lam, nu, lb)
                ok = bool(step.ok)
                L_t = jm.coords_bound(step.trial, S, psx, cfg)
                # a step whose first-order gain the bound cannot resolve is judged by the
                # gradient: kept unless the bound falls by more than its round-off (NaN fails)
                roundoff = _ROUNDOFF * level
                small = ok and bool(step.gain <= roundoff)
                accept = ok and (bool(L_t > L) or (small and bool(L_t >= L - roundoff)))
                dL = (L_t - L).clamp_min(0.0) if accept else torch.zeros_like(L)
                # Nielsen's rule: less damping after a step the quadratic model predicted
                # well, more (and faster each time) after a rejected one
                if accept:
                    rho = dL / step.predicted.clamp_min(1e-300)
                    down = torch.clamp(1.0 - (2.0 * rho - 1.0) ** 3, min=1.0 / 3.0, max=1.0)
                    lam, nu = (lam * down).clamp_min(_LM_FLOOR), torch.full_like(nu, 2.0)
                elif ok and not small:
                    lam, nu = lam * nu, 2.0 * nu
                moved = float((step.trial - x).abs().amax())
                converged = accept and bool(dL <= tol * level) and moved <= coef_tol and any_tol
                converged = converged or (small and (not accept or moved <= coef_tol))
                polish = converged and not polished and bool(lam > _LM_POLISH)
                converged = (converged and not polish) or not ok  # no damping made it definite
                since += 1
                slow = accept and not converged and since >= _PRUNE_EVERY
                slow = slow and bool(dL <= _PRUNE_GAIN * S.n)
                if accept:
                    x, L = step.trial, L_t
                if polish:
                    lam = torch.full_like(lam, _LM_FLOOR)
                pruning, scheduled, polished = converged or slow, slow, polished or polish
            hist.append(L)
            if bar is not None:
                bar.update(1)
    if stop and not any_tol:  # a fixed point: the remaining iterations repeat it
        hist += [L] * (max_iter - len(hist))
    state = State(*(t[0] for t in jm.from_coords(x, psx, cfg)))
    return Result(state, torch.cat(hist), len(hist), int(stop and any_tol))
