"""The (Bayesian) JFA regression model from moments: settings, state, E-step, updates, bounds.

Pure tensor functions behind `torchjfa.estimators.JFA` and `BayesianJFA`: what the model is,
not how it is fitted. Every quantity is in standardised units (each column of ``X`` and ``y``
scaled to unit variance); dtype and device come from the moments, and any leading batch shape
works. The equation numbers are those of ``docs/theory.md``, which derives everything here.
The optimisers use these functions: ``_jfa_newton.py`` (Bayesian JFA's default, on the
coordinates defined at the end of this module), ``_jfa_prune.py`` (its prune move) and
``_jfa_em.py`` (plain EM, maximum likelihood's closed form).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import NamedTuple

import torch

LOG_2PI = math.log(2.0 * math.pi)


@dataclass(frozen=True, kw_only=True)
class Settings:
    """What a fit holds fixed (plain numbers, the same for every problem of a batch).

    Attributes:
        bayes: the Bayesian model (priors on the loadings) or maximum likelihood.
        a0, b0: shape and rate of the Gamma prior of each relevance precision ``alpha_m``.
        shared_ard: ``alpha_m`` governs both loadings ``w_zm, w_xm`` (the paper's model), or
            ``w_zm`` alone, with ``w_xm ~ N(0, 1 / wx_precision)``.
        wx_precision: the fixed prior precision of ``w_xm`` when ``shared_ard`` is False.
        noise_floor: lower bound of psi_z and psi_x (standardised).
        noise_y_floor: lower bound of psi_y (standardised).
        fixed_x: psi_x is held at its initial value (the input noise is known).
    """

    bayes: bool
    noise_floor: float
    noise_y_floor: float
    fixed_x: bool
    a0: float = 1e-8
    b0: float = 1e-8
    shared_ard: bool = True
    wx_precision: float = 1e-8

    @property
    def n_loadings(self) -> float:
        """How many loadings ``alpha_m`` governs (eq. 7: it adds half of them to the shape)."""
        return 2.0 if self.shared_ard else 1.0

    @property
    def shape(self) -> float:
        """The shape ``a`` of every Q(alpha_m) (eq. 7)."""
        return self.a0 + 0.5 * self.n_loadings


class Stats(NamedTuple):
    """Standardised moments: ``xx (*batch, d, d)``, ``xy (*batch, d)``, ``yy, n (*batch,)``."""

    xx: torch.Tensor
    xy: torch.Tensor
    yy: torch.Tensor
    n: torch.Tensor

    @property
    def dg(self) -> torch.Tensor:
        """``diag(X^T X)``, ``(*batch, d)``."""
        return torch.diagonal(self.xx, dim1=-2, dim2=-1)


class State(NamedTuple):
    """A point of the fit: the posterior means ``mz, mx`` and variances ``vz, vx`` of the
    loadings (variances 0 for maximum likelihood), the rate ``rate`` of Q(alpha) (``<alpha> =
    a / rate``), the noise variances ``psz, psx``, each ``(*batch, d)``, and ``psy (*batch,)``."""

    mz: torch.Tensor
    mx: torch.Tensor
    vz: torch.Tensor
    vx: torch.Tensor
    rate: torch.Tensor
    psz: torch.Tensor
    psx: torch.Tensor
    psy: torch.Tensor


REASONS = ("max_iter", "bound", "coef")


class Result(NamedTuple):
    """A fit: the final ``state``; ``history (n_iter,)`` the bound after each iteration (the
    first at the starting state), nats; ``n_iter``; ``reason``, an index of `REASONS`."""

    state: State
    history: torch.Tensor
    n_iter: int
    reason: int


@functools.lru_cache(maxsize=64)
def _digamma(a: float) -> float:
    return float(torch.special.digamma(torch.tensor(a, dtype=torch.float64)))


def optimal_rate(mz, mx, vz, vx, cfg: Settings) -> torch.Tensor:
    """The rate of Q(alpha) given the loadings (eq. 7), ``(*batch, d)``."""
    w2 = mz * mz + vz
    if cfg.shared_ard:
        w2 = w2 + mx * mx + vx
    return 0.5 * w2 + cfg.b0


def initial_state(
    S: Stats, psx_fixed: torch.Tensor | None, cfg: Settings, gen: torch.Generator | None = None
) -> State:
    """The starting point (eq. 10): ``psi_x = 1/2`` (or the given noise), ``<w_x> = sqrt(1 -
    psi_x)``, ``<w_z> = cov(x, y) / <w_x>``, the variance of y left over split equally between
    psi_y and sum psi_z, Q(alpha) at its optimum.

    With a generator ``gen``, a perturbed start (another start of a multi-start fit): each
    learned ``psi_xm`` drawn uniformly from ``(0.2, 0.8)`` instead of 1/2, and each ``<w_zm>``
    multiplied by ``exp(u)``, ``u`` normal with standard deviation 1/2."""
    xy, d = S.xy, S.xy.shape[-1]
    psx = torch.full_like(xy, 0.5) if psx_fixed is None else psx_fixed.clamp_min(cfg.noise_floor)
    if gen is not None and psx_fixed is None:
        psx = 0.2 + 0.6 * torch.rand(xy.shape, generator=gen, dtype=xy.dtype).to(xy.device)
    mx = torch.sqrt((1.0 - psx).clamp_min(0.01))
    mz = xy / S.n[..., None] / mx
    if gen is not None:
        mz = mz * torch.exp(0.5 * torch.randn(xy.shape, generator=gen, dtype=xy.dtype)).to(mz)
    # correlated inputs can explain more than var(y) at this start: keep 1 % of it
    left = (1.0 - (mz * mz).sum(-1)).clamp_min(0.01)
    psz = (0.5 * left / d)[..., None].expand_as(xy).clamp_min(cfg.noise_floor)
    zero = torch.zeros_like(xy)
    rate = optimal_rate(mz, mx, zero, zero, cfg) if cfg.bayes else zero
    return State(mz, mx, zero, zero, rate, psz, psx, (0.5 * left).clamp_min(cfg.noise_y_floor))


def bound_const(n: torch.Tensor, d: int, cfg: Settings) -> torch.Tensor:
    """The terms of the bound that no state moves (eq. 9), ``(*batch,)`` nats."""
    const = n * (-0.5 * LOG_2PI * (1 + 3 * d) + d * (1.0 + LOG_2PI))
    if not cfg.bayes:
        return const
    a, a0, h = cfg.shape, cfg.a0, 0.5 * cfg.n_loadings
    dig = _digamma(a)
    per = (
        -h * LOG_2PI  # the Gaussian priors under alpha
        + a0 * math.log(cfg.b0)
        - math.lgamma(a0)
        + (a0 - 1.0 + h) * dig  # the Gamma prior
        + h * (1.0 + LOG_2PI)  # the entropies of their Q(w)
        + a
        + math.lgamma(a)
        + (1.0 - a) * dig  # the entropy of Q(alpha)
    )
    if not cfg.shared_ard:  # w_x ~ N(0, 1 / wx_precision): its normaliser and Q(w_x)'s entropy
        per += 0.5 * math.log(cfg.wx_precision) + 0.5
    return const + d * per


class EStep(NamedTuple):
    """Q(z, t)'s expected statistics (eqs. 3-5): ``k`` (the noisy-input predictor, eq. 11),
    ``szz``, ``stt``, ``szt``, ``sxt``, each ``(*batch, d)``; ``R = sum 1 / D``, ``c = psi_y + R``,
    ``S_ee`` the residual sum of squares of ``k``, each ``(*batch,)``."""

    k: torch.Tensor
    szz: torch.Tensor
    stt: torch.Tensor
    szt: torch.Tensor
    sxt: torch.Tensor
    R: torch.Tensor
    c: torch.Tensor
    S_ee: torch.Tensor


def estep(S: Stats, st: State, cfg: Settings) -> tuple[EStep, torch.Tensor]:
    """Q(z, t) at ``st`` (eqs. 3-5) and the bound there (eq. 9): ``(EStep, L (*batch,))``.

    One ``d x d`` matrix-vector product, ``(X^T X) k``; nothing depends on ``N`` otherwise.
    """
    mz, mx, vz, vx, rate, psz, psx, psy = st
    n, dg = S.n[..., None], S.dg
    wz, wx = mz * mz + vz, mx * mx + vx
    iz, ix = 1.0 / psz, 1.0 / psx
    A = 1.0 + wz * iz + wx * ix  # eq. 3
    E, F = mz * iz / A, mx * ix / A
    D = iz - mz * iz * E
    invD = 1.0 / D
    k = E * mx * ix * invD
    R = invD.sum(-1)
    c = psy + R
    s_xe = S.xy - (S.xx @ k[..., None])[..., 0]  # eq. 5
    S_ee = S.yy - (k * (S.xy + s_xe)).sum(-1)
    rho = invD / c[..., None]
    szx = k * dg + rho * s_xe  # sum_i <z_im> x_im
    sz2 = k * (szx + rho * s_xe) + S_ee[..., None] * rho * rho  # sum_i <z_im>^2
    szz_d = invD - rho * invD  # diag Sigma_zz (eq. 4)
    szt_d = E * szz_d  # diag Sigma_zt
    zt = E * sz2 + F * szx  # sum_i <z_im><t_im>
    sxt = E * szx + F * dg
    stt = E * zt + F * sxt + n * (1.0 / A + E * szt_d)
    es = EStep(k, sz2 + n * szz_d, stt, zt + n * szt_d, sxt, R, c, S_ee)
    # eq. 9, less bound_const
    qz = wz * stt - 2.0 * mz * es.szt + es.szz
    qx = wx * stt - 2.0 * mx * sxt + dg
    total = (qz * iz + qx * ix + stt).sum(-1) + S.n * torch.log(psz * psx * A * D).sum(-1)
    if cfg.bayes:
        a = cfg.shape
        w2 = wz + wx if cfg.shared_ard else wz
        per = 2.0 * a * (0.5 * w2 + cfg.b0) / rate + 2.0 * a * torch.log(rate)
        per = per - torch.log(vz * vx)
        if not cfg.shared_ard:
            per = per + cfg.wx_precision * wx
        total = total + per.sum(-1)
    L = -0.5 * S.n * torch.log(c) - (psy * S_ee / c + S.n * R) / (2.0 * c) - 0.5 * total
    return es, L + bound_const(S.n, dg.shape[-1], cfg)


def update(S: Stats, st: State, es: EStep, cfg: Settings) -> State:
    """One sweep after the E-step ``es`` at ``st``: Q(w_z), Q(w_x) (eq. 6, or the maximum
    likelihood loadings), Q(alpha) (eq. 7), then the noise variances (eq. 8)."""
    n = S.n[..., None]
    if cfg.bayes:
        ea = cfg.shape / st.rate
        vz = 1.0 / (es.stt / st.psz + ea)
        vx = 1.0 / (es.stt / st.psx + (ea if cfg.shared_ard else cfg.wx_precision))
        mz, mx = vz * es.szt / st.psz, vx * es.sxt / st.psx
        rate = optimal_rate(mz, mx, vz, vx, cfg)
    else:
        vz = vx = torch.zeros_like(st.psz)
        mz, mx, rate = es.szt / es.stt, es.sxt / es.stt, st.rate
    wz, wx = mz * mz + vz, mx * mx + vx
    psz = ((wz * es.stt - 2.0 * mz * es.szt + es.szz) / n).clamp_min(cfg.noise_floor)
    psx = st.psx
    if not cfg.fixed_x:
        psx = ((wx * es.stt - 2.0 * mx * es.sxt + S.dg) / n).clamp_min(cfg.noise_floor)
    r = st.psy / es.c
    psy = (r * r * es.S_ee / S.n + r * es.R).clamp_min(cfg.noise_y_floor)
    return State(mz, mx, vz, vx, rate, psz, psx, psy)


def first_sweep(
    S: Stats, psx_fixed: torch.Tensor | None, cfg: Settings, gen: torch.Generator | None = None
) -> State:
    """The state after one sweep from `initial_state` (whose zero variances have no bound):
    where every fit starts (``gen``: a perturbed start, see `initial_state`)."""
    st = initial_state(S, psx_fixed, cfg, gen)
    return update(S, st, estep(S, st, cfg)[0], cfg)


def data_terms(mz, mx, vz, vx, psz, psx):
    """What the data see of each input (eq. 12), ``(*batch, d)`` each: ``(kappa, v, k, q)``,
    ``kappa = 1 + V_z / psi_z + V_x / psi_x``, the model's variance ``v`` of ``x_m``, the
    noisy-input predictor ``k`` and the input's share ``q`` of ``c``."""
    kappa = 1.0 + vz / psz + vx / psx
    v = mx * mx / kappa + psx
    k = mz * mx / (kappa * v)
    q = psz + mz * mz * psx / (kappa * v)
    return kappa, v, k, q


def loading_terms(mz, mx, vz, vx, cfg: Settings) -> torch.Tensor:
    """Each input's prior and entropy terms of Q(w), Q(alpha) with Q(alpha) at its optimum
    (eq. 13), ``(*batch, d)`` nats."""
    a, a0, h = cfg.shape, cfg.a0, 0.5 * cfg.n_loadings
    wz, wx = mz * mz + vz, mx * mx + vx
    w2 = wz + wx if cfg.shared_ard else wz
    b = 0.5 * w2 + cfg.b0
    dig = _digamma(a)
    elog, ea = dig - torch.log(b), a / b  # <log alpha>, <alpha>
    out = (
        h * (elog - LOG_2PI)
        - 0.5 * ea * w2  # E log N(w; 0, 1 / alpha)
        + (a0 * math.log(cfg.b0) - math.lgamma(a0))
        + (a0 - 1.0) * elog
        - cfg.b0 * ea  # E log Gamma(alpha; a0, b0)
        + 0.5 * (torch.log(vz) + torch.log(vx))
        + (1.0 + LOG_2PI)  # the entropies of Q(w)
        + (a + math.lgamma(a) + (1.0 - a) * dig)
        - torch.log(b)  # the entropy of Q(alpha)
    )
    if not cfg.shared_ard:  # E log N(w_x; 0, 1 / wx_precision)
        lam = cfg.wx_precision
        out = out + 0.5 * (math.log(lam) - LOG_2PI - lam * wx)
    return out


def collapsed_bound(S: Stats, mz, mx, vz, vx, psz, psx, psy, cfg: Settings) -> torch.Tensor:
    """The bound with Q(z, t) and Q(alpha) at their optima (eq. 12), ``(*batch,)`` nats; the
    same number as `estep`'s bound at the state (``rate`` at `optimal_rate`)."""
    kappa, v, k, q = data_terms(mz, mx, vz, vx, psz, psx)
    c = psy + q.sum(-1)
    S_ee = S.yy - 2.0 * (k * S.xy).sum(-1) + (k * (S.xx @ k[..., None])[..., 0]).sum(-1)
    d = mz.shape[-1]
    L = (
        -0.5 * S.n * (torch.log(v).sum(-1) + torch.log(kappa).sum(-1) + torch.log(c))
        - 0.5 * (S.dg / v).sum(-1)
        - S_ee / (2.0 * c)
        - 0.5 * S.n * (d + 1) * LOG_2PI
    )
    return L + loading_terms(mz, mx, vz, vx, cfg).sum(-1) if cfg.bayes else L


def coef(st: State, cfg: Settings) -> torch.Tensor:
    """The noiseless-input estimate (eq. 11): ``<w_z><w_x> / <w_x^2>`` (0, not 0/0, where
    pruned), ``w_z / w_x`` for maximum likelihood; ``(*batch, d)``."""
    if cfg.bayes:
        return st.mz * st.mx / (st.mx * st.mx + st.vx)
    return st.mz / st.mx


def predictor(st: State) -> torch.Tensor:
    """The noisy-input predictor ``k`` (eq. 11) of a state, ``(*batch, d)``."""
    return data_terms(st.mz, st.mx, st.vz, st.vx, st.psz, st.psx)[2]


# ------------------------------------------------------------------------------ coordinates
def to_coords(st: State, cfg: Settings) -> torch.Tensor:
    """The coordinates ``(B, P)`` of a state ``(B, d)`` on which the Newton optimiser works:
    each input's ``<w_z>, <w_x>, log V_z, log V_x, log psi_z`` and (unless fixed) ``log psi_x``,
    row after row, then ``log psi_y``: ``P = r d + 1`` with ``r`` = 6 or 5."""
    rows = [st.mz, st.mx] + [torch.log(st.vz), torch.log(st.vx), torch.log(st.psz)]
    rows += [] if cfg.fixed_x else [torch.log(st.psx)]
    return torch.cat(rows + [torch.log(st.psy)[:, None]], -1)


def from_coords(x: torch.Tensor, psx: torch.Tensor, cfg: Settings) -> State:
    """The state of coordinates ``x (B, P)``, Q(alpha) at its optimum; ``psx (B, d)`` is used
    where psi_x is fixed."""
    d = psx.shape[-1]
    mz, mx = x[:, :d], x[:, d : 2 * d]
    vz, vx, psz = (torch.exp(x[:, i * d : (i + 1) * d]) for i in (2, 3, 4))
    psx = psx if cfg.fixed_x else torch.exp(x[:, 5 * d : 6 * d])
    rate = optimal_rate(mz, mx, vz, vx, cfg)
    return State(mz, mx, vz, vx, rate, psz, psx, torch.exp(x[:, -1]))


def coords_bound(x: torch.Tensor, S: Stats, psx: torch.Tensor, cfg: Settings) -> torch.Tensor:
    """The collapsed bound (eq. 12) at coordinates ``x (B, P)``, ``(B,)``."""
    st = from_coords(x, psx, cfg)
    return collapsed_bound(S, st.mz, st.mx, st.vz, st.vx, st.psz, st.psx, st.psy, cfg)
