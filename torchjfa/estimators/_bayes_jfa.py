"""The update equations of (Bayesian) joint factor analysis regression, from moments alone.

Pure tensor functions behind `torchjfa.estimators.JFA` and `BayesianJFA` (``_jfa.py``): the
E-step, Q(w)/Q(alpha) and M-step updates, and the lower bound of ``docs/bayesian-jfa.md``, in
standardised units, plus SQUAREM's extrapolation (Varadhan and Roland, Scand. J. Stat. 2008)
used to speed up the slow directions. Each iteration costs one ``d x d`` mat-vec, whatever ``N``.
"""

from __future__ import annotations

import math

import torch

_LOG_2PI = math.log(2.0 * math.pi)


class _Stats:
    """Standardised moments of the active columns (unit variance, centred if asked)."""

    __slots__ = ("n", "xx", "xy", "yy", "dg")

    def __init__(self, n: float, xx: torch.Tensor, xy: torch.Tensor, yy: float) -> None:
        self.n, self.xx, self.xy, self.yy = n, xx, xy, yy
        self.dg = torch.diagonal(xx).clone()


# A state is the tuple (mz, mx, vz, vx, b, psz, psx, psy, wz2, wx2): posterior means and
# variances of w_z and w_x (variances 0 for maximum likelihood), the rate b of Q(alpha)
# (<alpha> = (a0 + 1) / b; unused for maximum likelihood), the noise variances (psy a float) and
# the second moments <w_z^2>, <w_x^2>. Hyper-parameters hp = (bayes, a0 + 1, b0, floor, fixed_x).
_LINEAR = (True, True, False, False, False, False, False, False)  # else extrapolated in log
_STEP_GROWTH = 4.0  # SQUAREM: growth of the largest step after a step at the cap is accepted


def _estep(S: _Stats, st: tuple, hp: tuple, const: float) -> tuple[tuple, float]:
    """The note's E-step, Q(z, t) and its expected statistics, and the lower bound there.

    The bound is evaluated with this Q(z, t), i.e. at its optimum for the state ``st`` (for
    maximum likelihood it is then the log-likelihood). Costs one ``d x d`` mat-vec; scalars are
    Python floats to keep the per-iteration overhead low.
    """
    mz, mx, vz, vx, b, psz, psx, psy, wz2, wx2 = st
    n = S.n
    iz, ix = psz.reciprocal(), psx.reciprocal()
    mzi, mxi = mz * iz, mx * ix
    A = torch.addcmul(wz2 * iz, wx2, ix).add_(1.0)
    iA = A.reciprocal()
    E, F = mzi * iA, mxi * iA
    D = torch.addcmul(iz, mzi, E, value=-1.0)
    invD = D.reciprocal()
    k = (E * mxi).mul_(invD)  # the noisy-input predictor, eq. (3)
    R = float(invD.sum())
    c = psy + R
    rho = invD * (1.0 / c)
    s_xe = torch.addmv(S.xy, S.xx, k, alpha=-1.0)  # the one d x d product: X^T e
    S_ee = S.yy - float(k @ (S.xy + s_xe))
    rs = rho * s_xe
    szx = torch.addcmul(rs, k, S.dg)  # sum_i <z_im> x_im
    sz2 = torch.addcmul(rho.square().mul_(S_ee), k, szx + rs)  # sum_i <z_im>^2
    szz_d = torch.addcmul(invD, rho, invD, value=-1.0)  # diag Sigma_zz
    ezd = E * szz_d  # diag Sigma_zt
    sxt = torch.addcmul(E * szx, F, S.dg)
    sztm = torch.addcmul(E * sz2, F, szx)  # sum_i <z_im><t_im>
    stt = torch.addcmul(E * sztm, F, sxt).add_(torch.addcmul(iA, E, ezd), alpha=n)
    szt = torch.add(sztm, ezd, alpha=n)
    szz = torch.add(sz2, szz_d, alpha=n)
    # the bound: -1/2 sum_m [...] collects the per-input terms
    qz = torch.addcmul(torch.addcmul(szz, mz, szt, value=-2.0), wz2, stt)
    qx = torch.addcmul(torch.addcmul(S.dg, mx, sxt, value=-2.0), wx2, stt)
    per = torch.log(psz * psx * A * D).mul_(n).addcmul_(qz, iz).addcmul_(qx, ix).add_(stt)
    if hp[0]:
        a, b0 = hp[1], hp[2]
        prior = (wz2 + wx2).mul_(0.5).add_(b0).div_(b).add_(torch.log(b))
        per.add_(prior, alpha=2.0 * a).sub_(torch.log(vz * vx))
    L = -0.5 * n * math.log(c) - (psy * S_ee / c + n * R) / (2.0 * c) - 0.5 * float(per.sum())
    return (k, R, c, S_ee, szz, stt, szt, sxt, iz, ix), L + const


def _update(S: _Stats, es: tuple, st: tuple, hp: tuple) -> tuple:
    """Q(w_z), Q(w_x), Q(alpha) (or the maximum-likelihood W), then the M-step for the psi's."""
    _, R, c, S_ee, szz, stt, szt, sxt, iz, ix = es
    b, psz, psx, psy = st[4:8]
    bayes, a, b0, floor, fixed_x, floor_y = hp
    if bayes:
        ea = b.reciprocal().mul_(a)
        vz = torch.addcmul(ea, stt, iz).reciprocal_()
        mz = (vz * szt).mul_(iz)
        vx = torch.addcmul(ea, stt, ix).reciprocal_()
        mx = (vx * sxt).mul_(ix)
        wz2, wx2 = torch.addcmul(vz, mz, mz), torch.addcmul(vx, mx, mx)
        b = (wz2 + wx2).mul_(0.5).add_(b0)
    else:
        mz, mx = szt / stt, sxt / stt
        vz = vx = st[2]  # zeros
        wz2, wx2 = mz * mz, mx * mx
    inv_n = 1.0 / S.n
    psz = torch.addcmul(torch.addcmul(szz, mz, szt, value=-2.0), wz2, stt)
    psz = psz.mul_(inv_n).clamp_min_(floor)
    if not fixed_x:
        psx = torch.addcmul(torch.addcmul(S.dg, mx, sxt, value=-2.0), wx2, stt)
        psx = psx.mul_(inv_n).clamp_min_(floor)
    r = psy / c
    psy = max(r * r * S_ee * inv_n + r * R, floor_y)
    return mz, mx, vz, vx, b, psz, psx, psy, wz2, wx2


def _bound_const(n: float, d: int, hp: tuple) -> float:
    """State-independent terms of the bound (the 2 pi's, the Gamma prior, the entropies)."""
    bayes, a, b0 = hp[0], hp[1], hp[2]
    const = -0.5 * n * _LOG_2PI * (1 + 3 * d) + n * d * (1.0 + _LOG_2PI)
    if bayes:
        a0 = a - 1.0
        dig = float(torch.special.digamma(torch.tensor(a, dtype=torch.float64)))
        per = (
            -_LOG_2PI  # the two Gaussian priors
            + a0 * math.log(b0)  # the Gamma prior, with <log alpha> = digamma(a) - log b
            - math.lgamma(a0)
            + a0 * dig
            + 1.0  # entropies of Q(w_z), Q(w_x): two halves of log(2 pi e)
            + _LOG_2PI
            + a  # entropy of Q(alpha)
            + math.lgamma(a)
            + (1.0 - a) * dig
        )
        const += d * per
    return const


def _pack(st: tuple, free: tuple) -> torch.Tensor:
    """The free entries of a state as one vector: means as they are, variances in log."""
    lin = [st[i] for i in free if _LINEAR[i]]
    pos = [st[i] for i in free if not _LINEAR[i] and i != 7]
    psy = torch.full((1,), st[7], dtype=st[0].dtype, device=st[0].device)
    return torch.cat(lin + [torch.log(torch.cat(pos + [psy]))])


def _unpack(th: torch.Tensor, like: tuple, free: tuple, hp: tuple) -> tuple:
    """Inverse of `_pack`; entries not in ``free`` are taken from ``like``."""
    d = like[0].shape[0]
    n_lin = sum(1 for i in free if _LINEAR[i])
    lin = th[: n_lin * d].split(d)
    pos = torch.exp(th[n_lin * d : -1]).split(d)
    out = list(like)
    it_lin, it_pos = iter(lin), iter(pos)
    for i in free:
        if _LINEAR[i]:
            out[i] = next(it_lin)
        elif i != 7:
            out[i] = next(it_pos).clamp_min(hp[3]) if i in (5, 6) else next(it_pos)
    out[7] = max(math.exp(float(th[-1])), hp[5])
    out[8] = torch.addcmul(out[2], out[0], out[0])
    out[9] = torch.addcmul(out[3], out[1], out[1])
    return tuple(out)


def _squarem(th0, th1, th2, step_max: float) -> tuple[torch.Tensor | None, float]:
    """SQUAREM's extrapolation (Varadhan and Roland 2008, scheme S3) from two plain sweeps.

    With ``r = th1 - th0`` and ``v = th2 - 2 th1 + th0`` (packed states, `_pack`),
    ``alpha = clamp(||r|| / ||v||, 1, step_max)`` and the new point is ``th0 + 2 alpha r +
    alpha^2 v`` (``alpha = 1`` gives ``th2``). Returns ``(point or None, alpha)``.
    """
    r = th1 - th0
    v = th2 - th1 - r
    sr2, sv2 = float(r @ r), float(v @ v)
    if not (sv2 > 0.0 and math.isfinite(sr2 / sv2)):
        return None, 1.0
    alpha = min(max(math.sqrt(sr2 / sv2), 1.0), step_max)
    if alpha == 1.0:
        return None, alpha
    return th0 + (2.0 * alpha) * r + (alpha * alpha) * v, alpha


def _coef(st: tuple, bayes: bool) -> torch.Tensor:
    """Eq. (4), the noiseless-input slope ``<w_z><w_x> / <w_x^2>`` (0, not 0/0, when pruned)."""
    return st[0] * st[1] / st[9] if bayes else st[0] / st[1]
