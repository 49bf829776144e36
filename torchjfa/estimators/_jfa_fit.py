"""Fitting (Bayesian) JFA from standardised moments: `fit` picks the method, `run_newton` is
Bayesian JFA's default optimiser.

- ``"em"``: plain EM (``_jfa_em.run_em``), the reference of ``docs/theory.md``.
- ``"newton"`` (Bayesian): `run_newton`, damped Newton steps on the collapsed bound
  (``_jfa_newton.py``) and prune moves (``_jfa_prune.py``), every move kept only if the bound
  rises (eq. 16).
- ``"closed_form"`` (maximum likelihood): ``_jfa_em.ml_closed_form`` (eq. 19).

All take a batch of problems, ``(*batch, d, d)`` moments. A batch follows each problem's path
as its single fit does, up to round-off; where the bound has several optima that round-off can
send a batch and a single fit to different ones (the docs, "Batches and optima").
"""

from __future__ import annotations

from typing import NamedTuple

import torch

from .._util import single_thread
from . import _jfa_newton as jn
from ._jfa_em import Result, first_sweep, full, ml_closed_form, run_em
from ._jfa_model import Settings, State, Stats
from ._jfa_prune import prune_trial


def fit(
    S: Stats, psx_fixed, cfg: Settings, *, method: str, max_iter, tol, coef_tol, bar=None
) -> Result:
    """Fit a batch of problems from standardised moments (``diag(xx) = n``).

    Args:
        S: ``xx (*batch, d, d)``, ``xy (*batch, d)``, ``yy, n (*batch,)``.
        psx_fixed: ``(*batch, d)`` psi_x to hold fixed (standardised), or None
            (``cfg.fixed_x`` says which).
        cfg: the settings. method: ``"em"``, ``"newton"`` or ``"closed_form"``.
        max_iter, tol, coef_tol: the stopping rule (`run_em`, `run_newton`).
        bar: an optional progress bar (``update(k)``).
    """
    st = first_sweep(S, psx_fixed, cfg)
    kw = {"max_iter": max_iter, "tol": tol, "coef_tol": coef_tol}
    if method == "em":
        return run_em(S, st, cfg, bar=bar, **kw)
    if method == "newton" and cfg.bayes:
        return run_newton(S, st, cfg, bar=bar, **kw)
    if method == "closed_form" and not cfg.bayes:
        return ml_closed_form(S, st, cfg, **kw)
    raise ValueError(f"no method {method!r} for {'Bayesian' if cfg.bayes else 'ML'} JFA")


class _Run(NamedTuple):
    """The optimiser's per-problem state, ``(B,)`` each but ``x (B, P)``: the coordinates,
    their bound, the damping ``lam, nu``; whether the problem is ``live``, has a prune trial
    next (``pruning``; ``scheduled`` if it follows a slow step, not a convergence), went to the
    damping floor since its last prune (``polished``); Newton iterations ``since`` the last
    prune trial; ``fixed``: stopped at a fixed point with no tolerance given."""

    x: torch.Tensor
    L: torch.Tensor
    lam: torch.Tensor
    nu: torch.Tensor
    live: torch.Tensor
    pruning: torch.Tensor
    scheduled: torch.Tensor
    polished: torch.Tensor
    since: torch.Tensor
    fixed: torch.Tensor


def run_newton(S: Stats, st: State, cfg: Settings, *, max_iter, tol, coef_tol, bar=None):
    """The Newton optimiser with prune moves from ``st`` (eq. 16), on one thread (its kernels
    are small: threads would only wait on each other).

    An iteration is one damped Newton trial or one prune trial; the bound after it is recorded
    (the first record is the bound at ``st``) and never falls. Newton has converged when a kept
    step changes the bound by at most ``tol * max(|L|, N)`` and no coordinate by more than
    ``coef_tol``, when its step's first-order gain is below the bound's round-off, or when no
    damping makes the Newton matrix definite; a convergence with the damping above
    ``_LM_POLISH`` is re-checked once at the floor. Then a prune trial runs: if it gains,
    Newton resumes, else the problem stops (``"bound"``). A prune trial also follows a kept step
    that gained little (``_PRUNE_GAIN``), and Newton goes on if it finds nothing. With ``tol =
    coef_tol = 0`` a problem that stops is at a fixed point of the iteration, recorded up to
    ``max_iter``.
    """
    batch = S.xy.shape[:-1]
    flat = Stats(*(t.reshape(-1, *t.shape[len(batch) :]) for t in S))
    st = State(*(t.reshape(-1, *t.shape[len(batch) :]) for t in st))
    with single_thread():
        res = _newton_loop(flat, st, cfg, max_iter=max_iter, tol=tol, coef_tol=coef_tol, bar=bar)
    return Result(
        State(*(t.reshape(batch + t.shape[1:]) for t in res.state)),
        *(t.reshape(batch + t.shape[1:]) for t in res[1:]),
    )


def _newton_loop(S: Stats, st: State, cfg: Settings, *, max_iter, tol, coef_tol, bar) -> Result:
    psx, d = st.psx, st.psx.shape[-1]
    x = jn.to_coords(st, cfg)
    lb = torch.full(x.shape[-1:], -torch.inf, dtype=x.dtype, device=x.device)
    lb[4 * d : (5 if cfg.fixed_x else 6) * d] = torch.log(torch.tensor(cfg.noise_floor))
    lb[-1] = torch.log(torch.tensor(cfg.noise_y_floor))
    lb = torch.minimum(lb, x)  # the start is feasible
    L = jn.coords_bound(x, S, psx, cfg)
    no = torch.zeros_like(L, dtype=torch.bool)
    run = _Run(x, L, torch.full_like(L, jn._LM_START), torch.full_like(L, 2.0), ~no, no, no, no,
               full(L, 0), no)  # fmt: skip
    reason, n_iter, hist = full(L, 0), full(L, 1), [L]
    stops = tol > 0 or coef_tol > 0
    while bool(run.live.any()) and len(hist) < max_iter:
        level = torch.maximum(run.L.abs(), S.n.clamp_min(1.0))
        newton, pruning = run.live & ~run.pruning, run.live & run.pruning
        if bool(newton.any()):  # each on its own problems: a batch's finished ones cost nothing
            i = _indices(newton)
            sub = (_rows(run, i), _rows(S, i), _rows(psx, i), cfg, _rows(lb, i), _rows(level, i))
            run = _merge(run, i, _newton_iteration(*sub, tol, coef_tol, stops))
        if bool(pruning.any()):
            i = _indices(pruning)
            sub = (_rows(run, i), _rows(S, i), _rows(psx, i), cfg, tol * _rows(level, i))
            run = _merge(run, i, _prune_iteration(*sub, stops))
        stopped = pruning & ~run.live & ~run.fixed
        reason = torch.where(stopped, 1, reason)
        n_iter = n_iter + (newton | pruning).long()
        hist.append(torch.where(newton | pruning, run.L, torch.nan))
        if bar is not None:
            bar.update(1)
    if bool(run.fixed.any()):  # a fixed point: the remaining iterations repeat it
        hist = [torch.where(run.fixed & torch.isnan(h), run.L, h) for h in hist]
        hist += [torch.where(run.fixed, run.L, torch.nan)] * (max_iter - len(hist))
        n_iter = torch.where(run.fixed, max_iter, n_iter)
    return Result(jn.from_coords(run.x, psx, cfg), torch.stack(hist, -1), n_iter, reason)


def _indices(mask: torch.Tensor) -> torch.Tensor | None:
    """The problems of ``mask (B,)``, None for all of them (no copies in a single fit)."""
    return None if bool(mask.all()) else mask.nonzero()[:, 0]


def _rows(t, idx: torch.Tensor | None):
    """The problems ``idx`` of a tensor or of a tuple of tensors."""
    if idx is None:
        return t
    if isinstance(t, torch.Tensor):
        return t.index_select(0, idx)
    return type(t)(*(f.index_select(0, idx) for f in t))


def _merge(run: _Run, idx: torch.Tensor | None, sub: _Run) -> _Run:
    """``run`` with the problems ``idx`` replaced by ``sub``."""
    if idx is None:
        return sub
    return _Run(*(t.index_copy(0, idx, s) for t, s in zip(run, sub, strict=True)))


def _newton_iteration(run: _Run, S, psx, cfg, lb, level, tol, coef_tol, stops) -> _Run:
    """One damped Newton trial on every problem of ``run`` (eq. 16)."""
    cv = jn.derivatives(run.x, S, psx, cfg)
    step, lam, nu = jn.damped_step(run.x, cv, S.xx, run.lam, run.nu, lb)
    L_t = torch.where(step.ok, jn.coords_bound(step.trial, S, psx, cfg), -torch.inf)
    # a step whose first-order gain the bound cannot resolve is judged by the gradient: kept
    # unless the bound falls by more than its round-off (NaN fails either way)
    roundoff = jn._ROUNDOFF * level
    small = step.ok & (step.gain <= roundoff)
    accept = step.ok & ((L_t > run.L) | (small & (L_t >= run.L - roundoff)))
    rejected = step.ok & ~small & ~accept
    dL = torch.where(accept, L_t - run.L, 0.0).clamp_min(0.0)
    # Nielsen's rule: less damping after a step the quadratic model predicted well, more (and
    # faster each time) after a rejected one
    rho = dL / step.predicted.clamp_min(1e-300)
    down = torch.clamp(1.0 - (2.0 * rho - 1.0) ** 3, min=1.0 / 3.0, max=1.0)
    lam = torch.where(accept, (lam * down).clamp_min(jn._LM_FLOOR), lam)
    lam = torch.where(rejected, lam * nu, lam)
    nu = torch.where(accept, 2.0, torch.where(rejected, 2.0 * nu, nu))
    moved = (step.trial - run.x).abs().amax(-1)
    converged = accept & (dL <= tol * level) & (moved <= coef_tol) & stops
    converged = converged | (small & (~accept | (moved <= coef_tol)))
    polish = converged & ~run.polished & (lam > jn._LM_POLISH)
    converged = (converged & ~polish) | ~step.ok  # ~ok: no damping gives a definite matrix
    since = run.since + 1
    slow = accept & ~converged & (dL <= jn._PRUNE_GAIN * S.n) & (since >= jn._PRUNE_EVERY)
    return run._replace(
        x=torch.where(accept[:, None], step.trial, run.x),
        L=torch.where(accept, L_t, run.L),
        lam=torch.where(polish, jn._LM_FLOOR, lam),
        nu=nu,
        pruning=converged | slow,
        scheduled=slow,
        polished=run.polished | polish,
        since=since,
    )


def _prune_iteration(run: _Run, S, psx, cfg, thr, stops) -> _Run:
    """One prune trial on every problem of ``run`` (eq. 17); stops those where it finds nothing
    after a convergence."""
    x_p, L_p, found = prune_trial(run.x, S, psx, cfg, thr)
    found = found & (L_p > run.L)
    stop = ~found & ~run.scheduled
    return run._replace(
        x=torch.where(found[:, None], x_p, run.x),
        L=torch.where(found, L_p, run.L),
        lam=torch.where(found, jn._LM_START, run.lam),
        nu=torch.where(found, 2.0, run.nu),
        live=run.live & ~stop,
        pruning=torch.zeros_like(stop),
        scheduled=torch.zeros_like(stop),
        polished=run.polished & ~found,
        since=torch.zeros_like(run.since),
        fixed=run.fixed | (stop & (not stops)),
    )
