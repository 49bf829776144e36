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
        return t if self.idx is None else t[self.idx]

    def stats(self, S: Stats) -> Stats:
        return S if self.idx is None else Stats(*(t[self.idx] for t in S))

    def put(self, dst: torch.Tensor, rows: torch.Tensor) -> None:
        if self.idx is None:
            dst.copy_(rows)
        else:
            dst[self.idx] = rows

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
        dig = float(torch.special.digamma(torch.tensor(a, dtype=torch.float64)))
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
    dig = float(torch.special.digamma(torch.tensor(a, dtype=torch.float64)))
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
class Jet:
    """A ``(B, d)`` quantity with its gradient ``g (B, r, d)`` and Hessian ``h (B, r, r, d)``
    with respect to ``r`` coordinates of each input, where input m's value depends on its own
    coordinates alone (second-order forward mode: each derivative is written out once, per
    operation, for all inputs at once). ``g`` and ``h`` broadcast: a coordinate starts as
    ``g (1, r, 1)``, ``h (1, 1, 1, 1)``. Constants (floats, ``(B, d)`` or ``(B, 1)`` tensors)
    combine with jets on the right of ``*``, ``+``, ``-`` and ``/``."""

    __slots__ = ("v", "g", "h")

    def __init__(self, v: torch.Tensor, g: torch.Tensor, h: torch.Tensor) -> None:
        self.v, self.g, self.h = v, g, h

    @staticmethod
    def _up(c):  # a (B, d) constant against g (B, r, d) and h (B, r, r, d)
        return (c[..., None, :], c[..., None, None, :]) if torch.is_tensor(c) else (c, c)

    def __add__(self, o) -> Jet:
        if isinstance(o, Jet):
            return Jet(self.v + o.v, self.g + o.g, self.h + o.h)
        return Jet(self.v + o, self.g, self.h)

    __radd__ = __add__

    def __neg__(self) -> Jet:
        return Jet(-self.v, -self.g, -self.h)

    def __sub__(self, o) -> Jet:
        return self + (-o)

    def __rsub__(self, o) -> Jet:
        return (-self) + o

    def __mul__(self, o) -> Jet:
        if not isinstance(o, Jet):
            c1, c2 = self._up(o)
            return Jet(self.v * o, self.g * c1, self.h * c2)
        a1, a2 = self._up(self.v)
        b1, b2 = self._up(o.v)
        cross = self.g[..., :, None, :] * o.g[..., None, :, :]
        return Jet(
            self.v * o.v,
            a1 * o.g + b1 * self.g,
            a2 * o.h + b2 * self.h + cross + cross.transpose(-3, -2),
        )

    __rmul__ = __mul__

    def __truediv__(self, o) -> Jet:
        return self * (o.recip() if isinstance(o, Jet) else 1.0 / o)

    def _chain(self, f, f1, f2) -> Jet:
        """``F(self)`` from ``F``, ``F'`` and ``F''`` at ``self.v``."""
        gg = self.g[..., :, None, :] * self.g[..., None, :, :]
        return Jet(
            f,
            f1[..., None, :] * self.g,
            f1[..., None, None, :] * self.h + f2[..., None, None, :] * gg,
        )

    def exp(self) -> Jet:
        e = torch.exp(self.v)
        return self._chain(e, e, e)

    def log(self) -> Jet:
        i = 1.0 / self.v
        return self._chain(torch.log(self.v), i, -i * i)

    def recip(self) -> Jet:
        i = 1.0 / self.v
        return self._chain(i, -i * i, 2.0 * i * i * i)


def input_jets(th: torch.Tensor, psx_c: torch.Tensor, n: torch.Tensor, dg, hp: Hyper):
    """Each input's own terms of the bound, its predictor ``k`` and its share ``q`` of ``c``
    as `Jet` s in its coordinates ``th (B, r, d)``: ``<w_z>, <w_x>, log V_z, log V_x,
    log psi_z`` and, unless psi_x is fixed (then ``psx_c (B, d)``), ``log psi_x``.

    The own terms are ``-N/2 (log v + log tau) - (X^T X)_mm / (2 v)`` plus `kl_terms` less its
    constant: with Q(alpha)'s rate ``b`` at its optimum, ``-a log b + (log V_z + log V_x) / 2``
    (``- lam <w_x^2> / 2`` when alpha governs w_z alone). ``n (B,)``, ``dg (B, d)``.
    """
    B, r, d = th.shape
    eye = torch.eye(r, dtype=th.dtype, device=th.device)
    zero = th.new_zeros(1, 1, 1, 1)
    mz, mx, lvz, lvx, lpsz, *rest = (Jet(th[:, i], eye[i][None, :, None], zero) for i in range(r))
    vz, vx, psz = lvz.exp(), lvx.exp(), lpsz.exp()
    if hp.fixed_x:
        psx = psx_c
        tau = (lvz - lpsz).exp() + vx * (1.0 / psx_c) + 1.0
    else:
        psx = rest[0].exp()
        tau = (lvz - lpsz).exp() + (lvx - rest[0]).exp() + 1.0
    mx2 = mx * mx
    v = mx2 / tau + psx
    itv = (tau * v).recip()
    k = mz * mx * itv
    mz2 = mz * mz
    q = psz + mz2 * psx * itv
    own = (v.log() + tau.log()) * (-0.5 * n[:, None]) - v.recip() * (0.5 * dg)
    if hp.bayes:
        wz, wx = mz2 + vz, mx2 + vx
        b = ((wz + wx) if hp.shared else wz) * 0.5 + hp.b0
        own = own + b.log() * (-hp.a) + (lvz + lvx) * 0.5
        if not hp.shared:
            own = own + wx * (-0.5 * hp.lam)
    return own, k, q
