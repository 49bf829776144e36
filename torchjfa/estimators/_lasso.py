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

import numpy as np
import torch

from .._util import progress_bar
from ..stats import Moments
from ._cv import MomentEstimator, check_grid, check_positive_real, cv_mse, train_test_splits

__all__ = ["Lasso", "lasso_path"]


def _min_norm_solve_np(sxx: np.ndarray, sxy: np.ndarray, rcond: float = 1e-12) -> np.ndarray:
    """NumPy twin of `min_norm_solve` (scaled eigen-decomposition pseudo-inverse)."""
    scale = np.sqrt(np.clip(np.diagonal(sxx), 0, None))
    scale = np.where(scale > 0, scale, 1.0)
    corr = sxx / np.outer(scale, scale)
    evals, evecs = np.linalg.eigh(0.5 * (corr + corr.T))
    keep = evals > rcond * max(evals[-1], np.finfo(evals.dtype).tiny)
    z = evecs[:, keep].T @ (sxy / scale)
    return (evecs[:, keep] @ (z / evals[keep])) / scale


def _polish(sxx: np.ndarray, sxy: np.ndarray, lam: float, coef: np.ndarray):
    """Try to finish one lasso problem exactly from the support and signs of ``coef``.

    On the orthant of ``coef``'s signs the objective is the smooth quadratic whose minimiser
    solves ``S_AA b_A = s_A - lam sign_A``. If that minimiser keeps the signs and satisfies the
    optimality conditions of the inactive coordinates, it is the lasso solution. Otherwise the
    point on the segment from ``coef`` towards it where the first coordinate changes sign (or the
    minimiser itself) has a lower objective, and is returned for coordinate descent to continue
    from (the feature-sign step of Lee et al., 2007).

    Shapes: ``sxx`` ``(d, d)``, ``sxy`` ``(d,)``, ``lam`` (``n alpha``), ``coef`` ``(d,)``;
    NumPy float64 (the coordinate-descent loop runs in NumPy: its cost is per-op overhead).

    Returns:
        ``(point, exact)``: the new iterate (None when the support's Gram matrix is singular
        and the stationarity system has no solution) and whether it is the solution.
    """
    support = coef != 0
    out = np.zeros_like(coef)
    if support.any():
        signs = np.sign(coef[support])
        sub = sxx[np.ix_(support, support)]
        rhs = sxy[support] - lam * signs
        try:
            chol = np.linalg.cholesky(sub)
            sol = np.linalg.solve(chol.T, np.linalg.solve(chol, rhs))
        except np.linalg.LinAlgError:
            # singular, e.g. duplicated inputs: any minimiser will do if the system is consistent
            sol = _min_norm_solve_np(sub, rhs)
            if np.abs(sub @ sol - rhs).max() > 1e-9 * (np.abs(rhs).max() + lam):
                return None, False
        flipped = np.sign(sol) != signs
        if flipped.any():
            cur = coef[support]
            ratio = cur[flipped] / (cur[flipped] - sol[flipped])  # in (0, 1]
            k = int(np.argmin(ratio))
            point = cur + ratio[k] * (sol - cur)
            point[np.flatnonzero(flipped)[k]] = 0.0
            out[support] = point
            return out, False
        out[support] = sol
    grad = sxy - sxx @ out
    slack = lam * (1 + 1e-11) + 1e-13 * np.abs(sxy).max()
    return out, not bool((np.abs(grad[~support]) > slack).any())


def _duality_gap(s, b, grad, lam, syy):
    """Duality gap of ``0.5 ||y - X b||^2 + lam ||b||_1`` per problem, from the moments.

    With ``r = y - X b``: ``X^T r = grad``, ``r^T y = syy - b.s``, ``||r||^2 = r^T y - b.grad``;
    the dual point is ``r`` scaled into the feasible set ``||X^T theta||_inf <= lam``
    (scikit-learn's ``enet_coordinate_descent_gram``).
    """
    ry = syy - np.einsum("bi,bi->b", b, s)
    r2 = np.maximum(ry - np.einsum("bi,bi->b", b, grad), 0.0)
    dual_norm = np.abs(grad).max(1)
    const = np.where(dual_norm > lam, lam / np.maximum(dual_norm, np.finfo(np.float64).tiny), 1.0)
    gap = 0.5 * r2 * (1 + const**2) + lam * np.abs(b).sum(1) - const * ry
    return np.where(dual_norm > lam, gap, r2 + lam * np.abs(b).sum(1) - ry)


def _coordinate_descent(sxx, sxy, lam, coef, *, tol: float, max_iter: int, syy=None, gap_tol=0.0):
    """Solve a batch of lasso problems in place, starting from ``coef``.

    Args:
        sxx: ``(B, d, d)``; sxy: ``(B, d)``; lam: ``(B,)`` thresholds ``n alpha``.
        coef: ``(B, d)`` warm start, overwritten with the solutions.
        tol: stop a problem when no coordinate moved more than ``tol * max |coef|`` in a sweep
            (only needed when the exact step does not apply, e.g. singular ``S_AA``).
        max_iter: maximum number of sweeps.
        syy: ``(B,)`` output sums of squares; with ``gap_tol`` > 0, a problem also stops when
            its duality gap (scikit-learn's, of ``0.5 ||y - X b||^2 + lam ||b||_1``) is at most
            ``gap_tol * syy``. This ends problems whose minimiser is not unique (exactly
            collinear inputs), where neither the exact step nor the step size settle.
        gap_tol: relative duality-gap tolerance (0: off).

    Returns:
        ``(n_sweeps, converged)``.

    The sweeps run on float64 NumPy copies: a sweep is ``d`` sequential updates of ``B``
    numbers each, whose cost is the per-operation overhead (about 1 us in NumPy against several
    in torch), not arithmetic.
    """
    S = sxx.detach().cpu().double().numpy()
    s = sxy.detach().cpu().double().numpy()
    lam_np = np.broadcast_to(lam.detach().cpu().double().numpy(), (s.shape[0],)).copy()
    b = coef.detach().cpu().double().numpy().copy()
    n_batch, d = s.shape
    diag = np.diagonal(S, axis1=1, axis2=2).copy()  # (B, d)
    usable = diag > 0
    safe = np.where(usable, diag, 1.0)
    grad = s - np.einsum("bij,bj->bi", S, b)  # (B, d)
    syy_np = None
    if syy is not None and gap_tol > 0:
        syy_np = np.broadcast_to(syy.detach().cpu().double().numpy(), (n_batch,)).copy()
    done = np.zeros(n_batch, dtype=bool)
    tried: list[bytes | None] = [None] * n_batch
    cols = np.ascontiguousarray(np.swapaxes(S, 1, 2))  # cols[:, j] = S[:, :, j]
    result = (max_iter, False)
    for sweep in range(1, max_iter + 1):
        step = np.zeros(n_batch)
        for j in range(d):
            old = b[:, j].copy()
            rho = grad[:, j] + diag[:, j] * old
            new = np.sign(rho) * np.clip(np.abs(rho) - lam_np, 0, None) / safe[:, j]
            new = np.where(usable[:, j] & ~done, new, np.where(done, old, 0.0))
            delta = new - old
            grad -= delta[:, None] * cols[:, j]
            b[:, j] = new
            np.maximum(step, np.abs(delta), out=step)
        scale = np.maximum(np.abs(b).max(1), np.finfo(np.float64).tiny)
        stalled = step <= tol * scale
        for i in np.flatnonzero(~done):
            # the exact step depends only on the support and signs: retry it when they change
            signature = np.sign(b[i]).astype(np.int8).tobytes()
            if signature == tried[i]:
                continue
            tried[i] = signature
            point, exact = _polish(S[i], s[i], float(lam_np[i]), b[i])
            if point is not None:
                b[i] = point
                grad[i] = s[i] - S[i] @ point
                done[i] = exact
        done |= stalled
        if syy_np is not None:
            done |= _duality_gap(s, b, grad, lam_np, syy_np) <= gap_tol * syy_np
        if done.all():
            result = (sweep, True)
            break
    coef.copy_(torch.from_numpy(b).to(coef))
    return result


def lasso_path(
    sxx: torch.Tensor,
    sxy: torch.Tensor,
    n: torch.Tensor,
    alphas: torch.Tensor,
    *,
    syy: torch.Tensor | None = None,
    gap_tol: float = 0.0,
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
        syy: output sums of squares (centred when fitting an intercept), shape ``(B,)``, for
            the duality-gap stop.
        gap_tol: relative duality-gap tolerance (see `Lasso`; 0: off).
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
            sweeps, ok = _coordinate_descent(
                sxx, sxy, n * alpha, coef, tol=tol, max_iter=max_iter, syy=syy, gap_tol=gap_tol
            )
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
        gap_tol: a problem also stops when its duality gap is at most ``gap_tol * y^T y``
            (``y`` centred when fitting an intercept; scikit-learn stops at 1e-4). It ends the
            problems whose minimiser is not unique (exactly collinear inputs), where the exact
            step does not apply and coordinate descent creeps; 0 turns it off.
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

    def __init__(
        self,
        *,
        alpha: float | None = None,
        alphas=None,
        n_alphas: int = 100,
        eps: float = 1e-3,
        tol: float = 1e-10,
        gap_tol: float = 1e-6,
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
        self.gap_tol = gap_tol
        self.max_iter = max_iter

    _cv_parameter = "alpha"

    @property
    def needs_folds(self) -> bool:
        """True when ``alpha`` is None: it is then chosen by cross-validation."""
        return self.alpha is None

    def _check_params(self, n_features: int) -> None:
        if self.alpha is not None:
            check_positive_real(self.alpha, "alpha")
        check_positive_real(self.tol, "tol")
        if not (isinstance(self.gap_tol, numbers.Real) and 0 <= self.gap_tol < 1):
            raise ValueError(f"gap_tol must be in [0, 1), got {self.gap_tol!r}")
        for name in ("n_alphas", "max_iter"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < 1:
                raise ValueError(f"{name} must be a positive integer, got {value!r}")
        eps = check_positive_real(self.eps, "eps")
        if eps >= 1:
            raise ValueError(f"eps must be in (0, 1), got {self.eps!r}")

    def _solve(self, moments: Moments, folds) -> torch.Tensor:
        sxx, sxy, syy, n = self._centered(moments)
        kw = {
            "tol": float(self.tol),
            "max_iter": int(self.max_iter),
            "gap_tol": float(self.gap_tol),
        }
        if self.alpha is not None:
            self.alpha_ = float(self.alpha)
            alphas = torch.tensor([self.alpha_], dtype=sxx.dtype, device=sxx.device)
            coefs, n_iter = lasso_path(sxx[None], sxy[None], n[None], alphas, syy=syy[None], **kw)
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
        problems = [self._centered(train) for train, _ in splits] + [(sxx, sxy, syy, n)]
        coefs, n_iter = lasso_path(
            torch.stack([p[0] for p in problems]),
            torch.stack([p[1] for p in problems]),
            torch.stack([p[3] for p in problems]),
            grid,
            syy=torch.stack([p[2] for p in problems]),
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
