"""Plain EM for (Bayesian) JFA from moments, and maximum-likelihood JFA's closed-form optimum.

`run_em` is the reference: the sweeps of ``docs/theory.md`` (eqs. 3-8), each raising the
bound (eq. 9), at a rate of ``1 - O(1/N)`` along the unidentified directions, so that it needs
thousands of sweeps; ``_jfa_newton.py`` has the optimiser `BayesianJFA` uses by default.
`ml_closed_form` is `JFA`'s default (eq. 19). Both take any leading batch shape of problems.
"""

from __future__ import annotations

from typing import NamedTuple

import torch

from . import _jfa_model as jm
from ._jfa_model import Settings, State, Stats

REASONS = ("max_iter", "bound", "coef")


class Result(NamedTuple):
    """A fit of a batch: the final ``state``; ``history (*batch, T)`` the bound after each
    iteration (NaN after a problem stopped); ``n_iter`` and ``reason`` (an index of `REASONS`),
    ``(*batch,)`` int64."""

    state: State
    history: torch.Tensor
    n_iter: torch.Tensor
    reason: torch.Tensor


def first_sweep(S: Stats, psx_fixed: torch.Tensor | None, cfg: Settings) -> State:
    """The state after one sweep from `initial_state` (whose zero variances have no bound)."""
    st = jm.initial_state(S, psx_fixed, cfg)
    return jm.update(S, st, jm.estep(S, st, cfg)[0], cfg)


def full(like: torch.Tensor, value: int) -> torch.Tensor:
    """An int64 tensor of ``like``'s shape and device filled with ``value``."""
    return torch.full(like.shape, value, dtype=torch.int64, device=like.device)


def run_em(S: Stats, st: State, cfg: Settings, *, max_iter, tol, coef_tol, bar=None) -> Result:
    """Plain EM sweeps from ``st`` until each problem's rule holds.

    A problem stops when a sweep changes its bound by at most ``tol * max(|L|, N)``
    (``"bound"``), else when ``||delta coef|| <= coef_tol ||coef||`` (``"coef"``), or after
    ``max_iter`` recorded bounds (the first is the bound at ``st``).
    """
    es, L = jm.estep(S, st, cfg)
    scale = S.n.clamp_min(1.0)
    hist, cf = [L], jm.coef(st, cfg)
    live = torch.ones_like(L, dtype=torch.bool)
    reason, n_iter = full(L, 0), full(L, 1)
    while bool(live.any()) and len(hist) < max_iter:
        st1 = jm.update(S, st, es, cfg)
        es1, L1 = jm.estep(S, st1, cfg)
        cf1 = jm.coef(st1, cfg)
        on_bound = (L1 - L).abs() <= tol * torch.maximum(L1.abs(), scale)
        dc = torch.linalg.vector_norm(cf1 - cf, dim=-1)
        on_coef = dc <= coef_tol * torch.linalg.vector_norm(cf1, dim=-1)
        st, es = jm.where(live, st1, st), jm.where(live, es1, es)
        L, cf = torch.where(live, L1, L), cf1
        hist.append(torch.where(live, L1, torch.nan))
        n_iter = n_iter + live.long()
        reason = torch.where(live & on_bound, 1, torch.where(live & on_coef, 2, reason))
        live = live & ~on_bound & ~on_coef
        if bar is not None:
            bar.update(1)
    return Result(st, torch.stack(hist, -1), n_iter, reason)


def ml_closed_form(S: Stats, st: State, cfg: Settings, **em_kw) -> Result:
    """Maximum-likelihood JFA at its optimum (eq. 19) from the state after the first sweep.

    The likelihood sees the state only through ``v = diag(X^T X) / N``, ``k`` = OLS and
    ``c = RSS / N``; of the flat ridge of states with these, the one returned has the noise
    share ``r = psi_x / v`` given (psi_x fixed) or 1/2, lowered where the floors need it, and
    splits what the loadings leave of ``c`` equally between psi_y and sum psi_z. Two bounds
    are recorded: after the first sweep and at the optimum. A problem whose optimum the floors
    (or a fixed psi_x) put out of reach is fitted by `run_em` (``em_kw``: its stopping rule).
    """
    d = S.xy.shape[-1]
    L0 = jm.estep(S, st, cfg)[1]
    v = S.dg / S.n[..., None]
    evals, evecs = torch.linalg.eigh(S.xx)  # k = OLS, the least-norm one if X^T X is singular
    cut = evals.amax(-1, keepdim=True) * d * torch.finfo(evals.dtype).eps
    inv = torch.where(evals > cut, 1.0 / evals, 0.0)
    k = (evecs @ (inv * (evecs.mT @ S.xy[..., None])[..., 0])[..., None])[..., 0]
    rss = S.yy - 2.0 * (k * S.xy).sum(-1) + (k * (S.xx @ k[..., None])[..., 0]).sum(-1)
    c = rss.clamp_min(0.0) / S.n
    need = max(cfg.noise_y_floor + d * cfg.noise_floor, 2 * d * cfg.noise_floor)
    if cfg.fixed_x:
        r = st.psx / v
    else:  # r / (1 - r) <= t keeps psi_y + sum psi_z >= need (aimed 1e-9 inside it)
        K = (k * k * v).sum(-1).clamp_min(1e-300)
        t = ((c - need * (1.0 + 1e-9)) / K).clamp_min(0.0)
        r = torch.minimum(torch.full_like(v, 0.5), (t / (1.0 + t))[..., None])
    ok = (r > 0).all(-1) & (r < 1).all(-1)
    r = r.clamp(1e-300, 1.0 - 1e-12)
    left = c - (k * k * v * r / (1.0 - r)).sum(-1)  # psi_y + sum psi_z
    psy = torch.clamp(0.5 * left, min=cfg.noise_y_floor)
    mx = torch.sqrt(v * (1.0 - r))
    zero = torch.zeros_like(mx)
    psz = ((left - psy) / d)[..., None].expand_as(mx)
    best = State(k * v / mx, mx, zero, zero, zero, psz, r * v, psy)
    L1 = jm.collapsed_bound(S, *best[:4], psz, r * v, psy, cfg)
    ok = ok & (left >= need) & (L1 >= L0)
    out = Result(best, torch.stack([L0, L1], -1), full(L0, 2), full(L0, 1))
    if bool(ok.all()):
        return out
    em = run_em(S, st, cfg, **em_kw)
    T = em.history.shape[-1]
    hist = torch.nn.functional.pad(out.history, (0, max(T - 2, 0)), value=torch.nan)
    em_hist = torch.nn.functional.pad(em.history, (0, max(2 - T, 0)), value=torch.nan)
    return Result(
        jm.where(ok, best, em.state),
        torch.where(ok[..., None], hist, em_hist),
        torch.where(ok, out.n_iter, em.n_iter),
        torch.where(ok, out.reason, em.reason),
    )
