"""The prune move of Bayesian JFA's Newton optimiser (``docs/theory.md``, eqs. 17-18).

`prune_trial` is the move that `_jfa_newton.run_newton` tries at each convergence (and after
slow steps); the rest of this module is its parts, tested one by one.

An input that does not help explain ``y`` heads for the prior's zero (``<w_z> = 0``, its
relevance precision unbounded), which Newton on the log-variances approaches only
geometrically. The prune move jumps there: ``<w_zm> = 0`` (and ``<w_xm> = 0`` with ``psi_xm =
v_m`` when alpha is shared and psi_x learned), ``psi_zm = q_m`` so that ``c`` stays, the
input's posterior variances at their optimum. Each single prune's gain is exact, and inputs
are pruned greedily, the best first, while they gain.
"""

from __future__ import annotations

from typing import NamedTuple

import torch

from . import _jfa_model as jm
from ._jfa_model import Settings, State, Stats, coords_bound, from_coords, to_coords


def pruned_variances(mx, vz, vx, psz, psx, n, cfg: Settings, rounds: int = 2):
    """The posterior variances ``(V_z, V_x)`` at which a pruned input's own terms are
    stationary (eq. 18), given its ``<w_x>`` and noise variances (``<w_z> = 0``), ``(B, d)``.

    With ``kappa`` held, ``V_z = b / (N_z b + a)`` with ``N_z = N / (psi_z kappa)`` (``V_x``
    alike where alpha is shared, else ``1 / (N_x + lambda)``) and Q(alpha)'s rate ``b`` the root
    of an increasing convex function; Newton from the left-hand root of its second-order
    expansion overshoots once and then falls to it monotonically. ``kappa`` is then updated
    and the solve repeated ``rounds`` times.
    """
    a, shared = cfg.shape, cfg.shared_ard
    n = n[:, None]
    kappa = 1.0 + vz / psz + vx / psx
    base = cfg.b0 + (0.5 * mx * mx if shared else 0.0)
    lin = 1.0 - 0.5 * cfg.n_loadings / a
    for _ in range(rounds):
        nz, nx = n / (psz * kappa), n / (psx * kappa)
        quad = 0.5 * (nz + (nx if shared else 0.0)) / (a * a)
        b = 2.0 * base / (lin + torch.sqrt(lin * lin + 4.0 * quad * base))
        for it in range(48):
            dz = nz * b + a
            f, df = b - base - 0.5 * b / dz, 1.0 - 0.5 * a / (dz * dz)
            if shared:
                dx = nx * b + a
                f, df = f - 0.5 * b / dx, df - 0.5 * a / (dx * dx)
            b_new = (b - f / df).clamp_min(cfg.b0)
            done = it % 4 == 3 and bool(((b - b_new).abs() <= 1e-12 * b).all())
            b = b_new
            if done:
                break
        vz = b / (nz * b + a)
        vx = b / (nx * b + a) if shared else 1.0 / (nx + cfg.wx_precision)
        kappa = 1.0 + vz / psz + vx / psx
    return vz, vx


class Candidates(NamedTuple):
    """Every input pruned alone (`candidates`): the ``state`` now and ``pruned``, each input's
    values once pruned; ``gain (B, d)`` each single prune's exact gain, nats; the predictor
    ``k (B, d)`` and ``c (B,)``."""

    state: State
    pruned: State
    gain: torch.Tensor
    k: torch.Tensor
    c: torch.Tensor


def candidates(x: torch.Tensor, S: Stats, psx: torch.Tensor, cfg: Settings) -> Candidates:
    """Each input pruned alone (module docstring) and its gain (eq. 17): the change of
    ``-S_ee / (2 c)`` as ``k_m`` goes to 0 plus that of the input's own terms. An input pruned
    before (``k_m = 0``) is no candidate (gain ``-inf``): Newton has its variances in hand."""
    st = from_coords(x, psx, cfg)
    kappa, v, k, q = jm.data_terms(st.mz, st.mx, st.vz, st.vx, st.psz, st.psx)
    c = st.psy + q.sum(-1)
    s_xe = S.xy - (S.xx @ k[..., None])[..., 0]
    zero = torch.zeros_like(k)
    both = cfg.shared_ard and not cfg.fixed_x  # <w_x> and psi_x move too
    mx, psx_new = (zero, v) if both else (st.mx, st.psx)
    vz, vx = pruned_variances(
        mx, st.vz * q / st.psz, st.vx * psx_new / st.psx, q, psx_new, S.n, cfg
    )
    pruned = State(zero, mx, vz, vx, jm.optimal_rate(zero, mx, vz, vx, cfg), q, psx_new, st.psy)
    kappa_new = 1.0 + vz / q + vx / psx_new
    v_new = mx * mx / kappa_new + psx_new  # v itself where <w_x> is pruned
    own = jm.loading_terms(zero, mx, vz, vx, cfg) - jm.loading_terms(
        st.mz, st.mx, st.vz, st.vx, cfg
    )
    n = S.n[:, None]
    own = own - 0.5 * n * (torch.log(kappa_new / kappa) + torch.log(v_new / v))
    own = own - 0.5 * S.dg * (1.0 / v_new - 1.0 / v)
    gain = -(2.0 * k * s_xe + k * k * S.dg) / (2.0 * c[:, None]) + own
    return Candidates(st, pruned, torch.where(k == 0, -torch.inf, gain), k, c)


def greedy_pick(cand: Candidates, S: Stats, thr: torch.Tensor) -> torch.Tensor:
    """The inputs that pruning one at a time prunes, the best first, each while it gains more
    than ``thr (1,)`` given those before it: ``(1, d)`` bool, for one problem (``B = 1``). A
    prune keeps ``c``, so pruning input j changes input m's gain by ``-k_m (X^T X)_mj k_j / c``
    alone (eq. 17)."""
    gain, k, xx = cand.gain[0], cand.k[0], S.xx[0]
    rate = k / cand.c[0]
    pick = torch.zeros_like(gain, dtype=torch.bool)
    while bool(gain.max() > thr[0]):
        j = int(gain.argmax())
        gain = gain - rate * xx[:, j] * k[j]
        gain[j] = -torch.inf
        pick[j] = True
    return pick[None]


def with_prunes(cand: Candidates, pick: torch.Tensor, cfg: Settings) -> torch.Tensor:
    """The coordinates with the inputs of ``pick (B, d)`` pruned."""
    new = [torch.where(pick, a, b) for a, b in zip(cand.pruned[:-1], cand.state[:-1], strict=True)]
    return to_coords(State(*new, cand.state.psy), cfg)


def prune_trial(x: torch.Tensor, S: Stats, psx: torch.Tensor, cfg: Settings, thr: torch.Tensor):
    """The prune move on every input (`greedy_pick`): ``(x_trial, L_trial, found)``, ``found
    (B,)`` whether any input was pruned."""
    cand = candidates(x, S, psx, cfg)
    pick = greedy_pick(cand, S, thr)
    trial = with_prunes(cand, pick, cfg)
    return trial, coords_bound(trial, S, psx, cfg), pick.any(-1)
