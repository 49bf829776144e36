"""The update equations of (Bayesian) joint factor analysis regression, from moments alone.

Pure array functions behind `torchjfa.estimators.JFA` and `BayesianJFA` (``_jfa.py``): the
E-step, Q(w)/Q(alpha) and M-step updates, and the lower bound of ``docs/bayesian-jfa.md``, in
standardised units, plus SQUAREM's extrapolation (Varadhan and Roland, Scand. J. Stat. 2008)
used to speed up the slow directions. Each iteration costs one ``d x d`` mat-vec, whatever ``N``.

Why NumPy here: after the single pass over the data, the loop works on ``O(d^2)`` numbers
(``d`` is a few hundred at most), so its time is per-operation overhead, not arithmetic. A
float64 NumPy operation on a ``(2, d)`` array costs about 1 us, a torch CPU operation 3 to 5 us
and a CUDA launch more (plus a sync for every stopping test). The estimators therefore run the
loop on CPU NumPy copies of the moments, whatever the device of the data, and hand tensors on
the data's device back. The z and x halves of the model are stacked into ``(2, d)`` arrays
(row 0: z, row 1: x) so that each line below updates both at once.
"""

from __future__ import annotations

import math

import numpy as np
import torch

_LOG_2PI = math.log(2.0 * math.pi)
_STEP_GROWTH = 4.0  # SQUAREM: growth of the largest step after a step at the cap is accepted


class _Stats:
    """Standardised moments of the active columns (unit variance, centred if asked), float64."""

    __slots__ = ("n", "xx", "xy", "yy", "dg")

    def __init__(self, n: float, xx: np.ndarray, xy: np.ndarray, yy: float) -> None:
        self.n, self.xx, self.xy, self.yy = float(n), xx, xy, float(yy)
        self.dg = np.ascontiguousarray(np.diagonal(xx))


# A state is the tuple (M, V, W2, b, P, psy): M = [<w_z>; <w_x>] and V = their posterior
# variances, shape (2, d) (V = 0 for maximum likelihood), W2 = M^2 + V the second moments, b the
# rate of Q(alpha), shape (d,) (<alpha> = (a0 + 1) / b; unused for maximum likelihood),
# P = [psi_z; psi_x], shape (2, d), and psy = psi_y, a float.
# Hyper-parameters hp = (bayes, a0 + 1, b0, floor, fixed_x, floor_y).


def _estep(S: _Stats, st: tuple, hp: tuple, const: float, bound: bool = True) -> tuple:
    """The note's E-step, Q(z, t) and its expected statistics, and the lower bound there.

    The bound is evaluated with this Q(z, t), i.e. at its optimum for the state ``st`` (for
    maximum likelihood it is then the log-likelihood); ``bound=False`` skips it (returns NaN).
    Returns ``(es, L)`` with ``es = (k, R, c, S_ee, szz, stt, Ct, I)``: the noisy-input
    predictor ``k``, ``R = sum 1/D``, ``c = psy + R``, the residual sum of squares, ``S_zz``,
    ``S_tt``, ``Ct = [S_zt; S_xt]`` and ``I = 1 / P``.
    """
    M, V, W2, b, P, psy = st
    n, dg = S.n, S.dg
    I = 1.0 / P
    MI = M * I
    A = (W2 * I).sum(0)
    A += 1.0
    iA = 1.0 / A
    EF = MI * iA  # [E; F]
    E = EF[0]
    D = I[0] - MI[0] * E
    invD = 1.0 / D
    k = E * MI[1]
    k *= invD  # the noisy-input predictor, eq. (3)
    R = float(invD.sum())
    c = psy + R
    s_xe = S.xy - S.xx @ k  # the one d x d product: X^T e
    S_ee = S.yy - float(k @ (S.xy + s_xe))
    rho = invD * (1.0 / c)
    rs = rho * s_xe
    U = np.empty((3, dg.shape[0]))  # [sum <z>^2; sum <z> x; diag X^T X]
    np.multiply(k, dg, out=U[1])
    U[1] += rs
    np.add(U[1], rs, out=U[0])
    U[0] *= k
    U[0] += (S_ee * rho) * rho
    U[2] = dg
    szz_d = invD - rho * invD  # diag Sigma_zz
    ezd = E * szz_d  # diag Sigma_zt
    Ct = E * U[:2]
    Ct += EF[1] * U[1:]  # [sum <z><t>; S_xt]
    stt = (EF * Ct).sum(0)
    stt += n * (iA + E * ezd)
    Ct[0] += n * ezd  # S_zt
    szz = U[0] + n * szz_d
    es = (k, R, c, S_ee, szz, stt, Ct, I)
    if not bound:
        return es, math.nan
    # the bound: -1/2 sum_m [...] collects the per-input terms
    Q = W2 * stt
    Q -= 2.0 * (M * Ct)
    Q[0] += szz
    Q[1] += dg
    per = n * float(np.log(P[0] * P[1] * A * D).sum()) + float(np.vdot(Q, I)) + float(stt.sum())
    if hp[0]:
        a, b0 = hp[1], hp[2]
        quad = float(np.vdot(W2.sum(0) * 0.5 + b0, 1.0 / b)) + float(np.log(b).sum())
        per += 2.0 * a * quad - float(np.log(V[0] * V[1]).sum())
    L = -0.5 * n * math.log(c) - (psy * S_ee / c + n * R) / (2.0 * c) - 0.5 * per
    return es, L + const


def _update(S: _Stats, es: tuple, st: tuple, hp: tuple) -> tuple:
    """Q(w_z), Q(w_x), Q(alpha) (or the maximum-likelihood W), then the M-step for the psi's."""
    _, R, c, S_ee, szz, stt, Ct, I = es
    V, b, P, psy = st[1], st[3], st[4], st[5]
    bayes, a, b0, floor, fixed_x, floor_y = hp
    if bayes:
        V = stt * I
        V += a / b
        V = np.reciprocal(V, out=V)
        M = V * Ct
        M *= I
        W2 = M * M
        W2 += V
        b = W2.sum(0)
        b *= 0.5
        b += b0
    else:
        M = Ct / stt
        W2 = M * M
    Q = W2 * stt
    Q -= 2.0 * (M * Ct)
    Q[0] += szz
    Q[1] += S.dg
    Q *= 1.0 / S.n
    Pn = np.maximum(Q, floor, out=Q)
    if fixed_x:
        Pn[1] = P[1]
    r = psy / c
    psy = max(r * r * S_ee / S.n + r * R, floor_y)
    return M, V, W2, b, Pn, psy


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


def _pack(st: tuple, hp: tuple) -> np.ndarray:
    """The free entries of a state as one vector: means as they are, variances in log."""
    M, V, _, b, P, psy = st
    pos = [P[0] if hp[4] else P.ravel(), [psy]]
    if hp[0]:
        pos = [V.ravel(), b] + pos
    return np.concatenate((M.ravel(), np.log(np.concatenate(pos))))


def _unpack(th: np.ndarray, like: tuple, hp: tuple) -> tuple:
    """Inverse of `_pack`; the fixed psi_x (if any) is taken from ``like``."""
    bayes, floor, fixed_x, floor_y = hp[0], hp[3], hp[4], hp[5]
    d = like[0].shape[1]
    M = th[: 2 * d].reshape(2, d)
    pos = np.exp(th[2 * d : -1])
    if bayes:
        V, b, pp = pos[: 2 * d].reshape(2, d), pos[2 * d : 3 * d], pos[3 * d :]
    else:
        V, b, pp = like[1], like[3], pos
    if fixed_x:
        P = np.stack((np.maximum(pp, floor), like[4][1]))
    else:
        P = np.maximum(pp.reshape(2, d), floor)
    psy = max(math.exp(min(float(th[-1]), 700.0)), floor_y)
    return M, V, M * M + V, b, P, psy


def _squarem(th0, th1, th2, step_max: float) -> tuple[np.ndarray | None, float]:
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


def _coef(st: tuple, bayes: bool) -> np.ndarray:
    """Eq. (4), the noiseless-input slope ``<w_z><w_x> / <w_x^2>`` (0, not 0/0, when pruned)."""
    M = st[0]
    return M[0] * M[1] / st[2][1] if bayes else M[0] / M[1]
