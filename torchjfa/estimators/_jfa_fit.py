"""Fitting (Bayesian) JFA regression from moments: plain EM, a monotone Newton optimiser of the
bound, and the closed form of maximum-likelihood JFA.

Tensor functions for any leading batch shape of problems (``_jfa_bound.py`` has the model and
the state); `fit` is the entry point. Three methods:

- ``"em"``: the plain (variational) EM sweeps of ``docs/bayesian-jfa.md``. Each iteration costs
  one E-step; along the unidentified ``psi_x / w_x^2`` ridge and the pruning paths its rate is
  ``1 - O(1/N)`` (``docs/bayesian-jfa-fitting.md``), so it crawls. Kept as the reference.
- ``"newton"``: Levenberg-Marquardt-damped Newton steps on the bound with Q(z, t) and Q(alpha)
  optimised out (`_jfa_bound.reduced_bound`), in the coordinates ``<w_z>, <w_x>, log V_z, log
  V_x, log psi_z, log psi_x, log psi_y`` (the floors as bounds of a projected step), with the
  exact Hessian in factored form, solved through its structure (``_jfa_newton.py``). When Newton
  has converged, and also when its steps gain little (an input heading for the prior's zero,
  which Newton approaches only geometrically in the log-variances), the prune move of the
  fitting note is tried on every input at once (``<w_zm> = 0``, and ``<w_xm> = 0`` with ``psi_xm
  = v_m`` when alpha is shared and psi_x free; ``c`` unchanged, the input's posterior variances
  moved to their optimum, where Newton would take several steps); the improving prunes are
  kept together, or greedily one after another, whichever gains more, and Newton resumes
  with the pruned inputs' ``<w_z>`` held at 0 (where ``<w_x>`` was pruned too, nothing needs
  holding). No free coordinate then moves their predictors, so the dense part of the Newton
  system is factored on the other inputs alone (`_jfa_newton.newton_step`): ``O(a^3)`` for
  ``a`` inputs left, not ``O(d^3)``. A held
  ``<w_z>`` is freed as soon as Newton alone would gain more than ``_RELEASE`` nats a sample
  on it (`_jfa_newton.escapes`: an input the others' moves make relevant again), and all of
  them when Newton has converged without them, so the fit ends at a stationary point of the
  whole bound.
  Before a Newton trial the damping is raised until the blocks of the Newton matrix are
  positive definite, which needs no trial (`_jfa_newton.block_damping`). Where psi_x is
  learned, a kept Newton step that gained little is followed by the fitting note's ridge move
  (`_ridge_move`): each input moved along ``psi_x / v`` with ``v``, ``k``, ``q`` and ``tau``
  held, a 1-D maximisation of its own prior terms, no mat-vec; Newton crawls along these curved
  ridges, more slowly the more data (``docs/benchmarks.md``: about half the iterations from
  3 10^4 rows on, at the same optima). Every step,
  damped or a prune, is kept only if the bound does not fall, so the recorded bound never
  decreases (beyond its round-off); near an optimum the steps converge quadratically, so the
  answer does not depend on the path to it (the chunking of the data, a batch or a single fit)
  beyond round-off. The bound has many optima, though: on large problems with redundant inputs,
  round-off amplified near saddles early in the path can lead two chunkings to different ones
  (``docs/benchmarks.md``). A batch and a single fit round alike (products as row sums, each
  problem's dense system at an order of its own: `_jfa_newton._order`), so they take one path.
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
from ._jfa_bound import MX, MZ, PX, PZ, VX, VZ, Hyper, Rows, Stats
from ._jfa_newton import block_damping, derivatives, escapes, newton_step

REASONS = ("max_iter", "bound", "coef")
_LM_START = 1e-3  # Levenberg-Marquardt damping, relative to the Hessian's diagonal
_LM_MAX = 1e12
_LM_FLOOR = 1e-12
_LM_POLISH = 1e-9  # a convergence at more damping than this is checked by a step at the floor
_ROUNDOFF = 64 * 2.0**-52  # relative round-off of the bound (a sum of O(d) terms of size O(N))
_SMALL_RUN = 5  # so many kept steps below the bound's resolution in a row end Newton's run
# the prune move is tried at each convergence of Newton, and also after a kept Newton step that
# gained at most _PRUNE_GAIN nats per sample, from the _PRUNE_WARM-th iteration on and at most
# once in _PRUNE_EVERY Newton iterations (docs/benchmarks.md: what each schedule cost)
_PRUNE_WARM = 5
_PRUNE_EVERY = 3
_PRUNE_GAIN = 1e-3
# a held <w_z> is freed when Newton alone would gain more than _RELEASE nats a sample on it
_RELEASE = 1e-5
# the ridge move (psi_x learned) follows a kept Newton step that gained at most _PRUNE_GAIN
# nats per sample; each input's 1-D maximisation takes _RIDGE_ROUNDS safeguarded Newton steps
_RIDGE_ROUNDS = 2


class Result(NamedTuple):
    """A fit of a batch: ``st (*batch, 7, d)``, ``psy (*batch,)``, ``history (*batch, T)`` the
    bound after each iteration (NaN after a problem stopped), ``n_iter``, ``reason`` (index in
    `REASONS`), ``n_accepted`` (accepted Newton steps and prunes), ``n_estep`` (E-step
    equivalents, the cost in ``d x d`` mat-vecs: one per bound evaluation and per gradient
    and Hessian, ``n^3 / (6 d^2)`` per Newton solve (its Cholesky's flops over a mat-vec's,
    ``n <= d + 1`` the order of the dense system factored: `_jfa_newton.Step`), ``r^3 / (6
    d)`` per raise of the damping that refactors the ``r x r`` blocks alone
    (`_jfa_newton.block_damping`), 3 per prune trial), all ``(*batch,)`` int64."""

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


def _greedy_prunes(cand: _Prunes, S: Stats, thr) -> torch.Tensor:
    """The inputs that pruning one at a time prunes, the best first, each while it gains more
    than ``thr`` given the ones before it: ``(*batch, d)`` bool. A prune keeps ``c`` and
    changes the other inputs' gains only through ``X^T e``: when input j goes, input m's gain
    changes by ``-k_m (X^T X)_mj k_j / c``, ``O(d)`` a round, where the prunes one Newton
    cycle at a time cost about four iterations each (``scripts/bench_fit_cost.py``)."""
    gain, k = cand.gain, cand.k
    pick = torch.zeros_like(gain, dtype=torch.bool)
    rate = k / cand.c[..., None]
    ninf = torch.tensor(-torch.inf, dtype=gain.dtype, device=gain.device)
    for _ in range(gain.shape[-1]):
        j = gain.argmax(-1, keepdim=True)
        best = gain.gather(-1, j)
        ok = best > thr[..., None]
        if not bool(ok.any()):
            break
        col = torch.gather(S.xx, -1, j[..., None].expand(*S.xx.shape[:-1], 1))[..., 0]
        gain = gain - rate * col * torch.where(ok, k.gather(-1, j), 0.0)
        gain = gain.scatter(-1, j, torch.where(ok, ninf, best))
        pick = pick.scatter(-1, j, ok | pick.gather(-1, j))
    return pick


def _prune_gains(k, s_xe, dg, c, own, pruned_before):
    """Each single prune's gain, ``(*batch, d)`` nats: the change of ``-S_ee / (2 c)`` as
    ``k_m`` goes to 0, plus its own terms' change ``own``; ``-inf`` for an input pruned before
    (``k = 0``): a prune would move its variances alone, which Newton has in hand, and a
    found prune resets the damping."""
    gain = -(2.0 * k * s_xe + k * k * dg) / (2.0 * c[..., None]) + own
    return torch.where(pruned_before, -torch.inf, gain)


def _pruned_variances(mx, vz, vx, psz, psx, n, hp: Hyper, rounds: int = 2):
    """The posterior variances ``(V_z, V_x)`` at which a pruned input's own terms are
    stationary, ``(*batch, d)`` each, given its ``<w_x>`` and noise variances (``<w_z> = 0``).

    With ``tau = 1 + V_z / psi_z + V_x / psi_x`` held, the bound's ``V``-terms are ``-N/2 log
    tau - a log b + (log V_z + log V_x) / 2`` (and ``-lam V_x / 2`` when alpha governs w_z
    alone), ``b`` Q(alpha)'s rate, so ``V_z = b / (N_z b + a)`` with ``N_z = N / (psi_z tau)``,
    likewise ``V_x`` when alpha is shared (else ``1 / (N_x + lam)``), and ``b`` is the root of
    ``g(b) = b - b0 - <w_x>^2 / 2 [shared] - (V_z(b) + V_x(b) [shared]) / 2``: convex and
    increasing, so Newton from the right converges to it monotonically. Newton on the bound
    approaches this point only geometrically (``V`` falls by about e a step: ``b`` ends near
    ``sqrt(b0 / N)``, orders of magnitude below the unpruned input's), hence this move. ``tau``
    is then updated and the solve repeated (``rounds``). Where ``<w_x> != 0`` this ignores how
    ``tau`` moves ``v`` (second order at ``v``'s optimum); the prune's gain counts it.
    """
    a, shared = hp.a, hp.shared
    n = n[..., None]
    tau = 1.0 + vz / psz + vx / psx
    base = hp.b0 + (0.5 * mx * mx if shared else 0.0)
    for _ in range(rounds):
        nz, nx = n / (psz * tau), n / (psx * tau)
        # start at the root of g's expansion to second order in N b / a, which lies left of
        # g's (the expansion bounds g from above); the first Newton step lands right of it,
        # from where the steps fall monotonically
        quad = 0.5 * (nz + (nx if shared else 0.0)) / (a * a)
        lin = 1.0 - (1.0 if shared else 0.5) / a
        b = 2.0 * base / (lin + torch.sqrt(lin * lin + 4.0 * quad * base))
        for it in range(48):
            dz = nz * b + a
            g = b - base - 0.5 * b / dz
            dg = 1.0 - 0.5 * a / (dz * dz)
            if shared:
                dx = nx * b + a
                g = g - 0.5 * b / dx
                dg = dg - 0.5 * a / (dx * dx)
            b_new = (b - g / dg).clamp_min(hp.b0)
            # quadratic at the end; the relative change stalls near 1e-15 (round-off)
            if it % 4 == 3 and bool(((b - b_new).abs() <= 1e-12 * b).all()):
                b = b_new
                break
            b = b_new
        vz = b / (nz * b + a)
        vx = b / (nx * b + a) if shared else 1.0 / (nx + hp.lam)
        tau = 1.0 + vz / psz + vx / psx
    return vz, vx


class _Prunes(NamedTuple):
    """The prune move's candidates at one state (`_prune_candidates`): ``cols`` the state's
    ``mz, mx, vz, vx, psz, psx`` and ``new`` each input's values once pruned (dicts of
    ``(*batch, d)``), ``psy``; ``gain (*batch, d)`` each single prune's exact gain, nats;
    ``k (*batch, d)`` and ``c (*batch,)`` (for `_greedy_prunes`)."""

    cols: dict
    new: dict
    psy: torch.Tensor
    gain: torch.Tensor
    k: torch.Tensor
    c: torch.Tensor


def _prune_candidates(theta, S: Stats, psx_c, hp: Hyper) -> _Prunes:
    """Each input pruned alone (module docstring): ``<w_z> = 0``, and ``<w_x> = 0`` with
    ``psi_x = v`` when alpha is shared and psi_x free; ``psi_z = q``, so ``c`` is unchanged,
    the posterior variances at their optimum for the pruned input (`_pruned_variances`).
    Its gain is exact: the change of ``S_ee`` (through ``k_m`` alone) and of the input's own
    terms."""
    mz, mx, vz, vx, psz, psx, psy = _unpack(theta, psx_c, hp)
    tau, v, k, q = jb.data_terms(mz, mx, vz, vx, psz, psx)
    c = psy + q.sum(-1)
    s_xe = S.xy - jb.matvec(S.xx, k)
    both = hp.shared and not hp.fixed_x  # prune w_x too (psi_x takes v), else w_z alone
    zero = torch.zeros_like(mz)
    new = {"mz": zero, "psz": q}
    new.update({"mx": zero, "psx": v} if both else {"mx": mx, "psx": psx})
    new["vz"], new["vx"] = _pruned_variances(
        new["mx"], vz * q / psz, vx * new["psx"] / psx, new["psz"], new["psx"], S.n, hp
    )
    n = S.n[..., None]
    tau_new = 1.0 + new["vz"] / new["psz"] + new["vx"] / new["psx"]
    v_new = new["mx"] * new["mx"] / tau_new + new["psx"]  # v itself when w_x is pruned
    own = jb.kl_terms(new["mz"], new["mx"], new["vz"], new["vx"], hp)
    own = own - jb.kl_terms(mz, mx, vz, vx, hp)
    own = own - 0.5 * n * (torch.log(tau_new) - torch.log(tau) + torch.log(v_new) - torch.log(v))
    own = own - 0.5 * S.dg * (1.0 / v_new - 1.0 / v)
    gain = _prune_gains(k, s_xe, S.dg, c, own, k == 0)
    cols = {"mz": mz, "mx": mx, "vz": vz, "vx": vx, "psz": psz, "psx": psx}
    return _Prunes(cols, new, psy, gain, k, c)


def _with_prunes(cand: _Prunes, pick: torch.Tensor, hp: Hyper) -> torch.Tensor:
    """The packed state with the inputs of ``pick (*batch, d)`` pruned."""
    cols = {key: torch.where(pick, cand.new[key], val) for key, val in cand.cols.items()}
    st = torch.stack([cols[r] for r in ("mz", "mx", "vz", "vx", "psz", "psx")], -2)
    st = torch.cat([st[..., :4, :], torch.zeros_like(st[..., :1, :]), st[..., 4:, :]], -2)
    return _pack(st, cand.psy, hp)


def _prune_trial(theta, S: Stats, psx_c, hp: Hyper, thr):
    """The prune move on every input: ``(theta_trial, L_trial, any)``.

    Of the single prunes (`_prune_candidates`), those that gain more than ``thr`` are tried
    together, and greedily one after the other (`_greedy_prunes`); the better of the two is
    returned (``any``: some candidate gained).
    """
    cand = _prune_candidates(theta, S, psx_c, hp)
    good = cand.gain > thr[..., None]
    greedy = _greedy_prunes(cand, S, thr)
    trials = [_with_prunes(cand, pick, hp) for pick in (good, greedy)]
    bounds = [_theta_bound(th, *S, psx_c, hp) for th in trials]
    first = bounds[0] >= bounds[1]
    return (
        torch.where(first[..., None], trials[0], trials[1]),
        torch.where(first, bounds[0], bounds[1]),
        good.any(-1),
    )


class _Ridge(NamedTuple):
    """What the ridge move holds of each input, ``(B, d)`` each (`_ridge_move`): ``a_z = k^2
    tau v`` and ``b_x = tau v`` (``<w_z>^2 = a_z / (1 - r)``, ``<w_x>^2 = b_x (1 - r)``), ``q``,
    ``kkv = k^2 v`` (``psi_z = q - kkv r / (1 - r)``), ``v`` (``psi_x = r v``) and ``cz = V_z /
    psi_z``, ``cx = V_x / psi_x`` (the posterior variances scale with the noise variances)."""

    a_z: torch.Tensor
    b_x: torch.Tensor
    q: torch.Tensor
    kkv: torch.Tensor
    v: torch.Tensor
    cz: torch.Tensor
    cx: torch.Tensor


def _ridge_terms(e: torch.Tensor, fixed: _Ridge, hp: Hyper):
    """An input's terms of the bound that move along its ridge, at ``e = r / (1 - r)``:
    ``-a log b + (log V_z + log V_x) / 2`` (``- lam <w_x^2> / 2`` with alpha on w_z alone)
    less a constant, and ``psi_z``, ``psi_x``."""
    omr = 1.0 / (e + 1.0)  # 1 - r
    r = e * omr
    psz = fixed.q - fixed.kkv * e
    psx = r * fixed.v
    wz = (e + 1.0) * fixed.a_z + psz * fixed.cz
    wx = omr * fixed.b_x + psx * fixed.cx
    b = (0.5 * (wz + wx) if hp.shared else 0.5 * wz) + hp.b0
    f = -hp.a * torch.log(b) + 0.5 * (torch.log(psz) + torch.log(r))
    if not hp.shared:
        f = f - 0.5 * hp.lam * wx
    return f, psz, psx


def _ridge_slope(e: torch.Tensor, fixed: _Ridge, hp: Hyper):
    """The first and second derivatives of `_ridge_terms` in ``u = log e``: with ``r' = r (1 -
    r)``, ``<w_z^2>`` and ``psi_z`` move as ``e``, ``<w_x^2>`` and ``psi_x`` as ``r'``."""
    omr = 1.0 / (e + 1.0)
    r = e * omr
    rr = r * omr  # dr / du
    rr2 = rr * (omr - r)  # d2r / du2
    psz = fixed.q - fixed.kkv * e
    dz = e * (fixed.a_z - fixed.cz * fixed.kkv)  # d<w_z^2>/du = its second derivative
    sx = fixed.cx * fixed.v - fixed.b_x
    wz = (e + 1.0) * fixed.a_z + psz * fixed.cz
    wx = omr * fixed.b_x + r * fixed.v * fixed.cx
    if hp.shared:
        b, db, db2 = 0.5 * (wz + wx) + hp.b0, 0.5 * (dz + rr * sx), 0.5 * (dz + rr2 * sx)
    else:
        b, db, db2 = 0.5 * wz + hp.b0, 0.5 * dz, 0.5 * dz
    lb1 = db / b
    lz1 = -fixed.kkv * e / psz
    g = -hp.a * lb1 + 0.5 * (lz1 + omr)
    h = -hp.a * (db2 / b - lb1 * lb1) + 0.5 * (lz1 - lz1 * lz1 - rr)
    if not hp.shared:
        g = g - 0.5 * hp.lam * rr * sx
        h = h - 0.5 * hp.lam * rr2 * sx
    return g, h


def _ridge_move(theta: torch.Tensor, psx_c, hp: Hyper) -> tuple[torch.Tensor, torch.Tensor]:
    """The fitting note's ridge move (``../shared/docs/bayesian-jfa-fitting.md``, move 1),
    psi_x learned: each input moved along ``r = psi_x / v`` in (0, 1) with its ``v``, ``k``,
    ``q`` and ``tau`` held, so that the data's part of the bound (through ``v``, ``k`` and
    ``c``) stays and only the input's own prior and entropy terms change; each ``r``
    maximises those (`_ridge_terms`) by `_RIDGE_ROUNDS` Newton steps in ``log(r / (1 - r))``,
    each kept only if the terms rise (halved up to twice), with ``psi_z`` and ``psi_x`` above
    the floor. No mat-vec. ``theta (B, P)`` packed (`_pack`, psi_x free; ``psx_c`` as for
    `_unpack`): ``(theta', gain (B,))``, the gain the bound's exact change (up to round-off). Newton on the bound moves
    along these ridges (``psi_x`` trading against ``<w_x>^2``) slowly: the ridge is curved,
    and its curvature across grows with ``N``."""
    d = psx_c.shape[-1]
    mz, mx, vz, vx, psz, psx, _ = _unpack(theta, psx_c, hp)
    tau, v, k, q = jb.data_terms(mz, mx, vz, vx, psz, psx)
    fixed = _Ridge(k * k * tau * v, tau * v, q, k * k * v, v, vz / psz, vx / psx)
    live = mx != 0  # where <w_x> = 0 the input is pruned: r = 1
    e = torch.where(live, psx / (v - psx), 1.0)
    ok = live & (e > 0) & torch.isfinite(e)
    e = torch.where(ok, e, 1.0)
    f0 = _ridge_terms(e, fixed, hp)[0]
    u, f = torch.log(e), f0
    half = torch.tensor([1.0, 0.5, 0.25], dtype=theta.dtype, device=theta.device)[:, None, None]
    for _ in range(_RIDGE_ROUNDS):
        g, h = _ridge_slope(torch.exp(u), fixed, hp)
        du = torch.where(h < 0, -g / torch.where(h < 0, h, -1.0), torch.sign(g))
        du = torch.where(torch.isfinite(du), du.clamp(-2.0, 2.0), 0.0)
        cand = u + half * du  # (3, B, d)
        fc, pz, px = _ridge_terms(torch.exp(cand), fixed, hp)
        fc = torch.where((pz >= hp.floor) & (px >= hp.floor) & torch.isfinite(fc), fc, -torch.inf)
        better = fc > f
        first = torch.where(better.any(0), better.to(torch.int8).argmax(0), 0)
        take = ok & better.any(0)
        u = torch.where(take, cand.gather(0, first[None])[0], u)
        f = torch.where(take, fc.gather(0, first[None])[0], f)
    moved = ok & (f > f0)
    e = torch.exp(u)
    omr = 1.0 / (e + 1.0)
    r = e * omr
    psz_n = fixed.q - fixed.kkv * e
    psx_n = r * fixed.v
    new = [
        torch.sign(mz) * torch.sqrt((e + 1.0) * fixed.a_z),
        torch.sign(mx) * torch.sqrt(omr * fixed.b_x),
        torch.log(fixed.cz * psz_n),
        torch.log(fixed.cx * psx_n),
        torch.log(psz_n),
        torch.log(psx_n),
    ]
    cols = [torch.where(moved, n, theta[:, i * d : (i + 1) * d]) for i, n in enumerate(new)]
    gain = torch.where(moved, f - f0, 0.0).sum(-1)
    return torch.cat(cols + [theta[:, -1:]], -1), gain


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
    bound rises. Where psi_x is learned, a kept Newton step that gained at most
    ``_PRUNE_GAIN`` nats a sample is followed in the same iteration by `_ridge_move`, kept if
    the bound rises beyond its round-off (then that step is no convergence). Newton has
    converged when a kept step changes the bound by at most
    ``tol * max(|L|, N)`` and no coordinate by more than ``coef_tol`` (means in standardised
    units, log-variances), or when the next step's first-order gain is at round-off level, or
    when no damping finds an ascent; then the prune trial runs, and the problem stops
    (``"bound"``) when no prune gains. A prune trial also runs, on the schedule of
    `_PRUNE_GAIN`, after a kept step that gained little; when it finds nothing, Newton goes on.
    The inputs a kept prune zeroes have their ``<w_z>`` held at 0 (module docstring) until
    Newton would move one (`_jfa_newton.escapes`) or a stop test finds no prune: then all are
    freed, once, and Newton runs on to the stop test of the whole bound. A refused Newton
    step (the matrix not proven definite) is no move, and its bound is not computed. With
    ``tol = coef_tol = 0`` it runs ``max_iter``
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
    polished = torch.zeros_like(stale)  # the damping went to its floor since the last prune
    forced = torch.zeros_like(stale)  # the coming prune trial is a scheduled one, not a stop test
    since = _int(L)  # Newton iterations since the last prune trial
    n_small = _int(L)  # consecutive kept steps below the bound's resolution
    reason, n_iter, n_acc, n_estep = _int(L), _int(L, 1), _int(L), _int(L, 1)
    # pruned inputs whose <w_z> Newton holds at 0 until it converges without them (then all
    # are freed, once), and the problems whose held inputs were freed so
    held = torch.zeros((B, d), dtype=torch.bool, device=theta.device)
    released = torch.zeros_like(stale)
    block_cost = math.ceil(((P - 1) // d) ** 3 / (6 * d))  # d Cholesky factors of r x r
    hist = [L]
    while bool(live.any()) and len(hist) < max_iter:
        was_live = live
        newton, pruning = live & ~settled, live & settled
        need = newton & stale
        if bool(need.any()):
            rows = Rows(need)
            new = derivatives(rows.take(theta), rows.stats(flat), rows.take(psx_c), hp)
            if cv is None or rows.idx is None:  # every problem (always the first time)
                cv = type(new)(*(t.contiguous() for t in new))
            else:
                for kept, fresh in zip(cv, new, strict=True):
                    rows.put(kept, fresh)
            stale = stale & ~need
            n_estep = n_estep + need.long()
        level = torch.maximum(L.abs(), scale)
        thr, roundoff = tol * level, _ROUNDOFF * level
        th_t, L_t = theta, L
        accept = torch.zeros_like(live)
        small = torch.zeros_like(live)
        if bool(newton.any()):
            # on the problems taking a Newton step only (the others wait or are done)
            rows = Rows(newton)
            sub, th_i, lb_i = rows.stats(flat), rows.take(theta), rows.take(lb)
            cv_i = type(cv)(*(rows.take(t) for t in cv))
            # the damping the block part needs, found without a trial (`block_damping`)
            held_i = rows.take(held)
            if bool(held_i.any()):  # free the held <w_z> that Newton would move
                rows.put(held, held_i & ~escapes(th_i, cv_i, lb_i, sub.n, _RELEASE))
            hold_i = torch.nn.functional.pad(rows.take(held), (0, P - d))
            lam_i, nu_i, raises, blocks = block_damping(
                th_i, cv_i, rows.take(lam), rows.take(nu), lb_i, _LM_MAX, hold_i
            )
            rows.put(lam, lam_i)
            rows.put(nu, nu_i)
            step = newton_step(th_i, cv_i, lam_i, lb_i, flat.xx, blocks, hold_i, rows.idx)
            # the raises of the damping, and the solve at each problem's order (`Step`)
            solve = -(-(step.size**3) // (6 * d * d))
            rows.put(n_estep, rows.take(n_estep) + raises * block_cost + solve)
            th_n, L_n = theta.clone(), L.clone()
            rows.put(th_n, step.trial)
            ok, gain, pred = torch.zeros_like(live), torch.zeros_like(L), torch.zeros_like(L)
            rows.put(ok, step.ok)
            rows.put(gain, step.gain)
            rows.put(pred, step.predicted)
            if bool(step.ok.any()):  # a refused step is no move: its bound is not computed
                inner = Rows(step.ok)
                good = rows.sub(inner)
                L_good = _theta_bound(
                    inner.take(step.trial), *inner.stats(sub), good.take(psx_c), hp
                )
                good.put(L_n, L_good)
            # a step whose first-order gain the bound cannot resolve is judged by its model:
            # kept unless the bound falls by more than its round-off (NaN fails either way)
            small = newton & ok & (gain <= roundoff)
            accept = newton & ok & ((L_n > L) | (small & (L_n >= L - roundoff)))
            th_t = torch.where(newton[..., None], th_n, th_t)
            L_t = torch.where(newton, L_n, L_t)
            n_estep = n_estep + ok.long()
        found = torch.zeros_like(live)
        if bool(pruning.any()):
            rows = Rows(pruning)
            th_i, L_i, found_i = _prune_trial(
                rows.take(theta), rows.stats(flat), rows.take(psx_c), hp, rows.take(thr)
            )
            th_p, L_p = theta.clone(), L.clone()
            rows.put(th_p, th_i)
            rows.put(L_p, L_i)
            rows.put(found, found_i)
            found = pruning & found & (L_p > L)
            accept = accept | found
            th_t = torch.where(pruning[..., None], th_p, th_t)
            L_t = torch.where(pruning, L_p, L_t)
            n_estep = n_estep + pruning.long() * 3
        dL, dth = L_t - L, (th_t - theta).abs().amax(-1)
        # a kept prune zeroes its inputs' <w_z>: held there until Newton converges (where
        # <w_x> went to 0 too, no coordinate moves k_m and nothing needs holding)
        pruned = (th_t[..., :d] == 0) & (th_t[..., d : 2 * d] != 0)
        held = held | ((found & ~released)[..., None] & pruned)
        theta = torch.where(accept[..., None], th_t, theta)
        L = torch.where(accept, L_t, L)
        # after a kept Newton step that gained little, the ridge move (psi_x learned)
        ridged = torch.zeros_like(live)
        if hp.bayes and not hp.fixed_x:
            want = newton & accept & (dL <= _PRUNE_GAIN * flat.n)
            if bool(want.any()):
                rows = Rows(want)
                th_r, gain_r = _ridge_move(rows.take(theta), rows.take(psx_c), hp)
                L_r = _theta_bound(th_r, *rows.stats(flat), rows.take(psx_c), hp)
                ok_r = (L_r > rows.take(L)) & (gain_r > rows.take(roundoff))
                rows.put(theta, torch.where(ok_r[:, None], th_r, rows.take(theta)))
                rows.put(L, torch.where(ok_r, L_r, rows.take(L)))
                rows.put(ridged, ok_r)
                n_estep = n_estep + want.long()
        stale = stale | accept
        n_acc = n_acc + accept.long()
        # Levenberg-Marquardt damping, Nielsen's rule: less after a kept step the quadratic
        # model predicted well, more (and faster each time) after a rejected one
        rejected = newton & ~accept & ~small
        if bool(newton.any()):
            rho = dL / pred.clamp_min(1e-300)
            down = torch.clamp(1.0 - (2.0 * rho - 1.0) ** 3, min=1.0 / 3.0, max=1.0)
            lam = torch.where(newton & accept, (lam * down).clamp_min(_LM_FLOOR), lam)
        lam = torch.where(rejected, lam * nu, lam)
        nu = torch.where(rejected, 2.0 * nu, torch.where(newton & accept, 2.0, nu))
        # (a ridge move after the step gained beyond round-off: not converged)
        converged = newton & accept & (dL <= thr) & (dth <= coef_tol) & stops & ~ridged
        # damped steps are short along weakly curved directions (the psi_x / w_x^2 ridge):
        # before a convergence counts, Newton runs on with the damping at its floor
        polish = (converged | (small & accept)) & ~polished & (lam > _LM_POLISH)
        lam = torch.where(polish, _LM_FLOOR, lam)
        polished = polished | polish
        converged = converged & ~polish
        n_small = torch.where(
            newton, torch.where(small & accept & ~ridged, n_small + 1, 0), n_small
        )
        tiny = (small & ~accept) | (n_small >= _SMALL_RUN)  # nothing left the bound can see
        stuck = rejected & (lam > _LM_MAX)  # no damping finds an ascent: stationary
        failed = pruning & ~found & ~forced  # no prune gains at a stationary point: the optimum
        # of the inputs not held; then Newton resumes with the held ones free, once
        release = failed & held.any(-1)
        held = held & ~release[..., None]
        released = released | release
        failed = failed & ~release
        since = torch.where(pruning, 0, since + newton.long())
        due = newton & ~(tiny | converged | stuck) & (n_iter >= _PRUNE_WARM)
        due = due & (since >= _PRUNE_EVERY) & accept & (dL <= _PRUNE_GAIN * flat.n)
        settled = (settled & ~pruning) | tiny | converged | stuck | due
        forced = due
        lam = torch.where(found | stuck | failed | tiny | release, _LM_START, lam)
        polished = polished & ~(found | release)
        n_small = torch.where(tiny, 0, n_small)
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
    # what psi_y + sum psi_z must leave above the floors; r aims 1e-9 inside it, so that the
    # check below does not hang on round-off (a batch and a single fit round differently)
    need0 = max(hp.floor_y + d * hp.floor, 2 * d * hp.floor)
    need = need0 * (1.0 + 1e-9)
    K = (k * k * v).sum(-1)
    if hp.fixed_x:
        r = st[..., PX, :] / v
    else:  # r / (1 - r) <= t keeps c - sum k^2 v r / (1 - r) >= need
        t = ((c - need) / K.clamp_min(1e-300)).clamp_min(0.0)
        r = torch.minimum(torch.full_like(v, 0.5), (t / (1.0 + t))[..., None])
    ok = (r > 0).all(-1) & (r < 1).all(-1)
    r = r.clamp(1e-300, 1.0 - 1e-12)
    left = c - (k * k * v * r / (1.0 - r)).sum(-1)  # psi_y + sum psi_z
    ok = ok & (left >= need0)
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
