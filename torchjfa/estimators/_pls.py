"""Partial least squares regression (PLS1) from sufficient statistics.

Use `PLS` when the inputs are many and strongly collinear and a low-rank model is wanted: it
regresses ``y`` on the few directions of ``X`` that covary most with ``y``. With all components
it is `OLS`.

PLS1 with ``k`` components is least squares restricted to the Krylov space
``K_k(Sxx, Sxy) = span{Sxy, Sxx Sxy, ..., Sxx^(k-1) Sxy}`` (Helland 1988), so it needs only the
(centred) Gram matrix and cross-moment. The orthonormal basis ``W`` of that space is built one
weight vector at a time: ``w_(k+1)`` is the normalised residual gradient ``Sxy - Sxx b_k``
(which is what NIPALS's deflated ``X_k^T y_k`` equals), re-orthogonalised for stability, and
``b_k = W (W^T Sxx W)^-1 W^T Sxy``. The coefficients equal those of
``sklearn.cross_decomposition.PLSRegression(scale=False)``.
"""

from __future__ import annotations

import numbers

import torch

from .._util import progress_bar
from ..stats import Moments
from ._cv import MomentEstimator, cv_mse, train_test_splits

__all__ = ["PLS", "pls1_path"]

# a residual gradient this small (relative to |Sxy|) means the fit is exact: no more components
_STOP_RTOL = 1e-12


def pls1_path(sxx: torch.Tensor, sxy: torch.Tensor, n_components: int) -> tuple[torch.Tensor, int]:
    """PLS1 coefficients for ``1..n_components`` components.

    Args:
        sxx: Gram matrix (centred if an intercept is fitted), shape ``(d, d)``.
        sxy: cross-moment, shape ``(d,)``.
        n_components: largest number of components.

    Returns:
        ``(coefs, n_used)``: coefficients of shape ``(n_components, d)``, row ``k`` using
        ``k + 1`` components, and the number of components actually built. When the Krylov space
        stops growing earlier (the residual gradient vanishes: the fit is already the
        least-squares one, or ``Sxy = 0``), the remaining rows repeat the last solution.
    """
    d = sxx.shape[0]
    coefs = torch.zeros(n_components, d, dtype=sxx.dtype, device=sxx.device)
    basis = torch.zeros(d, 0, dtype=sxx.dtype, device=sxx.device)  # W, (d, k)
    coef = torch.zeros(d, dtype=sxx.dtype, device=sxx.device)
    norm0 = float(torch.linalg.vector_norm(sxy))
    for k in range(n_components):
        grad = sxy - sxx @ coef
        for _ in range(2):  # classical Gram-Schmidt, twice is enough
            grad = grad - basis @ (basis.T @ grad)
        norm = float(torch.linalg.vector_norm(grad))
        if norm0 == 0.0 or norm <= _STOP_RTOL * norm0:
            coefs[k:] = coef
            return coefs, k
        basis = torch.cat([basis, (grad / norm)[:, None]], dim=1)
        proj = basis.T @ sxx @ basis  # (k+1, k+1), positive definite
        coef = basis @ torch.linalg.solve(0.5 * (proj + proj.T), basis.T @ sxy)
        coefs[k] = coef
    return coefs, n_components


class PLS(MomentEstimator):
    """PLS1 regression (partial least squares with one output, unscaled inputs).

    Args:
        n_components: number of latent components, ``1 <= n_components <= d``; ``None`` to
            choose it by ``cv``-fold cross-validation over ``1..max_components``.
        max_components: largest number tried by cross-validation (default: all informative
            inputs).
        fit_intercept: centre the moments and fit an intercept.
        cv: number of contiguous folds used by `fit` when ``n_components`` is None.
        verbose: show a progress bar over the folds.

    Attributes:
        coef_, intercept_: the fitted model.
        n_components_: components used (fewer than asked when the fit became exact earlier, or
            when there are fewer informative inputs).
        mse_path_: validation mean squared error of each candidate on each fold, shape
            ``(max_components, n_folds)`` (only when chosen by CV).
        n_components_grid_: the candidates, ``1..max_components``.
    """

    def __init__(
        self,
        *,
        n_components: int | None = None,
        max_components: int | None = None,
        fit_intercept: bool = True,
        cv: int = 5,
        verbose: bool = False,
    ) -> None:
        super().__init__(fit_intercept=fit_intercept, cv=cv, verbose=verbose)
        self.n_components = n_components
        self.max_components = max_components

    _cv_parameter = "n_components"

    @property
    def needs_folds(self) -> bool:
        """True when ``n_components`` is None: it is then chosen by cross-validation."""
        return self.n_components is None

    def _check_params(self, n_features: int) -> None:
        for name in ("n_components", "max_components"):
            value = getattr(self, name)
            if value is None:
                continue
            if isinstance(value, bool) or not isinstance(value, numbers.Integral):
                raise ValueError(f"{name} must be an integer or None, got {value!r}")
            if not 1 <= int(value) <= n_features:
                raise ValueError(
                    f"{name} must be between 1 and the number of inputs ({n_features}), got {value}"
                )

    def _solve(self, moments: Moments, folds) -> torch.Tensor:
        d = moments.n_features
        if self.n_components is not None:
            k = min(int(self.n_components), d)
        else:
            k_max = d if self.max_components is None else min(int(self.max_components), d)
            splits = train_test_splits(moments, folds)
            coefs = []
            with progress_bar(total=len(splits), desc="PLS CV", enabled=self.verbose) as bar:
                for train, _ in splits:
                    sxx, sxy, _, _ = self._centered(train)
                    coefs.append(pls1_path(sxx, sxy, k_max)[0])
                    bar.update(1)
            self.mse_path_ = cv_mse(splits, coefs, self.fit_intercept)
            self.n_components_grid_ = torch.arange(1, k_max + 1)
            k = int(torch.argmin(self.mse_path_.mean(1))) + 1
        sxx, sxy, _, _ = self._centered(moments)
        path, self.n_components_ = pls1_path(sxx, sxy, k)
        return path[-1]
