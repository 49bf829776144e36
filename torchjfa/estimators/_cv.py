"""Shared machinery of the standard linear estimators: parameter checks and CV on fold moments.

Cross-validation never touches rows: for fold ``k`` the training statistics are
``total - fold_k`` and the validation error is ``fold_k``'s residual sum of squares, computed from
the fold's own moments (`Moments.rss`). So ``fit(X, y)`` (which builds contiguous fold moments
with `kfold_moments`) and ``fit_moments(folds)`` give the same answer, however the folds were
accumulated.
"""

from __future__ import annotations

import inspect
import numbers
from collections.abc import Sequence

import torch

from ..stats import Moments, as_folds
from ._base import LinearEstimator

__all__ = ["MomentEstimator", "batched_rss", "fold_intercepts", "train_test_splits"]


class MomentEstimator(LinearEstimator):
    """`LinearEstimator` that checks ``fit_intercept`` and ``cv`` at fit time.

    Subclasses implement ``_check_params(n_features)`` (`LinearEstimator._check_params`:
    raising ``ValueError`` on invalid hyper-parameters) in addition to ``_solve``.
    """

    def __init__(self, *, fit_intercept: bool = True, cv: int = 5, verbose: bool = False) -> None:
        super().__init__(fit_intercept=fit_intercept, cv=cv)
        self.verbose = verbose

    def fit(self, X, y, weights=None):
        """Fit from raw data: ``X`` ``(n, d)``, ``y`` ``(n,)``, optional ``weights`` ``(n,)``.

        Returns ``self``. Estimators that choose a hyper-parameter by cross-validation split the
        rows into ``cv`` contiguous folds (`kfold_moments`).
        """
        self._check_common()
        return super().fit(X, y, weights)

    def fit_moments(self, moments: Moments | Sequence[Moments]):
        """Fit from sufficient statistics. Returns ``self``.

        Args:
            moments: a `Moments`, or a sequence of `Moments` of disjoint folds of the data
                (their sum is the training set; estimators that choose a hyper-parameter by
                cross-validation use the folds).

        Raises:
            ValueError: on invalid hyper-parameters, empty moments, or when a hyper-parameter
                must be chosen by cross-validation and a single `Moments` was given.
        """
        _, folds = as_folds(moments)
        self._check_common()
        return super().fit_moments(moments if folds is None else folds)

    def _check_common(self) -> None:
        if not isinstance(self.fit_intercept, bool):
            raise TypeError(f"fit_intercept must be a bool, got {self.fit_intercept!r}")
        if (
            isinstance(self.cv, bool)
            or not isinstance(self.cv, numbers.Integral)
            or int(self.cv) < 2
        ):
            raise ValueError(
                f"cv must be an integer of at least 2 (the number of folds), got {self.cv!r}"
            )

    def __repr__(self) -> str:
        names = [k for k in inspect.signature(type(self).__init__).parameters if k != "self"]
        params = ", ".join(f"{k}={getattr(self, k)!r}" for k in names)
        return f"{type(self).__name__}({params})"


def check_positive_real(value, name: str, *, allow_zero: bool = False) -> float:
    """``value`` as a float, raising ``ValueError`` unless it is finite and > 0 (or >= 0)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise TypeError(f"{name} must be a real number, got {value!r}")
    v = float(value)
    ok = v >= 0 if allow_zero else v > 0
    if not (ok and v < float("inf")):
        bound = "non-negative" if allow_zero else "positive"
        raise ValueError(f"{name} must be finite and {bound}, got {value!r}")
    return v


def check_grid(values, name: str, *, device) -> torch.Tensor:
    """A user-given hyper-parameter grid as a 1-D float64 tensor of positive finite values."""
    grid = torch.as_tensor(values, dtype=torch.float64, device=device).reshape(-1)
    if grid.numel() < 1 or not bool(torch.isfinite(grid).all()) or not bool((grid > 0).all()):
        raise ValueError(f"{name} must be a non-empty sequence of positive finite numbers")
    return grid


def train_test_splits(total: Moments, folds: list[Moments]) -> list[tuple[Moments, Moments]]:
    """``[(total - fold_k, fold_k)]``: training and validation statistics of each fold."""
    return [(total - f, f) for f in folds]


def fold_intercepts(train: Moments, coef: torch.Tensor, fit_intercept: bool) -> torch.Tensor:
    """Intercepts ``mean_y - mean_x @ coef`` of coefficients ``(k, d)``, shape ``(k,)``."""
    if not fit_intercept:
        return torch.zeros(coef.shape[0], dtype=coef.dtype, device=coef.device)
    return train.mean_y - coef @ train.mean_x


def batched_rss(m: Moments, coef: torch.Tensor, intercept: torch.Tensor) -> torch.Tensor:
    """`Moments.rss` of a batch of models: ``coef`` ``(k, d)``, ``intercept`` ``(k,)``.

    Returns:
        Residual sums of squares, shape ``(k,)``.
    """
    quad = torch.einsum("kd,de,ke->k", coef, m.xtx, coef)
    return (
        m.yty
        - 2 * coef @ m.xty
        + quad
        - 2 * intercept * (m.sum_y - coef @ m.sum_x)
        + intercept * intercept * m.n
    )


def cv_mse(
    splits: list[tuple[Moments, Moments]], coefs: list[torch.Tensor], fit_intercept: bool
) -> torch.Tensor:
    """Validation mean squared errors, shape ``(k, n_folds)``.

    Args:
        splits: ``(train, test)`` moments of each fold.
        coefs: per fold, the coefficients of ``k`` candidate models fitted on ``train``,
            shape ``(k, d)``.
        fit_intercept: whether each model's intercept is ``train.mean_y - train.mean_x @ coef``.

    Returns:
        ``rss / weight`` of each candidate on each validation fold (weighted mean squared error).
    """
    cols = []
    for (train, test), coef in zip(splits, coefs, strict=True):
        c = fold_intercepts(train, coef, fit_intercept)
        cols.append(batched_rss(test, coef, c) / test.n)
    return torch.stack(cols, dim=1)
