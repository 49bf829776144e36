"""The (Bayesian) JFA regression model from moments: state, plain EM sweep and lower bound.

Pure tensor functions behind `torchjfa.estimators.JFA` and `BayesianJFA` (``_jfa.py``), written
once for any leading batch shape of problems: the moments are stacked as ``xx (*batch, d, d)``,
``xy (*batch, d)``, ``yy, n (*batch,)``, in standardised units (every column of ``X`` and ``y``
scaled to unit variance), and dtype and device come from them. ``_jfa_fit.py`` drives these
functions (the plain EM loop, the Newton optimiser of the bound, the closed form of maximum
likelihood JFA); use it, not this module, to fit.

The update equations and the bound are those of ``docs/bayesian-jfa.md``; `reduced_bound` is the
bound with Q(z, t) optimised out (``docs/bayesian-jfa-fitting.md``), a smooth function of the
state that the Newton optimiser differentiates. Both bounds are the same number (tested).

The state is one ``(*batch, 7, d)`` tensor with rows `MZ`, `MX` (the posterior means ``<w_z>``,
``<w_x>``), `VZ`, `VX` (their variances; 0 for maximum likelihood), `B` (the rate of Q(alpha),
``<alpha> = a / b``; unused for maximum likelihood), `PZ`, `PX` (psi_z, psi_x), plus
``psy (*batch,)``.
"""

from __future__ import annotations

import copy
import functools
import math
from typing import NamedTuple

import torch

MZ, MX, VZ, VX, B, PZ, PX = range(7)
LOG_2PI = math.log(2.0 * math.pi)


class Hyper(NamedTuple):
    """Static settings of a fit (plain Python numbers, the same for every problem of a batch).

    ``a``: the shape of Q(alpha) (``a0 + 1`` with alpha shared by both loadings, ``a0 + 1/2``
    with alpha on ``w_z`` alone); ``lam``: the fixed prior precision of ``w_x`` when alpha
    governs ``w_z`` alone, ``-1`` when alpha is shared; ``floor``, ``floor_y``: lower bounds
    of psi_z and psi_x, and of psi_y; ``fixed_x``: psi_x held at its initial value.
    """

    bayes: bool
    a: float
    b0: float
    floor: float
    fixed_x: bool
    floor_y: float
    lam: float

    @property
    def shared(self) -> bool:
        return self.lam < 0.0


class Stats(NamedTuple):
    """Standardised moments: ``xx (*batch, d, d)``, ``xy (*batch, d)``, ``yy, n (*batch,)``."""

    xx: torch.Tensor
    xy: torch.Tensor
    yy: torch.Tensor
    n: torch.Tensor

    @property
    def dg(self) -> torch.Tensor:
        return torch.diagonal(self.xx, dim1=-2, dim2=-1)


class Rows:
    """The problems of a batch that ``mask (B,)`` selects: ``take`` their rows of a tensor and
    ``put`` rows back. Where it selects all of them (a single fit, most iterations of a
    batch), both are the tensor itself: indexing by a tensor copies, and ``d x d`` statistics
    each iteration."""

    def __init__(self, mask: torch.Tensor) -> None:
        self.idx = None if bool(mask.all()) else mask.nonzero()[:, 0]

    def take(self, t: torch.Tensor) -> torch.Tensor:
        return t if self.idx is None else t.index_select(0, self.idx)

    def stats(self, S: Stats) -> Stats:
        return S if self.idx is None else Stats(*(self.take(t) for t in S))

    def put(self, dst: torch.Tensor, rows: torch.Tensor) -> None:
        if self.idx is None:
            dst.copy_(rows)
        else:
            dst.index_copy_(0, self.idx, rows)

    def sub(self, inner: Rows) -> Rows:
        """The rows that ``inner`` (a selection of these rows) selects, as rows of the batch."""
        out = copy.copy(inner)
        if self.idx is not None:
            out.idx = self.idx if inner.idx is None else self.idx[inner.idx]
        return out


def matvec(A: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """``A x`` for ``A (*batch, m, n)``, ``x (*batch, n)``: ``(*batch, m)``, as products summed
    along each row, whose order does not depend on the batch (a batched ``@`` runs other BLAS
    kernels for other batch sizes, so a batch and a single fit would round differently)."""
    return (A * x[..., None, :]).sum(-1)


@functools.lru_cache(maxsize=64)
def _digamma(a: float) -> float:
    """``digamma(a)`` of a Python float (Q(alpha)'s shape: one per fit, asked every bound)."""
    return float(torch.special.digamma(torch.tensor(a, dtype=torch.float64)))


def bound_const(n: torch.Tensor, d: int, hp: Hyper) -> torch.Tensor:
    """State-independent terms of the bound (the 2 pi's, the Gamma prior, the entropies).

    Args:
        n: ``(*batch,)`` number of samples. d: number of inputs.

    Returns:
        ``(*batch,)`` nats.
    """
    const = n * (-0.5 * LOG_2PI * (1 + 3 * d) + d * (1.0 + LOG_2PI))
    if hp.bayes:
        a = hp.a
        dig = _digamma(a)
        k = 1.0 if hp.shared else 0.5  # loadings under alpha
        a0 = a - k
        per = (
            -k * LOG_2PI  # the Gaussian priors under alpha
            + a0 * math.log(hp.b0)  # the Gamma prior
            - math.lgamma(a0)
            + (a0 - 1.0 + k) * dig
            + k * (1.0 + LOG_2PI)  # entropies of their Q(w): halves of log(2 pi e)
            + a  # entropy of Q(alpha)
            + math.lgamma(a)
            + (1.0 - a) * dig
        )
        if not hp.shared:  # w_x ~ N(0, 1 / lam): the prior's normaliser and Q(w_x)'s entropy
            per += 0.5 * math.log(hp.lam) + 0.5
        const = const + d * per
    return const


def _row(st: torch.Tensor, r: int) -> torch.Tensor:
    return st[..., r, :]


def estep(S: Stats, st: torch.Tensor, psy: torch.Tensor, hp: Hyper):
    """The note's E-step: Q(z, t), its expected statistics, and the lower bound there.

    Args:
        S: the moments. st: ``(*batch, 7, d)`` state. psy: ``(*batch,)`` psi_y.

    Returns:
        ``(es, R, c, S_ee, L)``: ``es (*batch, 5, d)`` with rows ``k`` (the noisy-input
        predictor), ``S_zz``, ``S_tt``, ``S_zt``, ``S_xt``; ``R = sum 1/D``, ``c = psi_y + R``,
        the residual sum of squares ``S_ee`` and the bound ``L`` without `bound_const`, each
        ``(*batch,)``.
    """
    mz, mx, vz, vx, b, psz, psx = st.unbind(-2)
    n, dg = S.n[..., None], S.dg
    wz, wx = mz * mz + vz, mx * mx + vx
    i0, i1 = 1.0 / psz, 1.0 / psx
    A = 1.0 + wz * i0 + wx * i1
    ia = 1.0 / A
    E = mz * i0 * ia
    D = i0 - mz * i0 * E
    invD = 1.0 / D
    F = mx * i1 * ia
    k = E * mx * i1 * invD  # the noisy-input predictor, eq. (3)
    R = invD.sum(-1)
    c = psy + R
    s_xe = S.xy - matvec(S.xx, k)  # X^T e, the one d x d product
    S_ee = S.yy - (k * (S.xy + s_xe)).sum(-1)
    rho = invD / c[..., None]
    rs = rho * s_xe
    szx = k * dg + rs  # sum <z> x
    sz2 = k * (szx + rs) + S_ee[..., None] * rho * rho  # sum <z>^2
    szz_d = invD - rho * invD  # diag Sigma_zz
    ezd = E * szz_d  # diag Sigma_zt
    ct0 = E * sz2 + F * szx  # sum <z><t>
    sxt = E * szx + F * dg
    stt = E * ct0 + F * sxt + n * (ia + E * ezd)
    szt = ct0 + n * ezd
    szz = sz2 + n * szz_d
    es = torch.stack([k, szz, stt, szt, sxt], -2)
    qz = wz * stt - 2.0 * mz * szt + szz
    qx = wx * stt - 2.0 * mx * sxt + dg
    per = qz * i0 + qx * i1 + stt
    total = per.sum(-1) + S.n * torch.log(psz * psx * A * D).sum(-1)
    if hp.bayes:
        if hp.shared:
            per_b = 2.0 * hp.a * (0.5 * (wz + wx) + hp.b0) / b
        else:
            per_b = 2.0 * hp.a * (0.5 * wz + hp.b0) / b + hp.lam * wx
        total = total + per_b.sum(-1) + (2.0 * hp.a * torch.log(b) - torch.log(vz * vx)).sum(-1)
    L = -0.5 * S.n * torch.log(c) - (psy * S_ee / c + S.n * R) / (2.0 * c) - 0.5 * total
    return es, R, c, S_ee, L


def update(S: Stats, es, R, c, S_ee, st: torch.Tensor, psy: torch.Tensor, hp: Hyper):
    """Q(w_z), Q(w_x), Q(alpha) (or the maximum-likelihood W), then the M-step for the psi's.

    Args:
        es, R, c, S_ee: the E-step at ``(st, psy)`` (`estep`).

    Returns:
        The new ``(st, psy)``.
    """
    psz, psx = _row(st, PZ), _row(st, PX)
    n = S.n[..., None]
    _, szz, stt, szt, sxt = es.unbind(-2)
    i0, i1 = 1.0 / psz, 1.0 / psx
    if hp.bayes:
        ea = hp.a / _row(st, B)
        vz = 1.0 / (stt * i0 + ea)
        vx = 1.0 / (stt * i1 + (ea if hp.shared else hp.lam))
        mz = vz * szt * i0
        mx = vx * sxt * i1
    else:
        vz = torch.zeros_like(psz)
        vx = torch.zeros_like(psz)
        mz = szt / stt
        mx = sxt / stt
    wz, wx = mz * mz + vz, mx * mx + vx
    b = 0.5 * (wz + wx if hp.shared else wz) + hp.b0 if hp.bayes else _row(st, B)
    psz = ((wz * stt - 2.0 * mz * szt + szz) / n).clamp_min(hp.floor)
    if not hp.fixed_x:
        psx = ((wx * stt - 2.0 * mx * sxt + S.dg) / n).clamp_min(hp.floor)
    r = psy / c
    psy = (r * r * S_ee / S.n + r * R).clamp_min(hp.floor_y)
    return torch.stack([mz, mx, vz, vx, b, psz, psx], -2), psy


def optimal_rate(st: torch.Tensor, hp: Hyper) -> torch.Tensor:
    """The rate of Q(alpha) that maximises the bound for the loadings of ``st``, ``(*batch, d)``."""
    wz = _row(st, MZ) ** 2 + _row(st, VZ)
    if not hp.shared:
        return 0.5 * wz + hp.b0
    return 0.5 * (wz + _row(st, MX) ** 2 + _row(st, VX)) + hp.b0


def data_terms(mz, mx, vz, vx, psz, psx):
    """What the data see of each input, ``(*batch, d)`` each: ``tau = 1 + V_z / psi_z + V_x /
    psi_x``, the model's variance of ``x_m`` ``v = <w_x>^2 / tau + psi_x``, the noisy-input
    predictor ``k = <w_z><w_x> / (tau v)`` (eq. 3) and the input's share of ``c``, ``q = psi_z +
    <w_z>^2 psi_x / (tau v)`` (`reduced_bound`): ``(tau, v, k, q)``."""
    tau = 1.0 + vz / psz + vx / psx
    v = mx * mx / tau + psx
    k = mz * mx / (tau * v)
    q = psz + mz * mz * psx / (tau * v)
    return tau, v, k, q


def predictor(st: torch.Tensor) -> torch.Tensor:
    """The noisy-input predictor ``k`` (eq. 3) of a state, ``(*batch, d)``."""
    mz, mx, vz, vx, _, psz, psx = st.unbind(-2)
    return data_terms(mz, mx, vz, vx, psz, psx)[2]


def reduced_bound(
    S: Stats,
    mz: torch.Tensor,
    mx: torch.Tensor,
    vz: torch.Tensor,
    vx: torch.Tensor,
    psz: torch.Tensor,
    psx: torch.Tensor,
    psy: torch.Tensor,
    hp: Hyper,
) -> torch.Tensor:
    """The bound with Q(z, t) and Q(alpha) at their optima for the loadings and noise variances.

    With ``tau = 1 + V_z / psi_z + V_x / psi_x``, the model's variance of ``x_m``
    ``v = <w_x>^2 / tau + psi_x``, the predictor ``k = <w_z><w_x> / (tau v)`` and
    ``c = psi_y + sum_m (psi_z + <w_z>^2 psi_x / (tau v))``::

        L = sum_m [-N/2 log(2 pi v) - (X^T X)_mm / (2 v) - N/2 log tau]
            - N/2 log(2 pi c) - S_ee(k) / (2 c) + sum_m KL_m

    where ``S_ee(k) = y^T y - 2 k^T X^T y + k^T X^T X k`` and ``KL_m`` collects the prior and
    entropy terms of Q(w) and Q(alpha), with Q(alpha)'s rate at its optimum (`optimal_rate`).

    Args:
        S: the moments. mz, mx, vz, vx, psz, psx: ``(*batch, d)`` (``vz = vx = 0`` for maximum
            likelihood). psy: ``(*batch,)``.

    Returns:
        ``(*batch,)`` the bound, nats (equal to `estep`'s ``L`` plus `bound_const`).
    """
    n = S.n
    tau, v, k, q = data_terms(mz, mx, vz, vx, psz, psx)
    c = psy + q.sum(-1)
    S_ee = S.yy - 2.0 * (k * S.xy).sum(-1) + (k * matvec(S.xx, k)).sum(-1)
    d = mz.shape[-1]
    L = (
        -0.5 * n * (torch.log(v).sum(-1) + torch.log(tau).sum(-1) + torch.log(c))
        - 0.5 * (S.dg / v).sum(-1)
        - S_ee / (2.0 * c)
        - 0.5 * n * (d + 1) * LOG_2PI
    )
    if not hp.bayes:
        return L
    return L + kl_terms(mz, mx, vz, vx, hp).sum(-1)


def kl_terms(
    mz: torch.Tensor, mx: torch.Tensor, vz: torch.Tensor, vx: torch.Tensor, hp: Hyper
) -> torch.Tensor:
    """Each input's prior and entropy terms of Q(w), Q(alpha) in the bound, ``(*batch, d)``.

    ``E log p(w | alpha) + E log p(alpha) + H[Q(w)] + H[Q(alpha)]`` with Q(alpha)'s rate at
    its optimum (`optimal_rate`), nats.
    """
    a = hp.a
    wz, wx = mz * mz + vz, mx * mx + vx
    b = 0.5 * (wz + wx if hp.shared else wz) + hp.b0
    dig = _digamma(a)
    k_a = 1.0 if hp.shared else 0.5  # loadings under alpha
    a0 = a - k_a
    elog = dig - torch.log(b)  # <log alpha>
    ea = a / b  # <alpha>
    kl = (
        k_a * (elog - LOG_2PI)
        - 0.5 * ea * (wz + wx if hp.shared else wz)  # E log N(w; 0, 1/alpha)
        + (a0 * math.log(hp.b0) - math.lgamma(a0))
        + (a0 - 1.0) * elog
        - hp.b0 * ea  # E log Gamma(alpha; a0, b0)
        + 0.5 * (torch.log(vz) + torch.log(vx))
        + (1.0 + LOG_2PI)  # entropies of Q(w)
        + (a + math.lgamma(a) + (1.0 - a) * dig)
        - torch.log(b)  # entropy of Q(alpha)
    )
    if not hp.shared:  # E log N(w_x; 0, 1 / lam)
        kl = kl + 0.5 * (math.log(hp.lam) - LOG_2PI - hp.lam * wx)
    return kl


# ------------------------------------------------------- derivatives of each input's own terms
class InputTerms(NamedTuple):
    """What `input_curvature` needs of each input at packed coordinates (`input_terms`), ``(B,
    d)`` each: the means ``mz, mx``, the variances ``vz, vx, psz, psx``, ``a = V_z / psi_z``,
    ``beta = V_x / psi_x``, ``c1 = a psi_x``, ``iT = 1 / T`` with ``T = tau v = <w_x>^2 +
    psi_x + c1 + V_x``, the predictor ``k = <w_z><w_x> / T`` and the share ``q = psi_z +
    <w_z>^2 psi_x / T`` of ``c``."""

    mz: torch.Tensor
    mx: torch.Tensor
    vz: torch.Tensor
    vx: torch.Tensor
    psz: torch.Tensor
    psx: torch.Tensor
    a: torch.Tensor
    beta: torch.Tensor
    c1: torch.Tensor
    iT: torch.Tensor
    k: torch.Tensor
    q: torch.Tensor


def input_terms(th: torch.Tensor, psx_c: torch.Tensor, hp: Hyper) -> InputTerms:
    """`InputTerms` at each input's coordinates ``th (B, r, d)``: ``<w_z>, <w_x>, log V_z,
    log V_x, log psi_z`` and, unless psi_x is fixed (then ``psx_c (B, d)``), ``log psi_x``."""
    mz, mx = th[:, 0], th[:, 1]
    vz, vx, psz = torch.exp(th[:, 2]), torch.exp(th[:, 3]), torch.exp(th[:, 4])
    a = torch.exp(th[:, 2] - th[:, 4])
    if hp.fixed_x:
        psx, beta = psx_c, vx / psx_c
    else:
        psx, beta = torch.exp(th[:, 5]), torch.exp(th[:, 3] - th[:, 5])
    c1 = a * psx
    iT = 1.0 / (mx * mx + psx + c1 + vx)
    k = mz * mx * iT
    q = psz + mz * mz * psx * iT
    return InputTerms(mz, mx, vz, vx, psz, psx, a, beta, c1, iT, k, q)


def input_curvature(t: InputTerms, g_k, g_c, n, dg, hp: Hyper, r: int):
    """Each input's part of the bound's gradient and Hessian in its ``r`` coordinates
    (`input_terms`), written out: ``(grad (B, r, d), hess (B, r, r, d), jk (B, r, d), jq (B,
    r, d))``, the gradient and Hessian of ``F_m = f_m + g_k k_m + g_c q_m`` and the gradients
    of ``k_m`` and ``q_m``, for ``g_k (B, d)``, ``g_c (B, 1)`` held (the data's part of the
    bound, ``-N/2 log c - S_ee(k) / (2 c)``, to first order), ``n (B,)``, ``dg (B, d)``.

    Input m's own terms are ``f = -N/2 (log v + log tau) - (X^T X)_mm / (2 v)`` plus
    `kl_terms` less its constant, ``-a log b + (log V_z + log V_x) / 2`` (``- lam <w_x^2> /
    2`` with alpha on w_z alone; ``b`` Q(alpha)'s optimal rate). With ``T = tau v = <w_x>^2 +
    psi_x + V_z psi_x / psi_z + V_x``, ``F = -N/2 log T + M / T + g_c psi_z`` + the prior's
    terms, where ``M = -(X^T X)_mm tau / 2 + g_k <w_z><w_x> + g_c <w_z>^2 psi_x``; ``T``,
    ``M``, ``tau`` and ``b`` are sums of monomials in the means and of exponentials of the
    log-variances, so their derivatives are sparse, and the Hessian is those, two rank-one
    terms (of ``1 / T`` and ``log b``) and nothing else: a few full ``r x r`` products
    instead of one per operation."""
    mz, mx, vz, vx, psz, psx, a, beta, c1, iT, k, q = t
    n = n[:, None]
    hdg = 0.5 * dg
    zero = torch.zeros_like(mz)
    M = (g_k * mx + g_c * mz * psx) * mz - hdg * (1.0 + a + beta)
    phi = (0.5 * n + M * iT) * iT  # -dF/dT
    chi = (0.5 * n + 2.0 * M * iT) * iT * iT  # d2F/dT2
    gT = torch.stack([zero, 2.0 * mx, c1, vx, -c1, psx + c1][:r], 1)  # dT
    gM = [
        g_k * mx + 2.0 * g_c * mz * psx,
        g_k * mz,
        -hdg * a,
        -hdg * beta,
        hdg * a,
        hdg * beta + g_c * mz * mz * psx,
    ]
    gM = torch.stack(gM[:r], 1)
    extra = [zero, zero, zero, zero, g_c * psz, zero]  # gradient beyond -N/2 log T + M / T
    diag = [  # the Hessian's diagonal beyond the rank-one terms
        2.0 * g_c * psx * iT,
        -2.0 * phi,
        -hdg * a * iT - phi * c1,
        -hdg * beta * iT - phi * vx,
        -hdg * a * iT - phi * c1 + g_c * psz,
        (g_c * mz * mz * psx - hdg * beta) * iT - phi * (c1 + psx),
    ]
    off = {  # and its entries off the diagonal, (i, j) with i < j
        (0, 1): g_k * iT,
        (0, 5): 2.0 * g_c * mz * psx * iT,
        (2, 4): hdg * a * iT + phi * c1,
        (2, 5): -phi * c1,
        (4, 5): phi * c1,
        (3, 5): hdg * beta * iT,
    }
    p = 0.5 * chi[:, None] * gT - (iT * iT)[:, None] * gM
    hess = gT[:, :, None] * p[:, None] + p[:, :, None] * gT[:, None]
    if hp.bayes:
        s = 1.0 if hp.shared else 0.0
        b = 0.5 * (mz * mz + vz + s * (mx * mx + vx)) + hp.b0
        ib = 1.0 / b
        gb = torch.stack([mz, s * mx, 0.5 * vz, 0.5 * s * vx, zero, zero][:r], 1)
        rb = gb * (math.sqrt(hp.a) * ib)[:, None]
        hess = hess + rb[:, :, None] * rb[:, None]
        aib = hp.a * ib
        extra[0] = -aib * mz
        extra[1] = -aib * s * mx
        extra[2] = 0.5 - 0.5 * aib * vz
        extra[3] = 0.5 - 0.5 * aib * s * vx
        diag[0] = diag[0] - aib
        diag[1] = diag[1] - aib * s
        diag[2] = diag[2] - 0.5 * aib * vz
        diag[3] = diag[3] - 0.5 * aib * s * vx
        if not hp.shared:
            extra[1] = extra[1] - hp.lam * mx
            extra[3] = extra[3] - 0.5 * hp.lam * vx
            diag[1] = diag[1] - hp.lam
            diag[3] = diag[3] - 0.5 * hp.lam * vx
    grad = gM * iT[:, None] - phi[:, None] * gT + torch.stack(extra[:r], 1)
    hess.diagonal(dim1=1, dim2=2).add_(torch.stack(diag[:r], -1))
    for (i, j), h in off.items():
        if j < r:
            hess[:, i, j] += h
            hess[:, j, i] += h
    jk = torch.stack([mx * iT, mz * iT, zero, zero, zero, zero][:r], 1) - (k * iT)[:, None] * gT
    jq = [2.0 * mz * psx * iT, zero, zero, zero, psz, mz * mz * psx * iT]
    jq = torch.stack(jq[:r], 1) - ((q - psz) * iT)[:, None] * gT
    return grad, hess, jk, jq
