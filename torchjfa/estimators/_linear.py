"""Ordinary least squares, ridge regression and total least squares from sufficient statistics.

Use `OLS` when the inputs are exact and well excited, `Ridge` when the Gram matrix is badly
conditioned (the penalty is chosen by generalised cross-validation unless given), and `TLS` when
inputs and output carry noise of equal variance (scale them first). For noisy inputs with
unknown, per-input noise levels use `BayesianJFA`; for sparse or low-rank models use `Lasso`,
`Stepwise` or `PLS`.

All three see only `Moments` (second moments about the mean when fitting an intercept), so they
work on logs of any length.
"""

from __future__ import annotations

import math

import torch

from .._util import single_thread
from ..stats import Moments
from ._cv import MomentEstimator, check_grid, check_positive_real

__all__ = ["OLS", "Ridge", "TLS", "min_norm_solve"]


#: columns whose norm is below this fraction of the largest column's are round-off: their
#: coefficient is 0 (sqrt of the float64 epsilon)
ROUNDOFF_COLUMN = 1.5e-8


@single_thread()  # small matrices: threads only wait on each other
def min_norm_solve(
    sxx: torch.Tensor, sxy: torch.Tensor, *, rcond: float = 1e-12
) -> tuple[torch.Tensor, int]:
    """Least-squares coefficients from the normal equations ``sxx b = sxy``, robust to singularity.

    The Gram matrix is scaled to unit diagonal (``C = D^-1 sxx D^-1``, ``D = sqrt(diag sxx)``),
    which removes the ill-conditioning due to column units, and solved through the
    eigen-decomposition of ``C``; eigenvalues below ``rcond * max eigenvalue`` are treated as
    zero (pseudo-inverse). Columns whose norm is below `ROUNDOFF_COLUMN` of the largest
    column's hold round-off only and get coefficient 0. For full-rank data this is the least-squares solution; for
    rank-deficient data (e.g. duplicated columns) it is the minimum-norm solution in the scaled
    coordinates, which is the usual minimum-norm solution when the dependent columns have the
    same scale (exactly duplicated columns share their weight equally).

    Args:
        sxx: Gram matrix, shape ``(d, d)``, symmetric positive semi-definite.
        sxy: right-hand side, shape ``(d,)``.
        rcond: relative cut-off on the eigenvalues of the scaled Gram matrix (so on the squared
            singular values of the scaled inputs).

    Returns:
        ``(coef, rank)``: coefficients of shape ``(d,)`` and the numerical rank used.
    """
    scale = torch.sqrt(torch.diagonal(sxx).clamp_min(0))
    # a column this far below the largest holds round-off (a kinematic cos(pi/2), say), not a
    # signal: scaled to unit norm it would look like one and take an absurd coefficient
    live = scale > ROUNDOFF_COLUMN * scale.max()
    coef = torch.zeros_like(sxy)
    if not bool(live.any()):
        return coef, 0
    s, idx = scale[live], live.nonzero().flatten()
    corr = sxx[idx][:, idx] / torch.outer(s, s)
    evals, evecs = torch.linalg.eigh(0.5 * (corr + corr.T))
    keep = evals > rcond * evals[-1].clamp_min(torch.finfo(evals.dtype).tiny)
    z = evecs[:, keep].T @ (sxy[idx] / s)
    coef[idx] = (evecs[:, keep] @ (z / evals[keep])) / s
    return coef, int(keep.sum())


class OLS(MomentEstimator):
    """Ordinary least squares: minimise ``||y - X b - c||^2`` (``c`` only if ``fit_intercept``).

    Rank-deficient data (duplicated or collinear columns) does not fail: the normal equations
    are solved by an eigen-decomposition based pseudo-inverse of the column-scaled Gram matrix
    (see `min_norm_solve`), which returns the minimum-norm solution among the least-squares
    ones, like ``numpy.linalg.lstsq``.

    Args:
        fit_intercept: fit an unpenalised intercept (centre the moments).
        rcond: relative eigenvalue cut-off of the scaled Gram matrix below which directions
            are treated as unidentifiable.

    Attributes:
        coef_: shape ``(d,)``; 0 for constant columns.
        intercept_: 0-d.
        rank_: numerical rank of the (non-constant part of the) Gram matrix.
    """

    def __init__(self, *, fit_intercept: bool = True, rcond: float = 1e-12) -> None:
        super().__init__(fit_intercept=fit_intercept)
        self.rcond = rcond

    def _check_params(self, n_features: int) -> None:
        check_positive_real(self.rcond, "rcond")

    def _solve(self, moments: Moments, folds) -> torch.Tensor:
        sxx, sxy, _, _ = self._centered(moments)
        coef, self.rank_ = min_norm_solve(sxx, sxy, rcond=float(self.rcond))
        return coef


class Ridge(MomentEstimator):
    """Ridge regression: minimise ``||y - X b - c||^2 + alpha ||b||^2`` (intercept unpenalised).

    The penalty is scikit-learn's (`sklearn.linear_model.Ridge`). With ``alpha=None`` it is
    chosen by generalised cross-validation (Golub, Heath & Wahba 1979),

        GCV(alpha) = (RSS(alpha) / n) / (1 - tr H(alpha) / n)^2,
        tr H(alpha) = [fit_intercept] + sum_i s_i / (s_i + alpha),

    with ``s_i`` the eigenvalues of the (centred) Gram matrix and ``n`` the total weight; both
    RSS and the trace of the hat matrix follow from one eigen-decomposition, so no folds are
    needed and `fit_moments` accepts a single `Moments`.

    Args:
        alpha: penalty (``>= 0``; 0 is `OLS`); ``None`` to choose it by GCV.
        alphas: candidate penalties for GCV; by default ``n_alphas`` values log-spaced from
            ``1e-10`` to ``1e4`` times the mean eigenvalue of the Gram matrix.
        n_alphas: size of the default grid.
        fit_intercept: fit an unpenalised intercept.

    Attributes:
        coef_, intercept_: the fitted model.
        alpha_: the penalty used.
        alphas_: the GCV grid, shape ``(n_alphas,)`` (only when ``alpha`` is None).
        gcv_: GCV value at each grid point, shape ``(n_alphas,)`` (``inf`` where the hat
            matrix has trace ``>= n``); ``alpha_`` is its argmin.
    """

    def __init__(
        self,
        *,
        alpha: float | None = None,
        alphas=None,
        n_alphas: int = 100,
        fit_intercept: bool = True,
    ) -> None:
        super().__init__(fit_intercept=fit_intercept)
        self.alpha = alpha
        self.alphas = alphas
        self.n_alphas = n_alphas

    def _check_params(self, n_features: int) -> None:
        if self.alpha is not None:
            check_positive_real(self.alpha, "alpha", allow_zero=True)
        if self.alpha is None and self.alphas is None:
            if isinstance(self.n_alphas, bool) or not isinstance(self.n_alphas, int):
                raise ValueError(f"n_alphas must be a positive integer, got {self.n_alphas!r}")
            if self.n_alphas < 1:
                raise ValueError(f"n_alphas must be a positive integer, got {self.n_alphas!r}")

    def _solve(self, moments: Moments, folds) -> torch.Tensor:
        sxx, sxy, syy, n = self._centered(moments)
        if self.alpha is not None:
            self.alpha_ = float(self.alpha)
            if self.alpha_ == 0.0:
                return min_norm_solve(sxx, sxy)[0]
            eye = torch.eye(sxx.shape[0], dtype=sxx.dtype, device=sxx.device)
            return torch.linalg.solve(sxx + self.alpha_ * eye, sxy)
        evals, evecs = torch.linalg.eigh(sxx)
        evals = evals.clamp_min(0)  # (d,)
        if self.alphas is None:
            scale = evals.mean().clamp_min(torch.finfo(evals.dtype).tiny)
            grid = scale * torch.logspace(
                -10, 4, int(self.n_alphas), dtype=evals.dtype, device=evals.device
            )
        else:
            grid = check_grid(self.alphas, "alphas", device=sxx.device)
        z2 = (evecs.T @ sxy) ** 2  # (d,)
        a = grid[:, None]  # (k, 1)
        # RSS(alpha) = syy - 2 z^T (S + a)^-1 z + z^T S (S + a)^-2 z, in the eigenbasis
        rss = syy - (z2 * (evals + 2 * a) / (evals + a) ** 2).sum(1)
        rss = rss.clamp_min(0)
        trace = float(self.fit_intercept) + (evals / (evals + a)).sum(1)
        gcv = (rss / n) / (1 - trace / n) ** 2
        gcv = torch.where(trace < n, gcv, torch.full_like(gcv, math.inf))
        best = int(torch.argmin(gcv))
        self.alphas_, self.gcv_ = grid, gcv
        self.alpha_ = float(grid[best])
        return evecs @ ((evecs.T @ sxy) / (evals + grid[best]))


class TLS(MomentEstimator):
    """Total least squares (errors-in-variables with equal noise on every input and the output).

    Minimises the orthogonal distance of the points ``[x_i, y_i]`` to the hyperplane
    ``y = x^T b + c``: ``b = -v[:d] / v[d]`` with ``v`` the eigenvector of the smallest eigenvalue
    of the (centred) augmented Gram matrix ``[[Sxx, Sxy], [Sxy^T, Syy]]``, i.e. the last right
    singular vector of ``[X y]`` (Golub & Van Loan 1980). TLS is not scale invariant: express
    inputs and output in units in which their noise variances are equal.

    Args:
        fit_intercept: fit an intercept (centre the moments).

    Attributes:
        coef_, intercept_: the fitted model.
        noise_variance_: smallest eigenvalue divided by the total weight, the (biased) estimate
            of the common noise variance.

    Exact collinearities among the inputs (redundant columns) are skipped, and a repeated
    smallest singular value gives the minimum-norm solution over its subspace (Golub and Van
    Loan, 1980).

    Raises:
        ValueError: at fit, when the least-varying direction of ``[X y]`` that is not an exact
            input collinearity has no output component (the hyperplane is parallel to ``y``).
    """

    def __init__(self, *, fit_intercept: bool = True) -> None:
        super().__init__(fit_intercept=fit_intercept)

    def _solve(self, moments: Moments, folds) -> torch.Tensor:
        sxx, sxy, syy, n = self._centered(moments)
        d = sxx.shape[0]
        aug = torch.empty(d + 1, d + 1, dtype=sxx.dtype, device=sxx.device)
        aug[:d, :d], aug[:d, d], aug[d, :d], aug[d, d] = sxx, sxy, sxy, syy
        evals, evecs = torch.linalg.eigh(aug)  # ascending
        tol = 1e-12 * float(evals[-1].abs())
        y_min = math.sqrt(torch.finfo(evecs.dtype).eps)
        # Exact collinearities among the inputs are null directions of [X y] with no output
        # component; they say nothing about y and are skipped (the minimum-norm solution spreads
        # the coefficient over the collinear inputs).
        k = 0
        while k < d and float(evals[k]) <= tol and float(evecs[d, k].abs()) <= y_min:
            k += 1
        # A repeated smallest singular value leaves a subspace of solutions: take the
        # minimum-norm one over the whole cluster (Golub and Van Loan, 1980, section 3).
        cluster = (evals >= evals[k] - tol) & (evals <= evals[k] + tol)
        V2 = evecs[:, cluster]  # (d + 1, p)
        if float(V2[d].norm()) <= y_min:
            raise ValueError(
                "TLS is degenerate: the best-fitting hyperplane of [X y] is parallel to the y axis "
                "(y is uncorrelated with the least-varying input direction), so y cannot be "
                "expressed in X; use OLS/Ridge or rescale the variables"
            )
        self.noise_variance_ = float(evals[k].clamp_min(0) / n)
        return -(V2[:d] @ V2[d]) / (V2[d] @ V2[d])
