"""Stepwise regression: variable selection by partial F-tests, from sufficient statistics.

Use `Stepwise` when a small, interpretable subset of the inputs is wanted and a classical
hypothesis-test criterion is acceptable; `Lasso` selects by a penalty chosen by
cross-validation instead. Forward selection adds, at each step, the input whose partial F-test

    F = (RSS_current - RSS_with_j) / (RSS_with_j / (n - k - [fit_intercept]))

(``k`` inputs in the enlarged model, ``n`` the total weight) has the smallest p-value, as long
as that p-value is below ``p_enter``; with ``p_remove`` set, after each entry the input whose
removal has the largest p-value is dropped while that p-value exceeds ``p_remove``
(bidirectional selection, Efroymson 1960). Every RSS is a Schur complement of the (centred)
Gram matrix, so no pass over the data is needed.
"""

from __future__ import annotations

import math
import numbers

import torch

from ..stats import Moments, as_folds
from ._cv import MomentEstimator
from ._linear import min_norm_solve

__all__ = ["Stepwise", "f_sf"]

_BETAINC_MAX_ITER = 100_000


def _betainc_cf(a: torch.Tensor, b: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """Regularised incomplete beta ``I_x(a, b)`` by its continued fraction (modified Lentz).

    Converges quickly where ``x < (a + 1) / (a + b + 2)``; the caller uses the symmetry
    ``I_x(a, b) = 1 - I_(1-x)(b, a)`` elsewhere.
    """
    tiny = 1e-300
    eps = torch.finfo(x.dtype).eps
    qab, qap, qam = a + b, a + 1, a - 1
    c = torch.ones_like(x)
    d = 1 - qab * x / qap
    d = torch.where(d.abs() < tiny, torch.full_like(d, tiny), d)
    d = 1 / d
    h = d.clone()
    for m in range(1, _BETAINC_MAX_ITER + 1):
        m2 = 2 * m
        for aa in (
            m * (b - m) * x / ((qam + m2) * (a + m2)),
            -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2)),
        ):
            d = 1 + aa * d
            d = torch.where(d.abs() < tiny, torch.full_like(d, tiny), d)
            c = 1 + aa / c
            c = torch.where(c.abs() < tiny, torch.full_like(c, tiny), c)
            d = 1 / d
            delta = d * c
            h = h * delta
        if bool(((delta - 1).abs() <= 4 * eps).all()):
            break
    log_front = (
        torch.lgamma(a + b)
        - torch.lgamma(a)
        - torch.lgamma(b)
        + a * torch.log(x)
        + b * torch.log1p(-x)
    )
    return torch.exp(log_front) * h / a


def f_sf(f: torch.Tensor, dfn: float, dfd: float) -> torch.Tensor:
    """Survival function ``P(F > f)`` of the F distribution with ``(dfn, dfd)`` degrees of freedom.

    ``P(F > f) = I_(dfd / (dfd + dfn f))(dfd / 2, dfn / 2)`` (regularised incomplete beta),
    evaluated in the input's dtype; the p-value of a partial F-test.

    Args:
        f: F statistics, any shape, ``>= 0``.
        dfn, dfd: numerator and denominator degrees of freedom, ``> 0``.
    """
    f = torch.as_tensor(f)
    f = f.to(torch.float64) if not f.is_floating_point() else f
    x = dfd / (dfd + dfn * f.clamp_min(0))
    a = torch.full_like(x, dfd / 2)
    b = torch.full_like(x, dfn / 2)
    direct = x < (a + 1) / (a + b + 2)
    xs = torch.where(direct, x, 1 - x).clamp(1e-300, 1 - 1e-16)
    val = _betainc_cf(torch.where(direct, a, b), torch.where(direct, b, a), xs)
    out = torch.where(direct, val, 1 - val)
    out = torch.where(x >= 1, torch.ones_like(out), out)  # f == 0
    return torch.where(x <= 0, torch.zeros_like(out), out).clamp(0, 1)  # f == inf


class Stepwise(MomentEstimator):
    """Forward (optionally bidirectional) stepwise regression by partial F-tests.

    Args:
        p_enter: an input enters when its partial F-test p-value is below this, in ``(0, 1)``.
        p_remove: if given, an input in the model is removed when its p-value exceeds this;
            must be in ``(p_enter, 1)`` so that selection cannot cycle.
        max_features: stop after this many inputs are in the model (default: no limit).
        fit_intercept: centre the moments and fit an intercept (always in the model).

    Attributes:
        coef_, intercept_: least-squares fit on the selected inputs (0 elsewhere).
        selected_: indices of the selected inputs, in order of entry.
        steps_: the selection history, a list of ``(action, index, F, p_value)`` with action
            ``"enter"`` or ``"remove"``.
    """

    def __init__(
        self,
        *,
        p_enter: float = 0.05,
        p_remove: float | None = None,
        max_features: int | None = None,
        fit_intercept: bool = True,
    ) -> None:
        super().__init__(fit_intercept=fit_intercept)
        self.p_enter = p_enter
        self.p_remove = p_remove
        self.max_features = max_features

    def _check_params(self, n_features: int) -> None:
        for name in ("p_enter", "p_remove"):
            value = getattr(self, name)
            if value is None and name == "p_remove":
                continue
            if isinstance(value, bool) or not isinstance(value, numbers.Real):
                raise TypeError(f"{name} must be a real number, got {value!r}")
            if not 0 < float(value) < 1:
                raise ValueError(f"{name} must be in the open interval (0, 1), got {value!r}")
        if self.p_remove is not None and not self.p_remove > self.p_enter:
            raise ValueError(
                f"p_remove ({self.p_remove}) must be larger than p_enter ({self.p_enter}), "
                "otherwise an input could enter and leave forever"
            )
        if self.max_features is not None and (
            isinstance(self.max_features, bool)
            or not isinstance(self.max_features, numbers.Integral)
            or self.max_features < 1
        ):
            raise ValueError(f"max_features must be a positive integer, got {self.max_features!r}")

    def fit_moments(self, moments):
        """Fit from sufficient statistics (a `Moments`, or fold moments, which are summed)."""
        super().fit_moments(moments)
        total, _ = as_folds(moments)
        active = torch.nonzero(self._active_columns(total)).flatten().tolist()
        self.selected_ = [active[i] for i in self.selected_]
        self.steps_ = [(act, active[i], f, p) for act, i, f, p in self.steps_]
        return self

    def _solve(self, moments: Moments, folds) -> torch.Tensor:
        sxx, sxy, syy, n = self._centered(moments)
        d = sxx.shape[0]
        n = float(n)
        offset = 1 if self.fit_intercept else 0
        limit = d if self.max_features is None else min(int(self.max_features), d)
        selected: list[int] = []
        steps: list[tuple[str, int, float, float]] = []
        diag = torch.diagonal(sxx)
        for _ in range(4 * d + 4):  # entries and removals; bounded to rule out cycling
            rss, coef = self._rss(sxx, sxy, syy, selected)
            dfd = n - len(selected) - 1 - offset  # residual df after adding one input
            if len(selected) >= limit or dfd <= 0:
                break
            # residual gradient and Schur complements of every candidate given the selection
            if selected:
                cross = sxx[:, selected]  # (d, k)
                grad = sxy - cross @ coef
                inv_cross = torch.linalg.lstsq(sxx[selected][:, selected], cross.T).solution
                schur = diag - (cross * inv_cross.T).sum(1)
            else:
                grad, schur = sxy.clone(), diag.clone()
            ok = schur > 1e-10 * diag
            ok[selected] = False
            if not bool(ok.any()):
                break
            gain = torch.where(ok, grad**2 / torch.where(ok, schur, 1.0), -1.0)
            j = int(torch.argmax(gain))
            rss_new = max(float(rss - gain[j]), 0.0)
            f = math.inf if rss_new == 0 else float(gain[j]) / (rss_new / dfd)
            p = float(f_sf(torch.tensor(f, dtype=torch.float64), 1.0, dfd))
            if not p < self.p_enter:
                break
            selected.append(j)
            steps.append(("enter", j, f, p))
            if self.p_remove is not None:
                self._remove(sxx, sxy, syy, n, offset, selected, steps)
        self.selected_, self.steps_ = selected, steps
        coef = torch.zeros(d, dtype=sxx.dtype, device=sxx.device)
        if selected:
            coef[selected] = self._rss(sxx, sxy, syy, selected)[1]
        return coef

    def _remove(self, sxx, sxy, syy, n, offset, selected, steps) -> None:
        """Backward step: drop the least significant inputs while their p-value > p_remove."""
        while len(selected) > 1:
            rss_full, _ = self._rss(sxx, sxy, syy, selected)
            dfd = n - len(selected) - offset
            if dfd <= 0:
                return
            stats = []
            for i in selected[:-1]:  # the input that just entered stays
                rest = [k for k in selected if k != i]
                rss_without, _ = self._rss(sxx, sxy, syy, rest)
                diff = max(float(rss_without - rss_full), 0.0)
                f = math.inf if float(rss_full) <= 0 else diff / (float(rss_full) / dfd)
                stats.append((f, i))
            f, i = min(stats)
            p = float(f_sf(torch.tensor(f, dtype=torch.float64), 1.0, dfd))
            if not p > self.p_remove:
                return
            selected.remove(i)
            steps.append(("remove", i, f, p))

    @staticmethod
    def _rss(sxx, sxy, syy, subset) -> tuple[torch.Tensor, torch.Tensor]:
        """Residual sum of squares and coefficients of least squares on ``subset``."""
        if not subset:
            return syy, sxx.new_zeros(0)
        coef = min_norm_solve(sxx[subset][:, subset], sxy[subset])[0]
        return syy - coef @ sxy[subset], coef
