"""The lasso (L1-penalised least squares) by coordinate descent on the Gram matrix.

Use `Lasso` when only a few inputs matter and the others should get coefficient exactly 0;
`Stepwise` does the same by hypothesis tests, `Ridge` shrinks without selecting.

The objective is scikit-learn's, ``(1 / (2 n)) ||y - X b - c||^2 + alpha ||b||_1`` with ``n``
the total weight and an unpenalised intercept ``c``. Coordinate descent needs only the (centred)
Gram matrix ``S`` and cross-moment ``s``: with ``g = s - S b``, coordinate ``j`` becomes
``soft(g_j + S_jj b_j, n alpha) / S_jj``. Once the signs of the support stop changing, the
exact solution on that support, ``S_AA b_A = s_A - n alpha sign(b_A)``, is computed and kept if
it satisfies the optimality (KKT) conditions, so the result is exact to rounding rather than to
a stopping tolerance. Cross-validation problems (one per fold) are solved together as a batch
along the path of penalties, each warm-started from the previous penalty (like
`sklearn.linear_model.LassoCV`).
"""

from __future__ import annotations

import math
import numbers
import warnings

import torch

from .._progress import progress_bar
from ..stats import Moments
from ._cv import MomentEstimator, check_grid, check_positive_real, cv_mse, train_test_splits
from ._linear import min_norm_solve

__all__ = ["Lasso", "lasso_path"]


def _polish(sxx: torch.Tensor, sxy: torch.Tensor, lam: torch.Tensor, coef: torch.Tensor):
    """Try to finish one lasso problem exactly from the support and signs of ``coef``.

    On the orthant of ``coef``'s signs the objective is the smooth quadratic whose minimiser
    solves ``S_AA b_A = s_A - lam sign_A``. If that minimiser keeps the signs and satisfies the
    optimality conditions of the inactive coordinates, it is the lasso solution. Otherwise the
    point on the segment from ``coef`` towards it where the first coordinate changes sign (or the
    minimiser itself) has a lower objective, and is returned for coordinate descent to continue
    from (the feature-sign step of Lee et al., 2007).

    Shapes: ``sxx`` ``(d, d)``, ``sxy`` ``(d,)``, ``lam`` 0-d (``n alpha``), ``coef`` ``(d,)``.

    Returns:
        ``(point, exact)``: the new iterate (None when the support's Gram matrix is singular
        and the stationarity system has no solution) and whether it is the solution.
    """
    support = coef != 0
    out = torch.zeros_like(coef)
    if bool(support.any()):
        signs = torch.sign(coef[support])
        sub = sxx[support][:, support]
        rhs = sxy[support] - lam * signs
        chol, info = torch.linalg.cholesky_ex(sub)
        if int(info) == 0:
            sol = torch.cholesky_solve(rhs[:, None], chol)[:, 0]
        else:  # singular, e.g. duplicated inputs: any minimiser will do if the system is consistent
            sol = min_norm_solve(sub, rhs)[0]
            if float((sub @ sol - rhs).abs().max()) > 1e-9 * float(rhs.abs().max() + lam):
                return None, False
        flipped = torch.sign(sol) != signs
        if bool(flipped.any()):
            cur = coef[support]
            ratio = cur[flipped] / (cur[flipped] - sol[flipped])  # in (0, 1]
            k = int(torch.argmin(ratio))
            point = cur + ratio[k] * (sol - cur)
            point[torch.nonzero(flipped).flatten()[k]] = 0.0
            out[support] = point
            return out, False
        out[support] = sol
    grad = sxy - sxx @ out
    slack = lam * (1 + 1e-11) + 1e-13 * sxy.abs().max()
    return out, not bool((grad[~support].abs() > slack).any())


def _coordinate_descent(sxx, sxy, lam, coef, *, tol: float, max_iter: int):
    """Solve a batch of lasso problems in place, starting from ``coef``.

    Args:
        sxx: ``(B, d, d)``; sxy: ``(B, d)``; lam: ``(B,)`` thresholds ``n alpha``.
        coef: ``(B, d)`` warm start, overwritten with the solutions.
        tol: stop a problem when no coordinate moved more than ``tol * max |coef|`` in a sweep
            (only needed when the exact step does not apply, e.g. singular ``S_AA``).
        max_iter: maximum number of sweeps.

    Returns:
        ``(n_sweeps, converged)``.
    """
    n_batch, d = sxy.shape
    diag = torch.diagonal(sxx, dim1=1, dim2=2)  # (B, d)
    usable = diag > 0
    safe = torch.where(usable, diag, torch.ones_like(diag))
    grad = sxy - torch.einsum("bij,bj->bi", sxx, coef)  # (B, d)
    done = torch.zeros(n_batch, dtype=torch.bool, device=sxy.device)
    for sweep in range(1, max_iter + 1):
        step = torch.zeros(n_batch, dtype=sxy.dtype, device=sxy.device)
        for j in range(d):
            old = coef[:, j]
            rho = grad[:, j] + diag[:, j] * old
            new = torch.sign(rho) * (rho.abs() - lam).clamp_min(0) / safe[:, j]
            new = torch.where(usable[:, j] & ~done, new, torch.where(done, old, 0.0))
            delta = new - old
            grad -= delta[:, None] * sxx[:, :, j]
            coef[:, j] = new
            step = torch.maximum(step, delta.abs())
        scale = coef.abs().amax(1).clamp_min(torch.finfo(coef.dtype).tiny)
        stalled = step <= tol * scale
        for i in torch.nonzero(~done).flatten().tolist():
            point, exact = _polish(sxx[i], sxy[i], lam[i], coef[i])
            if point is not None:
                coef[i] = point
                grad[i] = sxy[i] - sxx[i] @ point
                done[i] = exact
        done |= stalled
        if bool(done.all()):
            return sweep, True
    return max_iter, False


def lasso_path(
    sxx: torch.Tensor,
    sxy: torch.Tensor,
    n: torch.Tensor,
    alphas: torch.Tensor,
    *,
    tol: float = 1e-10,
    max_iter: int = 10_000,
    verbose: bool = False,
) -> tuple[torch.Tensor, list[int]]:
    """Lasso solutions of a batch of problems along a path of penalties, with warm starts.

    Args:
        sxx: Gram matrices (centred when fitting an intercept), shape ``(B, d, d)``.
        sxy: cross-moments, shape ``(B, d)``.
        n: total weight of each problem, shape ``(B,)``.
        alphas: penalties, shape ``(A,)``, best in decreasing order (for the warm starts).
        tol: coordinate-descent fallback tolerance (see `Lasso`).
        max_iter: maximum sweeps per penalty.
        verbose: progress bar over the penalties.

    Returns:
        ``(coefs, n_iter)``: coefficients of shape ``(A, B, d)`` and the sweeps used per penalty.
    """
    n_batch, d = sxy.shape
    coef = torch.zeros(n_batch, d, dtype=sxy.dtype, device=sxy.device)
    out = torch.empty(len(alphas), n_batch, d, dtype=sxy.dtype, device=sxy.device)
    n_iter = []
    with progress_bar(total=len(alphas), desc="lasso path", enabled=verbose) as bar:
        for a, alpha in enumerate(alphas):
            sweeps, ok = _coordinate_descent(sxx, sxy, n * alpha, coef, tol=tol, max_iter=max_iter)
            if not ok:
                warnings.warn(
                    f"lasso coordinate descent did not converge in {max_iter} sweeps at "
                    f"alpha={float(alpha):.3g}; increase max_iter or tol",
                    RuntimeWarning,
                    stacklevel=3,
                )
            out[a] = coef
            n_iter.append(sweeps)
            bar.update(1)
    return out, n_iter


class Lasso(MomentEstimator):
    """L1-penalised least squares: ``(1/(2n)) ||y - X b - c||^2 + alpha ||b||_1``.

    The scaling of ``alpha`` is `sklearn.linear_model.Lasso`'s (``n`` is the total weight, so
    weighted moments match scikit-learn's ``sample_weight``).

    Args:
        alpha: penalty, ``> 0``; ``None`` to choose it by ``cv``-fold cross-validation along a
            path of ``n_alphas`` penalties log-spaced from ``alpha_max = max |Sxy| / n`` (the
            smallest penalty with all coefficients 0) down to ``eps * alpha_max``, like
            `sklearn.linear_model.LassoCV`.
        alphas: explicit candidate penalties for cross-validation (overrides the default grid).
        n_alphas: size of the default grid.
        eps: ratio of the smallest to the largest penalty of the default grid.
        tol: fallback stopping tolerance of coordinate descent (largest coordinate change
            relative to the largest coefficient), used when the exact polish step does not
            apply.
        max_iter: maximum coordinate-descent sweeps per penalty.
        fit_intercept: centre the moments and fit an unpenalised intercept.
        cv: number of contiguous folds used by `fit` when ``alpha`` is None.
        verbose: progress bar over the path.

    Attributes:
        coef_, intercept_: the fitted model.
        alpha_: the penalty used.
        alphas_: the path, decreasing, shape ``(n_alphas,)`` (CV only).
        mse_path_: validation mean squared error, shape ``(n_alphas, n_folds)`` (CV only);
            ``alpha_`` is the argmin of its mean over folds.
        n_iter_: coordinate-descent sweeps of the final fit.
    """

    _uses_folds = True

    def __init__(
        self,
        *,
        alpha: float | None = None,
        alphas=None,
        n_alphas: int = 100,
        eps: float = 1e-3,
        tol: float = 1e-10,
        max_iter: int = 10_000,
        fit_intercept: bool = True,
        cv: int = 5,
        verbose: bool = False,
    ) -> None:
        super().__init__(fit_intercept=fit_intercept, cv=cv, verbose=verbose)
        self.alpha = alpha
        self.alphas = alphas
        self.n_alphas = n_alphas
        self.eps = eps
        self.tol = tol
        self.max_iter = max_iter

    def _needs_folds(self) -> bool:
        return self.alpha is None

    def _check_params(self, n_features: int) -> None:
        if self.alpha is not None:
            check_positive_real(self.alpha, "alpha")
        check_positive_real(self.tol, "tol")
        for name in ("n_alphas", "max_iter"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        eps = check_positive_real(self.eps, "eps")
        if eps >= 1:
            raise ValueError(f"eps must be in (0, 1), got {self.eps!r}")

    def _solve(self, moments: Moments, folds) -> torch.Tensor:
        sxx, sxy, _, n = self._centered(moments)
        kw = {"tol": float(self.tol), "max_iter": int(self.max_iter)}
        if self.alpha is not None:
            self.alpha_ = float(self.alpha)
            alphas = torch.tensor([self.alpha_], dtype=sxx.dtype, device=sxx.device)
            coefs, n_iter = lasso_path(sxx[None], sxy[None], n[None], alphas, **kw)
            self.n_iter_ = n_iter[0]
            return coefs[0, 0]
        if self.alphas is None:
            alpha_max = float(sxy.abs().max() / n)
            if alpha_max == 0.0:  # y uncorrelated with X: every alpha gives 0
                alpha_max = float(torch.finfo(sxx.dtype).eps)
            grid = torch.logspace(
                math.log10(alpha_max),
                math.log10(alpha_max * float(self.eps)),
                int(self.n_alphas),
                dtype=sxx.dtype,
                device=sxx.device,
            )
        else:
            grid = check_grid(self.alphas, "alphas", device=sxx.device)
            grid = torch.sort(grid, descending=True).values
        splits = train_test_splits(moments, folds)
        problems = [self._centered(train) for train, _ in splits] + [(sxx, sxy, None, n)]
        coefs, n_iter = lasso_path(
            torch.stack([p[0] for p in problems]),
            torch.stack([p[1] for p in problems]),
            torch.stack([p[3] for p in problems]),
            grid,
            verbose=self.verbose,
            **kw,
        )  # (A, K + 1, d)
        fold_coefs = [coefs[:, k] for k in range(len(splits))]
        self.mse_path_ = cv_mse(splits, fold_coefs, self.fit_intercept)
        self.alphas_ = grid
        best = int(torch.argmin(self.mse_path_.mean(1)))
        self.alpha_ = float(grid[best])
        self.n_iter_ = n_iter[best]
        return coefs[best, -1]
