"""Plain EM for (Bayesian) JFA from moments, and maximum-likelihood JFA's closed-form optimum.

`run_em` is the reference (``method="em"``): the sweeps of ``docs/theory.md`` (eqs. 3-8), each
raising the bound (eq. 9), at a rate of ``1 - O(1/N)`` along the unidentified directions, so
that it needs thousands of sweeps; `BayesianJFA` fits by default with the Newton optimiser of
``_jfa_newton.py`` instead. `ml_closed_form` is `JFA`'s default (eq. 19). Both fit one
problem, from the state after `_jfa_model.first_sweep`.
"""

from __future__ import annotations

import torch

from . import _jfa_model as jm
from ._jfa_model import Result, Settings, State, Stats


def run_em(S: Stats, st: State, cfg: Settings, *, max_iter, tol, coef_tol, bar=None) -> Result:
    """Plain EM sweeps from ``st`` until the stopping rule holds.

    It stops when a sweep changes the bound by at most ``tol * max(|L|, N)`` (``"bound"``),
    else when ``||delta coef|| <= coef_tol ||coef||`` (``"coef"``), or after ``max_iter``
    recorded bounds (the first is the bound at ``st``).
    """
    es, L = jm.estep(S, st, cfg)
    hist, cf, reason = [L], jm.coef(st, cfg), 0
    while reason == 0 and len(hist) < max_iter:
        st = jm.update(S, st, es, cfg)
        es, L1 = jm.estep(S, st, cfg)
        cf1 = jm.coef(st, cfg)
        if (L1 - L).abs() <= tol * torch.maximum(L1.abs(), S.n.clamp_min(1.0)):
            reason = 1
        elif torch.linalg.vector_norm(cf1 - cf) <= coef_tol * torch.linalg.vector_norm(cf1):
            reason = 2
        hist.append(L1)
        L, cf = L1, cf1
        if bar is not None:
            bar.update(1)
    return Result(st, torch.stack(hist), len(hist), reason)


def ml_closed_form(S: Stats, st: State, cfg: Settings, **em_kw) -> Result:
    """Maximum-likelihood JFA at its optimum (eq. 19) from the state after the first sweep.

    The likelihood sees the state only through ``v = diag(X^T X) / N``, ``k`` = OLS and
    ``c = RSS / N``; of the flat ridge of states with these, the one returned has the noise
    share ``r = psi_x / v`` given (psi_x fixed) or 1/2, lowered where the floors need it, and
    splits what the loadings leave of ``c`` equally between psi_y and sum psi_z. Two bounds
    are recorded: after the first sweep and at the optimum. Where the floors (or a fixed psi_x)
    put that optimum out of reach, `run_em` fits instead (``em_kw``: its stopping rule and
    progress bar).
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
    if bool(ok & (left >= need) & (L1 >= L0)):
        return Result(best, torch.stack([L0, L1]), 2, 1)
    return run_em(S, st, cfg, **em_kw)
